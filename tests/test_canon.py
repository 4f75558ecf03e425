"""Motion, heading and canonicalisations (repro.motion.motion / heading / canon)."""

from __future__ import annotations

import math
import re
import tarfile

import numpy as np
import pytest
import torch

from repro.data.clipset import ClipSet
from repro.motion.canon import (canonicalize_with, face_front, marionette_normalize,
                                positions_root_to_origin, root_to_origin, uncanonicalize,
                                zero_canon)
from repro.motion.heading import (body_frame, body_forward, body_heading, chain_global_rotmat,
                                  heading_angle, motion_heading, positions_heading,
                                  rotate_about_y, yaw_matrix)
from repro.motion.motion import Motion
from repro.motion.rotations import euler_to_matrix, matrix_to_euler, random_rotmats
from repro.motion.skeleton import Skeleton, forward_kinematics
from repro.seeding import torch_generator

ATOL = 1e-5


def smpl_like() -> Skeleton:
    """Nine SMPL joints with (rounded) SMPL neutral rest offsets, metres; faces +Z, Y up."""
    names = ("pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
             "neck", "head")
    parents = (-1, 0, 0, 0, 1, 2, 3, 6, 7)
    offsets = [[0, 0, 0], [0.059, -0.082, -0.018], [-0.060, -0.091, -0.004], [0.004, 0.124, -0.038],
               [0.043, -0.386, 0.008], [-0.043, -0.383, -0.005], [0.004, 0.138, 0.027],
               [-0.013, 0.210, -0.033], [0.005, 0.065, 0.051]]
    return Skeleton(names, parents, np.array(offsets))


def bandai_like() -> Skeleton:
    """The stand-in's hips/spine/legs with its BVH rest offsets (cm → m): bones along ±X."""
    names = ("Hips", "Spine", "Chest", "Neck", "Head", "UpperLeg_L", "LowerLeg_L", "UpperLeg_R",
             "LowerLeg_R")
    parents = (-1, 0, 1, 2, 3, 0, 5, 0, 7)
    offsets = np.array([[-0.726466, 93.3139, -2.00062], [15.7357, 0, 0], [8.98455, -0.406207, 0],
                        [16.3773, 0, 0], [6.45672, 0, 0], [-2.19248, -6.46944, 0],
                        [39.0811, 0, 0], [-2.19251, 6.46944, 0], [-39.0811, 0, 0]]) / 100.0
    return Skeleton(names, parents, offsets)


def random_motion(skeleton: Skeleton, B=4, T=9, seed=0, dtype=torch.float32) -> Motion:
    g = torch_generator(seed, "motion", skeleton.names[0])
    R = random_rotmats((B, T, skeleton.n_joints), g, dtype=dtype)
    root = torch.randn(B, T, 3, generator=g, dtype=dtype) + torch.tensor([0.0, 0.9, 0.0], dtype=dtype)
    return Motion.from_rotmats(root, R, skeleton, 30.0)


def assert_same_motion(a: Motion, b: Motion, atol=ATOL):
    assert torch.allclose(a.root, b.root, atol=atol)
    assert torch.allclose(a.rot6d, b.rot6d, atol=atol)
    assert torch.allclose(a.joints(), b.joints(), atol=atol)


def body_rotmats(m: Motion, frame_index=None) -> torch.Tensor:
    """R_pelvis · F: the body frame's axes (left, up, forward) in the world."""
    bf = body_frame(m.skeleton)
    G = chain_global_rotmat(m.skeleton, m.rotmats(), bf.pelvis)
    return G @ torch.as_tensor(bf.matrix, dtype=G.dtype)


def up_floor_angle(m: Motion) -> torch.Tensor:
    """Angle (B, T) between the body's up axis and the floor plane (radians)."""
    up = body_rotmats(m)[..., :, 1]
    return torch.asin(up[..., 1].clamp(-1, 1))


SKELETONS = [smpl_like, bandai_like]


# --- body frame and heading ----------------------------------------------------------------
def test_body_frame_of_stand_in_rest_pose():
    bf = body_frame(bandai_like())
    assert bf.pelvis == 0 and bf.joints == ("UpperLeg_L", "UpperLeg_R", "Head")
    assert np.allclose(bf.forward, [0, 0, 1], atol=1e-9)          # +Z in the Hips frame
    assert np.allclose(bf.up, [1, 0, 0], atol=1e-2)               # spine along +X
    assert np.allclose(bf.left, [0, -1, 0], atol=1e-2)
    assert np.allclose(bf.matrix.T @ bf.matrix, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(bf.matrix), 1.0)


def test_body_frame_of_smpl_faces_plus_z():
    bf = body_frame(smpl_like())
    assert bf.joints == ("left_hip", "right_hip", "head")
    assert np.degrees(np.arccos(bf.forward @ [0, 0, 1])) < 10
    assert np.degrees(np.arccos(bf.left @ [1, 0, 0])) < 10
    assert np.allclose(body_forward(smpl_like()), bf.forward)


def test_body_frame_overrides_and_errors():
    sk = Skeleton(("root", "a", "b", "c"), (-1, 0, 0, 0),
                  np.array([[0, 0, 0], [0.1, -0.1, 0], [-0.1, -0.1, 0], [0, 0.3, 0]]))
    with pytest.raises(ValueError, match="left_hip="):
        body_frame(sk)
    bf = body_frame(sk, left_hip="a", right_hip="b", up_joint="c")
    assert np.allclose(bf.forward, [0, 0, 1]) and bf.pelvis == 0
    with pytest.raises(ValueError, match="no joint"):
        body_frame(sk, left_hip="zz", right_hip="b", up_joint="c")
    # hips found by name that start at one point (CMU's lhipjoint / rhipjoint) are named
    cmu = Skeleton(("root", "lhipjoint", "lfemur", "rhipjoint", "rfemur", "head"),
                   (-1, 0, 1, 0, 3, 0), np.array([[0, 0, 0], [0, 0, 0], [0.1, -0.1, 0],
                                                  [0, 0, 0], [-0.1, -0.1, 0], [0, 0.5, 0]]))
    with pytest.raises(ValueError, match="the hips found, 'lhipjoint' and 'rhipjoint', are at "
                                         "one point"):
        body_frame(cmu)
    assert body_frame(cmu, left_hip="lfemur", right_hip="rfemur").joints[:2] == ("lfemur",
                                                                                   "rfemur")
    upright = Skeleton(("root", "a", "b", "c"), (-1, 0, 0, 0),
                       np.array([[0, 0, 0], [0, 0.1, 0], [0, -0.1, 0], [0, 0.3, 0]]))
    with pytest.raises(ValueError, match=r"the hip line \('a' to 'b'\) is parallel"):
        body_frame(upright, left_hip="a", right_hip="b", up_joint="c")


@pytest.mark.parametrize("make", SKELETONS)
def test_lateral_heading_is_the_vertical_first_euler_yaw(make):
    m = random_motion(make(), dtype=torch.float64)
    Rb = body_rotmats(m)
    yaw = matrix_to_euler(Rb, "YZX", intrinsic=True)[..., 0]
    h = motion_heading(m, axis="lateral")
    assert torch.equal(body_heading(m.skeleton, m.rotmats(), axis="lateral"), h)
    assert torch.allclose(torch.remainder(h - yaw + math.pi, 2 * math.pi) - math.pi,
                          torch.zeros_like(h), atol=1e-9)


def test_heading_shifts_with_world_yaw_and_matches_atan2():
    g = torch_generator(5, "heading")
    R = random_rotmats((50,), g, dtype=torch.float64)
    f = np.array([0.0, 0.0, 1.0])
    h = heading_angle(R, f)
    v = R[..., :, 2]
    assert torch.allclose(h, torch.atan2(v[:, 0], v[:, 2]))
    d = torch.full((50,), 0.7, dtype=torch.float64)
    h2 = heading_angle(yaw_matrix(d) @ R, f)
    wrap = torch.remainder(h2 - h - 0.7 + math.pi, 2 * math.pi) - math.pi
    assert torch.allclose(wrap, torch.zeros_like(wrap), atol=1e-9)
    # Ry(θ) maps +Z to (sin θ, 0, cos θ)
    p = rotate_about_y(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), torch.tensor(0.3, dtype=torch.float64))
    assert torch.allclose(p, torch.tensor([math.sin(0.3), 0.0, math.cos(0.3)], dtype=torch.float64))


def test_positions_heading_agrees_with_rotation_heading_when_upright():
    sk = smpl_like()
    T = 6
    theta = torch.linspace(-3.0, 3.0, T, dtype=torch.float64)
    R = torch.eye(3, dtype=torch.float64).expand(1, T, sk.n_joints, 3, 3).clone()
    R[0, :, 0] = yaw_matrix(theta)
    m = Motion.from_rotmats(torch.zeros(1, T, 3, dtype=torch.float64), R, sk, 30)
    hp = positions_heading(m.joints(), sk.index("left_hip"), sk.index("right_hip"))
    hl = motion_heading(m, axis="lateral")
    def wrap(x):
        return torch.remainder(x + math.pi, 2 * math.pi) - math.pi

    off = wrap(hp - hl)  # constant: hip line vs body frame (both the hip line, up to rounding)
    assert torch.allclose(off, off[0, :1].expand_as(off), atol=1e-9)
    rest = wrap(hl[0] - theta)  # constant: the SMPL rest pose's own small yaw
    assert torch.allclose(rest, rest[:1].expand_as(rest), atol=1e-9) and abs(rest[0]) < 0.2


# --- canonicalisations ---------------------------------------------------------------------
@pytest.mark.parametrize("make", SKELETONS)
@pytest.mark.parametrize("canon", [face_front, marionette_normalize, zero_canon, root_to_origin])
def test_uncanonicalize_inverts_exactly(make, canon):
    m = random_motion(make())
    c, params = canon(m)
    assert_same_motion(uncanonicalize(c, params), m)
    # FK commutes with the rigid map
    assert torch.allclose(c.joints(), params.apply_points(m.joints()), atol=ATOL)
    assert torch.allclose(params.invert_points(c.joints()), m.joints(), atol=ATOL)
    # and canonicalize_with re-applies the same map
    assert_same_motion(canonicalize_with(m, params), c)


@pytest.mark.parametrize("make", SKELETONS)
def test_face_front_zeroes_anchor_yaw_and_keeps_pitch_roll(make):
    m = random_motion(make(), dtype=torch.float64)
    anchor = torch.tensor([0, 3, 8, -1])
    c, params = face_front(m, anchor)
    B = torch.arange(4)
    a = anchor % m.n_frames
    assert torch.equal(params.anchor, a)
    h = motion_heading(c, axis="lateral")[B, a]
    assert torch.allclose(h, torch.zeros(4, dtype=torch.float64), atol=1e-9)
    assert torch.allclose(c.root[B, a], torch.zeros(4, 3, dtype=torch.float64), atol=1e-12)
    # the angle between the body's up axis and the floor is unchanged (every frame)
    assert torch.allclose(up_floor_angle(c), up_floor_angle(m), atol=1e-9)
    # pitch and roll of the anchor (vertical-first Euler) are kept, yaw -> 0
    e0 = matrix_to_euler(body_rotmats(m)[B, a], "YZX")
    e1 = matrix_to_euler(body_rotmats(c)[B, a], "YZX")
    assert torch.allclose(e1[:, 0], torch.zeros(4, dtype=torch.float64), atol=1e-9)
    assert torch.allclose(e1[:, 1:], e0[:, 1:], atol=1e-9)
    # non-root local rotations untouched
    assert torch.equal(c.rot6d[:, :, 1:], m.rot6d[:, :, 1:])


def test_face_front_forward_axis_and_upright_agreement():
    sk = bandai_like()
    m = random_motion(sk, dtype=torch.float64)
    c, _ = face_front(m, heading_axis="forward")
    assert torch.allclose(motion_heading(c, axis="forward")[:, -1], torch.zeros(4, dtype=torch.float64), atol=1e-9)
    # for an upright body (yaw only) both axes give the same canonical motion
    T = m.n_frames
    R = torch.eye(3, dtype=torch.float64).expand(2, T, sk.n_joints, 3, 3).clone()
    stand = torch.as_tensor(body_frame(sk).matrix).T  # rest -> upright facing +Z
    R[:, :, 0] = yaw_matrix(torch.linspace(-2, 2, 2 * T, dtype=torch.float64).reshape(2, T)) @ stand
    up = Motion.from_rotmats(m.root[:2], R, sk, 30)
    a, _ = face_front(up, heading_axis="lateral")
    b, _ = face_front(up, heading_axis="forward")
    assert_same_motion(a, b, atol=1e-9)


def test_face_front_of_raw_6d_round_trips_and_is_differentiable():
    sk = smpl_like()
    g = torch_generator(9, "raw6d")
    raw = torch.randn(2, 5, sk.n_joints, 6, generator=g, requires_grad=True)
    m = Motion(torch.randn(2, 5, 3, generator=g), raw, sk, 20)
    c, p = face_front(m, 2)
    back = uncanonicalize(c, p)
    assert torch.allclose(back.rot6d, raw, atol=ATOL)  # raw, non-orthonormal 6D comes back
    c.joints().square().sum().backward()
    assert raw.grad is not None and torch.isfinite(raw.grad).all()


def test_marionette_translation_modes():
    m = random_motion(bandai_like(), dtype=torch.float64)
    c, p = marionette_normalize(m)                        # anchor P_-1, D = full xyz
    assert torch.allclose(c.root[:, -1], torch.zeros(4, 3, dtype=torch.float64), atol=1e-12)
    assert torch.allclose(motion_heading(c)[:, -1], torch.zeros(4, dtype=torch.float64), atol=1e-9)
    assert p.settings == {"heading_axis": "forward", "translation": "xyz",
                          "body_joints": ["UpperLeg_L", "UpperLeg_R", "Head"]}
    cz, pz = marionette_normalize(m, translation="xz")
    assert torch.allclose(cz.root[..., 1], m.root[..., 1], atol=1e-12)   # height kept
    assert torch.allclose(cz.root[:, -1, [0, 2]], torch.zeros(4, 2, dtype=torch.float64), atol=1e-12)
    assert_same_motion(uncanonicalize(cz, pz), m, atol=1e-9)
    with pytest.raises(ValueError, match="translation"):
        marionette_normalize(m, translation="xy")


@pytest.mark.parametrize("make", SKELETONS)
def test_zero_canon_removes_the_whole_rotation(make):
    m = random_motion(make(), dtype=torch.float64)
    bf = body_frame(m.skeleton)
    c, _ = zero_canon(m, 4)
    G = chain_global_rotmat(c.skeleton, c.rotmats()[:, 4], bf.pelvis)
    assert torch.allclose(G, torch.eye(3, dtype=torch.float64).expand(4, 3, 3), atol=1e-9)
    cu, _ = zero_canon(m, 4, target="upright")
    assert torch.allclose(body_rotmats(cu)[:, 4], torch.eye(3, dtype=torch.float64).expand(4, 3, 3), atol=1e-9)
    # unlike face-front, zero-canon changes the body's angle to the floor in general
    assert not torch.allclose(up_floor_angle(cu)[:, 4], up_floor_angle(m)[:, 4], atol=1e-3)


def test_canonical_frame_shared_by_a_continuation():
    m = random_motion(smpl_like(), T=12)
    prev, cont = m.slice_time(0, 6), m.slice_time(6, None)
    c_prev, p = face_front(prev)                      # anchor = last previous frame
    c_all, _ = face_front(m, 5)
    assert_same_motion(Motion.cat_time([c_prev, canonicalize_with(cont, p)]), c_all)


def test_root_to_origin_positions_like_odmo():
    m = random_motion(smpl_like())
    c, p = root_to_origin(m)
    assert torch.allclose(c.root[:, 0], torch.zeros(4, 3), atol=1e-6)
    assert torch.equal(c.rot6d, m.rot6d)
    J = m.joints()
    pos, pp = positions_root_to_origin(J)
    expected = J - J[:, :1, :1, :]                   # every joint minus frame-0 root
    assert torch.allclose(pos, expected, atol=1e-6)
    assert torch.allclose(pp.invert_points(pos), J, atol=1e-6)
    assert torch.allclose(c.joints(), pos, atol=1e-5)


def test_anchor_errors():
    m = random_motion(smpl_like())
    with pytest.raises(ValueError, match="out of range"):
        face_front(m, 9)
    with pytest.raises(ValueError, match="one per batch"):
        face_front(m, [1, 2])
    with pytest.raises(ValueError, match="heading_axis"):
        face_front(m, heading_axis="up")


def test_params_record_is_plain_json():
    import json

    _, p = face_front(random_motion(smpl_like(), B=1))
    rec = p.to_record()
    assert json.loads(json.dumps(rec))["kind"] == "face_front"


# --- Motion <-> ClipSet ----------------------------------------------------------------------
def make_clipset(sk: Skeleton, lengths=(7, 12, 5), seed=0) -> ClipSet:
    g = torch_generator(seed, "clipset")
    F = int(sum(lengths))
    R = random_rotmats((F, sk.n_joints), g, dtype=torch.float64)
    from repro.motion.rotations import matrix_to_quat

    q = matrix_to_quat(R).numpy().astype(np.float32)
    root = torch.randn(F, 3, generator=g, dtype=torch.float64).numpy().astype(np.float32)
    joints = forward_kinematics(sk, R.numpy(), root.astype(np.float64)).astype(np.float32)
    n = len(lengths)
    return ClipSet(name="synthetic", skeleton=sk, fps=30.0, rotations=q, root=root, joints=joints,
                   starts=np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64),
                   lengths=np.asarray(lengths, np.int64), labels=np.arange(n, dtype=np.int64) % 2,
                   label_names=("a", "b"), styles=np.full(n, -1, np.int64), style_names=(),
                   clip_names=tuple(f"clip{i}" for i in range(n)), split=np.zeros(n, np.int8),
                   fingerprint="synthetic")


def test_motion_from_clipset_and_back():
    sk = smpl_like()
    cs = make_clipset(sk)
    m = Motion.from_clipset(cs, [0, 1], start=[1, 4], length=5)
    assert m.root.shape == (2, 5, 3) and m.rot6d.shape == (2, 5, sk.n_joints, 6) and m.fps == 30.0
    assert m.dtype == torch.float32
    assert np.allclose(m.joints()[1].numpy(), cs.clip_joints(1)[4:9], atol=1e-5)
    assert np.allclose(m.root[0].numpy(), cs.clip_root(0)[1:6])
    back = m.to_clipset("back", labels=[0, 1], label_names=("a", "b"), lengths=[5, 3])
    assert back.lengths.tolist() == [5, 3] and back.n_frames == 8
    q0, q1 = back.clip_rotations(1), cs.clip_rotations(1)[4:7]
    assert np.allclose(np.abs((q0 * q1).sum(-1)), 1.0, atol=1e-5)  # same rotations (±q)
    assert np.allclose(back.clip_joints(0), cs.clip_joints(0)[1:6], atol=1e-5)
    assert back.fingerprint == m.to_clipset("x", [0, 1], ("a", "b"), lengths=[5, 3]).fingerprint


def test_motion_from_clipset_padding_and_errors():
    cs = make_clipset(smpl_like())
    with pytest.raises(ValueError, match="run past"):
        Motion.from_clipset(cs, [2], 0, 8)
    m = Motion.from_clipset(cs, [2], 0, 8, pad=True)
    assert torch.equal(m.root[0, 5:], m.root[0, 4:5].expand(3, 3))
    with pytest.raises(ValueError, match="remaining length"):
        Motion.from_clipset(cs, [0, 1])
    assert Motion.from_clipset(cs, [1]).n_frames == 12
    with pytest.raises(ValueError, match="outside"):
        Motion.from_clipset(cs, [0], start=7, length=1)


def test_motion_validation_and_slicing():
    sk = smpl_like()
    with pytest.raises(ValueError, match="rot6d"):
        Motion(torch.zeros(1, 4, 3), torch.zeros(1, 4, 3, 6), sk, 30)
    with pytest.raises(ValueError, match="fps"):
        Motion(torch.zeros(1, 4, 3), torch.zeros(1, 4, sk.n_joints, 6), sk, 0)
    m = random_motion(sk, T=10)
    s = m.slice_time(2, 10, 2)
    assert s.n_frames == 4 and s.fps == 15.0 and torch.equal(s.root, m.root[:, 2:10:2])
    assert m.select(1).batch_size == 1 and Motion.cat_batch([m, m]).batch_size == 8
    assert math.isclose(m.duration, 9 / 30)


# --- real data: heading on the stand-in ------------------------------------------------------
_WANT = {
    "walk": re.compile(r"dataset-2_walk_normal_00[12]\.bvh$"),
    "wave": re.compile(r"dataset-2_wave-both-hands_normal_001\.bvh$"),
    "raise": re.compile(r"dataset-2_raise-up-left-hand_normal_001\.bvh$"),
    "turn_left": re.compile(r"dataset-2_walk-turn-left_normal_001\.bvh$"),
    "turn_right": re.compile(r"dataset-2_walk-turn-right_normal_001\.bvh$"),
}
_COUNT = {"walk": 2}


def _parse_bvh(text: str) -> Motion:
    """Minimal stand-in BVH reader for this test only (SOURCE.md: 6 channels per joint, ZXY
    intrinsic Euler degrees, cm, dummy ``joint_Root`` dropped so ``Hips`` is the root)."""
    lines = text.splitlines()
    names, parents, offsets, stack, pending, i = [], [], [], [], None, 0
    while not lines[i].strip().startswith("MOTION"):
        tok = lines[i].split()
        if tok and tok[0] in ("ROOT", "JOINT"):
            names.append(tok[1])
            parents.append(stack[-1] if stack else -1)
            pending = len(names) - 1
        elif tok and tok[0] == "End":
            pending = None
        elif tok and tok[0] == "{":
            stack.append(pending)
        elif tok and tok[0] == "}":
            stack.pop()
        elif tok and tok[0] == "OFFSET" and pending is not None and len(offsets) < len(names):
            offsets.append([float(v) for v in tok[1:4]])
        i += 1
    n, frame_time = int(lines[i + 1].split()[1]), float(lines[i + 2].split()[2])
    data = np.array(" ".join(lines[i + 3:i + 3 + n]).split(), dtype=np.float64)
    data = data.reshape(n, len(names), 6)
    assert names[0] == "joint_Root" and not data[:, 0].any()
    sk = Skeleton(tuple(names[1:]), tuple(max(p - 1, -1) for p in parents[1:]),
                  np.array(offsets[1:]) / 100.0)
    R = euler_to_matrix(data[:, 1:, 3:], "ZXY", intrinsic=True, degrees=True)
    root = data[:, 1, :3] / 100.0
    return Motion.from_rotmats(torch.from_numpy(root)[None], torch.from_numpy(R)[None], sk,
                               1.0 / frame_time)


@pytest.fixture(scope="module")
def stand_in_clips(bandai_archive):
    found: dict[str, list[Motion]] = {k: [] for k in _WANT}
    with tarfile.open(bandai_archive, "r:xz") as tar:
        for member in tar:
            for key, pat in _WANT.items():
                if pat.search(member.name) and len(found[key]) < _COUNT.get(key, 1):
                    found[key].append(_parse_bvh(tar.extractfile(member).read().decode()))
            if all(len(found[k]) >= _COUNT.get(k, 1) for k in _WANT):
                break
    return found


def _wrap_deg(x):
    return np.degrees(np.abs(np.angle(np.exp(1j * np.asarray(x)))))


@pytest.mark.data
def test_stand_in_heading_follows_walking_direction(stand_in_clips):
    for m in stand_in_clips["walk"] + stand_in_clips["turn_left"] + stand_in_clips["turn_right"]:
        h = motion_heading(m)[0].numpy()
        root = m.root[0].numpy()
        k = 15  # ±0.5 s
        v = root[2 * k:, [0, 2]] - root[:-2 * k, [0, 2]]
        moving = np.linalg.norm(v, axis=1) / (2 * k / m.fps) > 0.5
        diff = _wrap_deg(h[k:-k] - np.arctan2(v[:, 0], v[:, 1]))[moving]
        assert moving.sum() > 30
        assert np.median(diff) < 15 and np.percentile(diff, 90) < 30


@pytest.mark.data
def test_stand_in_headings_per_class(stand_in_clips):
    for m in stand_in_clips["wave"] + stand_in_clips["raise"]:          # face +Z
        assert np.median(_wrap_deg(motion_heading(m)[0].numpy())) < 15
    h_left = motion_heading(stand_in_clips["turn_left"][0])[0, 0].item()   # starts facing +X
    h_right = motion_heading(stand_in_clips["turn_right"][0])[0, 0].item()  # starts facing +Z
    assert _wrap_deg(h_left - math.pi / 2) < 20 and _wrap_deg(h_right) < 20


@pytest.mark.data
def test_stand_in_face_front_round_trip_and_axes_agree(stand_in_clips):
    m = stand_in_clips["turn_left"][0].to(dtype=torch.float32)
    c, p = face_front(m, 50)
    assert abs(motion_heading(c, axis="lateral")[0, 50].item()) < 1e-5
    assert torch.allclose(uncanonicalize(c, p).joints(), m.joints(), atol=1e-4)
    # upright mocap: the forward and lateral headings agree to a few degrees
    for clips in stand_in_clips.values():
        for mm in clips:
            d = _wrap_deg((motion_heading(mm) - motion_heading(mm, axis="lateral"))[0].numpy())
            assert d.max() < 5
