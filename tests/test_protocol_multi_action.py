"""The ``multi_action`` and ``ss_ar`` protocols (Neural Marionette Tables 3-5, Figs 8 and 10)
on bandai2-mini with a tiny heading-free recogniser: test-set construction (supp. §4.2), the
chained pure generative pipeline (supp. Alg. 1), the columns, and the NEURAL MARIONETTE
pipeline."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from repro.errors import ConfigError
from repro.eval.protocols import get_protocol
from repro.models.base import generator_class

S, L = 6, 4


def tiny_settings():
    from repro.eval.settings import resolve_settings

    return resolve_settings("quick", {
        "window": 40, "heading": "remove",
        "transformer": {"d_model": 32, "heads": 2, "layers": 1, "ff": 64, "dropout": 0.0},
        "train": {"epochs": 20, "windows_per_epoch": 256, "batch_size": 128, "lr": 3e-3,
                  "checkpoint_every": 10}})


class Spy:
    """Wraps a generator and records every condition batch it was given."""

    method_id = "spy"

    def __init__(self, gen):
        self.gen, self.calls = gen, []

    def sample(self, cond, *, seed, use_mean=False):
        out = self.gen.sample(cond, seed=seed, use_mean=use_mean)
        self.calls.append((cond, out))
        return out


@pytest.fixture(scope="module")
def setup():
    from repro.data.registry import load_clipset
    from repro.eval.training import train_evaluator

    torch.set_num_threads(1)
    clips = load_clipset("bandai2-mini")
    proto = get_protocol("multi_action", {"sequences": S, "actions_per_sequence": L,
                                          "candidate_confidence": 0.3})
    sc = proto.split_clipset(clips)
    train, test = proto.train_items(clips), proto.test_items(clips)
    ev = train_evaluator(sc, proto.evaluator_kind, tiny_settings(), seed=0)
    gen = generator_class("nearest_clip")(None, sc.skeleton, sc.n_classes, sc.fps)
    gen.fit(train, seed=0)
    return {"clips": clips, "proto": proto, "train": train, "test": test, "ev": ev, "gen": gen}


def test_params_and_registry():
    p = get_protocol("multi_action", {})
    assert p.params.sequences == 764 and p.params.actions_per_sequence == 20
    assert p.params.score_from_action == 2 and p.params.candidate_confidence == 0.5
    assert p.evaluator_heading == "remove"
    assert get_protocol("ss_ar", {}).params.pipeline == "neural_marionette"
    with pytest.raises(ConfigError):
        get_protocol("multi_action", {"test_set": "sometimes"})


@pytest.mark.parametrize("which", ["overall", "sufficient"])
def test_test_sets_follow_supp_4_2(setup, which):
    proto = get_protocol("multi_action", {**setup["proto"].params.model_dump(),
                                          "test_set": which})
    items, ev, clips = setup["test"], setup["ev"], setup["clips"]
    ts = proto.test_set(clips, items, ev)
    assert ts.actions.shape == (S, L)
    cand = set(ts.candidates.tolist())
    assert set(ts.actions.reshape(-1).tolist()) <= cand           # every action is a candidate
    assert (ts.confidence[ts.candidates] >= 0.3).all()
    assert (np.delete(ts.confidence, ts.candidates) < 0.3).all()
    labels, own_next = items.labels.numpy(), items.next_labels.numpy()
    counts = proto.transition_counts(clips)
    has = {int(labels[c]) for c in cand}
    for s in range(S):
        for i in range(1, L):
            a, b = labels[ts.actions[s, i - 1]], labels[ts.actions[s, i]]
            if which == "overall":
                ok = counts[a, b] > 0 or not any(counts[a, t] > 0 and t in has
                                                 for t in range(len(counts)))
            else:
                conn = np.flatnonzero(counts[a] > 0)
                top = conn[np.argsort(-counts[a, conn], kind="stable")][:4]
                ok = b in set(top.tolist()) | {a, own_next[ts.actions[s, i - 1]]}
            assert ok, (s, i, a, b)
            assert ts.next_labels[s, i - 1] == b                    # conditioning next tag
        assert ts.next_labels[s, -1] == labels[ts.actions[s, -1]]  # last: its own tag
    again = proto._build_test_set(clips, items, ev)
    assert np.array_equal(again.actions, ts.actions)              # deterministic


def test_chain_follows_alg_1(setup):
    proto, items, ev, clips = setup["proto"], setup["test"], setup["ev"], setup["clips"]
    spy = Spy(setup["gen"])
    out = proto.generate(spy, items, seed=0, replicate=0, evaluator=ev, clipset=clips)
    ts = proto.test_set(clips, items, ev)
    assert len(spy.calls) == L and len(out) == S * L
    K = items.n_init
    first = torch.from_numpy(ts.actions[:, 0])
    c0, _ = spy.calls[0]
    # action 1 starts from the real previous motion of the first candidate
    assert torch.allclose(c0.initial_world().root, items.initial_world().select(first).root,
                          atol=1e-5)
    for i in range(1, L):
        cond, _ = spy.calls[i]
        _, prev = spy.calls[i - 1]
        Lp = prev.lengths
        for s in range(S):
            want = prev.motion.root[s, Lp[s] - K:Lp[s]] if Lp[s] >= K else None
            if want is not None:  # the next initial motion is the last K generated frames
                assert torch.allclose(cond.initial_world().root[s], want, atol=1e-4)
        idx = torch.from_numpy(ts.actions[:, i])
        assert torch.equal(cond.labels, items.labels[idx])
        assert torch.equal(cond.lengths, items.lengths[idx])
        assert torch.equal(cond.next_labels, torch.from_numpy(ts.next_labels[:, i]))
    # samples are sequence-major and equal the generator's outputs
    _, o2 = spy.calls[2]
    T = int(o2.lengths.max())
    assert torch.allclose(out.motion.root[2::L][:, :T], o2.motion.root[:, :T])


def test_measure_columns_and_round_trip(setup, tmp_path):
    from repro.metrics.transitions import pose_gap

    proto, items, ev, clips = setup["proto"], setup["test"], setup["ev"], setup["clips"]
    out = proto.generate(setup["gen"], items, seed=0, replicate=1, evaluator=ev, clipset=clips)
    path = proto.save_generated(out, tmp_path / "g.npz")
    back = proto.load_generated(path)
    assert torch.equal(back.motion.root, out.motion.root) and back.test_set_key == out.test_set_key
    vals = proto.measure(back, items, ev, seed=0, clipset=clips)
    for m in ("acc", "fid", "pose_gap", "vel_gap", "action_qr", "motion_qr"):
        assert np.isfinite(vals[m]), m
    for x in range(1, L + 1):
        assert f"acc@{x}" in vals and f"motion_qr@{x}" in vals and f"fid@{x}" in vals
    assert "pose_gap@1" not in vals and "pose_gap@2" in vals
    # Δ_pose at action 2 is the mean over sequences of the junction's per-joint distance
    j = back.joints().numpy()
    lens = back.lengths.numpy()
    prev = [j[s * L + 0, :lens[s * L]] for s in range(S)]
    cur = [j[s * L + 1, :lens[s * L + 1]] for s in range(S)]
    assert vals["pose_gap@2"] == pytest.approx(pose_gap(prev, cur), rel=1e-6)
    # averages run from action 2: acc is the mean of acc@2..acc@L
    assert vals["acc"] == pytest.approx(np.mean([vals[f"acc@{x}"] for x in range(2, L + 1)]))
    # the Motion QR curve can only fall
    mq = [vals[f"motion_qr@{x}"] for x in range(1, L + 1)]
    assert all(a >= b for a, b in zip(mq, mq[1:]))
    real = proto.real_replicate(clips, items, ev, seed=0, replicate=0)
    assert set(real) >= {"acc", "fid", "action_qr", "motion_qr"} and "pose_gap" not in real
    # harness columns (issue 11): over the scored actions; the real row's nearest-training
    # distance is clearly above zero (test actions are not training actions)
    for m in ("nn_train_feat", "nn_train_joint", "precision", "recall", "density", "coverage"):
        assert np.isfinite(vals[m]), m
    assert real["nn_train_joint"] > 0.02 and "precision" not in real
    off = proto.__class__(proto.params.model_copy(update={"memorisation": False}))
    plain = off.measure(back, items, ev, seed=0, clipset=clips)
    assert "nn_train_joint" not in plain and plain["fid"] == vals["fid"]


def test_test_set_record_is_what_the_drawn_test_set_holds(setup):
    """``test_sets`` of a table's JSON (issue 26): test_set_stats of the drawn chains' tags
    against the training counts, keyed by the set; deterministic; no generator involved."""
    from repro.data.tag_chains import test_set_stats

    items, ev, clips = setup["test"], setup["ev"], setup["clips"]
    C = items.n_classes
    for which in ("overall", "sufficient"):
        proto = get_protocol("multi_action", {**setup["proto"].params.model_dump(),
                                              "test_set": which})
        rec = proto.test_set_record(clips, ev)
        assert list(rec) == [which]
        r = rec[which]
        ts = proto.test_set(clips, items, ev)
        counts = proto.transition_counts(clips)
        tags = items.labels.numpy()[ts.actions]
        assert r == {**test_set_stats(tags, counts, C), "candidates": int(ts.candidates.size),
                     "classes": list(items.label_names), "test_set_key": ts.key()}
        share = np.asarray(r["class_share_by_position"])
        assert share.shape == (L, C) and np.allclose(share.sum(1), 1.0, atol=1e-3)
        assert (r["chains"], r["length"]) == (S, L)
        support = counts[tags[:, :-1], tags[:, 1:]]
        assert r["unseen_share"] == pytest.approx(float((support == 0).mean()), abs=1e-4)
        assert r["median_support"] == float(np.median(support))
        assert proto.test_set_record(clips, ev) == rec             # deterministic
    # ss_ar scores Table 3's overall set, so it records the same chains
    ss = get_protocol("ss_ar", {**setup["proto"].params.model_dump(), "test_set": "overall"})
    mo = get_protocol("multi_action", {**setup["proto"].params.model_dump(),
                                       "test_set": "overall"})
    assert ss.test_set_record(clips, ev) == mo.test_set_record(clips, ev)


def test_ss_ar_runs_neural_marionette_with_the_evaluator_as_f_c(setup):
    from repro.models.marionet import MarioNet

    clips, items, ev = setup["clips"], setup["test"], setup["ev"]
    params = {**setup["proto"].params.model_dump(), "pipeline": "neural_marionette"}
    asked = []

    def factory(kind, seed):  # the engine trains F_c; here it records the request
        asked.append((kind, seed))
        return ev

    proto = get_protocol("ss_ar", params)
    assert proto.params.revision_classifier == "evaluator"   # §5.2.6: the scoring network
    sk = items.skeleton
    tiny = {"d_model": 32, "traj_dim": 8, "cond_heads": 2, "cond_ff": 32, "cond_layers": 1,
            "unroll_heads": 2, "unroll_ff": 32, "unroll_layers": 1, "dec_heads": 2,
            "dec_ff": 32, "dec_layers": 1, "epochs": 1}
    mn = MarioNet(tiny, sk, items.n_classes, items.fps)
    mn.fit(setup["train"].subset(range(40)), seed=0)
    nm_cls = generator_class("neural_marionette")
    nm = nm_cls.from_marionet(mn, {"shadow_start": "on_revision", "action_revision": True,
                                   "revision_classifier": "independent"})
    with pytest.raises(ConfigError, match="factory"):
        proto.generate(nm, items, seed=0, replicate=0, evaluator=ev, clipset=clips)
    out = proto.generate(nm, items, seed=0, replicate=0, evaluator=ev, clipset=clips,
                         evaluator_factory=factory)
    assert asked == [("a2m_gru", 1)]  # another architecture, another seed
    # the row's reading wins over the protocol's; unset, the protocol's (here the evaluator)
    assert proto.fc_reading(nm) == "independent"
    unset = nm_cls.from_marionet(mn, {"shadow_start": "on_revision", "action_revision": True})
    assert proto.fc_reading(unset) == "evaluator" and proto.fc_request("evaluator") is None
    ind = get_protocol("ss_ar", {**params, "revision_classifier": "independent"})
    assert ind.fc_reading(unset) == "independent"
    own = nm_cls.from_marionet(mn, {"shadow_start": "on_revision", "action_revision": True,
                                    "revision_classifier": "evaluator"})
    assert ind.fc_reading(own) == "evaluator"
    assert ind.revision_classifier(ev, factory, ind.fc_reading(own)) is ev
    assert asked == [("a2m_gru", 1)]  # the scoring network is not asked of the factory
    # with F_c = the scoring network, an action is revised exactly when the scorer rejected
    # its plain pass (§5.2.6: it fails only when both passes fail)
    by_ev = proto.generate(unset, items, seed=0, replicate=0, evaluator=ev, clipset=clips)
    assert asked == [("a2m_gru", 1)]
    assert out.revised is not None and out.revised.dtype == torch.bool
    # an action is revised exactly when the evaluator rejected its plain pass: with an
    # untrained model most are rejected
    plain = get_protocol("multi_action", {**params, "pipeline": "pure_generative"})
    base = plain.generate(mn, items, seed=0, replicate=0, evaluator=ev, clipset=clips)
    vals = proto.measure(out, items, ev, seed=0, clipset=clips)
    assert 0.0 <= vals["revised"] <= 1.0
    # action 1 is generated from the same real context by both: where it was not revised it is
    # bitwise the plain pipeline's
    keep = ~out.revised[0::L]
    assert torch.equal(out.motion.root[0::L][keep], base.motion.root[0::L][keep])
    # F_c = the scorer: action 1 is revised exactly where the scorer rejects the plain pass
    from repro.eval.protocols.multi_action import MultiAction
    from repro.data.action_items import GeneratedItems
    from repro.seeding import derive_seed

    first = torch.arange(S) * L
    plain1 = GeneratedItems(base.motion.select(first), base.lengths[first], base.labels[first])
    _, logits = proto._encode(ev, plain1, derive_seed(0, MultiAction.id, "revision"))
    rejected = torch.from_numpy(np.asarray(logits).argmax(1) != plain1.labels.numpy())
    assert torch.equal(by_ev.revised[0::L], rejected)
    # the plain MARIONET row under ss_ar is the pure pipeline
    again = proto.generate(mn, items, seed=0, replicate=0, evaluator=ev, clipset=clips)
    assert torch.equal(again.motion.root, base.motion.root)
    assert not bool(again.revised.any())


@pytest.mark.parametrize("scale", ["quick", "medium"])
def test_marionette_tables_share_one_training_per_model(scale):
    """Tables 1-5 and Figs 8/10 key a training by how its items are made, not by protocol:
    the full MarioNet is one job for all of them (NEURAL MARIONETTE rows included), at every
    profile whose protocols make items alike."""
    from repro.engine.table_plan import build_plan
    from repro.specs.load import find_spec
    from repro.specs.scales import resolve_scale

    sc = resolve_scale(scale)
    keys = {}
    for t in ("table1", "table2", "table3", "table4", "table5", "fig8", "fig10"):
        plan = build_plan(find_spec(f"marionette/{t}"), sc, dataset="bandai2-mini")
        for rp in plan.rows:
            for bi, trains in rp.train.items():
                cfg = trains[0].config
                if cfg["method"] == "marionet" and cfg["method_config"].get("next_tag", True) \
                        and cfg["method_config"].get("scheduled_sampling", True) \
                        and cfg["method_config"].get("time_unrolling", True) \
                        and cfg["method_config"].get("tag_injection", True):
                    keys.setdefault(trains[0].key(), set()).add(f"{t}/{rp.row_id}")
    assert len(keys) == 1, keys
    users = next(iter(keys.values()))
    assert {"table1/marionet", "table3/marionet", "table5/neural_marionette",
            "fig10/marionet_ss"} <= users
def test_test_sets_reach_the_table_json(setup, monkeypatch):
    """Issue 26: a multi-action table's JSON (``repro show --format json``) has ``test_sets``:
    per set the drawn chains' unseen share, median support and class share by position (the
    run records them in its summary, :func:`repro.engine.table_facts.test_sets_stored`,
    outside the job graph)."""
    import json

    from repro.engine import table_facts
    from repro.engine.table_view import make_view
    from repro.engine.table_plan import build_plan
    from repro.report import render
    from repro.specs.load import find_spec
    from repro.specs.scales import resolve_scale

    # the band's evaluator is the fixture's tiny one (no quick-scale recogniser is trained)
    monkeypatch.setattr("repro.engine.steps.evaluator_for",
                        lambda cfg, weights=True: setup["ev"])
    C = setup["test"].n_classes
    for table, sets in (("marionette/table3", {"overall", "sufficient"}),
                        ("marionette/fig8", {"overall", "sufficient"}),
                        ("marionette/table5", {"overall"}), ("marionette/fig10", {"overall"})):
        spec = find_spec(table)
        plan = build_plan(spec, resolve_scale("quick"), dataset="bandai2-mini")
        got = table_facts.test_sets_stored(plan)
        assert set(got) == sets, table
        n = plan.bands[0].params["actions_per_sequence"]
        for name, r in got.items():
            assert 0.0 <= r["unseen_share"] <= 1.0 and r["median_support"] >= 0
            share = np.asarray(r["class_share_by_position"])
            assert share.shape == (n, C) and np.allclose(share.sum(1), 1.0, atol=1e-3)
            assert r["classes"] == list(setup["test"].label_names)
        assert table_facts.test_sets_stored(plan) == got            # stored, the same
        view = make_view(spec, {}, {"cells": {}, "test_sets": got}, [], "bandai2-mini")
        assert json.loads(render(view, "json"))["test_sets"] == got
    # a table that draws no test chains has none
    t1 = build_plan(find_spec("marionette/table1"), resolve_scale("quick"),
                    dataset="bandai2-mini")
    assert table_facts.test_sets_stored(t1) == {}
    assert json.loads(render(make_view(t1.spec, {}, {"cells": {}}, [], "bandai2-mini"),
                             "json"))["test_sets"] is None
