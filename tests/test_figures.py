"""Figures: per-x cells, claims along the x axis, the figure view in every format.

Synthetic measure-job values (``{"acc": …, "acc@1": …, "fid@1": …}``, as the figure protocols
emit them) go through the aggregation functions directly; nothing is trained.
"""

from __future__ import annotations

import csv
import io
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from repro.engine.table_view import make_view
from repro.engine.table_plan import Band, RowPlan, TablePlan
from repro.engine.tables import _claim, _values_by_cell, collect_values, summarise
from repro.paths import repo_root
from repro.report import FORMATS, render
from repro.report.render import _num
from repro.specs.load import load_spec
from repro.stats.claims import mean_probability

XS = range(1, 7)  # the quick scale's 6 actions of the paper's 20


def _spec(name: str):
    return load_spec(repo_root() / "tables" / f"{name}.toml")


class _Job:
    def __init__(self, key: str, seed: int):
        self._key, self.seed = key, seed

    def key(self) -> str:
        return self._key


def _fake_run(spec, per_row: dict[str, list[dict]], monkeypatch):
    """A plan with one band of every column and, per row, one measure job per replicate whose
    stored values are ``per_row[row][replicate]``; returns (plan, reports)."""
    import repro.engine.steps as steps

    monkeypatch.setattr(steps, "read_values", lambda obj: obj)
    band = Band(spec.protocol, {}, [c.id for c in spec.columns],
                {c.id: c.metric for c in spec.columns}, implemented=True)
    objects, rows = {}, []
    for row in spec.rows:
        rp = RowPlan(row.id, row.method)
        jobs = []
        for r, vals in enumerate(per_row.get(row.id, [])):
            job = _Job(f"{row.id}-measure-r{r}", seed=r)
            objects[job.key()] = vals
            jobs.append(job)
        if jobs:
            rp.measures[0] = jobs
        rows.append(rp)
    n = max(len(v) for v in per_row.values())
    plan = TablePlan(spec, SimpleNamespace(bootstrap_resamples=200), "bandai2-mini", "fp", None,
                     tuple(range(n)), [band], rows)
    report = SimpleNamespace(object=lambda job: objects[job.key()])
    return plan, {rp.row_id: report for rp in rows}


def _curves(metric_curves: dict[str, callable], reps: int = 3, xs=XS, seed: int = 0) -> list[dict]:
    """One values dict per replicate: ``metric@x`` = curve(x, r) plus the plain averages (which
    a figure does not record) and keys that are not per-x values of any column."""
    out = []
    for r in range(reps):
        d = {"n_sequences": 12.0, "acc@x": 1.0}
        for m, f in metric_curves.items():
            pts = {x: f(x, r) for x in xs}
            d[m] = sum(pts.values()) / len(pts)
            d.update({f"{m}@{x}": v for x, v in pts.items()})
        d["acc@25"] = 0.5  # beyond the axis (stop = 20): ignored
        out.append(d)
    return out


def _jitter(r: int, x: int, scale: float) -> float:
    return scale * math.sin(7.3 * r + 1.7 * x + 0.4)  # deterministic, replicate- and x-dependent


def _fig8_values(acc_slope: float = -0.05) -> dict[str, list[dict]]:
    """MARIONET best on every metric at every x; accuracy changing by ``acc_slope`` per action."""
    base = {"mann": (0.80, 25.0), "a2m": (0.85, 20.0), "marionet": (0.95, 10.0)}
    out = {}
    for row, (acc0, fid0) in base.items():
        out[row] = _curves({
            "acc": lambda x, r, a=acc0: a + acc_slope * x + _jitter(r, x, 0.004),
            "fid": lambda x, r, f=fid0: f + x + _jitter(r, x, 0.3),
            "action_qr": lambda x, r, a=acc0: a - 0.04 * x + _jitter(r, x, 0.004),
            "motion_qr": lambda x, r, a=acc0: a - 0.06 * x + _jitter(r, x, 0.004),
        })
    return out


@pytest.fixture
def fig8_run(monkeypatch):
    spec = _spec("marionette/fig8")
    plan, reports = _fake_run(spec, _fig8_values(), monkeypatch)
    values = collect_values(plan, reports)
    return spec, plan, values


def _claim_by_id(spec, cid: str, **update):
    cl = next(c for c in spec.claims if c.id == cid)
    return cl.model_copy(update=update) if update else cl


# ---------------------------------------------------------------------------------------------
# aggregation


def test_figure_values_are_one_record_per_x_with_col_at_x_ids(fig8_run):
    spec, _, values = fig8_run
    cols = {c.id for c in spec.columns}
    assert len(values) == 3 * len(cols) * 3 * len(XS)  # rows × columns × replicates × x
    for v in values:
        col, _, x = v["column"].rpartition("@")
        assert col in cols and int(x) == v["x"] and v["x"] in XS
        assert v["metric"] == spec.column(col).metric
    assert {v["column"] for v in values if v["row"] == "mann"} == \
        {f"{c}@{x}" for c in cols for x in XS}
    assert not any(v["column"] in cols for v in values)  # the plain averages are not recorded


def test_figure_summary_has_an_interval_per_x(fig8_run):
    spec, plan, values = fig8_run
    summary = summarise(plan, values)
    assert summary["x"] == {"id": "action_index", "label": "Action index", "start": 1,
                            "stop": 20, "present": list(XS)}
    cells = summary["cells"]
    assert set(cells) == {"mann", "a2m", "marionet"}
    assert set(cells["marionet"]) == {f"{c.id}@{x}" for c in spec.columns for x in XS}
    for x in XS:
        c = cells["marionet"][f"overall.acc@{x}"]
        assert c["n"] == 3 and len(c["values"]) == 3
        lo, hi = c["bootstrap_percentile"]
        assert lo <= c["mean"] <= hi
        assert c["mean"] == pytest.approx(0.95 - 0.05 * x, abs=0.005)
    # the claims of Fig. 8 at the quick scale's 6 actions
    by_id = {c["id"]: c for c in summary["claims"]}
    assert by_id["best_within_8_actions"]["verdict"] == "supported"
    assert by_id["fid_better_after_8_actions"]["verdict"] == "not evaluated"
    assert by_id["accuracy_decreases"]["verdict"] == "supported"


def test_table_values_and_summary_are_unchanged(monkeypatch):
    spec = _spec("marionette/table1")
    per_row = {"real": [{"fid": 1.0 + r, "acc": 0.9, "div": 5.0, "multimod": 3.0,
                         "acc@1": 0.5} for r in range(3)]}
    plan, reports = _fake_run(spec, per_row, monkeypatch)
    values = collect_values(plan, reports)
    assert {v["column"] for v in values} == {"fid", "acc", "div", "multimod"}
    assert all("x" not in v for v in values)
    summary = summarise(plan, values)
    assert "x" not in summary and set(summary["cells"]["real"]) == {"fid", "acc", "div", "multimod"}


_RECORDS = sorted(p for d in sorted((repo_root() / "docs" / "results").iterdir()) if d.is_dir()
                  for p in d.iterdir() if (p / "values.jsonl").is_file())


@pytest.mark.parametrize("path", _RECORDS, ids=[p.name for p in _RECORDS])
def test_table_claims_recomputed_from_records_are_unchanged(path):
    """The claim code gives the committed records' posterior verdicts and P exactly (records
    made since issue 11, whose claims carry their evidence; earlier ones were summarised
    under the former edge-case rules: P = 1/0 for a column without spread)."""
    rj = json.loads((path / "run.json").read_text())
    summary = json.loads((path / "summary.json").read_text())
    if not all("evidence" in c for c in summary["claims"]):
        pytest.skip("a record made before issue 11's verdict rules")
    values = [json.loads(ln) for ln in (path / "values.jsonl").read_text().splitlines()]
    spec = _spec(rj["table"])
    cells = _values_by_cell(values)
    for recorded in summary["claims"]:
        cl = next(c for c in spec.claims if c.id == recorded["id"])
        posterior = {k: v for k, v in recorded.items() if k not in ("evidence",
                                                                     "posterior_verdict")}
        posterior["verdict"] = recorded["posterior_verdict"]
        from repro.store.atomic import jsonable

        assert jsonable(_claim(spec, cl, cells, values)) == posterior


# ---------------------------------------------------------------------------------------------
# claims


def test_order_over_x_range_supported_with_what_decided_it(fig8_run):
    spec, _, values = fig8_run
    got = _claim(spec, _claim_by_id(spec, "best_within_8_actions"), _values_by_cell(values), values)
    assert got["verdict"] == "supported" and got["probability"] >= 0.95
    assert len(got["pairwise"]) == 4 * 6 * 2  # columns × x in range × rows beaten
    assert got["probability"] == min(got["pairwise"])
    assert got["x"] == list(XS)
    assert got["reason"].startswith("x 1..6 present of x_range 1..8 (the run's axis stops at 6); "
                                    "3 replicates each")


def test_order_contradicted_when_one_x_goes_the_other_way(monkeypatch):
    spec = _spec("marionette/fig8")
    per_row = _fig8_values()
    for d in per_row["marionet"]:  # at action 3 MARIONET's FID is the worst
        d["fid@3"] = 40.0 + d["fid@3"] / 100
    plan, reports = _fake_run(spec, per_row, monkeypatch)
    values = collect_values(plan, reports)
    cl = _claim_by_id(spec, "best_within_8_actions", column=["overall.fid"])
    got = _claim(spec, cl, _values_by_cell(values), values)
    assert got["verdict"] == "contradicted" and got["probability"] <= 0.05


def test_order_beyond_the_runs_axis_is_not_evaluated(fig8_run):
    spec, _, values = fig8_run
    got = _claim(spec, _claim_by_id(spec, "fid_better_after_8_actions"), _values_by_cell(values),
                 values)
    assert got["verdict"] == "not evaluated" and got["probability"] is None
    assert "x_range 9..20" in got["reason"] and "the run's axis stops at 6" in got["reason"]


def test_order_without_a_row_is_not_evaluated(monkeypatch):
    spec = _spec("marionette/fig8")
    per_row = _fig8_values()
    del per_row["mann"]
    plan, reports = _fake_run(spec, per_row, monkeypatch)
    values = collect_values(plan, reports)
    got = _claim(spec, _claim_by_id(spec, "best_within_8_actions"), _values_by_cell(values), values)
    assert got["verdict"] == "not evaluated"
    assert got["reason"] == "no reproduced values for row 'mann' in column 'overall.acc'"


@pytest.mark.parametrize("slope, expected", [(-0.05, "supported"), (0.05, "contradicted")])
def test_trend_along_x(monkeypatch, slope, expected):
    spec = _spec("marionette/fig8")
    plan, reports = _fake_run(spec, _fig8_values(acc_slope=slope), monkeypatch)
    values = collect_values(plan, reports)
    cells = _values_by_cell(values)
    cl = _claim_by_id(spec, "accuracy_decreases")
    got = _claim(spec, cl, cells, values)
    assert got["verdict"] == expected
    assert len(got["pairwise"]) == 3 * 2  # rows × columns
    assert got["probability"] == min(got["pairwise"])
    assert set(got["slopes"]) == {f"{r}/{c}" for r in cl.rows for c in cl.column}
    assert all(s == pytest.approx(slope, abs=0.005) for s in got["slopes"].values())
    assert got["reason"].startswith("x 1..6 present of the axis 1..20 (the run's axis stops at "
                                    "6); 3 replicates each; least-squares slope per replicate")
    # without the raw records the cells' replicate order gives the same slopes
    assert _claim(spec, cl, cells)["slopes"] == got["slopes"]


def test_trend_along_x_noise_is_inconclusive(monkeypatch):
    spec = _spec("marionette/fig8")
    slopes = (0.010, -0.012, 0.003)  # per replicate: no consistent direction
    per_row = {row: _curves({"acc": lambda x, r: 0.8 + slopes[r] * (x - 3.5)
                             + _jitter(r, x, 0.002)})
               for row in ("mann", "a2m", "marionet")}
    plan, reports = _fake_run(spec, per_row, monkeypatch)
    values = collect_values(plan, reports)
    got = _claim(spec, _claim_by_id(spec, "accuracy_decreases"), _values_by_cell(values), values)
    assert got["verdict"] == "inconclusive"
    assert 0.05 < got["probability"] < 0.95


def test_trend_along_x_range_and_missing_points(monkeypatch):
    """x_range narrows the slope's x; a replicate missing a point is left out, said so."""
    spec = _spec("marionette/fig8")
    per_row = _fig8_values()
    per_row["mann"][2]["acc@4"] = float("nan")
    plan, reports = _fake_run(spec, per_row, monkeypatch)
    values = collect_values(plan, reports)
    cl = _claim_by_id(spec, "accuracy_decreases", x_range=(2, 5), column=["overall.acc"])
    got = _claim(spec, cl, _values_by_cell(values), values)
    assert got["x"] == [2, 3, 4, 5]
    assert "x 2..5 present; 2-3 replicates per cell" in got["reason"]
    assert "mann/overall.acc: 1 replicate(s) left out for a missing x" in got["reason"]
    one = _claim_by_id(spec, "accuracy_decreases", x_range=(6, 9))
    got = _claim(spec, one, _values_by_cell(values), values)
    assert got["verdict"] == "not evaluated" and "a slope needs two" in got["reason"]


def _fig6_values(acc_slope: float) -> dict[str, list[dict]]:
    out = {}
    for row, a0 in (("multiact", 0.8), ("actor", 0.5), ("actor_ssmct", 0.5),
                    ("interpolation", 0.5)):
        out[row] = _curves({
            "acc": lambda x, r, a=a0: a + acc_slope * x + _jitter(r, x, 0.005),
            "fid_test": lambda x, r, a=a0: 10 * a + _jitter(r, x, 0.1),
        }, reps=4)
    return out


@pytest.mark.parametrize("slope, expected", [(0.0, "supported"), (-0.05, "contradicted")])
def test_stable_trend_within_delta(monkeypatch, slope, expected):
    """MultiAct Fig. 6 "maintains the quality": |mean slope| · (x_hi − x_lo) <= 0.1 over x 2..6."""
    spec = _spec("multiact/fig6")
    plan, reports = _fake_run(spec, _fig6_values(slope), monkeypatch)
    values = collect_values(plan, reports)
    got = _claim(spec, _claim_by_id(spec, "accuracy_maintained"), _values_by_cell(values), values)
    assert got["verdict"] == expected
    assert got["x"] == [2, 3, 4, 5, 6]
    assert "x 2..6 present of x_range 2..20 (the run's axis stops at 6); 4 replicates each" \
        in got["reason"]


def test_one_sample_probability():
    rng = np.random.default_rng(0)
    down = rng.normal(-0.05, 0.01, size=5)
    assert mean_probability(down, "lower").verdict == "supported"
    assert mean_probability(down, "higher").verdict == "contradicted"
    assert mean_probability(-down, "lower").verdict == "contradicted"
    noise = np.array([0.01, -0.012, 0.003])
    r = mean_probability(noise, "lower")
    assert r.verdict == "inconclusive" and 0.3 < r.probability < 0.7
    assert math.isnan(r.ess) and r.n_a == 3 and r.n_b == 0
    # P(lower) + P(higher) = 1 for δ = 0; within: the mass between ±δ
    assert r.probability + mean_probability(noise, "higher").probability == pytest.approx(1.0)
    assert mean_probability(down, "within", delta=0.2).verdict == "supported"
    assert mean_probability(down, "within", delta=0.001).verdict == "contradicted"
    # scale-invariant
    assert mean_probability(1000 * noise, "lower").probability == pytest.approx(r.probability)
    # edge cases, as claim_probability
    one = mean_probability([0.3], "lower")
    assert one.verdict == "inconclusive" and math.isnan(one.probability) and "single" in one.reason
    flat = mean_probability([-1.0, -1.0, -1.0], "lower")
    assert flat.verdict == "supported" and math.isnan(flat.probability) and "no spread" in flat.reason
    assert flat.decided_by == "values" and "no posterior" in flat.reason
    assert mean_probability([0.0] * 3, "lower").verdict == "contradicted"
    assert mean_probability([0.05] * 3, "within", delta=0.1).verdict == "supported"
    from repro.errors import ConfigError

    with pytest.raises(ConfigError):
        mean_probability([1.0, 2.0], "down")
    with pytest.raises(ConfigError):
        mean_probability([1.0, 2.0], "lower", delta=-1)


@pytest.mark.parametrize("n", [3, 10])
def test_one_sample_calibration(n):
    """With a true mean of zero, "supported" comes out in 5 % of samples (the one-sided t test):
    2000 simulated sets of replicate slopes."""
    rng = np.random.default_rng(n)
    hits = sum(mean_probability(rng.normal(0.0, 1.0, size=n), "lower").verdict == "supported"
               for _ in range(2000))
    assert 0.035 < hits / 2000 < 0.065
    strong = sum(mean_probability(rng.normal(-2.0, 1.0, size=n), "lower").verdict == "supported"
                 for _ in range(200))
    assert strong >= (110 if n == 3 else 199)  # power of the t test at R = 3: about 0.7


# ---------------------------------------------------------------------------------------------
# the view


def _view(spec, summary):
    rows = summary["rows"] if summary else {r.id: {"status": "not run"} for r in spec.rows}
    return make_view(spec, rows, summary, ["Spec marionette/fig8 v1; run test"], "bandai2-mini")


def test_figure_renders_every_x_in_every_format(fig8_run):
    spec, plan, values = fig8_run
    summary = summarise(plan, values)
    view = _view(spec, summary)
    assert view.x.values == list(XS)
    means = {x: _num(summary["cells"]["marionet"][f"overall.acc@{x}"]["mean"]) for x in XS}
    assert len(set(means.values())) == len(XS)
    for fmt in ("term", "md", "latex", "html"):
        text = render(view, fmt)
        assert "figure: no printed values" in text, fmt
        assert "Action index" in text and "STAND-IN" in text
        for x, m in means.items():
            assert f"{m} [" in text, (fmt, x)
        assert "SUPPORTED" in text and "NOT EVALUATED" in text and "axis stops at 6" in text
        assert "Acc-S" in text and "Motion QR-O" in text  # one block per column
    data = json.loads(render(view, "json"))
    assert data["x"]["values"] == list(XS)
    for row in data["rows"]:
        assert set(row["cells"]) == {f"{c.id}@{x}" for c in spec.columns for x in XS}
        assert all(c["reported"] is None and c["status"] == "ok" for c in row["cells"].values())
    lines = list(csv.DictReader(io.StringIO(render(view, "csv"))))
    assert len(lines) == 3 * len(spec.columns) * len(XS)
    assert {(ln["row"], ln["column"], ln["x"]) for ln in lines} == \
        {(r.id, f"{c.id}@{x}", str(x)) for r in spec.rows for c in spec.columns for x in XS}
    assert all(ln["paper"] == "" and ln["n"] == "3" for ln in lines)


def test_term_figure_stays_narrow(fig8_run):
    spec, plan, values = fig8_run
    text = render(_view(spec, summarise(plan, values)), "term")
    table_lines = [ln for ln in text.splitlines() if ln.startswith(("┃", "│", "┏", "┡", "└"))]
    assert table_lines and max(len(ln) for ln in table_lines) <= 100


def test_figure_view_before_a_run_says_so_in_every_format():
    spec = _spec("marionette/fig8")
    view = _view(spec, None)
    assert view.x.values == [] and view.cell_keys("overall.acc") == [("–", "overall.acc")]
    for fmt in FORMATS:
        text = render(view, fmt)
        assert "not run" in text, fmt
        if fmt not in ("json", "csv"):
            assert "reproduced: nothing yet" in text and "NOT EVALUATED" in text
    lines = list(csv.DictReader(io.StringIO(render(view, "csv"))))
    assert len(lines) == 3 * len(spec.columns) and {ln["x"] for ln in lines} == {""}


def test_missing_row_and_x_cells_say_why(monkeypatch):
    spec = _spec("marionette/fig8")
    per_row = _fig8_values()
    del per_row["mann"]
    plan, reports = _fake_run(spec, per_row, monkeypatch)
    plan.rows[0].status, plan.rows[0].reason = "not implemented", "method 'mann' is not built"
    summary = summarise(plan, collect_values(plan, reports))
    view = _view(spec, summary)
    mann = view.rows[0]
    assert {c.status for c in mann.cells.values()} == {"not implemented"}
    assert "not implemented" in render(view, "term")


# ---------------------------------------------------------------------------------------------
# baselines (repro verify) read the "col@x" ids like any other


def test_baseline_of_a_figure_compares_cell_by_cell(fig8_run):
    from repro.engine.baselines import compare, make_baseline

    spec, plan, values = fig8_run
    summary = summarise(plan, values)
    base = make_baseline(summary, scale="quick", dataset="bandai2-mini", run_id="r")
    assert "overall.acc@3" in base["cells"]["marionet"]
    assert compare(base, summary) == []
    drifted = json.loads(json.dumps(summary))
    drifted["cells"]["marionet"]["overall.acc@3"]["mean"] += 0.5
    del drifted["cells"]["mann"]["overall.fid@6"]
    problems = compare(base, drifted)
    assert any(p.startswith("marionet/overall.acc@3:") for p in problems)
    assert "mann/overall.fid@6: in the baseline but not reproduced now" in problems
