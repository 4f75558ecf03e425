"""The papers' own "±" half-widths, exactly as each reference code computes them, and Wilson
intervals for proportions.

protocols.md §1.6; each table spec names the convention its paper printed:

``"z_sem"``          z·s/√R, s the sample standard deviation (ddof 1), z = Φ⁻¹(0.975) ≈ 1.96.
                     The generic "mean ± 1.96·sd/√R" of DESIGN.md.
``"t_sem"``          t_{0.975, R-1}·s/√R (MultiAct, ``scipy.stats.t.interval`` with ``sem``;
                     R = 20 -> 2.093·s/√20).
``"z_sd_sqrt_nm1"``  z·s/√(R-1), s with ddof 1, z = ``NormalDist().inv_cdf(0.975)`` (ODMO's
                     ``confidence_interval``; R = 10 -> 1.96·s/3).
``"z_var"``          1.96·var(values), the population variance (ddof 0) — not a standard error
                     (ACTOR's ``easy_table`` quirk; its accuracy is scaled to % *before* the
                     variance, so pass ``scale=100`` for percent columns).  ``conf`` is ignored:
                     ACTOR hard-codes 1.96.
``"none"``           no interval (Neural Marionette prints none).

Every method returns ``None`` for fewer than two replicates: there is no spread to show, and
an interval of 0 would read as exact.  Half-widths are in the units of ``values·scale``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from repro.errors import ConfigError, DataError


def _values(values, scale: float = 1.0) -> np.ndarray:
    v = np.asarray(values, dtype=np.float64).ravel() * scale
    if not np.all(np.isfinite(v)):
        raise DataError("interval: replicate values contain NaN or infinite values")
    return v


def _z(conf: float) -> float:
    from scipy.stats import norm

    if not 0.0 < conf < 1.0:
        raise ConfigError(f"confidence level must lie in (0, 1), got {conf}")
    return float(norm.ppf(0.5 + conf / 2.0))


def z_sem(values, conf: float = 0.95) -> float | None:
    v = _values(values)
    if v.size < 2:
        return None
    return _z(conf) * float(np.std(v, ddof=1)) / math.sqrt(v.size)


def t_sem(values, conf: float = 0.95) -> float | None:
    from scipy.stats import t

    v = _values(values)
    if v.size < 2:
        return None
    return float(t.ppf(0.5 + conf / 2.0, v.size - 1)) * float(np.std(v, ddof=1)) / math.sqrt(v.size)


def z_sd_sqrt_nm1(values, conf: float = 0.95) -> float | None:
    v = _values(values)
    if v.size < 2:
        return None
    return _z(conf) * float(np.std(v, ddof=1)) / math.sqrt(v.size - 1)


def z_var(values, conf: float = 0.95) -> float | None:
    v = _values(values)
    if v.size < 2:
        return None
    return 1.96 * float(np.var(v))


def no_interval(values, conf: float = 0.95) -> None:
    return None


INTERVAL_METHODS: dict[str, Callable[..., float | None]] = {
    "z_sem": z_sem,
    "t_sem": t_sem,
    "z_sd_sqrt_nm1": z_sd_sqrt_nm1,
    "z_var": z_var,
    "none": no_interval,
}

#: One line per method, for reports ("the ± printed by the paper is …").
INTERVAL_DESCRIPTIONS: dict[str, str] = {
    "z_sem": "1.96·sd/√R (sd with ddof 1)",
    "t_sem": "Student-t t(0.975, R−1)·sd/√R (MultiAct)",
    "z_sd_sqrt_nm1": "1.96·sd/√(R−1) (ODMO)",
    "z_var": "1.96·population variance (ACTOR)",
    "none": "no interval printed (Neural Marionette)",
}


def paper_halfwidth(values, method: str, conf: float = 0.95, scale: float = 1.0) -> float | None:
    """The "±" half-width of ``values·scale`` under a paper's convention (module docstring)."""
    if method not in INTERVAL_METHODS:
        raise ConfigError(f"unknown interval method {method!r} (use one of {sorted(INTERVAL_METHODS)})")
    return INTERVAL_METHODS[method](_values(values, scale), conf=conf)


def wilson(successes: int, n: int, conf: float = 0.95) -> tuple[float, float]:
    """Wilson score interval (no continuity correction) for a proportion successes/n.

    Via ``scipy.stats.binomtest(...).proportion_ci(method="wilson")``; 0 % and 100 % get a
    non-degenerate interval, so they do not read as exact.
    """
    from scipy.stats import binomtest

    k, n = int(successes), int(n)
    if n < 1 or not 0 <= k <= n or k != successes or n != int(n):
        raise DataError(f"wilson: need integers 0 <= successes <= n, n >= 1; got {successes}/{n}")
    ci = binomtest(k, n).proportion_ci(confidence_level=conf, method="wilson")
    return float(ci.low), float(ci.high)
