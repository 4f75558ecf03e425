"""BABEL v1.0 annotations joined with AMASS motions (MultiAct's data; Neural Marionette's source).

Upstream layout (MultiAct's ``data/BABEL/``, ``[MA] data/datasets/BABEL.py``)::

    <root>/babel_v1.0_release/train.json   (the training split)
    <root>/babel_v1.0_release/val.json     (MultiAct's "test set")
    <root>/AMASS/<feat_p>                  e.g. AMASS/CMU/CMU/141/141_05_poses.npz

Each split file is a JSON object keyed by sequence id (a string); each value holds
``babel_sid`` (int), ``feat_p`` (the AMASS path), ``dur`` (seconds), ``url`` (a render),
``seq_ann`` and ``frame_ann``.  An annotation is ``{"babel_lid", "anntr_id", "mul_act",
"labels": [...]}``; a label has ``raw_label`` (the annotator's words), ``proc_label`` (the
processed label MultiAct uses), ``act_cat`` (a list of action categories) and ``seg_id``;
frame-level labels also have ``start_t`` and ``end_t`` in **seconds**.  ``frame_ann`` is
``null`` for sequences labelled only as a whole; segments may overlap.

Seconds become frames only through :func:`repro.data.timebase.segment_frames`, at the AMASS
file's own ``mocap_framerate`` (default rounding ``"trunc"`` = MultiAct's ``int(t · fps)``,
both ends, half-open ranges).  A sequence without ``frame_ann`` gets one segment per sequence
label spanning the whole clip ``[0, T)``.  (MultiAct's loader ends such segments at ``T − 1``;
a caller reproducing that exactly subtracts one.)  Empty segments are dropped, as MultiAct does.

:func:`babel_clipset` turns segments into a single-action ClipSet: every kept segment becomes a
clip, subsampled from its first frame with MultiAct's step ``int(round(fps) / 20)``; joints
come from the SMPL-H body model (required; see :mod:`repro.data.upstream.smpl`), rotations from
the AMASS poses, all in Y-up metres; ``train`` is TRAIN and ``val`` is TEST.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Literal, Sequence

import numpy as np

from repro.data.timebase import Rounding, segment_frames, subsample_step
from repro.errors import DataError, MissingDataError

from .amass import AmassMotion, amass_joints, amass_local_rotations, read_amass_npz
from .fingerprint import file_digests, tree_fingerprint

ANNOTATION_DIR = "babel_v1.0_release"
MOTION_DIR = "AMASS"
SPLITS = ("train", "val")
TARGET_FPS = 20.0


@dataclass(frozen=True)
class BabelLabel:
    """One BABEL label (sequence-level when ``start_t``/``end_t`` are None), times in seconds."""

    raw_label: str | None
    proc_label: str | None
    act_cat: tuple[str, ...]
    seg_id: str | None
    start_t: float | None = None
    end_t: float | None = None


@dataclass(frozen=True)
class BabelSequence:
    """One annotated AMASS sequence of a BABEL split file."""

    sid: str
    babel_sid: int | None
    feat_p: str
    dur: float
    url: str | None
    seq_labels: tuple[BabelLabel, ...]
    frame_labels: tuple[BabelLabel, ...] | None
    split: str


@dataclass(frozen=True)
class FrameSegment:
    """A labelled frame range ``[start, stop)`` of a sequence at its source frame rate."""

    proc_label: str | None
    raw_label: str | None
    act_cat: tuple[str, ...]
    seg_id: str | None
    start: int
    stop: int
    level: str  # "frame" or "seq"


def _label(d, where: str, path: Path, timed: bool) -> BabelLabel:
    if not isinstance(d, dict):
        raise DataError(f"{where}: a label must be an object", path)
    cats = d.get("act_cat") or []
    if isinstance(cats, str):
        cats = [cats]
    if not isinstance(cats, list) or not all(isinstance(c, str) for c in cats):
        raise DataError(f"{where}: act_cat must be a list of strings", path)
    for k in ("raw_label", "proc_label", "seg_id"):
        if d.get(k) is not None and not isinstance(d[k], str):
            raise DataError(f"{where}: {k} must be a string", path)
    start = end = None
    if timed:
        try:
            start, end = float(d["start_t"]), float(d["end_t"])
        except KeyError as e:
            raise DataError(f"{where}: frame label lacks {e.args[0]}", path) from None
        except (TypeError, ValueError):
            raise DataError(f"{where}: start_t/end_t must be numbers of seconds", path) from None
        if not (math.isfinite(start) and math.isfinite(end)) or start < 0 or end < start:
            raise DataError(f"{where}: bad segment times start_t={start}, end_t={end}", path)
    return BabelLabel(d.get("raw_label"), d.get("proc_label"), tuple(cats), d.get("seg_id"),
                      start, end)


def _labels(ann, where: str, path: Path, timed: bool) -> tuple[BabelLabel, ...] | None:
    if ann is None:
        return None
    if not isinstance(ann, dict) or not isinstance(ann.get("labels"), list):
        raise DataError(f"{where}: expected an object with a 'labels' list", path)
    return tuple(_label(d, f"{where}.labels[{i}]", path, timed)
                 for i, d in enumerate(ann["labels"]))


def read_babel_split(path: str | Path) -> tuple[BabelSequence, ...]:
    """Parse one BABEL split file (``train.json`` / ``val.json``), sequences in file order."""
    path = Path(path)
    if not path.is_file():
        raise MissingDataError("BABEL split file not found", path)
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except json.JSONDecodeError as e:
        raise DataError(f"invalid JSON ({e.msg})", path, e.lineno) from None
    if not isinstance(data, dict):
        raise DataError("expected a JSON object keyed by sequence id", path)
    split = path.stem
    out = []
    for sid, ann in data.items():
        where = f"sequence {sid}"
        if not isinstance(ann, dict):
            raise DataError(f"{where}: expected an object", path)
        feat_p = ann.get("feat_p")
        if not isinstance(feat_p, str) or not feat_p:
            raise DataError(f"{where}: missing feat_p (the AMASS file)", path)
        try:
            dur = float(ann.get("dur"))
        except (TypeError, ValueError):
            raise DataError(f"{where}: dur must be a number of seconds", path) from None
        seq = _labels(ann.get("seq_ann"), f"{where}.seq_ann", path, timed=False) or ()
        frame = _labels(ann.get("frame_ann"), f"{where}.frame_ann", path, timed=True)
        bsid = ann.get("babel_sid")
        out.append(BabelSequence(str(sid), int(bsid) if isinstance(bsid, (int, float)) else None,
                                 feat_p, dur, ann.get("url"), seq, frame, split))
    return tuple(out)


def babel_frame_segments(seq: BabelSequence, fps: float, n_frames: int,
                         rounding: Rounding = "trunc", drop_empty: bool = True
                         ) -> list[FrameSegment]:
    """The sequence's labels as frame ranges at ``fps`` (module docstring), sorted by start."""
    segs = []
    if seq.frame_labels is not None:
        for lab in seq.frame_labels:
            a, b = segment_frames(lab.start_t, lab.end_t, fps, n_frames, rounding)
            segs.append(FrameSegment(lab.proc_label, lab.raw_label, lab.act_cat, lab.seg_id,
                                     a, b, "frame"))
    else:
        for lab in seq.seq_labels:
            segs.append(FrameSegment(lab.proc_label, lab.raw_label, lab.act_cat, lab.seg_id,
                                     0, n_frames, "seq"))
    if drop_empty:
        segs = [s for s in segs if s.stop > s.start]
    return sorted(segs, key=lambda s: (s.start, s.stop))


@dataclass(frozen=True, eq=False)
class BabelData:
    """BABEL splits with their AMASS motions located (motions are loaded on demand)."""

    root: str
    sequences: tuple[BabelSequence, ...] = field(repr=False)
    fingerprint: str

    def motion_path(self, seq: BabelSequence) -> Path:
        return Path(self.root) / MOTION_DIR / seq.feat_p

    def load_motion(self, seq: BabelSequence) -> AmassMotion:
        return read_amass_npz(self.motion_path(seq))

    def split(self, name: str) -> tuple[BabelSequence, ...]:
        return tuple(s for s in self.sequences if s.split == name)


def read_babel(root: str | Path, splits: Sequence[str] = SPLITS) -> BabelData:
    """Read BABEL split files under ``root`` and check that every referenced AMASS file exists.

    The fingerprint hashes the split files' bytes and the (path, size) of every referenced
    AMASS file (see :func:`repro.data.upstream.fingerprint.tree_fingerprint`).
    """
    root = Path(root)
    seqs: list[BabelSequence] = []
    for sp in splits:
        seqs.extend(read_babel_split(root / ANNOTATION_DIR / f"{sp}.json"))
    feats = sorted({s.feat_p for s in seqs})
    absent = [f for f in feats if not (root / MOTION_DIR / f).is_file()]
    if absent:
        raise MissingDataError(
            f"{len(absent)} of {len(feats)} AMASS files named by the BABEL annotations are "
            f"missing, e.g. {absent[0]} (put the AMASS SMPL-H 'body data' under "
            f"{root / MOTION_DIR})", root / MOTION_DIR / absent[0])
    ann_fp = tree_fingerprint(root, [f"{ANNOTATION_DIR}/{sp}.json" for sp in splits])
    mot_fp = tree_fingerprint(root / MOTION_DIR, feats, content=False)
    from repro.keys import content_key

    return BabelData(str(root), tuple(seqs), content_key({"annotations": ann_fp,
                                                          "motions": mot_fp}))


def babel_clipset(data: BabelData, model, *, labels: Iterable[str] | None = None,
                  exclude: Iterable[str] = ("transition",), target_fps: float = TARGET_FPS,
                  rounding: Rounding = "trunc", joint_method: Literal["fk", "mesh"] = "fk",
                  betas: Literal["zero", "file"] = "zero", min_frames: int = 1,
                  name: str = "babel"):
    """A single-action ClipSet of BABEL segments (module docstring); ``model``: SMPL-H.

    ``labels``: the ``proc_label`` vocabulary, in class order (default: every label that yields
    a clip, sorted); segments with other labels, or in ``exclude``, or with fewer than
    ``min_frames`` frames after subsampling, are skipped.  ``joint_method``: ``"fk"`` or
    ``"mesh"`` (MultiAct's regressed joints); ``betas``: ``"zero"`` (MultiAct) or ``"file"``.
    The skeleton is the model's zero-shape skeleton, so with ``betas="file"`` FK of the stored
    rotations differs from the stored joints by the subjects' shape.
    """
    from repro.data.clipset import ClipSet
    from repro.keys import content_key
    import roma
    import torch

    excl = set(exclude)
    wanted = None if labels is None else tuple(labels)
    rots, roots, joints, lens, labs, names, split = [], [], [], [], [], [], []
    for seq in data.sequences:
        mot = data.load_motion(seq)
        segs = babel_frame_segments(seq, mot.fps, mot.n_frames, rounding)
        step = subsample_step(mot.fps, target_fps)
        for seg in segs:
            if (seg.proc_label is None or seg.proc_label in excl
                    or (wanted is not None and seg.proc_label not in wanted)):
                continue
            frames = np.arange(seg.start, seg.stop, step)
            if len(frames) < min_frames:
                continue
            fk = amass_joints(mot, model, frames=frames, method="fk", betas=betas)
            j = fk if joint_method == "fk" else amass_joints(mot, model, frames=frames,
                                                             method=joint_method, betas=betas)
            rots.append(amass_local_rotations(mot, frames))
            roots.append(fk[:, 0])
            joints.append(j)
            lens.append(len(frames))
            labs.append(seg.proc_label)
            names.append(f"{seq.split}/{seq.sid}:{seg.seg_id or seg.start}")
            split.append(0 if seq.split == "train" else 1)
    if not lens:
        raise DataError("no BABEL segment matched the requested labels", data.root)
    vocab = wanted if wanted is not None else tuple(sorted(set(labs)))
    index = {lab: i for i, lab in enumerate(vocab)}
    R = np.concatenate(rots)
    quats = roma.rotmat_to_unitquat(torch.from_numpy(R)).numpy().astype(np.float32)
    lengths = np.asarray(lens, dtype=np.int64)
    model_fp = (file_digests([model.source])[0] if Path(model.source).is_file()
                else content_key({"J": model.J_regressor @ model.v_template}))
    fp = content_key({"source": data.fingerprint, "model": model_fp,
                      "labels": vocab, "exclude": sorted(excl), "target_fps": target_fps,
                      "rounding": rounding, "joint_method": joint_method, "betas": betas,
                      "min_frames": min_frames, "reader": "upstream-babel-v1"})
    return ClipSet(
        name=name, skeleton=model.skeleton(None), fps=float(target_fps), rotations=quats,
        root=np.concatenate(roots).astype(np.float32),
        joints=np.concatenate(joints).astype(np.float32),
        starts=np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64), lengths=lengths,
        labels=np.asarray([index[x] for x in labs], dtype=np.int64), label_names=vocab,
        styles=np.full(len(lens), -1, dtype=np.int64), style_names=(), clip_names=tuple(names),
        split=np.asarray(split, dtype=np.int8), fingerprint=fp)
