"""Mode discovery (both K rules + the discovery variant) and ODMO mode-homogeneity."""

import numpy as np
import pytest

import repro.metrics.modes as modes
from repro.errors import DataError
from repro.metrics.modes import discover_modes, mode_homogeneity, select_k


def _planted(rng, k, n, d=3, sep=8.0):
    centers = rng.normal(scale=sep, size=(k, d))
    lab = np.repeat(np.arange(k), n)
    return centers[lab] + rng.normal(size=(k * n, d)), lab


def _fake_scores(monkeypatch, scores: dict[int, float]):
    """Replace the GMM by a stub whose silhouette for K = k is scores[k]."""
    monkeypatch.setattr(modes, "_fit_gmm", lambda codes, k, seed, n_init: (None, np.full(len(codes), k)))
    monkeypatch.setattr(modes, "_silhouette", lambda codes, labels: scores[int(labels[0])])


def test_rules_on_a_slowly_declining_silhouette(monkeypatch):
    # drops of ~2% per step: the code rule never stops, the paper rule stops at once
    _fake_scores(monkeypatch, {k: 0.50 - 0.01 * (k - 3) for k in range(3, 12)})
    codes = np.random.default_rng(0).normal(size=(40, 2))
    assert select_k(codes, "code").k == 9
    assert select_k(codes, "discovery").k == 8
    assert select_k(codes, "paper").k == 3
    assert [k for k, _ in select_k(codes, "paper").scores] == list(range(3, 12))


def test_rules_on_a_peak(monkeypatch):
    _fake_scores(monkeypatch, {3: 0.50, 4: 0.60, 5: 0.70, 6: 0.50, 7: 0.8, 8: 0.1, 9: 0.1,
                               10: 0.1, 11: 0.1})
    codes = np.random.default_rng(0).normal(size=(40, 2))
    assert select_k(codes, "code").k == 5  # stops at 6 (0.50 < 0.95 * 0.70)
    assert select_k(codes, "discovery").k == 5
    assert select_k(codes, "paper").k == 5  # first i with S_i > 0.95 S_{i+1}
    _fake_scores(monkeypatch, {k: 0.1 * k for k in range(3, 12)})  # always rising
    assert select_k(codes, "paper").k == 11


CORNERS = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]])


def test_planted_clusters_are_found():
    rng = np.random.default_rng(0)
    codes = np.repeat(CORNERS, 50, axis=0) + rng.normal(size=(200, 3))
    # silhouettes of this draw: K=3 0.63, K=4 0.77, K=5 0.65
    assert select_k(codes, "code").k == 4
    assert select_k(codes, "paper").k == 4
    assert select_k(codes, "code", seed=0) == select_k(codes, "code", seed=0)


def test_small_components_dropped_and_reassigned():
    rng = np.random.default_rng(0)
    codes = np.repeat(CORNERS[:3], 60, axis=0) + rng.normal(size=(180, 3))
    tiny = np.array([20.0, 20.0, 20.0]) + rng.normal(size=(6, 3))  # a 6-code far-away cluster
    cc = np.concatenate([codes, tiny])
    m = discover_modes(cc, "code")
    assert m.selection.k == 4 and len(m.kept) == 3  # the 6-code component (<= 10) is dropped
    assert set(np.unique(m.assignment)) == set(m.kept)
    assert len(discover_modes(cc, "paper").kept) == 3  # < 10 dropped too
    ex = discover_modes(cc, "code", small_modes="exclude")
    assert (ex.assignment == -1).sum() == 6
    assert len(discover_modes(cc, "discovery").kept) == 4  # mode discovery drops nothing


def test_homogeneity_positive_on_planted_modes_and_zero_on_one_gaussian():
    rng = np.random.default_rng(0)
    codes, motions, labels = [], [], []
    for cls in range(2):
        c, lab = _planted(rng, 4, 40)
        centers = rng.normal(scale=3, size=(4, 20, 5, 3))
        motions.append(centers[lab] + 0.3 * rng.normal(size=(len(lab), 20, 5, 3)))
        codes.append(c)
        labels.append(np.full(len(lab), cls))
    r = mode_homogeneity(np.concatenate(motions), np.concatenate(codes), np.concatenate(labels))
    assert r.value > 50.0 and len(r.per_class) == 2

    # codes from one Gaussian, motions unrelated to the codes: modes split nothing real
    c = rng.normal(size=(240, 3))
    m = rng.normal(size=(240, 20, 5, 3))
    y = np.repeat([0, 1], 120)
    for rule in ("code", "paper"):
        r0 = mode_homogeneity(m, c, y, rule=rule)
        assert abs(r0.value) < 3.0


def test_errors():
    rng = np.random.default_rng(1)
    with pytest.raises(DataError, match="too few"):
        select_k(rng.normal(size=(3, 2)))
    with pytest.raises(DataError, match="unknown rule"):
        select_k(rng.normal(size=(30, 2)), rule="elbow")
    with pytest.raises(DataError, match="motions but"):
        mode_homogeneity(rng.normal(size=(10, 4)), rng.normal(size=(9, 2)), np.zeros(10, int))


# -- the small-component threshold scales with the codes per class (issue 27) ---------------

def _seven_modes(rng, n=60, d=20, sep=6.0):
    centres = rng.normal(scale=sep, size=(7, d))
    lab = rng.integers(0, 7, n)
    return centres[lab] + rng.normal(size=(n, d)), lab


def test_a_planted_seven_mode_latent_keeps_its_modes_at_60_codes_per_class():
    for seed in range(2):
        codes, lab = _seven_modes(np.random.default_rng(seed))
        scaled = discover_modes(codes, "code", reference_codes=2560)
        assert len(scaled.kept) >= 5, seed
        # the assignment recovers the planted modes
        from sklearn.metrics import adjusted_rand_score
        assert adjusted_rand_score(lab, scaled.assignment) > 0.9
        # the published "<= 10" at 60 codes merges them (what the scaling is for)
        assert len(discover_modes(codes, "code").kept) <= 2


def test_threshold_scale_is_the_published_one_at_the_reference_count():
    from repro.metrics.modes import RULES, small_scale

    counts = np.array([0, 9, 10, 11, 30])
    assert RULES["code"].dropped(counts, small_scale(2560, 2560)).tolist() == [1, 1, 1, 0, 0]
    assert RULES["paper"].dropped(counts, small_scale(410, 410)).tolist() == [1, 1, 0, 0, 0]
    # 60 codes against 2,560: 10 × 60 / 2560 = 0.23, only empty components go
    assert RULES["code"].dropped(counts, small_scale(60, 2560)).tolist() == [1, 0, 0, 0, 0]
    assert RULES["paper"].dropped(counts, small_scale(60, 2560)).tolist() == [1, 0, 0, 0, 0]
    # 1,280 codes: code rule drops <= 5, paper rule < 5
    assert RULES["code"].dropped(np.array([4, 5, 6]), small_scale(1280, 2560)).tolist() == [1, 1, 0]
    assert RULES["paper"].dropped(np.array([4, 5, 6]), small_scale(1280, 2560)).tolist() == [1, 0, 0]
    assert RULES["discovery"].dropped(counts, 0.5).tolist() == [1, 0, 0, 0, 0]
    with pytest.raises(DataError, match="reference_codes"):
        small_scale(60, 0)


def test_k_under_each_rule_on_eight_planted_clusters():
    # 8 overlapping planted clusters in D = 20 whose silhouette rises slowly from K = 3 to 4
    # (this draw: 0.217, 0.222, 0.299, 0.345, 0.352, 0.313, ...): the paper's rule stops at
    # the first rise under ~5 % (K = 3), the code's keeps going until the first drop (K = 7)
    rng = np.random.default_rng(1)
    centres = rng.normal(scale=2.0, size=(8, 20))
    codes = centres[np.repeat(np.arange(8), 40)] + rng.normal(size=(320, 20))
    assert select_k(codes, "paper").k == 3
    assert select_k(codes, "code").k == 7
    # well separated, both rules find the 8
    rng = np.random.default_rng(0)
    centres = rng.normal(scale=6.0, size=(8, 20))
    codes = centres[np.repeat(np.arange(8), 40)] + rng.normal(size=(320, 20))
    assert select_k(codes, "paper").k == 8 and select_k(codes, "code").k == 8


def test_threshold_scales_by_the_codes_drawn_not_the_distinct_ones():
    # the reference's 2,560 codes per class are draws (duplicates included), so n is the draw:
    # 3 big planted modes of 40 distinct codes and one of 4, every code drawn 10 times.  At
    # n = reference the threshold is the published 10 and the 4-code mode goes; scaled by the
    # 124 distinct codes instead (threshold 1) it would stay.
    rng = np.random.default_rng(3)
    centres = np.eye(4, 6) * 40.0
    sizes = (40, 40, 40, 4)
    distinct = np.concatenate([c + rng.normal(size=(m, 6)) for c, m in zip(centres, sizes)])
    lab = np.repeat(np.arange(4), sizes)
    codes, lab = np.repeat(distinct, 10, axis=0), np.repeat(lab, 10)
    modes = discover_modes(codes, "code", reference_codes=codes.shape[0])
    small = modes.assignment[lab == 3]
    assert np.isin(small, modes.assignment[lab != 3]).all()   # dropped: joined a big mode
    assert modes.counts[list(modes.kept)].min() > 10
    # scaled by the 124 distinct codes instead (the old reading) nothing would be dropped
    from repro.metrics.modes import RULES, small_scale
    assert not RULES["code"].dropped(modes.counts, small_scale(124, codes.shape[0])).any()
