"""A table end to end through the spine (issue 4 "Done when"), at a tiny scale.

A reduced Marionette Table 1 (the Real row and the harness's nearest-clip reference) runs on
the bundled bandai2-mini with a tiny evaluator, so the whole graph — evaluator, gate, train,
generate, measure, aggregate, run record, report, baseline check — is exercised in seconds.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from repro.paths import repo_root

TINY_SCALES = """
schema = 1
version = 1

[quick]
description = "tiny test profile"
dataset = "bandai2-mini"
replicates = 3
seed_base = 0
bootstrap_resamples = 200

[quick.evaluator]
window = 30
transformer = { d_model = 16, heads = 2, layers = 1, ff = 32, dropout = 0.0 }
train = { epochs = 3, windows_per_epoch = 128, batch_size = 64, checkpoint_every = 1 }
real = { per_class = 6, replicates = 2, max_fid = 1000.0, gate_margin = 1.0 }

[quick.protocols.single_action]
samples_per_class = 3
max_frames = 40
"""
#: the profiles a test profile file must list but no test runs
UNUSED_PROFILES = """
[medium]
description = "unused"
replicates = 2
bootstrap_resamples = 200

[paper]
description = "unused"
replicates = 2
bootstrap_resamples = 200
"""
TINY_SCALES += UNUSED_PROFILES


def _reduced_table1(src: Path, dst: Path) -> None:
    """marionette/table1 with only the rows that need no trained generative model."""
    import tomli_w

    spec = tomllib.loads(src.read_text())
    spec["rows"] = [r for r in spec["rows"] if r["method"] in ("real", "nearest_clip")]
    spec["claims"] = [{
        "id": "reference_vs_real_acc", "kind": "gap", "column": "acc", "a": "nearest_clip",
        "b": "real", "bound": "within", "delta": 1.0,
        "source": spec["claims"][0]["source"],
        "note": "test-only claim: exercises claim evaluation on rows that exist here",
    }]
    dst.parent.mkdir(parents=True, exist_ok=True)
    dst.write_text(tomli_w.dumps(spec))


@pytest.fixture
def tiny_tables(tmp_path, monkeypatch):
    root = tmp_path / "tables"
    _reduced_table1(repo_root() / "tables" / "marionette" / "table1.toml",
                    root / "marionette" / "table1.toml")
    (root / "scales.toml").write_text(TINY_SCALES)
    monkeypatch.setenv("REPRO_TABLES", str(root))
    return root


def _repro(*args, env_home, tables, check=True):
    import os

    env = {**os.environ, "REPRO_HOME": str(env_home), "REPRO_TABLES": str(tables)}
    out = subprocess.run([sys.executable, "-m", "cli.main", *args], capture_output=True,
                         text=True, env=env, cwd=repo_root())
    if check and out.returncode != 0:
        raise AssertionError(f"repro {' '.join(args)} exited {out.returncode}:\n{out.stderr}")
    return out


def test_table_runs_end_to_end_then_all_hits(tiny_tables, _repro_home, monkeypatch):
    from repro.engine.runner import run_table, table_view
    from repro.report import render

    plan, summary, run1 = run_table("marionette/table1", scale="quick", progress=False)
    cells = summary["cells"]
    assert set(cells) == {"real", "nearest_clip"}
    for row in ("real", "nearest_clip"):
        for col in ("fid", "acc", "div", "multimod"):
            c = cells[row][col]
            assert c["n"] == 3 and len(c["values"]) == 3
            lo, hi = c["bootstrap_percentile"]
            assert lo <= c["mean"] <= hi
    assert "traj_err" in cells["nearest_clip"] and "traj_err" not in cells["real"]
    claim = summary["claims"][0]
    assert claim["verdict"] in ("supported", "contradicted", "inconclusive")
    assert claim["probability"] is not None

    # the run record is the truth: raw values on disk, read-only, indexed
    run_dir = _repro_home / "runs" / run1
    rj = json.loads((run_dir / "run.json").read_text())
    assert rj["status"] == "FINISHED" and rj["table"] == "marionette/table1"
    assert rj["spec"]["hash"] == plan.spec.spec_hash
    n_lines = len((run_dir / "values.jsonl").read_text().splitlines())
    assert n_lines == sum(c["n"] for r in cells.values() for c in r.values())

    text = render(table_view("marionette/table1", run=run1), "term")
    assert "STAND-IN" in text and "Real Test Data" in text
    assert "not implemented" not in text  # the reduced spec has only built rows

    # a second identical run is all cache hits (how much faster: benchmarks, not a timed
    # test); the real rows the gate checks are stored too (computing them again would fail)
    import repro.eval

    def no_recompute(*a, **k):
        raise AssertionError("the gate's real rows were recomputed")

    monkeypatch.setattr(repro.eval, "real_rows", no_recompute)
    _, summary2, run2 = run_table("marionette/table1", scale="quick", progress=False)
    assert set(summary2["counts"]) == {"hit"}
    assert summary2["cells"] == summary["cells"]


def test_a_cached_rerun_reads_no_evaluator_weights(tiny_tables, _repro_home, monkeypatch):
    """Fixed costs (issue 17): when every measurement is stored, the rerun neither loads nor
    re-hashes the evaluator's weights (its record names it) and the gate reads its stored
    real rows; the summary, footer and cells are those of the first run."""
    from repro.engine.runner import run_table
    from repro.eval import provider
    from repro.eval.evaluator import Evaluator

    # an evaluator an earlier test loaded (same key, another home) would not be stored here
    monkeypatch.setattr(provider, "_LOADED", {})
    _, s1, _ = run_table("marionette/table1", scale="quick", progress=False)
    real_load = Evaluator.load.__func__

    def record_only(cls, path, *, weights=True):
        if weights:
            raise AssertionError("a fully cached rerun loaded evaluator weights")
        return real_load(cls, path, weights=False)

    monkeypatch.setattr(Evaluator, "load", classmethod(record_only))
    monkeypatch.setattr(provider, "_LOADED", {})  # a fresh process: nothing loaded yet
    _, s2, _ = run_table("marionette/table1", scale="quick", progress=False)
    assert set(s2["counts"]) == {"hit"}
    assert s2["evaluators"] == s1["evaluators"] and s2["cells"] == s1["cells"]
    assert s2["footer"][:-1] == s1["footer"][:-1]  # the last line names each run's id
    assert any(ln.startswith("Kernels: pinned x86-64-avx2-portable") for ln in s1["footer"])
    assert list(s2["rows"]) == ["real", "nearest_clip"]  # the stored summary keeps row order
    (_, line), = s2["evaluators"].items()
    stored = json.loads(next((_repro_home / "store" / "objects").rglob("evaluator.json"))
                        .read_text())
    assert stored["fingerprint"][:12] in line
    assert not provider._LOADED  # the record is not kept as a scoring evaluator
    with pytest.raises(RuntimeError, match="without its weights"):
        Evaluator.load(next((_repro_home / "store" / "objects").rglob("evaluator.json")).parent,
                       weights=False).features(np.zeros((1, 30, 19, 3)))


def _heavy_imports(args: list[str], env: dict[str, str]) -> str:
    """The last line of ``repro ARGS`` run in a fresh process with ``env`` added: ``HEAVY [...]``,
    which of torch and roma the process imported (it must exit 0)."""
    import os

    code = (f"import sys; from cli.main import main; rc = main({args!r}); "
            "heavy = sorted(m for m in ('torch', 'roma') if m in sys.modules); "
            "print('HEAVY', heavy); sys.exit(rc)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=False, cwd=repo_root(), env={**os.environ, **env})
    assert out.returncode == 0, out.stderr
    return out.stdout.strip().splitlines()[-1]


def test_show_and_list_of_a_run_table_import_no_torch(tiny_tables, _repro_home):
    """``repro show`` and ``repro list`` read run records only: no torch, no roma in the
    process (fixed costs, issue 17)."""
    from repro.engine.runner import run_table

    run_table("marionette/table1", scale="quick", progress=False)
    for args in (["show", "marionette/table1"], ["list"]):
        assert _heavy_imports(args, {"REPRO_HOME": str(_repro_home),
                                     "REPRO_TABLES": str(tiny_tables)}) == "HEAVY []", args


@pytest.mark.parametrize("table", ["marionette/table1", "multiact/table1", "odmo/table1"])
def test_plan_on_the_bundled_data_imports_no_torch(table, _repro_home):
    """``repro plan`` computes nothing: every row's config comes from its method's torch-free
    card, every band's protocol module imports torch only to compute, and MultiAct's evaluator
    split is keyed without resampling its clips: no torch, no roma in the process (issue 31)."""
    from repro.data.bundle import MINI_NAME
    from repro.data.registry import load_clipset

    load_clipset(MINI_NAME)  # the bundle's first decoding (torch) is computing: done once before
    assert _heavy_imports(["plan", table], {"REPRO_HOME": str(_repro_home)}) == "HEAVY []"


def test_a_failing_method_fails_its_row_and_the_others_go_on(tiny_tables, _repro_home,
                                                             monkeypatch, capsys):
    from repro.engine.runner import run_table
    from repro.models.nearest_clip import NearestClip

    def broken_fit(self, *a, **k):
        raise FloatingPointError("loss is nan")

    monkeypatch.setattr(NearestClip, "fit", broken_fit)
    _, summary, run_id = run_table("marionette/table1", scale="quick", progress=False)
    assert set(summary["cells"]) == {"real"}  # the Real row is measured all the same
    assert summary["rows"]["nearest_clip"]["status"] == "failed"
    assert "loss is nan" in summary["rows"]["nearest_clip"]["reason"]
    assert "row nearest_clip failed" in capsys.readouterr().err
    jobs = json.loads((_repro_home / "runs" / run_id / "run.json").read_text())["jobs"]
    assert {j["status"] for j in jobs if j["label"].startswith("nearest_clip/")} == \
        {"failed", "cancelled"}
    assert summary["counts"]["failed"] == 1


def test_several_tables_run_as_one_graph_with_a_record_each(tiny_tables, _repro_home):
    import tomllib

    import tomli_w

    from repro.engine.runner import run_table, run_tables

    # a second table with the same rows (as Tables 1, 2 and 4 share MarioNet's jobs)
    spec = tomllib.loads((tiny_tables / "marionette" / "table1.toml").read_text())
    spec["id"] = "marionette/table5"
    (tiny_tables / "marionette" / "table5.toml").write_text(tomli_w.dumps(spec))
    out = run_tables(["marionette/table1", "marionette/table5", "marionette/table1"],
                     scale="quick", jobs=2, progress=False)
    assert [p.spec.id for p, _, _ in out] == ["marionette/table1", "marionette/table5"]
    (_, s1, r1), (_, s5, r5) = out
    def values(summary):  # bootstrap seeds derive from the table id; the values must agree
        return {(r, c): cell["values"] for r, cols in summary["cells"].items()
                for c, cell in cols.items()}

    assert values(s1) == values(s5) and s1["counts"] == s5["counts"]
    assert s1["counts"].get("computed", 0) > 0
    runs = [json.loads((_repro_home / "runs" / r / "run.json").read_text()) for r in (r1, r5)]
    assert [r["status"] for r in runs] == ["FINISHED", "FINISHED"]
    assert [r["table"] for r in runs] == ["marionette/table1", "marionette/table5"]
    assert {j["key"] for j in runs[0]["jobs"]} == {j["key"] for j in runs[1]["jobs"]}
    manifests = list((_repro_home / "store" / "objects").rglob("manifest.json"))
    assert len(manifests) == len({m.parent.name for m in manifests})  # each job stored once
    _, alone, _ = run_table("marionette/table1", scale="quick", progress=False)
    assert alone["cells"] == s1["cells"] and set(alone["counts"]) == {"hit"}


def test_with_two_jobs_the_trainings_run_beside_the_evaluator(tiny_tables, _repro_home,
                                                               tmp_path, monkeypatch, capsys):
    from repro.engine.runner import run_table, run_tables

    ((_, two, run2),) = run_tables(["marionette/table1"], scale="quick", jobs=2,
                                   progress=False, lines=True)
    err = capsys.readouterr().err
    assert "1 evaluator(s), 1 training(s) and 3 other job(s) that need no evaluator, on 2 " \
        "worker(s)" in err
    assert "evaluator trained [" in err
    assert err.index("evaluator trained [") < err.index("gate")  # before the gate and graph
    import re

    counters = [(int(a), int(b)) for a, b in re.findall(r"\((\d+)/(\d+)\)", err)]
    assert counters and all(a <= b for a, b in counters)  # each graph counts its own jobs
    rec = json.loads((_repro_home / "runs" / run2 / "run.json").read_text())
    trains = [j for j in rec["jobs"] if j["kind"] == "train"]
    assert [j["status"] for j in trains] == ["computed"]  # trained once, counted as computed
    assert trains[0]["key"] in rec["keys"]["written"] and trains[0]["key"] not in rec["keys"]["read"]
    assert len(rec["jobs"]) == len({j["key"] for j in rec["jobs"]})  # one line a job
    assert two["counts"] == {"computed": len(rec["jobs"])}
    # the same numbers as one job at a time, in a store of its own
    monkeypatch.setenv("REPRO_HOME", str(tmp_path / "other"))
    _, one, _ = run_table("marionette/table1", scale="quick", progress=False)
    assert one["cells"] == two["cells"] and one["counts"] == two["counts"]


def test_corrupt_object_is_detected_and_rebuilt(tiny_tables, _repro_home):
    from repro.engine.runner import run_table

    _, s1, _ = run_table("marionette/table1", scale="quick", progress=False)
    # corrupt the reference row's stored samples and the measured values read from them
    hit = 0
    for name in ("generated.npz", "values.json"):
        for f in (_repro_home / "store" / "objects").rglob(name):
            man = json.loads((f.parent / "manifest.json").read_text())
            if man.get("kind") not in ("generate", "measure"):
                continue
            f.chmod(0o644)
            b = bytearray(f.read_bytes())
            b[len(b) // 2] ^= 0x01
            f.write_bytes(bytes(b))
            hit += 1
    assert hit == 6
    _, s2, _ = run_table("marionette/table1", scale="quick", progress=False)
    # the measure objects are read (and found corrupt), recomputed from their samples, which
    # are read in turn (and found corrupt) and regenerated: same values as before
    assert s2["counts"].get("computed", 0) == 6, s2["counts"]
    assert s2["cells"] == s1["cells"]
    assert any((_repro_home / "store").rglob("quarantine*"))


def test_concurrent_runs_agree_and_share_objects(tiny_tables, _repro_home):
    import os

    env = {**os.environ, "REPRO_HOME": str(_repro_home), "REPRO_TABLES": str(tiny_tables)}
    cmd = [sys.executable, "-m", "cli.main", "run", "marionette/table1", "--scale", "quick",
           "--quiet", "--format", "json"]
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env=env, cwd=repo_root()) for _ in range(2)]
    outs = [p.communicate(timeout=900) for p in procs]
    assert all(p.returncode == 0 for p in procs), [o[1][-2000:] for o in outs]
    views = [json.loads(o[0]) for o in outs]
    assert views[0]["rows"] == views[1]["rows"]
    manifests = list((_repro_home / "store" / "objects").rglob("manifest.json"))
    keys = [m.parent.name for m in manifests]
    assert len(keys) == len(set(keys))


def test_verify_against_baseline_and_hand_edit_fails(tiny_tables, _repro_home, tmp_path):
    base = tmp_path / "baselines"
    _repro("run", "marionette/table1", "--quiet", env_home=_repro_home, tables=tiny_tables)
    _repro("verify", "marionette/table1", "--baseline", str(base), "--update",
           env_home=_repro_home, tables=tiny_tables)
    ok = _repro("verify", "marionette/table1", "--baseline", str(base),
                env_home=_repro_home, tables=tiny_tables)
    assert "matches the baseline" in ok.stdout
    path = base / "marionette" / "table1.json"
    data = json.loads(path.read_text())
    data["cells"]["real"]["acc"]["mean"] += 0.5  # a hand edit
    path.write_text(json.dumps(data, indent=2))
    bad = _repro("verify", "marionette/table1", "--baseline", str(base),
                 env_home=_repro_home, tables=tiny_tables, check=False)
    assert bad.returncode == 1
    assert "edited by hand" in bad.stdout and "real/acc" in bad.stdout


def test_show_without_run_and_not_implemented_rows(_repro_home):
    out = _repro("show", "marionette/table3", env_home=_repro_home,
                 tables=repo_root() / "tables")
    assert "not run" in out.stdout and "7.854" in out.stdout
    out = _repro("show", "odmo/table1", env_home=_repro_home,
                 tables=repo_root() / "tables")
    assert "not run" in out.stdout and "not implemented" not in out.stdout  # all ODMO rows built


def test_unknown_table_is_one_line_exit_2(_repro_home):
    out = _repro("run", "marionette/tabel1", env_home=_repro_home,
                 tables=repo_root() / "tables", check=False)
    assert out.returncode == 2
    assert "did you mean 'marionette/table1'" in out.stderr
    assert "Traceback" not in out.stderr


def _all_spec_ids():
    from repro.specs.load import load_all

    return sorted(load_all(repo_root() / "tables"))


@pytest.mark.parametrize("table", _all_spec_ids())
def test_every_spec_plans_and_renders(table, monkeypatch):
    """Conformance over every spec: it plans at the quick scale, every row gets a status, and
    the rendered table shows every number the paper printed for it."""
    from repro.engine.runner import table_view
    from repro.report import FORMATS, render
    from repro.specs.load import find_spec

    monkeypatch.setenv("REPRO_TABLES", str(repo_root() / "tables"))
    spec = find_spec(table)
    view = table_view(table, scale="quick")
    assert [r.id for r in view.rows] == [r.id for r in spec.rows]
    for row in view.rows:
        assert row.status in ("not run", "not implemented", "data unavailable"), row
        for cell in row.cells.values():
            assert cell.value is None  # nothing is reproduced before a run
    md = render(view, "md")
    for row in spec.rows:
        for cell in row.reported.values():
            assert cell.printed in md
    for fmt in FORMATS:
        assert render(view, fmt)


def test_seeds_option_parses_and_replaces_replicates(tiny_tables):
    from repro.engine.runner import plan_table
    from repro.engine.table_plan import parse_seeds
    from repro.errors import ConfigError

    assert parse_seeds("0-2,7") == (0, 1, 2, 7)
    with pytest.raises(ConfigError):
        parse_seeds("1,1")
    with pytest.raises(ConfigError):
        parse_seeds("a-b")
    entries = plan_table("marionette/table1", seeds=(5, 6))
    measures = [e for e in entries if e["kind"] == "measure_real"]
    assert len(measures) == 2


def test_run_without_its_data_prints_the_paper_then_exits_2(tiny_tables, _repro_home):
    out = _repro("run", "marionette/table1", "--scale", "medium", "--quiet",
                 env_home=_repro_home, tables=tiny_tables, check=False)
    assert out.returncode == 2, out.stderr
    errors = [ln for ln in out.stderr.splitlines() if ln.startswith("repro: error:")]
    assert len(errors) == 1 and "data set 'bandai2'" in errors[0]
    assert "repro data prepare bandai2" in errors[0] and "Traceback" not in out.stderr
    assert "data unavailable" in out.stdout and "Real Test Data" in out.stdout


def test_every_table_job_computes_with_the_profiles_threads(tiny_tables):
    """The CPU thread count is a profile value carried by every job of a table (so --jobs
    never changes a result) and part of each key (another count is another computation)."""
    import dataclasses

    from repro.engine.job import topo_order
    from repro.engine.table_plan import build_plan
    from repro.specs.load import find_spec
    from repro.specs.scales import resolve_scale

    spec, scale = find_spec("marionette/table1"), resolve_scale("quick")
    assert scale.threads == 1 and scale.to_dict()["threads"] == 1

    def jobs(s):
        plan = build_plan(spec, s)
        return topo_order(j for rp in plan.rows for ms in rp.measures.values() for j in ms)

    ones, twos = jobs(scale), jobs(dataclasses.replace(scale, threads=2))
    assert ones and {j.threads for j in ones} == {1} and {j.threads for j in twos} == {2}
    assert not {j.key() for j in ones} & {j.key() for j in twos}


def test_table_jobs_hash_the_method_and_protocol_they_load_by_name(tiny_tables):
    """The method's and the protocol's modules are found through registries, not imports:
    each table job names them as plug-ins, so editing MarioNet's code changes its keys.  A
    training names only its method: its items are made by repro.data.contexts (imported by
    the training step, so hashed), which every Marionette protocol shares."""
    from repro.engine.job import topo_order
    from repro.engine.source_hash import source_manifest
    from repro.engine.table_plan import build_plan
    from repro.specs.load import find_spec
    from repro.specs.scales import resolve_scale

    plan = build_plan(find_spec("marionette/table1"), resolve_scale("quick"))
    jobs = topo_order(j for rp in plan.rows for ms in rp.measures.values() for j in ms)
    proto = "repro.eval.protocols.single_action"
    assert proto not in dict(source_manifest("repro.engine.steps"))  # why plug-ins are needed
    by_kind = {}
    for j in jobs:
        by_kind.setdefault(j.kind, set()).add(j.plugins)
        assert proto in j.plugins or j.kind == "train", j.label
    assert ("repro.models.nearest_clip",) in by_kind["train"]
    assert "repro.data.contexts" in dict(source_manifest("repro.engine.steps"))
    assert by_kind["measure_real"] == {(proto,)}


def test_retrain_gives_each_replicate_its_own_training(tiny_tables, _repro_home):
    """--retrain: replicate r samples from a model trained with seed r (the first training is
    the default run's own), the footer says the intervals include training-seed variance,
    and baselines (verify) only ever read runs made without it."""
    from repro.engine.job import topo_order
    from repro.engine.runner import latest_run, run_table
    from repro.engine.table_plan import build_plan
    from repro.specs.load import find_spec
    from repro.specs.scales import resolve_scale

    spec, scale = find_spec("marionette/table1"), resolve_scale("quick")
    one, each = build_plan(spec, scale), build_plan(spec, scale, retrain=True)
    rp1 = next(r for r in one.rows if r.method == "nearest_clip")
    rpn = next(r for r in each.rows if r.method == "nearest_clip")
    assert [j.seed for j in rp1.train[0]] == [0]
    assert [j.seed for j in rpn.train[0]] == list(each.seeds) == [0, 1, 2]
    assert rpn.train[0][0].key() == rp1.train[0][0].key()  # shared with the default run
    for r, measure in enumerate(rpn.measures[0]):
        (generate,) = measure.inputs
        assert generate.inputs == (rpn.train[0][r],)
    trains = [j for j in topo_order(each.jobs()) if j.kind == "train"]
    assert len(trains) == 3 and each.config["retrain"] is True and one.config["retrain"] is False

    _, plain, run1 = run_table("marionette/table1", scale="quick", progress=False)
    _, summary, run2 = run_table("marionette/table1", scale="quick", progress=False,
                                 retrain=True)
    assert any("independent trainings" in line for line in summary["footer"])
    assert not any("independent trainings" in line for line in plain["footer"])
    assert latest_run("marionette/table1", "quick").name == run2
    assert latest_run("marionette/table1", "quick", retrain=False).name == run1


@pytest.mark.parametrize("table", ["multiact/table1", "multiact/table3", "odmo/table1",
                                   "marionette/table1"])
def test_the_plans_split_view_is_the_evaluators_clipset(table, _repro_home, monkeypatch):
    """What a plan keys and split-checks the evaluator from (``evaluator_split``, no clips
    built) equals the clip set the evaluator trains on (``evaluator_clipset``): fingerprint,
    labels, split, label names, classes (issue 31), for every band of a spec per paper kind."""
    from repro.engine.steps import clipset, evaluator_clipset, evaluator_split
    from repro.engine.table_plan import build_plan
    from repro.eval.protocols import get_protocol
    from repro.specs.load import find_spec
    from repro.specs.scales import resolve_scale

    monkeypatch.setenv("REPRO_TABLES", str(repo_root() / "tables"))
    plan = build_plan(find_spec(table), resolve_scale("quick", None))
    assert plan.data_fingerprint is not None, plan.data_missing
    clips = clipset(plan.dataset)
    bands = [b for b in plan.bands if b.implemented]
    assert bands
    for b in bands:
        proto = get_protocol(b.protocol, b.params)
        view, full = evaluator_split(proto, clips), evaluator_clipset(proto, clips)
        assert view.fingerprint == full.fingerprint
        assert view.label_names == full.label_names and view.n_classes == full.n_classes
        assert np.array_equal(view.labels, full.labels)
        assert np.array_equal(view.split, full.split)


def test_every_methods_card_is_its_generators():
    """A method's torch-free card (what the planner reads) and its Generator class (what a
    job runs) say the same: method id, Config, trains_as, inference fields, components and
    device use (issue 31)."""
    from repro.models.base import GENERATOR_MODULES, generator_class, method_card

    for m in GENERATOR_MODULES:
        card, cls = method_card(m), generator_class(m)
        assert cls.card is card, m
        assert (cls.method_id, cls.Config, cls.trains_as, tuple(cls.inference_fields),
                dict(cls.components), cls.uses_device) == (
            card.method_id, card.Config, card.trains_as, tuple(card.inference_fields),
            dict(card.components), card.uses_device), m


def test_a_method_without_its_card_module_is_one_config_error(monkeypatch):
    """A method listed without its ``<module>_config`` is a ConfigError naming the missing
    module (a row reason at plan time), not a traceback."""
    from repro.errors import ConfigError
    from repro.models import base

    monkeypatch.setitem(base.GENERATOR_MODULES, "nocard", "repro.models.nocard")
    with pytest.raises(ConfigError, match="repro.models.nocard_config is missing"):
        base.method_card("nocard")
