"""Issue 29, outputs and the run index: ``repro report | strips | export --out`` never write
through a link and refuse an ``--out`` that is not a folder; ``repro runs ls`` survives a
damaged index or run folder; ``--run ''`` says the id is empty; Markdown and LaTeX output
escape what spec labels carry.  Every test here failed on the code before these fixes."""

from __future__ import annotations

import json
import logging
import os
import sqlite3
from contextlib import closing

import pytest

from cli.main import main
from repro.errors import ConfigError
from repro.store.index import RunIndex
from repro.store.runs import RunRecorder, resolve_run
from test_tables_engine import tiny_tables  # noqa: F401 (fixture)


def _one_error_line(capsys, *needles) -> str:
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("repro: error:"), err
    for n in needles:
        assert n in lines[0], (n, lines[0])
    assert "Traceback" not in err
    return lines[0]


# ------------------------------------------------------------------------ --out
@pytest.fixture
def fifo(tmp_path):
    p = tmp_path / "pipe"
    os.mkfifo(p)
    return str(p)


@pytest.mark.parametrize("cmd", [["report", "marionette/table1"], ["strips", "marionette/table1"],
                                 ["export", "marionette/table1"]], ids=lambda c: c[0])
@pytest.mark.parametrize("out", ["/etc/passwd", "/dev/null", "/proc/x", "", "FIFO",
                                 "/etc/passwd/x", "x" * 300],
                         ids=["file", "devnull", "proc", "empty", "fifo", "under-a-file", "long"])
def test_an_out_that_cannot_be_a_folder_is_one_line_exit_2(cmd, out, fifo, capsys, tmp_path,
                                                           monkeypatch):
    monkeypatch.chdir(tmp_path)
    out = fifo if out == "FIFO" else out
    before = sorted(os.listdir(tmp_path))
    assert main([*cmd, "--out", out]) == 2
    _one_error_line(capsys, "--out")
    assert sorted(os.listdir(tmp_path)) == before  # '' did not write into the current folder


def _victims(tmp_path):
    outside = tmp_path / "outside"
    (outside / "linked-folder").mkdir(parents=True)
    victim = outside / "victim.txt"
    victim.write_text("precious\n")
    return outside, victim


def _snapshot(folder):
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(folder.rglob("*"))}


def stub_report_plots(monkeypatch) -> None:
    """The report's plots drawn by stubs that write through the real file writers (what is
    tested is where files go, not matplotlib's drawing, which costs seconds a page)."""
    from repro.render import plots
    from repro.store.atomic import write_output

    def plot(view, path, data_path=None, **kw):
        write_output(path, b"\x89PNG\r\n\x1a\n stub")
        if data_path is not None:
            plots.write_data(data_path, [{"row": "r"}], ["row"], {"kind": "stub"})

    for name in ("table_plot", "figure_plot", "learning_curve_plot"):
        monkeypatch.setattr(plots, name, plot)


@pytest.fixture
def stub_plots(monkeypatch):
    """:func:`stub_report_plots` for one test."""
    stub_report_plots(monkeypatch)


def test_report_replaces_links_in_out_and_never_writes_through_them(tiny_tables, stub_plots,  # noqa: F811
                                                                    tmp_path):
    from repro.report.html_report import write_report

    _table1_run()  # a recorded run, no strips: the page is made from its summary, no plan
    # built and no clips loaded (seconds saved; what is tested is where the files go)
    outside, victim = _victims(tmp_path)
    before = _snapshot(outside)
    out = tmp_path / "report"
    out.mkdir()
    for name in ("index.html", "report.json", "marionette-table1.html"):
        (out / name).symlink_to(victim)
    (out / "marionette-table1").symlink_to(outside / "linked-folder", target_is_directory=True)
    write_report(["marionette/table1"], out, strips=False)
    assert _snapshot(outside) == before  # nothing written through a link
    for name in ("index.html", "report.json", "marionette-table1.html", "marionette-table1"):
        assert not (out / name).is_symlink(), name
    assert {p.name for p in (out / "marionette-table1").iterdir()} >= {"cells.png", "cells.csv"}
    # links planted on the asset files themselves (a real folder this time) are replaced too
    for name in ("cells.png", "cells.csv"):
        (out / "marionette-table1" / name).unlink()
        (out / "marionette-table1" / name).symlink_to(victim)
    write_report(["marionette/table1"], out, strips=False)
    assert _snapshot(outside) == before
    assert not (out / "marionette-table1" / "cells.csv").is_symlink()


def test_output_helpers_refuse_files_where_folders_go(tmp_path):
    from repro.store.atomic import output_dir, output_subdir, write_output

    (tmp_path / "f").write_text("x")
    with pytest.raises(ConfigError, match="is a file, not a folder"):
        output_subdir(tmp_path, "f")
    with pytest.raises(ConfigError, match="is a file, not a folder"):
        output_dir(tmp_path / "f")
    (tmp_path / "d").mkdir()
    with pytest.raises(ConfigError, match="cannot write"):
        write_output(tmp_path / "d", b"x")  # a folder where the file goes
    assert output_dir(tmp_path / "a" / "b") == tmp_path / "a" / "b"


# ------------------------------------------------------------------------ run index
def _run(i: int) -> RunRecorder:
    r = RunRecorder(table="marionette/table3", config={"i": i}, command=["repro", "run"])
    with r:
        r.add_values([{"row": "a", "column": "b", "replicate": 0, "value": 0.5 + i}])
    return r


def _ls(capsys) -> tuple[list[str], str]:
    assert main(["runs", "ls", "--json"]) == 0
    got = capsys.readouterr()
    return [r["run_id"] for r in json.loads(got.out)], got.err


def _corrupt_runs_table(path) -> None:
    """Break the b-tree page holding the ``runs`` rows, leaving the header, the schema and the
    SQL indexes intact (``SELECT count(*)`` still answers; reading a row does not)."""
    with sqlite3.connect(path) as con:
        root = con.execute("SELECT rootpage FROM sqlite_master WHERE name='runs'").fetchone()[0]
        size = con.execute("PRAGMA page_size").fetchone()[0]
    data = bytearray(path.read_bytes())
    start = (root - 1) * size
    data[start:start + 12] = b"\xff" * 12
    path.write_bytes(bytes(data))


def test_an_index_with_corrupt_pages_is_moved_aside_and_rebuilt(capsys, caplog):
    runs = [_run(i) for i in range(3)]
    idx = RunIndex()
    assert len(idx.list()) == 3
    _corrupt_runs_table(idx.path)
    with caplog.at_level(logging.WARNING, logger="repro.runs"):
        ids, _ = _ls(capsys)
    assert sorted(ids) == sorted(r.run_id for r in runs)
    aside = list(idx.path.parent.glob("runs.sqlite.corrupt-*"))
    assert len(aside) == 1
    warned = [r.getMessage() for r in caplog.records if "damaged" in r.getMessage()]
    assert len(warned) == 1 and aside[0].name in warned[0]
    assert all(r.path.is_dir() for r in runs)  # run folders are never touched


def test_an_index_replaced_by_a_folder_is_moved_aside(capsys):
    runs = [_run(i) for i in range(2)]
    idx = RunIndex()
    idx.path.unlink()
    idx.path.mkdir()
    (idx.path / "junk").write_text("x")
    ids, _ = _ls(capsys)
    assert sorted(ids) == sorted(r.run_id for r in runs)
    assert idx.path.is_file()
    assert [p for p in idx.path.parent.glob("runs.sqlite.corrupt-*") if p.is_dir()]


def test_an_index_with_bytes_that_are_not_utf8_is_rebuilt(capsys):
    """Found by tests/test_fuzz_outputs.py: a byte edit in the stored schema makes SQLite's
    error message quote bytes that are not UTF-8, and sqlite3 raises UnicodeDecodeError (not
    a DatabaseError) decoding it."""
    runs = [_run(i) for i in range(2)]
    idx = RunIndex()
    idx.list()
    data = idx.path.read_bytes()
    at = data.index(b"indexrun_keys_key") + len(b"index")  # the schema row's index name
    idx.path.write_bytes(data[:at] + b"\x8c" + data[at + 1:])
    ids, _ = _ls(capsys)
    assert sorted(ids) == sorted(r.run_id for r in runs)


def test_an_index_row_whose_text_is_not_utf8_is_rebuilt(capsys):
    """Found by the long fuzz run (issue 29): a byte edit inside a stored row's text (the last
    byte of the file, in the ``digest`` column) makes sqlite3 raise an OperationalError "Could
    not decode to UTF-8 column ..." while listing; it was taken for an unusable store (exit 2)
    instead of damage (moved aside, rebuilt)."""
    runs = [_run(i) for i in range(3)]
    idx = RunIndex()
    idx.list()
    data = bytearray(idx.path.read_bytes())
    digest = max(data.rfind(bytes(c, "ascii")) for c in "0123456789abcdef")
    data[digest] = 0xD6  # the row's last digest character becomes a lone UTF-8 lead byte
    idx.path.write_bytes(bytes(data))
    ids, err = _ls(capsys)
    assert sorted(ids) == sorted(r.run_id for r in runs)
    assert list(idx.path.parent.glob("runs.sqlite.corrupt-*")), err


def _damage(path, how: str) -> None:
    for f in path.iterdir():
        os.chmod(f, 0o644)
    if how in ("values-fifo", "run-json-fifo"):  # reading one blocked runs ls for ever
        f = path / ("values.jsonl" if how == "values-fifo" else "run.json")
        f.unlink()
        os.mkfifo(f)
        return
    if how in ("replicate", "dict-value"):
        line = {"row": "a", "column": "b", "replicate": 0, "value": 1.0}
        line.update(replicate=2 ** 70) if how == "replicate" else line.update(value={"x": 1})
        (path / "values.jsonl").write_text(json.dumps(line) + "\n")
        return
    rj = json.loads((path / "run.json").read_text())
    if how == "status-list":
        rj["status"] = ["FINISHED"]
    elif how == "surrogate":
        rj["table"] = "walk\ud800"
    elif how == "jobs-str":
        rj["jobs"] = "oops"
    elif how == "pid":
        rj["status"], rj["env"]["pid"] = "RUNNING", 2 ** 70
    (path / "run.json").write_text(json.dumps(rj))


@pytest.mark.parametrize("how", ["replicate", "dict-value", "status-list", "surrogate",
                                 "jobs-str", "pid", "values-fifo", "run-json-fifo"])
def test_a_damaged_run_folder_is_left_out_with_one_warning(how, capsys, caplog):
    good, bad, other = (_run(i) for i in range(3))
    assert len(RunIndex().list()) == 3
    _damage(bad.path, how)
    with caplog.at_level(logging.WARNING, logger="repro.runs"):
        ids, _ = _ls(capsys)
    assert sorted(ids) == sorted([good.run_id, other.run_id])
    warned = [r.getMessage() for r in caplog.records if bad.run_id in r.getMessage()]
    assert len(warned) == 1, warned
    # the good runs still show; the damaged one is one error line
    assert main(["runs", "show", good.run_id]) == 0
    capsys.readouterr()
    assert main(["runs", "show", bad.run_id]) == 2
    _one_error_line(capsys, bad.run_id)


# ------------------------------------------------------------------------ --run ''
def test_an_empty_run_id_says_so(capsys):
    _run(0)
    with pytest.raises(ConfigError, match="the run id is empty"):
        resolve_run("")
    assert main(["runs", "show", ""]) == 2
    _one_error_line(capsys, "the run id is empty")
    for cmd in (["show", "marionette/table1"], ["report", "marionette/table1", "--out", "r"],
                ["strips", "marionette/table1", "--out", "s"], ["export", "marionette/table1",
                                                                "--list"]):
        with pytest.raises(SystemExit) as e:
            main([*cmd, "--run", ""])
        assert e.value.code == 2
        err = capsys.readouterr().err  # argparse's refusal is one line too (no usage block)
        assert "the run id is empty" in err and err.count("\n") == 1, err


# ------------------------------------------------------------------------ md / LaTeX
def _view():
    from repro.report.view import CellView, ClaimView, ColumnView, RowView, TableView

    evil = "<script>alert(1)</script> & co | $x^2$ ~{y}_#1 %c \\d"
    return TableView(id="t/x", title=evil, paper="p",
                     columns=[ColumnView(id="c", label=evil)],
                     rows=[RowView(id="r", label=evil, method="m", status="ok",
                                   cells={"c": CellView(reported=evil)})],
                     claims=[ClaimView(id="k", text="line one\n\\input{/etc/passwd}")],
                     footer=["foot <b>\n\\write18{x}"])


def test_markdown_escapes_html_and_latex_escapes_every_special():
    from repro.report.render import _tex, render

    md = render(_view(), "md")
    assert "<script>" not in md and "<b>" not in md
    assert "&lt;script&gt;alert(1)&lt;/script&gt; &amp; co \\| $x^2$" in md
    assert all(not ln.startswith("\\input") for ln in md.splitlines())
    tex = render(_view(), "latex")
    assert (r"\& co | \$x\textasciicircum{}2\$ \textasciitilde{}\{y\}\_\#1 \%c "
            r"\textbackslash{}d") in tex
    assert "$x^2$" not in tex and "~{y}" not in tex
    for ln in tex.splitlines():  # a line break in a claim or footer stays inside its comment
        assert not ln.startswith(("\\input", "\\write18")), ln
    assert _tex("±↓") == r"$\pm$$\downarrow$"


# ------------------------------------------------------------------------ run readers (review)
def _table1_run(summary=None, **config):
    """A FINISHED plain run of Marionette Table 1 at the quick scale (what `repro show` picks)."""
    from repro.engine.runner import table_scale, table_spec

    sc = table_scale("quick", None)
    r = RunRecorder(table="marionette/table1", scale=sc.name,
                    dataset=sc.dataset_for(table_spec("marionette/table1")),
                    config={"budget": 1.0, "evaluator_seed": 0, "retrain": False, **config})
    with r:
        r.write_summary(summary if summary is not None else {"rows": {}, "footer": []})
    return r


def _damage_table1(path, how: str) -> None:
    rj, sf = path / "run.json", path / "summary.json"
    if how in ("budget", "seed"):
        data = json.loads(rj.read_text())
        data["config"]["budget" if how == "budget" else "evaluator_seed"] = "x"
        rj.write_text(json.dumps(data))
    elif how == "summary-list":
        sf.write_text("[1]")
    elif how == "summary-missing":
        sf.unlink()
    elif how == "summary-fifo":
        sf.unlink()
        os.mkfifo(sf)
    elif how == "summary-huge":  # sparse: over the 16 MiB cap, nothing read
        os.truncate(sf, 3 << 30)


@pytest.mark.parametrize("how", ["budget", "seed", "summary-list", "summary-missing",
                                 "summary-fifo", "summary-huge"])
def test_show_skips_a_damaged_run_with_one_warning_and_uses_the_newest_good_one(how, capsys):
    from repro.engine.runner import latest_run

    good = _table1_run()
    bad = _table1_run()
    _damage_table1(bad.path, how)
    assert main(["show", "marionette/table1"]) == 0  # before: ValueError, AttributeError,
    err = capsys.readouterr().err                    # FileNotFoundError or a hang
    warned = [ln for ln in err.splitlines() if bad.run_id in ln]
    assert len(warned) == 1 and warned[0].startswith("repro: warning: skipping run"), err
    assert "Traceback" not in err
    assert latest_run("marionette/table1") == good.path
    assert main(["show", "marionette/table1", "--run", bad.run_id]) == 2
    _one_error_line(capsys, bad.run_id)


def test_a_huge_sparse_values_file_is_refused_without_reading_it(tmp_path):
    """A sparse 3 GB ``values.jsonl`` in one run folder: `runs ls` (in a process limited to
    1 GiB) lists the other runs, with one warning naming the file's cap."""
    import subprocess
    import sys
    import textwrap

    good, bad = _run(0), _run(1)
    os.truncate(bad.path / "values.jsonl", 3 << 30)
    code = textwrap.dedent("""
        import resource, sys
        resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))
        from cli.main import main
        sys.exit(main(["runs", "ls", "--json"]))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, env={**os.environ})
    assert out.returncode == 0, out.stderr
    assert [r["run_id"] for r in json.loads(out.stdout)] == [good.run_id]
    warned = [ln for ln in out.stderr.splitlines() if bad.run_id in ln]
    assert len(warned) == 1 and "cap" in warned[0], out.stderr


def test_runs_export_all_skips_a_run_whose_values_are_damaged(capsys, monkeypatch):
    from repro.exporters import mlflow_runs as mlflow_export

    good, bad = _run(0), _run(1)
    _damage(bad.path, "replicate")
    seen = []
    monkeypatch.setattr(mlflow_export, "export_runs",
                        lambda refs, *a, **k: seen.extend(refs) or [])
    assert main(["runs", "export", "--all", "--mlflow", "file:///nowhere"]) == 0
    assert [p.name for p in seen] == [good.run_id]
    err = capsys.readouterr().err
    assert len([ln for ln in err.splitlines() if bad.run_id in ln]) == 1, err


def test_the_corrupt_index_warning_is_one_line(capsys, caplog):
    """A wrong fragment count on the ``runs`` page: ``SELECT count(*)`` still answers, and
    ``quick_check`` reports it in a row of several lines (``*** in database main ***`` first)."""
    [_run(i) for i in range(3)]
    idx = RunIndex()
    idx.list()
    with sqlite3.connect(idx.path) as con:
        root = con.execute("SELECT rootpage FROM sqlite_master WHERE name='runs'").fetchone()[0]
        size = con.execute("PRAGMA page_size").fetchone()[0]
    data = bytearray(idx.path.read_bytes())
    data[(root - 1) * size + 7] ^= 0x1f  # the page's count of fragmented free bytes
    idx.path.write_bytes(bytes(data))
    with caplog.at_level(logging.WARNING, logger="repro.runs"):
        _ls(capsys)
    warned = [r.getMessage() for r in caplog.records if "damaged" in r.getMessage()]
    assert len(warned) == 1 and "quick_check" in warned[0] and "\n" not in warned[0], warned


def test_a_read_only_index_is_one_error_line_and_is_not_moved_aside(capsys, monkeypatch):
    """``attempt to write a readonly database`` is not damage: nothing is moved aside."""
    _run(0)
    new = _run(1)
    idx = RunIndex()
    idx.list()
    with closing(sqlite3.connect(idx.path)) as con, con:  # `runs ls` must write it back
        con.execute("DELETE FROM runs WHERE run_id = ?", (new.run_id,))

    def read_only(self, path):  # as SQLite opens a file on a read-only mount (root passes chmod)
        con = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=1)
        con.row_factory = sqlite3.Row
        return con

    monkeypatch.setattr(RunIndex, "_open", read_only)
    assert main(["runs", "ls"]) == 2
    _one_error_line(capsys, "run index", "readonly")
    assert idx.path.is_file()
    assert not list(idx.path.parent.glob("runs.sqlite.corrupt-*"))


def test_checking_a_missing_out_folder_makes_nothing_outside_it(tmp_path, monkeypatch):
    from repro.store import atomic

    def no_mkdir(*a, **k):
        raise AssertionError(f"mkdir {a} during a check")

    monkeypatch.setattr(os, "mkdir", no_mkdir)
    assert atomic.output_dir(tmp_path / "a" / "b", create=False) == tmp_path / "a" / "b"
    monkeypatch.setattr(os, "access", lambda *a, **k: False)
    with pytest.raises(ConfigError, match="no permission"):
        atomic.output_dir(tmp_path / "c", create=False)


@pytest.mark.parametrize("fail", ["mkdir", "write"])
def test_data_bundle_out_that_cannot_be_made_is_one_line(fail, capsys, monkeypatch, tmp_path):
    """``--out`` passes the check, then cannot be made after the prepare (here a file appears
    there meanwhile); a write failing inside the bundle (a full disk) is one line too, not a
    traceback after the whole prepare."""
    from types import SimpleNamespace

    from cli.commands import data as data_cmd
    from repro.data import bandai, bundle

    out = tmp_path / "b"
    fp = SimpleNamespace(fingerprint="f")

    def prepare(*a, **k):
        if fail == "mkdir":
            out.write_text("not a folder")
        return fp

    monkeypatch.setattr(data_cmd, "_prepare_bandai", prepare)
    monkeypatch.setattr(bandai, "load_bandai2", lambda *a, **k: fp)
    monkeypatch.setattr(data_cmd, "_default_source", lambda s: None)

    def build_mini(clips, out_dir):
        from pathlib import Path

        Path(out_dir).mkdir(parents=True, exist_ok=True)  # what the real one does first
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(bundle, "build_mini", build_mini)
    assert main(["data", "bundle", "--out", str(out)]) == 2
    _one_error_line(capsys, "is a file" if fail == "mkdir" else "No space left")


def test_out_on_a_pseudo_file_system_is_refused_by_the_check():
    """A guard for the check above (not a before/after test: the old probe refused it too):
    root passes ``os.access`` on ``/proc``, so the file system itself is looked at."""
    from repro.store.atomic import output_dir

    with pytest.raises(ConfigError, match="cannot be made"):
        output_dir("/proc/repro-x/y", create=False)
