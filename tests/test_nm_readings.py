"""NEURAL MARIONETTE's reading switches as rows of Table 5 and Fig. 10 (issue 26; paper §4.3.2,
§5.2.6): F_c of Action Revision (the scoring network / an independent classifier) and the
radius of Shadow Start's L2 step (unit / the retrieved training embeddings' norm).

Checked on the plan (no run): every marked row exists with the reading its label names, the
unmarked rows carry the default readings and the claims, every row samples the one trained
MarioNet, an independent F_c is one classifier for every row that reads it, and the switches
are named in the specs' notes and the tables' footers."""

from __future__ import annotations

import json

import pytest

from repro.eval.protocols import get_protocol
from repro.models.neural_marionette import NeuralMarionetteConfig

TABLES = ("marionette/table5", "marionette/fig10")
FC_MARK = "(F_c: independent classifier"
NORM_MARK = "SS step: embedding norm)"


@pytest.fixture(scope="module", params=TABLES)
def plan(request):
    from repro.engine.table_plan import build_plan
    from repro.specs.load import find_spec
    from repro.specs.scales import resolve_scale

    return build_plan(find_spec(request.param), resolve_scale("quick"), dataset="bandai2-mini")


def _generate(rp):
    return [j for j in rp.measures[0][0].inputs if j.kind == "generate"][0]


def _reading(cfg: dict) -> tuple[str | None, str | None]:
    """(F_c reading, L2 radius reading) of a resolved neural_marionette config (None: n/a)."""
    c = NeuralMarionetteConfig(**cfg)
    fc = (c.revision_classifier or "protocol") if c.action_revision else None
    norm = c.ss_norm if c.shadow_start != "never" and c.ss_l2_normalize else None
    return fc, norm


def test_rows_carry_the_reading_their_label_names(plan):
    spec = plan.spec
    rows = {r.id: r for r in spec.rows}
    readings = {}
    for rp in plan.rows:
        assert rp.status == "ok", (rp.row_id, rp.reason)
        if rp.method != "neural_marionette":
            continue
        cfg = _generate(rp).config["method_config"]
        fc, norm = _reading(cfg)
        label = rows[rp.row_id].label
        # the mark is there exactly when the row leaves the default reading
        assert (FC_MARK in label) == (fc == "independent"), rp.row_id
        assert (NORM_MARK in label) == (norm == "neighbours"), rp.row_id
        if fc is not None:
            assert fc in ("evaluator", "independent"), (rp.row_id, "F_c set explicitly")
        if norm is not None:
            assert norm in ("unit", "neighbours"), rp.row_id
        readings[rp.row_id] = (label.split(" (")[0], cfg["shadow_start"],
                               cfg["ss_l2_normalize"], fc, norm)
    got = set(readings.values())
    # NEURAL MARIONETTE under both F_c readings x both L2 radii; NM* (no L2 step) under both
    # F_c readings; MarioNet+SS (no F_c) under both radii
    for fc in ("evaluator", "independent"):
        for norm in ("unit", "neighbours"):
            assert ("NEURAL MARIONETTE", "on_revision", True, fc, norm) in got
        assert ("NEURAL MARIONETTE*", "on_revision", False, fc, None) in got
    for norm in ("unit", "neighbours"):
        assert ("MarioNet+SS", "always", True, None, norm) in got
    assert len(got) == len(readings)                 # no two rows run the same reading
    # the paper's labels (and its numbers) stay on the default readings
    assert readings["neural_marionette"][3:] == ("evaluator", "unit")
    assert readings["neural_marionette_no_l2"][3:] == ("evaluator", None)
    assert readings["marionet_ss"][3:] == (None, "unit")
    for r in spec.rows:
        if r.reported:
            assert "(" not in r.label, r.id


def test_claims_read_the_default_rows(plan):
    spec = plan.spec
    labels = {r.id: r.label for r in spec.rows}
    involved = {r for cl in spec.claims for r in cl.involved_rows()}
    assert {"neural_marionette", "marionet_ss", "marionet"} <= involved
    assert all("(" not in labels[r] for r in involved), involved


def test_rows_share_one_marionet_and_one_independent_f_c(plan):
    trains = {}
    fc_requests, fc_evaluators, gens = set(), set(), set()
    band = plan.bands[0]
    proto = get_protocol(band.protocol, band.params)
    for rp in plan.rows:
        if rp.method == "real":
            continue
        (job,) = rp.train[0]
        trains[rp.row_id] = job.key()
        gen = _generate(rp)
        gens.add(gen.key())
        assert gen.inputs == (job,)
        if rp.method != "neural_marionette":
            continue
        cfg = gen.config["method_config"]
        if not cfg["action_revision"]:
            continue
        reading = proto.fc_reading(type("G", (), {"config": NeuralMarionetteConfig(**cfg)}))
        assert reading == cfg["revision_classifier"]
        req = proto.fc_request(reading)
        if req is None:
            continue
        fc_requests.add(req)
        # the engine's factory trains {**band evaluator, kind, seed}: one classifier per kind
        fc_evaluators.add(json.dumps({**gen.config["evaluator"], "kind": req[0],
                                      "seed": req[1]}, sort_keys=True))
    assert len(set(trains.values())) == 1, trains    # MarioNet trains once for every row
    assert len(gens) == len(trains)                  # each row samples its own reading
    assert fc_requests == {("a2m_gru", 1)} and len(fc_evaluators) == 1


def test_switches_are_named_in_notes_and_footer(plan):
    from repro.engine.runner import _footer

    spec = plan.spec
    for words in ('revision_classifier = "evaluator"', 'revision_classifier = "independent"',
                  'ss_norm = "unit"', 'ss_norm = "neighbours"'):
        assert words in " ".join(spec.note.split()), (spec.id, words)
    footer = " ".join(_footer(plan, {}, None))
    for words in ("F_c: independent classifier", "SS step: embedding norm",
                  'revision_classifier = "evaluator"', 'revision_classifier = "independent"',
                  'ss_norm = "unit"', 'ss_norm = "neighbours"'):
        assert words in footer, (spec.id, words)


def test_protocol_default_is_the_scoring_network():
    p = get_protocol("ss_ar", {})
    assert p.params.revision_classifier == "evaluator"
    assert p.fc_request("evaluator") is None
    assert p.fc_request("independent") == ("a2m_gru", 1)
