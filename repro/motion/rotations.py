"""Rotation conversions, all through :mod:`roma` (6D, matrix, Euler of any order, quaternion,
axis-angle).

Conventions (DESIGN.md): rotation matrices act on column vectors; ``world = parent · local``.
Angles are radians unless ``degrees=True``.

- **Matrix**: (..., 3, 3).
- **6D** (Zhou et al., CVPR 2019, "On the continuity of rotation representations"; used by all
  three papers): the first two *columns* of the matrix, laid out row-major as a 3×2 block,
  i.e. ``(R00, R01, R10, R11, R20, R21)``; shape (..., 6).  Back to a matrix with
  :func:`roma.special_gramschmidt` (normalise column 1, remove its component from column 2 and
  normalise, column 3 = cross product).  The map is equivariant: ``GS(G·M) = G·GS(M)`` for any
  rotation ``G``, which the canonicalisations use to rotate raw 6D outputs exactly.
- **Quaternion**: unit quaternions in roma's ``xyzw`` order (scalar last), as stored in
  :class:`repro.data.clipset.ClipSet`; shape (..., 4).
- **Axis-angle** (rotation vector): axis × angle in radians; shape (..., 3).
- **Euler**: any of the 12 orders (``"ZXY"``, ``"xyz"``, ``"ZYZ"``, ...), intrinsic (rotations
  about the moving axes; for ``"ZXY"``: ``R = Rz(a)·Rx(b)·Ry(c)``) or extrinsic (about the fixed
  world axes; for ``"zxy"`` extrinsic: ``R = Ry(c)·Rx(b)·Rz(a)``).  Mapped onto roma's
  convention strings (upper case intrinsic, lower case extrinsic, the same as
  :mod:`scipy.spatial.transform`).  Angles are given in the order of the letters.

Every function accepts torch tensors (differentiable where roma is) or numpy arrays; numpy in
gives numpy out.
"""

from __future__ import annotations

import functools
from typing import Callable

import numpy as np

__all__ = [
    "matrix_to_6d", "sixd_to_matrix", "quat_to_matrix", "matrix_to_quat", "axis_angle_to_matrix",
    "matrix_to_axis_angle", "euler_to_matrix", "matrix_to_euler", "euler_convention",
    "sixd_to_quat", "quat_to_6d", "convert", "random_rotmats", "REPRESENTATIONS",
]

#: Names accepted by :func:`convert`, with the size of their trailing shape.
REPRESENTATIONS = {"matrix": (3, 3), "6d": (6,), "quat": (4,), "axis_angle": (3,), "euler": (3,)}


def _roma():
    """roma, imported on first use: importing it loads ``torch._dynamo`` (seconds), which a
    process that converts no rotation (``repro plan``, a fully cached rerun) need not pay."""
    import roma

    return roma


def _numpy_compatible(fn: Callable) -> Callable:
    """Let ``fn`` (first argument: an array) take numpy and give numpy back."""

    @functools.wraps(fn)
    def wrapper(x, *args, **kwargs):
        import torch

        if isinstance(x, np.ndarray):
            t = torch.from_numpy(np.ascontiguousarray(x))
            if not t.is_floating_point():
                t = t.to(torch.float64)
            return fn(t, *args, **kwargs).numpy()
        x = torch.as_tensor(x)
        if not x.is_floating_point():
            x = x.to(torch.get_default_dtype())
        return fn(x, *args, **kwargs)

    return wrapper


def _check_tail(x: torch.Tensor, tail: tuple[int, ...], what: str) -> None:
    if tuple(x.shape[len(x.shape) - len(tail):]) != tail or x.dim() < len(tail):
        raise ValueError(f"{what} must have shape (..., {', '.join(map(str, tail))}), "
                         f"got {tuple(x.shape)}")


@_numpy_compatible
def matrix_to_6d(R):
    """(..., 3, 3) rotation matrices → (..., 6): first two columns, row-major 3×2 layout."""
    _check_tail(R, (3, 3), "rotation matrices")
    return R[..., :, :2].reshape(R.shape[:-2] + (6,))


@_numpy_compatible
def sixd_to_matrix(d6):
    """(..., 6) → (..., 3, 3) by :func:`roma.special_gramschmidt` on the 3×2 column block.

    Any input whose two 3-vectors are not colinear gives a proper rotation (det +1); for the
    output of :func:`matrix_to_6d` it returns the original matrix (to rounding).
    """
    _check_tail(d6, (6,), "6D rotations")
    return _roma().special_gramschmidt(d6.reshape(d6.shape[:-1] + (3, 2)))


@_numpy_compatible
def quat_to_matrix(q):
    """(..., 4) quaternions, ``xyzw`` → (..., 3, 3).  Inputs are normalised first."""
    _check_tail(q, (4,), "quaternions")
    return _roma().unitquat_to_rotmat(_roma().quat_normalize(q))


@_numpy_compatible
def matrix_to_quat(R):
    """(..., 3, 3) → (..., 4) unit quaternions, ``xyzw``."""
    _check_tail(R, (3, 3), "rotation matrices")
    return _roma().rotmat_to_unitquat(R)


@_numpy_compatible
def axis_angle_to_matrix(v):
    """(..., 3) rotation vectors (axis × angle, radians) → (..., 3, 3)."""
    _check_tail(v, (3,), "rotation vectors")
    return _roma().rotvec_to_rotmat(v)


@_numpy_compatible
def matrix_to_axis_angle(R):
    """(..., 3, 3) → (..., 3) rotation vectors (angle in [0, π])."""
    _check_tail(R, (3, 3), "rotation matrices")
    return _roma().rotmat_to_rotvec(R)


@_numpy_compatible
def sixd_to_quat(d6):
    """(..., 6) → (..., 4) ``xyzw`` (via Gram-Schmidt, then roma)."""
    return _roma().rotmat_to_unitquat(sixd_to_matrix(d6))


@_numpy_compatible
def quat_to_6d(q):
    """(..., 4) ``xyzw`` → (..., 6)."""
    return matrix_to_6d(quat_to_matrix(q))


def euler_convention(order: str, intrinsic: bool = True) -> str:
    """roma's (and scipy's) convention string for an Euler ``order`` (any case) and kind.

    ``euler_convention("zxy", intrinsic=True) == "ZXY"``; extrinsic gives lower case.
    """
    if not isinstance(order, str) or len(order) != 3 or any(c not in "xyz" for c in order.lower()):
        raise ValueError(f"Euler order must be three letters from x, y, z, got {order!r}")
    o = order.lower()
    if o[0] == o[1] or o[1] == o[2]:
        raise ValueError(f"Euler order {order!r}: consecutive axes must differ")
    return o.upper() if intrinsic else o


@_numpy_compatible
def euler_to_matrix(angles, order: str, *, intrinsic: bool = True, degrees: bool = False):
    """(..., 3) Euler angles, in the order of ``order``'s letters → (..., 3, 3)."""
    _check_tail(angles, (3,), "Euler angles")
    return _roma().euler_to_rotmat(euler_convention(order, intrinsic), angles, degrees=degrees)


@_numpy_compatible
def matrix_to_euler(R, order: str, *, intrinsic: bool = True, degrees: bool = False):
    """(..., 3, 3) → (..., 3) Euler angles (roma's ranges; at gimbal lock the third is 0)."""
    _check_tail(R, (3, 3), "rotation matrices")
    return _roma().rotmat_to_euler(euler_convention(order, intrinsic), R, degrees=degrees)


def _to_matrix(x, src: str, order, intrinsic, degrees):
    if src == "matrix":
        return x
    if src == "6d":
        return sixd_to_matrix(x)
    if src == "quat":
        return quat_to_matrix(x)
    if src == "axis_angle":
        return axis_angle_to_matrix(x)
    if src == "euler":
        return euler_to_matrix(x, order, intrinsic=intrinsic, degrees=degrees)
    raise ValueError(f"unknown rotation representation {src!r}; one of {sorted(REPRESENTATIONS)}")


def convert(x, src: str, dst: str, *, order: str | None = None, intrinsic: bool = True,
            degrees: bool = False):
    """Convert between any two of ``matrix``, ``6d``, ``quat`` (xyzw), ``axis_angle``, ``euler``.

    ``order``/``intrinsic``/``degrees`` describe the Euler side (needed when ``src`` or ``dst``
    is ``"euler"``).  Goes through the rotation matrix.
    """
    for r in (src, dst):
        if r not in REPRESENTATIONS:
            raise ValueError(f"unknown rotation representation {r!r}; one of {sorted(REPRESENTATIONS)}")
        if r == "euler" and order is None:
            raise ValueError("an Euler conversion needs `order`")
    if src == dst:
        return x
    R = _to_matrix(x, src, order, intrinsic, degrees)
    if dst == "matrix":
        return R
    if dst == "6d":
        return matrix_to_6d(R)
    if dst == "quat":
        return matrix_to_quat(R)
    if dst == "axis_angle":
        return matrix_to_axis_angle(R)
    return matrix_to_euler(R, order, intrinsic=intrinsic, degrees=degrees)


def random_rotmats(shape: tuple[int, ...] | int, generator: torch.Generator,
                   dtype: torch.dtype | None = None) -> torch.Tensor:
    """Uniformly random rotation matrices (``shape + (3, 3)``) from an explicit generator
    (``dtype``: None is float32)."""
    import torch

    dtype = torch.float32 if dtype is None else dtype
    size = (shape,) if isinstance(shape, int) else tuple(shape)
    return _roma().random_rotmat(size, dtype=dtype, generator=generator)
