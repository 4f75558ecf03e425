"""Fréchet distance between classifier-feature distributions (FID, FID_train, FID_test).

Follows the Action2Motion protocol that all three papers adopt (Neural Marionette §5.1.2,
MultiAct §5 "Evaluation metrics", ODMO §4.2.1; protocols.md §1.1):

    FID = ||mu_a - mu_b||^2 + Tr(S_a) + Tr(S_b) - 2 Tr((S_a S_b)^{1/2})

with ``mu = mean(f)`` and ``S = np.cov(f, rowvar=False)`` (unbiased, divides by N-1).  Units:
squared feature units (the features are the recogniser's dimensionless 30-d tanh layer).

Two routes to the trace of the matrix square root, chosen with ``method``:

- ``"eigh"`` (default): symmetric eigen-decompositions only.  With A = S_a^{1/2} (PSD square
  root from ``eigh``), Tr((S_a S_b)^{1/2}) = Tr((A S_b A)^{1/2}) = sum of the square roots of the
  (clipped non-negative) eigenvalues of the symmetric PSD matrix A S_b A.  Never complex, stable
  for singular or nearly singular covariances.
- ``"scipy"``: the reference implementations' semantics exactly: ``scipy.linalg.sqrtm(S_a @ S_b)``;
  if the result is not finite, retry with 1e-6·I added to both covariances; an imaginary part
  above 1e-3 on the *diagonal* is an error (the references test
  ``np.allclose(np.diagonal(covmean).imag, 0, atol=1e-3)``, and only the trace is used, so
  off-diagonal imaginary parts do not matter); otherwise the real part is kept.

Both agree to round-off when the covariances are well conditioned (tested).  FID_train and
FID_test are the same distance against two reference sets (the training or the test split);
:func:`fid_train_test` computes both.  Every result carries its sample counts and dimension.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from repro.errors import DataError
from repro.metrics.arrays import float_array

SqrtMethod = Literal["eigh", "scipy"]


@dataclass(frozen=True)
class FIDResult:
    """One FID value with the sample counts and feature dimension it was computed from."""

    value: float
    n_a: int
    n_b: int
    dim: int

    def __float__(self) -> float:
        return float(self.value)

    def to_dict(self) -> dict:
        return {"value": float(self.value), "n_a": self.n_a, "n_b": self.n_b, "dim": self.dim}


@dataclass(frozen=True, eq=False)
class FeatureStats:
    """Mean (D,) and unbiased covariance (D, D) of N feature vectors; reusable as a reference
    (ODMO computes its real-data statistics once and scores every generated set against them)."""

    mu: np.ndarray
    sigma: np.ndarray
    n: int

    @property
    def dim(self) -> int:
        return int(self.mu.shape[0])

    @classmethod
    def of(cls, feats) -> "FeatureStats":
        mu, sigma = feature_stats(feats)
        return cls(mu=mu, sigma=sigma, n=int(np.shape(feats)[0]))


def feature_stats(feats) -> tuple[np.ndarray, np.ndarray]:
    """``(mu, sigma)`` of an (N, D) feature matrix: mean and ``np.cov(rowvar=False)`` (ddof 1).

    Protocols §1.1.  Needs N >= 2.  Float64 throughout.
    """
    f = float_array(feats, "features", ndim=2, min_len=2)
    mu = f.mean(axis=0)
    sigma = np.atleast_2d(np.cov(f, rowvar=False))
    return mu, sigma


def _psd_sqrt(s: np.ndarray) -> np.ndarray:
    """Symmetric PSD square root via ``eigh`` (negative round-off eigenvalues clipped to 0)."""
    w, v = np.linalg.eigh((s + s.T) / 2.0)
    return (v * np.sqrt(np.clip(w, 0.0, None))) @ v.T


def _trace_sqrt_product_eigh(s1: np.ndarray, s2: np.ndarray) -> float:
    a = _psd_sqrt(s1)
    m = a @ s2 @ a
    w = np.linalg.eigvalsh((m + m.T) / 2.0)
    return float(np.sqrt(np.clip(w, 0.0, None)).sum())


def _trace_sqrt_product_scipy(s1: np.ndarray, s2: np.ndarray) -> float:
    from scipy.linalg import sqrtm

    covmean = sqrtm(s1 @ s2)
    if not np.all(np.isfinite(covmean)):
        eps = 1e-6
        offset = np.eye(s1.shape[0]) * eps
        covmean = sqrtm((s1 + offset) @ (s2 + offset))
    if np.iscomplexobj(covmean):
        diag = np.diagonal(covmean).imag
        if not np.allclose(diag, 0, atol=1e-3):  # the references' test: the diagonal only
            imag = float(np.max(np.abs(diag)))
            raise DataError(f"FID: matrix square root has an imaginary diagonal component "
                            f"{imag:.3g} (> 1e-3); the covariances are too ill-conditioned for "
                            "method='scipy'")
        covmean = np.real(covmean)
    return float(np.trace(covmean))


def frechet_distance(mu1, sigma1, mu2, sigma2, method: SqrtMethod = "eigh") -> float:
    """Fréchet distance between N(mu1, sigma1) and N(mu2, sigma2) (protocols §1.1 formula).

    ``method`` picks the matrix-square-root route (module docstring).  Returns a float in
    squared feature units; tiny negative round-off is returned as is (never clipped), so a set
    against itself reads as ~1e-13, not as an exact 0.
    """
    mu1 = float_array(mu1, "mu1", ndim=1)
    mu2 = float_array(mu2, "mu2", ndim=1)
    s1 = np.atleast_2d(float_array(sigma1, "sigma1"))
    s2 = np.atleast_2d(float_array(sigma2, "sigma2"))
    d = mu1.shape[0]
    if mu2.shape != (d,) or s1.shape != (d, d) or s2.shape != (d, d):
        raise DataError(f"FID: shapes disagree (mu1 {mu1.shape}, sigma1 {s1.shape}, "
                        f"mu2 {mu2.shape}, sigma2 {s2.shape})")
    diff = mu1 - mu2
    if method == "eigh":
        tr_covmean = _trace_sqrt_product_eigh(s1, s2)
    elif method == "scipy":
        tr_covmean = _trace_sqrt_product_scipy(s1, s2)
    else:
        raise DataError(f"FID: unknown method {method!r} (use 'eigh' or 'scipy')")
    return float(diff @ diff + np.trace(s1) + np.trace(s2) - 2.0 * tr_covmean)


def _stats(x, name: str) -> FeatureStats:
    if isinstance(x, FeatureStats):
        return x
    f = float_array(x, name, ndim=2, min_len=2)
    return FeatureStats.of(f)


def fid(feats_a, feats_b, method: SqrtMethod = "eigh") -> FIDResult:
    """FID between two feature sets, each an (N, D) array/tensor or a :class:`FeatureStats`.

    Protocols §1.1; A2M/ACTOR/ODMO/MultiAct ``calculate_frechet_distance`` semantics with
    ``method="scipy"``.  Returns :class:`FIDResult` (value, n_a, n_b, dim).
    """
    a = _stats(feats_a, "features a")
    b = _stats(feats_b, "features b")
    if a.dim != b.dim:
        raise DataError(f"FID: feature dimensions differ ({a.dim} vs {b.dim})")
    value = frechet_distance(a.mu, a.sigma, b.mu, b.sigma, method=method)
    return FIDResult(value=value, n_a=a.n, n_b=b.n, dim=a.dim)


def fid_train_test(gen_feats, train_ref, test_ref, method: SqrtMethod = "eigh") -> dict[str, FIDResult]:
    """``{"fid_train": ..., "fid_test": ...}``: generated features against the training-split
    and the test-split reference (MultiAct Tables 1-3 FID_tr/FID_test; ODMO Table 1 UESTC
    FID_tr/FID_test; protocols §3.4, §4.4).  References may be precomputed :class:`FeatureStats`.
    """
    g = _stats(gen_feats, "generated features")
    return {"fid_train": fid(g, train_ref, method=method), "fid_test": fid(g, test_ref, method=method)}
