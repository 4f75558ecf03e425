"""HumanAct12 as ACTOR distributes it: ``humanact12poses.pkl``.

Upstream layout (``[ACTOR] src/datasets/humanact12poses.py``): a pickled dict with

- ``poses``: a list (one entry per clip) of float arrays (T, 72): SMPL axis-angle, 24 joints x 3,
  radians (joint 0 = global orientation);
- ``joints3D``: a list of float arrays (T, 24, 3): the 24 SMPL joints, metres;
- ``y``: a list of ints 0..11, the coarse action (A01..A12 minus one).

1,191 clips in the release (ODMO Table S6).  Class names and order are ODMO's
(``[ODMO] src/param/data_params.py`` ``humanact12_class_names``), the A01..A12 order that the
released Action2Motion classifier expects.  HumanAct12 has no test split (all clips are
``TRAIN``; ODMO holds out validation clips itself).

Conversions (written down because the file does not say):

- **Axes.** ``joints3D`` are taken as **Y up** (``up="+y"``): Action2Motion's HumanAct12 rest
  offsets point the spine to +y and the legs to -y.  The reader refuses data whose head is below
  its pelvis in most frames after conversion, so a wrong assumption fails loudly.
- **Units.** metres (SMPL units); no scaling.
- **Frame rate.** The file records none; :data:`HUMANACT12_FPS` = 20 is an assumption that only
  affects rendering and time-based resampling (every HumanAct12 protocol here counts frames).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from repro.errors import DataError

from .axes import UpAxis, to_y_up
from .fingerprint import tree_fingerprint
from .joint_fit import build_clipset, check_upright
from .restricted_pickle import load_restricted
from .skeletons import SMPL_24

HUMANACT12_FILE = "humanact12poses.pkl"
HUMANACT12_CLASSES = ("Warm up", "Walk", "Run", "Jump", "Drink", "Lift dumbbell", "Sit", "Eat",
                      "Turn steering wheel", "Phone", "Boxing", "Throw")
HUMANACT12_FPS = 20.0


@dataclass(frozen=True, eq=False)
class HumanAct12Data:
    """The clips of ``humanact12poses.pkl`` as stored (source axes), one entry per clip."""

    poses: tuple[np.ndarray, ...] = field(repr=False)     # (T, 72) axis-angle, radians
    joints: tuple[np.ndarray, ...] = field(repr=False)    # (T, 24, 3) metres, source axes
    labels: np.ndarray = field(repr=False)                # (N,) int64 in 0..11
    class_names: tuple[str, ...]
    source: str
    fingerprint: str

    def __len__(self) -> int:
        return len(self.joints)


def _as_list(data: dict, key: str, path: Path) -> list:
    if key not in data:
        raise DataError(f"missing key {key!r} (expected poses, joints3D, y)", path)
    v = data[key]
    if isinstance(v, (list, tuple)) or (isinstance(v, np.ndarray) and v.ndim >= 1):
        return list(v)
    got = f"a 0-d {v.dtype} array" if isinstance(v, np.ndarray) else type(v).__name__
    raise DataError(f"key {key!r} must be a list of per-clip arrays, got {got}", path)


def _quote(x) -> str:
    """A short description of an untrusted value for an error line (never a full repr: a
    pickled list graph can print forever)."""
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, int) and not isinstance(x, bool) and x.bit_length() > 128:
        return f"an integer of {x.bit_length()} bits"  # (repr refuses over 4,300 digits)
    if isinstance(x, (str, bytes, int, float)):
        r = repr(x)
        return r if len(r) <= 40 else r[:40] + "..."
    return f"a {type(x).__name__}"


def _numeric_clip(x, i: int, key: str, path: Path) -> np.ndarray:
    """Clip ``i`` of ``key`` as a numeric array (issue 16: a string or an object array was a
    TypeError traceback, a nested list could make numpy walk a shared list graph)."""
    if not isinstance(x, np.ndarray):
        raise DataError(f"clip {i}: {key} must be a numeric array, got {_quote(x)}", path)
    if x.dtype.kind not in "iuf":
        raise DataError(f"clip {i}: {key} must be a numeric array, got dtype {x.dtype} "
                        f"({'objects' if x.dtype.kind == 'O' else x.dtype.kind})", path)
    return x


def _label(y, i: int, path: Path) -> int:
    """An integer class label: a Python/numpy integer, or a float with an integral value.
    Anything else (3.7, '3', True, a list) is refused (issue 16: 3.7 used to become 3)."""
    if isinstance(y, np.ndarray) and y.size == 1 and y.dtype.kind in "iuf":
        y = y.reshape(()).item()
    if isinstance(y, (bool, np.bool_)):
        raise DataError(f"clip {i}: label {_quote(y)} is not an integer", path)
    if isinstance(y, (int, np.integer)):
        return int(y)
    if isinstance(y, (float, np.floating)) and np.isfinite(y) and float(y).is_integer():
        return int(y)
    raise DataError(f"clip {i}: label {_quote(y)} is not an integer", path)


def read_humanact12(path: str | Path) -> HumanAct12Data:
    """Read ACTOR's ``humanact12poses.pkl`` (restricted unpickler); validate every clip.

    Each clip's ``poses``/``joints3D`` must be a numeric array and each label an integer (an
    integral float such as ``3.0`` is accepted); a DataError names the file otherwise."""
    path = Path(path)
    if path.is_dir():
        path = path / HUMANACT12_FILE
    data = load_restricted(path)
    if not isinstance(data, dict):
        raise DataError(f"expected a dict with poses, joints3D, y; got {type(data).__name__}", path)
    poses = _as_list(data, "poses", path)
    joints = _as_list(data, "joints3D", path)
    ys = _as_list(data, "y", path)
    if not (len(poses) == len(joints) == len(ys)):
        raise DataError(f"poses ({len(poses)}), joints3D ({len(joints)}) and y ({len(ys)}) "
                        "differ in length", path)
    if not poses:
        raise DataError("the file holds no clips", path)
    P, Jt, labels = [], [], []
    for i, (p, j, y) in enumerate(zip(poses, joints, ys)):
        p = _numeric_clip(p, i, "poses", path)
        j = _numeric_clip(j, i, "joints3D", path)
        if p.ndim == 3 and p.shape[1:] == (24, 3):
            p = p.reshape(p.shape[0], 72)
        if p.ndim != 2 or p.shape[1] != 72:
            raise DataError(f"clip {i}: poses must be (T, 72), got {p.shape}", path)
        if j.ndim != 3 or j.shape[1:] != (24, 3):
            raise DataError(f"clip {i}: joints3D must be (T, 24, 3), got {j.shape}", path)
        if p.shape[0] != j.shape[0] or p.shape[0] == 0:
            raise DataError(f"clip {i}: poses has {p.shape[0]} frames, joints3D {j.shape[0]}",
                            path)
        with np.errstate(over="ignore", invalid="ignore"):
            p, j = p.astype(np.float32), j.astype(np.float32)  # as stored below
        if not (np.isfinite(p).all() and np.isfinite(j).all()):
            raise DataError(f"clip {i}: non-finite values (or beyond float32's range)", path)
        yi = _label(y, i, path)
        if not 0 <= yi < len(HUMANACT12_CLASSES):
            raise DataError(f"clip {i}: label {_quote(yi)} outside "
                            f"0..{len(HUMANACT12_CLASSES) - 1}", path)
        P.append(p)
        Jt.append(j)
        labels.append(yi)
    fp = tree_fingerprint(path.parent, [path.name])
    return HumanAct12Data(tuple(P), tuple(Jt), np.asarray(labels, dtype=np.int64),
                          HUMANACT12_CLASSES, str(path), fp)


def humanact12_clipset(data: HumanAct12Data, *, up: UpAxis = "+y", fps: float = HUMANACT12_FPS,
                       name: str = "humanact12"):
    """A :class:`~repro.data.clipset.ClipSet` of the 24 joints (Y up, metres), all ``TRAIN``.

    Rotations are fitted to the joints (:mod:`repro.data.upstream.joint_fit`); the file's SMPL
    ``poses`` stay available on ``data`` for methods that consume them (ACTOR).
    """
    clips = [to_y_up(j.astype(np.float64), up) for j in data.joints]
    check_upright(clips, SMPL_24, "head", "pelvis", data.source, up)
    return build_clipset(
        name=name, joint_set=SMPL_24, fps=fps, clips=clips, labels=data.labels,
        label_names=data.class_names,
        clip_names=tuple(f"humanact12_{i:04d}" for i in range(len(data))),
        split=np.zeros(len(data), dtype=np.int8), source_fingerprint=data.fingerprint,
        options={"up": up})
