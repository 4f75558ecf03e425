"""Recognition accuracy (top-1, top-k) and the confusion matrix.

Action2Motion protocol used by all three papers (Neural Marionette §5.1.2 "Recognition
Accuracy", MultiAct §5 "Accuracy" with top-5, ODMO §4.2.1 "Acc"; protocols.md §1.2, §4.5):
the recogniser's arg-max prediction is compared with the conditioning label; accuracy is
correct / N over all samples (no per-class averaging).  Units: a fraction in [0, 1].

``merge`` reproduces MultiAct's label merging: a mapping from ground-truth class index to the
set of accepted predicted indices (or a :class:`~repro.metrics.label_merge.LabelMerge`, e.g.
:data:`MULTIACT_LABEL_MERGE`).  A ground-truth class that is not a key needs an exact match.
For top-k, a sample is correct if *any* of its k highest-scoring classes qualifies.

Ties in the logits go to the lower class index (numpy's arg-max / stable sort).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass

import numpy as np

from repro.errors import DataError
from repro.metrics.arrays import check_classes, int_array, to_numpy
from repro.metrics.label_merge import MULTIACT_LABEL_MERGE, MULTIACT_LABELS, LabelMerge

__all__ = ["AccuracyResult", "accuracy", "confusion_matrix", "top_k_predictions",
           "MULTIACT_LABEL_MERGE", "MULTIACT_LABELS", "LabelMerge"]


@dataclass(frozen=True)
class AccuracyResult:
    """``value = correct / n`` (fraction); the counts are kept for Wilson intervals."""

    value: float
    correct: int
    n: int

    def __float__(self) -> float:
        return float(self.value)

    def to_dict(self) -> dict:
        return {"value": float(self.value), "correct": self.correct, "n": self.n}


def top_k_predictions(logits, k: int) -> np.ndarray:
    """(N, k) class indices of the k largest logits per row, best first (ties: lower index)."""
    x = to_numpy(logits)
    if x.ndim != 2:
        raise DataError(f"logits: expected an (N, C) array, got shape {x.shape}")
    if not 1 <= k <= x.shape[1]:
        raise DataError(f"top_k must lie in 1..{x.shape[1]} (the number of classes), got {k}")
    x = x.astype(np.float64, copy=False)
    if np.isnan(x).any():
        raise DataError("logits: contains NaN")
    return np.argsort(-x, axis=1, kind="stable")[:, :k]


def _merge_index_map(merge, n_classes: int | None) -> dict[int, frozenset[int]] | None:
    if merge is None:
        return None
    if isinstance(merge, LabelMerge):
        return merge.index_map()
    if not isinstance(merge, Mapping):
        raise DataError("merge: expected a LabelMerge or a mapping {gt index: accepted indices}")
    out: dict[int, frozenset[int]] = {}
    for key, accepted in merge.items():
        if not isinstance(key, (int, np.integer)) or not isinstance(accepted, Collection):
            raise DataError("merge: keys must be class indices and values collections of "
                            "class indices (use a LabelMerge for label names)")
        out[int(key)] = frozenset(int(a) for a in accepted)
    return out


def accuracy(logits_or_preds, labels, top_k: int = 1, merge=None) -> AccuracyResult:
    """Top-k accuracy of predictions against ground-truth class indices.

    ``logits_or_preds``: (N, C) logits/probabilities, or (N,) predicted indices (top_k = 1
    only).  ``labels``: (N,) ground-truth indices.  ``merge``: optional label merging (module
    docstring).  Returns :class:`AccuracyResult`.
    """
    x = to_numpy(logits_or_preds)
    if x.ndim == 1:
        if top_k != 1:
            raise DataError("top_k > 1 needs (N, C) logits, not predicted indices")
        top = int_array(x, "predictions")[:, None]
    else:
        top = top_k_predictions(x, top_k)
    y = int_array(labels, "labels", n=top.shape[0])
    if y.size == 0:
        raise DataError("accuracy: no samples")
    if x.ndim == 2:
        check_classes(y, x.shape[1], "labels")
    index_map = _merge_index_map(merge, None)
    hit = top == y[:, None]
    if index_map:
        for gt, accepted in index_map.items():
            rows = y == gt
            if rows.any() and accepted:
                hit[rows] |= np.isin(top[rows], np.fromiter(accepted, dtype=np.int64))
    correct = int(hit.any(axis=1).sum())
    n = int(y.shape[0])
    return AccuracyResult(value=correct / n, correct=correct, n=n)


def confusion_matrix(preds, labels, n_classes: int) -> np.ndarray:
    """(C, C) int64 counts; row = ground-truth label, column = prediction (protocols §1.2).

    ``preds`` may be (N,) indices or (N, C) logits (arg-max taken).
    """
    p = to_numpy(preds)
    p = top_k_predictions(p, 1)[:, 0] if p.ndim == 2 else int_array(p, "predictions")
    y = int_array(labels, "labels", n=p.shape[0])
    check_classes(y, n_classes, "labels")
    check_classes(p, n_classes, "predictions")
    flat = np.bincount(y * n_classes + p, minlength=n_classes * n_classes)
    return flat.reshape(n_classes, n_classes).astype(np.int64)
