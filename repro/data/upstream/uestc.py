"""UESTC (40 actions, 118 subjects, 8 views) in the two preprocessed layouts the papers use.

**ODMO layout** (what ODMO's tables were computed on; ``[ODMO] src/param/param_uestc.py``,
``src/dataloader/dataloader_samplestart_rotate2xz.py``)::

    <root>/odmo_3d/<name>.npy      float (T, 18, 3) joints per clip
    <root>/uestc_train.csv         columns motion, action_type (one row per clip)
    <root>/uestc_test.csv

``motion`` is a clip name (its extension, if any, is dropped to find the ``.npy``);
``action_type`` is a class *name* from ODMO's 40-name list (:data:`UESTC_ODMO_CLASSES`, the
order ODMO's classifier expects).  Split = the CSV a row comes from.

**ACTOR layout** (``[ACTOR] src/datasets/uestc.py``; ODMO "used the same preprocessed data")::

    <root>/vibe_cache_refined.pkl  dict: pose (list of (T, 72)), joints3d (list of (T, 49, 3)),
                                   orig_cam (list of (T, 4): sx, sy, tx, ty)
    <root>/info/names.txt          25,600 names a<action>_d<view>_p<subject>_c<side>_color.avi
    <root>/info/num_frames_min.txt one frame count per name
    <root>/info/action_classes.txt 40 class names, by action id
    <root>/globtrans_usez.pkl      optional: per-clip root trajectories (T, 3)

ACTOR's processing, reproduced: a clip has ``min(num_frames_min, len(pose))`` frames; side-
view clips (``c != 1``) of view 8 are dropped and the other side views are turned to the front
by a rotation of ``-view·π/4`` about the camera's y axis; the per-frame root trajectory
(``globtrans_usez.pkl`` or, when absent, computed from ``orig_cam`` as ACTOR does: ``(tx, ty,
tz)`` minus its first frame, with the depth of a weak-perspective camera
``tz = f / (0.5 · s · img)``, ``f = 500``, ``img = 540``; this is ACTOR's ``get_z`` in closed
form) is added to the joints; the 18 joints are VIBE's ``action2motion_joints``.  Subjects in
ACTOR's 51-subject list are ``TRAIN`` (kept only with at least ``min_train_frames`` = 45
frames, ACTOR's 3/4 of 60), all others ``TEST``.

Conversions: joints are VIBE camera coordinates (x right, **y down**, z forward), so the
default is ``up="-y"``; units metres; frame rate 30 fps (:data:`UESTC_FPS`, the Kinect v2 rate
of the UESTC recordings; the files record none).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from repro.errors import DataError, MissingDataError

from ._files import load_joint_npy, read_csv_rows, read_lines
from .axes import UpAxis, to_y_up
from .fingerprint import tree_fingerprint
from .joint_fit import build_clipset, check_upright
from .restricted_pickle import load_restricted
from .skeletons import UESTC_18, VIBE_TO_UESTC18

UESTC_FPS = 30.0
ACTOR_FILES = ("vibe_cache_refined.pkl", "info/names.txt", "info/num_frames_min.txt",
               "info/action_classes.txt")
ODMO_FILES = ("uestc_train.csv", "uestc_test.csv")
ODMO_JOINT_DIR = "odmo_3d"

#: ACTOR's training subjects (``[ACTOR] src/datasets/uestc.py``); the other 67 are test.
ACTOR_TRAIN_SUBJECTS = (
    1, 2, 6, 12, 13, 16, 21, 24, 28, 29, 30, 31, 33, 35, 39, 41, 42, 45, 47, 50, 52, 54, 55, 57,
    59, 61, 63, 64, 67, 69, 70, 71, 73, 77, 81, 84, 86, 87, 88, 90, 91, 93, 96, 99, 102, 103,
    104, 107, 108, 112, 113)

#: ODMO's class order (``[ODMO] src/param/data_params.py`` ``uestc_class_names``).
UESTC_ODMO_CLASSES = (
    "punching-and-knee-lifting", "marking-time-and-knee-lifting", "jumping-jack", "squatting",
    "forward-lunging", "left-lunging", "left-stretching", "raising-hand-and-jumping",
    "left-kicking", "rotation-clapping", "front-raising", "pulling-chest-expanders", "punching",
    "wrist-circling", "single-dumbbell-raising", "shoulder-raising", "elbow-circling",
    "dumbbell-one-arm-shoulder-pressing", "arm-circling", "dumbbell-shrugging", "pinching-back",
    "head-anticlockwise-circling", "shoulder-abduction", "deltoid-muscle-stretching",
    "straight-forward-flexion", "spinal-stretching", "dumbbell-side-bend",
    "standing-opposite-elbow-to-knee-crunch", "standing-rotation", "overhead-stretching",
    "upper-back-stretching", "knee-to-chest", "knee-circling", "alternate-knee-lifting",
    "bent-over-twist", "rope-skipping", "standing-toe-touches", "standing-gastrocnemius-calf",
    "single-leg-lateral-hopping", "high-knees-running")

_NAME_RE = re.compile(r"^a(\d+)_d(\d+)_p(\d+)_c(\d+)")
Layout = Literal["auto", "odmo", "actor"]


@dataclass(frozen=True, eq=False)
class UESTCData:
    """UESTC clips: 18 joints in source axes (VIBE camera frame), labels, split."""

    joints: tuple[np.ndarray, ...] = field(repr=False)   # (T, 18, 3) metres, source axes
    labels: np.ndarray = field(repr=False)               # (N,) int64
    class_names: tuple[str, ...]
    clip_names: tuple[str, ...] = field(repr=False)
    split: np.ndarray = field(repr=False)                # (N,) int8: 0 train, 1 test
    subjects: np.ndarray = field(repr=False)             # (N,) int64, -1 when unknown
    views: np.ndarray = field(repr=False)                # (N,) int64, -1 when unknown
    layout: str
    source: str
    fingerprint: str

    def __len__(self) -> int:
        return len(self.joints)


def _norm(name: str) -> str:
    return re.sub(r"[\s_]+", "-", name.strip().lower())


def _parse_name(name: str) -> tuple[int, int, int, int] | None:
    m = _NAME_RE.match(Path(name).name)
    return tuple(int(g) for g in m.groups()) if m else None  # type: ignore[return-value]


def detect_layout(root: str | Path) -> str | None:
    """``"odmo"`` or ``"actor"`` if that layout's index files are all present, else ``None``."""
    root = Path(root)
    if all((root / f).is_file() for f in ODMO_FILES) and (root / ODMO_JOINT_DIR).is_dir():
        return "odmo"
    if all((root / f).is_file() for f in ACTOR_FILES):
        return "actor"
    return None


def odmo_listed_files(root: str | Path) -> list[str]:
    """Relative paths of the ODMO-layout files the reader consumes (split CSVs + listed clips)."""
    root = Path(root)
    rel = list(ODMO_FILES)
    for csv_name in ODMO_FILES:
        for _, motion, _ in read_csv_rows(root / csv_name):
            rel.append(f"{ODMO_JOINT_DIR}/{motion.split('.')[0]}.npy")
    return rel


def read_uestc(root: str | Path, layout: Layout = "auto", *, min_train_frames: int = 45,
               class_order: Literal["file", "odmo"] | None = None) -> UESTCData:
    """Read UESTC from ``root`` in the ODMO or ACTOR layout (module docstring).

    ``class_order``: ``"odmo"`` (ODMO's 40-name order; the default for the ODMO layout) or
    ``"file"`` (ACTOR's action ids and ``action_classes.txt`` names; the default for the ACTOR
    layout).
    """
    root = Path(root)
    if layout == "auto":
        found = detect_layout(root)
        if found is None:
            raise MissingDataError(
                f"no UESTC data: expected {', '.join(ODMO_FILES)} and {ODMO_JOINT_DIR}/*.npy "
                f"(ODMO layout) or {', '.join(ACTOR_FILES)} (ACTOR layout)", root)
        layout = found  # type: ignore[assignment]
    if layout == "odmo":
        return _read_odmo(root, class_order or "odmo")
    if layout == "actor":
        return _read_actor(root, min_train_frames, class_order or "file")
    raise ValueError(f"unknown UESTC layout {layout!r}")


def _read_odmo(root: Path, class_order: str) -> UESTCData:
    if class_order != "odmo":
        raise ValueError("the ODMO layout names classes by ODMO's list; use class_order='odmo'")
    index = {_norm(c): i for i, c in enumerate(UESTC_ODMO_CLASSES)}
    joints, labels, names, split, subjects, views, rel = [], [], [], [], [], [], []
    for sp, csv_name in enumerate(ODMO_FILES):
        path = root / csv_name
        for lineno, motion, action in read_csv_rows(path):
            if _norm(action) not in index:
                raise DataError(f"unknown UESTC action {action!r} (not in ODMO's 40 classes)",
                                path, lineno)
            npy = root / ODMO_JOINT_DIR / (motion.split(".")[0] + ".npy")
            j = load_joint_npy(npy, 18, path, lineno)
            joints.append(j)
            labels.append(index[_norm(action)])
            names.append(motion)
            split.append(sp)
            parsed = _parse_name(motion)
            subjects.append(parsed[2] if parsed else -1)
            views.append(parsed[1] if parsed else -1)
            rel.append(f"{ODMO_JOINT_DIR}/{npy.name}")
    if not joints:
        raise DataError("the split lists name no clips", root / ODMO_FILES[0])
    fp = tree_fingerprint(root, list(ODMO_FILES) + rel)
    return UESTCData(tuple(joints), np.asarray(labels, np.int64), UESTC_ODMO_CLASSES,
                     tuple(names), np.asarray(split, np.int8), np.asarray(subjects, np.int64),
                     np.asarray(views, np.int64), "odmo", str(root), fp)


def _rot_y(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def weak_perspective_depth(scale: np.ndarray, focal: float = 500.0,
                           img_size: float = 540.0) -> np.ndarray:
    """ACTOR's ``get_z`` in closed form: depth ``f / (0.5 · |s| · img)`` of a weak-perspective
    camera with scale ``s`` (the ratio of projected to 3-D height is ``0.5 · |s| · img``)."""
    s = np.abs(np.asarray(scale, dtype=np.float64))
    return focal / (0.5 * img_size * np.where(s > 0, s, np.nan))


def _read_actor(root: Path, min_train_frames: int, class_order: str) -> UESTCData:
    """The ACTOR layout (module docstring): its index files, ``vibe_cache_refined.pkl`` and the
    root trajectories, then each clip as ACTOR processes it."""
    names, counts, classes = _actor_index(root)
    pkl, j3d, poses, globtrans, cams = _actor_vibe(root, names)
    remap, class_names = _actor_classes(root, classes, class_order)
    train_subjects = set(ACTOR_TRAIN_SUBJECTS)
    joints, labels, out_names, split, subjects, views = [], [], [], [], [], []
    for i, name in enumerate(names):
        parsed = _parse_name(name)
        if parsed is None:
            raise DataError(f"name {name!r} is not a<action>_d<view>_p<subject>_c<side>...",
                            root / "info/names.txt", i + 1)
        action, view, subject, side = parsed
        if not 0 <= action < len(classes):
            raise DataError(f"action {action} has no class name", root / "info/names.txt", i + 1)
        j = np.asarray(j3d[i], dtype=np.float64)
        if j.ndim != 3 or j.shape[1] != 49 or j.shape[2] != 3:
            raise DataError(f"clip {i}: joints3d must be (T, 49, 3), got {j.shape}", pkl)
        n = min(counts[i], j.shape[0], np.asarray(poses[i]).shape[0])
        if side != 1 and view == 8:
            continue
        gt = _actor_trajectory(i, globtrans, cams)
        if gt.shape[0] < n:
            raise DataError(f"clip {i}: root trajectory has {gt.shape[0]} frames, need {n}", pkl)
        j, gt = j[:n], gt[:n]
        if side != 1:
            R = _rot_y(-view * np.pi / 4)
            j = j @ R.T
            gt = gt @ R.T
        j = (j + gt[:, None])[:, list(VIBE_TO_UESTC18)]
        is_train = subject in train_subjects
        if is_train and n < min_train_frames:
            continue
        if n == 0 or not np.isfinite(j).all():
            raise DataError(f"clip {i} ({name}): empty or non-finite joints", pkl)
        joints.append(j.astype(np.float32))
        labels.append(remap[action])
        out_names.append(name)
        split.append(0 if is_train else 1)
        subjects.append(subject)
        views.append(view)
    rel = list(ACTOR_FILES) + (["globtrans_usez.pkl"] if globtrans is not None else [])
    fp = tree_fingerprint(root, rel)
    return UESTCData(tuple(joints), np.asarray(labels, np.int64), tuple(class_names),
                     tuple(out_names), np.asarray(split, np.int8), np.asarray(subjects, np.int64),
                     np.asarray(views, np.int64), "actor", str(root), fp)


def _actor_index(root: Path) -> tuple[list[str], list[int], tuple[str, ...]]:
    """The ACTOR layout's ``info/`` files: clip names, one integer frame count per name, and
    the class names by action id."""
    names = read_lines(root / "info/names.txt")
    counts_txt = read_lines(root / "info/num_frames_min.txt")
    classes = tuple(read_lines(root / "info/action_classes.txt"))
    if len(counts_txt) != len(names):
        raise DataError(f"{len(counts_txt)} frame counts for {len(names)} names",
                        root / "info/num_frames_min.txt")
    try:
        counts = [int(c) for c in counts_txt]
    except ValueError:
        raise DataError("frame counts must be integers", root / "info/num_frames_min.txt") from None
    return names, counts, classes


def _actor_vibe(root: Path, names: list[str]):
    """``(pkl, joints3d, pose, globtrans, orig_cam)`` of ``vibe_cache_refined.pkl`` (one clip per
    name) and the root trajectories: ``globtrans_usez.pkl`` when present (``orig_cam`` is then
    None), else the cache's ``orig_cam`` (``globtrans`` None)."""
    pkl = root / "vibe_cache_refined.pkl"
    vibe = load_restricted(pkl)
    if not isinstance(vibe, dict) or "joints3d" not in vibe:
        raise DataError("expected a dict with 'pose', 'joints3d' and 'orig_cam'", pkl)
    j3d = list(vibe["joints3d"])
    poses = list(vibe.get("pose", j3d))
    if len(j3d) != len(names):
        raise DataError(f"{len(j3d)} clips for {len(names)} names in info/names.txt", pkl)
    gpath = root / "globtrans_usez.pkl"
    globtrans = list(load_restricted(gpath)) if gpath.is_file() else None
    cams = None if globtrans is not None else vibe.get("orig_cam")
    if globtrans is None and cams is None:
        raise DataError("neither globtrans_usez.pkl nor 'orig_cam' is available for the root "
                        "trajectory", pkl)
    return pkl, j3d, poses, globtrans, cams


def _actor_classes(root: Path, classes: tuple[str, ...], class_order: str):
    """``(remap, class_names)``: the label of each action id and the class names, in ODMO's
    order (``class_order="odmo"``: every file class must be in ODMO's list) or the file's."""
    if class_order == "odmo":
        index = {_norm(c): i for i, c in enumerate(UESTC_ODMO_CLASSES)}
        unknown = [c for c in classes if _norm(c) not in index]
        if unknown:
            raise DataError(f"class names not in ODMO's list: {unknown[:5]}",
                            root / "info/action_classes.txt")
        return [index[_norm(c)] for c in classes], UESTC_ODMO_CLASSES
    if class_order == "file":
        return list(range(len(classes))), classes
    raise ValueError(f"unknown class_order {class_order!r}")


def _actor_trajectory(i: int, globtrans, cams) -> np.ndarray:
    """Clip ``i``'s root trajectory (T, 3): its ``globtrans_usez.pkl`` entry, else computed
    from ``orig_cam`` as ACTOR does (``tx, ty`` and the weak-perspective depth, minus the first
    frame)."""
    if globtrans is not None:
        return np.asarray(globtrans[i], dtype=np.float64).reshape(-1, 3)
    cam = np.asarray(cams[i], dtype=np.float64).reshape(-1, 4)
    gt = np.stack([cam[:, 2], cam[:, 3], weak_perspective_depth(cam[:, 0])], axis=1)
    return gt - gt[:1]


def uestc_clipset(data: UESTCData, *, up: UpAxis = "-y", fps: float = UESTC_FPS,
                  name: str = "uestc"):
    """A ClipSet of the 18 joints (Y up, metres) with UESTC's train/test split."""
    clips = [to_y_up(j.astype(np.float64), up) for j in data.joints]
    check_upright(clips, UESTC_18, "neck", "mid_hip", data.source, up)
    return build_clipset(
        name=name, joint_set=UESTC_18, fps=fps, clips=clips, labels=data.labels,
        label_names=data.class_names, clip_names=data.clip_names, split=data.split,
        source_fingerprint=data.fingerprint, options={"up": up, "layout": data.layout})
