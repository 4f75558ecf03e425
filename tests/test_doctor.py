"""`repro doctor`: one line per registered data set, what is missing, exit 0 (2 if broken)."""

import json
import pickle

import numpy as np
import pytest
from test_upstream_cmu import write_cmu
from test_upstream_humanact12 import write_humanact12
from upstream_synth import body_model_arrays

from cli.main import main
from repro.data.registry import DATASETS
from repro.data.upstream.humanact12 import read_humanact12
from repro.data.upstream.skeletons import SMPLH_52


def test_nothing_present_lists_every_dataset_and_what_is_missing(paper_data, capsys):
    assert main(["doctor"]) == 0
    out = capsys.readouterr().out
    for name in DATASETS:
        assert any(line.startswith(name + " ") for line in out.splitlines()), name
    assert (f"HumanAct12: put humanact12poses.pkl (ACTOR's HumanAct12Poses release) at "
            f"{paper_data / 'humanact12' / 'humanact12poses.pkl'}") in out
    assert "uestc_train.csv" in out and "pose_clip_7class.csv" in out
    assert "babel_v1.0_release" in out and "did not release it" in out
    assert "REPRO_SMPL_DIR is not set" in out
    assert "environment: python" in out and "threads" in out


def test_prepared_datasets_show_fingerprints(paper_data, capsys, tmp_path, monkeypatch):
    (paper_data / "humanact12").mkdir(parents=True)
    write_humanact12(paper_data / "humanact12" / "humanact12poses.pkl")
    write_cmu(paper_data / "cmu-mocap", csv_name="pose_clip_7class.csv",
              rows=[("02_01", "Walk"), ("09_01", "Run")])
    smpl_dir = tmp_path / "models"
    (smpl_dir / "smplh" / "male").mkdir(parents=True)
    np.savez(smpl_dir / "smplh" / "male" / "model.npz", **body_model_arrays(SMPLH_52))
    monkeypatch.setenv("REPRO_SMPL_DIR", str(smpl_dir))
    assert main(["doctor", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    rows = {r["name"]: r for r in rep["datasets"]}
    h = rows["humanact12"]
    assert h["prepared"] and h["missing"] is None and h["paper_dataset"]
    assert h["fingerprint"] == read_humanact12(paper_data / "humanact12").fingerprint
    assert rows["cmu-mocap"]["prepared"]
    from repro.data.upstream.cmu_mocap import read_cmu_mocap

    assert rows["cmu-mocap"]["fingerprint"] == read_cmu_mocap(paper_data / "cmu-mocap").fingerprint
    assert not rows["uestc"]["prepared"] and rows["uestc"]["location"] == str(paper_data / "uestc")
    assert not rows["babel-mag"]["prepared"]
    models = {m["kind"]: m for m in rep["body_models"]}
    assert models["smplh"]["path"].endswith("smplh/male/model.npz")
    assert models["smpl"]["path"] is None and "SMPL_NEUTRAL" in models["smpl"]["missing"]
    # The text view shows the fingerprint prefix on the dataset's line.
    assert main(["doctor"]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("humanact12"))
    assert "prepared, valid" in line and h["fingerprint"][:12] in line
    assert h["state"] == "prepared, valid" and h["valid"] is True and h["damaged"] is None


def test_partial_cmu_folder_names_missing_clips(paper_data, capsys):
    write_cmu(paper_data / "cmu-mocap", csv_name="pose_clip_7class.csv",
              rows=[("02_01", "Walk"), ("09_01", "Run")])
    (paper_data / "cmu-mocap" / "mocap_3djoints" / "09_01.npy").unlink()
    assert main(["doctor"]) == 0
    out = capsys.readouterr().out
    assert "1 clips named in pose_clip_7class.csv are missing" in out and "09_01.npy" in out


def test_broken_registry_exits_2(paper_data, capsys, monkeypatch):
    import repro.data.registry as reg

    class Broken(dict):
        def items(self):
            raise RuntimeError("data set 'x' is registered twice")

    monkeypatch.setattr(reg, "DATASETS", Broken())
    assert main(["doctor"]) == 2
    assert "registry cannot be read" in capsys.readouterr().err


# ------------------------------------------------------------------ validation (issue 16)
def _rows(capsys) -> dict:
    assert main(["doctor", "--json"]) == 0  # a report: damage is not an error exit
    return {r["name"]: r for r in json.loads(capsys.readouterr().out)["datasets"]}


def _text_lines(capsys, name) -> list[str]:
    assert main(["doctor"]) == 0
    out = capsys.readouterr().out.splitlines()
    i = next(i for i, ln in enumerate(out) if ln.startswith(name + " "))
    return [out[i]] + [ln for ln in out[i + 1:i + 3] if ln.startswith(" ")]


@pytest.mark.parametrize("damage, problem", [
    (lambda p: p.write_bytes(p.read_bytes()[:300]), "not a readable pickle"),
    (lambda p: p.write_bytes(b"PK\x03\x04 this is a zip, not a pickle"), "not a readable pickle"),
    (lambda p: p.write_bytes(pickle.dumps({"poses": [np.zeros((5, 72), object)],
                                           "joints3D": [np.zeros((5, 24, 3))], "y": [1]},
                                          protocol=2)), "clip 0: poses must be a numeric array"),
    (lambda p: p.write_bytes(b"\x80\x02c__builtin__\nbytearray\nJ\x00\x00\x00\x40\x85R."),
     "refused to unpickle"),
], ids=["truncated", "wrong-format", "object-poses", "1-GiB-bytearray"])
def test_damaged_upstream_file_is_reported_as_damaged(paper_data, capsys, damage, problem):
    """Before issue 16 any humanact12poses.pkl present was "prepared yes"."""
    (paper_data / "humanact12").mkdir(parents=True)
    p = paper_data / "humanact12" / "humanact12poses.pkl"
    write_humanact12(p)
    assert _rows(capsys)["humanact12"]["state"] == "prepared, valid"
    damage(p)
    before = p.read_bytes()
    h = _rows(capsys)["humanact12"]
    assert h["state"] == "prepared, damaged" and h["valid"] is False
    assert h["damaged"].startswith(f"{p}: ") and problem in h["damaged"], h["damaged"]
    lines = _text_lines(capsys, "humanact12")
    assert "prepared, damaged" in lines[0]
    assert lines[1].strip() == f"damaged: {h['damaged']}"
    assert p.read_bytes() == before  # doctor only reads


def test_damaged_cmu_clip_is_named(paper_data, capsys):
    write_cmu(paper_data / "cmu-mocap", csv_name="pose_clip_7class.csv",
              rows=[("02_01", "Walk"), ("09_01", "Run")])
    assert _rows(capsys)["cmu-mocap"]["state"] == "prepared, valid"
    clip = paper_data / "cmu-mocap" / "mocap_3djoints" / "09_01.npy"
    clip.write_bytes(clip.read_bytes()[:100])
    row = _rows(capsys)["cmu-mocap"]
    assert row["state"] == "prepared, damaged" and row["damaged"].startswith(f"{clip}: ")


def _prepare_toy_bandai2(tmp_path):
    import dataclasses

    from test_bandai import TOY_CARD, write_toy

    from repro.data.bandai import prepare_bandai2

    card = dataclasses.replace(TOY_CARD, name="bandai2")
    write_toy(tmp_path / "src", card=card)
    return prepare_bandai2(tmp_path / "src", card=card, workers=0).path


def _truncate(f):
    f.write_bytes(f.read_bytes()[:-64])


def _zero_tail(f):
    data = f.read_bytes()
    f.write_bytes(data[:-64] + bytes(64))  # same size: a crash's zero-filled tail


def _garble_meta(f):
    f.write_text("{not json")


def _swap_lengths(f):
    a = np.load(f)
    np.save(f, a[::-1].copy() if a[0] != a[-1] else a + 1)


@pytest.mark.parametrize("file, damage, problem", [
    ("rotations.npy", _truncate, "truncated?"),
    ("joints.npy", lambda f: f.write_bytes(b"garbage"), "not a readable .npy"),
    ("rotations.npy", _zero_tail, "not unit quaternions"),
    ("meta.json", _garble_meta, "not valid JSON"),
    ("lengths.npy", _swap_lengths, "starts.npy: not the running sum of lengths.npy"),
    ("labels.npy", lambda f: np.save(f, np.full_like(np.load(f), 7)), "outside 0..1"),
])
def test_damaged_prepared_cache_is_reported_and_kept(tmp_path, capsys, file, damage, problem):
    from test_bandai import cache_listing

    from repro.data.cache import dataset_dir

    cache = _prepare_toy_bandai2(tmp_path)
    row = _rows(capsys)["bandai2"]
    assert row["state"] == "prepared, valid" and row["valid"] is True
    damage(cache / file)
    before = cache_listing(dataset_dir("bandai2"))
    row = _rows(capsys)["bandai2"]
    assert row["state"] == "prepared, damaged" and row["valid"] is False
    assert str(cache) in row["damaged"] and problem in row["damaged"], row["damaged"]
    assert row["damaged"].endswith("--force")  # says how to rebuild it
    lines = _text_lines(capsys, "bandai2")
    assert "prepared, damaged" in lines[0] and lines[1].strip().startswith(f"damaged: {cache}")
    assert not any("missing:" in ln for ln in lines)
    assert cache_listing(dataset_dir("bandai2")) == before  # nothing prepared is lost


def test_tampered_bundle_is_reported(tmp_path, capsys, monkeypatch):
    import shutil

    import repro.data.bundle as bundle

    copy = tmp_path / "bundled"
    shutil.copytree(bundle.bundled_dir(), copy)
    monkeypatch.setattr(bundle, "bundled_dir", lambda: copy)
    assert _rows(capsys)["bandai2-mini"]["state"] == "prepared, valid"
    data = bytearray((copy / bundle.NPZ).read_bytes())
    data[len(data) // 2] ^= 0xFF
    (copy / bundle.NPZ).write_bytes(bytes(data))
    row = _rows(capsys)["bandai2-mini"]
    assert row["state"] == "prepared, damaged"
    assert row["damaged"].startswith(f"{copy / bundle.NPZ}: content does not match the sha256")


def test_cli_doctor_names_the_damaged_file(paper_data, tmp_path):
    import os
    import subprocess
    import sys
    from pathlib import Path

    (paper_data / "humanact12").mkdir(parents=True)
    p = paper_data / "humanact12" / "humanact12poses.pkl"
    write_humanact12(p)
    p.write_bytes(p.read_bytes()[:-10])
    r = subprocess.run([sys.executable, "-m", "cli.main", "doctor"], capture_output=True,
                       text=True, cwd=Path(__file__).resolve().parents[1],
                       env=dict(os.environ), timeout=300)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr  # a report: exit 0
    out = r.stdout.splitlines()
    i = next(i for i, ln in enumerate(out) if ln.startswith("humanact12 "))
    assert "prepared, damaged" in out[i]
    assert out[i + 1].strip().startswith(f"damaged: {p}: not a readable pickle")
