"""Property-based fuzzing (Hypothesis) of the readers that take untrusted input.

Targets: the BVH parser (:func:`repro.data.bvh.parse_bvh`), the table spec and scale loaders
(:func:`repro.specs.load.load_spec`, :func:`repro.specs.scales.load_scales` and
:func:`~repro.specs.scales.resolve_scale`), and the restricted unpickler
(:func:`repro.data.upstream.restricted_pickle.loads_restricted`) with the HumanAct12 reader on
top of it (:func:`repro.data.upstream.humanact12.read_humanact12`), and declared data sets: spec
files, labels side files, and sources that are hostile tar archives, prepared end to end
(:func:`repro.data.dataset_prepare.prepare_dataset`).  Inputs come from
``tests/fuzz_strategies.py`` and ``tests/fuzz_dataset_strategies.py``.

Properties:

- any exception other than :class:`repro.errors.ReproError` (and its subclasses) is a failure;
- a pickle naming a disallowed global never runs it (a sentinel file never appears), and one
  that was not mutated is refused;
- a valid generated BVH parses, and gives back exactly the hierarchy, channels and frames it was
  generated from (which also checks the generator); anything a mutated file parses to is
  internally consistent (finite values, matching shapes);
- a well-formed generated HumanAct12 pickle reads, and a pickle that reads gives back its labels
  exactly (a label 1.5 must not become 1) and only finite values (1e39 must not become a
  float32 inf).

Example counts: ``make test`` runs each test with :data:`DEFAULT_EXAMPLES` examples,
derandomized (the same inputs on every run and machine, whatever else is collected: see
``_no_local_constants``), no example database.  A longer run:
``REPRO_FUZZ_EXAMPLES=N`` gives every test N examples (same derandomized stream, extended);
``REPRO_FUZZ_LOG=path.jsonl`` additionally records foreign exceptions instead of failing at the
first one, so the whole run completes, and appends per-target input counts, times and every
distinct finding (with its smallest input) to that file.  docs/fuzzing.md has the figures.
"""

from __future__ import annotations

import atexit
import contextlib
import json
import math
import os
import shutil
import tempfile
import time
from pathlib import Path

import fuzz_dataset_strategies as fzd
import fuzz_strategies as fz
from fuzz_findings import FOREIGN, REFUSED, Findings, shown_text
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from repro.data.bvh import MAX_DEPTH, Bvh, parse_bvh
from repro.data.upstream.humanact12 import read_humanact12
from repro.data.upstream.restricted_pickle import loads_restricted
from repro.specs.load import load_spec
from repro.specs.scales import SCALE_NAMES, load_scales, resolve_scale
from repro.specs.schema import TableSpec

# ------------------------------------------------------------------------------ settings
#: examples per test in `make test` (5 BVH, 3 spec, 4 pickle tests)
DEFAULT_EXAMPLES = 200
_ENV = os.environ.get("REPRO_FUZZ_EXAMPLES", "").strip()
if _ENV and not (_ENV.isdigit() and int(_ENV) > 0):
    raise ValueError(f"REPRO_FUZZ_EXAMPLES must be a positive integer, got {_ENV!r}")
EXAMPLES = int(_ENV) if _ENV else DEFAULT_EXAMPLES
LOG = os.environ.get("REPRO_FUZZ_LOG") or None

settings.register_profile(
    "repro-fuzz", max_examples=DEFAULT_EXAMPLES, deadline=None, derandomize=True, database=None,
    suppress_health_check=list(HealthCheck), print_blob=False)
settings.register_profile("repro-fuzz-long", parent=settings.get_profile("repro-fuzz"),
                          max_examples=EXAMPLES)
#: applied per test (the profiles are registered, never loaded globally, so other test modules
#: keep Hypothesis's defaults)
FUZZ = settings.get_profile("repro-fuzz-long" if _ENV else "repro-fuzz")

# ------------------------------------------------------------------------------ bookkeeping
_WORK = Path(tempfile.mkdtemp(prefix="repro-fuzz-"))
atexit.register(shutil.rmtree, _WORK, ignore_errors=True)  # also when no test here ran
SENTINEL = _WORK / "sentinel" / "fired"
SENTINEL.parent.mkdir()
_FINDINGS = Findings(LOG, chained_where=True)
_REFUSED, _FOREIGN = REFUSED, FOREIGN
_COUNTS, _ACCEPTED = _FINDINGS.counts, _FINDINGS.accepted
_TIMES, _FOUND = _FINDINGS.times, _FINDINGS.found
_shown, call, fail = shown_text, _FINDINGS.call, _FINDINGS.fail


@contextlib.contextmanager
def memory_cap(headroom: int = 512 << 20):
    """Lower the address-space limit to what the process uses now + ``headroom`` while a pickle
    is loaded, so a pickle that asks for gigabytes fails fast with MemoryError instead of
    taking the (shared) machine's memory.  Linux only; elsewhere a no-op."""
    try:
        import resource

        status = Path("/proc/self/status").read_text()
        vm = int(status.split("VmSize:")[1].split()[0]) * 1024
    except (ImportError, OSError, IndexError, ValueError):
        yield
        return
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = vm + headroom
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def check_sentinel(target: str, shown) -> None:
    fired = SENTINEL.exists()
    SENTINEL.unlink(missing_ok=True)
    if fired:
        fail(target, "a disallowed global ran: the sentinel file was created", shown)


@pytest.fixture(scope="module", autouse=True)
def _no_local_constants():
    """Keep the inputs the same whichever modules are loaded.

    Besides its seed, Hypothesis draws some values from constants it finds in the source of
    every local module imported so far (``hypothesis.internal.conjecture.providers``).  That
    pool depends on which test modules pytest collected and on edits anywhere in ``repro/``, so
    ``make test`` and ``pytest tests/test_fuzz.py`` would see different inputs.  Here the pool
    is empty (only Hypothesis's own constants and ours in fuzz_strategies.py are used).  The
    hook is internal to the pinned Hypothesis; if it is gone, this does nothing."""
    try:
        from hypothesis.internal.conjecture import providers
        from hypothesis.internal.constants_ast import Constants
        cache = providers.CONSTANTS_CACHE.cache
        hooked = callable(providers._get_local_constants)
    except (ImportError, AttributeError):
        hooked = False
    if not hooked:
        yield
        return
    empty = Constants()
    mp = pytest.MonkeyPatch()
    mp.setattr(providers, "_get_local_constants", lambda: empty)
    cache.clear()
    yield
    mp.undo()
    cache.clear()


@pytest.fixture(scope="module", autouse=True)
def _fuzz_summary():
    t0 = time.perf_counter()
    yield
    time.sleep(0.5)  # a subprocess.Popen that had been let through would have touched it by now
    check_sentinel("pickle", "(end of module: an asynchronous disallowed call)")
    shutil.rmtree(_WORK, ignore_errors=True)
    _FINDINGS.write_log({"summary": True, "examples_per_test": EXAMPLES}, t0)


@pytest.fixture(autouse=True)
def _timed(request):
    t0 = time.perf_counter()
    yield
    _TIMES[request.node.name] = round(time.perf_counter() - t0, 1)


# ============================================================================ BVH

def _bvh_invariants(b: Bvh) -> str | None:
    """What is wrong with a parsed file, or None: the parser must never hand back garbage."""
    J = len(b.names)
    if not (len(b.parents) == J == len(b.channels) and b.offsets.shape == (J, 3)):
        return "joint tables of different lengths"
    if b.parents[0] != -1 or any(not 0 <= p < j for j, p in enumerate(b.parents) if j):
        return f"parents {b.parents} are not a depth-first tree"
    if len(set(b.names)) != J:
        return "duplicate joint names"
    if b.motion.shape != (b.n_frames, b.n_channels) or b.n_frames < 1:
        return f"motion shape {b.motion.shape} for {b.n_channels} channels"
    if not (np.isfinite(b.motion).all() and np.isfinite(b.offsets).all()
            and np.isfinite(b.end_offsets).all()):
        return "non-finite values"
    if not (math.isfinite(b.frame_time) and b.frame_time > 0):
        return f"frame time {b.frame_time}"
    if any(not 0 <= p < J for p in b.end_parents):
        return "End Site of no joint"
    return None


@FUZZ
@given(case=fz.bvh_cases())
def test_valid_bvh_parses_to_what_was_generated(case):
    for data in (case.data, case.data.decode("utf-8")):
        got = call("bvh", parse_bvh, data, "fuzz.bvh", shown=case)
        if got is _FOREIGN:
            continue
        if got is _REFUSED:
            fail("bvh", "valid BVH refused", case)
            continue
        checks = {
            "joint count": (got.n_joints, len(case.names)),
            "frame count": (got.n_frames, case.motion.shape[0]),
            "names": (got.names, case.names),
            "parents": (got.parents, case.parents),
            "channels": (got.channels, case.channels),
            "end sites": (got.end_parents, case.end_parents),
            "frame time": (got.frame_time, case.frame_time),
        }
        for what, (a, b) in checks.items():
            if a != b:
                fail("bvh", f"valid BVH: {what} {a!r} != generated {b!r}", case)
        for what, a, b in (("offsets", got.offsets, case.offsets),
                           ("End Site offsets", got.end_offsets, case.end_offsets),
                           ("motion", got.motion, case.motion)):
            if a.shape != b.shape or not np.array_equal(a, b):
                fail("bvh", f"valid BVH: {what} differ from the generated ones", case)


def _parse_any(data) -> None:
    got = call("bvh", parse_bvh, data, "fuzz.bvh", shown=data)
    if isinstance(got, Bvh):
        problem = _bvh_invariants(got)
        if problem:
            fail("bvh", f"mutated BVH parsed to an inconsistent Bvh: {problem}", data)


@FUZZ
@given(data=fz.mutated_bvh())
def test_mutated_bvh_raises_only_data_errors(data):
    _parse_any(data)


@FUZZ
@given(data=fz.bvh_header_variants())
def test_bvh_header_values_raise_only_data_errors(data):
    _parse_any(data)


@FUZZ
@given(data=fz.byte_mutated_bvh())
def test_byte_mutated_bvh_raises_only_data_errors(data):
    _parse_any(data)


@FUZZ
@given(deep=fz.deep_bvh())
def test_bvh_depth_limit(deep):
    depth, end_site, data = deep
    got = call("bvh", parse_bvh, data, "deep.bvh", shown=(depth, end_site))
    ok = depth + end_site <= MAX_DEPTH
    if got is _FOREIGN:
        return
    if ok and not (isinstance(got, Bvh) and got.n_joints == depth):
        fail("bvh", f"chain of {depth} joints (End Site: {end_site}) not read", (depth, end_site))
    if not ok and got is not _REFUSED:
        fail("bvh", f"chain of {depth} joints deeper than MAX_DEPTH read", (depth, end_site))


# ============================================================================ TOML specs

def _spec_path(base: Path | None, where: int) -> Path:
    """Where a fuzzed spec is written: its own paper folder and name (so its id matches the
    path), another registered-looking place, or a neutral folder."""
    if base is not None and where == 0:
        p = _WORK / "specs" / base.parent.name / base.name
    elif where == 1:
        p = _WORK / "specs" / "marionette" / "table1.toml"
    else:
        p = _WORK / "specs" / "elsewhere" / "fuzzed.toml"
    p.parent.mkdir(parents=True, exist_ok=True)
    return p


def _load_spec_bytes(data: bytes, base: Path | None, where: int) -> None:
    path = _spec_path(base, where)
    path.write_bytes(data)
    got = call("spec", load_spec, path, shown=data)
    if got not in (_REFUSED, _FOREIGN) and not isinstance(got, TableSpec):
        fail("spec", f"load_spec returned {type(got).__name__}", data)


@FUZZ
@given(doc=fz.mutated_toml_doc(fz.SPEC_FILES), where=st.integers(0, 2))
def test_mutated_spec_raises_only_spec_errors(doc, where):
    base, data = doc
    _load_spec_bytes(data, base, where)


@FUZZ
@given(data=fz.toml_texts(fz.SPEC_FILES), where=st.integers(1, 2))
def test_spec_text_raises_only_spec_errors(data, where):
    _load_spec_bytes(data, None, where)


DATASET_SPEC = Path(__file__).resolve().parents[1] / "docs" / "examples" / "bandai2-declared.toml"


@FUZZ
@given(data=fz.mutated_toml_doc((DATASET_SPEC,)).map(lambda d: d[1])
       | fz.toml_texts((DATASET_SPEC,)))
def test_dataset_specs_raise_only_spec_errors(data):
    """Data-set specs (repro.data.dataset_spec): damaged copies of the shipped example."""
    from repro.data.dataset_spec import DatasetSpec, load_dataset_spec

    path = _WORK / "datasets" / "fuzzed.toml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    got = call("dataset spec", load_dataset_spec, path, shown=data)
    if got not in (_REFUSED, _FOREIGN) and not isinstance(got, DatasetSpec):
        fail("dataset spec", f"load_dataset_spec returned {type(got).__name__}", data)


_LABEL_SEEDS = (b"clip,action,style,subject\nc0,walk,happy,s1\nc1,run,,s2\n",
                b'{"c0": "walk", "c1": {"action": "run", "style": "sad", "subject": "s2"}}')


@FUZZ
@given(seed=st.sampled_from(_LABEL_SEEDS), edits=st.lists(st.tuples(
    st.integers(0, 80), st.integers(0, 8), st.binary(max_size=6)), max_size=6),
    by_subject=st.booleans())
def test_label_files_raise_only_data_errors(seed, edits, by_subject):
    """A declared data set's labels side file (CSV or JSON): damaged copies of a valid one,
    read and matched to the clips c0, c1 (repro.data.dataset_labels.labels_for)."""
    from repro.data.dataset_labels import labels_for
    from repro.data.dataset_spec import DatasetSpec

    data = bytearray(seed)
    for at, cut, ins in edits:  # splice: replace data[at:at+cut] by ins
        at = min(at, len(data))
        data[at:at + cut] = ins
    fmt = "csv" if seed.startswith(b"clip") else "json"
    folder = _WORK / "labels"
    folder.mkdir(exist_ok=True)
    (folder / f"labels.{fmt}").write_bytes(bytes(data))
    spec = DatasetSpec.model_validate({
        "schema": 1, "name": "fz", "source": {"path": "x"},
        "labels": {"from": fmt, "file": f"labels.{fmt}"},
        "split": {"by": "subject" if by_subject else "clip"}})
    call("label file", labels_for, spec, folder, ["c0", "c1"], shown=bytes(data))


@FUZZ
@given(text=fzd.label_texts(), by_subject=st.booleans())
def test_hostile_label_files_raise_only_data_errors(text, by_subject, monkeypatch):
    """Labels files built to attack (issue 29): repeated JSON keys and CSV columns, lone
    surrogates, C0 / C1 controls, deep nesting, files past the cap (lowered to 4 KiB here).
    Property: only ReproErrors, and every name read is free of control characters."""
    from repro.data import dataset_spec
    from repro.data.dataset_labels import labels_for
    from repro.data.dataset_spec import DatasetSpec, bad_char

    monkeypatch.setattr(dataset_spec, "MAX_LABELS_BYTES", 4096)
    fmt = "json" if text.lstrip(b"\xef\xbb\xbf\xff\xfe").startswith((b"{", b"[", b"n", b"1", b'"')) \
        or not text.strip() else "csv"
    folder = _WORK / "labels-hostile"
    folder.mkdir(exist_ok=True)
    (folder / f"labels.{fmt}").write_bytes(text)
    spec = DatasetSpec.model_validate({
        "schema": 1, "name": "fz", "source": {"path": "x"},
        "labels": {"from": fmt, "file": f"labels.{fmt}"},
        "split": {"by": "subject" if by_subject else "clip"}})
    got = call("label file (hostile)", labels_for, spec, folder, ["c0", "c1"], shown=text)
    if got in (_REFUSED, _FOREIGN):
        return
    names = [*got[2], *got[3], *(x for x in got[4] if x is not None), *got[5]]
    if any(bad_char(n) is not None for n in names):
        fail("label file (hostile)", f"a name with a control character was read: {names!r}",
             text)


@FUZZ
@given(case=fzd.archive_cases())
def test_dataset_archives_raise_only_repro_errors(case):
    """Declared data sets whose source is a hostile tar archive (issue 29: long, deep, '..',
    absolute and control-character member names; links, FIFOs, devices, sparse and duplicate
    members; archive-root clips), labelled by a pattern or a side file, prepared end to end
    under a memory cap.  Property: only ReproErrors; a prepared set names its clips by their
    file stems, without control characters."""
    import roma  # noqa: F401  (imported before the memory cap: prepare loads them)
    import torch  # noqa: F401

    from repro.data.dataset_prepare import prepare_dataset
    from repro.data.dataset_spec import bad_char

    folder = _WORK / "archives"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    (folder / f"clips.{case['ext']}").write_bytes(case["archive"])
    lab = (f"pattern = {json.dumps(case['pattern'])}" if case["labels"] == "filename" else
           f'from = "{case["labels"]}"\nfile = "{case["side"][0]}"')
    if case["side"]:
        (folder / case["side"][0]).write_bytes(case["side"][1])
    inc = f"include = {json.dumps(case['include'])}\n" if case["include"] else ""
    (folder / "s.toml").write_text(
        f'schema = 1\nname = "fz"\n[source]\npath = "clips.{case["ext"]}"\n{inc}'
        f'[labels]\n{lab}\n[split]\ntest_fraction = 0.5\nby = "{case["by"]}"\n')
    shown = {k: v for k, v in case.items() if k != "archive"} | {
        "members": _members(case["archive"])}
    with memory_cap():
        res = call("dataset archive", prepare_dataset, folder / "s.toml", force=True,
                   shown=shown)
    if res in (_REFUSED, _FOREIGN):
        return
    names = json.loads((res.path / "meta.json").read_text())["clip_names"]
    if any(bad_char(n) is not None or ":" in n or "/" in n for n in names):
        fail("dataset archive", f"clip names {names!r}", shown)


def _members(data: bytes) -> list:
    """The (name, type) list of a generated archive, for the record of a finding."""
    import io
    import tarfile

    try:
        with tarfile.open(fileobj=io.BytesIO(data), errors="surrogateescape") as tf:
            return [(m.name[:200], m.type) for m in tf.getmembers()]
    except Exception as e:  # noqa: BLE001 (only a description)
        return [f"unreadable: {type(e).__name__}"]


_datasets = st.sampled_from((None, None, "bandai2", "bandai2-mini", "humanact12", "nope", ""))


@FUZZ
@given(data=fz.mutated_toml_doc((fz.SCALES_FILE,)).map(lambda d: d[1])
       | fz.toml_texts((fz.SCALES_FILE,)), dataset=_datasets)
def test_scales_raise_only_repro_errors(data, dataset):
    path = _WORK / "scales" / "scales.toml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    if call("scales", load_scales, path, shown=data) in (_REFUSED, _FOREIGN):
        return
    for name in SCALE_NAMES:
        resolved = call("scales", resolve_scale, name, dataset, path=path,
                        shown=(name, dataset, data))
        if resolved not in (_REFUSED, _FOREIGN):
            call("scales", lambda r: r.scale_hash, resolved, shown=(name, dataset, data))


# ============================================================================ pickles

def _loads(data: bytes, target: str = "pickle"):
    with memory_cap():
        return call(target, loads_restricted, data, source="fuzz.pkl", shown=data)


def _read_humanact12(data: bytes, shown):
    path = _WORK / "humanact12" / "humanact12poses.pkl"
    path.parent.mkdir(exist_ok=True)
    path.write_bytes(data)
    with memory_cap():
        return call("humanact12", read_humanact12, path.parent, shown=shown)


def _fits_float32(a: np.ndarray) -> bool:
    """Finite once stored as float32 (what the reader keeps; 1e39 is not)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return bool(np.isfinite(a.astype(np.float32)).all())


def _well_formed(obj) -> bool:
    """Whether ``obj`` is a HumanAct12 payload a correct reader must accept."""
    if not (isinstance(obj, dict) and {"poses", "joints3D", "y"} <= set(obj)):
        return False
    P, J, Y = obj["poses"], obj["joints3D"], obj["y"]
    if not all(isinstance(v, (list, tuple)) for v in (P, J, Y)) or not len(P) == len(J) == len(Y) > 0:
        return False
    for p, j, y in zip(P, J, Y):
        good = (isinstance(p, np.ndarray) and isinstance(j, np.ndarray)
                and p.dtype in (np.float32, np.float64) and j.dtype in (np.float32, np.float64)
                and p.shape[1:] in ((72,), (24, 3)) and p.ndim in (2, 3) and j.ndim == 3
                and j.shape[1:] == (24, 3) and p.shape[0] == j.shape[0] > 0
                and _fits_float32(p) and _fits_float32(j))
        if not good or isinstance(y, (bool, np.bool_)) or not isinstance(y, (int, np.integer)) \
                or not 0 <= y < 12:
            return False
    return True


def _label_values(obj) -> list | None:
    """The numeric value of every label, when all are plain real numbers."""
    try:
        ys = list(obj["y"])
    except (TypeError, KeyError, IndexError, ValueError):
        return None
    out = []
    for y in ys:
        if isinstance(y, (int, float, np.integer, np.floating)) and not isinstance(y, (bool, np.bool_)):
            out.append(float(y))
        else:
            return None
    return out


@FUZZ
@given(pair=fz.payload_pickles())
def test_pickled_payloads_raise_only_repro_errors(pair):
    obj, data = pair
    _loads(data)
    got = _read_humanact12(data, obj)
    if got is _FOREIGN:
        return
    if got is _REFUSED:
        if _well_formed(obj):
            fail("humanact12", "a well-formed HumanAct12 pickle was refused", obj)
        return
    values = _label_values(obj)
    if values is not None and [float(v) for v in got.labels] != values:
        fail("humanact12", f"labels {values} read as {got.labels.tolist()}", obj)
    if not all(np.isfinite(a).all() for a in (*got.poses, *got.joints)):
        fail("humanact12", "non-finite values in what was read", obj)


@FUZZ
@given(data=fz.mutated_pickles())
def test_mutated_pickles_raise_only_repro_errors(data):
    _loads(data)
    _read_humanact12(data, data)


@FUZZ
@given(evil=fz.evil_pickles(str(SENTINEL)))
def test_disallowed_globals_never_run(evil):
    data, mutated = evil
    got = _loads(data)
    check_sentinel("pickle", data)
    if not mutated and got is not _REFUSED and got is not _FOREIGN:
        fail("pickle", "a pickle naming a disallowed global was loaded", data)
    _read_humanact12(data, data)
    check_sentinel("humanact12", data)


@FUZZ
@given(data=fz.call_pickles())
def test_admitted_globals_with_hostile_arguments(data):
    _loads(data)
    check_sentinel("pickle", data)
