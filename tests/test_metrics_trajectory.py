"""Δ_Traj, Δ_JPE, dist_e, Δ_pose, Δ_vel and the qualification ratios on hand-made joints."""

import numpy as np
import pytest

from repro.errors import DataError
from repro.metrics.qualification import qualification_counts, qualification_curves, qualification_ratios
from repro.metrics.trajectory import endpoint_error, joint_position_error, trajectory_error
from repro.metrics.transitions import pose_gap, velocity_gap


def test_trajectory_error_plane_and_3d():
    target = np.zeros((2, 10, 3))
    pred = target + np.array([3.0, 5.0, 4.0])  # x 3, y 5, z 4
    assert trajectory_error(pred, target) == pytest.approx(5.0)
    assert trajectory_error(pred, target[..., [0, 2]]) == pytest.approx(5.0)  # (x, z) targets
    assert trajectory_error(pred, target, plane="xyz") == pytest.approx(np.sqrt(50.0))
    mask = np.zeros((2, 10), bool)
    mask[:, :3] = True
    pred2 = pred.copy()
    pred2[:, 3:] += 100.0  # padded frames must not count
    assert trajectory_error(pred2, target, mask=mask) == pytest.approx(5.0)
    with pytest.raises(DataError):
        trajectory_error(pred, target[..., :2], plane="xyz")


def test_joint_position_error_in_cm():
    gt = np.random.default_rng(0).normal(size=(3, 8, 21, 3))
    pred = gt + np.array([0.006, 0.0, 0.008])  # 1 cm per joint
    assert joint_position_error(pred, gt) == pytest.approx(1.0)
    assert joint_position_error(pred, gt, scale=1.0) == pytest.approx(0.01)


def test_endpoint_error_squared_summed_and_per_class():
    assert endpoint_error([[0.0, 0.0, 0.0]], [[1.0, 2.0, 2.0]]) == pytest.approx(9.0)  # not /3
    gen = np.zeros((3, 3))
    tgt = np.array([[1.0, 0, 0], [np.sqrt(3.0), 0, 0], [np.sqrt(10.0), 0, 0]])  # sq 1, 3, 10
    assert endpoint_error(gen, tgt) == pytest.approx(14 / 3)
    assert endpoint_error(gen, tgt, labels=[0, 0, 1]) == pytest.approx((2.0 + 10.0) / 2)


def _walk(start, step, frames, joints=4):
    t = np.arange(frames)[:, None, None]
    return np.broadcast_to(np.asarray(start) + t * np.asarray(step), (frames, joints, 3)).copy()


def test_pose_gap_in_cm():
    prev = _walk([0, 0, 0], [0.01, 0, 0], 10)
    cur = _walk(prev[-1, 0] + np.array([0.03, 0.04, 0.0]), [0.01, 0, 0], 7)
    assert pose_gap([prev], [cur]) == pytest.approx(5.0)
    assert pose_gap(prev[None], cur[None], scale=1.0) == pytest.approx(0.05)


def test_velocity_gap_boundary_and_junction():
    prev = _walk([0, 0, 0], [0.01, 0, 0], 10)  # 1 cm/frame in x
    same = _walk(prev[-1, 0] + [0.01, 0, 0], [0.01, 0, 0], 5)
    back = _walk(prev[-1, 0], [-0.01, 0, 0], 5)
    assert velocity_gap([prev], [same]) == pytest.approx(0.0, abs=1e-9)
    assert velocity_gap([prev], [back]) == pytest.approx(2.0)
    # junction: the step across the junction is 0 for `back` (it starts at prev's last pose)
    assert velocity_gap([prev], [back], frames="junction") == pytest.approx(1.0)
    assert velocity_gap([prev], [same], frames="junction") == pytest.approx(0.0, abs=1e-9)
    per = velocity_gap([prev, prev], [same, back], reduce="none")  # variable lengths OK
    np.testing.assert_allclose(per, [0.0, 2.0], atol=1e-9)
    with pytest.raises(DataError, match="at least 2 frames"):
        velocity_gap([prev], [back[:1]])


def test_qualification_ratios_hand_made():
    correct = np.array([[1, 1, 1, 0, 0], [1, 1, 1, 1, 1]], bool)
    aqr, mqr = qualification_ratios(correct)
    assert aqr == pytest.approx(0.8) and mqr == pytest.approx(0.5)
    aqr1, mqr1 = qualification_ratios(correct, from_action=1)
    assert aqr1 == pytest.approx((0.5 + 1.0) / 2) and mqr1 == pytest.approx(0.5)
    assert qualification_counts(correct) == {"actions_correct": 8, "actions": 10,
                                             "motions_qualified": 1, "motions": 2}
    a_curve, m_curve = qualification_curves(correct)
    np.testing.assert_allclose(m_curve, [1, 1, 1, 0.5, 0.5])
    np.testing.assert_allclose(a_curve[-1], aqr)
    with pytest.raises(DataError):
        qualification_ratios(np.array([[2, 0]]))
