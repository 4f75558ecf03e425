"""repro sweep (issue 11, items 2 and 4): axes, classes of a claim along them, the record."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from repro.engine.sweep import build_record, classify_budget, parse_factors, render_sweep
from repro.errors import ConfigError
from repro.specs.load import find_spec


def test_parse_factors():
    assert parse_factors("0.5,1,2,4") == (0.5, 1.0, 2.0, 4.0)
    for bad in ("", "0", "-1", "1,1", "x", "nan", ",".join(["1"] * 13)):
        with pytest.raises(ConfigError, match="--budget"):
            parse_factors(bad)


def test_classify_budget():
    assert classify_budget(["inconclusive"] * 4) == "stable"
    assert classify_budget(["inconclusive", "inconclusive", "supported", "supported"]) == \
        "converging"
    assert classify_budget(["supported", "inconclusive", "supported"]) == "flipping"


def _summary(fid_marionet: float, verdict: str, p: float, fraction: float) -> dict:
    return {"cells": {"marionet": {"fid": {"mean": fid_marionet, "bootstrap_percentile": [
        fid_marionet - 0.1, fid_marionet + 0.1], "n": 3}},
                      "mann": {"fid": {"mean": 2.0, "bootstrap_percentile": [1.9, 2.1], "n": 3}}},
            "claims": [{"id": "fid_best", "verdict": verdict, "probability": p,
                        "posterior_verdict": verdict}],
            "budgets": {"marionet": {"method": "marionet", "fraction": fraction, "epochs": 10,
                                     "paper_epochs": 1000, "steps": None, "paper_steps": None}}}


def _plan():
    spec = find_spec("marionette/table1")
    return SimpleNamespace(spec=spec, scale=SimpleNamespace(name="quick"), dataset="bandai2-mini",
                           retrain=False, seeds=(0, 1, 2))


def test_budget_record_and_render():
    runs = [(0.5, _plan(), _summary(3.0, "not reproduced at this budget", 0.01, 0.005), "r1"),
            (1.0, _plan(), _summary(2.2, "inconclusive", 0.3, 0.01), "r2"),
            (2.0, _plan(), _summary(1.5, "supported", 0.99, 0.02), "r3")]
    rec = build_record("budget", runs)
    assert rec["points"] == [0.5, 1.0, 2.0] and rec["runs"] == ["r1", "r2", "r3"]
    assert rec["claims"]["fid_best"]["along_budget"] == "flipping"
    assert [p["mean"] for p in rec["cells"]["marionet"]["fid"]] == [3.0, 2.2, 1.5]
    md = render_sweep(rec)
    assert "×0.5" in md and "×2" in md and "flipping" in md and "0.5%" in md
    assert "marionet better than mann, a2m, actor on fid" in md


def test_evaluator_record_spread_and_holds_under_all():
    runs = [(s, _plan(), _summary(1.0 + 0.1 * s, "supported", 0.99, 0.01), f"r{s}")
            for s in (0, 1, 2)]
    rec = build_record("evaluator_seed", runs)
    cell = rec["cells"]["marionet"]["fid"]
    assert cell["range"] == pytest.approx(0.2) and cell["sd"] == pytest.approx(0.1)
    assert rec["claims"]["fid_best"]["under_evaluators"] == "holds under all"
    runs[1] = (1, _plan(), _summary(1.1, "inconclusive", 0.5, 0.01), "r1")
    assert build_record("evaluator_seed", runs)["claims"]["fid_best"]["under_evaluators"] == \
        "depends on the evaluator"
    assert "seed 2" in render_sweep(build_record("evaluator_seed", runs))


def test_sweep_cli_refuses_bad_axes_before_running(tmp_path, monkeypatch):
    import subprocess
    import sys

    env = {"REPRO_HOME": str(tmp_path), "PATH": "/usr/bin:/bin"}
    r = subprocess.run([sys.executable, "-m", "cli.main", "sweep", "marionette/table1",
                        "--budget", "0,1"], capture_output=True, text=True, env=env)
    assert r.returncode == 2 and "--budget" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([sys.executable, "-m", "cli.main", "sweep", "marionette/table1"],
                       capture_output=True, text=True, env=env)
    assert r.returncode == 2 and "one of the arguments" in r.stderr


def test_plateau_point_parses_last_and_resolves_a_plateau_schedule():
    from repro.engine.sweep import PLATEAU, _ordered
    from repro.specs.scales import resolve_scale, until_override

    assert parse_factors("plateau,1,2") == (1.0, 2.0, PLATEAU)
    assert _ordered([PLATEAU, 2.0, 0.5]) == [0.5, 2.0, PLATEAU]
    for bad in ("plateau,plateau", "plateau,x"):
        with pytest.raises(ConfigError, match="--budget"):
            parse_factors(bad)
    assert resolve_scale("quick").schedule is None
    with until_override(PLATEAU):
        sched = resolve_scale("quick").schedule
    assert sched["until"] == "plateau" and sched["tolerance"] == 0.01
    assert resolve_scale("quick").schedule is None
    assert resolve_scale("converged").schedule["max_minutes"] == 20.0
