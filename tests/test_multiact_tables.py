"""MultiAct's six specs as job graphs (issue 13): every row built, trainings shared.

Plans only (nothing is trained): the quick scale on the bundled bandai2-mini.
"""

from __future__ import annotations

import pytest

from repro.paths import repo_root

TABLES = ("multiact/table1", "multiact/table2", "multiact/table3", "multiact/tableA",
          "multiact/tableB", "multiact/fig6")


@pytest.fixture(scope="module")
def plans(tmp_path_factory):
    import os

    from repro.engine.table_plan import build_plan
    from repro.specs.load import find_spec
    from repro.specs.scales import resolve_scale

    old = {k: os.environ.get(k) for k in ("REPRO_HOME", "REPRO_TABLES")}
    os.environ["REPRO_HOME"] = str(tmp_path_factory.mktemp("home"))
    os.environ["REPRO_TABLES"] = str(repo_root() / "tables")
    try:
        scale = resolve_scale("quick")
        yield {t: build_plan(find_spec(t), scale) for t in TABLES}
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _train_keys(plan, row_id):
    rp = next(r for r in plan.rows if r.row_id == row_id)
    return [(j.config["method"], j.key()) for js in rp.train.values() for j in js]


def _generate_jobs(plan, row_id):
    rp = next(r for r in plan.rows if r.row_id == row_id)
    return [m.inputs[0] for ms in rp.measures.values() for m in ms]


@pytest.mark.parametrize("table", TABLES)
def test_every_row_is_built(plans, table):
    plan = plans[table]
    assert all(b.implemented for b in plan.bands), [b.reason for b in plan.bands]
    for rp in plan.rows:
        assert rp.status == "ok", (rp.row_id, rp.reason)
        assert rp.measures, rp.row_id


def test_one_macvae_training_serves_every_table(plans):
    """Table 1's MACVAE, Table A's 4-frame row, Table B's transformer, both of Table 3's MACVAE
    rows (prev_motion_source is inference-only) and Fig. 6's MultiAct are one train job."""
    key = dict(_train_keys(plans["multiact/table1"], "macvae"))["macvae"]
    for table, row in (("multiact/table2", "macvae"), ("multiact/tableA", "frames_4"),
                       ("multiact/tableB", "transformer"), ("multiact/table3", "macvae_prev_test"),
                       ("multiact/table3", "macvae_prev_actor"), ("multiact/fig6", "multiact")):
        assert dict(_train_keys(plans[table], row))["macvae"] == key, (table, row)


def test_ablations_train_their_own_models(plans):
    t1 = plans["multiact/table1"]
    keys = {r.row_id: dict(_train_keys(t1, r.row_id)).get("macvae") for r in t1.rows
            if r.method == "macvae"}
    assert len(set(keys.values())) == len(keys)  # six distinct models
    tA = plans["multiact/tableA"]
    assert len({dict(_train_keys(tA, r.row_id))["macvae"] for r in tA.rows
                if r.method == "macvae"}) == 5


def test_composites_reuse_the_actor_row_and_share_ssmct(plans):
    actor = dict(_train_keys(plans["multiact/table2"], "actor"))["actor"]
    t3 = plans["multiact/table3"]
    align, no_align = dict(_train_keys(t3, "ssmct_align")), dict(_train_keys(t3, "ssmct_no_align"))
    assert align["actor"] == no_align["actor"] == actor
    assert align["ssmct"] == no_align["ssmct"]
    assert "actor_ssmct" not in align  # a composite trains nothing of its own
    assert dict(_train_keys(t3, "interpolation")) == {"actor": actor}
    # the previous motion from ACTOR: the MACVAE row also loads the ACTOR model
    assert dict(_train_keys(t3, "macvae_prev_actor"))["actor"] == actor
    assert "actor" not in dict(_train_keys(t3, "macvae_prev_test"))
    # align is an inference option: same inputs, different generate jobs
    g_a, g_n = _generate_jobs(t3, "ssmct_align")[0], _generate_jobs(t3, "ssmct_no_align")[0]
    assert [i.key() for i in g_a.inputs] == [i.key() for i in g_n.inputs]
    assert g_a.key() != g_n.key()
    assert g_a.config["method_config"]["align"] is True
    assert g_n.config["method_config"]["align"] is False


def test_real_rows_differ_by_split(plans):
    t1 = plans["multiact/table1"]
    rows = {r.row_id: r for r in t1.rows}
    tr = [m for ms in rows["real_train"].measures.values() for m in ms]
    te = [m for ms in rows["real_test"].measures.values() for m in ms]
    assert tr[0].config["real"] == {"split": "train"} and te[0].config["real"] == {"split": "test"}
    assert tr[0].key() != te[0].key()
    # Neural Marionette's Real row is unaffected (its protocol reads no row option)
    from repro.engine.table_plan import build_plan
    from repro.specs.load import find_spec
    from repro.specs.scales import resolve_scale

    nm = build_plan(find_spec("marionette/table1"), resolve_scale("quick"))
    real = next(r for r in nm.rows if r.method == "real")
    assert all("real" not in m.config for ms in real.measures.values() for m in ms)


def test_figure_panels_share_one_generation(plans):
    fig = plans["multiact/fig6"]
    assert len(fig.bands) == 1  # action accuracy and transition FID from one pass
    assert set(fig.bands[0].metrics.values()) == {"acc", "fid_test"}
