"""CMU MoCap as Action2Motion preprocessed it (and ODMO reused it, minus the Wash class).

Upstream layout (``[A2M] dataProcessing/dataset.py`` MotionFolderDatasetMocap,
``[ODMO] src/param/param_mocap.py``)::

    <root>/mocap_3djoints/<motion>.npy   float (T, 20, 3) joints, e.g. 90_15.npy (subject_trial)
    <root>/pose_clip_7class.csv          ODMO: columns motion, action_type (7 classes)
    <root>/pose_clip.csv                 Action2Motion: the same columns, 8 classes (with Wash)

Classes: ODMO's order (``"odmo7"``, default: Walk, Run, Jump, Animal Behavior, Dance, Step,
Climb; 970 clips, ODMO Table S5) or Action2Motion's (``"a2m8"``: Walk, Wash, Run, Jump, Animal
Behavior, Dance, Step, Climb).  A row whose class is not in the chosen set is an error unless
``drop_unknown=True`` (e.g. reading A2M's ``pose_clip.csv`` with the 7 ODMO classes drops
Wash).  There is no test split (all ``TRAIN``).

Conversions (written down because the files do not say):

- **Scale.** Both references divide the stored coordinates by **20** (``scale = 1/20``), and
  ODMO's classifier was trained on that scale, so it is the default.  If the files are in CMU
  ASF units (1 unit = 1/0.45 inch), exact metres would be ``x 0.0254/0.45 = 0.0564``; the /20
  scale is then 0.886 of true metres.  ``scale`` is a parameter and enters the fingerprint.
- **Axes.** Y up (A2M's raw offsets point the spine to +y and the legs to -y): ``up="+y"``.
- **Frame rate.** Not recorded by A2M; :data:`CMU_A2M_FPS` = 120 (CMU's capture rate) is an
  assumption that only matters for rendering (ODMO's protocol counts frames: T = 100).
- **Joints.** 20, not the 21 of ODMO's text (``[ODMO]`` reshapes to 20 x 3).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from repro.errors import DataError, MissingDataError

from ._files import load_joint_npy, read_csv_rows
from .axes import UpAxis, to_y_up
from .fingerprint import tree_fingerprint
from .joint_fit import build_clipset, check_upright
from .skeletons import CMU_20

CMU_A2M_FPS = 120.0
CMU_A2M_SCALE = 1.0 / 20.0
JOINT_DIR = "mocap_3djoints"
CLASS_SETS = {
    "odmo7": ("Walk", "Run", "Jump", "Animal Behavior", "Dance", "Step", "Climb"),
    "a2m8": ("Walk", "Wash", "Run", "Jump", "Animal Behavior", "Dance", "Step", "Climb"),
}
CSV_FOR_CLASSES = {"odmo7": "pose_clip_7class.csv", "a2m8": "pose_clip.csv"}


@dataclass(frozen=True, eq=False)
class CMUMocapData:
    """CMU clips as stored (source units and axes), with labels in the chosen class order."""

    joints: tuple[np.ndarray, ...] = field(repr=False)   # (T, 20, 3) source units
    labels: np.ndarray = field(repr=False)
    class_names: tuple[str, ...]
    clip_names: tuple[str, ...] = field(repr=False)
    csv_name: str
    source: str
    fingerprint: str

    def __len__(self) -> int:
        return len(self.joints)


def resolve_clip_list(root: str | Path, classes: str = "odmo7",
                      csv_name: str | None = None) -> tuple[str, bool]:
    """(clip-list file name, drop rows of other classes?) for ``classes`` (see the reader)."""
    root = Path(root)
    if csv_name is not None:
        return csv_name, False
    csv_name = CSV_FOR_CLASSES[classes]
    if (not (root / csv_name).is_file() and classes == "odmo7"
            and (root / "pose_clip.csv").is_file()):
        return "pose_clip.csv", True
    return csv_name, False


def listed_files(root: str | Path, classes: str = "odmo7") -> list[str]:
    """Relative paths the reader consumes for ``classes``: the clip list + its clips' ``.npy``."""
    root = Path(root)
    csv_name, _ = resolve_clip_list(root, classes)
    names = {n.lower() for n in CLASS_SETS[classes]}
    rows = read_csv_rows(root / csv_name)
    return [csv_name] + [f"{JOINT_DIR}/{m}.npy" for _, m, a in rows if a.lower() in names]


def read_cmu_mocap(root: str | Path, classes: Literal["odmo7", "a2m8"] = "odmo7",
                   csv_name: str | None = None, drop_unknown: bool = False) -> CMUMocapData:
    """Read the A2M/ODMO CMU MoCap folder (module docstring).

    ``csv_name`` defaults to the list that matches ``classes`` (``pose_clip_7class.csv`` for
    ``odmo7``); when that file is absent and ``classes="odmo7"``, A2M's ``pose_clip.csv`` is
    used with its Wash rows dropped.
    """
    root = Path(root)
    if classes not in CLASS_SETS:
        raise ValueError(f"unknown CMU class set {classes!r}; choose {', '.join(CLASS_SETS)}")
    names = CLASS_SETS[classes]
    csv_name, dropping = resolve_clip_list(root, classes, csv_name)
    drop_unknown = drop_unknown or dropping
    path = root / csv_name
    if not path.is_file():
        raise MissingDataError(f"clip list not found (expected {csv_name} with columns motion, "
                               "action_type)", path)
    index = {n.lower(): i for i, n in enumerate(names)}
    joints, labels, clip_names, rel = [], [], [], []
    for lineno, motion, action in read_csv_rows(path):
        key = action.lower()
        if key not in index:
            if drop_unknown:
                continue
            raise DataError(f"class {action!r} is not in the {classes} set ({', '.join(names)})",
                            path, lineno)
        npy = root / JOINT_DIR / f"{motion}.npy"
        joints.append(load_joint_npy(npy, 20, path, lineno))
        labels.append(index[key])
        clip_names.append(motion)
        rel.append(f"{JOINT_DIR}/{npy.name}")
    if not joints:
        raise DataError("the clip list names no clips of the chosen classes", path)
    fp = tree_fingerprint(root, [csv_name] + rel)
    return CMUMocapData(tuple(joints), np.asarray(labels, np.int64), names, tuple(clip_names),
                        csv_name, str(root), fp)


def cmu_mocap_clipset(data: CMUMocapData, *, scale: float = CMU_A2M_SCALE, up: UpAxis = "+y",
                      fps: float = CMU_A2M_FPS, name: str = "cmu-mocap"):
    """A ClipSet of the 20 joints, scaled by ``scale`` (default A2M's 1/20), Y up, all TRAIN."""
    clips = [to_y_up(j.astype(np.float64) * scale, up) for j in data.joints]
    check_upright(clips, CMU_20, "head", "root", data.source, up)
    return build_clipset(
        name=name, joint_set=CMU_20, fps=fps, clips=clips, labels=data.labels,
        label_names=data.class_names, clip_names=data.clip_names,
        split=np.zeros(len(data), dtype=np.int8), source_fingerprint=data.fingerprint,
        options={"up": up, "scale": float(scale), "csv": data.csv_name})
