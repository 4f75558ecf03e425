"""Seeded bootstrap confidence intervals (percentile and BCa) over replicates or samples.

Built on ``scipy.stats.bootstrap`` (Efron & Tibshirani's percentile and bias-corrected and
accelerated intervals).  ``values`` is either

- a 1-D array of replicate values (e.g. the 10 or 20 per-seed FIDs of a cell) with a ``stat``
  over 1-D arrays (default the mean) — "over replicates"; or
- an (N, ...) array of samples (e.g. N feature vectors) with a ``stat`` that maps an (M, ...)
  array to a number (e.g. ``lambda f: fid(f, ref).value``) — "over samples": rows are
  resampled with replacement.

Deterministic: the resampling generator is :func:`repro.seeding.numpy_rng` of ``seed``.
Fewer than two values give ``(nan, nan)``: resampling one value would fake a zero-width
interval.  When every resample gives the same statistic (e.g. all replicates equal) the
interval is that value, for both methods (BCa is undefined there).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Literal

import numpy as np

from repro.errors import ConfigError, DataError
from repro.seeding import numpy_rng


def bootstrap_ci(values, stat: Callable = np.mean, method: Literal["percentile", "bca"] = "percentile",
                 n_boot: int = 1000, conf: float = 0.95, seed: int = 0) -> tuple[float, float]:
    """``(lo, hi)`` bootstrap interval of ``stat`` (module docstring)."""
    from scipy.stats import bootstrap

    if method not in ("percentile", "bca"):
        raise ConfigError(f"bootstrap method must be 'percentile' or 'bca', got {method!r}")
    if n_boot < 2:
        raise ConfigError(f"n_boot must be at least 2, got {n_boot}")
    if not 0.0 < conf < 1.0:
        raise ConfigError(f"confidence level must lie in (0, 1), got {conf}")
    v = np.asarray(values.detach().cpu().numpy() if hasattr(values, "detach") else values)
    if v.ndim == 0:
        v = v.reshape(1)
    if np.issubdtype(v.dtype, np.number) and not np.all(np.isfinite(v)):
        raise DataError("bootstrap: values contain NaN or infinite values")
    n = v.shape[0]
    if n < 2:
        return float("nan"), float("nan")
    if v.ndim == 1 and stat in (np.mean, np.median, np.std, np.var):
        data, statistic, vectorized = (v.astype(np.float64),), stat, True
    else:
        data = (np.arange(n),)
        vectorized = False

        def statistic(idx):
            return float(stat(v[np.asarray(idx, dtype=np.int64)]))

    point = float(stat(v))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # scipy's DegenerateDataWarning: handled below
        res = bootstrap(data, statistic, n_resamples=n_boot, vectorized=vectorized,
                        confidence_level=conf, method="BCa" if method == "bca" else "percentile",
                        rng=numpy_rng(seed, "bootstrap"))
    lo, hi = float(res.confidence_interval.low), float(res.confidence_interval.high)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        dist = np.asarray(res.bootstrap_distribution)
        if np.allclose(dist, dist.flat[0], rtol=0.0, atol=1e-12 * max(1.0, abs(point))):
            return point, point
        raise DataError(f"bootstrap: the {method} interval is undefined for these values")
    return lo, hi
