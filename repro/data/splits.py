"""Deterministic train/test splits of a :class:`~repro.data.clipset.ClipSet`.

Two splits, both seeded (:func:`repro.seeding.numpy_rng`, one independent stream per stratum,
so adding a class never reshuffles another):

- :func:`stratified_split`: the stand-in's default split, stratified by action *and* style
  (default 80/20).  Within each (action, style) cell the clips are shuffled and the first
  ``round(n * test_fraction)`` go to test (half-up rounding).
- :func:`subject_split`: whole subjects to test (a declared data set's ``[split] by =
  "subject"``): subjects in a seeded order join the test side until it holds at least
  ``round(n * test_fraction)`` clips, so no subject is on both sides.
- :func:`group_split`: whole groups (styles or subjects) to test, chosen so that every action
  has test *and* training clips (a declared data set's ``[split] by = "style"``, or ``by =
  "subject"`` with ``stratify = "action"``; algorithm in its docstring).
- :func:`marionette_split`: Neural Marionette Sec. 5.1.1 ("for every action class, we randomly
  select 20% to 100 samples to construct a testing set and use the rest data for training"),
  read as ``min(cap, round(0.2 * n_class))`` test clips per class, classes only (protocols.md §5).

Each returns an ``int8`` array, 0 = train and 1 = test (:data:`~repro.data.clipset.TRAIN`,
:data:`~repro.data.clipset.TEST`); :func:`with_split` puts one on a ClipSet.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from repro.data.clipset import TEST, TRAIN, ClipSet
from repro.seeding import numpy_rng

#: Seed of the stored default split of the stand-in data sets.
DEFAULT_SPLIT_SEED = 0
DEFAULT_TEST_FRACTION = 0.2


def _n_test(n: int, fraction: float) -> int:
    return int(math.floor(n * fraction + 0.5))


def _check_fraction(test_fraction: float) -> None:
    if not 0.0 <= test_fraction < 1.0:
        raise ValueError(f"test_fraction must be in [0, 1), got {test_fraction}")


def stratified_split(labels, styles=None, *, test_fraction: float = DEFAULT_TEST_FRACTION,
                     seed: int = DEFAULT_SPLIT_SEED) -> np.ndarray:
    """A seeded split stratified by (label, style): per cell, ``round(n·f)`` clips go to test.

    ``labels``, ``styles``: (N,) ints (``styles=None`` or ``-1`` entries: stratify by label only).
    Clip order defines identity: the same arrays and seed give the same split, byte for byte.
    """
    _check_fraction(test_fraction)
    labels = np.asarray(labels, np.int64)
    styles = np.full_like(labels, -1) if styles is None else np.asarray(styles, np.int64)
    if styles.shape != labels.shape:
        raise ValueError("labels and styles differ in shape")
    split = np.full(labels.shape[0], TRAIN, dtype=np.int8)
    cells = sorted(set(zip(labels.tolist(), styles.tolist())))
    for lab, sty in cells:
        idx = np.flatnonzero((labels == lab) & (styles == sty))
        k = _n_test(idx.size, test_fraction)
        if k:
            rng = numpy_rng(seed, "stratified_split", test_fraction, lab, sty)
            split[rng.permutation(idx)[:k]] = TEST
    return split


def subject_split(subjects, *, test_fraction: float = DEFAULT_TEST_FRACTION,
                  seed: int = DEFAULT_SPLIT_SEED) -> np.ndarray:
    """A seeded subject-disjoint split: ``subjects`` (N,) names (or ids), one per clip; the
    subjects, sorted then permuted by the seed, go to test one by one until it holds at least
    ``round(N·f)`` clips; at least one subject stays in training (ValueError with fewer than
    two subjects)."""
    _check_fraction(test_fraction)
    subjects = [str(x) for x in subjects]
    names = sorted(set(subjects))
    if len(names) < 2:
        raise ValueError(f"a subject split needs at least two subjects, got {len(names)}")
    order = [names[i] for i in numpy_rng(seed, "subject_split", test_fraction).permutation(len(names))]
    target = _n_test(len(subjects), test_fraction)
    count = {n: subjects.count(n) for n in names}
    test: set[str] = set()
    for n in order[:-1]:
        if sum(count[t] for t in test) >= target:
            break
        test.add(n)
    return np.array([TEST if x in test else TRAIN for x in subjects], dtype=np.int8)


class NoGroupSplit(ValueError):
    """No choice of whole groups gives every action a test and a training clip; ``actions``:
    the label ids left without a test clip, ``single``: those whose clips all lie in one
    group (no choice can put them on both sides)."""

    def __init__(self, message: str, actions: list[int], single: list[int]):
        super().__init__(message)
        self.actions, self.single = actions, single


def group_split(labels, groups, *, test_fraction: float = DEFAULT_TEST_FRACTION,
                seed: int = DEFAULT_SPLIT_SEED) -> np.ndarray:
    """A seeded split that keeps each group (``groups``: (N,) names, a style or a subject per
    clip) whole and gives every action of ``labels`` (N,) test and training clips, with about
    ``round(N·f)`` clips in test.

    The groups, sorted by name, are put in a seeded order (``numpy_rng(seed, "group_split",
    f)``).  *Cover*: while an action has no test clip, the group (not yet in test) that gives
    test clips to the most such actions goes to test, the first in the seeded order on a tie,
    skipping any group whose move would leave an action without a training clip.  *Fill*: the
    remaining groups, in the seeded order, go to test while the test side holds fewer than
    ``round(N·f)`` clips, each only when it brings the count closer to that target and leaves
    every action a training clip.  :class:`NoGroupSplit` (a ValueError) when the cover cannot
    be completed: an action whose clips all lie in one group can never be on both sides.
    Clip order does not matter (a group's clips move together); the same inputs and seed give
    the same split, byte for byte."""
    _check_fraction(test_fraction)
    labels = np.asarray(labels, np.int64)
    groups = [str(x) for x in groups]
    if len(groups) != labels.shape[0]:
        raise ValueError("labels and groups differ in length")
    names = sorted(set(groups))
    index = {n: i for i, n in enumerate(names)}
    gidx = np.array([index[g] for g in groups], np.int64)
    actions = np.unique(labels).tolist()
    # counts[g, a]: clips of action a in group g
    counts = np.zeros((len(names), len(actions)), np.int64)
    np.add.at(counts, (gidx, np.searchsorted(actions, labels)), 1)
    total = counts.sum(0)
    order = numpy_rng(seed, "group_split", test_fraction).permutation(len(names)).tolist()
    in_test = np.zeros(len(names), bool)

    def keeps_train(g: int) -> bool:
        return bool((counts[in_test].sum(0) + counts[g] < total).all())

    while True:
        covered = counts[in_test].sum(0) > 0
        if covered.all():
            break
        best, gain = None, 0
        for g in order:
            if in_test[g] or not keeps_train(g):
                continue
            n = int(((counts[g] > 0) & ~covered).sum())
            if n > gain:
                best, gain = g, n
        if best is None:
            missing = [actions[a] for a in np.flatnonzero(~covered).tolist()]
            single = [actions[a] for a in range(len(actions)) if (counts[:, a] > 0).sum() < 2]
            raise NoGroupSplit("no choice of whole groups gives every action a test and a "
                               "training clip", missing, single)
        in_test[best] = True
    target = _n_test(labels.shape[0], test_fraction)
    for g in order:
        have = int(counts[in_test].sum())
        if have >= target:
            break
        if in_test[g] or not keeps_train(g):
            continue
        if abs(have + int(counts[g].sum()) - target) < abs(have - target):
            in_test[g] = True
    return np.where(in_test[gidx], TEST, TRAIN).astype(np.int8)


def marionette_split(labels, *, seed: int = DEFAULT_SPLIT_SEED, fraction: float = 0.2,
                     cap: int = 100) -> np.ndarray:
    """Neural Marionette's test split (Sec. 5.1.1): per class, ``min(cap, round(fraction·n))``
    randomly chosen clips are test, the rest train.  Seeded; classes are independent streams."""
    _check_fraction(fraction)
    if cap < 0:
        raise ValueError("cap must be >= 0")
    labels = np.asarray(labels, np.int64)
    split = np.full(labels.shape[0], TRAIN, dtype=np.int8)
    for lab in np.unique(labels).tolist():
        idx = np.flatnonzero(labels == lab)
        k = min(cap, _n_test(idx.size, fraction))
        if k:
            rng = numpy_rng(seed, "marionette_split", fraction, cap, lab)
            split[rng.permutation(idx)[:k]] = TEST
    return split


def with_split(clips: ClipSet, split) -> ClipSet:
    """A copy of ``clips`` sharing its arrays, with ``split`` as its train/test assignment.

    The fingerprint gains the split's content key, so caches keyed on it stay honest.
    """
    from repro.keys import content_key

    split = np.asarray(split, dtype=np.int8)
    if split.shape != (len(clips),):
        raise ValueError(f"split must have shape ({len(clips)},), got {split.shape}")
    if not np.isin(split, (TRAIN, TEST)).all():
        raise ValueError("split values must be 0 (train) or 1 (test)")
    if np.array_equal(split, clips.split):
        return clips
    fp = content_key({"base": clips.fingerprint, "split": split.tolist()})
    return dataclasses.replace(clips, split=split, fingerprint=fp)


def marionette_clipset(clips: ClipSet, *, seed: int = DEFAULT_SPLIT_SEED, fraction: float = 0.2,
                       cap: int = 100) -> ClipSet:
    """``clips`` with Neural Marionette's per-class test split (see :func:`marionette_split`)."""
    return with_split(clips, marionette_split(clips.labels, seed=seed, fraction=fraction, cap=cap))


def split_counts(labels, split, n_classes: int | None = None) -> dict[str, list[int]]:
    """Per-class train and test counts (for reports and tests)."""
    labels = np.asarray(labels, np.int64)
    split = np.asarray(split)
    n = int(n_classes if n_classes is not None else (labels.max() + 1 if labels.size else 0))
    return {"train": np.bincount(labels[split == TRAIN], minlength=n).tolist(),
            "test": np.bincount(labels[split == TEST], minlength=n).tolist()}
