"""CMU MoCap as Action2Motion preprocessed it: mocap_3djoints/*.npy + pose_clip(_7class).csv."""

import numpy as np
import pytest
from upstream_synth import fk_clip, skeleton_of

from repro.data.upstream.cmu_mocap import (CLASS_SETS, cmu_mocap_clipset, listed_files,
                                           read_cmu_mocap)
from repro.data.upstream.skeletons import CMU_20
from repro.errors import DataError, MissingDataError

ROWS = [("02_01", "Walk"), ("02_10", "Wash"), ("09_01", "Run"), ("13_11", "Jump"),
        ("55_01", "Animal Behavior"), ("05_02", "Dance"), ("90_15", "Climb")]


def write_cmu(root, csv_name="pose_clip.csv", rows=ROWS, seed=0):
    rng = np.random.default_rng(seed)
    skel = skeleton_of(CMU_20, seed=5)
    (root / "mocap_3djoints").mkdir(parents=True, exist_ok=True)
    truth = {}
    for motion, _ in rows:
        metres = fk_clip(skel, int(rng.integers(10, 30)), rng)
        np.save(root / "mocap_3djoints" / f"{motion}.npy", (metres * 20.0).astype(np.float32))
        truth[motion] = metres
    (root / csv_name).write_text("motion,action_type\n"
                                 + "".join(f"{m},{a}\n" for m, a in rows))
    return truth


def test_a2m_list_with_odmo_classes_drops_wash(tmp_path):
    truth = write_cmu(tmp_path)
    data = read_cmu_mocap(tmp_path)                      # no pose_clip_7class.csv: A2M's list
    assert data.csv_name == "pose_clip.csv" and len(data) == 6
    assert data.class_names == CLASS_SETS["odmo7"]
    assert [data.class_names[i] for i in data.labels] == ["Walk", "Run", "Jump",
                                                          "Animal Behavior", "Dance", "Climb"]
    assert "02_10" not in data.clip_names
    cs = cmu_mocap_clipset(data)                         # /20 as A2M and ODMO do
    for i, m in enumerate(data.clip_names):
        np.testing.assert_allclose(cs.clip_joints(i), truth[m], atol=1e-5)
    assert cs.skeleton.n_joints == 20 and (cs.split == 0).all()
    assert cmu_mocap_clipset(data, scale=0.0254 / 0.45).fingerprint != cs.fingerprint


def test_a2m8_classes_keep_wash_in_a2m_order(tmp_path):
    write_cmu(tmp_path)
    data = read_cmu_mocap(tmp_path, classes="a2m8")
    assert len(data) == 7 and data.class_names[1] == "Wash"
    assert data.labels.tolist() == [0, 1, 2, 3, 4, 5, 7]


def test_odmo_seven_class_list_is_preferred(tmp_path):
    write_cmu(tmp_path)
    write_cmu(tmp_path, csv_name="pose_clip_7class.csv", rows=ROWS[:1] + ROWS[2:4])
    data = read_cmu_mocap(tmp_path)
    assert data.csv_name == "pose_clip_7class.csv" and len(data) == 3
    assert listed_files(tmp_path)[0] == "pose_clip_7class.csv"


def test_unknown_class_and_missing_clip(tmp_path):
    write_cmu(tmp_path, csv_name="pose_clip_7class.csv")  # carries a Wash row
    with pytest.raises(DataError, match=r"pose_clip_7class.csv:3: class 'Wash'"):
        read_cmu_mocap(tmp_path)
    assert len(read_cmu_mocap(tmp_path, drop_unknown=True)) == 6
    (tmp_path / "mocap_3djoints" / "90_15.npy").unlink()
    with pytest.raises(MissingDataError, match="90_15.npy"):
        read_cmu_mocap(tmp_path, drop_unknown=True)
    with pytest.raises(MissingDataError, match="pose_clip_7class.csv"):
        read_cmu_mocap(tmp_path / "empty")
