"""Posterior probability of a paper's claim "row A's metric is lower (higher) than row B's
[by at least δ]", sampled with ``emcee``.

Model (fitted jointly, the two rows independent): each row's replicate values are
Student-t(ν) around a location μ with scale σ,

    x_{A,i} ~ t_ν(μ_A, σ_A),   x_{B,i} ~ t_ν(μ_B, σ_B),   ν = 4 (robust to an odd replicate),

with weak priors, stated on standardised data (values minus the pooled mean, divided by the
pooled within-row standard deviation S): μ flat on [-10^6, 10^6]; log σ flat on
[log 10^-6, log 10^3] (scale-invariant).  The claim's probability is the posterior mass of

    "lower":  μ_B - μ_A >= δ        "higher":  μ_A - μ_B >= δ        (δ >= 0, metric units).

Sampler: ``emcee.EnsembleSampler`` (stretch move) with a vectorised log-probability, 64 walkers
started from a rough posterior draw around each row's mean and spread, 100 steps of which the
first 25 are discarded (τ ≈ 10 steps, so about 450 effective samples).  The result carries
P(claim), the effective sample size of μ_A - μ_B (emcee's integrated autocorrelation time)
and the mean acceptance fraction.  Verdict (see
:func:`verdict`): "supported" at P >= 0.95, "contradicted" at P <= 0.05, else "inconclusive".
A chain that did not mix is "inconclusive" with the reason, whatever its P: a mean acceptance
fraction of 0 (no walker ever moved, e.g. rows 10^6 pooled sds apart put every proposal
outside the prior's bounds), or an effective sample size that is not finite or under
``min_ess``.

Honest edge cases (``decided_by`` says which applies):
- a row with a single replicate has no spread to learn from: no sampling, P = NaN,
  verdict "inconclusive", reason given (``decided_by = "nothing"``);
- both rows with zero spread (every replicate identical, e.g. a deterministic metric such as
  Δ_JPE with z = μ from one training): there is no posterior to speak of, so P = NaN; the
  verdict is decided by the values themselves (``decided_by = "values"``), with that reason;
  ``ess``/``acceptance`` NaN.

Calibration (tests/test_stats_claims.py): with equal true means, "supported" comes out in about
5 % of simulated tables (8 and 11 of 200 at R = 10, 20); with a true difference of two standard
deviations, in 199 and 200 of 200 (docs/metrics.md).

One-sample claims (:func:`mean_probability`; a figure's trend along x is a claim about the mean
of the replicates' least-squares slopes): the replicate values s_1..s_R are modelled as
Normal(μ, σ) with the reference prior p(μ, σ) ∝ 1/σ, whose posterior of μ is exactly Student-t
with R − 1 degrees of freedom around the sample mean, scale sd/√R.  The claim's probability is
that posterior's mass of

    "lower":  μ <= −δ        "higher":  μ >= δ        "within":  −δ <= μ <= δ

in closed form (no sampling: ``ess`` and ``acceptance`` are NaN).  Why not the two-group
sampler against a row of zeros: a constant "row" has no spread, so its σ runs to the prior's
floor and the pooled scale is that of one row only; the one-sample posterior says the same thing
without the artefact.  Why Normal rather than t(4): a replicate's slope averages every x point
of its curve, so it is close to normal, and with the reference prior P("lower") >= 0.95 is then
exactly the one-sided t test at 5 %: with a true slope of zero, "supported" comes out in 5 % of
runs (tests/test_stats_claims.py checks this by simulation).  The same edge cases as above:
one replicate → P = NaN, "inconclusive"; no spread at all → decided by the value, P = NaN, with a
reason.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from repro.errors import ConfigError, DataError
from repro.seeding import derive_seed, numpy_rng

SUPPORTED, CONTRADICTED, INCONCLUSIVE = "supported", "contradicted", "inconclusive"
_MU_BOUND = 1e6
_LOG_SIGMA_MIN, _LOG_SIGMA_MAX = math.log(1e-6), math.log(1e3)


@dataclass(frozen=True)
class ClaimResult:
    probability: float
    verdict: str
    ess: float
    acceptance: float
    reason: str | None = None
    direction: str = "lower"
    delta: float = 0.0
    n_a: int = 0
    n_b: int = 0
    decided_by: str = "posterior"  # "posterior", "values" (no spread anywhere) or "nothing"

    def to_dict(self) -> dict:
        def num(x):
            return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else x

        return {"probability": num(self.probability), "verdict": self.verdict, "ess": num(self.ess),
                "acceptance": num(self.acceptance), "reason": self.reason,
                "direction": self.direction, "delta": self.delta, "n_a": self.n_a, "n_b": self.n_b,
                "decided_by": self.decided_by}


def verdict(p: float, supported_at: float = 0.95, contradicted_at: float = 0.05) -> str:
    """"supported" if p >= 0.95, "contradicted" if p <= 0.05, otherwise "inconclusive"."""
    if p is None or not math.isfinite(p):
        return INCONCLUSIVE
    if p >= supported_at:
        return SUPPORTED
    if p <= contradicted_at:
        return CONTRADICTED
    return INCONCLUSIVE


def _row(values, name: str) -> np.ndarray:
    v = np.asarray(values, dtype=np.float64).ravel()
    if v.size == 0:
        raise DataError(f"claim: row {name} has no replicate values")
    if not np.all(np.isfinite(v)):
        raise DataError(f"claim: row {name} has NaN or infinite replicate values")
    return v


def _make_log_prob(a: np.ndarray, b: np.ndarray, nu: float):
    half = 0.5 * (nu + 1.0)

    def log_prob(theta: np.ndarray) -> np.ndarray:
        mu_a, ls_a, mu_b, ls_b = theta[:, 0], theta[:, 1], theta[:, 2], theta[:, 3]
        inside = ((np.abs(mu_a) <= _MU_BOUND) & (np.abs(mu_b) <= _MU_BOUND)
                  & (ls_a >= _LOG_SIGMA_MIN) & (ls_a <= _LOG_SIGMA_MAX)
                  & (ls_b >= _LOG_SIGMA_MIN) & (ls_b <= _LOG_SIGMA_MAX))
        za = (a[None, :] - mu_a[:, None]) * np.exp(-ls_a)[:, None]
        zb = (b[None, :] - mu_b[:, None]) * np.exp(-ls_b)[:, None]
        out = (-a.size * ls_a - half * np.log1p(za * za / nu).sum(axis=1)
               - b.size * ls_b - half * np.log1p(zb * zb / nu).sum(axis=1))
        return np.where(inside, out, -np.inf)

    return log_prob


def _integrated_time(chain: np.ndarray, c: float = 5.0) -> float:
    """Integrated autocorrelation time of a (steps, walkers) chain: the walker-averaged
    autocorrelation function with Sokal's automatic window, via emcee's own helpers (without
    the warning ``integrated_time`` logs for chains shorter than 50 τ)."""
    from emcee.autocorr import auto_window, function_1d

    f = np.mean([function_1d(chain[:, k]) for k in range(chain.shape[1])], axis=0)
    taus = 2.0 * np.cumsum(f) - 1.0
    return float(taus[auto_window(taus, c)])


def _initial(rng: np.random.Generator, a: np.ndarray, b: np.ndarray, n_walkers: int) -> np.ndarray:
    cols = []
    for x in (a, b):
        sd = max(float(np.std(x, ddof=1)), 1e-4)
        df = x.size - 1
        mu = x.mean() + sd / math.sqrt(x.size) * rng.standard_t(max(df, 1), size=n_walkers)
        ls = math.log(sd) + rng.normal(scale=1.0 / math.sqrt(2.0 * df), size=n_walkers)
        cols += [mu, np.clip(ls, _LOG_SIGMA_MIN + 1.0, _LOG_SIGMA_MAX - 1.0)]
    return np.stack(cols, axis=1)


def claim_probability(a_values, b_values, direction: Literal["lower", "higher"] = "lower",
                      delta: float = 0.0, seed: int = 0, nu: float = 4.0, n_walkers: int = 64,
                      n_steps: int = 100, burn: int = 25, min_ess: float = 100.0) -> ClaimResult:
    """P(row A's metric is ``direction`` than row B's by at least ``delta``) (module docstring)."""
    import emcee

    if direction not in ("lower", "higher"):
        raise ConfigError(f"claim direction must be 'lower' or 'higher', got {direction!r}")
    delta = float(delta)
    if not math.isfinite(delta) or delta < 0:
        raise ConfigError(f"claim margin delta must be a finite number >= 0, got {delta}")
    if n_steps <= burn or n_walkers < 8 or n_walkers % 2:
        raise ConfigError("claim sampler: need n_steps > burn and an even n_walkers >= 8")
    a, b = _row(a_values, "A"), _row(b_values, "B")
    common = dict(direction=direction, delta=delta, n_a=int(a.size), n_b=int(b.size))
    nan = float("nan")
    if a.size < 2 or b.size < 2:
        which = " and ".join(n for n, x in (("A", a), ("B", b)) if x.size < 2)
        return ClaimResult(nan, INCONCLUSIVE, 0.0, nan,
                           reason=f"row {which} has a single replicate: no spread to estimate",
                           decided_by="nothing", **common)
    sign = 1.0 if direction == "lower" else -1.0  # claim: sign·(mu_B - mu_A) >= delta
    var_a, var_b = np.var(a, ddof=1), np.var(b, ddof=1)
    if var_a == 0.0 and var_b == 0.0:
        gap = sign * (b[0] - a[0])
        holds = bool(gap > 0.0) if delta == 0.0 else bool(gap >= delta)  # "lower" is strict
        return ClaimResult(nan, SUPPORTED if holds else CONTRADICTED, nan, nan,
                           reason="no spread in either row: decided by the values themselves, "
                                  "no posterior probability", decided_by="values", **common)
    scale = math.sqrt((var_a * (a.size - 1) + var_b * (b.size - 1)) / (a.size + b.size - 2))
    center = float(np.concatenate([a, b]).mean())
    za, zb = (a - center) / scale, (b - center) / scale
    rng = numpy_rng(seed, "claim")
    p0 = _initial(rng, za, zb, n_walkers)
    sampler = emcee.EnsembleSampler(n_walkers, 4, _make_log_prob(za, zb, nu), vectorize=True)
    sampler.random_state = np.random.RandomState(derive_seed(seed, "claim", "emcee") % 2**32).get_state()
    # a row without spread starts its walkers at the sd floor: emcee's condition-number check of
    # the initial state would refuse that ensemble, though sampling from it is well defined
    # Rows about 10^6 pooled sds apart put every walker outside the prior's bounds (log
    # probability -inf): emcee's stretch move then compares -inf - (-inf) = NaN, which rejects
    # the proposal (NaN > x is False), and the chain that never moved has the autocorrelation
    # 0/0 = NaN, so ess is NaN.  Both are the "did not mix (acceptance 0)" case handled below;
    # numpy's "invalid value" RuntimeWarnings for them leaked to a run's stderr (issue 28), so
    # only that floating-point state is silenced here, never overflow or divide-by-zero.
    with np.errstate(invalid="ignore"):
        sampler.run_mcmc(p0, n_steps, progress=False, skip_initial_state_check=True)
        chain = sampler.get_chain(discard=burn)
        diff = sign * (chain[:, :, 2] - chain[:, :, 0])
        p = float(np.mean(diff >= delta / scale))
        tau = _integrated_time(diff)
    ess = float(diff.size / max(tau, 1.0))
    acceptance = float(np.mean(sampler.acceptance_fraction))
    v, reason = verdict(p), None
    if not acceptance > 0.0:  # no walker ever moved: the chain says nothing
        v, reason = INCONCLUSIVE, "the sampler did not mix (acceptance 0)"
    elif not (math.isfinite(ess) and ess >= min_ess):  # NaN compares False: test it explicitly
        v, reason = INCONCLUSIVE, (f"the sampler did not mix (effective sample size "
                                   f"{ess:.0f} < {min_ess:.0f})" if math.isfinite(ess) else
                                   "the sampler did not mix (effective sample size not finite)")
    return ClaimResult(p, v, ess, acceptance, reason=reason, **common)


def mean_probability(values, direction: Literal["lower", "higher", "within"] = "lower",
                     delta: float = 0.0) -> ClaimResult:
    """P(the mean μ of the population ``values`` are drawn from is <= −δ ("lower"), >= δ
    ("higher") or within [−δ, δ] ("within")): Student-t posterior of μ under a normal model
    with the reference prior (module docstring, "One-sample claims")."""
    from scipy.stats import t as student_t

    if direction not in ("lower", "higher", "within"):
        raise ConfigError(f"one-sample claim direction must be 'lower', 'higher' or 'within', "
                          f"got {direction!r}")
    delta = float(delta)
    if not math.isfinite(delta) or delta < 0:
        raise ConfigError(f"claim margin delta must be a finite number >= 0, got {delta}")
    x = _row(values, "values")
    common = dict(direction=direction, delta=delta, n_a=int(x.size), n_b=0)
    nan = float("nan")
    if x.size < 2:
        return ClaimResult(nan, INCONCLUSIVE, 0.0, nan,
                           reason="a single replicate: no spread to estimate",
                           decided_by="nothing", **common)
    m, sd = float(x.mean()), float(np.std(x, ddof=1))
    if sd == 0.0:
        if direction == "within":
            holds = abs(m) <= delta
        elif direction == "lower":
            holds = m < 0.0 if delta == 0.0 else m <= -delta
        else:
            holds = m > 0.0 if delta == 0.0 else m >= delta
        return ClaimResult(nan, SUPPORTED if holds else CONTRADICTED, nan, nan,
                           reason="no spread across replicates: decided by the values "
                                  "themselves, no posterior probability", decided_by="values",
                           **common)
    se, df = sd / math.sqrt(x.size), x.size - 1
    if direction == "lower":
        p = float(student_t.cdf((-delta - m) / se, df))
    elif direction == "higher":
        p = float(student_t.sf((delta - m) / se, df))
    else:
        p = float(student_t.cdf((delta - m) / se, df) - student_t.cdf((-delta - m) / se, df))
    return ClaimResult(p, verdict(p), nan, nan, reason=None, **common)
