"""Every verdict says what decided it (issue 11, item 1): variance, training budget against the
paper's, evaluator; a contradicted claim below the paper's budget, or without training-seed
variance, is "not reproduced", and only a paper-budget run with --retrain reads
"contradicted"; a deterministic column has no posterior probability, and says so only there."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from repro.engine.evidence import (NOT_REPRODUCED_BUDGET, NOT_REPRODUCED_REDUCED,
                                   NOT_REPRODUCED_SAMPLING, NOT_REPRODUCED_UNKNOWN, budget_text,
                                   claim_evidence, qualified_verdict, scale_epochs,
                                   training_budget)
from repro.engine.table_plan import build_plan
from repro.engine.tables import summarise
from repro.specs.load import find_spec
from repro.specs.scales import resolve_scale

ROWS = ("real", "mann", "a2m", "marionet", "actor", "nearest_clip")


def _values(spec, per_row: dict[str, dict[str, list[float]]]) -> list[dict]:
    out = []
    for row, cols in per_row.items():
        for col, vals in cols.items():
            for r, v in enumerate(vals):
                out.append({"row": row, "column": col, "replicate": r, "seed": r, "value": v,
                            "metric": spec.column(col).metric, "job": "k"})
    return out


def _table1_values(spec, *, marionet_fid: float, traj_const: bool = True, reps: int = 5):
    rng = np.random.default_rng(0)
    per_row = {}
    for row, fid in (("real", 0.1), ("mann", 2.0), ("a2m", 2.5), ("marionet", marionet_fid),
                     ("actor", 3.0), ("nearest_clip", 0.08)):
        cols = {"fid": list(fid + 0.05 * rng.normal(size=reps)),
                "acc": list(0.8 + 0.01 * rng.normal(size=reps))}
        if row in ("mann", "marionet", "actor"):  # deterministic Δ_Traj: identical replicates
            cols["traj_err"] = [0.2 if row != "marionet" else 0.1] * reps if traj_const else \
                list(0.2 + 0.01 * rng.normal(size=reps))
        per_row[row] = cols
    return _values(spec, per_row)


def _plan(scale: str, retrain: bool = False):
    spec = find_spec("marionette/table1")
    return spec, build_plan(spec, resolve_scale(scale, "bandai2-mini"), "bandai2-mini",
                            retrain=retrain)


def _claim(summary, cid):
    return next(c for c in summary["claims"] if c["id"] == cid)


def test_below_the_papers_budget_a_contradiction_is_not_a_refutation():
    spec, plan = _plan("quick")
    s = summarise(plan, _table1_values(spec, marionet_fid=4.0))
    c = _claim(s, "fid_best")
    assert c["posterior_verdict"] == "contradicted"
    assert c["verdict"] == NOT_REPRODUCED_BUDGET
    ev = c["evidence"]
    assert ev["variance"] == "sampling" and ev["min_budget"] < 0.05
    assert "sampling passes of one trained model" in ev["text"]
    assert "marionet" in ev["text"] and "%" in ev["text"]
    assert "evaluator: transformer seed 0" in ev["text"]
    # every evaluated claim carries an evidence line
    assert all(cl.get("evidence", {}).get("text") for cl in s["claims"]
               if cl["verdict"] != "not evaluated")


def test_paper_budget_with_retrain_may_read_contradicted_and_without_it_may_not():
    spec, plan = _plan("paper", retrain=True)
    vals = _table1_values(spec, marionet_fid=4.0)
    c = _claim(summarise(plan, vals), "fid_best")
    assert c["evidence"]["min_budget"] == pytest.approx(1.0)
    assert c["evidence"]["variance"] == "training" and c["verdict"] == "contradicted"
    assert "independent trainings" in c["evidence"]["text"] and "training-seed" in c["evidence"]["text"]
    spec, plan = _plan("paper", retrain=False)
    c = _claim(summarise(plan, vals), "fid_best")
    assert c["verdict"] == NOT_REPRODUCED_SAMPLING


def test_supported_claims_keep_their_verdict_with_the_evidence():
    spec, plan = _plan("quick")
    c = _claim(summarise(plan, _table1_values(spec, marionet_fid=1.0)), "fid_best")
    assert c["verdict"] == "supported" and c["probability"] > 0.95
    assert c["evidence"]["text"].startswith("variance:")


def test_a_deterministic_column_has_no_posterior_and_says_so_only_there():
    spec, plan = _plan("quick")
    s = summarise(plan, _table1_values(spec, marionet_fid=1.0))
    traj = _claim(s, "traj_best")
    assert traj["probability"] is None and traj["verdict"] == "supported"
    assert "traj_err: no spread in either row" in traj["reason"]
    assert "no posterior probability" in traj["reason"]
    for cid in ("fid_best", "acc_best"):
        assert "no spread" not in (_claim(s, cid).get("reason") or "")


def test_a_chain_that_does_not_mix_gives_inconclusive_in_a_table():
    spec, plan = _plan("quick")
    rng = np.random.default_rng(1)
    per_row = {r: {"fid": list((80.0 if r == "marionet" else 100.0)
                               + 1e-5 * rng.normal(size=10))} for r in ROWS}
    for r in ROWS:  # multimod 10^6 sds apart too: the "within" claim must not read a P
        per_row[r]["multimod"] = list((2.0 if r == "marionet" else 3.0)
                                      + 1e-7 * rng.normal(size=10))
    s = summarise(plan, _values(spec, per_row))
    c = _claim(s, "fid_best")
    assert c["verdict"] == "inconclusive" and "did not mix" in c["reason"]
    assert c["probability"] is None  # a chain that did not mix gives no P
    w = _claim(s, "multimod_close_to_mann")
    assert w["verdict"] == "inconclusive" and "did not mix" in w["reason"]


def test_budget_fraction_from_the_record_and_from_the_config():
    cfg = {"epochs": 10, "batch_size": 30}
    rec = {"history": [{"batches": 40}] * 10, "n_train": 1190}
    b = training_budget("marionet", cfg, rec)
    # paper: 1,000 epochs at batch 30 on the same 1,190 items (40 batches an epoch)
    assert b["steps"] == 400 and b["paper_steps"] == 40_000 and b["fraction"] == pytest.approx(0.01)
    assert not b["assumed"] and "supp. Sec. 3" in b["schedule"]
    assert training_budget("marionet", cfg, None)["fraction"] == pytest.approx(0.01)
    assert budget_text(b) == "marionet 1% (400 of 40,000 steps)"
    assert training_budget("nearest_clip", {"match_frames": None}, None) is None
    # MANN (drops the last partial batch): samples = batches × batch; the paper's batch 32 and
    # 150 epochs; an assumed schedule is marked
    m = training_budget("mann", {"epochs": 15, "batch_size": 256},
                        {"history": [{"batches": 10}] * 15, "n_train": 300})
    assert m["paper_steps"] == 150 * 80 and m["steps"] == 150 and m["assumed"]
    assert budget_text(m, short=True) == "mann 1.2%*"
    # Action2Motion's schedule is 50,000 iterations
    a = training_budget("a2m", {"epochs": 12, "batch_size": 64},
                        {"history": [{"batches": 35}] * 12, "n_train": 2200})
    assert a["paper_steps"] == 50_000 and a["steps"] == 420
    # just under the budget never prints as 100 %
    assert "<100%" in budget_text({**b, "fraction": 0.997, "steps": None})


def test_qualified_verdicts_and_epoch_scaling():
    ev = claim_evidence(rows=["a", "b"], budgets={"a": {"method": "m", "fraction": 0.5,
                                                        "epochs": 5, "paper_epochs": 10}},
                        retrain=True, replicates=3, evaluators=[])
    assert qualified_verdict("contradicted", ev) == NOT_REPRODUCED_BUDGET
    assert qualified_verdict("supported", ev) == "supported"
    assert qualified_verdict("inconclusive", ev) == "inconclusive"
    none = claim_evidence(rows=["real", "nearest_clip"], budgets={}, retrain=False,
                          replicates=3, evaluators=[])
    assert qualified_verdict("contradicted", none) == "contradicted"  # nothing trained
    full = {"method": "m", "fraction": 1.0, "epochs": 10, "paper_epochs": 10}
    for scale, retrain, want in (("paper", True, "contradicted"),
                                 ("paper", False, NOT_REPRODUCED_SAMPLING),
                                 ("medium", True, NOT_REPRODUCED_REDUCED)):
        ev = claim_evidence(rows=["a"], budgets={"a": full}, retrain=retrain, replicates=3,
                            evaluators=[], scale=scale)
        assert qualified_verdict("contradicted", ev) == want, (scale, retrain)
    unknown = claim_evidence(rows=["a", "b"], budgets={"a": full, "b": {**full, "fraction": None}},
                             retrain=True, replicates=3, evaluators=[], scale="paper")
    assert qualified_verdict("contradicted", unknown) == NOT_REPRODUCED_UNKNOWN
    cfg = {"epochs": 20, "ss_activate_epoch": 5, "ss_accomplish_epoch": 15, "lr": 1e-3}
    assert scale_epochs(cfg, 1) == cfg
    half = scale_epochs(cfg, 0.5)
    assert half == {"epochs": 10, "ss_activate_epoch": 3, "ss_accomplish_epoch": 8, "lr": 1e-3}
    assert scale_epochs({"epochs": 1}, 0.1)["epochs"] == 1
    # the warm-up survives a small factor; a one-cycle restart schedule stays one cycle
    assert scale_epochs(cfg, 0.1)["ss_activate_epoch"] == 1
    assert scale_epochs({"epochs": 15, "restart_period": 15}, 0.5) == {"epochs": 8,
                                                                       "restart_period": 8}


def test_every_render_format_prints_the_evidence():
    from repro.engine.table_view import make_view
    from repro.report import render

    spec, plan = _plan("quick")
    s = summarise(plan, _table1_values(spec, marionet_fid=4.0))
    view = make_view(spec, s["rows"], s, ["footer"], "bandai2-mini")
    for fmt in ("term", "md", "html", "latex", "json"):
        text = render(view, fmt)
        assert "decided by" in text or fmt == "json"
        assert "variance:" in text
        assert "not reproduced at this budget".upper() in text.upper()


def test_uncertain_paper_cells_are_marked():
    """Regression (issue 11, item 6): NM Table 1's Real FID "1" is marked uncertain in the
    spec; every view shows that mark and says what it means."""
    from repro.engine.table_view import make_view
    from repro.report import render

    spec, plan = _plan("quick")
    view = make_view(spec, {}, None, [], "bandai2-mini")
    real = next(r for r in view.rows if r.id == "real")
    assert real.cells["fid"].reported == "1?"
    assert real.cells["acc"].reported == "0.894"
    md = render(view, "md")
    assert "1?" in md and "uncertain in the PDF extraction" in md
    assert next(r for r in view.rows if r.id == "real").cells["nn_train_joint"].reported \
        == "not in paper"


def test_a_record_without_evidence_says_so():
    """A summary recorded before verdicts carried their evidence is shown with a line saying
    the evidence was not recorded, never as a bare verdict."""
    from repro.engine.table_view import NO_EVIDENCE, make_view
    from repro.report import render

    spec, plan = _plan("quick")
    s = summarise(plan, _table1_values(spec, marionet_fid=4.0))
    for c in s["claims"]:
        c.pop("evidence", None)
        c["verdict"] = c.pop("posterior_verdict")
    view = make_view(spec, s["rows"], s, [], "bandai2-mini")
    fid = next(c for c in view.claims if c.id == "fid_best")
    assert fid.verdict == "contradicted" and fid.evidence == NO_EVIDENCE
    assert "decided by: not recorded" in render(view, "md")


def test_the_evaluator_is_said_to_be_trained_on_the_runs_data_set():
    """A built-in stand-in is "the stand-in"; a data set a spec declares is named as own data
    (issue 28: never called a stand-in)."""
    from repro.engine.evidence import evaluator_text

    ev = {"kind": "transformer", "seed": 0}
    assert evaluator_text(ev).endswith("(trained by the harness on the stand-in)")
    assert evaluator_text(ev, "bandai2-mini").endswith("on the stand-in)")
    assert evaluator_text(ev, "lab-styles").endswith("on lab-styles (own data))")
    assert evaluator_text(ev, "humanact12").endswith("on humanact12)")  # a paper's data set
    assert evaluator_text(None, "lab-styles") is None


def test_a_metric_that_could_not_be_measured_decides_no_claim(tmp_path):
    """A NaN value (multimodality with one sample per class, repro.metrics.diversity) is no
    value: the cell is absent from the summary and a claim on it is "not evaluated"."""
    from repro.engine.steps import write_values

    spec, plan = _plan("quick")
    values = _table1_values(spec, marionet_fid=1.0)
    for row in ("mann", "a2m", "marionet", "actor"):
        values += [{**v, "column": "multimod", "metric": "multimod", "value": None}
                   for v in _values(spec, {row: {"multimod": [0.0] * 5}})]
    s = summarise(plan, values)
    assert all("multimod" not in cols for cols in s["cells"].values())
    c = _claim(s, "multimod_mann_best_of_three")
    assert c["verdict"] == "not evaluated" and c["probability"] is None
    assert "no reproduced values for row 'mann' in column 'multimod'" in c["reason"]

    # the job's values file: a NaN is written as no value
    ctx = SimpleNamespace(out=tmp_path)
    write_values(ctx, {"multimod": float("nan"), "fid": 1.5})
    got = json.loads(next(tmp_path.iterdir()).read_text())["values"]
    assert got == {"multimod": None, "fid": 1.5}
