"""The convergence rule (issue 32, item 1) on planted curves, and training until it fires
(item 2): the loop stops at the rule's epoch and a killed run resumes to the same bytes."""

import math

import numpy as np
import pytest
import torch

from repro.train.loop import Stopping, train, use_stopping
from repro.train.plateau import PlateauRule, convergence_record, fires_at, plateau_epoch, window


def _hist(values, metric="val_loss"):
    return [{"epoch": i, metric: float(v)} for i, v in enumerate(values)]


def test_still_falling_never_fires():
    # 5 % better every epoch: every window improves by far more than 1 %
    assert plateau_epoch(_hist(0.95 ** np.arange(80)), PlateauRule()) is None
    # a slow fall of 0.5 % per epoch still improves > 1 % over any 5-epoch window
    assert plateau_epoch(_hist(0.995 ** np.arange(80)), PlateauRule()) is None


def test_flat_fires_as_soon_as_two_windows_fit():
    e = plateau_epoch(_hist([1.0] * 30), PlateauRule())
    # smoothing needs 3 epochs (first smoothed value at epoch 2), then two 5-epoch windows
    assert e == 2 + 2 * 5 - 1


def test_flat_at_zero_fires():
    assert plateau_epoch(_hist([0.0] * 30), PlateauRule()) == 11


def test_rising_fires():
    e = plateau_epoch(_hist(list(0.8 ** np.arange(10)) + list(0.8 ** 9 * 1.02 ** np.arange(1, 30))),
                      PlateauRule())
    assert e is not None and 12 <= e <= 20


def test_noisy_flat_fires_and_stays_converged():
    rng = np.random.default_rng(0)
    curve = list(2.0 * 0.7 ** np.arange(15) + 1.0)
    noisy = curve + list(1.0 + 0.004 * rng.standard_normal(45))
    e = plateau_epoch(_hist(noisy), PlateauRule())
    assert e is not None and 15 <= e <= 35
    rec = convergence_record(_hist(noisy), PlateauRule())
    assert rec["converged"] is True and rec["converged_epoch"] == e


def _best_vs_best(values, tol=0.01):
    """The rule's first reading (best smoothed value before the window against the best in
    it): kept here to show what the window means fix."""
    s = np.convolve(values, np.ones(3) / 3, mode="valid")
    for e in range(len(s)):
        w = max(5, math.ceil(0.2 * (e + 3)))
        if e - w < 0:
            continue
        before, inside = s[: e - w + 1].min(), s[e - w + 1: e + 1].min()
        if before - inside < tol * abs(before):
            return e
    return None


@pytest.mark.parametrize("seed", range(6))
def test_noisy_still_falling_does_not_fire(seed):
    # 0.6 % better per epoch (3 % per 5-epoch window, more per longer one) under 1.5 % noise:
    # still learning.  One lucky epoch makes the best-vs-best reading fire early; window means
    # do not.
    rng = np.random.default_rng(seed)
    values = 0.994 ** np.arange(100) * (1.0 + 0.015 * rng.standard_normal(100))
    assert plateau_epoch(_hist(values), PlateauRule()) is None
    if seed == 0:
        assert _best_vs_best(values) is not None


@pytest.mark.parametrize("seed", range(6))
def test_a_spike_at_the_end_of_a_falling_curve_does_not_fire(seed):
    # 1 % better per epoch, then three bad epochs: window means read the spike as "no
    # improvement" and fire; medians, which the default rule also requires, do not move
    rng = np.random.default_rng(seed)
    values = 0.99 ** np.arange(60) * (1.0 + 0.005 * rng.standard_normal(60))
    values[-3:] *= 2.0  # as MACVAE's val_kl did (243 -> 528)
    h = _hist(values)
    assert fires_at(h, PlateauRule(statistic="mean"), 59)
    assert not fires_at(h, PlateauRule(), 59)
    assert not fires_at(h, PlateauRule(statistic="median"), 59)


@pytest.mark.parametrize("seed", range(6))
def test_noisy_still_falling_needs_the_means_too(seed):
    # medians alone are noisier than means: on a curve still falling under Gaussian noise they
    # can fire early; the default rule fires only when both agree, so it never fires earlier
    # than the mean reading
    rng = np.random.default_rng(seed)
    values = 0.994 ** np.arange(100) * (1.0 + 0.015 * rng.standard_normal(100))
    h = _hist(values)
    both = plateau_epoch(h, PlateauRule())
    assert both is None or both >= (plateau_epoch(h, PlateauRule(statistic="mean")) or 0)


def test_the_recorded_macvae_curve_that_fired_on_a_kl_spike_no_longer_fires():
    """multiact/table2's first converged record: MACVAE's rule (val_loss, val_kl two-sided)
    fired at epoch 63 under window means, in the middle of a jump of both quantities
    (val_kl 243 -> 528 over epochs 61-63); medians see the KL still falling."""
    import json

    from repro.paths import repo_root

    rec = repo_root() / "docs" / "results" / "converged" / "20261206T211808.145Z-e0a5bd"
    tr = next(t["training"] for t in json.loads((rec / "trainings.json").read_text())["trainings"]
              if t["method"] == "macvae")
    rule = dict(tr["convergence"]["rule"], also=tuple(tr["convergence"]["rule"]["also"]))
    assert tr["convergence"]["converged_epoch"] == 63  # as recorded, under means
    assert plateau_epoch(tr["history"], PlateauRule(**rule, statistic="mean")) == 63
    assert plateau_epoch(tr["history"], PlateauRule(**rule)) is None


def test_falls_then_plateaus_fires_after_the_knee():
    curve = [max(0.3, 1.0 - 0.05 * i) for i in range(60)]   # flat from epoch 14
    e = plateau_epoch(_hist(curve), PlateauRule())
    assert e is not None and 14 < e <= 14 + 2 + 2 * window(PlateauRule(), e + 1)


def test_converged_means_the_rule_holds_at_the_last_epoch():
    # flat for 20 epochs, then a second descent (a fixed-epoch record read afterwards)
    curve = [1.0] * 20 + list(0.9 ** np.arange(1, 21))
    rec = convergence_record(_hist(curve), PlateauRule())
    assert rec["converged_epoch"] == 11 and rec["converged"] is False
    from repro.report.curves import convergence_line

    line = convergence_line({"convergence": rec, "until": "epochs"})
    assert line.startswith("not converged at its last epoch") and "epoch 11" in line


def test_window_grows_with_the_run():
    r = PlateauRule()
    assert window(r, 10) == 5 and window(r, 25) == 5 and window(r, 26) == 6 and window(r, 100) == 20


def test_start_epoch_and_metric_and_nan():
    flat = _hist([1.0] * 30, metric="val_mpjpe")
    assert plateau_epoch(flat, PlateauRule()) is None           # reads val_loss: absent
    assert plateau_epoch(flat, PlateauRule(metric="val_mpjpe")) == 11
    assert plateau_epoch(flat, PlateauRule(metric="val_mpjpe", start_epoch=10)) == 21
    with_nan = _hist([1.0] * 6 + [math.nan] * 30)
    assert plateau_epoch(with_nan, PlateauRule()) is None


def test_a_rule_on_two_quantities_fires_when_both_do():
    rule = PlateauRule(also=("val_kl",))
    flat_loss_falling_kl = [{"val_loss": 1.0, "val_kl": 0.9 ** i} for i in range(40)]
    assert plateau_epoch(flat_loss_falling_kl, rule) is None
    assert plateau_epoch(flat_loss_falling_kl, PlateauRule()) == 11
    both = [{"val_loss": 1.0, "val_kl": 0.9 ** min(i, 20)} for i in range(60)]
    e = plateau_epoch(both, rule)
    assert e is not None and e > 20
    assert "val_kl changed < 1% either way" in convergence_record(both, rule)["criterion"]
    # a KL still rising (posteriors drifting from the prior) holds the rule back too
    rising_kl = [{"val_loss": 1.0, "val_kl": 1.02 ** i} for i in range(60)]
    assert plateau_epoch(rising_kl, rule) is None
    assert plateau_epoch(rising_kl, PlateauRule()) == 11


def test_a_gate_counts_only_epochs_where_it_is_one():
    rule = PlateauRule(gate="val_ss_active")
    hist = [{"val_loss": 1.0, "val_ss_active": 1.0 if i >= 8 else 0.5} for i in range(40)]
    assert plateau_epoch(hist, rule) == 8 + 11
    hist[25]["val_ss_active"] = 0.75   # one held-out batch fell back to teacher forcing
    e = plateau_epoch(hist, rule)
    assert e == 8 + 11 and not convergence_record(hist[:27], rule)["converged"]


def test_a_method_without_a_rule_never_converges():
    rule = PlateauRule(metric=None)
    rec = convergence_record(_hist([1.0] * 40), rule)
    assert rec["converged"] is False and rec["converged_epoch"] is None
    assert rec["criterion"].startswith("none:")


def test_method_rules():
    from repro.models.base import generator_class

    def rule_of(method_id, **cfg):
        cls = generator_class(method_id)
        gen = cls.__new__(cls)
        gen.config = cls.Config(**cfg)
        return gen.plateau_rule()

    r = rule_of("marionet", ss_activate_epoch=3, ss_accomplish_epoch=10)
    assert (r.metric, r.gate, r.start_epoch) == ("val_loss", "val_ss_active", 10)
    assert rule_of("marionet", scheduled_sampling=False) == PlateauRule()
    assert rule_of("macvae").metrics == ("val_loss", "val_kl")
    assert rule_of("actor").metrics == ("val_loss", "val_kl")
    assert rule_of("act_mocogan").metrics == ()
    assert rule_of("odmo", tf_decay_epochs=20).start_epoch == 20


def test_rule_settings_are_checked():
    with pytest.raises(ValueError):
        PlateauRule(tolerance=0.0)
    r = PlateauRule(metric="val_mpjpe", start_epoch=3).with_settings(
        {"until": "plateau", "tolerance": 0.05, "min_window": 7, "max_minutes": 3})
    assert (r.metric, r.start_epoch, r.tolerance, r.min_window) == ("val_mpjpe", 3, 0.05, 7)


# ------------------------------------------------------------------ the loop, until the plateau
def _setup():
    torch.manual_seed(123)
    model = torch.nn.Sequential(torch.nn.Linear(4, 8), torch.nn.Tanh(), torch.nn.Linear(8, 1))
    opt = torch.optim.Adam(model.parameters(), lr=3e-2)
    X = torch.linspace(-1, 1, 64 * 4).reshape(64, 4)
    y = X.sum(1, keepdim=True) ** 2

    def batches(epoch, gen):
        perm = torch.randperm(64, generator=gen)
        for i in range(0, 64, 16):
            idx = perm[i:i + 16]
            yield X[idx], y[idx]

    def step(m, batch, epoch):
        xb, yb = batch
        return {"loss": torch.nn.functional.mse_loss(m(xb), yb)}

    def validate(m, epoch):
        return {"loss": torch.nn.functional.mse_loss(m(X), y)}

    return model, opt, batches, step, validate


def _weights(m):
    return torch.cat([p.detach().flatten() for p in m.parameters()])


def test_train_until_plateau_stops_at_the_rules_epoch_and_resumes_bitwise(tmp_path):
    cfg = {"what": "toy regression until a plateau"}
    rule = PlateauRule()
    m, o, b, s, v = _setup()
    full = train(m, o, batches=b, step=s, validate=v, epochs=300, seed=3, config=cfg)
    fired = plateau_epoch(full.history, rule)
    assert full.stopped_by == "epochs" and fired is not None and fired < 250

    m1, o1, b, s, v = _setup()
    with use_stopping(Stopping(rule)):
        res = train(m1, o1, batches=b, step=s, validate=v, epochs=300, seed=3, config=cfg,
                    ckpt_dir=tmp_path / "a")
    assert res.stopped_by == "plateau" and len(res.history) == fired + 1
    assert res.history == full.history[: fired + 1]

    # killed half-way (a checkpoint after `fired // 2` epochs), then the same command again
    m2, o2, b, s, v = _setup()
    with use_stopping(Stopping(rule)):
        train(m2, o2, batches=b, step=s, validate=v, epochs=fired // 2 + 1, seed=3, config=cfg,
              ckpt_dir=tmp_path / "b")
    m3, o3, b, s, v = _setup()
    with use_stopping(Stopping(rule)):
        again = train(m3, o3, batches=b, step=s, validate=v, epochs=300, seed=3, config=cfg,
                      ckpt_dir=tmp_path / "b")
    assert again.resumed_from == fired // 2 + 1 and again.stopped_by == "plateau"
    assert torch.equal(_weights(m3), _weights(m1)) and again.history == res.history

    # a finished run started again reads its checkpoint and trains no further epoch
    m4, o4, b, s, v = _setup()
    with use_stopping(Stopping(rule)):
        done = train(m4, o4, batches=b, step=s, validate=v, epochs=300, seed=3, config=cfg,
                     ckpt_dir=tmp_path / "a")
    assert done.resumed_from == fired + 1 and len(done.history) == fired + 1
    assert torch.equal(_weights(m4), _weights(m1))


def test_time_cap_and_no_validation():
    m, o, b, s, v = _setup()
    with use_stopping(Stopping(PlateauRule(), max_seconds=0.0)):
        res = train(m, o, batches=b, step=s, validate=v, epochs=50, seed=3, config={})
    assert res.stopped_by == "time" and len(res.history) == 1
    m, o, b, s, _ = _setup()  # no validation: the rule has nothing to read and never fires
    with use_stopping(Stopping(PlateauRule())):
        res = train(m, o, batches=b, step=s, epochs=12, seed=3, config={})
    assert res.stopped_by == "epochs" and len(res.history) == 12


# ------------------------------------------------------------ records, evidence and verdicts
def _training(row, until, converged, epochs=20, stopped_by="plateau"):
    hist = [{"epoch": i, "val_loss": 1.0, "batches": 3} for i in range(epochs)]
    return {"row": row, "training": {"until": until, "epochs": 80, "history": hist,
                                     "convergence": {"converged": converged,
                                                     "converged_epoch": epochs - 1 if converged else None,
                                                     "criterion": "val_loss improved < 1%",
                                                     "stopped_by": stopped_by}}}


def test_row_convergence_counts_only_trainings_run_until_the_plateau():
    from repro.engine.tables import row_convergence

    conv = row_convergence([_training("a", "plateau", True), _training("a", "plateau", False,
                                                                         stopped_by="time"),
                            _training("b", "epochs", True, stopped_by="epochs"),
                            {"row": "nn", "training": {"epochs": None, "history": []}}])
    assert conv["a"]["trainings"] == 2 and conv["a"]["converged"] == 1
    assert conv["b"]["converged"] == 0 and conv["b"]["plateau_runs"] == 0
    assert "nn" not in conv


def test_verdicts_at_convergence():
    from repro.engine.evidence import NOT_REPRODUCED_BUDGET, claim_evidence, qualified_verdict
    from repro.engine.tables import row_convergence

    budgets = {"a": {"method": "m", "fraction": 0.01, "epochs": 20, "paper_epochs": 1000},
               "b": {"method": "n", "fraction": 0.02, "epochs": 20, "paper_epochs": 1000}}

    def ev(trainings, retrain=True, rows=("a", "b"), dataset="bandai2"):
        return claim_evidence(rows=list(rows), budgets=budgets, retrain=retrain, replicates=3,
                              evaluators=[], scale="converged",
                              convergence=row_convergence(trainings), dataset=dataset)

    both = [_training("a", "plateau", True), _training("b", "plateau", True)]
    e = ev(both)
    assert e["converged"] is True and "every training at its plateau" in e["text"]
    assert "at the converged profile's widths, smaller than the papers'" in e["text"]
    assert qualified_verdict("contradicted", e) == "contradicted at convergence on the stand-in"
    assert qualified_verdict("supported", e) == "supported at convergence on the stand-in"
    assert qualified_verdict("inconclusive", e) == "inconclusive"
    assert qualified_verdict("supported", ev(both, retrain=False)) == \
        "supported at convergence on the stand-in (sampling variance only)"
    # one training per row cannot contradict: another seed could reverse the ordering
    assert qualified_verdict("contradicted", ev(both, retrain=False)) == \
        "not reproduced at convergence on the stand-in (sampling variance only)"
    # one row cut by the time cap: as before (the budget decides a contradiction)
    half = [_training("a", "plateau", True), _training("b", "plateau", False, stopped_by="time")]
    e = ev(half)
    assert e["converged"] is False and "the time cap" in e["text"]
    assert qualified_verdict("contradicted", e) == NOT_REPRODUCED_BUDGET
    assert qualified_verdict("supported", e) == "supported"
    # fixed epochs whose rule fired: not "at convergence" (baselines' verdicts keep meaning)
    fixed = [_training("a", "epochs", True, stopped_by="epochs"),
             _training("b", "epochs", True, stopped_by="epochs")]
    e = ev(fixed)
    assert e["converged"] is False and "a fixed number of epochs" in e["text"]
    assert qualified_verdict("supported", e) == "supported"
    # no trained row: None
    assert ev(both, rows=("real",))["converged"] is None
    # the evaluators of a converged comparison are named as trained for fixed epochs
    from repro.engine.tables import row_convergence as rc

    with_eval = claim_evidence(rows=["a", "b"], budgets=budgets, retrain=True, replicates=3,
                               evaluators=["transformer seed 0 (trained on the stand-in)"],
                               scale="converged", convergence=rc(both), dataset="bandai2")
    assert "evaluators below are trained for their profile's fixed number of epochs" in \
        with_eval["text"]


def test_curve_text_says_when_the_rule_fired():
    from repro.report.curves import format_learning_curve

    t = _training("a", "plateau", True)["training"]
    lines = format_learning_curve(t)
    assert "epochs 20 of a cap of 80" in lines[-2]
    assert lines[-1].startswith("converged at epoch 19") and "trained until the plateau" in lines[-1]
    old = dict(t)
    del old["convergence"]
    assert not format_learning_curve(old)[-1].startswith("converged")


def test_train_jobs_carry_the_schedule_only_when_training_until_the_plateau():
    from repro.engine.table_plan import build_plan
    from repro.specs.load import find_spec
    from repro.specs.scales import resolve_scale

    spec = find_spec("multiact/table2")

    def train_configs(scale):
        plan = build_plan(spec, resolve_scale(scale, "bandai2-mini"))
        return [j.config for rp in plan.rows for js in rp.train.values() for j in js]

    quick = train_configs("quick")
    conv = train_configs("converged")
    assert quick and all("schedule" not in c for c in quick)
    assert conv and all(c["schedule"]["until"] == "plateau" for c in conv)
    caps = {c["method"]: c["schedule"]["max_minutes"] for c in conv}
    assert caps == {"macvae": 60.0, "actor": 240.0}  # their own caps (method_max_minutes)
    assert all("method_max_minutes" not in c["schedule"] for c in conv)


def test_a_method_cap_changes_only_that_methods_schedule(tmp_path):
    from repro.specs.scales import resolve_scale, scales_path

    text = scales_path().read_text()
    conv = resolve_scale("converged")
    assert conv.schedule_for("marionet")["max_minutes"] == 300.0
    assert conv.schedule_for("odmo")["max_minutes"] == 20.0
    assert resolve_scale("quick").schedule_for("marionet") is None
    # without the table, every method's schedule is the profile's, as before the option
    plain = tmp_path / "scales.toml"
    plain.write_text(text.replace("method_max_minutes = {", "# method_max_minutes = {"))
    sched = resolve_scale("converged", path=plain).schedule_for("marionet")
    assert sched["max_minutes"] == 20.0 and "method_max_minutes" not in sched
    assert sched == resolve_scale("converged", path=plain).schedule_for("odmo")


def test_a_misspelt_method_in_the_caps_is_named_with_a_suggestion(tmp_path):
    from repro.specs.load import SpecValidationError
    from repro.specs.scales import resolve_scale, scales_path

    bad = tmp_path / "scales.toml"
    bad.write_text(scales_path().read_text().replace("marionet = 300.0", "marionett = 300.0"))
    with pytest.raises(SpecValidationError) as err:
        resolve_scale("converged", path=bad)
    assert "method_max_minutes: unknown method 'marionett' (did you mean 'marionet'?)" in \
        str(err.value)
