"""BVH export (repro.data.bvh_write): round trips through our reader, the Bandai converter and
the independent library bvhio; validation and determinism."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from repro.data.bvh import parse_bvh, read_bvh
from repro.data.bvh_write import END_SITE_FRACTION, bvh_text, write_bvh
from repro.motion.skeleton import Skeleton, forward_kinematics

# A 10-joint tree with two branches off the root and one off the chest.
NAMES = ("Hips", "Spine", "Chest", "Neck", "Head", "Arm_L", "Hand_L", "Leg_L", "Knee_L", "Leg_R")
PARENTS = (-1, 0, 1, 2, 3, 2, 5, 0, 7, 0)


def random_skeleton(seed: int = 0) -> Skeleton:
    rng = np.random.default_rng(seed)
    offsets = rng.uniform(-0.3, 0.3, size=(len(NAMES), 3))
    offsets[0] = [0.01, 0.9, -0.02]  # a root offset (ignored by FK; written as zero)
    return Skeleton(NAMES, PARENTS, offsets)


def random_motion(skel: Skeleton, T: int = 12, seed: int = 0):
    """(root (T, 3) m, rotmats (T, J, 3, 3)): uniform random rotations, plus Euler triples in
    ZXY whose middle (X) angle sits at or near ±90° (gimbal lock) and outer angles near ±180°."""
    rng = np.random.default_rng(seed)
    J = skel.n_joints
    R = Rotation.random(T * J, random_state=seed).as_matrix().reshape(T, J, 3, 3)
    mids = np.array([89.0, -89.0, 89.99, -89.999, 90.0, -90.0, 179.9, -179.99])
    k = T * J // 2
    eul = rng.uniform(-180, 180, size=(k, 3))
    eul[:, 1] = rng.choice(mids[:6], size=k) + rng.normal(0, 0.01, size=k) * (rng.random(k) < .5)
    eul[::3, 0] = rng.choice(mids[6:], size=len(eul[::3]))
    flat = R.reshape(T * J, 3, 3)
    idx = rng.permutation(T * J)[:k]
    flat[idx] = Rotation.from_euler("ZXY", eul, degrees=True).as_matrix()
    root = rng.normal(0, 1.5, size=(T, 3))
    return root, flat.reshape(T, J, 3, 3)


def fk_cm(skel, R, root):
    return forward_kinematics(skel, np.asarray(R, np.float64), np.asarray(root, np.float64)) * 100


# ----------------------------------------------------------------------------- our reader
@pytest.mark.parametrize("order", ["ZXY", "XYZ", "YZX"])
def test_random_motion_round_trips_through_our_reader(tmp_path, order):
    skel = random_skeleton()
    root, R = random_motion(skel)
    p = write_bvh(tmp_path / "sub" / "gen.bvh", skel, root, R, 30.0, order=order)
    assert p.is_file() and not [q for q in p.parent.iterdir() if q != p]  # no temp file left
    b = read_bvh(p)
    assert b.names == skel.names and b.parents == skel.parents
    assert b.channels[0] == ("Xposition", "Yposition", "Zposition") + tuple(
        f"{a}rotation" for a in order)
    assert all(c == tuple(f"{a}rotation" for a in order) for c in b.channels[1:])
    assert b.n_frames == len(root) and b.fps == pytest.approx(30.0, rel=1e-6)
    np.testing.assert_allclose(b.offsets[1:], skel.offsets[1:] * 100, atol=1e-6)
    assert np.abs(b.offsets[0]).max() == 0.0
    leaves = tuple(j for j in range(len(NAMES)) if j not in PARENTS)
    assert b.end_parents == leaves
    np.testing.assert_allclose(b.end_offsets, skel.offsets[list(leaves)] * 100 * END_SITE_FRACTION,
                               atol=1e-6)
    rot_err = np.abs(b.local_rotations().numpy() - R).max()
    pos_err = np.abs(b.world_positions() - fk_cm(skel, R, root)).max()
    assert rot_err < 1e-6, rot_err
    assert pos_err < 1e-4, pos_err  # cm


def test_torch_float32_input_and_units_m(tmp_path):
    skel = random_skeleton(1)
    root, R = random_motion(skel, T=5, seed=1)
    text_np = bvh_text(skel, root, R.astype(np.float32), 25.0)
    text_t = bvh_text(skel, torch.tensor(root), torch.tensor(R, dtype=torch.float32,
                                                              requires_grad=True), 25.0)
    assert text_np == text_t
    b = parse_bvh(bvh_text(skel, root, R, 25.0, units="m", precision=8))
    pos_err = np.abs(b.world_positions(scale=100.0) - fk_cm(skel, R, root)).max()
    assert pos_err < 1e-4, pos_err  # cm
    np.testing.assert_allclose(b.offsets[1:], skel.offsets[1:], atol=1e-8)
    # default precision in metres: 5e-7 m rounding on the root, still well under 1e-4 m
    b6 = parse_bvh(bvh_text(skel, root, R, 25.0, units="m"))
    assert np.abs(b6.world_positions() - fk_cm(skel, R, root) / 100).max() < 1e-5


def test_output_is_deterministic_and_clean():
    skel = random_skeleton()
    root, R = random_motion(skel, T=4)
    a = bvh_text(skel, root, R, 30.0)
    assert a == bvh_text(skel, root.copy(), R.copy(), 30.0)
    assert "-0.000000" not in a and "nan" not in a.lower()
    lines = a.splitlines()
    assert lines[0] == "HIERARCHY" and "MOTION" in lines
    assert lines[lines.index("MOTION") + 1:lines.index("MOTION") + 3] == [
        "Frames: 4", "Frame Time: 0.03333333"]
    assert len(lines) == lines.index("MOTION") + 3 + 4
    assert parse_bvh(a).names == skel.names
    # a name with a space survives our reader (not every reader: bvhio keeps the first word)
    spaced = Skeleton(NAMES[:-1] + ("Leg R",), PARENTS, skel.offsets)
    assert "JOINT Leg R\n" in bvh_text(spaced, root, R, 30.0)
    assert parse_bvh(bvh_text(spaced, root, R, 30.0)).names[-1] == "Leg R"


# ----------------------------------------------------------------------------- validation
def test_bad_input_raises_value_error():
    skel = random_skeleton()
    root, R = random_motion(skel, T=3)
    cases = [
        ((skel, root, R[:, :-1], 30), {}, r"\(T, 10, 3, 3\)"),
        ((skel, root, R[..., :2], 30), {}, "shape"),
        ((skel, root[:2], R, 30), {}, r"root must have shape \(3, 3\)"),
        ((skel, root, R[:0], 30), {}, "no frames"),
        ((skel, root, R, 0), {}, "fps"),
        ((skel, root, R, float("nan")), {}, "fps"),
        ((skel, root, R, 30), {"order": "zxy"}, "upper-case"),
        ((skel, root, R, 30), {"order": "ZXZ"}, "permutation"),
        ((skel, root, R, 30), {"units": "mm"}, "units"),
        ((skel, root, R * 2, 30), {}, "not a rotation"),
        ((skel, root, -R, 30), {}, "not a rotation"),
        ((skel, root, R, 30), {"dummy_root": "Hips"}, "already a joint"),
        ((skel, root, R, 30), {"dummy_root": "a { b"}, "dummy_root"),
        ((skel, root, R, 30), {"precision": -1}, "precision"),
    ]
    for args, kw, msg in cases:
        with pytest.raises(ValueError, match=msg):
            bvh_text(*args, **kw)
    for bad_val in (np.nan, np.inf):
        r2, R2 = root.copy(), R.copy()
        r2[1, 2] = bad_val
        with pytest.raises(ValueError, match=r"root holds a non-finite value .*\(1, 2\)"):
            bvh_text(skel, r2, R, 30)
        R2[2, 4, 0, 1] = bad_val
        with pytest.raises(ValueError, match="rotmats holds a non-finite"):
            bvh_text(skel, root, R2, 30)
    bad_names = Skeleton(("a", "b\tc"), (-1, 0), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="joint name"):
        bvh_text(bad_names, root, R[:, :2], 30)


def test_failed_write_leaves_no_file(tmp_path):
    skel = random_skeleton()
    root, R = random_motion(skel, T=2)
    with pytest.raises(ValueError):
        write_bvh(tmp_path / "x.bvh", skel, root, R[:, :3], 30)
    assert not list(tmp_path.iterdir())


# ----------------------------------------------------------------------------- real data
@pytest.fixture(scope="module")
def real_clip():
    """The shortest clip of the bundled mini data set: (skeleton, root m, rotmats, fps)."""
    import roma

    from repro.data.bundle import load_mini

    cs = load_mini()
    i = int(np.argmin(cs.lengths))
    q = torch.from_numpy(np.asarray(cs.clip_rotations(i), np.float64))
    R = roma.unitquat_to_rotmat(q / q.norm(dim=-1, keepdim=True)).numpy()
    joints = np.asarray(cs.clip_joints(i), np.float64)
    return cs.skeleton, np.asarray(cs.clip_root(i), np.float64), R, cs.fps, joints


def test_real_clip_round_trips(tmp_path, real_clip):
    skel, root, R, fps, joints = real_clip
    b = read_bvh(write_bvh(tmp_path / "real.bvh", skel, root, R, fps))
    assert b.names == skel.names and b.n_frames == len(root)
    ours = b.world_positions()
    pos_err = np.abs(ours - fk_cm(skel, R, root)).max()
    assert pos_err < 1e-4, pos_err  # cm
    assert np.abs(ours - joints * 100).max() < 1e-3  # the stored float32 joints
    assert np.abs(b.local_rotations().numpy() - R).max() < 1e-6


def test_dummy_root_passes_the_bandai_converter(real_clip):
    from repro.data.bandai import CM_TO_M, DUMMY_ROOT, convert_clips

    skel, root, R, fps, _ = real_clip
    text = bvh_text(skel, root, R, fps, dummy_root=DUMMY_ROOT)
    b = parse_bvh(text)
    assert b.names == (DUMMY_ROOT,) + skel.names and b.parents[:2] == (-1, 0)
    assert np.abs(b.motion[:, :6]).max() == 0.0 and np.abs(b.offsets[0]).max() == 0.0
    (res,) = convert_clips([("exported/dataset-2_walk_normal_999.bvh", text.encode())])
    assert res["names"] == skel.names and res["parents"] == skel.parents
    assert res["frame_time"] == pytest.approx(1 / fps, rel=1e-6)
    np.testing.assert_allclose(res["offsets"][1:] * CM_TO_M, skel.offsets[1:], atol=1e-8)
    expected = fk_cm(skel, R, root)
    # res["joints"] is float32 metres: allow its rounding on top of 1e-4 cm
    tol = 1e-4 + 100 * float(np.spacing(np.float32(np.abs(expected).max() / 100)))
    assert np.abs(res["joints"].astype(np.float64) * 100 - expected).max() < tol  # cm
    assert np.abs(res["root"].astype(np.float64) - root).max() < 1e-6  # m
    q = res["rotations"].astype(np.float64)
    R_back = Rotation.from_quat(q.reshape(-1, 4)).as_matrix().reshape(R.shape)
    assert np.abs(R_back - R).max() < 1e-6


# ----------------------------------------------------------------------------- bvhio
def _bvhio_positions(bvhio, path, frames):
    root = bvhio.readAsHierarchy(str(path))
    layout = [j for j, _, _ in root.layout()]
    out = np.empty((len(frames), len(layout), 3))
    for k, f in enumerate(frames):
        root.loadPose(int(f))
        for i, j in enumerate(layout):
            out[k, i] = tuple(j.PositionWorld)
    return tuple(j.Name for j in layout), out


@pytest.mark.parametrize("which", ["random", "real"])
def test_independent_reader_bvhio_agrees(tmp_path, real_clip, which):
    bvhio = pytest.importorskip("bvhio")
    if which == "random":
        skel = random_skeleton(2)
        root, R = random_motion(skel, T=6, seed=2)
        fps = 30.0
    else:
        skel, root, R, fps, _ = real_clip
    p = write_bvh(tmp_path / f"{which}.bvh", skel, root, R, fps)
    meta = bvhio.readAsBvh(str(p))
    assert meta.FrameCount == len(root) and meta.FrameTime == pytest.approx(1 / fps, rel=1e-6)
    frames = np.unique(np.linspace(0, len(root) - 1, 4).round().astype(int))
    names, theirs = _bvhio_positions(bvhio, p, frames)
    assert names == skel.names
    err = np.abs(theirs - fk_cm(skel, R, root)[frames]).max()
    assert err < 1e-3, err  # cm (bvhio computes in float32)
