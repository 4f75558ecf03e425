"""HumanAct12 from a humanact12poses.pkl written exactly as ACTOR distributes it."""

import pickle

import numpy as np
import pytest
from upstream_synth import fk_clip, skeleton_of

from repro.data.upstream.humanact12 import (HUMANACT12_CLASSES, humanact12_clipset,
                                            read_humanact12)
from repro.data.upstream.skeletons import SMPL_24
from repro.errors import DataError, MissingDataError


def write_humanact12(path, n=6, seed=0, protocol=2):
    rng = np.random.default_rng(seed)
    skel = skeleton_of(SMPL_24, seed=1)
    joints = [fk_clip(skel, int(rng.integers(8, 20)), rng).astype(np.float32) for _ in range(n)]
    poses = [rng.normal(scale=0.2, size=(j.shape[0], 72)).astype(np.float32) for j in joints]
    y = [int(i % 12) for i in range(n)]
    with open(path, "wb") as f:
        pickle.dump({"poses": poses, "joints3D": joints, "y": y}, f, protocol=protocol)
    return joints, poses, y


def test_reads_actor_keys_and_builds_clipset(tmp_path):
    p = tmp_path / "humanact12poses.pkl"
    joints, poses, y = write_humanact12(p)
    data = read_humanact12(tmp_path)          # a folder is accepted too
    assert len(data) == 6 and data.class_names == HUMANACT12_CLASSES
    assert data.class_names[0] == "Warm up" and data.class_names[11] == "Throw"
    assert data.labels.tolist() == y
    np.testing.assert_array_equal(data.poses[2], poses[2])
    np.testing.assert_array_equal(data.joints[4], joints[4])
    cs = humanact12_clipset(data)
    assert cs.skeleton.names == SMPL_24.names and cs.skeleton.n_joints == 24
    assert len(cs) == 6 and (cs.split == 0).all() and cs.label_names == HUMANACT12_CLASSES
    np.testing.assert_allclose(cs.clip_joints(3), joints[3], atol=1e-6)   # +y: unchanged
    # One skeleton for all clips (same bone lengths here), so FK of the fits matches the data.
    import roma
    import torch

    from repro.motion.skeleton import forward_kinematics

    R = roma.unitquat_to_rotmat(torch.from_numpy(cs.rotations.astype(np.float64))).numpy()
    pos = forward_kinematics(cs.skeleton, R, cs.root.astype(np.float64))
    assert np.abs(pos - cs.joints).max() < 1e-4
    assert humanact12_clipset(read_humanact12(p)).fingerprint == cs.fingerprint


def test_fingerprint_follows_file_content(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    write_humanact12(a / "humanact12poses.pkl", seed=0)
    write_humanact12(b / "humanact12poses.pkl", seed=0, protocol=4)
    fa, fb = read_humanact12(a).fingerprint, read_humanact12(b).fingerprint
    assert fa != fb  # different bytes (protocol) -> different fingerprint
    write_humanact12(b / "humanact12poses.pkl", seed=0)
    assert read_humanact12(b).fingerprint == fa


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d.pop("y"), "missing key 'y'"),
    (lambda d: d["y"].pop(), "differ in length"),
    (lambda d: d["y"].__setitem__(0, 12), "label 12 outside"),
    (lambda d: d["joints3D"].__setitem__(1, np.zeros((5, 23, 3))), r"clip 1: joints3D must be"),
    (lambda d: d["poses"].__setitem__(2, np.zeros((3, 72))), "clip 2: poses has 3 frames"),
])
def test_malformed_files_name_file_and_problem(tmp_path, mutate, message):
    p = tmp_path / "humanact12poses.pkl"
    write_humanact12(p)
    with open(p, "rb") as f:
        d = pickle.load(f)
    mutate(d)
    with open(p, "wb") as f:
        pickle.dump(d, f, protocol=2)
    with pytest.raises(DataError, match=message) as e:
        read_humanact12(p)
    assert str(p) in str(e.value)


def test_missing_file_and_wrong_up_axis(tmp_path):
    with pytest.raises(MissingDataError, match="humanact12poses.pkl"):
        read_humanact12(tmp_path)
    p = tmp_path / "humanact12poses.pkl"
    write_humanact12(p)
    with pytest.raises(DataError, match="up-axis"):
        humanact12_clipset(read_humanact12(p), up="-y")
