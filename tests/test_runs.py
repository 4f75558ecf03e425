"""Run records: status transitions, read-only files, values.jsonl, the SQLite index
(incremental == rebuilt, silent rebuild when corrupt), stale runs, and `repro runs`."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys

import pytest

from repro.errors import ConfigError, DataError
from repro.paths import repro_home, runs_root
from repro.store.index import RunIndex
from repro.store.runs import (RunRecorder, collect_garbage, git_state, load_run, resolve_run,
                              run_dirs)


def _writable(p) -> bool:
    return bool(stat.S_IMODE(p.stat().st_mode) & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))


def _make_run(table="marionette/table3", lr=1e-4, values=((0.5, 0.7),), finish=True, **kw):
    rec = RunRecorder(table=table, spec_version=1, spec_hash="ab" * 32,
                      config={"lr": lr, "model": {"width": 64}}, scale="quick",
                      dataset="bandai2-mini", **kw)
    rec.start()
    rows = []
    for rep, vs in enumerate(values):
        rows += [{"row": "MARIONET", "column": "fid", "replicate": rep, "value": vs[0]},
                 {"row": "MARIONET", "column": "acc", "replicate": rep, "value": vs[1]}]
    rec.add_values(rows)
    rec.write_summary({"cells": {"MARIONET/fid": {"mean": values[0][0]}}})
    if finish:
        rec.finish()
    return rec


def test_status_transitions_history_and_read_only_when_finished():
    rec = RunRecorder(table="odmo/table1", config={"b": 1, "a": [1, 2]}, scale="quick")
    run = json.loads((rec.path / "run.json").read_text())
    assert run["schema"] == 1 and run["status"] == "QUEUED" and run["run_id"] == rec.run_id
    assert run["packages"]["numpy"] and run["packages"]["python"]
    assert run["env"]["device"] == "cpu" and run["env"]["pid"] == os.getpid()
    assert set(run["env"]["cpu"]) == {"model", "cpus", "isa"} and run["env"]["cpu"]["cpus"] >= 1
    with pytest.raises(RuntimeError, match="cannot go from QUEUED to FINISHED"):
        rec.finish()
    rec.start()
    rec.record_job({"kind": "train", "label": "t", "key": "1" * 64, "status": "computed"})
    rec.record_job({"kind": "prep", "label": "p", "key": "2" * 64, "status": "hit"})
    rec.add_values([{"row": "R", "column": "C", "replicate": 0, "value": float("nan"), "x": 1}])
    rec.finish()
    run = json.loads((rec.path / "run.json").read_text())
    assert [h["status"] for h in run["status_history"]] == ["QUEUED", "RUNNING", "FINISHED"]
    assert run["started"] and run["ended"] and run["ended"] >= run["started"]
    assert run["keys"] == {"read": ["2" * 64], "written": ["1" * 64]}
    line = json.loads((rec.path / "values.jsonl").read_text())
    assert line == {"schema": 1, "row": "R", "column": "C", "replicate": 0, "value": None,
                    "nonfinite": "nan", "x": 1}
    for p in rec.path.iterdir():
        assert not _writable(p), p
    with pytest.raises(RuntimeError, match="read-only"):
        rec.add_values([{"row": "R", "column": "C", "replicate": 1, "value": 1.0}])
    with pytest.raises(RuntimeError, match="read-only"):
        rec.record_job({"key": "3" * 64, "status": "hit"})
    rec.fail("late")  # a no-op once ended
    assert load_run(rec.path).status == "FINISHED"


def test_context_manager_marks_failed_and_interrupted():
    with pytest.raises(ValueError):
        with RunRecorder(table="t") as rec:
            assert rec.status == "RUNNING"
            raise ValueError("bad thing")
    data = load_run(rec.path).run
    assert data["status"] == "FAILED" and data["error"] == "ValueError: bad thing"
    with pytest.raises(KeyboardInterrupt):
        with RunRecorder(table="t") as rec2:
            raise KeyboardInterrupt
    assert load_run(rec2.path).status == "INTERRUPTED"
    assert not _writable(rec2.path / "run.json")
    with RunRecorder(table="t") as rec3:
        pass
    assert load_run(rec3.path).status == "FINISHED"


def test_value_rows_are_validated():
    rec = RunRecorder(table="t")
    rec.start()
    with pytest.raises(ValueError, match="needs 'replicate'"):
        rec.add_values([{"row": "R", "column": "C", "value": 1.0}])
    with pytest.raises(ValueError, match="replicate"):
        rec.add_values([{"row": "R", "column": "C", "replicate": 0.5, "value": 1.0}])
    with pytest.raises(ValueError, match="string"):
        rec.add_values([{"row": 1, "column": "C", "replicate": 0, "value": 1.0}])


def test_run_ids_sort_by_time_and_resolve_by_prefix():
    a = _make_run()
    b = _make_run()
    assert [d.name for d in run_dirs()] == sorted([a.run_id, b.run_id])
    assert a.run_id < b.run_id
    assert resolve_run(b.run_id) == b.path
    assert resolve_run("latest") == b.path
    assert resolve_run(b.run_id[:-3]) == b.path or a.run_id[:-3] == b.run_id[:-3]
    with pytest.raises(ConfigError, match="no run"):
        resolve_run("nope")
    with pytest.raises(ConfigError, match="ambiguous"):
        resolve_run(a.run_id[:4])


def test_incremental_index_equals_reindex_and_corrupt_index_is_rebuilt():
    _make_run(lr=1e-4)
    _make_run(lr=2e-4, values=((0.4, 0.8), (0.45, 0.75)))
    failing = RunRecorder(table="odmo/table2")
    failing.start()
    failing.fail("boom")
    open_run = _make_run(table="multiact/table1", finish=False)
    idx = RunIndex()
    incremental = idx.dump()
    assert len(incremental["runs"]) == 4 and len(incremental["run_values"]) == 2 + 4 + 2
    assert idx.reindex() == 4
    assert idx.dump() == incremental
    rows = idx.list()
    assert [r["run_id"] for r in rows] == sorted((r["run_id"] for r in rows), reverse=True)
    assert {r["status"] for r in rows} == {"FINISHED", "FAILED", "RUNNING"}
    assert [r["run_id"] for r in idx.list(table="multiact/table1")] == [open_run.run_id]
    assert len(idx.list(status="finished")) == 2
    # a corrupt index file is rebuilt silently
    idx.path.write_bytes(b"this is not a database" * 100)
    assert len(RunIndex().list()) == 4
    assert RunIndex().dump() == incremental
    # a missing one too
    idx.path.unlink()
    assert len(RunIndex().list()) == 4
    # folders changed behind the index's back are picked up (one removed here)
    import shutil

    shutil.rmtree(failing.path)
    assert len(RunIndex().list()) == 3
    assert (repro_home() / "runs.sqlite").exists()


def test_dead_running_run_is_marked_interrupted_when_listed(tmp_path):
    script = (
        "import os, sys\n"
        "from repro.store.runs import RunRecorder\n"
        "rec = RunRecorder(table='t', runs_dir=sys.argv[1])\n"
        "rec.start()\n"
        "print(rec.run_id, flush=True)\n"
        "os._exit(0)\n"  # dies without closing the run (like kill -9)
    )
    out = subprocess.run([sys.executable, "-c", script, str(runs_root())], capture_output=True,
                         text=True, timeout=60, check=True)
    run_id = out.stdout.strip()
    rows = {r["run_id"]: r for r in RunIndex().list()}
    assert rows[run_id]["status"] == "INTERRUPTED"
    data = load_run(runs_root() / run_id).run
    assert data["status"] == "INTERRUPTED" and "ended without closing" in data["note"]
    # a live one is left alone
    live = RunRecorder(table="t")
    live.start()
    assert {r["run_id"]: r for r in RunIndex().list()}[live.run_id]["status"] == "RUNNING"


def test_git_state_in_and_outside_a_checkout(tmp_path):
    from repro.paths import repo_root

    assert git_state(tmp_path) is None
    if (repo_root() / ".git").exists():
        g = git_state()
        assert g is not None and len(g["commit"]) == 40
        assert (g["diff_sha256"] is None) == (not g["dirty"])


def test_bad_run_json_is_a_one_line_data_error():
    rec = _make_run()
    p = rec.path / "run.json"
    os.chmod(p, 0o644)
    p.write_text("{oops")
    with pytest.raises(DataError, match="run.json is not valid JSON"):
        load_run(rec.path)
    from cli.main import main

    assert main(["runs", "show", rec.run_id]) == 2


def test_gc_keeps_objects_referenced_by_runs():
    from repro.keys import content_key
    from repro.store.objects import Store

    store = Store()
    used, unused = content_key("used"), content_key("unused")
    rec = RunRecorder(table="t")
    rec.start()
    for k in (used, unused):
        store.compute(k, "demo", lambda out: (out / "f").write_text("x"))
    rec.record_job({"kind": "demo", "key": used, "status": "computed"})
    # while the run is live, everything created since it started is kept
    assert collect_garbage(dry_run=True).objects == []
    rec.finish()
    rep = collect_garbage()
    assert [o.key for o in rep.objects] == [unused]
    assert store.has(used) and not store.has(unused)


def test_runs_cli_ls_show_diff_reindex(capsys):
    from cli.main import main

    a = _make_run(lr=1e-4, values=((0.5, 0.7), (0.5, 0.7)))
    b = _make_run(lr=2e-4, values=((0.4, 0.8), (0.6, 0.8)))
    assert main(["runs", "ls", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["run_id"] for r in rows] == [b.run_id, a.run_id]
    assert rows[0]["n_values"] == 4 and rows[0]["table_id"] == "marionette/table3"
    assert main(["runs", "ls", "--table", "other"]) == 0
    assert "0 runs" in capsys.readouterr().out
    assert main(["runs", "show", a.run_id[:-2], "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["run"]["config"]["lr"] == 1e-4 and len(shown["values"]) == 4
    assert shown["summary"]["schema"] == 1
    assert main(["runs", "show", "latest"]) == 0
    out = capsys.readouterr().out
    assert b.run_id in out and "MARIONET" in out and "FINISHED" in out
    assert main(["runs", "diff", a.run_id, b.run_id, "--json"]) == 0
    diff = json.loads(capsys.readouterr().out)
    by_field = {(r["section"], r["field"]): r for r in diff["rows"]}
    assert by_field[("config", "lr")]["values"] == ["0.0001", "0.0002"]
    assert by_field[("config", "lr")]["differs"]
    assert not by_field[("config", "model.width")]["differs"]
    assert by_field[("cells", "MARIONET | fid")]["values"] == ["0.5 (n=2)", "0.5 (n=2)"]
    assert not by_field[("cells", "MARIONET | fid")]["differs"]
    assert by_field[("cells", "MARIONET | acc")]["differs"]
    assert main(["runs", "diff", a.run_id, b.run_id, "--only-diff", "--json"]) == 0
    only = json.loads(capsys.readouterr().out)["rows"]
    assert only and all(r["differs"] for r in only)
    assert {("config", "lr"), ("cells", "MARIONET | acc")} <= {(r["section"], r["field"])
                                                                 for r in only}
    assert main(["runs", "diff", a.run_id, b.run_id, "--only-diff"]) == 0
    out = capsys.readouterr().out
    assert "fields differ" in out and "model.width" not in out
    assert main(["runs", "diff", a.run_id]) == 2
    assert main(["runs", "reindex"]) == 0
    assert "indexed 2 runs" in capsys.readouterr().out
