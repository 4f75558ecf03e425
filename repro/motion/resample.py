"""Frame-rate conversion: slerp for rotations, linear interpolation for translation.

:func:`resample_fps` samples a motion of ``src_fps`` at times ``k / dst_fps`` seconds,
``k = 0 .. K-1`` with ``K = floor((T − 1)·dst/src) + 1`` (the output never extrapolates past the
last source frame; the first frame is kept exactly).  Between source frames ``i`` and ``i + 1``
with fraction ``w``:

- rotations: spherical linear interpolation of unit quaternions (Shoemake 1985) along the
  shortest arc, evaluated element-wise as ``q_i ⊗ exp(w · log(q_i⁻¹ ⊗ q_{i+1}))`` with roma's
  quaternion product / rotation-vector maps.  This is the same curve as
  :func:`roma.unitquat_slerp` (a test checks it); roma's function takes one step vector for the
  whole batch, whereas every output frame here has its own fraction.
- translations (and any other per-frame vector): ``(1 − w)·x_i + w·x_{i+1}``.

Neural Marionette "downsampled to 30 Hz" (Sec. 5.1.1) uses this.  MultiAct instead keeps every
``int(src_fps / 20)``-th frame (reference code ``BABEL.py``; protocols.md §4.1), so 150 Hz and
250 Hz sources end at 21.43 and 20.83 fps: that is :func:`subsample_step`, a separate function.

Arrays are time-first here (``(T, ...)``); :class:`~repro.motion.motion.Motion` versions handle
(B, T, ...).  numpy in gives numpy out.
"""

from __future__ import annotations

import math

import numpy as np
import roma
import torch

from repro.motion.motion import Motion
from repro.motion.rotations import matrix_to_6d, quat_to_matrix, sixd_to_quat

__all__ = ["frame_positions", "bracket", "slerp", "resample_quaternions",
           "resample_linear", "resample_fps", "subsample_step", "step_for", "resample_clip"]


def _check_fps(src_fps: float, dst_fps: float) -> None:
    for name, v in (("src_fps", src_fps), ("dst_fps", dst_fps)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a positive number, got {v!r}")


def frame_positions(n_frames: int, src_fps: float, dst_fps: float) -> np.ndarray:
    """Source-frame coordinates (float64) of the output frames: ``k·src/dst``."""
    _check_fps(src_fps, dst_fps)
    if n_frames < 1:
        raise ValueError("cannot resample an empty clip")
    ratio = src_fps / dst_fps
    K = int(math.floor((n_frames - 1) / ratio + 1e-9)) + 1
    return np.arange(K, dtype=np.float64) * ratio


def bracket(n_frames: int, src_fps: float, dst_fps: float):
    """The source frames either side of each output frame and the fraction between them:
    ``(i0, i1, w)`` (int64 tensors, a float64 array) for :func:`frame_positions`; the
    resamplers here and :func:`repro.data.prepare_caps.resample_clip`'s slices share them."""
    s = frame_positions(n_frames, src_fps, dst_fps)
    i0 = np.minimum(np.floor(s + 1e-9).astype(np.int64), max(n_frames - 2, 0))
    w = np.clip(s - i0, 0.0, 1.0) if n_frames > 1 else np.zeros_like(s)
    i1 = np.minimum(i0 + 1, n_frames - 1)
    return torch.from_numpy(i0), torch.from_numpy(i1), w


def slerp(q0: torch.Tensor, q1: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Element-wise shortest-arc slerp of ``xyzw`` quaternions; ``w`` broadcasts to
    ``q0.shape[:-1]`` (0 → q0, 1 → ±q1)."""
    d = roma.quat_product(roma.quat_conjugation(q0), q1)
    v = roma.unitquat_to_rotvec(d, shortest_arc=True)
    return roma.quat_product(q0, roma.rotvec_to_unitquat(v * w[..., None]))


def _as_tensor(x):
    if isinstance(x, np.ndarray):
        return torch.from_numpy(np.ascontiguousarray(x)), True
    return torch.as_tensor(x), False


def resample_quaternions(quats, src_fps: float, dst_fps: float):
    """Quaternions (T, ..., 4) ``xyzw`` at ``src_fps`` → (K, ..., 4) at ``dst_fps`` (slerp)."""
    q, was_np = _as_tensor(quats)
    q = roma.quat_normalize(q)
    if src_fps == dst_fps:
        out = q.clone()
    else:
        i0, i1, w = bracket(q.shape[0], src_fps, dst_fps)
        wt = torch.as_tensor(w, dtype=q.dtype).reshape((-1,) + (1,) * (q.dim() - 2))
        wt = wt.expand(q[i0].shape[:-1])
        out = slerp(q[i0], q[i1], wt)
    return out.numpy() if was_np else out


def resample_linear(x, src_fps: float, dst_fps: float):
    """Per-frame vectors (T, ...) at ``src_fps`` → (K, ...) at ``dst_fps`` (linear)."""
    t, was_np = _as_tensor(x)
    if src_fps == dst_fps:
        out = t.clone()
    else:
        i0, i1, w = bracket(t.shape[0], src_fps, dst_fps)
        wt = torch.as_tensor(w, dtype=t.dtype).reshape((-1,) + (1,) * (t.dim() - 1))
        out = (1 - wt) * t[i0] + wt * t[i1]
    return out.numpy() if was_np else out



def resample_clip(quats, root, src_fps: float, dst_fps: float):
    """One clip's (T, J, 4) quaternions and (T, 3) root → both at ``dst_fps``."""
    return resample_quaternions(quats, src_fps, dst_fps), resample_linear(root, src_fps, dst_fps)


def resample_fps(motion: Motion, dst_fps: float) -> Motion:
    """A :class:`Motion` at ``dst_fps`` (slerp on every joint's rotation, linear root)."""
    _check_fps(motion.fps, dst_fps)
    if dst_fps == motion.fps:
        return motion
    q = sixd_to_quat(motion.rot6d).transpose(0, 1)             # (T, B, J, 4)
    q = resample_quaternions(q, motion.fps, dst_fps).transpose(0, 1)
    root = resample_linear(motion.root.transpose(0, 1), motion.fps, dst_fps).transpose(0, 1)
    return Motion(root.contiguous(), matrix_to_6d(quat_to_matrix(q)).contiguous(),
                  motion.skeleton, float(dst_fps))


def step_for(src_fps: float, target_fps: float = 20.0) -> int:
    """MultiAct's integer step ``int(src_fps / target_fps)`` (at least 1 required)."""
    _check_fps(src_fps, target_fps)
    step = int(src_fps / target_fps)
    if step < 1:
        raise ValueError(f"cannot subsample {src_fps} fps to {target_fps} fps by an integer step")
    return step


def subsample_step(x, src_fps: float, target_fps: float = 20.0):
    """Keep every ``int(src_fps/target_fps)``-th frame (MultiAct, protocols.md §4.1).

    ``x``: a :class:`Motion` (its ``fps`` is used; ``src_fps`` may be ``None``) or a time-first
    array.  Returns ``(subsampled, effective_fps)`` with ``effective_fps = src_fps / step``,
    which is not exactly ``target_fps`` for 150 Hz or 250 Hz sources.
    """
    if isinstance(x, Motion):
        step = step_for(x.fps, target_fps)
        return x.slice_time(step=step), x.fps / step
    step = step_for(src_fps, target_fps)
    return x[::step], src_fps / step
