"""Frame-rate conversion (repro.motion.resample)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import roma
import torch

from repro.motion.motion import Motion
from repro.motion.resample import (frame_positions, resample_clip, resample_fps,
                                   resample_linear, resample_quaternions, slerp, step_for,
                                   subsample_step)
from repro.motion.rotations import matrix_to_quat, random_rotmats
from repro.motion.skeleton import Skeleton
from repro.seeding import torch_generator


def chain(J=4) -> Skeleton:
    return Skeleton(tuple(f"j{i}" for i in range(J)), tuple(range(-1, J - 1)),
                    np.tile([0.0, 0.1, 0.0], (J, 1)))


def spin(T: int, fps: float, axis=(0.3, 0.8, -0.5), speed=2.0) -> torch.Tensor:
    """(T, 4) quaternions of a constant angular velocity (rad/s) about ``axis``."""
    a = torch.tensor(axis, dtype=torch.float64)
    a = a / a.norm()
    t = torch.arange(T, dtype=torch.float64) / fps
    return roma.rotvec_to_unitquat(a * (speed * t)[:, None])


def same_rot(q0, q1, atol=1e-9):
    return torch.allclose((q0 * q1).sum(-1).abs(), torch.ones(q0.shape[:-1], dtype=q0.dtype), atol=atol)


def test_frame_positions_counts():
    assert np.allclose(frame_positions(7, 60, 30), [0, 2, 4, 6])
    assert np.allclose(frame_positions(8, 60, 30), [0, 2, 4, 6])
    assert np.allclose(frame_positions(4, 30, 20), [0, 1.5, 3])
    assert len(frame_positions(100, 120, 30)) == 25
    assert np.allclose(frame_positions(3, 30, 60), [0, 0.5, 1, 1.5, 2])
    with pytest.raises(ValueError):
        frame_positions(5, 30, 0)


def test_slerp_equals_roma_unitquat_slerp():
    g = torch_generator(0, "slerp")
    q0 = roma.random_unitquat((20,), dtype=torch.float64, generator=g)
    q1 = roma.random_unitquat((20,), dtype=torch.float64, generator=g)
    for w in (0.0, 0.25, 0.5, 0.9, 1.0):
        ref = roma.unitquat_slerp(q0, q1, torch.tensor([w], dtype=torch.float64))[0]
        assert same_rot(slerp(q0, q1, torch.full((20,), w, dtype=torch.float64)), ref)


def test_constant_angular_velocity_is_resampled_exactly():
    src = spin(61, 60.0)                              # 1 s at 60 fps
    for dst in (30.0, 24.0, 20.0, 100.0, 45.0):
        out = resample_quaternions(src, 60.0, dst)
        t = torch.as_tensor(frame_positions(61, 60.0, dst)) / 60.0
        a = torch.tensor([0.3, 0.8, -0.5], dtype=torch.float64)
        exact = roma.rotvec_to_unitquat((a / a.norm()) * (2.0 * t)[:, None])
        assert out.shape == exact.shape and same_rot(out, exact, atol=1e-12)


def test_integer_ratio_is_frame_selection_and_same_fps_identity():
    g = torch_generator(1, "sel")
    q = matrix_to_quat(random_rotmats((13, 5), g, dtype=torch.float64))
    x = torch.randn(13, 3, generator=g, dtype=torch.float64)
    assert same_rot(resample_quaternions(q, 60, 30), q[::2], atol=1e-12)
    assert torch.allclose(resample_linear(x, 60, 30), x[::2])
    assert torch.equal(resample_linear(x, 30, 30), x)
    assert same_rot(resample_quaternions(q, 30, 30), q, atol=1e-12)


def test_linear_translation_and_numpy_io():
    t = np.arange(31, dtype=np.float64) / 30.0
    root = np.stack([1.5 * t, 0.9 + 0 * t, -0.4 * t], axis=1)
    out = resample_linear(root, 30, 20)
    assert isinstance(out, np.ndarray)
    tt = frame_positions(31, 30, 20) / 30
    assert np.allclose(out, np.stack([1.5 * tt, 0.9 + 0 * tt, -0.4 * tt], 1))
    q, r = resample_clip(spin(31, 30).numpy()[:, None].repeat(3, 1), root, 30, 20)
    assert q.shape == (21, 3, 4) and r.shape == (21, 3)


def test_motion_resample_keeps_joint_paths_smooth():
    sk = chain()
    T = 31
    q = spin(T, 30.0)[:, None].expand(T, sk.n_joints, 4)
    root = torch.stack([torch.linspace(0, 1, T, dtype=torch.float64)] * 3, 1)
    m = Motion.from_quaternions(root[None], q[None], sk, 30.0)
    r = resample_fps(m, 20.0)
    assert r.fps == 20.0 and r.n_frames == 21
    # analytic target: the same constant-velocity motion sampled at 20 fps
    m20 = Motion.from_quaternions(torch.stack([torch.linspace(0, 1, 21, dtype=torch.float64)] * 3, 1)[None],
                                  spin(21, 20.0)[:, None].expand(21, sk.n_joints, 4)[None], sk, 20.0)
    assert torch.allclose(r.joints(), m20.joints(), atol=1e-9)
    assert resample_fps(m, 30.0) is m


def test_multiact_integer_step():
    assert step_for(120) == 6 and step_for(150) == 7 and step_for(250) == 12 and step_for(60) == 3
    x = np.arange(300)
    sub, fps = subsample_step(x, 150.0)
    assert np.array_equal(sub, x[::7]) and math.isclose(fps, 150 / 7)
    sk = chain()
    m = Motion(torch.zeros(1, 24, 3), torch.zeros(1, 24, sk.n_joints, 6) + torch.tensor([1., 0, 0, 1, 0, 0]), sk, 120)
    ms, f = subsample_step(m, None)
    assert ms.n_frames == 4 and ms.fps == 20.0 and f == 20.0
    with pytest.raises(ValueError, match="integer step"):
        step_for(15)
