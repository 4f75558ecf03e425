"""AMASS motion files (``*_poses.npz``, SMPL-H "body data" as BABEL references them).

Upstream format (AMASS; read by ``[MA] data/datasets/BABEL.py``): an ``.npz`` with

- ``poses``: (T, 156) float axis-angle, radians: 52 SMPL-H joints x 3 (joint 0 = root
  orientation, 1..21 body, 22..51 hands);
- ``trans``: (T, 3) root translation, metres, **Z up** (AMASS world);
- ``mocap_framerate``: scalar, Hz (60, 100, 120, 150 or 250 across AMASS; AMASS's SMPL-X
  release spells it ``mocap_frame_rate``, accepted too);
- ``betas`` (16,) shape coefficients and ``gender`` (a string array), optional here;
  ``dmpls`` (soft-tissue coefficients) are ignored.

Joint positions need the SMPL-H body model (:mod:`repro.data.upstream.smpl`):
:func:`amass_joints` computes them by forward kinematics (``method="fk"``) or, as MultiAct's
evaluator does, by regressing them from the skinned mesh (``method="mesh"``), and returns them
in ``repro``'s Y-up frame.  MultiAct uses the male model with zero betas whatever the file says,
hence the defaults ``betas="zero"`` and (in :mod:`repro.data.upstream.babel`) gender ``male``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from repro.errors import DataError, MissingDataError

from .axes import to_y_up, to_y_up_matrix
from .smpl import BodyModel


@dataclass(frozen=True, eq=False)
class AmassMotion:
    """One AMASS sequence as stored (AMASS world: Z up, metres, radians)."""

    poses: np.ndarray = field(repr=False)     # (T, 3J) axis-angle
    trans: np.ndarray = field(repr=False)     # (T, 3)
    fps: float
    betas: np.ndarray | None = field(repr=False, default=None)
    gender: str | None = None
    source: str = ""

    @property
    def n_frames(self) -> int:
        return int(self.poses.shape[0])


def read_amass_npz(path: str | Path) -> AmassMotion:
    """Read an AMASS ``*_poses.npz`` (no pickled objects admitted); errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise MissingDataError("AMASS motion file not found", path)
    try:
        with np.load(path, allow_pickle=False) as z:
            keys = set(z.files)
            missing = [k for k in ("poses", "trans") if k not in keys]
            rate_key = ("mocap_framerate" if "mocap_framerate" in keys
                        else "mocap_frame_rate" if "mocap_frame_rate" in keys else None)
            if missing or rate_key is None:
                need = missing + ([] if rate_key else ["mocap_framerate"])
                raise DataError(f"AMASS npz lacks {', '.join(need)} "
                                f"(has {', '.join(sorted(keys))})", path)
            poses = np.asarray(z["poses"], dtype=np.float64)
            trans = np.asarray(z["trans"], dtype=np.float64)
            fps = float(np.asarray(z[rate_key]).reshape(-1)[0])
            betas = (np.asarray(z["betas"], dtype=np.float64).reshape(-1) if "betas" in keys
                     else None)
            gender = str(np.asarray(z["gender"]).reshape(-1)[0]) if "gender" in keys else None
    except DataError:
        raise
    except (ValueError, OSError, IndexError, TypeError) as e:
        raise DataError(f"not a readable AMASS npz ({type(e).__name__}: {e})", path) from None
    if poses.ndim != 2 or poses.shape[1] % 3 or poses.shape[0] == 0:
        raise DataError(f"poses must be (T, 3J) with T > 0, got {poses.shape}", path)
    if trans.shape != (poses.shape[0], 3):
        raise DataError(f"trans must be ({poses.shape[0]}, 3), got {trans.shape}", path)
    if not (np.isfinite(poses).all() and np.isfinite(trans).all()):
        raise DataError("non-finite poses or trans", path)
    if not (np.isfinite(fps) and fps > 0):
        raise DataError(f"mocap_framerate must be positive, got {fps}", path)
    if gender is not None:
        gender = gender.strip().lower()
    return AmassMotion(poses, trans, fps, betas, gender, str(path))


def _betas(motion: AmassMotion, betas: Literal["zero", "file"]):
    if betas == "zero":
        return None
    if betas == "file":
        return motion.betas
    raise ValueError(f"betas must be 'zero' or 'file', got {betas!r}")


def amass_joints(motion: AmassMotion, model: BodyModel, *, frames: np.ndarray | None = None,
                 method: Literal["fk", "mesh"] = "fk",
                 betas: Literal["zero", "file"] = "zero") -> np.ndarray:
    """Joint positions (T', J, 3), metres, **Y up**, of ``frames`` (default: all) of ``motion``."""
    if motion.poses.shape[1] != 3 * model.n_joints:
        raise DataError(f"poses have {motion.poses.shape[1] // 3} joints, the {model.kind} model "
                        f"{model.n_joints}", motion.source)
    idx = np.arange(motion.n_frames) if frames is None else np.asarray(frames, dtype=np.int64)
    pose, tr, b = motion.poses[idx], motion.trans[idx], _betas(motion, betas)
    if method == "fk":
        j = model.fk_joints(pose, b, tr)
    elif method == "mesh":
        j = model.mesh_joints(pose, b, tr)
    else:
        raise ValueError(f"method must be 'fk' or 'mesh', got {method!r}")
    return to_y_up(j, "+z")


def amass_local_rotations(motion: AmassMotion, frames: np.ndarray | None = None) -> np.ndarray:
    """Local rotation matrices (T', J, 3, 3) in ``repro``'s Y-up frame.

    Only the root's rotation changes frame (left-multiplied by the Z-up -> Y-up rotation); every
    other joint's rotation is relative to its parent and is frame-independent.
    """
    import roma
    import torch

    idx = np.arange(motion.n_frames) if frames is None else np.asarray(frames, dtype=np.int64)
    aa = motion.poses[idx].reshape(len(idx), -1, 3)
    R = roma.rotvec_to_rotmat(torch.from_numpy(aa)).numpy()
    R[:, 0] = to_y_up_matrix("+z") @ R[:, 0]
    return R
