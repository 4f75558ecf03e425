"""The papers' ± conventions (as the reference codes compute them), Wilson, bootstrap."""

import math
from statistics import NormalDist

import numpy as np
import pytest
import scipy.stats as st

from repro.errors import ConfigError, DataError
from repro.stats.bootstrap import bootstrap_ci
from repro.stats.intervals import INTERVAL_METHODS, paper_halfwidth, wilson
from repro.stats.summary import summarize

V5 = [1.0, 2.0, 3.0, 4.0, 5.0]  # sd (ddof 1) = sqrt(2.5), population var = 2


def test_known_half_widths():
    sd = math.sqrt(2.5)
    z = NormalDist().inv_cdf(0.975)
    assert paper_halfwidth(V5, "z_sem") == pytest.approx(z * sd / math.sqrt(5))
    assert paper_halfwidth(V5, "t_sem") == pytest.approx(2.7764451 * sd / math.sqrt(5), rel=1e-7)
    assert paper_halfwidth(V5, "z_sd_sqrt_nm1") == pytest.approx(z * sd / 2.0)
    assert paper_halfwidth(V5, "z_var") == pytest.approx(1.96 * 2.0)
    assert paper_halfwidth(V5, "none") is None
    assert set(INTERVAL_METHODS) == {"z_sem", "t_sem", "z_sd_sqrt_nm1", "z_var", "none"}


def test_match_the_reference_code_recipes():
    vals = np.random.default_rng(0).normal(3.0, 0.4, size=20)
    # MultiAct: st.t.interval(0.95, n-1, loc=mean, scale=st.sem(values))
    lo, hi = st.t.interval(0.95, len(vals) - 1, loc=vals.mean(), scale=st.sem(vals))
    assert paper_halfwidth(vals, "t_sem") == pytest.approx((hi - lo) / 2, rel=1e-12)
    assert paper_halfwidth(vals, "t_sem") / (np.std(vals, ddof=1) / math.sqrt(20)) == pytest.approx(2.093, abs=1e-3)
    # ODMO: NormalDist.from_samples(data).stdev * z / sqrt(n - 1), n = 10
    ten = vals[:10]
    odmo = NormalDist.from_samples(ten).stdev * NormalDist().inv_cdf(0.975) / math.sqrt(9)
    assert paper_halfwidth(ten, "z_sd_sqrt_nm1") == pytest.approx(odmo, rel=1e-12)
    # ACTOR: 1.96 * np.var(values), accuracy scaled to % first
    acc = np.array([0.91, 0.93, 0.92, 0.95])
    assert paper_halfwidth(acc, "z_var", scale=100) == pytest.approx(1.96 * np.var(100 * acc))


def test_single_replicate_has_no_interval():
    for m in INTERVAL_METHODS:
        assert paper_halfwidth([3.0], m) is None
    with pytest.raises(ConfigError, match="unknown interval method"):
        paper_halfwidth(V5, "sem")
    with pytest.raises(DataError):
        paper_halfwidth([1.0, float("nan")], "z_sem")


def test_wilson_known_values_and_extremes():
    z = NormalDist().inv_cdf(0.975)
    lo, hi = wilson(0, 20)
    assert lo == pytest.approx(0.0, abs=1e-12) and hi == pytest.approx(z * z / (20 + z * z))
    lo, hi = wilson(20, 20)
    assert lo == pytest.approx(20 / (20 + z * z)) and hi == pytest.approx(1.0)
    k, n = 7, 25
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    assert wilson(k, n) == pytest.approx((centre - half, centre + half))
    with pytest.raises(DataError):
        wilson(5, 3)


def test_bootstrap_deterministic_and_sensible():
    x = np.random.default_rng(1).lognormal(size=30)
    a = bootstrap_ci(x, seed=3)
    assert a == bootstrap_ci(x, seed=3) and a != bootstrap_ci(x, seed=4)
    lo, hi = a
    assert lo < x.mean() < hi
    blo, bhi = bootstrap_ci(x, method="bca", seed=3)
    assert blo < x.mean() < bhi and (blo, bhi) != (lo, hi)  # skewed data: BCa shifts
    # over samples: resampling rows of a 2-D array with an arbitrary statistic
    rows = np.stack([x, -x], axis=1)
    assert bootstrap_ci(rows, stat=lambda f: f[:, 0].mean(), method="bca", seed=3) == pytest.approx((blo, bhi))


def test_bootstrap_percentile_coverage():
    rng = np.random.default_rng(2)
    hits = 0
    for i in range(200):
        lo, hi = bootstrap_ci(rng.normal(size=20), seed=i)
        hits += lo <= 0.0 <= hi
    assert 0.88 <= hits / 200 <= 0.99  # nominal 95 %; percentile is a little narrow at n = 20


def test_bootstrap_degenerate_cases():
    lo, hi = bootstrap_ci([2.5])
    assert math.isnan(lo) and math.isnan(hi)
    assert bootstrap_ci([2.5, 2.5, 2.5], method="bca") == (2.5, 2.5)
    with pytest.raises(ConfigError):
        bootstrap_ci(V5, method="basic")


def test_summary_keeps_raw_values_and_is_json_safe():
    import json

    s = summarize([0.91, 0.93, 0.92], "z_var", scale=100)
    d = s.to_dict()
    assert d["values"] == pytest.approx([91.0, 93.0, 92.0]) and d["paper_method"] == "z_var"
    assert d["paper_halfwidth"] == pytest.approx(1.96 * np.var([91.0, 93.0, 92.0]))
    one = summarize([1.0], "t_sem").to_dict()
    assert one["paper_halfwidth"] is None and one["bootstrap_bca"] == [None, None]
    json.dumps(one, allow_nan=False)
