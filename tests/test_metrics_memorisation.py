"""Memorisation columns: nearest distances (copier ~0, brute-force agreement), masked joint-space
RMS (loop reference, truncated copies, metres), PRDC (known answers, ties, brute force)."""

import numpy as np
import pytest
import torch

from repro.errors import DataError
from repro.metrics import memorisation
from repro.metrics.memorisation import masked_nearest_rms, nearest_distances, prdc

# ---------------------------------------------------------------- nearest_distances


def test_copier_has_near_zero_nearest_distance():
    rng = np.random.default_rng(0)
    bank = rng.normal(size=(300, 32))
    picks = rng.choice(300, size=60, replace=False)
    queries = bank[picks] + 1e-9 * rng.normal(size=(60, 32))
    d = nearest_distances(queries, bank)
    assert d.shape == (60,) and d.dtype == np.float64
    assert np.all(d < 1e-6)
    assert nearest_distances(bank[picks], bank).max() == 0.0  # exact copies read exactly 0


def test_nearest_distances_match_brute_force():
    rng = np.random.default_rng(1)
    bank = rng.normal(size=(120, 7))
    queries = rng.normal(size=(45, 7)) * 1.5
    expected = np.sqrt(((queries[:, None, :] - bank[None, :, :]) ** 2).sum(axis=2)).min(axis=1)
    np.testing.assert_allclose(nearest_distances(queries, bank), expected, rtol=1e-12, atol=0)
    # torch tensors are accepted
    got = nearest_distances(torch.from_numpy(queries), torch.from_numpy(bank))
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=0)


@pytest.mark.parametrize("queries, bank, message", [
    (np.zeros((3, 4)), np.zeros((5, 3)), "feature dimensions differ"),
    (np.zeros(4), np.zeros((5, 4)), "2-D"),
    (np.zeros((0, 4)), np.zeros((5, 4)), "at least 1 rows"),
    (np.zeros((3, 4)), np.zeros((0, 4)), "at least 1 rows"),
    (np.array([[0.0, np.nan]]), np.zeros((5, 2)), "NaN"),
    (np.zeros((3, 2)), np.array([[np.inf, 0.0]]), "NaN or infinite"),
])
def test_nearest_distances_rejects_bad_input(queries, bank, message):
    with pytest.raises(DataError, match=message):
        nearest_distances(queries, bank)


# ---------------------------------------------------------------- masked_nearest_rms


def _masked_reference(queries, lengths, bank):
    n, _, j, _ = queries.shape
    dist = np.empty(n)
    idx = np.empty(n, dtype=np.int64)
    for a in range(n):
        best, best_m = np.inf, -1
        for m in range(bank.shape[0]):
            total = 0.0
            for t in range(lengths[a]):
                total += np.sum((queries[a, t] - bank[m, t]) ** 2)
            d = np.sqrt(total / (lengths[a] * j))
            if d < best:
                best, best_m = d, m
        dist[a], idx[a] = best, best_m
    return dist, idx


def test_masked_rms_matches_double_loop_reference():
    rng = np.random.default_rng(2)
    n, m, w, j = 23, 17, 9, 5
    queries = rng.normal(size=(n, w, j, 3))
    bank = rng.normal(size=(m, w, j, 3))
    lengths = rng.integers(1, w + 1, size=n)
    lengths[:2] = [1, w]
    dist, idx = masked_nearest_rms(queries, lengths, bank)
    ref_dist, ref_idx = _masked_reference(queries, lengths, bank)
    assert dist.dtype == np.float64 and idx.dtype == np.int64
    np.testing.assert_array_equal(idx, ref_idx)
    np.testing.assert_allclose(dist, ref_dist, rtol=1e-12, atol=0)


def test_masked_rms_chunking_does_not_change_the_answer(monkeypatch):
    rng = np.random.default_rng(3)
    queries = rng.normal(size=(40, 6, 4, 3))
    bank = rng.normal(size=(11, 6, 4, 3))
    lengths = rng.integers(1, 7, size=40)
    whole = masked_nearest_rms(queries, lengths, bank)
    monkeypatch.setattr(memorisation, "QUERY_CHUNK", 7)
    chunked = masked_nearest_rms(queries, lengths, bank)
    np.testing.assert_array_equal(whole[1], chunked[1])
    np.testing.assert_allclose(whole[0], chunked[0], rtol=1e-14, atol=0)
    np.testing.assert_array_equal(chunked[1], _masked_reference(queries, lengths, bank)[1])


def test_truncated_bank_window_with_garbage_tail_is_found_at_zero():
    rng = np.random.default_rng(4)
    w, j = 12, 6
    bank = rng.normal(size=(30, w, j, 3))
    targets = np.array([3, 17, 29, 0])
    lengths = np.array([5, 1, 12, 8])
    queries = bank[targets].copy()
    for a, length in enumerate(lengths):
        queries[a, length:] = 50.0 * rng.normal(size=(w - length, j, 3))  # garbage past L
    queries[3, 8:] = np.nan  # even NaN past L is ignored
    dist, idx = masked_nearest_rms(queries, lengths, bank)
    np.testing.assert_array_equal(idx, targets)
    assert np.all(dist < 1e-12)


def test_masked_rms_is_in_metres_per_joint():
    rng = np.random.default_rng(5)
    w, j = 10, 22
    bank = rng.normal(size=(15, w, j, 3))  # windows ~1 m apart per joint: 0.1 m stays nearest
    offset = np.array([0.06, 0.08, 0.0])  # a 0.1 m displacement of every joint in every frame
    queries = bank[[7, 2]] + offset
    lengths = np.array([w, 4])
    queries[1, 4:] = 9.0
    dist, idx = masked_nearest_rms(queries, lengths, bank)
    np.testing.assert_array_equal(idx, [7, 2])
    np.testing.assert_allclose(dist, [0.1, 0.1], rtol=1e-12)


@pytest.mark.parametrize("lengths, message", [
    ([0, 3], r"1\.\.4"),
    ([5, 3], r"1\.\.4"),
    ([2, 2.5], "whole numbers"),
    ([2, 2, 2], r"shape \(2,\)"),
])
def test_masked_rms_rejects_bad_lengths(lengths, message):
    q = np.zeros((2, 4, 3, 3))
    with pytest.raises(DataError, match=message):
        masked_nearest_rms(q, np.array(lengths), np.zeros((5, 4, 3, 3)))


def test_masked_rms_rejects_bad_arrays():
    q = np.zeros((2, 4, 3, 3))
    with pytest.raises(DataError, match="must agree"):
        masked_nearest_rms(q, [4, 4], np.zeros((5, 6, 3, 3)))
    with pytest.raises(DataError, match="4-D"):
        masked_nearest_rms(q.reshape(2, 4, 9), [4, 4], np.zeros((5, 4, 9)))
    q[1, 1, 0, 0] = np.nan
    with pytest.raises(DataError, match="valid frames"):
        masked_nearest_rms(q, [4, 4], np.zeros((5, 4, 3, 3)))
    assert masked_nearest_rms(q, [4, 1], np.zeros((5, 4, 3, 3)))[0][1] == 0.0  # NaN past L: fine
    with pytest.raises(DataError, match="NaN"):
        masked_nearest_rms(np.zeros((2, 4, 3, 3)), [4, 4], np.full((5, 4, 3, 3), np.inf))


# ---------------------------------------------------------------- prdc


def _prdc_reference(real, fake, k):
    def pdist(a, b):
        return np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(axis=2))

    r_real = np.sort(pdist(real, real), axis=1)[:, k]  # column 0 is the point itself
    r_fake = np.sort(pdist(fake, fake), axis=1)[:, k]
    d = pdist(real, fake)  # (N, M)
    inside_real = d <= r_real[:, None]
    return {
        "precision": inside_real.any(axis=0).mean(),
        "recall": (d <= r_fake[None, :]).any(axis=1).mean(),
        "density": inside_real.sum() / (k * fake.shape[0]),
        "coverage": (d.min(axis=1) <= r_real).mean(),
    }


def test_prdc_matches_brute_force(monkeypatch):
    rng = np.random.default_rng(6)
    real = rng.normal(size=(40, 6))
    fake = rng.normal(size=(35, 6)) * 1.3 + 0.4
    expected = _prdc_reference(real, fake, 3)
    got = prdc(real, fake, k=3)
    assert set(got) == {"precision", "recall", "density", "coverage"}
    assert all(type(v) is float for v in got.values())
    for key in expected:
        assert got[key] == pytest.approx(expected[key], abs=1e-12), key
    assert 0 < got["precision"] < 1 and 0 < got["recall"] < 1 and 0 < got["coverage"] < 1
    monkeypatch.setattr(memorisation, "_PAIR_BUDGET", 50)  # a couple of rows per chunk
    assert prdc(real, fake, k=3) == got


def test_prdc_copy_of_real_data():
    rng = np.random.default_rng(7)
    real = rng.normal(size=(200, 10))
    for k in (1, 5):
        got = prdc(real, real.copy(), k=k)
        assert got["precision"] == got["recall"] == got["coverage"] == 1.0
        # each real ball holds its own copy plus the copies of its k neighbours (closed balls)
        assert got["density"] == pytest.approx((k + 1) / k, abs=1e-12)


def test_prdc_mode_dropping_generator():
    rng = np.random.default_rng(8)
    centres = 20.0 * np.eye(8)[:4]  # four blobs, ~28 apart, unit spread
    labels = np.repeat(np.arange(4), 150)
    real = centres[labels] + rng.normal(size=(600, 8))
    fake = centres[0] + rng.normal(size=(300, 8))  # every sample from blob 0
    got = prdc(real, fake, k=5)
    assert got["precision"] > 0.9
    assert got["recall"] < 0.4 and got["coverage"] < 0.4
    # control: a generator that covers all four blobs is not flagged
    fair = centres[np.repeat(np.arange(4), 75)] + rng.normal(size=(300, 8))
    ok = prdc(real, fair, k=5)
    assert ok["recall"] > 0.8 and ok["coverage"] > 0.8


def test_prdc_far_away_generator_scores_zero():
    rng = np.random.default_rng(9)
    real = rng.normal(size=(100, 5))
    fake = rng.normal(size=(80, 5)) + 100.0
    got = prdc(real, fake, k=5)
    assert got["precision"] == 0.0 and got["coverage"] == 0.0 and got["density"] == 0.0
    assert got["recall"] == 0.0


def test_prdc_ball_boundary_counts_as_inside():
    # 1-D, k = 1.  Real 0, 1, 10, 11 all have radius 1; fakes 2, 20, 21 have radii 18, 1, 1.
    # Fake 2 lies only on the boundary of real 1's ball (distance 1 = radius), and real 1's
    # nearest fake is on that boundary: with strict "<" precision, density, coverage would be 0.
    real = np.array([[0.0], [1.0], [10.0], [11.0]])
    fake = np.array([[2.0], [20.0], [21.0]])
    got = prdc(real, fake, k=1)
    assert got == {"precision": 1 / 3, "recall": 1.0, "density": 1 / 3, "coverage": 1 / 4}
    # roles swapped: now real 2 sits on the boundary of fake 1's ball, so recall needs "<=" too
    swapped = prdc(fake, real, k=1)
    assert swapped == {"precision": 1.0, "recall": 1 / 3, "density": 1.0, "coverage": 1 / 3}


def test_prdc_rejects_bad_input():
    rng = np.random.default_rng(10)
    real, fake = rng.normal(size=(6, 3)), rng.normal(size=(5, 3))
    with pytest.raises(DataError, match=r"more than k = 5 samples, got 6 real and 5 fake"):
        prdc(real, fake, k=5)
    with pytest.raises(DataError, match=r"more than k = 6 samples, got 6 real and 5 fake"):
        prdc(real, fake, k=6)
    assert prdc(real, fake, k=4)["precision"] >= 0.0
    with pytest.raises(DataError, match="feature dimensions differ"):
        prdc(real, rng.normal(size=(5, 4)), k=2)
    with pytest.raises(DataError, match="positive integer"):
        prdc(real, fake, k=0)
    with pytest.raises(DataError, match="positive integer"):
        prdc(real, fake, k=2.0)
    bad = fake.copy()
    bad[0, 0] = np.nan
    with pytest.raises(DataError, match="fake: contains NaN"):
        prdc(real, bad, k=2)
