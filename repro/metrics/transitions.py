"""Transition smoothness at action junctions: pose gap Δ_pose and velocity gap Δ_vel.

Neural Marionette §5.2.2 "Transition Smoothness", Tables 3 and 5 (protocols.md §5):

- Δ_pose (cm): "the L2 distance of per-joint position between the end pose of the previous
  action and the start one in the current action" — here the mean over joints of
  ||J_prev[T] - J_cur[1]||, averaged over junctions.
- Δ_vel (cm/frame): "the difference of per-joint velocity between the end of the previous
  action and the start of the current action".  The frames are not given; ``frames`` picks:

  ``"boundary"`` (default, protocols.md's suggestion): each action's own boundary velocity,
      ||(J_prev[T] - J_prev[T-1]) - (J_cur[2] - J_cur[1])||;
  ``"junction"``: the previous action's last velocity against the step across the junction,
      ||(J_prev[T] - J_prev[T-1]) - (J_cur[1] - J_prev[T])||.

  Both average over joints, then over junctions.  Velocities are per frame (NM: 30 fps).

Inputs are joint positions in metres, (B, T, J, 3) arrays or sequences of (T_i, J, 3) arrays
(actions of different lengths); ``scale`` converts the result (default 100: metres -> cm).
With ``reduce="none"`` the per-junction values (B,) are returned instead of their mean.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from repro.errors import DataError
from repro.metrics.arrays import float_array


def _edge_frames(actions, name: str, end: bool, count: int) -> np.ndarray:
    """(B, count, J, 3): the last (``end``) or first ``count`` frames of every action."""
    if isinstance(actions, (list, tuple)):
        if not actions:
            raise DataError(f"{name}: no actions")
        items = [float_array(a, f"{name}[{i}]", ndim=3) for i, a in enumerate(actions)]
    else:
        arr = float_array(actions, name, ndim=(3, 4))
        items = [arr] if arr.ndim == 3 else list(arr)
    out = []
    for i, a in enumerate(items):
        if a.shape[-1] != 3:
            raise DataError(f"{name}[{i}]: expected (T, J, 3) joints, got shape {a.shape}")
        if a.shape[0] < count:
            raise DataError(f"{name}[{i}]: needs at least {count} frames, got {a.shape[0]}")
        out.append(a[-count:] if end else a[:count])
    shapes = {o.shape for o in out}
    if len(shapes) != 1:
        raise DataError(f"{name}: actions have different joint counts {sorted(shapes)}")
    return np.stack(out)


def _pair(prev, cur, count_prev: int, count_cur: int):
    p = _edge_frames(prev, "prev_joints", end=True, count=count_prev)
    c = _edge_frames(cur, "cur_joints", end=False, count=count_cur)
    if p.shape[0] != c.shape[0] or p.shape[2:] != c.shape[2:]:
        raise DataError(f"transition gap: {p.shape[0]} previous and {c.shape[0]} current actions "
                        f"with joints {p.shape[2:]} vs {c.shape[2:]}")
    return p, c


def _reduce(per_junction: np.ndarray, reduce: str):
    if reduce == "mean":
        return float(per_junction.mean())
    if reduce == "none":
        return per_junction
    raise DataError(f"reduce must be 'mean' or 'none', got {reduce!r}")


def pose_gap(prev_joints, cur_joints, scale: float = 100.0,
             reduce: Literal["mean", "none"] = "mean"):
    """Δ_pose: mean per-joint distance between the previous action's last frame and the
    current action's first frame, times ``scale`` (cm from metres)."""
    p, c = _pair(prev_joints, cur_joints, 1, 1)
    gap = np.linalg.norm(p[:, -1] - c[:, 0], axis=-1).mean(axis=-1)
    return _reduce(scale * gap, reduce)


def velocity_gap(prev_joints, cur_joints, frames: Literal["boundary", "junction"] = "boundary",
                 scale: float = 100.0, reduce: Literal["mean", "none"] = "mean"):
    """Δ_vel: mean per-joint norm of the velocity difference at the junction (cm/frame)."""
    if frames == "boundary":
        p, c = _pair(prev_joints, cur_joints, 2, 2)
        v_cur = c[:, 1] - c[:, 0]
    elif frames == "junction":
        p, c = _pair(prev_joints, cur_joints, 2, 1)
        v_cur = c[:, 0] - p[:, -1]
    else:
        raise DataError(f"velocity_gap: frames must be 'boundary' or 'junction', got {frames!r}")
    v_prev = p[:, -1] - p[:, -2]
    gap = np.linalg.norm(v_prev - v_cur, axis=-1).mean(axis=-1)
    return _reduce(scale * gap, reduce)
