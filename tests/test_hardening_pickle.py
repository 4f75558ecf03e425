"""Issue 16: the restricted unpickler bounds what a pickle may allocate, and the HumanAct12 reader
refuses non-numeric clips and non-integer labels, each with one line naming the file.

Every pickle here names only admitted globals: what it asks for (an exabyte buffer, a shape of
10**14 items, a short object list, a dtype resized after use, a hash bomb) is the attack.
"""

from __future__ import annotations

import os
import pickle
import struct
import subprocess
import sys
import textwrap
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from numpy._core.multiarray import _reconstruct

from repro.data.upstream import pickle_checks
from repro.data.upstream import restricted_pickle as rp
from repro.data.upstream.humanact12 import read_humanact12
from repro.data.upstream.restricted_pickle import load_restricted, loads_restricted
from repro.errors import DataError

REPO = Path(__file__).resolve().parents[1]


class Reduce:
    """Pickles as ``func(*args)`` (and ``BUILD state`` when given)."""

    def __init__(self, func, args, state=None):
        self.r = (func, args) if state is None else (func, args, state)

    def __reduce__(self):
        return self.r


def dumps(obj, protocol=2) -> bytes:
    return pickle.dumps(obj, protocol=protocol)


def recon(state):
    """An array pickled the way numpy does it, with the given __setstate__ state."""
    return Reduce(_reconstruct, (np.ndarray, (0,), b"b"), state)


HUGE = {
    "bytearray(2**60)": dumps(Reduce(bytearray, (2 ** 60,))),
    "bytes(2**60)": dumps(Reduce(bytes, (2 ** 60,))),
    "numpy.ndarray((10**7, 10**7))": dumps(Reduce(np.ndarray, ((10 ** 7, 10 ** 7),))),
    "_reconstruct shape": dumps(Reduce(_reconstruct, (np.ndarray, (10 ** 7, 10 ** 7), b"b"))),
    # numpy allocates an object array's shape before it looks at the item list
    "__setstate__ shape": dumps(recon((1, (10 ** 7, 10 ** 7), np.dtype("O"), False, []))),
    "list(range(10**12))": dumps(Reduce(list, (range(10 ** 12),)), protocol=3),
    "BYTEARRAY8 length": b"\x80\x05\x96" + struct.pack("<Q", 2 ** 60) + b".",
}


@pytest.mark.parametrize("name", list(HUGE))
def test_huge_requests_are_refused_before_anything_is_built(name, tmp_path):
    p = tmp_path / "humanact12poses.pkl"
    p.write_bytes(HUGE[name])
    with pytest.raises(DataError) as e:
        load_restricted(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}: ") and "refused" in msg, msg
    assert len(msg) < 400


@pytest.mark.parametrize("make", [
    lambda n: Reduce(bytearray, (n,)),
    lambda n: recon((1, (n // 8,), np.dtype("f8"), False, Reduce(bytes, (n,)))),
    lambda n: Reduce(_reconstruct, (np.ndarray, (n,), b"b")),
], ids=["bytearray", "setstate-from-bytes", "reconstruct"])
def test_a_size_that_fits_in_memory_is_still_not_allocated(make):
    """256 MiB fits under MAX_ARRAY_BYTES, but a 100-byte file cannot carry it: refused against
    the file's own size before the allocation (before issue 16 it was really allocated)."""
    raw = dumps(make(256 * 1024 ** 2))
    assert len(raw) < 300
    tracemalloc.start()
    try:
        with pytest.raises(DataError, match=r"the file is only \d+ bytes"):
            loads_restricted(raw, source="x.pkl")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16 * 1024 ** 2, peak


def test_per_array_cap_is_stated_and_enforced(monkeypatch):
    assert pickle_checks.MAX_ARRAY_BYTES == rp.MAX_ARRAY_BYTES == 2 * 1024 ** 3
    a = np.zeros((64, 1024), np.float64)  # 512 KiB of real data, in the file
    raw = dumps({"a": a})
    assert loads_restricted(raw)["a"].shape == (64, 1024)
    monkeypatch.setattr(pickle_checks, "MAX_ARRAY_BYTES", 256 * 1024)
    with pytest.raises(DataError, match=r"over the 0.25 MiB cap on one array"):
        loads_restricted(raw, source="x.pkl")


def test_object_array_with_too_few_items_is_refused():
    """numpy would build a 3-item object array from a 2-item list and read an unset pointer
    (a segmentation fault).  Run in a child so that a regression cannot kill the test run."""
    raw = dumps(recon((1, (3,), np.dtype("O"), False, [1, 2])))
    code = textwrap.dedent(f"""
        from repro.data.upstream.restricted_pickle import loads_restricted
        from repro.errors import DataError
        try:
            a = loads_restricted({raw!r}, source="obj.pkl")
        except DataError as e:
            print("REFUSED", e)
        else:
            print("LOADED", a.tolist())
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       cwd=REPO, timeout=120)
    assert r.returncode == 0 and "REFUSED obj.pkl:" in r.stdout, (r.returncode, r.stdout,
                                                                  r.stderr[-500:])
    assert "list of 3 items" in r.stdout


def test_dtype_state_may_not_resize_items():
    # numpy's dtype.__setstate__ would turn V8 into a 1 TiB item (and arrays built on it read
    # out of bounds).
    raw = dumps(Reduce(np.dtype, ("V8", False, True), (3, "|", None, None, None, 1 << 40, 1, 0)))
    with pytest.raises(DataError, match="would change .* size, alignment or flags"):
        loads_restricted(raw, source="d.pkl")
    raw = dumps(Reduce(np.dtype, ("f8,f8", False, True)))
    with pytest.raises(DataError, match="structured and sub-array"):
        loads_restricted(raw, source="d.pkl")


def test_states_numpy_reads_unchecked_are_refused():
    """Found by fuzzing: numpy reads a datetime dtype's unit from a 9th state item without
    checking it is there (a version-3 state: segmentation fault), and a string scalar past
    U+10FFFF is a SystemError.  In a child, so that a regression cannot kill the test run."""
    from numpy._core.multiarray import scalar

    bad_dt = dumps(Reduce(np.dtype, ("M8", False, True), (3, "<", None, None, None, -1, -1, 0)))
    bad_u = dumps(Reduce(scalar, (np.dtype("U1"), b"\xff\xff\xff\xff")))
    code = textwrap.dedent(f"""
        from repro.data.upstream.restricted_pickle import loads_restricted
        from repro.errors import DataError
        for raw in ({bad_dt!r}, {bad_u!r}):
            try:
                loads_restricted(raw, source="n.pkl")
            except DataError as e:
                print("REFUSED", e)
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       cwd=REPO, timeout=120)
    assert r.returncode == 0, (r.returncode, r.stderr[-500:])
    out = r.stdout.splitlines()
    assert len(out) == 2 and "the tuple numpy writes for a datetime dtype" in out[0], out
    assert "invalid code point" in out[1], out
    ok = dumps(np.array(["2020-01-01T00:00"], dtype="M8[m]"))
    assert loads_restricted(ok).dtype == np.dtype("M8[m]")


def test_array_data_must_match_its_shape():
    raw = dumps(recon((1, (10,), np.dtype("f4"), False, b"abc")))
    with pytest.raises(DataError, match="array data is 3 bytes.*need 40"):
        loads_restricted(raw, source="x.pkl")


def test_state_on_other_objects_and_foreign_codecs_are_refused():
    raw = dumps(Reduce(list, (), {"x": 1}))
    with pytest.raises(DataError, match="setting the state of a list"):
        loads_restricted(raw)
    import _codecs

    raw = dumps(Reduce(_codecs.encode, ("x" * 10, "zlib")))
    with pytest.raises(DataError, match="not a text codec"):
        loads_restricted(raw)


def test_hash_bomb_keys_are_refused_quickly():
    """A 60-level shared tuple (2**60 leaves, 300 bytes) as a dict key: hashing it never ends.
    Run in a child with a timeout, so a regression fails instead of hanging."""
    raw = b"\x80\x02}" + b")q\x000"  # {}, memo[0] = ()
    for i in range(60):  # memo[i + 1] = (memo[i], memo[i])
        raw += b"h" + bytes([i]) + b"h" + bytes([i]) + b"\x86q" + bytes([i + 1]) + b"0"
    raw += b"h<K\x01s."  # {memo[60]: 1}
    code = textwrap.dedent(f"""
        from repro.data.upstream.restricted_pickle import loads_restricted
        from repro.errors import DataError
        try:
            loads_restricted({raw!r}, source="bomb.pkl")
        except DataError as e:
            print("REFUSED", e)
    """)
    try:
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           cwd=REPO, timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail("hashing a shared tuple graph did not end within 60 s")
    assert "REFUSED bomb.pkl:" in r.stdout and "nests more than" in r.stdout, r.stdout + r.stderr


@pytest.mark.parametrize("protocol", [2, 3, 4, 5])
def test_legitimate_numpy_payloads_still_load(protocol):
    rng = np.random.default_rng(0)
    big = rng.normal(size=(1024, 1024)).astype(np.float64)  # 8 MiB, near the whole file
    data = {
        "big": big, "fortran": np.asfortranarray(rng.normal(size=(5, 7))),
        "strided": rng.normal(size=(4, 5, 6)).transpose(2, 0, 1), "empty": np.zeros((0, 72)),
        "objects": np.array([1, "a", None], dtype=object), "text": np.array(["ab", "c"]),
        "when": np.array(["2020-01-01"], dtype="M8[ns]"), "i8": np.arange(5), "b": b"\xff" * 9,
        "ba": bytearray(b"\x00\x01"), "set": {1, (2, "x")}, "fs": frozenset({3}),
        "c": 1 + 2j, "sl": slice(1, 5, 2), "scalars": [np.int16(3), np.str_("x")],
        "keys": {(1, 2): "tuple key", np.int64(4): "numpy key"},
    }
    if protocol >= 3:  # protocol 2 spells range as Python 2's xrange (refused, as before)
        data["r"] = range(3)
    got = loads_restricted(dumps(data, protocol))
    for k in ("big", "fortran", "strided", "empty", "text", "when", "i8"):
        assert np.array_equal(got[k], data[k]) and got[k].dtype == data[k].dtype, k
    assert got["objects"].tolist() == [1, "a", None]
    assert got["b"] == data["b"] and got["ba"] == data["ba"] and got["set"] == data["set"]
    assert got["fs"] == data["fs"] and got["c"] == 1 + 2j and got["sl"] == slice(1, 5, 2)
    assert got.get("r") == data.get("r") and got["scalars"] == [3, "x"]
    assert got["keys"] == data["keys"]


def test_python2_style_arrays_still_load():
    """numpy on Python 2 wrote dtype flags as 0/1 and array data as a byte string (read back
    as a latin-1 str)."""
    a = np.arange(12, dtype="<f4").reshape(3, 4)
    raw = dumps(a, 2)
    assert raw.count(b"\x89\x88\x87") == 1  # dtype args ('f4', False, True)
    raw = raw.replace(b"\x89\x88\x87", b"K\x00K\x01\x87")
    got = loads_restricted(raw)
    assert np.array_equal(got, a)
    py2 = dumps(recon((1, (3, 4), np.dtype("<f4"), False, a.tobytes().decode("latin1"))))
    assert np.array_equal(loads_restricted(py2), a)


# ----------------------------------------------------------------------------- HumanAct12
def write_h12(path: Path, poses=None, joints=None, y=None, n=2, protocol=2) -> None:
    rng = np.random.default_rng(0)
    j = [rng.normal(size=(5, 24, 3)).astype(np.float32) for _ in range(n)]
    p = [rng.normal(size=(5, 72)).astype(np.float32) for _ in range(n)]
    d = {"poses": p if poses is None else poses, "joints3D": j if joints is None else joints,
         "y": list(range(n)) if y is None else y}
    path.write_bytes(pickle.dumps(d, protocol=protocol))


@pytest.mark.parametrize("poses, message", [
    ("x" * 500, "key 'poses' must be a list of per-clip arrays, got str"),
    (np.array("abc"), "got a 0-d <U3 array"),
    (["abc", "def"], "clip 0: poses must be a numeric array, got 'abc'"),
    ([np.full((5, 72), "a"), np.zeros((5, 72))], "clip 0: poses must be a numeric array, got "
                                                 "dtype <U1"),
    ([np.zeros((5, 72), dtype=object), np.zeros((5, 72))], "dtype object (objects)"),
    ([np.zeros((5, 72)).tolist(), np.zeros((5, 72))], "got a list"),
], ids=["str", "0-d", "str-clips", "str-array", "object-array", "nested-list"])
def test_poses_that_are_not_numeric_arrays_name_the_file(tmp_path, poses, message):
    p = tmp_path / "humanact12poses.pkl"
    write_h12(p, poses=poses)
    with pytest.raises(DataError) as e:
        read_humanact12(p)
    assert str(e.value).startswith(f"{p}: ") and message in str(e.value), str(e.value)


def test_values_beyond_float32_are_refused(tmp_path):
    # 1e39 is finite as float64 but inf once stored as float32 (found by tests/test_fuzz.py)
    p = tmp_path / "humanact12poses.pkl"
    big = np.zeros((5, 72))
    big[0, 0] = 1e39
    write_h12(p, poses=[big, np.zeros((5, 72))])
    with pytest.raises(DataError, match="clip 0: non-finite values"):
        read_humanact12(p)


def test_a_huge_integer_label_is_quoted_short(tmp_path):
    p = tmp_path / "humanact12poses.pkl"
    write_h12(p, y=[0, 10 ** 5000])
    with pytest.raises(DataError, match=r"clip 1: label an integer of 16610 bits outside 0..11"):
        read_humanact12(p)
    write_h12(p, poses=[10 ** 5000, np.zeros((5, 72))])
    with pytest.raises(DataError, match=r"clip 0: poses must be a numeric array, got an integer"):
        read_humanact12(p)


@pytest.mark.parametrize("label", [3.7, "3", True, [1], None, float("nan"), np.float32(2.5)])
def test_labels_that_are_not_integers_are_refused(tmp_path, label):
    p = tmp_path / "humanact12poses.pkl"
    write_h12(p, y=[0, label])
    with pytest.raises(DataError, match=r"clip 1: label .* is not an integer") as e:
        read_humanact12(p)
    assert str(p) in str(e.value)


def test_integral_labels_of_any_numeric_type_are_read(tmp_path):
    p = tmp_path / "humanact12poses.pkl"
    write_h12(p, y=np.array([3.0, 11.0]), n=2)
    assert read_humanact12(p).labels.tolist() == [3, 11]
    write_h12(p, y=[np.int8(4), 5], n=2)
    assert read_humanact12(p).labels.tolist() == [4, 5]


# ----------------------------------------------------------------------------- CLI
def run_cli(*args, env_extra):
    env = {**os.environ, **env_extra}
    return subprocess.run([sys.executable, "-m", "cli.main", *args], capture_output=True,
                          text=True, cwd=REPO, env=env, timeout=300)


@pytest.mark.parametrize("payload, problem", [
    ("bytearray", "refused to unpickle: a zero-filled buffer would take"),
    ("string-poses", "clip 0: poses must be a numeric array"),
    ("float-label", "clip 1: label 1.5 is not an integer"),
])
def test_cli_ends_with_one_line_naming_the_file(tmp_path, payload, problem):
    root = tmp_path / "paper-data"
    (root / "humanact12").mkdir(parents=True)
    p = root / "humanact12" / "humanact12poses.pkl"
    if payload == "bytearray":
        p.write_bytes(HUGE["bytearray(2**60)"])
    elif payload == "string-poses":
        write_h12(p, poses=[np.full((5, 72), "a"), np.zeros((5, 72))])
    else:
        write_h12(p, y=[0, 1.5])
    before = p.read_bytes()
    r = run_cli("data", "info", "humanact12",
                env_extra={"REPRO_PAPER_DATA": str(root), "REPRO_HOME": str(tmp_path / "home")})
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"repro: error: {p}: "), r.stderr
    assert problem in lines[0], lines[0]
    assert "Traceback" not in r.stderr
    assert p.read_bytes() == before  # nothing touched
