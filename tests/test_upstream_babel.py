"""BABEL v1.0 split files joined with AMASS npz motions, written in exactly those formats."""

import json

import numpy as np
import pytest
from upstream_synth import body_model_arrays

from repro.data.upstream.amass import amass_joints, read_amass_npz
from repro.data.upstream.axes import to_y_up
from repro.data.upstream.babel import (babel_clipset, babel_frame_segments, read_babel,
                                       read_babel_split)
from repro.data.upstream.skeletons import SMPLH_52
from repro.data.upstream.smpl import load_body_model
from repro.errors import DataError, MissingDataError
from repro.motion.skeleton import forward_kinematics


def _lab(raw, proc, cats, seg, start=None, end=None):
    d = {"act_cat": cats, "proc_label": proc, "raw_label": raw, "seg_id": seg}
    if start is not None:
        d.update(start_t=start, end_t=end)
    return d


SEQS = {
    "train": {
        "7692": {"babel_sid": 7692, "dur": 2.0, "feat_p": "CMU/CMU/01/01_01_poses.npz",
                 "url": "https://example/007692.mp4",
                 "seq_ann": {"anntr_id": "a", "babel_lid": "b", "mul_act": True,
                             "labels": [_lab("walk then sit", "walk and sit", ["walk", "sit"],
                                             "s0")]},
                 "frame_ann": {"anntr_id": "c", "babel_lid": "d", "mul_act": True, "labels": [
                     _lab("sitting down", "sit", ["sit"], "f2", 1.2, 2.004),
                     _lab("walking", "walk", ["walk"], "f0", 0, 1),
                     _lab("transition", "transition", ["transition"], "f1", 1, 1.2),
                     _lab("waving", "wave", ["wave", "hand movements"], "f3", 0.5, 1.5)]}},
        "12": {"babel_sid": 12, "dur": 1.2, "feat_p": "EyesJapanDataset/Eyes/x/jump_poses.npz",
               "url": None,
               "seq_ann": {"anntr_id": "e", "babel_lid": "f", "mul_act": False,
                           "labels": [_lab("standing", "stand", ["stand"], "s1")]},
               "frame_ann": None},
    },
    "val": {
        "40": {"babel_sid": 40, "dur": 1.5, "feat_p": "KIT/KIT/3/walk_poses.npz", "url": "u",
               "seq_ann": {"anntr_id": "g", "babel_lid": "h", "mul_act": True,
                           "labels": [_lab("walk, jump", "walk jump", ["walk", "jump"], "s2")]},
               "frame_ann": {"anntr_id": "i", "babel_lid": "j", "mul_act": True, "labels": [
                   _lab("walk", "walk", ["walk"], "v0", 0, 0.5),
                   _lab("jump", "jump", ["jump"], "v1", 0.5, 1.5),
                   _lab("blink", "blink", ["blink"], "v2", 0.5, 0.5)]}},
    },
}
MOTIONS = {"CMU/CMU/01/01_01_poses.npz": (120.0, 240), "EyesJapanDataset/Eyes/x/jump_poses.npz":
           (250.0, 300), "KIT/KIT/3/walk_poses.npz": (60.0, 90)}


def write_babel(root, seed=0):
    rng = np.random.default_rng(seed)
    (root / "babel_v1.0_release").mkdir(parents=True)
    for split, seqs in SEQS.items():
        (root / "babel_v1.0_release" / f"{split}.json").write_text(json.dumps(seqs, indent=1))
    for feat, (fps, T) in MOTIONS.items():
        p = root / "AMASS" / feat
        p.parent.mkdir(parents=True, exist_ok=True)
        np.savez(p, poses=rng.normal(scale=0.3, size=(T, 156)),
                 trans=np.cumsum(rng.normal(scale=0.01, size=(T, 3)), axis=0),
                 betas=rng.normal(size=16), gender=np.array("male"),
                 mocap_framerate=np.array(fps), dmpls=np.zeros((T, 8)))
    return root


def test_split_file_structure_is_parsed(tmp_path):
    write_babel(tmp_path)
    seqs = read_babel_split(tmp_path / "babel_v1.0_release" / "train.json")
    a, b = seqs
    assert (a.sid, a.babel_sid, a.feat_p, a.dur, a.split) == ("7692", 7692,
                                                               "CMU/CMU/01/01_01_poses.npz", 2.0,
                                                               "train")
    assert a.seq_labels[0].proc_label == "walk and sit" and a.seq_labels[0].start_t is None
    wave = a.frame_labels[3]
    assert (wave.raw_label, wave.proc_label, wave.act_cat, wave.start_t, wave.end_t) == (
        "waving", "wave", ("wave", "hand movements"), 0.5, 1.5)
    assert b.frame_labels is None and b.url is None


def test_segments_become_frames_at_the_files_rate(tmp_path):
    data = read_babel(write_babel(tmp_path))
    a, b, c = data.sequences
    assert [s.split for s in data.sequences] == ["train", "train", "val"]
    segs = babel_frame_segments(a, 120.0, 240)
    assert [(s.proc_label, s.start, s.stop) for s in segs] == [
        ("walk", 0, 120), ("wave", 60, 180), ("transition", 120, 144), ("sit", 144, 240)]
    assert [(s.proc_label, s.start, s.stop, s.level) for s in babel_frame_segments(b, 250.0, 300)
            ] == [("stand", 0, 300, "seq")]
    segs_c = babel_frame_segments(c, 60.0, 90)
    assert [(s.proc_label, s.start, s.stop) for s in segs_c] == [("walk", 0, 30),
                                                                 ("jump", 30, 90)]
    assert len(babel_frame_segments(c, 60.0, 90, drop_empty=False)) == 3


def test_missing_amass_file_and_bad_json(tmp_path):
    write_babel(tmp_path)
    (tmp_path / "AMASS" / "KIT/KIT/3/walk_poses.npz").unlink()
    with pytest.raises(MissingDataError, match=r"1 of 3 AMASS files.*walk_poses.npz"):
        read_babel(tmp_path)
    (tmp_path / "babel_v1.0_release" / "val.json").write_text('{"1": {"feat_p": "x",\n oops}')
    with pytest.raises(DataError, match=r"val.json:2: invalid JSON"):
        read_babel(tmp_path)
    (tmp_path / "babel_v1.0_release" / "val.json").write_text(json.dumps(
        {"1": {"feat_p": "x", "dur": 1, "seq_ann": None,
               "frame_ann": {"labels": [{"proc_label": "a", "start_t": 2, "end_t": 1}]}}}))
    with pytest.raises(DataError, match="sequence 1.frame_ann.labels.0.: bad segment times"):
        read_babel_split(tmp_path / "babel_v1.0_release" / "val.json")


def test_amass_npz_validation(tmp_path):
    p = tmp_path / "m.npz"
    np.savez(p, poses=np.zeros((4, 156)), trans=np.zeros((4, 3)))
    with pytest.raises(DataError, match="m.npz: AMASS npz lacks mocap_framerate"):
        read_amass_npz(p)
    np.savez(p, poses=np.zeros((4, 156)), trans=np.zeros((4, 3)), mocap_frame_rate=30.0,
             gender=np.array(["Female"]))
    m = read_amass_npz(p)
    assert m.fps == 30.0 and m.gender == "female" and m.betas is None
    np.savez(p, poses=np.zeros((4, 156)), trans=np.zeros((5, 3)), mocap_framerate=30.0)
    with pytest.raises(DataError, match=r"trans must be \(4, 3\)"):
        read_amass_npz(p)
    np.savez(p, poses=np.array([{"a": 1}], dtype=object), trans=np.zeros((1, 3)),
             mocap_framerate=30.0)
    with pytest.raises(DataError, match="not a readable AMASS npz"):
        read_amass_npz(p)


@pytest.fixture
def smplh(tmp_path):
    np.savez(tmp_path / "model.npz", **body_model_arrays(SMPLH_52, seed=4))
    return load_body_model(tmp_path / "model.npz")


def test_babel_clipset_segments_joints_and_rotations(tmp_path, smplh):
    data = read_babel(write_babel(tmp_path / "babel"))
    cs = babel_clipset(data, smplh)
    assert cs.label_names == ("jump", "sit", "stand", "walk", "wave")   # transition excluded
    names = [cs.label_names[i] for i in cs.labels]
    assert names == ["walk", "wave", "sit", "stand", "walk", "jump"]
    # 120 Hz -> step 6, 250 Hz -> step 12, 60 Hz -> step 3 (MultiAct's int(round(fps)/20))
    assert cs.lengths.tolist() == [20, 20, 16, 25, 10, 20]
    assert cs.split.tolist() == [0, 0, 0, 0, 1, 1] and cs.fps == 20.0
    assert cs.skeleton.names == SMPLH_52.names
    # Joints are SMPL-H FK in Y-up metres; the root is C (J0 + trans) at the kept frames.
    mot = data.load_motion(data.sequences[0])
    frames = np.arange(144, 240, 6)
    np.testing.assert_allclose(cs.clip_joints(2), amass_joints(mot, smplh, frames=frames),
                               atol=1e-5)
    np.testing.assert_allclose(cs.clip_root(2), to_y_up(smplh.rest_joints()[0] + mot.trans[frames],
                                                        "+z"), atol=1e-5)
    # FK of the stored (Y-up) rotations from the stored root reproduces the stored joints.
    import roma
    import torch

    R = roma.unitquat_to_rotmat(torch.from_numpy(cs.rotations.astype(np.float64))).numpy()
    pos = forward_kinematics(cs.skeleton, R, cs.root.astype(np.float64))
    np.testing.assert_allclose(pos, cs.joints, atol=1e-4)
    only = babel_clipset(data, smplh, labels=["walk"])
    assert len(only) == 2 and only.fingerprint != cs.fingerprint
    assert babel_clipset(data, smplh).fingerprint == cs.fingerprint


def test_mesh_joints_option_and_fingerprint(tmp_path, smplh):
    data = read_babel(write_babel(tmp_path / "babel"))
    fk = babel_clipset(data, smplh, labels=["jump"])
    mesh = babel_clipset(data, smplh, labels=["jump"], joint_method="mesh")
    assert fk.fingerprint != mesh.fingerprint
    gap = np.abs(fk.joints - mesh.joints).max()
    assert 0 < gap < 0.2
    np.testing.assert_allclose(fk.root, mesh.root)    # the root stays the FK pelvis
