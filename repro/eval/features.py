"""The evaluators' input convention: world joint positions → per-frame flattened vectors.

Follows Action2Motion / ODMO (protocols.md §2.1, §3.1):

1. frames past a sequence's valid length are filled by repeating its last valid frame (the
   A2M/ODMO padding of short clips);
2. the window is translated so that the root joint (joint 0) of its first frame is at the
   origin; coordinates stay absolute, so the root trajectory is kept;
3. heading (bandai2 SOURCE.md: headings are fixed per class, so an evaluator for protocols
   that change heading must not key on it):

   - ``raw``: nothing more (A2M/ODMO convention);
   - ``remove``: rotate about the vertical (Y) axis so that the first frame faces +Z; the
     heading is that of the hip line (left hip − right hip lies along +X when facing +Z);
   - ``yaw_augment``: nothing at evaluation time; training windows get a uniformly random yaw
     about the first-frame root (:func:`random_yaw`);
4. each frame's J×3 coordinates are flattened to one vector (metres).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from repro.errors import ConfigError, DataError
from repro.motion.heading import body_frame, positions_heading, yaw_matrix
from repro.motion.skeleton import Skeleton


def facing_joint_indices(skeleton: Skeleton, explicit: Sequence[str] | None = None) -> tuple[int, int]:
    """Indices of the (left hip, right hip) joints whose line gives the heading.

    Found by :func:`repro.motion.heading.body_frame` (``UpperLeg_L``/``UpperLeg_R`` on the
    stand-in, SMPL, Mixamo, CMU names) unless ``explicit`` names them (settings
    ``facing_joints``).
    """
    try:
        if explicit is not None:
            frame = body_frame(skeleton, left_hip=explicit[0], right_hip=explicit[1])
        else:
            frame = body_frame(skeleton)
    except ValueError as e:
        raise ConfigError(f"heading = 'remove': {e}; set evaluator.facing_joints") from None
    return skeleton.index(frame.joints[0]), skeleton.index(frame.joints[1])


def pad_repeat_last(joints: np.ndarray, lengths: np.ndarray | None) -> np.ndarray:
    """Copy of ``joints`` (N, T, J, 3) with frames ``t ≥ lengths[n]`` set to frame ``lengths[n]-1``."""
    if lengths is None:
        return joints
    n, t = joints.shape[:2]
    lengths = np.asarray(lengths, dtype=np.int64).reshape(-1)
    if lengths.shape[0] != n:
        raise DataError(f"lengths has {lengths.shape[0]} entries for {n} sequences")
    if (lengths < 1).any() or (lengths > t).any():
        raise DataError(f"lengths must lie in 1..{t}")
    idx = np.minimum(np.arange(t)[None, :], (lengths - 1)[:, None])
    return np.take_along_axis(joints, idx[:, :, None, None], axis=1)


def facing_yaw(joints0: np.ndarray, facing: tuple[int, int]) -> np.ndarray:
    """Yaw (radians about +Y; 0 = facing +Z) of frames ``joints0`` (N, J, 3) from the hip
    line (:func:`repro.motion.heading.positions_heading`)."""
    return positions_heading(joints0, facing[0], facing[1]).numpy()


def to_model_input(
    joints: np.ndarray,
    lengths: np.ndarray | None = None,
    *,
    heading: str = "raw",
    facing: tuple[int, int] | None = None,
) -> np.ndarray:
    """(N, T, J, 3) world joints (metres) → (N, T, J·3) float32 model input (module docstring)."""
    x = np.asarray(joints, dtype=np.float64)
    if x.ndim != 4 or x.shape[-1] != 3:
        raise DataError(f"expected joints of shape (N, T, J, 3), got {tuple(x.shape)}")
    if not np.isfinite(x).all():
        raise DataError("joint positions contain NaN or infinity")
    x = pad_repeat_last(x, lengths)
    x = x - x[:, :1, :1, :]
    if heading == "remove":
        if facing is None:
            raise ConfigError("heading = 'remove' needs the facing joints")
        yaw = facing_yaw(x[:, 0], facing)
        rot = yaw_matrix(torch.as_tensor(-yaw, dtype=torch.float64)).numpy()
        x = np.einsum("nij,ntkj->ntki", rot, x)
    elif heading not in ("raw", "yaw_augment"):
        raise ConfigError(f"unknown heading mode {heading!r}")
    n, t = x.shape[:2]
    return x.reshape(n, t, -1).astype(np.float32)


def random_yaw(x, generator):
    """Rotate model inputs ``x`` (B, T, J·3) (torch, root-centred) by one uniform random yaw
    per window drawn from ``generator`` (training-time yaw augmentation)."""
    import math

    b, t, d = x.shape
    ang = torch.rand(b, generator=generator, dtype=torch.float64) * (2 * math.pi)
    rot = yaw_matrix(ang).to(x.dtype)
    pts = x.reshape(b, t, d // 3, 3)
    return torch.einsum("bij,btkj->btki", rot, pts).reshape(b, t, d)
