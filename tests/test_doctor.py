"""`repro doctor`: one line per registered data set, what is missing, exit 0 (2 if broken)."""

import json

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
    assert "prepared yes" in line and h["fingerprint"][:12] in line


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
