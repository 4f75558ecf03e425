"""The real rows (intervals, n-APD = 100, determinism) and the real-data gate (it refuses to
score methods when the real row is off, saying why).  Fast: synthetic data."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import torch

from test_eval_classifiers import synthetic_clipset, tiny_settings


@pytest.fixture(scope="module")
def setup():
    from repro.eval.training import test_accuracy, train_evaluator

    torch.set_num_threads(1)
    cs = synthetic_clipset(n_per_class=16, n_classes=3, seed=5)
    s = tiny_settings(train={"epochs": 15})
    ev = train_evaluator(cs, "a2m_gru", s, seed=0)
    ev.meta["test"] = test_accuracy(ev, cs).to_dict()
    return cs, ev


@pytest.fixture(scope="module")
def rows(setup):
    from repro.eval.real import real_rows

    cs, ev = setup
    return real_rows("synthetic", "quick", replicates=4, seed=0, evaluator=ev, clipset=cs)


def test_real_rows_hold_values_and_intervals(rows, setup):
    from repro.stats.intervals import z_sd_sqrt_nm1

    cs, ev = setup
    real = rows["rows"]["real"]
    assert set(real) == {"fid_train", "fid_test", "accuracy", "accuracy_top5", "diversity",
                         "multimodality", "n_apd"}
    for name, m in real.items():
        assert len(m["values"]) == 4
        assert math.isclose(m["mean"], float(np.mean(m["values"])))
        lo, hi = m["ci"]
        assert lo <= m["mean"] + 1e-12 and m["mean"] <= hi + 1e-12, name
    fid = real["fid_train"]
    assert math.isclose(fid["pm"], z_sd_sqrt_nm1(fid["values"]))  # ODMO's 1.96·s/√(n−1)
    assert all(v >= -1e-9 for v in fid["values"])
    assert real["n_apd"]["values"] == [100.0] * 4  # real vs itself, ODMO's real row
    assert real["n_apd"]["pm"] == 0.0
    assert real["diversity"]["mean"] > real["multimodality"]["mean"]
    assert rows["evaluator"]["fingerprint"] == ev.fingerprint
    assert rows["per_class"] == 12 and rows["replicates"] == 4 and rows["n_classes"] == 3
    assert rows["evaluator"]["test_top1"] == ev.meta["test"]["top1"]


def test_real_rows_are_deterministic_and_seeded(rows, setup):
    from repro.eval.real import real_rows
    from repro.keys import canonical_json

    cs, ev = setup
    again = real_rows("synthetic", "quick", replicates=4, seed=0, evaluator=ev, clipset=cs)
    assert canonical_json(again) == canonical_json(rows)
    other = real_rows("synthetic", "quick", replicates=4, seed=1, evaluator=ev, clipset=cs)
    assert other["rows"]["real"]["fid_train"]["values"] != rows["rows"]["real"]["fid_train"]["values"]


def test_gate_passes_on_sane_real_rows(rows, setup):
    from repro.eval.gate import check_real_gate, gate_failures

    _, ev = setup
    assert gate_failures(rows, ev.meta["test"]) == []
    assert check_real_gate(rows, ev.meta["test"], 0.1) is None


def _planted(rows, **changes):
    bad = copy.deepcopy(rows)
    for metric, values in changes.items():
        m = bad["rows"]["real"][metric]
        m["values"] = values
        m["mean"] = float(np.mean(values))
    return bad


def test_gate_raises_on_low_real_accuracy(rows, setup):
    from repro.errors import ReproError
    from repro.eval.gate import RealGateError, check_real_gate

    _, ev = setup
    bad = _planted(rows, accuracy=[0.4, 0.5, 0.45, 0.42])
    with pytest.raises(RealGateError) as e:
        check_real_gate(bad, {"top1": 0.97}, 0.05)
    msg = str(e.value)
    assert isinstance(e.value, ReproError)
    assert "real accuracy 0.443 is below the classifier's test accuracy 0.970 minus the margin 0.050" in msg
    assert "synthetic" in msg and ev.fingerprint[:12] in msg and "not scored" in msg
    # within the margin it passes
    check_real_gate(_planted(rows, accuracy=[0.93] * 4), {"top1": 0.97}, 0.05)


def test_gate_names_every_failed_check(rows):
    from repro.eval.gate import RealGateError, check_real_gate

    bad = _planted(rows, fid_train=[9.0, 11.0, 10.0, 10.0], diversity=[0.1] * 4,
                   multimodality=[0.2] * 4, n_apd=[100.0, 99.0, 100.0, 100.0])
    with pytest.raises(RealGateError) as e:
        check_real_gate(bad, {"top1": 0.0}, 0.05, max_fid=1.0)
    reasons = e.value.reasons
    assert len(reasons) == 3  # FID, diversity, n-APD (the accuracy check passes)
    assert any("FID(train, test) 10.000 exceeds the bound 1.000" in r for r in reasons)
    assert any("diversity 0.100 is not above real multimodality 0.200" in r for r in reasons)
    assert any("n-APD is not 100" in r for r in reasons)
    with pytest.raises(RealGateError, match="non-finite"):
        check_real_gate(_planted(rows, diversity=[float("nan")] * 4), {"top1": 0.0}, 0.05)


def test_gate_uses_recorded_stats_and_bounds(rows):
    from repro.eval.gate import gate_failures

    # no explicit stats: the evaluator's test accuracy recorded in the rows is used
    low = _planted(rows, accuracy=[0.0] * 4)
    assert any("below the classifier's test accuracy" in r for r in gate_failures(low))
    # the recorded max_fid applies when none is passed
    far = _planted(rows, fid_train=[rows["gate"]["max_fid"] * 2] * 4)
    assert any("exceeds the bound" in r for r in gate_failures(far, {"top1": 0.0}))
