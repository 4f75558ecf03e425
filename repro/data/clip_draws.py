"""Seeded draws of clip rows from a pool of a ClipSet: class-balanced and per-class (data layer).

ODMO (MM'22) §3.1, §4.1 and protocols.md §3.1-3.2: the reference loaders draw training windows
with a WeightedRandomSampler (class weight ∝ 1/count, so every class present is equally likely,
then a clip of it uniformly), and real reference sets take a fixed count per class.  Every
caller that draws clips for windows does it here: the evaluators' training windows
(:mod:`repro.eval.sampling`), ODMO's epoch draws (:class:`repro.data.odmo_items.WindowItems`)
and ODMO's real sets (:mod:`repro.eval.protocols.odmo_common`).

:func:`balanced_clips` has two recipes of the one class-balanced distribution.  They consume
the random generator differently, so each keeps the draws (and so the numbers) that were made
with it: ``"weights"`` (one weighted ``choice`` over the pool, the WeightedRandomSampler's
form; the evaluators' windows) and ``"class_first"`` (a class uniformly per draw, then a clip
uniformly within each class; ODMO's training draws).  ``"uniform"`` draws clips uniformly
without balancing.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

__all__ = ["balanced_clips", "per_class_clips"]


def balanced_clips(clipset, pool, n: int, rng: np.random.Generator,
                   *, recipe: Literal["weights", "class_first", "uniform"] = "weights"
                   ) -> np.ndarray:
    """``n`` clip rows drawn with replacement from ``pool`` (rows of ``clipset``): every class
    present equally likely, then a clip of it uniformly, by ``recipe`` (module docstring);
    ``"uniform"``: clips uniformly."""
    pool = np.asarray(pool, dtype=np.int64)
    n = int(n)
    if recipe == "uniform":
        return pool[rng.integers(0, pool.size, size=n)]
    labels = clipset.labels[pool]
    if recipe == "weights":
        classes, counts = np.unique(labels, return_counts=True)
        w = 1.0 / counts[np.searchsorted(classes, labels)]
        return pool[rng.choice(pool.size, size=n, replace=True, p=w / w.sum())]
    if recipe != "class_first":
        raise ValueError(f"recipe must be 'weights', 'class_first' or 'uniform', got {recipe!r}")
    classes = np.unique(labels)
    pick = classes[rng.integers(0, classes.size, size=n)]
    out = np.empty(n, dtype=np.int64)
    for c in classes:
        where = np.flatnonzero(pick == c)
        if where.size:
            members = pool[labels == c]
            out[where] = members[rng.integers(0, members.size, size=where.size)]
    return out


def per_class_clips(clipset, pool, per_class: int, rng: np.random.Generator) -> np.ndarray:
    """``per_class`` clip rows of every class present in ``pool``, drawn uniformly with
    replacement within the class, classes in index order (the clips of ODMO's real sets,
    protocols.md §3.2)."""
    pool = np.asarray(pool, dtype=np.int64)
    labels = np.asarray(clipset.labels[pool])
    clips = []
    for c in np.unique(labels):
        members = pool[labels == c]
        clips.append(members[rng.integers(0, members.size, size=per_class)])
    return np.concatenate(clips)
