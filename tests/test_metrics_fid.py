"""FID: known answers (self = 0, closed form for Gaussians), eigh vs scipy sqrtm, bookkeeping."""

import numpy as np
import pytest
import torch
from scipy.linalg import sqrtm

from repro.errors import DataError
from repro.metrics.fid import FeatureStats, FIDResult, feature_stats, fid, fid_train_test, frechet_distance


def _rand_cov(rng, d, cond=10.0):
    q, _ = np.linalg.qr(rng.normal(size=(d, d)))
    w = np.geomspace(1.0, cond, d)
    return (q * w) @ q.T


def test_feature_stats_is_mean_and_unbiased_cov():
    rng = np.random.default_rng(0)
    f = rng.normal(size=(50, 4))
    mu, sigma = feature_stats(f)
    np.testing.assert_allclose(mu, f.mean(0))
    np.testing.assert_allclose(sigma, (f - f.mean(0)).T @ (f - f.mean(0)) / 49)


def test_fid_of_a_set_with_itself_is_zero():
    f = np.random.default_rng(1).normal(size=(300, 30))
    for method in ("eigh", "scipy"):
        assert abs(fid(f, f, method=method).value) < 1e-8


def test_closed_form_diagonal_gaussians():
    # commuting covariances: FID = |mu1-mu2|^2 + sum (sqrt(a) - sqrt(b))^2
    mu1, mu2 = np.array([0.0, 1.0, -2.0]), np.array([1.0, 1.0, 0.0])
    a, b = np.array([1.0, 4.0, 9.0]), np.array([4.0, 1.0, 9.0])
    expected = 1.0 + 4.0 + (1 - 2) ** 2 + (2 - 1) ** 2 + 0.0
    for method in ("eigh", "scipy"):
        assert frechet_distance(mu1, np.diag(a), mu2, np.diag(b), method=method) == pytest.approx(expected, abs=1e-12)


def test_closed_form_one_dimension():
    # 1-D: (mu1 - mu2)^2 + (s1 - s2)^2
    assert frechet_distance([2.0], [[9.0]], [-1.0], [[1.0]]) == pytest.approx(9.0 + 4.0)


def test_samples_from_two_gaussians_approach_the_closed_form():
    rng = np.random.default_rng(2)
    mu_a, mu_b = np.zeros(3), np.array([1.0, 0.0, 0.5])
    a = rng.normal(size=(40000, 3))  # N(0, I)
    b = mu_b + 2.0 * rng.normal(size=(40000, 3))  # N(mu_b, 4 I)
    expected = 1.25 + 3 * (1.0 - 2.0) ** 2
    assert fid(a, b).value == pytest.approx(expected, abs=0.05)


def test_eigh_matches_scipy_sqrtm_when_well_conditioned():
    rng = np.random.default_rng(3)
    for d in (2, 5, 30):
        s1, s2 = _rand_cov(rng, d), _rand_cov(rng, d, cond=50.0)
        mu1, mu2 = rng.normal(size=d), rng.normal(size=d)
        v_eigh = frechet_distance(mu1, s1, mu2, s2, method="eigh")
        v_scipy = frechet_distance(mu1, s1, mu2, s2, method="scipy")
        # and the raw trace against scipy's sqrtm
        tr = np.trace(np.real(sqrtm(s1 @ s2)))
        direct = (mu1 - mu2) @ (mu1 - mu2) + np.trace(s1) + np.trace(s2) - 2 * tr
        assert v_eigh == pytest.approx(v_scipy, rel=1e-9, abs=1e-9)
        assert v_eigh == pytest.approx(direct, rel=1e-9, abs=1e-9)


def test_eigh_is_finite_for_singular_covariances():
    rng = np.random.default_rng(4)
    a = rng.normal(size=(10, 30))  # N < D: rank-deficient covariance
    b = rng.normal(size=(12, 30)) + 0.5
    v = fid(a, b).value
    assert np.isfinite(v) and v > 0


def test_result_carries_counts_and_dimension_and_accepts_tensors():
    rng = np.random.default_rng(5)
    a, b = rng.normal(size=(40, 6)), rng.normal(size=(25, 6))
    r = fid(torch.from_numpy(a), b)
    assert isinstance(r, FIDResult) and (r.n_a, r.n_b, r.dim) == (40, 25, 6)
    assert float(r) == r.value
    with pytest.raises(Exception):
        r.value = 0.0  # frozen


def test_feature_stats_reference_reuse_and_train_test():
    rng = np.random.default_rng(6)
    gen, tr, te = rng.normal(size=(50, 5)), rng.normal(size=(60, 5)) + 0.3, rng.normal(size=(70, 5)) - 0.3
    ref = FeatureStats.of(tr)
    assert fid(gen, ref).value == pytest.approx(fid(gen, tr).value, rel=1e-12)
    both = fid_train_test(gen, ref, te)
    assert both["fid_train"].n_b == 60 and both["fid_test"].n_b == 70
    assert both["fid_test"].value == pytest.approx(fid(gen, te).value)


def test_bad_input_is_a_data_error():
    rng = np.random.default_rng(7)
    with pytest.raises(DataError, match="dimensions differ"):
        fid(rng.normal(size=(10, 3)), rng.normal(size=(10, 4)))
    with pytest.raises(DataError, match="at least 2 rows"):
        fid(rng.normal(size=(1, 3)), rng.normal(size=(10, 3)))
    bad = rng.normal(size=(10, 3))
    bad[0, 0] = np.nan
    with pytest.raises(DataError, match="NaN"):
        fid(bad, rng.normal(size=(10, 3)))
    with pytest.raises(DataError, match="unknown method"):
        fid(rng.normal(size=(10, 3)), rng.normal(size=(10, 3)), method="svd")


def test_scipy_route_checks_only_the_diagonal_imaginary_part(monkeypatch):
    """Regression (issue 11): the references accept a square root whose off-diagonal entries
    carry imaginary round-off (they test ``np.diagonal(covmean).imag``); a large imaginary
    part on the diagonal is still refused."""
    import scipy.linalg

    from repro.metrics import fid as fid_mod

    s = np.eye(3)
    off = np.eye(3) + 0j
    off[0, 1] = 1.0 + 0.5j  # large imaginary part off the diagonal only
    monkeypatch.setattr(scipy.linalg, "sqrtm", lambda m: off)
    assert fid_mod._trace_sqrt_product_scipy(s, s) == pytest.approx(3.0)
    bad = np.eye(3) + 0j
    bad[1, 1] = 1.0 + 0.01j
    monkeypatch.setattr(scipy.linalg, "sqrtm", lambda m: bad)
    with pytest.raises(DataError, match="diagonal"):
        fid_mod._trace_sqrt_product_scipy(s, s)
