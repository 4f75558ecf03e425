"""Deterministic splits: stratified 80/20 by (action, style) and Neural Marionette's test split."""

from __future__ import annotations

import numpy as np
import pytest

from repro.data.clipset import TEST, TRAIN, ClipSet
from repro.data.splits import (marionette_clipset, marionette_split, split_counts,
                               stratified_split, with_split)
from repro.motion.skeleton import Skeleton


def _labels(seed=0):
    rng = np.random.default_rng(seed)
    labels = np.repeat(np.arange(5), [40, 13, 7, 1, 250])
    styles = rng.integers(0, 3, size=labels.size)
    return labels, styles


def test_stratified_split_counts_per_cell():
    labels, styles = _labels()
    split = stratified_split(labels, styles, test_fraction=0.2, seed=7)
    assert split.dtype == np.int8 and set(np.unique(split)) <= {TRAIN, TEST}
    for lab in np.unique(labels):
        for sty in np.unique(styles):
            m = (labels == lab) & (styles == sty)
            n = int(m.sum())
            assert int((split[m] == TEST).sum()) == int(np.floor(0.2 * n + 0.5)), (lab, sty, n)
    # every cell with >= 3 clips keeps train and test members
    assert abs((split == TEST).mean() - 0.2) < 0.03


def test_stratified_split_is_deterministic_and_seeded():
    labels, styles = _labels()
    a = stratified_split(labels, styles, seed=1)
    b = stratified_split(labels.copy(), styles.copy(), seed=1)
    c = stratified_split(labels, styles, seed=2)
    assert a.tobytes() == b.tobytes()
    assert not np.array_equal(a, c)
    assert (a == TEST).sum() == (c == TEST).sum()  # same counts, other members


def test_stratified_split_other_fractions_and_no_styles():
    labels, _ = _labels()
    s = stratified_split(labels, None, test_fraction=0.5, seed=0)
    assert split_counts(labels, s)["test"] == [20, 7, 4, 1, 125]
    assert (stratified_split(labels, None, test_fraction=0.0) == TRAIN).all()
    with pytest.raises(ValueError):
        stratified_split(labels, None, test_fraction=1.0)


def test_marionette_split_twenty_percent_capped_at_100():
    labels = np.repeat(np.arange(4), [1000, 300, 50, 2])
    s = marionette_split(labels, seed=3)
    assert split_counts(labels, s, 4)["test"] == [100, 60, 10, 0]
    assert marionette_split(labels, seed=3).tobytes() == s.tobytes()
    assert not np.array_equal(marionette_split(labels, seed=4), s)
    assert split_counts(labels, marionette_split(labels, cap=5), 4)["test"] == [5, 5, 5, 0]


def _clipset(labels, styles):
    n = len(labels)
    skel = Skeleton(("root", "child"), (-1, 0), np.array([[0, 0, 0], [0, 1, 0]]))
    lengths = np.full(n, 2, np.int64)
    F = int(lengths.sum())
    quat = np.zeros((F, 2, 4), np.float32)
    quat[..., 3] = 1
    return ClipSet(name="toy", skeleton=skel, fps=30.0, rotations=quat,
                   root=np.zeros((F, 3), np.float32), joints=np.zeros((F, 2, 3), np.float32),
                   starts=np.arange(n) * 2, lengths=lengths, labels=np.asarray(labels),
                   label_names=tuple(f"c{i}" for i in range(int(max(labels)) + 1)),
                   styles=np.asarray(styles), style_names=("s0", "s1", "s2"),
                   clip_names=tuple(f"clip{i}" for i in range(n)),
                   split=np.zeros(n, np.int8), fingerprint="base")


def test_marionette_clipset_and_with_split():
    labels, styles = _labels()
    cs = _clipset(labels, styles)
    m = marionette_clipset(cs, seed=0)
    assert m.rotations is cs.rotations  # arrays shared, not copied
    assert m.fingerprint != cs.fingerprint
    assert split_counts(m.labels, m.split, 5)["test"] == [8, 3, 1, 0, 50]
    assert marionette_clipset(cs, seed=0).fingerprint == m.fingerprint
    assert with_split(cs, cs.split) is cs
    with pytest.raises(ValueError):
        with_split(cs, np.zeros(3, np.int8))
    with pytest.raises(ValueError):
        with_split(cs, np.full(len(cs), 2, np.int8))
    assert len(m.indices(split=TEST)) == 62
