"""Diversity and Multimodality: known answers, seeding, the quota loop's distribution."""

import numpy as np
import pytest

from repro.errors import DataError
from repro.metrics.diversity import diversity, multimodality


def test_identical_features_give_zero():
    f = np.tile([[0.3, -1.0, 2.0]], (50, 1))
    assert diversity(f, seed=3) == 0.0
    assert multimodality(f, np.arange(50) % 5, 5, seed=3) == 0.0


def test_one_sample_per_class_is_not_measured():
    # own data with one test clip per class: no within-class pair exists, so the value is NaN
    # (a table's "not measured"), never a 0 that a claim would be decided on
    f = np.random.default_rng(1).normal(size=(4, 6))
    assert np.isnan(multimodality(f, [0, 1, 2, 3], 4, seed=0))
    # one singleton class among pairs is enough (its 0 would pull the mean down); an absent
    # class (MultiAct's early break) is not a singleton
    assert np.isnan(multimodality(f, [0, 0, 1, 2], 3, seed=0))
    got = multimodality(f, [0, 0, 2, 2], 3, per_class=20_000, seed=0, early_break=True)
    want = (np.linalg.norm(f[0] - f[1]) + np.linalg.norm(f[2] - f[3])) / 2 / 3
    assert got == pytest.approx(want, rel=0.03)


def test_seeded_and_deterministic():
    f = np.random.default_rng(0).normal(size=(100, 30))
    assert diversity(f, seed=1) == diversity(f, seed=1)
    assert diversity(f, seed=1) != diversity(f, seed=2)
    y = np.arange(100) % 4
    assert multimodality(f, y, 4, seed=5) == multimodality(f, y, 4, seed=5)
    assert diversity(f, seed=np.random.default_rng(9)) == diversity(f, seed=np.random.default_rng(9))


def test_diversity_expected_value_with_replacement():
    # N one-hot vectors: distinct pairs are sqrt(2) apart; index repeats (prob 1/N) give 0
    n = 10
    f = np.eye(n)
    got = diversity(f, n_pairs=200_000, seed=0)
    assert got == pytest.approx(np.sqrt(2) * (1 - 1 / n), rel=0.01)


def test_multimodality_expected_value_and_full_class_divisor():
    # classes 0 and 1: two points 2 apart each (pair distance 0 or 2, mean 1); class 2 absent
    f = np.array([[0.0], [2.0], [10.0], [12.0]])
    y = np.array([0, 0, 1, 1])
    with pytest.raises(DataError, match="no samples"):
        multimodality(f, y, 3)
    got = multimodality(f, y, 3, per_class=20_000, seed=0, early_break=True)
    assert got == pytest.approx((20_000 * 1 + 20_000 * 1) / (20_000 * 3), rel=0.02)
    got2 = multimodality(f, y, 2, per_class=20_000, seed=0)
    assert got2 == pytest.approx(1.0, rel=0.02)


def _reference_quota_loop(f, y, n_classes, per_class, rng):
    """The Action2Motion quota loop, literally (protocols.md §1.4)."""
    quota = np.full(n_classes, per_class)
    total = 0.0
    n = len(y)
    while quota.sum() > 0:
        i = rng.integers(n)
        if quota[y[i]] == 0:
            continue
        j = rng.integers(n)
        while y[j] != y[i]:
            j = rng.integers(n)
        total += np.linalg.norm(f[i] - f[j])
        quota[y[i]] -= 1
    return total / (per_class * n_classes)


def test_same_distribution_as_the_literal_quota_loop():
    rng = np.random.default_rng(11)
    f = rng.normal(size=(30, 3)) * np.repeat([[1.0], [3.0], [0.5]], 10, axis=0)
    y = np.repeat([0, 1, 2], 10)
    ours = [multimodality(f, y, 3, seed=s) for s in range(300)]
    ref_rng = np.random.default_rng(12)
    ref = [_reference_quota_loop(f, y, 3, 20, ref_rng) for _ in range(300)]
    # equal means within Monte-Carlo error (each run's sd ~ 0.15; 300 runs -> se ~ 0.009)
    assert np.mean(ours) == pytest.approx(np.mean(ref), abs=4 * np.std(ref) / np.sqrt(150))
    assert np.std(ours) == pytest.approx(np.std(ref), rel=0.25)


def test_bad_input():
    with pytest.raises(DataError):
        diversity(np.zeros((0, 3)))
    with pytest.raises(DataError, match="0..2"):
        multimodality(np.zeros((3, 2)), [0, 1, 5], 3)
