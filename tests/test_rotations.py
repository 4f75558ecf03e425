"""Rotation conversions (repro.motion.rotations) against scipy and round trips."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from repro.motion import rotations as rot
from repro.seeding import torch_generator

ORDERS = ["".join(p) for p in itertools.permutations("xyz")] + ["xyx", "xzx", "yxy", "yzy", "zxz", "zyz"]


@pytest.fixture(scope="module")
def R64():
    return rot.random_rotmats((64,), torch_generator(0, "rot"), dtype=torch.float64)


def test_random_rotmats_seeded_and_proper():
    a = rot.random_rotmats((5, 2), torch_generator(3, "x"))
    b = rot.random_rotmats((5, 2), torch_generator(3, "x"))
    c = rot.random_rotmats((5, 2), torch_generator(4, "x"))
    assert a.shape == (5, 2, 3, 3) and torch.equal(a, b) and not torch.equal(a, c)
    eye = torch.eye(3).expand_as(a)
    assert torch.allclose(a @ a.transpose(-1, -2), eye, atol=1e-5)
    assert torch.allclose(torch.det(a), torch.ones(5, 2), atol=1e-5)


def test_6d_layout_is_first_two_columns(R64):
    d6 = rot.matrix_to_6d(R64)
    assert d6.shape == (64, 6)
    assert torch.equal(d6.reshape(64, 3, 2), R64[:, :, :2])
    assert torch.allclose(rot.sixd_to_matrix(d6), R64, atol=1e-12)


def test_6d_gram_schmidt_of_arbitrary_input():
    g = torch_generator(1, "6d")
    x = torch.randn(100, 6, generator=g, dtype=torch.float64)
    R = rot.sixd_to_matrix(x)
    assert torch.allclose(R @ R.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(100, 3, 3), atol=1e-12)
    assert torch.allclose(torch.det(R), torch.ones(100, dtype=torch.float64), atol=1e-12)
    # first column is the normalised first input vector
    a1 = x.reshape(100, 3, 2)[:, :, 0]
    assert torch.allclose(R[:, :, 0], a1 / a1.norm(dim=-1, keepdim=True), atol=1e-12)
    # rotation equivariance, which canonicalisation relies on
    G = rot.random_rotmats((100,), g, dtype=torch.float64)
    lhs = rot.sixd_to_matrix((G @ x.reshape(100, 3, 2)).reshape(100, 6))
    assert torch.allclose(lhs, G @ R, atol=1e-12)


def test_quaternion_xyzw_matches_scipy(R64):
    q = rot.matrix_to_quat(R64)
    q_sp = Rotation.from_matrix(R64.numpy()).as_quat()  # scipy is xyzw too
    sign = np.sign((q.numpy() * q_sp).sum(-1, keepdims=True))
    assert np.allclose(q.numpy(), sign * q_sp, atol=1e-12)
    assert torch.allclose(rot.quat_to_matrix(q), R64, atol=1e-12)
    # non-unit input is normalised
    assert torch.allclose(rot.quat_to_matrix(3.0 * q), R64, atol=1e-12)


def test_axis_angle_matches_scipy(R64):
    v = rot.matrix_to_axis_angle(R64)
    assert np.allclose(v.numpy(), Rotation.from_matrix(R64.numpy()).as_rotvec(), atol=1e-10)
    assert torch.allclose(rot.axis_angle_to_matrix(v), R64, atol=1e-12)


@pytest.mark.parametrize("order", ORDERS)
@pytest.mark.parametrize("intrinsic", [True, False])
def test_euler_all_orders_against_scipy(order, intrinsic, R64):
    seq = order.upper() if intrinsic else order
    rng = np.random.default_rng(7)
    ang = rng.uniform(-np.pi, np.pi, (50, 3))
    ang[:, 1] = rng.uniform(0.2, np.pi - 0.2, 50) if order[0] == order[2] else rng.uniform(-1.3, 1.3, 50)
    R = rot.euler_to_matrix(ang, order, intrinsic=intrinsic)
    assert isinstance(R, np.ndarray)
    assert np.allclose(R, Rotation.from_euler(seq, ang).as_matrix(), atol=1e-12)
    back = rot.matrix_to_euler(R, order, intrinsic=intrinsic)
    assert np.allclose(back, Rotation.from_matrix(R).as_euler(seq), atol=1e-8)
    assert np.allclose(back, ang, atol=1e-8)
    # degrees
    Rd = rot.euler_to_matrix(np.degrees(ang), order, intrinsic=intrinsic, degrees=True)
    assert np.allclose(Rd, R, atol=1e-12)
    # arbitrary rotations round-trip through Euler
    e = rot.matrix_to_euler(R64, order, intrinsic=intrinsic)
    assert torch.allclose(rot.euler_to_matrix(e, order, intrinsic=intrinsic), R64, atol=1e-9)


def test_bvh_zxy_channels_compose_as_rz_rx_ry():
    # the stand-in's "Zrotation Xrotation Yrotation" channels: intrinsic ZXY = Rz·Rx·Ry
    a = np.radians([30.0, -20.0, 75.0])
    R = rot.euler_to_matrix(a, "ZXY", intrinsic=True)
    Rz, Rx, Ry = (Rotation.from_euler(ax, v).as_matrix() for ax, v in zip("zxy", a))
    assert np.allclose(R, Rz @ Rx @ Ry, atol=1e-12)


@pytest.mark.parametrize("src", sorted(rot.REPRESENTATIONS))
@pytest.mark.parametrize("dst", sorted(rot.REPRESENTATIONS))
def test_convert_round_trips(src, dst, R64):
    x = rot.convert(R64, "matrix", src, order="YZX")
    y = rot.convert(x, src, dst, order="YZX")
    back = rot.convert(y, dst, "matrix", order="YZX")
    assert torch.allclose(back, R64, atol=1e-9)


def test_numpy_and_torch_agree_and_grad_flows():
    g = torch_generator(2, "grad")
    x = torch.randn(4, 6, generator=g, requires_grad=True)
    R = rot.sixd_to_matrix(x)
    R.sum().backward()
    assert x.grad is not None and torch.isfinite(x.grad).all()
    assert np.allclose(rot.sixd_to_matrix(x.detach().numpy()), R.detach().numpy(), atol=1e-6)


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match="three letters"):
        rot.euler_convention("xy")
    with pytest.raises(ValueError, match="consecutive"):
        rot.euler_convention("xxy")
    with pytest.raises(ValueError, match="6D"):
        rot.sixd_to_matrix(torch.zeros(3, 5))
    with pytest.raises(ValueError, match="unknown rotation"):
        rot.convert(torch.zeros(3), "axis_angle", "rodrigues")
    with pytest.raises(ValueError, match="order"):
        rot.convert(torch.zeros(3, 3), "matrix", "euler")
    assert rot.euler_convention("zxy", intrinsic=True) == "ZXY"
    assert rot.euler_convention("ZXY", intrinsic=False) == "zxy"
