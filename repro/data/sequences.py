"""Composed multi-action sequences: a deterministic, seeded motion graph over a prepared ClipSet.

Why.  Neural Marionette trains and tests on BABEL-MAG (Sec. 3): every action comes with real
context, the ``k`` frames of motion before it (``{P}_{-k}^{-1}``), its own tag ``A^cur``, its
duration ``T`` and the tag of the action that follows (``A^next``).  Its multi-action test
chains actions "according to the transition matrix where the number of connections between
different action categories in the training set is calculated in advance" (Sec. 5.2.1; supp.
Sec. 2.1, Fig. 1), a sparse, skewed matrix (Sec. 4.3.2).  The stand-in data (``bandai2``) holds
single actions only, so we compose sequences from its real clips like a motion graph
(DESIGN.md, "Datasets").  BABEL-MAG's sequences are real recordings; ours are compositions of
real single-action clips joined where the recorded motions agree.  Every report says so.

Rules (every threshold and length is a :class:`ComposeConfig` field; the algorithm and why it
holds the statistics the papers assume are in :mod:`repro.data.compose_walk`):

- **Split by source clip.**  Sequences of split ``s`` use only clips with ``clips.split == s``;
  every usable clip of a split is exactly one ``ROLE_ACTION`` segment of that split's
  sequences.  A sequence is ``[lead-in, action × n, lead-out]`` with ``n`` drawn uniformly in
  ``[min_actions, max_actions]`` (fewer when the walk ends early; at least 1).  Lead-ins and
  lead-outs are real clips of the same split reused (any clip other than their neighbour), so
  every action has real frames before it and a real successor tag.
- **Whole actions**: an action segment is ``min_action_frames … max_action_frames`` frames cut
  anywhere in its clip (``max_action_frames`` ≤ every scale profile's ``max_frames``).
- **Tags**: a doubly stochastic, long-tailed target matrix (each tag: ``n_frequent``
  cheapest-joining other tags frequent, every other tag, itself included, rare), realised by
  per-split quotas (training: every pair at least once).
- **Junctions**: cheapest pose + velocity match anywhere inside the clips; the next segment is
  rotated about +Y so its heading matches and shifted on the ground plane so the mean of the
  anchor joints (the feet) matches; ``blend_frames`` transition frames are the previous clip's
  own continuation carried smoothly onto the next segment's first frame (label ``-1``,
  BABEL's ``transition`` segments).
- **World placement**: each sequence starts at a seeded heading (uniform) and ground position
  (uniform in ``±world_offset_m``), as recordings start anywhere (``world_placement``).

Determinism: the same clips and config give identical arrays and the same
:attr:`SequenceSet.fingerprint` (content key of ``COMPOSE_VERSION``, the source fingerprint,
the config and the sha256 of the index arrays).
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
import math
import threading
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, model_validator

from repro.data.clipset import TEST, TRAIN, ClipSet
from repro.data.compose_walk import (ROLE_ACTION, ROLE_LEAD_IN, ROLE_LEAD_OUT, ROLE_NAMES,
                                     anchor_joints, features, quat_yaw_mul, rot_y, tag_matrix,
                                     transition_frames, walk_split)
from repro.errors import ConfigError, DataError
from repro.keys import content_key
from repro.seeding import numpy_rng

__all__ = [
    "ROLE_LEAD_IN", "ROLE_ACTION", "ROLE_LEAD_OUT", "ROLE_NAMES", "COMPOSE_VERSION",
    "CARD_SCHEMA", "ComposeConfig", "SequenceSet", "compose_sequences", "sequences_for",
    "STAND_IN_NOTE", "foot_joints",
]

#: Bumped when composition changes; enters the fingerprint.  2: issue 26 (long-tailed doubly
#: stochastic tag matrix with quotas, junctions anywhere inside clips, whole actions, the
#: previous clip's continuation as transition, sequences placed in the world).
COMPOSE_VERSION = 2
#: Version of ``card.json`` / ``sequences.npz`` written by ``repro data prepare <view>``.
#: 2: the card's ``fidelity`` object (issue 26).
CARD_SCHEMA = 2

STAND_IN_NOTE = ("stand-in: motion-graph compositions of real single-action clips joined where "
                 "their recorded motions agree; BABEL-MAG's multi-action sequences are real "
                 "recordings")


class ComposeConfig(BaseModel):
    """Every threshold and length of the composition (all enter the fingerprint).

    Units: frames at the source ClipSet's fps, metres, radians.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    seed: int = 0                     # seeds the preference samples, ties, placement and walk
    min_actions: int = 3              # ROLE_ACTION segments per sequence, drawn uniformly in
    max_actions: int = 8              #   [min_actions, max_actions]
    min_action_frames: int = 30       # an action segment's length range (cut anywhere in its
    max_action_frames: int = 60       #   clip); max <= every scale's max_frames: whole actions
    blend_frames: int = 30            # transition frames: the previous clip's continuation
                                      # carried onto the next segment (0: a hard cut); 30 at
                                      # 30 fps = 1 s (the sweep in docs/data.md)
    velocity_weight: float = 3.0      # frames: converts the velocity distance (m/frame) to metres
    foot_weight: float = 6.0          # weight of the foot joints in the junction cost
    candidates_per_step: int = 8      # random unused clips of the drawn tag compared per step
    n_frequent: int = 4               # frequent successors per tag (other tags; itself is rare)
    frequent_weights: tuple[float, ...] = (0.4, 0.25, 0.2, 0.15)  # by rank
    rare_share: float = 0.15          # transition mass shared by the rare successors
    preference_samples: int = 7       # seeded (clip a, clip b) draws per tag pair; median cost
    lead_frames: int = 60             # frames kept of a lead-in (ending at its cut) / lead-out
    world_placement: Literal["random", "origin"] = "random"  # a sequence's start heading/place
    world_offset_m: float = 2.0       # half-width of the start position's square (random)
    heading_axis: Literal["forward", "lateral"] = "forward"  # body axis of the heading
    foot_joints: tuple[str, ...] | None = None  # anchors and junction quality; None: names
                                                #   with foot/toe/ankle
    foot_contact_m: float = 0.05      # a foot is on the ground within this height (m) of its
                                      #   lowest height in its clip (junction quality only)

    @model_validator(mode="after")
    def _check(self) -> "ComposeConfig":
        for k in ("min_actions", "min_action_frames", "candidates_per_step",
                  "preference_samples", "lead_frames", "n_frequent"):
            if getattr(self, k) < 1:
                raise ValueError(f"{k} must be >= 1")
        if self.blend_frames < 0:
            raise ValueError("blend_frames must be >= 0")
        if self.max_actions < self.min_actions:
            raise ValueError("max_actions must be >= min_actions")
        if self.max_action_frames < self.min_action_frames:
            raise ValueError("max_action_frames must be >= min_action_frames")
        if len(self.frequent_weights) < self.n_frequent or not all(
                math.isfinite(w) and w > 0 for w in self.frequent_weights):
            raise ValueError("frequent_weights needs n_frequent finite weights > 0")
        if not (math.isfinite(self.rare_share) and 0 <= self.rare_share < 1):
            raise ValueError("rare_share must be in [0, 1)")
        for k in ("velocity_weight", "world_offset_m", "foot_weight"):
            if not (math.isfinite(getattr(self, k)) and getattr(self, k) >= 0):
                raise ValueError(f"{k} must be finite and >= 0")
        if not (math.isfinite(self.foot_contact_m) and self.foot_contact_m > 0):
            raise ValueError("foot_contact_m must be finite and > 0")
        return self

    @classmethod
    def resolve(cls, overrides=None) -> "ComposeConfig":
        """A config from ``None`` (defaults), a ComposeConfig or a dict of overrides
        (a ConfigError names the bad field)."""
        from repro.config_errors import resolve_config

        return resolve_config(cls, overrides, "compose config: field", type_lead="compose config")


# ============================================================================ the result
_INDEX_FIELDS = ("seq_starts", "seq_lengths", "seq_split", "seg_seq", "seg_pos", "seg_role",
                 "seg_start", "seg_length", "seg_label", "seg_clip", "seg_clip_start",
                 "seg_yaw", "seg_offset", "trans_seq", "trans_start", "trans_length",
                 "preference")


@dataclass(frozen=True, eq=False)
class SequenceSet:
    """Composed multi-action sequences over ``clips`` (module docstring).

    Frames of all sequences are packed: sequence ``s`` occupies rows ``seq_starts[s] :
    seq_starts[s] + seq_lengths[s]`` of ``rotations`` (F, J, 4) xyzw, ``root`` (F, 3) metres and
    ``joints`` (F, J, 3) (forward kinematics), in the sequence's world frame (Y up).
    ``frame_label`` (F,) is the segment's label, ``-1`` on transition frames.

    One row per segment (lead-in, actions, lead-out), in sequence order: ``seg_seq``,
    ``seg_pos`` (position in its sequence), ``seg_role``, ``seg_start`` (frame offset inside its
    sequence), ``seg_length``, ``seg_label``, ``seg_clip`` (source clip index),
    ``seg_clip_start`` (first source frame used, the cut), and the rigid transform placing the
    source clip in the sequence: ``seq_point = R_y(seg_yaw) @ clip_point + seg_offset``, root
    joint rotation ``R_y(seg_yaw) · clip root rotation``.  Transitions: ``trans_seq``,
    ``trans_start`` (offset inside the sequence), ``trans_length``.  ``preference`` (C, C): the
    recorded tag-successor preference (row = from tag).  All arrays are read-only.
    """

    clips: ClipSet = field(repr=False)
    config: ComposeConfig
    name: str
    rotations: np.ndarray = field(repr=False)
    root: np.ndarray = field(repr=False)
    joints: np.ndarray = field(repr=False)
    frame_label: np.ndarray = field(repr=False)
    seq_starts: np.ndarray = field(repr=False)
    seq_lengths: np.ndarray = field(repr=False)
    seq_split: np.ndarray = field(repr=False)
    seg_seq: np.ndarray = field(repr=False)
    seg_pos: np.ndarray = field(repr=False)
    seg_role: np.ndarray = field(repr=False)
    seg_start: np.ndarray = field(repr=False)
    seg_length: np.ndarray = field(repr=False)
    seg_label: np.ndarray = field(repr=False)
    seg_clip: np.ndarray = field(repr=False)
    seg_clip_start: np.ndarray = field(repr=False)
    seg_yaw: np.ndarray = field(repr=False)
    seg_offset: np.ndarray = field(repr=False)
    trans_seq: np.ndarray = field(repr=False)
    trans_start: np.ndarray = field(repr=False)
    trans_length: np.ndarray = field(repr=False)
    preference: np.ndarray = field(repr=False)
    fingerprint: str
    #: summaries computed from the set, kept with it (:func:`repro.data.sequence_card.card_of`,
    #: :func:`~repro.data.sequence_card.quality_of`)
    memo: dict = field(default_factory=dict, repr=False, compare=False)

    # --- basics ------------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.seq_starts.shape[0])

    @property
    def label_names(self) -> tuple[str, ...]:
        return tuple(self.clips.label_names)

    @property
    def skeleton(self):
        return self.clips.skeleton

    @property
    def fps(self) -> float:
        return float(self.clips.fps)

    @property
    def n_classes(self) -> int:
        return self.clips.n_classes

    @property
    def n_frames(self) -> int:
        return int(self.frame_label.shape[0])

    def index_arrays(self) -> dict[str, np.ndarray]:
        """The index arrays (no frames): what ``sequences.npz`` stores and the fingerprint
        hashes."""
        return {k: getattr(self, k) for k in _INDEX_FIELDS}

    # --- segments ----------------------------------------------------------------------
    def segments(self, split: int | None = None, role: int | None = ROLE_ACTION) -> np.ndarray:
        """Indices (sorted) of the segments of sequences of ``split`` with ``role``
        (``None``: any)."""
        m = np.ones(self.seg_seq.shape[0], dtype=bool)
        if split is not None:
            m &= self.seq_split[self.seg_seq] == split
        if role is not None:
            m &= self.seg_role == role
        return np.flatnonzero(m)

    def _neighbour(self, idx, step: int) -> np.ndarray:
        idx = np.asarray(idx, dtype=np.int64)
        A = self.seg_seq.shape[0]
        if idx.size and (idx.min() < 0 or idx.max() >= A):
            raise IndexError(f"segment index out of range 0..{A - 1}")
        nb = idx + step
        ok = (nb >= 0) & (nb < A)
        nbc = np.clip(nb, 0, max(A - 1, 0))
        ok &= self.seg_seq[nbc] == self.seg_seq[idx]
        return np.where(ok, self.seg_label[nbc], -1).astype(np.int64)

    def previous_label(self, a: int) -> int:
        """Label of the segment before ``a`` in its sequence, ``-1`` if none."""
        return int(self._neighbour(np.array([a]), -1)[0])

    def next_label(self, a: int) -> int:
        """Label of the segment after ``a`` in its sequence (``A^next``), ``-1`` if none."""
        return int(self._neighbour(np.array([a]), 1)[0])

    def next_labels(self, idx) -> np.ndarray:
        """Vectorised :meth:`next_label` (int64, same shape as ``idx``)."""
        idx = np.asarray(idx, dtype=np.int64)
        return self._neighbour(idx.reshape(-1), 1).reshape(idx.shape)

    def segment_rows(self, a: int) -> slice:
        """Packed frame rows of segment ``a``."""
        s = int(self.seq_starts[self.seg_seq[a]] + self.seg_start[a])
        return slice(s, s + int(self.seg_length[a]))

    def to_clip_frame(self, a: int, rotations, root) -> tuple[np.ndarray, np.ndarray]:
        """Frames (rotations (K, J, 4), root (K, 3)) in the sequence frame, mapped into the
        frame of segment ``a``'s source clip (the inverse of ``a``'s rigid transform)."""
        yaw = -float(self.seg_yaw[a])
        rot = np.array(rotations, dtype=np.float64)
        rot[:, 0] = quat_yaw_mul(np.full(rot.shape[0], yaw), rot[:, 0])
        r = np.asarray(root, dtype=np.float64) - self.seg_offset[a]
        r = rot_y(r, np.full(r.shape[0], yaw))
        return rot.astype(np.float32), r.astype(np.float32)

    def context(self, a: int, K: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``K`` composed frames immediately before segment ``a`` (transition frames and the
        previous segment's end) in the frame of ``a``'s source clip: (rotations (K, J, 4),
        root (K, 3)) float32.  Followed by the clip's frames from ``seg_clip_start[a]`` on, they
        form one continuous motion in the clip's own world frame (BABEL-MAG's previous motion
        ``{P}_{-k}^{-1}``, Neural Marionette Sec. 3).  DataError if fewer than ``K`` frames
        precede ``a`` in its sequence."""
        a, K = int(a), int(K)
        if not 0 <= a < self.seg_seq.shape[0]:
            raise IndexError(f"segment {a} out of range 0..{self.seg_seq.shape[0] - 1}")
        if K < 0:
            raise ValueError("K must be >= 0")
        if int(self.seg_start[a]) < K:
            raise DataError(f"{self.name}: segment {a} has {int(self.seg_start[a])} frames "
                            f"before it in its sequence, fewer than the {K} asked for")
        e = int(self.seq_starts[self.seg_seq[a]] + self.seg_start[a])
        return self.to_clip_frame(a, self.rotations[e - K:e], self.root[e - K:e])

    # --- statistics --------------------------------------------------------------------
    def tag_pair_counts(self, split: int | None = TRAIN) -> np.ndarray:
        """(C, C) int64 counts of consecutive segment label pairs (all roles; row = earlier
        segment) in the sequences of ``split`` (``None``: all) — supp. Fig. 1's matrix."""
        C = self.n_classes
        if self.seg_seq.shape[0] < 2:
            return np.zeros((C, C), np.int64)
        same = self.seg_seq[1:] == self.seg_seq[:-1]
        if split is not None:
            same &= self.seq_split[self.seg_seq[:-1]] == split
        a, b = self.seg_label[:-1][same], self.seg_label[1:][same]
        return np.bincount(a * C + b, minlength=C * C).reshape(C, C).astype(np.int64)


# ============================================================================ composition
def _placement(cfg: ComposeConfig, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Start heading (n,) and ground offset (n, 3) of each sequence (``world_placement``)."""
    if cfg.world_placement == "origin":
        return np.zeros(n), np.zeros((n, 3))
    rng = numpy_rng(cfg.seed, "compose", COMPOSE_VERSION, "placement")
    yaw = rng.uniform(-math.pi, math.pi, n)
    off = np.zeros((n, 3))
    off[:, [0, 2]] = rng.uniform(-cfg.world_offset_m, cfg.world_offset_m, (n, 2))
    return yaw, off


def _fit(target: np.ndarray, src: np.ndarray) -> tuple[float, np.ndarray]:
    """The rotation about +Y and ground-plane shift ``(yaw, off)`` that carry the points
    ``src`` (n, 3) closest to ``target`` (n, 3) in the ground plane (least squares; one point:
    the shift only, yaw 0)."""
    a = target[:, [0, 2]] - target[:, [0, 2]].mean(axis=0)
    b = src[:, [0, 2]] - src[:, [0, 2]].mean(axis=0)
    # rot_y(v, t): x' = cos t x + sin t z, z' = -sin t x + cos t z
    yaw = float(np.arctan2((a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]).sum(),
                           (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]).sum())) if len(src) > 1 else 0.0
    moved = rot_y(src, yaw).mean(axis=0)
    goal = target.mean(axis=0)
    return yaw, np.array([goal[0] - moved[0], 0.0, goal[2] - moved[2]])


def _layout(clips: ClipSet, ft, cfg: ComposeConfig, walks, anchors: list[int]) -> dict:
    """Segment and transition tables, with each segment's rigid transform: B's heading at its
    entry cut equals A's at ``e = i + blend_frames + 1`` and the mean ground-plane position of
    the anchor joints coincide there (:mod:`repro.data.compose_walk`)."""
    L = np.asarray(clips.lengths, np.int64)
    labels = np.asarray(clips.labels, np.int64)
    starts = np.asarray(clips.starts, np.int64)
    k = cfg.blend_frames
    seg = collections.defaultdict(list)
    trans = collections.defaultdict(list)
    seq_len, seq_split = [], []
    yaw0, off0 = _placement(cfg, len(walks))

    def points(clip: int, f: int) -> np.ndarray:
        return np.asarray(clips.joints[starts[clip] + f, anchors], np.float64)

    for s, (split, wk) in enumerate(walks):
        cursor = 0
        yaw, off = float(yaw0[s]), off0[s].copy()
        for p in range(len(wk.clips)):
            c, role = wk.clips[p], wk.roles[p]
            if role == ROLE_LEAD_IN:
                end = wk.exit[p]
                start = max(0, end - cfg.lead_frames + 1)
            elif role == ROLE_LEAD_OUT:
                start = wk.entry[p]
                end = min(int(L[c]) - 1, start + cfg.lead_frames - 1)
            else:
                start, end = wk.entry[p], wk.exit[p]
            if p > 0:
                pa, e = wk.clips[p - 1], wk.exit[p - 1] + k + 1
                yaw, off = _fit(rot_y(points(pa, e), yaw) + off, points(c, start))
                trans["seq"].append(s)
                trans["start"].append(cursor)
                trans["length"].append(k)
                cursor += k
            seg["seq"].append(s)
            seg["pos"].append(p)
            seg["role"].append(role)
            seg["start"].append(cursor)
            seg["length"].append(end - start + 1)
            seg["label"].append(int(labels[c]))
            seg["clip"].append(c)
            seg["clip_start"].append(start)
            seg["yaw"].append(yaw)
            seg["offset"].append(off)
            cursor += end - start + 1
        seq_len.append(cursor)
        seq_split.append(split)
    i64 = lambda x: np.asarray(x, dtype=np.int64)  # noqa: E731
    seq_lengths = i64(seq_len)
    seq_starts = np.concatenate([[0], np.cumsum(seq_lengths)[:-1]]).astype(np.int64) \
        if seq_lengths.size else i64([])
    return {
        "seq_starts": seq_starts, "seq_lengths": seq_lengths,
        "seq_split": np.asarray(seq_split, dtype=np.int8),
        "seg_seq": i64(seg["seq"]), "seg_pos": i64(seg["pos"]),
        "seg_role": np.asarray(seg["role"], dtype=np.int8),
        "seg_start": i64(seg["start"]), "seg_length": i64(seg["length"]),
        "seg_label": i64(seg["label"]), "seg_clip": i64(seg["clip"]),
        "seg_clip_start": i64(seg["clip_start"]),
        "seg_yaw": np.asarray(seg["yaw"], dtype=np.float64),
        "seg_offset": np.asarray(seg["offset"], dtype=np.float64).reshape(-1, 3),
        "trans_seq": i64(trans["seq"]), "trans_start": i64(trans["start"]),
        "trans_length": i64(trans["length"]),
    }


def _placed(clips: ClipSet, rows: np.ndarray, yaw, off) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (float64) and root of source ``rows`` under the transform (yaw, off)."""
    rot = np.asarray(clips.rotations[rows], np.float64).copy()
    rot[:, 0] = quat_yaw_mul(np.broadcast_to(yaw, rows.shape), rot[:, 0])
    root = rot_y(np.asarray(clips.root[rows], np.float64), yaw) + off
    return rot, root


def _frames(clips: ClipSet, idx: dict, k: int) -> dict:
    """Composed rotations, root, joints and frame labels from the index arrays."""
    import torch

    from repro.motion.rotations import quat_to_matrix
    from repro.motion.skeleton import forward_kinematics

    J = clips.skeleton.n_joints
    F = int(idx["seq_lengths"].sum())
    rot = np.zeros((F, J, 4), np.float32)
    root = np.zeros((F, 3), np.float64)
    label = np.full(F, -1, np.int64)
    starts = np.asarray(clips.starts, np.int64)
    lens = idx["seg_length"]
    if lens.size:
        ramp = np.arange(int(lens.sum()), dtype=np.int64) - np.repeat(np.cumsum(lens) - lens, lens)
        out = np.repeat(idx["seq_starts"][idx["seg_seq"]] + idx["seg_start"], lens) + ramp
        src = np.repeat(starts[idx["seg_clip"]] + idx["seg_clip_start"], lens) + ramp
        yaw = np.repeat(idx["seg_yaw"], lens)
        rot[out] = clips.rotations[src]
        rot[out, 0] = quat_yaw_mul(yaw, np.asarray(clips.rotations[src, 0], np.float64))
        root[out] = (rot_y(np.asarray(clips.root[src], np.float64), yaw)
                     + np.repeat(idx["seg_offset"], lens, axis=0))
        label[out] = np.repeat(idx["seg_label"], lens)
        del ramp, out, src, yaw
    if k > 0:
        after = np.flatnonzero(idx["seg_pos"] > 0)          # transition t sits before after[t]
        for t, b in enumerate(after.tolist()):
            a = b - 1
            ya, oa = float(idx["seg_yaw"][a]), idx["seg_offset"][a]
            i = int(idx["seg_clip_start"][a] + idx["seg_length"][a] - 1)
            rows = starts[idx["seg_clip"][a]] + i + 1 + np.arange(k + 1)   # i+1 .. i+k, e
            ra, pa = _placed(clips, rows, ya, oa)
            jb = starts[idx["seg_clip"][b]] + idx["seg_clip_start"][b] + np.arange(2)  # j, j+1
            rb, pb = _placed(clips, jb, float(idx["seg_yaw"][b]), idx["seg_offset"][b])
            q, r = transition_frames(ra, pa, rb, pb)
            first = int(idx["seq_starts"][idx["trans_seq"][t]] + idx["trans_start"][t])
            rot[first:first + k] = q
            root[first:first + k] = r
    joints = np.empty((F, J, 3), np.float32)
    step = 32768
    for s0 in range(0, F, step):
        qq = torch.from_numpy(rot[s0:s0 + step].astype(np.float64))
        jj = forward_kinematics(clips.skeleton, quat_to_matrix(qq),
                                torch.from_numpy(root[s0:s0 + step]))
        joints[s0:s0 + step] = jj.numpy()
    return {"rotations": rot, "root": root.astype(np.float32), "joints": joints,
            "frame_label": label}


def _index_sha(idx: dict) -> str:
    h = hashlib.sha256()
    for k in _INDEX_FIELDS:
        a = np.ascontiguousarray(idx[k])
        h.update(f"{k}:{a.dtype.str}:{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def foot_joints(clips: ClipSet, cfg: ComposeConfig) -> list[int]:
    """Indices of the foot joints: ``cfg.foot_joints`` by name, else the joints named like a
    foot, toe or ankle (ConfigError for an unknown name)."""
    import re

    names = clips.skeleton.names
    if cfg.foot_joints is not None:
        out = []
        for n in cfg.foot_joints:
            if n not in names:
                raise ConfigError(f"compose config: foot joint {n!r} is not a joint of "
                                  f"{clips.name!r}")
            out.append(names.index(n))
        return out
    return [j for j, n in enumerate(names) if re.search(r"(foot|toe|ankle)", n, re.IGNORECASE)]


def compose_sequences(clips: ClipSet, config: ComposeConfig | dict | None = None, *,
                      name: str | None = None) -> SequenceSet:
    """Compose multi-action sequences from ``clips`` (module docstring; Neural Marionette
    Sec. 3 and supp. Fig. 1).  Deterministic: the same clips and config give identical arrays
    and fingerprint, in any process: the torch work runs on one thread (the float rounding of
    batched kernels depends on the thread count)."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _compose(clips, config, name)
    finally:
        torch.set_num_threads(before)


def _compose(clips: ClipSet, config, name: str | None) -> SequenceSet:
    cfg = ComposeConfig.resolve(config)
    if len(clips) == 0:
        raise DataError(f"ClipSet {clips.name!r} has no clips to compose")
    C = clips.n_classes
    labels = np.asarray(clips.labels, np.int64)
    if labels.min() < 0 or labels.max() >= C:
        raise DataError(f"ClipSet {clips.name!r}: labels outside 0..{C - 1}")
    feet = foot_joints(clips, cfg)
    ft = features(clips, cfg.heading_axis, feet, cfg.foot_weight)
    pref, _ = tag_matrix(clips, ft, cfg, COMPOSE_VERSION)
    walks = []
    for split in (TRAIN, TEST):
        walks += [(split, w) for w in walk_split(clips, ft, pref, cfg, split, COMPOSE_VERSION)]
    idx = _layout(clips, ft, cfg, walks, anchor_joints(clips.skeleton, feet))
    del ft
    idx["preference"] = pref
    fp = content_key({"version": COMPOSE_VERSION, "source": clips.fingerprint, "config": cfg,
                      "index": _index_sha(idx)})
    frames = _frames(clips, idx, cfg.blend_frames)
    for a in list(idx.values()) + list(frames.values()):
        a.setflags(write=False)
    return SequenceSet(clips=clips, config=cfg, name=name or f"{clips.name}-seq",
                       fingerprint=fp, **idx, **frames)


# ============================================================================ caching, views
_CACHE: "collections.OrderedDict[tuple[str, str], SequenceSet]" = collections.OrderedDict()
_CACHE_SIZE = 4
_LOCK = threading.Lock()


def sequences_for(clips: ClipSet, config: ComposeConfig | dict | None = None, *,
                  name: str | None = None) -> SequenceSet:
    """:func:`compose_sequences` through an in-process LRU cache (4 entries) keyed by
    ``(clips.fingerprint, config)``.  ``name`` only renames the result."""
    cfg = ComposeConfig.resolve(config)
    key = (clips.fingerprint, cfg.model_dump_json())
    with _LOCK:
        hit = _CACHE.get(key)
        if hit is not None:
            _CACHE.move_to_end(key)
    if hit is None:
        hit = compose_sequences(clips, cfg)
        with _LOCK:
            _CACHE[key] = hit
            _CACHE.move_to_end(key)
            while len(_CACHE) > _CACHE_SIZE:
                _CACHE.popitem(last=False)
    if name is not None and name != hit.name:  # the card names the set; quality is shared
        keep = {k: v for k, v in hit.memo.items() if k == "junction_quality"}
        hit = dataclasses.replace(hit, name=name, memo=keep)
    return hit
