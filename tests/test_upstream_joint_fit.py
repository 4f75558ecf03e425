"""Joint positions -> skeleton + fitted rotations (repro.data.upstream.joint_fit)."""

import numpy as np
import pytest
from upstream_synth import fk_clip, skeleton_of

from repro.data.upstream.joint_fit import (_shortest_arc, build_clipset, check_upright,
                                           fit_local_rotations, fk_residual,
                                           skeleton_from_joints)
from repro.data.upstream.skeletons import CMU_20, JOINT_SETS, SMPL_24, SMPLH_52, UESTC_18
from repro.errors import DataError
from repro.motion.skeleton import forward_kinematics


@pytest.mark.parametrize("js", [SMPL_24, UESTC_18, CMU_20, SMPLH_52], ids=lambda s: s.name)
def test_fitted_rotations_reproduce_fk_joints(js):
    rng = np.random.default_rng(1)
    skel = skeleton_of(js, seed=2)
    clips = [fk_clip(skel, 25, rng, scale=0.5) for _ in range(3)]
    est = skeleton_from_joints(js, clips)
    np.testing.assert_allclose(np.linalg.norm(est.offsets, axis=1),
                               np.linalg.norm(skel.offsets, axis=1), atol=1e-9)
    P = np.concatenate(clips)
    R = fit_local_rotations(est, P)
    assert R.shape == P.shape[:2] + (3, 3)
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape),
                               atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-9)
    assert fk_residual(est, R, P) < 1e-7


def test_joint_sets_are_valid_trees():
    for js in JOINT_SETS.values():
        skel = skeleton_of(js)
        assert skel.n_joints == len(js.names) == len(js.rest_directions)
    assert SMPLH_52.names[:22] == SMPL_24.names[:22]
    assert SMPLH_52.names[22] == "left_index1" and SMPLH_52.parents[37] == 21


def test_shortest_arc_including_antiparallel():
    a = np.array([0.0, 1.0, 0.0])
    b = np.array([[0.0, 2.0, 0.0], [1.0, 0.0, 0.0], [0.0, -3.0, 0.0], [0.0, 0.0, 0.0],
                  [0.3, -0.2, 0.9]])
    R = _shortest_arc(a, b)
    for Ri, bi in zip(R, b):
        n = np.linalg.norm(bi)
        if n == 0:
            assert np.allclose(Ri, np.eye(3))
        else:
            np.testing.assert_allclose(Ri @ a, bi / n, atol=1e-12)
        np.testing.assert_allclose(np.linalg.det(Ri), 1.0, atol=1e-12)


def test_upside_down_data_is_refused():
    rng = np.random.default_rng(0)
    skel = skeleton_of(SMPL_24)
    clip = fk_clip(skel, 10, rng, scale=0.1)
    check_upright([clip], SMPL_24, "head", "pelvis", "f.pkl", "+y")
    with pytest.raises(DataError, match="f.pkl.*up-axis"):
        check_upright([clip * np.array([1, -1, -1])], SMPL_24, "head", "pelvis", "f.pkl", "+y")


def test_build_clipset_is_deterministic_and_keeps_data_joints():
    rng = np.random.default_rng(3)
    skel = skeleton_of(CMU_20)
    clips = [fk_clip(skel, t, rng) for t in (7, 12, 5)]

    def make():
        return build_clipset(name="x", joint_set=CMU_20, fps=30.0, clips=clips, labels=[0, 1, 0],
                             label_names=("a", "b"), clip_names=("c0", "c1", "c2"),
                             split=[0, 0, 1], source_fingerprint="abc", options={"k": 1})

    cs1, cs2 = make(), make()
    assert cs1.fingerprint == cs2.fingerprint
    assert cs1.rotations.tobytes() == cs2.rotations.tobytes()
    assert len(cs1) == 3 and cs1.n_frames == 24
    np.testing.assert_allclose(cs1.clip_joints(1), clips[1], atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(cs1.rotations, axis=-1), 1.0, atol=1e-6)
    # FK of the stored quaternions reproduces the stored joints
    import roma
    import torch

    R = roma.unitquat_to_rotmat(torch.from_numpy(cs1.rotations.astype(np.float64))).numpy()
    pos = forward_kinematics(cs1.skeleton, R, cs1.root.astype(np.float64))
    np.testing.assert_allclose(pos, cs1.joints, atol=1e-5)
    other = build_clipset(name="x", joint_set=CMU_20, fps=30.0, clips=clips, labels=[0, 1, 0],
                          label_names=("a", "b"), clip_names=("c0", "c1", "c2"),
                          split=[0, 0, 1], source_fingerprint="abd", options={"k": 1})
    assert other.fingerprint != cs1.fingerprint
