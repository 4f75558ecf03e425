"""``repro.data.tag_chains.test_set_stats``: what a multi-action test set holds (issue 26;
supp. §4.2) — the share of its transitions never seen in training, their median training
support and the class share at each chain position — on hand-made chains whose answers are
known."""

from __future__ import annotations

import numpy as np
import pytest

from repro.data import tag_chains
from repro.data.tag_chains import chain_labels


def _stats(*a):
    """``tag_chains.test_set_stats`` (called through the module: a top-level name starting
    with ``test_`` would be collected by pytest as a test)."""
    return tag_chains.test_set_stats(*a)


def test_stats_of_hand_made_chains():
    C = 3
    counts = np.array([[5, 2, 0],
                       [0, 1, 7],
                       [3, 0, 0]])
    tags = np.array([[0, 1, 2],     # supports 2, 7
                     [0, 0, 2],     # 5, 0 (unseen)
                     [2, 0, 1]])    # 3, 2
    r = _stats(tags, counts, C)
    assert (r["chains"], r["length"]) == (3, 3)
    assert r["unseen_share"] == pytest.approx(1 / 6, abs=1e-4)
    assert r["median_support"] == 2.5                       # median of 0, 2, 2, 3, 5, 7
    share = np.asarray(r["class_share_by_position"])
    assert share.shape == (3, C)
    assert np.allclose(share[0], [2 / 3, 0, 1 / 3], atol=1e-4)
    assert np.allclose(share[1], [2 / 3, 1 / 3, 0], atol=1e-4)
    assert np.allclose(share[2], [0, 1 / 3, 2 / 3], atol=1e-4)
    assert np.allclose(share.sum(1), 1.0, atol=1e-3)
    # a plain JSON object, the same every time
    assert all(isinstance(v, float) for row in r["class_share_by_position"] for v in row)
    assert _stats(tags, counts, C) == r


def test_a_class_that_never_occurs_has_share_zero_and_positions_count_alone():
    counts = np.ones((4, 4), np.int64)
    tags = np.array([[1, 1], [1, 2]])
    r = _stats(tags, counts, 4)
    assert r["unseen_share"] == 0.0 and r["median_support"] == 1.0
    assert r["class_share_by_position"] == [[0.0, 1.0, 0.0, 0.0], [0.0, 0.5, 0.5, 0.0]]


def test_chain_labels_and_bad_input():
    labels = np.array([2, 0, 1, 1])
    acts = np.array([[0, 3], [1, 2]])
    assert chain_labels(labels, acts).tolist() == [[2, 1], [0, 1]]
    with pytest.raises(ValueError, match="non-empty"):
        _stats(np.zeros((0, 3), np.int64), np.ones((2, 2)), 2)
    with pytest.raises(ValueError, match="non-empty"):
        _stats(np.zeros(3, np.int64), np.ones((2, 2)), 2)
