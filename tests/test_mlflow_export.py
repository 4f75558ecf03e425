"""``repro runs export --mlflow`` into a real MLflow file store (no mock), read back through
``mlflow.search_runs`` and the tracking client (issue 15, item 3).

A tiny Marionette Table 1 (the fixture of test_tables_engine: Real and the nearest-clip
reference on the bundled data, a tiny evaluator) runs in seconds; its export must read back
with every replicate value, verdict and fingerprint, and a second export must change nothing.
A hand-made record covers the awkward values (NaN, ±inf, missing) and names MLflow would
refuse as keys.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from test_tables_engine import tiny_tables  # noqa: F401 (fixture)

from repro.paths import repo_root

# mlflow is imported only once the ``store`` fixture has set its variables (telemetry off)
pytestmark = pytest.mark.skipif(importlib.util.find_spec("mlflow") is None,
                                reason="needs the mlflow extra (pip install 'repro[mlflow]')")


@pytest.fixture
def store(tmp_path, monkeypatch):
    """A file-store URI; the variables the exporter would set are set here, so nothing leaks
    into other tests."""
    monkeypatch.setenv("MLFLOW_ALLOW_FILE_STORE", "true")
    monkeypatch.setenv("MLFLOW_DISABLE_TELEMETRY", "true")
    uri = (tmp_path / "mlruns").as_uri()
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    return uri


def _cli(capsys, *args) -> tuple[int, str, str]:
    from cli.main import main

    rc = main(list(args))
    out = capsys.readouterr()
    return rc, out.out, out.err


def _runs(run_id: str) -> list:
    import mlflow

    return mlflow.search_runs(search_all_experiments=True, output_format="list",
                              filter_string=f"tags.`repro.run_id` = '{run_id}'")


def _state(client, mrun, dst: Path) -> dict:
    """Everything an export writes into one MLflow run: params, tags, every metric's full
    history, the run's times and status, and a hash of every artifact file (downloaded into
    ``dst``)."""
    import mlflow

    mid = mrun.info.run_id
    run = client.get_run(mid)
    hist = {k: sorted((m.step, repr(m.value), m.timestamp)
                      for m in client.get_metric_history(mid, k)) for k in run.data.metrics}
    dst.mkdir(parents=True)
    art = Path(mlflow.artifacts.download_artifacts(run_id=mid, dst_path=str(dst)))
    files = {str(p.relative_to(art)): hashlib.sha256(p.read_bytes()).hexdigest()
             for p in sorted(art.rglob("*")) if p.is_file()}
    return {"params": dict(run.data.params), "tags": dict(run.data.tags), "metrics": hist,
            "info": (run.info.start_time, run.info.end_time, run.info.status,
                     run.info.experiment_id), "artifacts": files, "dir": art}


def test_a_table_run_reads_back_whole_and_a_second_export_changes_nothing(
        tiny_tables, _repro_home, store, tmp_path, capsys):  # noqa: F811
    from mlflow.tracking import MlflowClient

    from repro.engine.runner import run_table
    from repro.store.runs import load_run, read_trainings, resolve_run

    _, summary, run_id = run_table("marionette/table1", scale="quick", progress=False)
    rec = load_run(resolve_run(run_id))
    rc, out, err = _cli(capsys, "runs", "export", run_id, "--mlflow", store)
    assert rc == 0, err
    assert "new MLflow run" in out and "(0 new)" not in out

    (mrun,) = _runs(run_id)
    client = MlflowClient(store)
    first = _state(client, mrun, tmp_path / "first")
    assert client.get_experiment(mrun.info.experiment_id).name == "marionette/table1"
    assert first["info"][2] == "FINISHED"

    # every replicate value, at step = its replicate index, under value/<row>/<column>
    keys = json.loads((first["dir"] / "keys.json").read_text())
    cells: dict[tuple[str, str], dict[int, float]] = {}
    for v in rec.values:
        cells.setdefault((v["row"], v["column"]), {})[v["replicate"]] = v["value"]
    assert len(cells) >= 8 and all(len(s) == 3 for s in cells.values())
    for (row, col), by_rep in cells.items():
        key = f"value/{row}/{col}"  # plain names are keys as they are
        assert keys["metrics"][key] == {"row": row, "column": col, "step": "replicate"}
        got = client.get_metric_history(mrun.info.run_id, key)
        assert sorted((m.step, m.value) for m in got) == sorted(by_rep.items())
        assert mrun.data.metrics[f"mean/{row}/{col}"] == summary["cells"][row][col]["mean"]

    # every claim's verdict and probability, every fingerprint, the code, seeds, method configs
    tags, params = first["tags"], first["params"]
    assert summary["claims"]
    for c in summary["claims"]:
        assert tags[f"claim.{c['id']}.verdict"] == c["verdict"]
        assert tags[f"claim.{c['id']}.posterior_verdict"] == c["posterior_verdict"]
        assert json.loads(tags[f"claim.{c['id']}.probability"]) == c["probability"]
        assert tags[f"claim.{c['id']}.evidence"] == c["evidence"]["text"]
    cfg = rec.run["config"]
    assert params["fingerprints.data"] == cfg["data_fingerprint"]
    assert json.loads(params["fingerprints.evaluators"]) == [cfg["bands"][0]["evaluator_key"]]
    assert params["config.bands.0.evaluator_key"] == cfg["bands"][0]["evaluator_key"]
    assert params["fingerprints.spec"] == params["spec.hash"] == rec.run["spec"]["hash"]
    assert json.loads(params["config.seeds"]) == cfg["seeds"] == [0, 1, 2]
    assert params["scale"] == "quick" and params["config.scale.replicates"] == "3"
    if rec.run["git"]:
        assert params["git.commit"] == tags["mlflow.source.git.commit"] == rec.run["git"]["commit"]
    for t in read_trainings(rec.path):
        for k, v in t["method_config"].items():
            assert json.loads(params[f"method.{t['row']}.{k}"]) == v
    assert tags["repro.run_id"] == run_id and tags["repro.status"] == "FINISHED"
    assert "Real Test Data" in tags["mlflow.note.content"]  # the table, as the description

    # artifacts: the record as it is, the table in every format, the pictures
    for name in ("run.json", "values.jsonl", "summary.json", "trainings.json"):
        assert (first["dir"] / "record" / name).read_bytes() == (rec.path / name).read_bytes()
    assert {f"table/table.{x}" for x in ("txt", "md", "tex", "html", "json", "csv")} <= set(
        first["artifacts"])
    pics = [a for a in first["artifacts"] if a.startswith("report/marionette-table1/")]
    assert {"report/marionette-table1/cells.png", "report/marionette-table1/cells.csv"} <= set(pics)
    assert sum(a.endswith(".exr") for a in pics) == 2  # the run's samples are there: 2 strips
    assert sum(a.endswith(".png") for a in pics) >= 3

    # a second export: the same MLflow run, nothing added, nothing changed
    rc, out, err = _cli(capsys, "runs", "export", run_id, "--mlflow", store)
    assert rc == 0, err
    assert "(0 new)" in out and "new MLflow run" not in out
    (again,) = _runs(run_id)
    assert again.info.run_id == mrun.info.run_id
    second = _state(client, again, tmp_path / "second")
    for part in ("params", "tags", "metrics", "info", "artifacts"):
        assert second[part] == first[part], part
    assert len(client.search_runs([mrun.info.experiment_id])) == 1

    # --experiment cannot move an exported run; --json says what was written
    rc, _, err = _cli(capsys, "runs", "export", run_id, "--mlflow", store, "--experiment", "x")
    assert rc == 2 and "already exported to experiment 'marionette/table1'" in err
    rc, out, _ = _cli(capsys, "runs", "export", "latest", "--mlflow", store, "--no-pictures",
                      "--json")
    (res,) = json.loads(out)
    assert rc == 0 and res["mlflow_run"] == mrun.info.run_id and res["new_metric_values"] == 0


def _odd_record():
    """An INTERRUPTED run with awkward names and values (NaN, ±inf, missing), by hand."""
    from repro.store.runs import RunRecorder

    rec = RunRecorder(table="nowhere/table9", spec_version=1, spec_hash="cd" * 32,
                      config={"seeds": [0, 1], "data_fingerprint": "f" * 64,
                              "bands": [{"evaluator_key": "e" * 64, "params": {"a b": 1}}]},
                      scale="quick", dataset="bandai2-mini")
    rec.start()
    rec.add_values([
        {"row": "a/b", "column": "fid", "replicate": 0, "value": 1.5},
        {"row": "a/b", "column": "fid", "replicate": 1, "value": float("nan")},
        {"row": "a b", "column": "fid", "replicate": 0, "value": float("inf")},
        {"row": "a b", "column": "fid", "replicate": 1, "value": float("-inf")},
        {"row": ".", "column": "acc@3", "replicate": 0, "value": None},
        {"row": ".", "column": "acc@3", "replicate": 1, "value": 0.25},
        {"row": "ünï", "column": "..", "replicate": 0, "value": -2.0},
    ])
    rec.write_summary({"cells": {}, "rows": {"a/b": {"status": "ok", "reason": None}},
                       "claims": [{"id": "x/y", "verdict": "inconclusive", "probability": 0.5,
                                   "posterior_verdict": "inconclusive",
                                   "evidence": {"text": "e"}}]})
    rec.interrupt("test")
    return rec


def test_awkward_names_and_values_read_back_through_the_key_mapping(store, tmp_path, capsys):
    import mlflow
    from mlflow.tracking import MlflowClient

    from repro.exporters.mlflow_runs import key_part

    # the mapping: plain names unchanged, others cleaned + a hash of the original, never equal
    assert key_part("marionet") == "marionet" and key_part("acc.overall") == "acc.overall"
    odd = ["a/b", "a_b", "a b", ".", "..", "", "ünï", "acc@3"]
    mapped = [key_part(n) for n in odd]
    assert len(set(mapped)) == len(odd) and mapped[1] == "a_b"
    assert all(m.replace("-", "").replace("_", "").replace(".", "").isalnum() for m in mapped
               if m not in ("a_b",))
    assert key_part("a.b", dots=False) != key_part("a_b", dots=False)

    rec = _odd_record()
    rc, out, err = _cli(capsys, "runs", "export", rec.run_id, "--mlflow", store)
    assert rc == 0, err
    assert "no table" in err  # its table is unknown: record, values and keys still go
    (mrun,) = _runs(rec.run_id)
    assert mrun.info.status == "KILLED"  # INTERRUPTED
    client = MlflowClient(store)
    art = Path(mlflow.artifacts.download_artifacts(run_id=mrun.info.run_id,
                                                   dst_path=str(tmp_path)))
    keys = json.loads((art / "keys.json").read_text())
    by_cell = {(m["row"], m["column"]): k for k, m in keys["metrics"].items()
               if k.startswith("value/")}
    want = {("a/b", "fid"): {0: 1.5, 1: math.nan}, ("a b", "fid"): {0: math.inf, 1: -math.inf},
            (".", "acc@3"): {1: 0.25}, ("ünï", ".."): {0: -2.0}}
    assert set(by_cell) == set(want)
    for cell, values in want.items():
        got = {m.step: m.value for m in client.get_metric_history(mrun.info.run_id,
                                                                  by_cell[cell])}
        assert set(got) == set(values)
        for step, x in values.items():
            assert got[step] == x or (math.isnan(x) and math.isnan(got[step]))
    assert keys["missing_values"] == [{"row": ".", "column": "acc@3", "replicate": 0}]
    assert mrun.data.tags[f"claim.{key_part('x/y', dots=False)}.verdict"] == "inconclusive"
    assert mrun.data.params[f"config.bands.0.params.{key_part('a b', dots=False)}"] == "1"
    rc, out, _ = _cli(capsys, "runs", "export", rec.run_id, "--mlflow", store)
    assert rc == 0 and "(0 new)" in out and len(_runs(rec.run_id)) == 1


def test_names_whose_keys_collide_are_refused_not_merged(monkeypatch):
    """Two names mapped to one key would merge two cells into one metric: refused (forced
    here with a lossy mapping; the real one collides only through a sha256 prefix)."""
    import repro.exporters.mlflow_runs as mx
    from repro.errors import DataError
    from repro.store.runs import load_run

    rec = load_run(_odd_record().path)
    mx.build(rec)
    monkeypatch.setattr(mx, "key_part", lambda name, dots=True: "same")
    with pytest.raises(DataError, match="would hold both"):
        mx.build(rec)


def test_bad_input_is_one_line_exit_2(store, tmp_path, capsys):
    from repro.store.runs import RunRecorder

    rec = _odd_record()
    cases = [
        (["runs", "export", "nosuch", "--mlflow", store], "no run 'nosuch'"),
        (["runs", "export", rec.run_id, "--mlflow", "foo://bar"], "no store for this scheme"),
        (["runs", "export", rec.run_id, "--mlflow", str(Path(rec.path) / "run.json")],
         "not a folder"),
        (["runs", "export", "--mlflow", store], "name the runs (RUN...) or give --all"),
        (["runs", "export", rec.run_id, "--mlflow", "http://127.0.0.1:9"],
         "no tracking server answers at 127.0.0.1:9"),
    ]
    if importlib.util.find_spec("sqlalchemy") is None:
        cases.append((["runs", "export", rec.run_id, "--mlflow", f"sqlite:///{tmp_path}/m.db"],
                      "needs the full MLflow package"))
    running = RunRecorder(table="nowhere/table9", scale="quick")
    running.start()
    cases.append((["runs", "export", running.run_id, "--mlflow", store],
                  "is RUNNING: export it once it has ended"))
    for argv, needle in cases:
        rc, _, err = _cli(capsys, *argv)
        assert rc == 2, argv
        assert needle in err and err.count("\n") == 1 and "Traceback" not in err, err
    running.finish()
    rc, out, _ = _cli(capsys, "runs", "export", "--all", "--mlflow", store, "--no-pictures")
    assert rc == 0 and out.count("new MLflow run") == 2


def test_without_mlflow_the_export_says_what_to_install_and_help_never_imports_it(tmp_path):
    from repro.store.runs import RunRecorder

    code = ("import sys; sys.modules['mlflow'] = None  # as if it were not installed\n"
            "from cli.main import main\n"
            "sys.exit(main(['runs', 'export', 'latest', '--mlflow', sys.argv[1]]))")
    rec = RunRecorder(table="nowhere/table9", scale="quick")
    rec.start()
    rec.finish()
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "m")], capture_output=True,
                         text=True, cwd=repo_root(), check=False)
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == [out.stderr.strip()]
    assert "pip install 'repro[mlflow]'" in out.stderr and "Traceback" not in out.stderr
    help_then_modules = ("import sys\nfrom cli.main import main\n"
                         "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
                         "print(sorted(m for m in sys.modules if m.split('.')[0] in "
                         "('mlflow', 'torch', 'pandas')))")
    probe = subprocess.run([sys.executable, "-c", help_then_modules], capture_output=True,
                           text=True, cwd=repo_root(), check=True)
    assert probe.stdout.strip().splitlines()[-1] == "[]"
