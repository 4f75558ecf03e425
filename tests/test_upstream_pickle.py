"""The restricted unpickler: numpy arrays and containers load; everything else is refused."""

import os
import pickle
import sys

import numpy as np
import pytest

from repro.data.upstream.restricted_pickle import load_restricted, loads_restricted
from repro.errors import DataError, MissingDataError


@pytest.mark.parametrize("protocol", [2, 3, 4, 5])
def test_numpy_payloads_round_trip(protocol, tmp_path):
    data = {"poses": [np.arange(6, dtype=np.float32).reshape(2, 3)],
            "y": [np.int64(3), 4], "fps": np.float64(29.97), "gender": np.str_("male"),
            "mask": np.array([True, False]), "t": (1, 2.5, "x"), "s": {1, 2}, "b": b"\x00\x01"}
    p = tmp_path / "ok.pkl"
    p.write_bytes(pickle.dumps(data, protocol=protocol))
    got = load_restricted(p)
    assert np.array_equal(got["poses"][0], data["poses"][0])
    assert got["poses"][0].dtype == np.float32
    assert got["y"] == [3, 4] and got["fps"] == 29.97 and str(got["gender"]) == "male"
    assert got["t"] == (1, 2.5, "x") and got["s"] == {1, 2} and got["b"] == b"\x00\x01"


def test_os_system_is_refused_before_it_runs(tmp_path):
    marker = tmp_path / "ran"
    class Evil:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    p = tmp_path / "evil.pkl"
    p.write_bytes(pickle.dumps({"poses": [Evil()]}, protocol=2))
    with pytest.raises(DataError) as e:
        load_restricted(p)
    msg = str(e.value)
    assert str(p) in msg and "system" in msg and "refused" in msg
    assert not marker.exists()


@pytest.mark.parametrize("target", ["builtins.eval", "subprocess.Popen", "numpy.load",
                                    "numpy.testing.assert_equal"])
def test_other_globals_are_refused(target):
    mod, name = target.rsplit(".", 1)
    raw = b"\x80\x02c" + mod.encode() + b"\n" + name.encode() + b"\nq\x00."
    with pytest.raises(DataError, match=f"refused to unpickle global {target}"):
        loads_restricted(raw, source="x.pkl")


def test_numpy1_module_spelling_is_admitted():
    # Pickles written by numpy 1.x name numpy.core.multiarray._reconstruct.
    raw = pickle.dumps(np.arange(3), protocol=2).replace(b"numpy._core.multiarray",
                                                         b"numpy.core.multiarray")
    assert b"numpy.core.multiarray" in raw
    assert np.array_equal(loads_restricted(raw), np.arange(3))


def test_garbage_and_missing_files_name_the_file(tmp_path):
    p = tmp_path / "bad.pkl"
    p.write_bytes(b"not a pickle at all")
    with pytest.raises(DataError, match="bad.pkl.*not a readable pickle"):
        load_restricted(p)
    with pytest.raises(MissingDataError, match="absent.pkl"):
        load_restricted(tmp_path / "absent.pkl")


def test_extra_classes_only_by_exact_name(tmp_path):
    import scipy.sparse as sp

    m = sp.csc_matrix(np.eye(3))
    raw = pickle.dumps(m, protocol=2)
    with pytest.raises(DataError, match="csc_matrix"):
        loads_restricted(raw)
    got = loads_restricted(raw, extra=[("scipy.sparse._csc", "csc_matrix")])
    assert np.array_equal(got.toarray(), np.eye(3))
    assert "chumpy" not in sys.modules
