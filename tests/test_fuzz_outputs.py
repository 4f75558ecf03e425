"""Property-based fuzzing (Hypothesis) of the run index and of the folders commands write into
(issue 29); the conventions of ``tests/test_fuzz.py`` (docs/fuzzing.md).

Targets:

- **run index**: a store of three finished runs and its ``runs.sqlite``, damaged: random byte
  edits or a truncation of ``runs.sqlite``, the file replaced by a folder, a FIFO or a link to
  ``/dev/zero``; random JSON values (huge integers, NaN, lone surrogates, nested lists and
  objects) in ``run.json`` fields or in place of the whole record; ``values.jsonl`` lines of
  random fields or bytes; files deleted, made folders or FIFOs.  Then ``repro runs ls``
  (:meth:`repro.store.index.RunIndex.list`, or ``main(["runs", "ls", "--json"])``).
  Properties: nothing but a ReproError escapes; the listing holds every run that was not
  damaged and no other; a damaged index alone loses no run; no run folder disappears.
- **--out**: ``repro export | strips | report`` writing into random places: a new folder, an
  existing one, a link to a folder, a link to a file outside, a file, a FIFO, ``/dev/null``,
  ``/proc/...``, ``''``, names of 255 to 5,000 characters, a NUL, a path under a file; inside
  the folder, links to a file or folder outside, FIFOs, files and folders planted at the names
  the command writes.  Properties: nothing but a ReproError escapes; nothing outside the
  intended folder changes (bytes and names compared); what a successful write leaves at each
  output name is a regular file (never a link).  The report's plots are stubbed with the real
  file writers (matplotlib drawing is not what is fuzzed; it costs 0.5 s a page).

Examples: :data:`DEFAULT_EXAMPLES` per test (the report test a fifth; each default test
stays under ~4 s), or
``REPRO_FUZZ_EXAMPLES=N``; ``REPRO_FUZZ_LOG=path.jsonl`` records foreign exceptions instead of
failing at the first one and appends a summary line, as in ``tests/test_fuzz.py``.
"""

from __future__ import annotations

import atexit
import contextlib
import json
import os
import shutil
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fuzz_findings import FOREIGN, REFUSED, Findings, shown_text

DEFAULT_EXAMPLES = 50
_ENV = os.environ.get("REPRO_FUZZ_EXAMPLES", "").strip()
if _ENV and not (_ENV.isdigit() and int(_ENV) > 0):
    raise ValueError(f"REPRO_FUZZ_EXAMPLES must be a positive integer, got {_ENV!r}")
EXAMPLES = int(_ENV) if _ENV else DEFAULT_EXAMPLES
LOG = os.environ.get("REPRO_FUZZ_LOG") or None
FUZZ = settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
                suppress_health_check=list(HealthCheck), print_blob=False)
FUZZ_REPORT = settings(FUZZ, max_examples=max(10, EXAMPLES // 5))

_WORK = Path(tempfile.mkdtemp(prefix="repro-fuzz-out-"))
atexit.register(shutil.rmtree, _WORK, ignore_errors=True)
_FINDINGS = Findings(LOG, chained_where=False)
_REFUSED, _FOREIGN = REFUSED, FOREIGN
_COUNTS, _ACCEPTED = _FINDINGS.counts, _FINDINGS.accepted
_FOUND, _TIMES = _FINDINGS.found, _FINDINGS.times
_SEQ = iter(range(10 ** 9))
_shown, call, fail = shown_text, _FINDINGS.call, _FINDINGS.fail


@pytest.fixture(scope="module", autouse=True)
def _fuzz_summary():
    t0 = time.perf_counter()
    yield
    shutil.rmtree(_WORK, ignore_errors=True)
    _FINDINGS.write_log({"summary": True, "module": "test_fuzz_outputs",
                         "examples_per_test": EXAMPLES}, t0)


@pytest.fixture(autouse=True)
def _timed(request):
    t0 = time.perf_counter()
    yield
    _TIMES[request.node.name] = round(time.perf_counter() - t0, 1)


@contextlib.contextmanager
def _env(**kw):
    old = {k: os.environ.get(k) for k in kw}
    os.environ.update(kw)
    try:
        yield
    finally:
        for k, v in old.items():
            os.environ.pop(k, None) if v is None else os.environ.__setitem__(k, v)


# ============================================================================ values
_HUGE = st.sampled_from([2 ** 31, 2 ** 63 - 1, 2 ** 63, 2 ** 64, 2 ** 70, -2 ** 63 - 1, 10 ** 30,
                         10 ** 400, 4194304, -1, 0, 1])
_TEXTS = st.sampled_from(["", "FINISHED", "RUNNING", "QUEUED", "hit", "computed", "walk\ud800",
                          "\udfff", "x" * 5000, "\x00", "\x1b]0;x\x07", "a/b", "1e999"])
json_scalars = st.one_of(st.none(), st.booleans(), st.integers(), _HUGE,
                         st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
                         _TEXTS)
json_values = st.recursive(
    json_scalars, lambda c: st.lists(c, max_size=4) | st.dictionaries(
        st.text(max_size=6) | st.sampled_from(["status", "key", "read", "written", "pid",
                                               "host", "row", "value"]), c, max_size=4),
    max_leaves=10)
byte_edits = st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), min_size=1, max_size=24)


def _edit(data: bytes, edits) -> bytes:
    b = bytearray(data)
    for where, byte in edits:
        if b:
            b[min(int(where * len(b)), len(b) - 1)] = byte
    return bytes(b)


# ============================================================================ run index
_RUN_FIELDS = ["schema", "run_id", "status", "status_history", "table", "spec", "config", "scale",
               "dataset", "git", "packages", "env", "command", "created", "started", "ended",
               "keys", "jobs", "error", "note", "extra", ("env", "pid"), ("env", "host"),
               ("env", "pid_start"), ("spec", "hash"), ("spec", "version"), ("keys", "read"),
               ("git", "commit"), ("git", "dirty")]
index_damage = st.one_of(
    st.tuples(st.just("index-bytes"), byte_edits),
    st.tuples(st.just("index-truncate"), st.floats(0, 1)),
    st.tuples(st.sampled_from(["index-folder", "index-fifo", "index-devzero", "index-empty"])))
run_damage = st.one_of(
    st.tuples(st.just("run-field"), st.integers(0, 2), st.sampled_from(_RUN_FIELDS), json_values),
    st.tuples(st.just("run-drop-field"), st.integers(0, 2), st.sampled_from(_RUN_FIELDS[:21])),
    st.tuples(st.just("run-whole"), st.integers(0, 2), json_values),
    st.tuples(st.just("run-bytes"), st.integers(0, 2), byte_edits),
    st.tuples(st.just("job"), st.integers(0, 2), st.sampled_from(["key", "status", "kind"]),
              json_values),
    st.tuples(st.just("values-line"), st.integers(0, 2), st.fixed_dictionaries(
        {}, optional={k: json_values for k in ("row", "column", "replicate", "value")})),
    st.tuples(st.just("values-json"), st.integers(0, 2), json_values),
    st.tuples(st.just("values-bytes"), st.integers(0, 2), byte_edits),
    st.tuples(st.sampled_from(["no-run-json", "run-json-folder", "values-folder",
                               "run-json-fifo", "values-fifo", "summary-fifo"]),
              st.integers(0, 2)))


def _template() -> Path:
    """Three finished runs (with values and jobs) and their index, made once."""
    root = _WORK / "template"
    if root.exists():
        return root
    from repro.store.index import RunIndex
    from repro.store.runs import RunRecorder

    for i in range(3):
        r = RunRecorder(table=f"marionette/table{i + 1}", config={"i": i}, command=["repro"],
                        runs_dir=root / "runs", index=False, spec_version=1, spec_hash="ab" * 8)
        with r:
            r.record_job({"kind": "generate", "key": f"{i:064x}", "status": "computed",
                          "seconds": 1.5})
            r.add_values([{"row": "a", "column": "b", "replicate": k, "value": 0.5 * k}
                          for k in range(3)])
    RunIndex(root / "runs.sqlite", root / "runs").reindex()
    return root


def _apply(home: Path, damage, ids: list[str]) -> int | None:
    """Damage the copy ``home``; returns the damaged run's position (None: the index only)."""
    kind = damage[0]
    idx = home / "runs.sqlite"
    if kind.startswith("index"):
        if idx.is_symlink() or not idx.is_file():  # an earlier damage replaced it already
            return None
        if kind == "index-bytes":
            idx.write_bytes(_edit(idx.read_bytes(), damage[1]))
        elif kind == "index-truncate":
            idx.write_bytes(idx.read_bytes()[:int(damage[1] * idx.stat().st_size)])
        elif kind == "index-empty":
            idx.write_bytes(b"")
        else:
            idx.unlink()
            if kind == "index-folder":
                (idx / "sub").mkdir(parents=True)
            elif kind == "index-fifo":
                os.mkfifo(idx)
            else:
                idx.symlink_to("/dev/zero")
        return None
    which = damage[1]
    d = home / "runs" / ids[which]
    for f in d.iterdir():
        os.chmod(f, 0o644)
    rj, vals = d / "run.json", d / "values.jsonl"
    dump = lambda x: json.dumps(x, allow_nan=True)  # noqa: E731 - \ud800 stays an escape
    if kind in ("run-field", "run-drop-field", "job"):
        data = json.loads(rj.read_text())
        if kind == "job":
            data["jobs"][0][damage[2]] = damage[3]
        else:
            field = damage[2]
            obj, key = (data, field) if isinstance(field, str) else (data[field[0]], field[1])
            if kind == "run-field":
                obj[key] = damage[3]
            else:
                obj.pop(key, None)
        rj.write_text(dump(data))
    elif kind == "run-whole":
        rj.write_text(dump(damage[2]))
    elif kind == "run-bytes":
        rj.write_bytes(_edit(rj.read_bytes(), damage[2]))
    elif kind == "values-line":
        line = {"row": "a", "column": "b", "replicate": 0, "value": 0.5, **damage[2]}
        vals.write_text(vals.read_text() + dump(line) + "\n")
    elif kind == "values-json":
        vals.write_text(dump(damage[2]) + "\n" + vals.read_text())
    elif kind == "values-bytes":
        vals.write_bytes(_edit(vals.read_bytes(), damage[2]))
    elif kind == "no-run-json":
        rj.unlink()
    elif kind == "run-json-folder":
        rj.unlink()
        rj.mkdir()
    elif kind == "values-folder":
        vals.unlink()
        vals.mkdir()
    elif kind.endswith("-fifo"):  # reading one would block: it must be refused unread
        f = {"run": rj, "values": vals, "summary": d / "summary.json"}[kind.split("-")[0]]
        f.unlink(missing_ok=True)
        os.mkfifo(f)
    return which


def _list(home: Path, via_cli: bool) -> list[str]:
    from repro.store.index import RunIndex

    if not via_cli:
        return [r["run_id"] for r in RunIndex(home / "runs.sqlite", home / "runs").list()]
    import io
    from contextlib import redirect_stdout

    from cli.main import main

    buf = io.StringIO()
    with _env(REPRO_HOME=str(home)), redirect_stdout(buf):
        rc = main(["runs", "ls", "--json"])
    if rc != 0:
        raise AssertionError(f"runs ls exited {rc}")
    return [r["run_id"] for r in json.loads(buf.getvalue())]


@FUZZ
@given(damages=st.lists(st.one_of(index_damage, run_damage), min_size=1, max_size=3),
       via_cli=st.booleans())
def test_runs_ls_survives_a_damaged_index_and_run_folders(damages, via_cli):
    template = _template()
    home = _WORK / f"home-{next(_SEQ)}"
    shutil.copytree(template, home, symlinks=True)
    ids = sorted(p.name for p in (template / "runs").iterdir())
    try:
        hit: set[int] = set()
        for d in damages:  # one damage per run folder (a second would find the first's)
            if d[0].startswith("index") or d[1] not in hit:
                hit |= {_apply(home, d, ids)} - {None}
        shown = {"damages": damages, "via_cli": via_cli}
        with _quiet():
            got = call("run index", _list, home, via_cli, shown=shown)
            again = call("run index", _list, home, via_cli, shown=shown) \
                if isinstance(got, list) else None
        if got is _FOREIGN or again is _FOREIGN:
            return
        if got is _REFUSED:
            fail("run index", "runs ls refused a store with a damaged index or run folder",
                 shown)
            return
        intact = {ids[i] for i in range(3) if i not in hit}
        if not intact <= set(got) <= set(ids) or len(got) != len(set(got)):
            fail("run index", f"runs ls listed {got}, intact runs {sorted(intact)}", shown)
        if again != got:
            fail("run index", f"a second listing differs: {again} after {got}", shown)
        if sorted(p.name for p in (home / "runs").iterdir()) != ids:
            fail("run index", "a run folder disappeared", shown)
    finally:
        shutil.rmtree(home, ignore_errors=True)


@contextlib.contextmanager
def _quiet():
    """The index's one-line warnings are expected here; keep them off the test output."""
    import logging

    log = logging.getLogger("repro.runs")
    old = log.disabled
    log.disabled = True
    try:
        yield
    finally:
        log.disabled = old


# ============================================================================ --out
_NAMES = ["index.html", "report.json", "marionette-table1.html", "marionette-table1",
          "strips.json", "export.json", "marionette-table1/cells.png",
          "marionette-table1/cells.csv"]
out_places = st.one_of(
    st.sampled_from(["new", "new-nested", "existing", "link-to-folder", "link-to-file", "file",
                     "fifo", "/dev/null", "/proc/repro-x", "/proc/self", "", ".", "under-file",
                     "nul", "link-loop"]),
    st.tuples(st.just("long"), st.sampled_from([255, 256, 1000, 4097, 5000])))
plants = st.lists(st.tuples(st.sampled_from(_NAMES), st.sampled_from(
    ["link-file", "link-folder", "link-dangling", "fifo", "file", "folder"])), max_size=4)


def _setup_out(base: Path, place, planted) -> tuple[str, Path | None]:
    """The ``--out`` text and the folder it means (None when it cannot be one)."""
    outside, target, cwd = base / "outside", base / "target", base / "cwd"
    (outside / "victim-folder").mkdir(parents=True)
    (outside / "victim.txt").write_text("precious\n")
    target.mkdir()
    cwd.mkdir()
    out = cwd / "out"
    if isinstance(place, tuple):  # a name over NAME_MAX (255) cannot be made
        return "y" * place[1], (cwd / ("y" * place[1]) if place[1] <= 255 else None)
    text, folder = str(out), out
    if place == "new-nested":
        text = str(cwd / "a" / "b" / "out")
        folder = Path(text)
    elif place == "existing":
        out.mkdir()
    elif place == "link-to-folder":
        out.symlink_to(target, target_is_directory=True)
        folder = target
    elif place == "link-to-file":
        out.symlink_to(outside / "victim.txt")
    elif place == "file":
        out.write_text("a file")
    elif place == "fifo":
        os.mkfifo(out)
    elif place == "under-file":
        out.write_text("a file")
        text = str(out / "sub")
    elif place == "nul":
        text = str(out) + "\x00x"
    elif place == "link-loop":
        out.symlink_to(out)
    elif place == ".":
        text, folder = ".", cwd
    elif place != "new":
        text, folder = place, None
    if place in ("", "link-to-file", "file", "fifo", "under-file", "nul", "link-loop") or \
            folder is None:
        return text, None
    folder.mkdir(parents=True, exist_ok=True)
    for name, kind in planted:
        p = folder / name
        if os.path.lexists(p) or not p.parent.is_dir() or p.parent.is_symlink():
            continue
        if kind == "link-file":
            p.symlink_to(outside / "victim.txt")
        elif kind == "link-folder":
            p.symlink_to(outside / "victim-folder", target_is_directory=True)
        elif kind == "link-dangling":
            p.symlink_to(outside / "nothing-here")
        elif kind == "fifo":
            os.mkfifo(p)
        elif kind == "file":
            p.write_text("old")
        else:
            p.mkdir()
    if place == "new-nested":  # planted into a folder the command is to create: start clean
        shutil.rmtree(cwd / "a")
    return text, folder


def _state(folder: Path) -> dict:
    out = {}
    for root, dirs, files in os.walk(folder):
        for n in dirs + files:
            p = Path(root) / n
            out[str(p.relative_to(folder))] = (p.read_bytes() if p.is_file() and
                                               not p.is_symlink() else os.path.islink(p))
    return out


def _fake_rs():
    return SimpleNamespace(bands=[], spec=SimpleNamespace(id="marionette/table1"),
                           run_id="fuzz-run", run_path=None)


def _write(writer: str, text: str):
    if writer == "export":
        from repro.exporters.samples import export_samples

        return export_samples(_fake_rs(), text, replicate="all")  # no rows: export.json only
    if writer == "strips":
        from repro.report.strip_sets import write_strips

        return write_strips(_fake_rs(), text)
    from repro.report.html_report import write_report

    return write_report(["marionette/table1"], text, strips=False)


def _out_case(writer: str, place, planted) -> None:
    base = _WORK / f"out-{next(_SEQ)}"
    base.mkdir()
    cwd = Path.cwd()
    try:
        text, folder = _setup_out(base, place, planted)
        before = _state(base / "outside")
        shown = {"writer": writer, "out": place, "planted": planted}
        os.chdir(base / "cwd")
        try:
            got = call(f"--out ({writer})", _write, writer, text, shown=shown)
        finally:
            os.chdir(cwd)
        if _state(base / "outside") != before:
            fail(f"--out ({writer})", "something outside the intended folder changed", shown)
        if got is _REFUSED or got is _FOREIGN:
            return
        if folder is None:
            fail(f"--out ({writer})", f"wrote into {text!r}, which is not a folder", shown)
            return
        main = {"export": "export.json", "strips": "strips.json", "report": "index.html"}[writer]
        names = [main] + (["report.json", "marionette-table1.html", "marionette-table1/cells.png",
                           "marionette-table1/cells.csv"] if writer == "report" else [])
        for n in names:
            p = folder / n
            if p.is_symlink() or not p.is_file():
                fail(f"--out ({writer})", f"{n} is not a regular file after the write", shown)
    finally:
        shutil.rmtree(base, ignore_errors=True)


@FUZZ
@given(writer=st.sampled_from(["export", "strips"]), place=out_places, planted=plants)
def test_export_and_strips_out_write_only_into_their_folder(writer, place, planted):
    _out_case(writer, place, planted)


@pytest.fixture
def _tiny_report(tmp_path_factory, monkeypatch):
    """The reduced Marionette Table 1 of test_tables_engine with one recorded run (its page
    is made from the run's summary: no plan built, no clips loaded); plots drawn by stubs
    that write through the same writers as the real ones."""
    from repro.paths import repo_root
    from test_hardening_outputs import _table1_run, stub_report_plots
    from test_tables_engine import TINY_SCALES, _reduced_table1

    root = tmp_path_factory.mktemp("tables")
    _reduced_table1(repo_root() / "tables" / "marionette" / "table1.toml",
                    root / "marionette" / "table1.toml")
    (root / "scales.toml").write_text(TINY_SCALES)
    monkeypatch.setenv("REPRO_TABLES", str(root))
    stub_report_plots(monkeypatch)
    _table1_run()  # the page made from a run's summary: no plan built, no clips loaded


@FUZZ_REPORT
@given(place=out_places, planted=plants)
def test_report_out_writes_only_into_its_folder(_tiny_report, place, planted):
    _out_case("report", place, planted)
