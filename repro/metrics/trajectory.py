"""Trajectory-following errors: Δ_Traj, Δ_JPE (Neural Marionette) and dist_e (ODMO).

- :func:`trajectory_error` — Neural Marionette §5.1.2 "Trajectory Error (Δ_Traj)", Table 1:
  the per-frame L2 distance between the input trajectory and the generated root position,
  averaged over frames and samples.  The paper does not say whether the distance is taken on
  the ground plane or in 3-D; its supplement §1.4 defines the trajectory as F: frames -> R^2 on
  the ground, so the default is ``plane="xz"`` (Y up), with ``"xyz"`` available.  Units: those
  of the input (metres in ``repro``).
- :func:`joint_position_error` — Neural Marionette Table 2 "Δ_JPE" (not defined in the text;
  protocols.md §5): the mean per-joint L2 distance between predicted and ground-truth joint
  positions over joints, frames and samples, converted to centimetres (``scale=100`` from
  metres; Table 2's 4.58 … 9.42 read as cm).
- :func:`endpoint_error` — ODMO §4.3.2, Table 4 "dist_e" (protocols.md §3.8): the *squared*
  Euclidean distance between the target end location and the generated root at the last
  frame, summed over x, y, z (not divided by 3); averaged over pairs, or over the per-class
  means when ``labels`` are given (ODMO: mean over a class's 400 pairs, then over classes).
  Units: squared input units (ODMO: dataset units, MoCap divided by 20).

``mask`` arguments (bool, (..., T)) mark valid frames of padded batches; masked-out frames do
not count.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from repro.errors import DataError
from repro.metrics.arrays import check_classes, float_array, int_array, to_numpy

_PLANE_AXES = {"xz": (0, 2), "xyz": (0, 1, 2)}


def _masked_mean(values: np.ndarray, mask, name: str) -> float:
    if mask is None:
        if values.size == 0:
            raise DataError(f"{name}: no frames")
        return float(values.mean())
    m = to_numpy(mask).astype(bool)
    if m.shape != values.shape:
        raise DataError(f"{name}: mask shape {m.shape} does not match frames {values.shape}")
    if not m.any():
        raise DataError(f"{name}: the mask selects no frame")
    return float(values[m].mean())


def trajectory_error(pred_root, target_traj, plane: Literal["xz", "xyz"] = "xz",
                     mask=None) -> float:
    """Mean per-frame L2 between generated root (..., T, 3) and target trajectory.

    ``target_traj`` is (..., T, 3), or (..., T, 2) holding ground-plane (x, z) when
    ``plane="xz"``.  Returns input units (metres).
    """
    if plane not in _PLANE_AXES:
        raise DataError(f"trajectory_error: plane must be 'xz' or 'xyz', got {plane!r}")
    p = float_array(pred_root, "pred_root")
    t = float_array(target_traj, "target_traj")
    if p.ndim < 2 or p.shape[-1] != 3:
        raise DataError(f"pred_root: expected (..., T, 3), got shape {p.shape}")
    axes = list(_PLANE_AXES[plane])
    p = p[..., axes]
    if t.shape[-1] == 3:
        t = t[..., axes]
    elif not (t.shape[-1] == 2 and plane == "xz"):
        raise DataError(f"target_traj: expected (..., T, 3) (or (..., T, 2) for plane 'xz'), "
                        f"got shape {t.shape}")
    if p.shape != t.shape:
        raise DataError(f"trajectory_error: shapes differ ({p.shape} vs {t.shape})")
    return _masked_mean(np.linalg.norm(p - t, axis=-1), mask, "trajectory_error")


def joint_position_error(pred_joints, gt_joints, scale: float = 100.0, mask=None) -> float:
    """Mean per-joint L2 between (..., T, J, 3) joint arrays, times ``scale`` (m -> cm)."""
    p = float_array(pred_joints, "pred_joints")
    g = float_array(gt_joints, "gt_joints")
    if p.shape != g.shape or p.ndim < 3 or p.shape[-1] != 3:
        raise DataError(f"joint_position_error: expected equal (..., T, J, 3) shapes, got "
                        f"{p.shape} and {g.shape}")
    per_frame = np.linalg.norm(p - g, axis=-1).mean(axis=-1)  # mean over joints
    return scale * _masked_mean(per_frame, mask, "joint_position_error")


def endpoint_sq_errors(gen_end, target_end) -> np.ndarray:
    """(N,) squared Euclidean distances sum_xyz (target - generated)^2 of (N, 3) end points."""
    g = float_array(gen_end, "gen_end", ndim=2)
    t = float_array(target_end, "target_end", ndim=2)
    if g.shape != t.shape or g.shape[1] != 3:
        raise DataError(f"endpoint_error: expected two (N, 3) arrays, got {g.shape} and {t.shape}")
    return ((t - g) ** 2).sum(axis=1)


def endpoint_error(gen_end, target_end, labels=None, n_classes: int | None = None) -> float:
    """ODMO dist_e: mean squared end-point distance (summed over xyz); per-class mean first
    when ``labels`` are given.  ``gen_end`` is the generated root at the last frame."""
    err = endpoint_sq_errors(gen_end, target_end)
    if labels is None:
        return float(err.mean())
    y = int_array(labels, "labels", n=err.shape[0])
    if n_classes is None:
        n_classes = int(y.max()) + 1
    check_classes(y, n_classes, "labels")
    counts = np.bincount(y, minlength=n_classes)
    if (counts == 0).any():
        raise DataError(f"endpoint_error: classes {np.flatnonzero(counts == 0).tolist()} have no pairs")
    sums = np.bincount(y, weights=err, minlength=n_classes)
    return float(np.mean(sums / counts))
