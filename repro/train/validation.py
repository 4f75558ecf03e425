"""The validation split behind every learning curve: :func:`holdout`.

Why: none of the reproduced papers states a validation set (they train on the whole training
split and report no validation curve), so we cannot copy theirs.  To show whether a model
under- or over-fits at the scales we run, a small held-out part of the *training* actions
(``validation_fraction`` of the scale profile: 5 % of the training clips per class at the
quick and medium scales, none at paper scale) draws a validation curve beside the training
loss.  It is only ever plotted: no checkpoint, epoch count or hyper-parameter is selected
with it, and the test split is never touched.

How: items are held out by **source clip** (``ActionItems.clip_index``), so the windows of one
clip never sit on both sides (a window of a training clip would otherwise "validate" on frames
the model trained on); stratified per class label; seeded per class from
``(seed, "validation", label)``; at least one clip of every class with two or more clips is
held out (so every class appears in the curve) and none of a class with a single clip (so
every class is trained on).
"""

from __future__ import annotations

import math

import numpy as np

from repro.seeding import numpy_rng


def _groups(items) -> np.ndarray:
    """(N,) group id per item: its source clip, or its own position when it has none
    (``clip_index`` None, or -1 for an item not cut from a ClipSet)."""
    n = len(items)
    own = -1 - np.arange(n, dtype=np.int64)          # unique, never a clip row
    clip_index = getattr(items, "clip_index", None)  # PairItems: S_c's source clip, if given
    if clip_index is None:
        return own
    clip = clip_index.detach().cpu().numpy().astype(np.int64).reshape(n)
    return np.where(clip >= 0, clip, own)


def holdout_positions(items, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train positions, validation positions) of :func:`holdout`, each sorted ascending."""
    fraction = float(fraction)
    if not (0.0 <= fraction < 1.0) or math.isnan(fraction):
        raise ValueError(f"validation fraction must lie in [0, 1), got {fraction!r}")
    n = len(items)
    everything = np.arange(n, dtype=np.int64)
    if fraction == 0.0 or n == 0:
        return everything, np.zeros(0, np.int64)
    groups = _groups(items)
    labels = items.labels.detach().cpu().numpy().astype(np.int64).reshape(n)
    # a clip's class: the label of its first item (the windows of one clip share its label;
    # a composed sequence's segments may not, and then the first segment's label decides)
    uniq, first = np.unique(groups, return_index=True)
    clip_label = labels[first]
    held: list[np.ndarray] = []
    for lab in np.unique(clip_label):
        clips = np.sort(uniq[clip_label == lab])
        if clips.size < 2:
            continue
        k = min(max(1, math.floor(fraction * clips.size + 0.5)), clips.size - 1)
        pick = numpy_rng(seed, "validation", int(lab)).permutation(clips.size)[:k]
        held.append(clips[pick])
    if not held:
        return everything, np.zeros(0, np.int64)
    is_val = np.isin(groups, np.concatenate(held))
    return everything[~is_val], everything[is_val]


def holdout(items, fraction: float, seed: int):
    """Split ``items`` (an :class:`~repro.data.action_items.ActionItems`) into
    ``(train_items, val_items)`` by source clip, stratified per class (module docstring).

    ``fraction`` (0 ≤ f < 1) is the share of each class's clips held out, rounded to the
    nearest count, at least one when the class has two or more clips, never all of them.
    ``fraction == 0`` (or nothing to hold out) returns ``(items, None)`` unchanged, so a
    training without validation keeps its items (and its keys and checkpoints).  The split
    depends only on the items, ``fraction`` and ``seed``; both sides keep the items' order.
    """
    train_pos, val_pos = holdout_positions(items, fraction, seed)
    if val_pos.size == 0:
        return items, None
    return items.subset(train_pos), items.subset(val_pos)


__all__ = ["holdout", "holdout_positions"]
