"""Axis conventions of the upstream sources and their conversion to ``repro``'s Y-up frame.

``repro`` works in a right-handed frame with **Y up** (DESIGN.md).  Upstream sources differ:

- ``"+y"``: already Y up (CMU MoCap as Action2Motion exported it; HumanAct12 joints): identity.
- ``"-y"``: a camera frame, x right, **y down**, z away from the camera (VIBE's ``joints3d``,
  hence ACTOR's and ODMO's UESTC joints): a half turn about x, ``(x, y, z) -> (x, -y, -z)``.
  A person facing the camera then faces +z, with their left side at +x, as in SMPL's rest pose.
- ``"+z"``: **Z up** (AMASS world coordinates): a quarter turn about x,
  ``(x, y, z) -> (x, z, -y)``; AMASS's -y (the usual forward) becomes +z.

All three are proper rotations (determinant +1), so handedness and left/right are preserved.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

UpAxis = Literal["+y", "-y", "+z"]

_TO_Y_UP: dict[str, np.ndarray] = {
    "+y": np.eye(3),
    "-y": np.diag([1.0, -1.0, -1.0]),
    "+z": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]),
}


def to_y_up_matrix(up: UpAxis) -> np.ndarray:
    """The 3x3 rotation taking coordinates with the given ``up`` convention to Y up."""
    try:
        return _TO_Y_UP[up].copy()
    except KeyError:
        raise ValueError(f"unknown up-axis convention {up!r}; choose one of "
                         f"{', '.join(_TO_Y_UP)}") from None


def to_y_up(points: np.ndarray, up: UpAxis) -> np.ndarray:
    """Rotate points (..., 3) from the ``up`` convention into Y up (dtype preserved)."""
    pts = np.asarray(points)
    if up == "+y":
        return pts.copy()
    M = _TO_Y_UP[up] if up in _TO_Y_UP else to_y_up_matrix(up)
    return (pts @ M.T).astype(pts.dtype, copy=False)
