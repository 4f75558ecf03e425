"""UESTC in ODMO's layout (odmo_3d npy + split CSVs) and ACTOR's (VIBE cache + info lists)."""

import pickle

import numpy as np
import pytest
from upstream_synth import fk_clip, from_y_up, skeleton_of

from repro.data.upstream.skeletons import UESTC_18, VIBE_TO_UESTC18
from repro.data.upstream.uestc import (UESTC_ODMO_CLASSES, detect_layout, read_uestc,
                                       uestc_clipset, weak_perspective_depth)
from repro.errors import DataError, MissingDataError


def write_odmo(root, seed=0):
    rng = np.random.default_rng(seed)
    skel = skeleton_of(UESTC_18, seed=3)
    (root / "odmo_3d").mkdir(parents=True)
    rows = {"uestc_train.csv": [], "uestc_test.csv": []}
    truth = {}
    specs = [("a1_d1_p001_c1_color.avi", "squatting", "uestc_train.csv"),
             ("a2_d4_p001_c2_color.avi", "jumping-jack", "uestc_train.csv"),
             ("a3_d2_p005_c1_color.avi", "high-knees-running", "uestc_test.csv")]
    for name, action, csv_name in specs:
        y_up = fk_clip(skel, int(rng.integers(10, 16)), rng)
        np.save(root / "odmo_3d" / (name.split(".")[0] + ".npy"),
                from_y_up(y_up, "-y").astype(np.float32))
        rows[csv_name].append(f",{name},{action}")
        truth[name] = y_up
    for csv_name, lines in rows.items():
        (root / csv_name).write_text(",motion,action_type\n" + "\n".join(lines) + "\n\n")
    return truth


def test_odmo_layout(tmp_path):
    truth = write_odmo(tmp_path)
    assert detect_layout(tmp_path) == "odmo"
    data = read_uestc(tmp_path)
    assert data.layout == "odmo" and len(data) == 3
    assert data.class_names == UESTC_ODMO_CLASSES
    assert [data.class_names[i] for i in data.labels] == ["squatting", "jumping-jack",
                                                          "high-knees-running"]
    assert data.split.tolist() == [0, 0, 1]
    assert data.subjects.tolist() == [1, 1, 5] and data.views.tolist() == [1, 4, 2]
    cs = uestc_clipset(data)
    assert cs.skeleton.names == UESTC_18.names
    for i, name in enumerate(data.clip_names):
        np.testing.assert_allclose(cs.clip_joints(i), truth[name], atol=1e-5)
    assert (cs.split == data.split).all()


def test_odmo_layout_errors(tmp_path):
    write_odmo(tmp_path)
    csv = tmp_path / "uestc_test.csv"
    csv.write_text(",motion,action_type\n,a3_d2_p005_c1_color.avi,moonwalking\n")
    with pytest.raises(DataError, match=r"uestc_test.csv:2: unknown UESTC action 'moonwalking'"):
        read_uestc(tmp_path)
    csv.write_text(",motion,action_type\n,a9_d2_p005_c1_color.avi,squatting\n")
    with pytest.raises(MissingDataError, match=r"a9_d2_p005_c1_color.npy.*line 2 of uestc_test"):
        read_uestc(tmp_path)
    np.save(tmp_path / "odmo_3d" / "a9_d2_p005_c1_color.npy", np.zeros((4, 17, 3)))
    with pytest.raises(DataError, match=r"expected \(T, 18, 3\)"):
        read_uestc(tmp_path)
    with pytest.raises(MissingDataError, match="no UESTC data"):
        read_uestc(tmp_path / "nowhere")


def _actor_get_z(cam_s, cam_pos, joints, img_size=540, flength=500):
    """ACTOR's get_z as its docstring describes it (height ratio), written out independently."""
    target = (cam_s * (joints[:, :2] + cam_pos) + 1) * 0.5 * img_size
    h3 = np.linalg.norm(joints[:, :2].max(0) - joints[:, :2].min(0))
    h2 = np.linalg.norm(target.max(0) - target.min(0))
    return flength * h3 / h2


def write_actor(root, seed=0):
    rng = np.random.default_rng(seed)
    skel = skeleton_of(UESTC_18, seed=4)
    (root / "info").mkdir(parents=True)
    classes = list(UESTC_ODMO_CLASSES)[::-1]         # ACTOR's own order differs from ODMO's
    clips = [("a0_d1_p001_c1_color.avi", 50, 48),   # train, front, truncated to 48
             ("a5_d2_p001_c2_color.avi", 50, 50),   # train, side view 2: turned to the front
             ("a3_d8_p002_c2_color.avi", 50, 50),   # side view 8: dropped
             ("a7_d3_p003_c1_color.avi", 20, 20),   # test subject: kept although short
             ("a9_d1_p006_c1_color.avi", 30, 30)]   # train subject, < 45 frames: dropped
    joints3d, poses, cams = [], [], []
    for _, T, _ in clips:
        j18 = from_y_up(fk_clip(skel, T, rng, scale=0.2), "-y")
        j49 = rng.normal(size=(T, 49, 3))
        j49[:, list(VIBE_TO_UESTC18)] = j18
        joints3d.append(j49.astype(np.float32))
        poses.append(rng.normal(size=(T, 72)).astype(np.float32))
        s = rng.uniform(0.8, 1.2, size=T)
        cams.append(np.stack([s, s, rng.normal(scale=0.1, size=T),
                              rng.normal(scale=0.1, size=T)], axis=1).astype(np.float32))
    with open(root / "vibe_cache_refined.pkl", "wb") as f:
        pickle.dump({"pose": poses, "joints3d": joints3d, "orig_cam": cams}, f, protocol=2)
    (root / "info/names.txt").write_text("\n".join(c[0] for c in clips) + "\n")
    (root / "info/num_frames_min.txt").write_text("\n".join(str(c[2]) for c in clips) + "\n")
    (root / "info/action_classes.txt").write_text("\n".join(classes) + "\n")
    return clips, joints3d, cams, classes


def _expected_actor(j49, cam, n, view, side):
    j = j49[:n].astype(np.float64)
    gt = np.array([[c[2], c[3], _actor_get_z(c[0], c[2:4], j49[t].astype(np.float64))]
                   for t, c in enumerate(cam.astype(np.float64))])[:n]
    gt = gt - gt[0]
    if side != 1:
        th = -view * np.pi / 4
        R = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
        j, gt = j @ R.T, gt @ R.T
    return (j + gt[:, None])[:, list(VIBE_TO_UESTC18)]


def test_actor_layout_reproduces_actor_processing(tmp_path):
    clips, joints3d, cams, classes = write_actor(tmp_path)
    assert detect_layout(tmp_path) == "actor"
    data = read_uestc(tmp_path)
    assert data.layout == "actor"
    assert data.clip_names == (clips[0][0], clips[1][0], clips[3][0])
    assert data.split.tolist() == [0, 0, 1]
    assert data.class_names == tuple(classes)
    assert data.labels.tolist() == [0, 5, 7]
    assert [j.shape[0] for j in data.joints] == [48, 50, 20]
    for k, src in zip(range(3), (0, 1, 3)):
        view, side = (1, 1) if src != 1 else (2, 2)
        exp = _expected_actor(joints3d[src], cams[src], clips[src][2], view, side)
        np.testing.assert_allclose(data.joints[k], exp, atol=1e-4)
    odmo = read_uestc(tmp_path, class_order="odmo")
    assert odmo.class_names == UESTC_ODMO_CLASSES
    assert [odmo.class_names[i] for i in odmo.labels] == [classes[0], classes[5], classes[7]]
    cs = uestc_clipset(data)
    assert len(cs) == 3 and cs.split.tolist() == [0, 0, 1]


def test_weak_perspective_depth_matches_height_ratio_form():
    rng = np.random.default_rng(0)
    for _ in range(5):
        j = rng.normal(size=(49, 3))
        s, pos = rng.uniform(0.5, 2.0), rng.normal(size=2)
        assert np.isclose(weak_perspective_depth(s), _actor_get_z(s, pos, j))


def test_actor_layout_errors(tmp_path):
    write_actor(tmp_path)
    (tmp_path / "info/num_frames_min.txt").write_text("10\n20\n")
    with pytest.raises(DataError, match="2 frame counts for 5 names"):
        read_uestc(tmp_path)
    write_actor(tmp_path / "b")
    (tmp_path / "b/info/names.txt").write_text("clip0\nclip1\nclip2\nclip3\nclip4\n")
    with pytest.raises(DataError, match=r"names.txt:1: name 'clip0'"):
        read_uestc(tmp_path / "b")
