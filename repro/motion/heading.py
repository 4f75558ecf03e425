"""Heading (yaw about the vertical axis) from the body's own axes, not from raw Euler angles.

Why: a skeleton's rest pose need not be a T-pose facing +Z.  The Bandai-Namco-2 stand-in's BVH
rest pose lies along ±X (SOURCE.md), so the yaw of the raw root rotation is not where the
body faces.  We therefore derive a *body frame* from rest-pose geometry, in the pelvis' local
frame:

- ``left``    = rest position of the left hip minus the right hip (the hip line);
- ``up``      = rest position of the head (else neck, else spine) relative to the pelvis;
  ``left`` is then made orthogonal to ``up`` (Gram-Schmidt, ``up`` kept as is);
- ``forward`` = ``left × up``.

With Y up, a body facing +Z has ``left = +X`` (right-handed axes), as SMPL's rest pose does.

Heading of a unit axis ``a`` (in the pelvis frame) under the pelvis' global rotation ``R``:
project ``v = R·a`` onto the floor (XZ) and take the signed angle about +Y from a reference
direction: ``θ = atan2((ref × v)·ŷ, ref·v)``.  References: ``forward`` → +Z (``θ = atan2(v_x,
v_z)``), ``lateral`` (the left axis) → +X (``θ = atan2(-v_z, v_x)``).  A rotation ``Ry(-θ)``
about world +Y makes that axis point along its reference, i.e. the body faces +Z.

The two axes agree whenever the pelvis has no pitch *and* roll at once.  ``lateral`` is what an
Euler yaw with the vertical axis outermost and the body's left axis innermost computes: for
``R_body = Ry(a)·Rz(b)·Rx(c)`` (intrinsic ``"YZX"`` on body axes x=left, y=up, z=forward) the
left axis' heading is exactly ``a``.  That is MultiAct's ``face_front_align`` (ZYX Euler of the
SMPL global orient in Z-up AMASS, keeping the Z angle; SMPL's x axis is the body's left) and
Neural Marionette's "R_z of x-y-z Euler angles" read as extrinsic (= intrinsic ZYX), transposed
to our Y-up world.  ``forward`` is the "facing direction" of the Marionette text and the
project's design note.  Angles are radians; positions metres.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass

import numpy as np

from repro.motion.skeleton import Skeleton

__all__ = [
    "BodyFrame", "body_frame", "body_forward", "chain_global_rotmat", "heading_angle",
    "body_heading", "motion_heading", "yaw_matrix", "rotate_about_y", "positions_heading",
    "ancestors", "HEADING_AXES",
]

#: Axis name → reference world direction whose heading is 0 (a body facing +Z).
HEADING_AXES = {"forward": (0.0, 0.0, 1.0), "lateral": (1.0, 0.0, 0.0)}

# Name endings (lower case, non-alphanumerics removed) for SMPL, Bandai/Unity, Mixamo, CMU BVH.
_LEFT_HIP = ("upperlegl", "uplegl", "leftupleg", "leftupperleg", "lefthip", "lhip", "hipl",
             "lhipjoint", "lefthipjoint", "leftthigh", "lthigh", "thighl", "lupleg")
_RIGHT_HIP = ("upperlegr", "uplegr", "rightupleg", "rightupperleg", "righthip", "rhip", "hipr",
              "rhipjoint", "righthipjoint", "rightthigh", "rthigh", "thighr", "rupleg")
_UP_JOINTS = (("head",), ("neck", "neck1"), ("spine", "spine1", "spine01", "chest", "spine3",
                                             "lowerback", "upperback", "torso", "abdomen"))


def _norm(name: str) -> str:
    return re.sub(r"[^a-z0-9]", "", name.lower())


def _depth(skeleton: Skeleton, j: int) -> int:
    d = 0
    while skeleton.parents[j] != -1:
        j = skeleton.parents[j]
        d += 1
    return d


def ancestors(skeleton: Skeleton, j: int) -> list[int]:
    """``j`` and its ancestors up to the root, nearest first."""
    out = [j]
    while skeleton.parents[j] != -1:
        j = skeleton.parents[j]
        out.append(j)
    return out


def _find(skeleton: Skeleton, endings: tuple[str, ...], among: list[int] | None = None) -> int | None:
    cands = [j for j, n in enumerate(skeleton.names)
             if (among is None or j in among) and _norm(n).endswith(endings)]
    if not cands:
        return None
    return min(cands, key=lambda j: (_depth(skeleton, j), j))


def _rest_position(skeleton: Skeleton, joint: int, base: int) -> np.ndarray:
    """Rest position of ``joint`` relative to its ancestor ``base``, in ``base``'s frame."""
    p = np.zeros(3)
    j = joint
    while j != base:
        if j == -1:
            raise ValueError(f"joint {skeleton.names[joint]!r} is not below {skeleton.names[base]!r}")
        p = p + skeleton.offsets[j]
        j = skeleton.parents[j]
    return p


@dataclass(frozen=True, eq=False)
class BodyFrame:
    """Body axes in the pelvis joint's local frame (unit, orthonormal, right-handed).

    ``pelvis``: index of the joint whose global rotation orients the body; ``joints``: the
    (left hip, right hip, up joint) names the frame was derived from.
    """

    pelvis: int
    left: np.ndarray
    up: np.ndarray
    forward: np.ndarray
    joints: tuple[str, str, str]

    @property
    def matrix(self) -> np.ndarray:
        """(3, 3) with columns (left, up, forward): body coordinates → pelvis-local ones."""
        return np.stack([self.left, self.up, self.forward], axis=1)

    def axis(self, name: str) -> np.ndarray:
        if name == "forward":
            return self.forward
        if name == "lateral":
            return self.left
        raise ValueError(f"heading axis must be one of {sorted(HEADING_AXES)}, got {name!r}")


@functools.lru_cache(maxsize=64)
def _body_frame_cached(skeleton: Skeleton, left_hip, right_hip, up_joint) -> BodyFrame:
    def named(n):
        try:
            return skeleton.index(n)
        except KeyError:
            raise ValueError(f"body frame: skeleton has no joint {n!r}") from None

    L = named(left_hip) if left_hip else _find(skeleton, _LEFT_HIP)
    R = named(right_hip) if right_hip else _find(skeleton, _RIGHT_HIP)
    if L is None or R is None:
        raise ValueError("body frame: cannot find the left/right hip joints by name in "
                         f"{list(skeleton.names)}; pass left_hip= and right_hip=")
    anc_l, anc_r = ancestors(skeleton, L), set(ancestors(skeleton, R))
    pelvis = next(j for j in anc_l if j in anc_r)
    if pelvis in (L, R):
        raise ValueError("body frame: one hip joint is an ancestor of the other")
    if up_joint:
        U = named(up_joint)
    else:
        legs = {j for j in range(skeleton.n_joints)
                if {L, R} & set(ancestors(skeleton, j)) or j in (L, R)}
        below = [j for j in range(skeleton.n_joints)
                 if j != pelvis and pelvis in ancestors(skeleton, j) and j not in legs]
        U = None
        for endings in _UP_JOINTS:
            U = _find(skeleton, endings, below)
            if U is not None:
                break
        if U is None:
            raise ValueError("body frame: cannot find a head/neck/spine joint below the pelvis "
                             f"{skeleton.names[pelvis]!r}; pass up_joint=")
    left = _rest_position(skeleton, L, pelvis) - _rest_position(skeleton, R, pelvis)
    tiny = 1e-6 * max(1.0, np.linalg.norm(skeleton.offsets[L]))
    if np.linalg.norm(left) < tiny:  # CMU's lhipjoint / rhipjoint: both start at the root
        raise ValueError(f"body frame: the hips found, {skeleton.names[L]!r} and "
                         f"{skeleton.names[R]!r}, are at one point")
    up = _rest_position(skeleton, U, pelvis)
    nu = np.linalg.norm(up)
    if nu < 1e-9:
        raise ValueError(f"body frame: up joint {skeleton.names[U]!r} sits on the pelvis")
    up = up / nu
    left = left - (left @ up) * up
    nl = np.linalg.norm(left)
    if nl < tiny:
        raise ValueError(f"body frame: the hip line ({skeleton.names[L]!r} to "
                         f"{skeleton.names[R]!r}) is parallel to the up direction")
    left = left / nl
    forward = np.cross(left, up)
    for a in (left, up, forward):
        a.setflags(write=False)
    return BodyFrame(pelvis, left, up, forward,
                     (skeleton.names[L], skeleton.names[R], skeleton.names[U]))


def body_frame(skeleton: Skeleton, *, left_hip: str | None = None, right_hip: str | None = None,
               up_joint: str | None = None) -> BodyFrame:
    """The body frame of ``skeleton`` from its rest geometry (module docstring).

    Joints are found by name (``UpperLeg_L``/``UpperLeg_R``/``Head`` for the stand-in,
    ``left_hip``/``right_hip``/``head`` for SMPL, ``LeftUpLeg``... for Mixamo/CMU); the
    keyword arguments name them explicitly, else the skeleton's own ``hips`` / ``up_joint``
    when it names them (a data-set spec's ``[skeleton]``).  The pelvis is the hips' nearest
    common ancestor.
    """
    if skeleton.hips is not None:
        left_hip = left_hip or skeleton.hips[0]
        right_hip = right_hip or skeleton.hips[1]
    return _body_frame_cached(skeleton, left_hip, right_hip, up_joint or skeleton.up_joint)


def body_forward(skeleton: Skeleton, **names) -> np.ndarray:
    """The body's forward vector (3,) in the pelvis' local frame (see :func:`body_frame`)."""
    return body_frame(skeleton, **names).forward


def chain_global_rotmat(skeleton: Skeleton, rotmats: torch.Tensor, joint: int) -> torch.Tensor:
    """Global rotation (..., 3, 3) of one ``joint`` from local rotations (..., J, 3, 3)."""
    chain = ancestors(skeleton, joint)[::-1]
    G = rotmats[..., chain[0], :, :]
    for j in chain[1:]:
        G = G @ rotmats[..., j, :, :]
    return G


def heading_angle(rotmats: torch.Tensor, axis, reference=HEADING_AXES["forward"]) -> torch.Tensor:
    """Signed angle (radians, (-π, π]) about world +Y from ``reference`` to the floor
    projection of ``rotmats · axis``.

    ``rotmats``: (..., 3, 3) global rotation of the joint whose local frame ``axis`` (3,) is
    given in; ``reference``: a horizontal world direction (default +Z).  Differentiable except
    where the projection vanishes (axis vertical), where the angle is undefined (atan2(0, 0) = 0).
    """
    import torch

    R = torch.as_tensor(rotmats)
    a = torch.as_tensor(np.array(axis, dtype=np.float64), dtype=R.dtype, device=R.device)
    v = R @ a
    ref = torch.as_tensor(np.array(reference, dtype=np.float64), dtype=R.dtype, device=R.device)
    cross_y = ref[2] * v[..., 0] - ref[0] * v[..., 2]
    dot = ref[0] * v[..., 0] + ref[2] * v[..., 2]
    return torch.atan2(cross_y, dot)


def body_heading(skeleton: Skeleton, rotmats: torch.Tensor, *, axis: str = "forward",
                 body: BodyFrame | None = None) -> torch.Tensor:
    """Heading (...,) of the body from local rotations (..., J, 3, 3); 0 = facing +Z."""
    import torch

    body = body or body_frame(skeleton)
    G = chain_global_rotmat(skeleton, torch.as_tensor(rotmats), body.pelvis)
    return heading_angle(G, body.axis(axis), HEADING_AXES[axis])


def motion_heading(motion, *, axis: str = "forward", body: BodyFrame | None = None) -> torch.Tensor:
    """Per-frame heading (B, T) of a :class:`~repro.motion.motion.Motion`."""
    return body_heading(motion.skeleton, motion.rotmats(), axis=axis, body=body)


def yaw_matrix(angle) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) about world +Y by ``angle`` (radians; (...,) tensor)."""
    import torch

    a = torch.as_tensor(angle)
    if not a.is_floating_point():
        a = a.to(torch.get_default_dtype())
    ey = torch.zeros(a.shape + (3,), dtype=a.dtype, device=a.device)
    ey[..., 1] = 1.0
    import roma  # on first use: it imports torch._dynamo (rotations._roma)

    return roma.rotvec_to_rotmat(ey * a[..., None])


def rotate_about_y(points, angle) -> torch.Tensor:
    """Rotate points (..., 3) about world +Y by ``angle`` (broadcastable to ``points[..., 0]``)."""
    import torch

    p = torch.as_tensor(points)
    R = yaw_matrix(torch.as_tensor(angle, dtype=p.dtype, device=p.device))
    return torch.einsum("...ij,...j->...i", R, p)


def positions_heading(joints, left: int, right: int) -> torch.Tensor:
    """Heading (...,) from joint positions (..., J, 3) alone: the hip line ``p[left] -
    p[right]`` measured against +X (the ``lateral`` convention).  For xyz-only motions (ODMO,
    Action2Motion) and evaluators that remove heading."""
    import torch

    p = torch.as_tensor(joints)
    v = p[..., left, :] - p[..., right, :]
    return torch.atan2(-v[..., 2], v[..., 0])
