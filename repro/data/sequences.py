"""Composed multi-action sequences: a deterministic, seeded motion graph over a prepared ClipSet.

Why.  Neural Marionette trains and tests on BABEL-MAG (Sec. 3): every action comes with real
context, the ``k`` frames of motion before it (``{P}_{-k}^{-1}``), its own tag ``A^cur``, its
duration ``T`` and the tag of the action that follows (``A^next``).  Its multi-action test
chains actions "according to the transition matrix where the number of connections between
different action categories in the training set is calculated in advance" (Sec. 5.2.1; the
matrix is the heatmap of supp. Sec. 2.1, Fig. 1), and that matrix is sparse and skewed: "except
for a few tag pairs (e.g. turn-walk), most of the tag pairs have only limited connected samples
in the training data" (Sec. 4.3.2).  The stand-in data (``bandai2``) holds single actions only,
so we compose sequences from its real clips like a motion graph (DESIGN.md, "Datasets").
BABEL-MAG's sequences are real recordings; ours are compositions of real single-action clips
joined by short blended transitions.  Every report says so.

Rules (all thresholds and lengths are :class:`ComposeConfig` fields; units: frames at the
ClipSet's fps, metres, radians):

- **Split by source clip.**  Sequences of split ``s`` use only clips with ``clips.split == s``;
  every clip of a split is exactly one ``ROLE_ACTION`` segment of that split's sequences.  A
  sequence is ``[lead-in, action × n, lead-out]`` with ``n`` drawn uniformly in
  ``[min_actions, max_actions]`` (fewer when the walk cannot continue; at least 1).  Lead-ins
  and lead-outs are real clips of the same split reused (any clip other than their neighbour),
  so every action has real frames before it and a real successor tag.  A lead-in keeps its last
  ``lead_frames`` frames up to its exit cut, a lead-out its first ``lead_frames`` from its entry
  cut.
- **Join cost** of an exit frame ``i`` of clip A (one of its last ``cut_window`` frames) and an
  entry frame ``j`` of clip B (one of its first ``cut_window`` frames): the Euclidean distance of
  the root-relative, facing-normalised joint positions (joints minus root, rotated by the
  inverse body heading, :func:`repro.motion.heading.body_heading`; the pose feature of
  ``repro.models.items._pose_features``) plus ``velocity_weight`` × the distance of the
  facing-normalised joint velocities (frame differences ``x[t] − x[t−1]``; the forward
  difference at a clip's first frame).  The cheapest pair is the junction:
  A ends at ``i``, B starts at ``j``; no cut leaves an action shorter than
  ``min(min_action_frames, clip length)``.
- **Tag preference** (the recorded, seeded stand-in of supp. Fig. 1): for each ordered tag pair
  ``(a, b)``, the median over ``preference_samples`` seeded draws of (train clip of ``a``, train
  clip of ``b``) of the best join cost.  Per source tag, the target tags (itself included) are
  ranked by that cost (ties: a seeded order); the first ``n_frequent`` get ``frequent_weight``,
  the next ``n_rare`` ``rare_weight``, the rest 0 (absent pair).  A tag that no row selects
  gets ``rare_weight`` in the row that joins into it most cheaply, so every tag has a
  predecessor for its lead-ins.
- **Walk** (seeded :func:`repro.seeding.numpy_rng`): a sequence starts at a uniformly drawn
  unused clip; its lead-in tag is drawn ∝ the preference column of that clip's tag.  The next
  tag is drawn ∝ the preference row of the current tag restricted to tags with unused clips; if
  that row is all zero, or the sequence has its ``n`` actions, a lead-out (tag ∝ the preference
  row) closes the sequence.  Each clip chosen (actions, lead-ins, lead-outs) is the cheapest
  join among up to ``candidates_per_step`` random candidates of the drawn tag.  Hence every consecutive tag pair
  of a sequence has a non-zero preference (when every tag has at least two clips in the split).
- **Alignment**: B is rotated about +Y and shifted on the ground plane (height untouched) so
  that its entry heading equals A's exit heading and its entry root sits at A's exit root
  advanced by ``(blend_frames + 1)`` × the mean of A's exit and B's (rotated) entry ground-plane
  root velocity.  The sequence's world frame is its lead-in clip's own.
- **Transition**: ``blend_frames`` frames strictly between A's exit pose and B's aligned entry
  pose: slerp of every local joint rotation (shortest arc, roma) and linear interpolation of the
  root.  Their ``frame_label`` is ``-1`` (BABEL's ``transition`` segments).

Determinism: the same clips and config give identical arrays and the same
:attr:`SequenceSet.fingerprint` (content key of ``COMPOSE_VERSION``, the source fingerprint,
the config and the sha256 of the index arrays).
"""

from __future__ import annotations

import collections
import dataclasses
import difflib
import hashlib
import io
import json
import math
import re
import threading
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, ValidationError, model_validator

from repro.data.clipset import TEST, TRAIN, ClipSet
from repro.errors import ConfigError, DataError
from repro.keys import content_key
from repro.seeding import numpy_rng

__all__ = [
    "ROLE_LEAD_IN", "ROLE_ACTION", "ROLE_LEAD_OUT", "ROLE_NAMES", "COMPOSE_VERSION",
    "CARD_SCHEMA", "ComposeConfig", "SequenceSet", "compose_sequences", "sequences_for",
    "SEQUENCE_VIEWS", "load_view", "view_dir", "prepare_view", "view_card", "view_status",
]

ROLE_LEAD_IN, ROLE_ACTION, ROLE_LEAD_OUT = 0, 1, 2
ROLE_NAMES = ("lead_in", "action", "lead_out")

#: Bumped when composition changes; enters the fingerprint.
COMPOSE_VERSION = 1
#: Version of ``card.json`` / ``sequences.npz`` written by ``repro data prepare <view>``.
CARD_SCHEMA = 1

STAND_IN_NOTE = ("stand-in: motion-graph compositions of real single-action clips joined by "
                 "blended transitions; BABEL-MAG's multi-action sequences are real recordings")

_FOOT_NAME = re.compile(r"(foot|toe|ankle)", re.IGNORECASE)


class ComposeConfig(BaseModel):
    """Every threshold and length of the composition (all enter the fingerprint).

    Units: frames at the source ClipSet's fps, metres, radians.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    seed: int = 0                     # seeds the preference samples, tie order and the walk
    min_actions: int = 3              # ROLE_ACTION segments per sequence, drawn uniformly in
    max_actions: int = 8              #   [min_actions, max_actions]
    cut_window: int = 10              # frames at a clip's end (exit) / start (entry) for cuts
    min_action_frames: int = 30       # no cut leaves an action shorter (or its clip, if shorter)
    blend_frames: int = 3             # transition frames between two segments (0: a hard cut);
                                      # 3 < the 6 frames of P^ini, so a context holds real frames
                                      # of the previous action before the blend (docs/data.md)
    velocity_weight: float = 3.0      # frames: converts the velocity distance (m/frame) to metres
    candidates_per_step: int = 8      # random unused clips of the drawn tag compared per step
    n_frequent: int = 2               # frequent successor tags per tag
    n_rare: int = 3                   # rare successor tags per tag (after the frequent ones)
    frequent_weight: float = 1.0      # preference weight of a frequent pair
    rare_weight: float = 0.08         # preference weight of a rare pair (0: rare pairs absent)
    preference_samples: int = 7       # seeded (clip a, clip b) draws per tag pair; median cost
    lead_frames: int = 60             # frames kept of a lead-in (ending at its cut) / lead-out
    heading_axis: Literal["forward", "lateral"] = "forward"  # body axis of the heading
    foot_joints: tuple[str, ...] | None = None  # junction quality; None: names with foot/toe/ankle
    foot_contact_m: float = 0.05      # a foot is on the ground within this height (m) of its
                                      #   lowest height in its clip (junction quality only)

    @model_validator(mode="after")
    def _check(self) -> "ComposeConfig":
        for k in ("min_actions", "cut_window", "min_action_frames", "candidates_per_step",
                  "preference_samples", "lead_frames"):
            if getattr(self, k) < 1:
                raise ValueError(f"{k} must be >= 1")
        for k in ("blend_frames", "n_frequent", "n_rare"):
            if getattr(self, k) < 0:
                raise ValueError(f"{k} must be >= 0")
        if self.max_actions < self.min_actions:
            raise ValueError("max_actions must be >= min_actions")
        if self.n_frequent + self.n_rare < 1:
            raise ValueError("n_frequent + n_rare must be >= 1")
        for k in ("velocity_weight", "rare_weight"):
            if not (math.isfinite(getattr(self, k)) and getattr(self, k) >= 0):
                raise ValueError(f"{k} must be finite and >= 0")
        for k in ("frequent_weight", "foot_contact_m"):
            if not (math.isfinite(getattr(self, k)) and getattr(self, k) > 0):
                raise ValueError(f"{k} must be finite and > 0")
        return self

    @classmethod
    def resolve(cls, overrides=None) -> "ComposeConfig":
        """A config from ``None`` (defaults), a ComposeConfig or a dict of overrides
        (a ConfigError names the bad field)."""
        if overrides is None:
            return cls()
        if isinstance(overrides, cls):
            return overrides
        try:
            return cls(**dict(overrides))
        except ValidationError as e:
            err = e.errors()[0]
            loc = ".".join(str(p) for p in err.get("loc", ())) or "?"
            raise ConfigError(f"compose config: field {loc!r}: {err['msg']}") from None
        except TypeError as e:
            raise ConfigError(f"compose config: {e}") from None


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
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

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
        rot[:, 0] = _quat_yaw_mul(np.full(rot.shape[0], yaw), rot[:, 0])
        r = np.asarray(root, dtype=np.float64) - self.seg_offset[a]
        r = _rot_y(r, np.full(r.shape[0], yaw))
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

    def junction_quality(self) -> dict:
        """Velocity jump and foot slide at junctions vs inside the clips (see docs/data.md).

        - velocity jump: mean over joints of ``||v_t − v_{t−1}||`` (cm/frame², ``v`` the joint
          frame difference) at frames ``t`` whose stencil ``t−2..t`` touches a transition frame
          or spans two segments ("junction"), vs stencils inside one segment ("inside").
        - foot slide: mean horizontal speed (cm/frame) of the foot joints on frames where that
          foot is within ``foot_contact_m`` of its lowest height in its source clip (transition
          frames: the lower of the two neighbouring clips'), same junction/inside partition.
        """
        if "junction_quality" not in self._cache:
            self._cache["junction_quality"] = _junction_quality(self)
        return self._cache["junction_quality"]

    def card(self) -> dict:
        """A JSON-able summary (what ``repro data info`` prints and ``card.json`` stores)."""
        if "card" not in self._cache:
            self._cache["card"] = _card(self)
        return json.loads(json.dumps(self._cache["card"]))


# ============================================================================ small math
def _rot_y(v: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """``R_y(angle) @ v`` for vectors (..., 3); ``angle`` broadcasts to ``v[..., 0]``."""
    c, s = np.cos(angle), np.sin(angle)
    x, z = v[..., 0], v[..., 2]
    out = np.array(v, dtype=np.float64, copy=True)
    out[..., 0] = c * x + s * z
    out[..., 2] = -s * x + c * z
    return out


def _quat_yaw_mul(angle: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Quaternion product ``q_y(angle) ⊗ q`` (xyzw), i.e. the rotation ``R_y(angle) · R(q)``."""
    c, s = np.cos(angle / 2.0), np.sin(angle / 2.0)
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([c * x + s * z, c * y + s * w, c * z - s * x, c * w - s * y], axis=-1)


def _wrap(a: float) -> float:
    return float(math.atan2(math.sin(a), math.cos(a)))


# ============================================================================ features
@dataclass
class _Windows:
    """Per-clip entry (first W frames) and exit (last W frames) windows with features.

    ``*_loc`` (N, W) local frame indices, ``*_ok`` (N, W) validity, ``*_p``/``*_v`` (N, W, D)
    facing-normalised pose and velocity features, ``*_h`` (N, W) headings, ``*_root`` and
    ``*_rv`` (N, W, 3) root position and root velocity in the clip's world frame.
    """

    en_loc: np.ndarray
    en_ok: np.ndarray
    en_p: np.ndarray
    en_v: np.ndarray
    en_h: np.ndarray
    en_root: np.ndarray
    en_rv: np.ndarray
    ex_loc: np.ndarray
    ex_ok: np.ndarray
    ex_p: np.ndarray
    ex_v: np.ndarray
    ex_h: np.ndarray
    ex_root: np.ndarray
    ex_rv: np.ndarray
    ex_first: np.ndarray  # (N,) local index of the exit window's first frame


def _headings(clips: ClipSet, rows: np.ndarray, axis: str) -> np.ndarray:
    """Body heading (radians) of packed frame ``rows``: :func:`repro.motion.heading.body_heading`
    computed from the root-to-pelvis chain only (the other joints do not enter it)."""
    import torch

    from repro.motion.heading import HEADING_AXES, body_frame, heading_angle
    from repro.motion.rotations import quat_to_matrix

    sk = clips.skeleton
    body = body_frame(sk)
    chain = [body.pelvis]
    while sk.parents[chain[-1]] != -1:
        chain.append(sk.parents[chain[-1]])
    chain = chain[::-1]
    q = torch.from_numpy(np.asarray(clips.rotations[rows][:, chain], dtype=np.float64))
    R = quat_to_matrix(q)
    G = R[:, 0]
    for k in range(1, len(chain)):
        G = G @ R[:, k]
    return heading_angle(G, body.axis(axis), HEADING_AXES[axis]).numpy()


def _windows(clips: ClipSet, W: int, axis: str) -> _Windows:
    N = len(clips)
    starts = np.asarray(clips.starts, np.int64)
    L = np.asarray(clips.lengths, np.int64)
    k = np.arange(W, dtype=np.int64)[None, :]
    en_raw = np.broadcast_to(k, (N, W))
    ex_first = np.maximum(L - W, 0)
    ex_raw = ex_first[:, None] + k
    out = {}
    for tag, raw in (("en", en_raw), ("ex", ex_raw)):
        ok = raw < L[:, None]
        loc = np.minimum(raw, L[:, None] - 1)
        rows = starts[:, None] + loc
        # velocity: x[t] - x[t-1]; at t = 0 the forward difference (zero for 1-frame clips)
        a = np.where(loc >= 1, rows - 1, rows)
        b = np.where(loc >= 1, rows, np.minimum(rows + 1, (starts + L - 1)[:, None]))
        fr, fa, fb = rows.reshape(-1), a.reshape(-1), b.reshape(-1)
        h = _headings(clips, fr, axis)
        root = np.asarray(clips.root[fr], np.float64)
        jnt = np.asarray(clips.joints[fr], np.float64)
        vel = np.asarray(clips.joints[fb], np.float64) - np.asarray(clips.joints[fa], np.float64)
        rv = np.asarray(clips.root[fb], np.float64) - np.asarray(clips.root[fa], np.float64)
        p = _rot_y(jnt - root[:, None], -h[:, None]).reshape(len(fr), -1)
        v = _rot_y(vel, -h[:, None]).reshape(len(fr), -1)
        D = p.shape[1]
        out.update({f"{tag}_loc": loc, f"{tag}_ok": ok, f"{tag}_p": p.reshape(N, W, D),
                    f"{tag}_v": v.reshape(N, W, D), f"{tag}_h": h.reshape(N, W),
                    f"{tag}_root": root.reshape(N, W, 3), f"{tag}_rv": rv.reshape(N, W, 3)})
    return _Windows(ex_first=ex_first, **out)


def _best_joins(win: _Windows, A: np.ndarray, ex_mask: np.ndarray, B: np.ndarray,
                en_mask: np.ndarray, vw: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cheapest (exit i of A[p], entry j of B[p]) per pair p, vectorised.

    ``ex_mask``/``en_mask`` (P, W): allowed window slots.  Returns (cost (P,), i (P,) and
    j (P,) as *local frame indices* of the clips; cost ``inf`` and i = j = -1 when no slot is
    allowed).  Ties go to the first slot in (i, j) row-major order.
    """
    P = A.shape[0]
    W = win.en_ok.shape[1]
    cost = np.empty(P)
    ii = np.empty(P, np.int64)
    jj = np.empty(P, np.int64)
    chunk = max(1, 4096 // (W * W) * 16)
    for s in range(0, P, chunk):
        a, b = A[s:s + chunk], B[s:s + chunk]
        dp = np.linalg.norm(win.ex_p[a][:, :, None] - win.en_p[b][:, None], axis=-1)
        dv = np.linalg.norm(win.ex_v[a][:, :, None] - win.en_v[b][:, None], axis=-1)
        c = dp + vw * dv
        ok = ex_mask[s:s + chunk][:, :, None] & en_mask[s:s + chunk][:, None, :]
        c = np.where(ok, c, np.inf).reshape(len(a), W * W)
        kk = np.argmin(c, axis=1)
        best = c[np.arange(len(a)), kk]
        cost[s:s + chunk] = best
        bad = ~np.isfinite(best)
        ki, kj = kk // W, kk % W
        ii[s:s + chunk] = np.where(bad, -1, win.ex_loc[a, ki])
        jj[s:s + chunk] = np.where(bad, -1, win.en_loc[b, kj])
    return cost, ii, jj


# ============================================================================ preference
def _min_len(L: np.ndarray, cfg: ComposeConfig) -> np.ndarray:
    return np.minimum(cfg.min_action_frames, L)


def _entry_mask_action(win: _Windows, B: np.ndarray, L: np.ndarray, cfg: ComposeConfig):
    """Entry slots of action clips B that leave room for their minimum length."""
    return win.en_ok[B] & (win.en_loc[B] <= (L[B] - _min_len(L[B], cfg))[:, None])


def _exit_mask_action(win: _Windows, A: np.ndarray, entry: np.ndarray, L: np.ndarray,
                      cfg: ComposeConfig):
    """Exit slots of action clips A (entered at local frame ``entry``) keeping their minimum."""
    return win.ex_ok[A] & (win.ex_loc[A] >= (entry + _min_len(L[A], cfg) - 1)[:, None])


def _preference(clips: ClipSet, win: _Windows, cfg: ComposeConfig) -> tuple[np.ndarray, np.ndarray]:
    """(preference (C, C), median best join cost (C, C)) from seeded samples of train clips."""
    C = clips.n_classes
    S = cfg.preference_samples
    L = np.asarray(clips.lengths, np.int64)
    labels = np.asarray(clips.labels, np.int64)
    split = np.asarray(clips.split)
    pools = []
    for c in range(C):
        idx = np.flatnonzero((labels == c) & (split == TRAIN))
        if idx.size == 0:  # no train clip of this tag: fall back to all its clips
            idx = np.flatnonzero(labels == c)
        pools.append(idx)
    rng = numpy_rng(cfg.seed, "compose", COMPOSE_VERSION, "preference-samples")
    A_list, B_list, pair = [], [], []
    for a in range(C):
        for b in range(C):
            pa, pb = pools[a], pools[b]
            if pa.size == 0 or pb.size == 0:
                continue
            ca = rng.choice(pa, S, replace=pa.size < S)
            cb = rng.choice(pb, S, replace=pb.size < S)
            if a == b and pa.size > 1:  # a clip never joins itself
                pos = np.searchsorted(pa, cb)
                cb = np.where(ca == cb, pa[(pos + 1) % pa.size], cb)
            A_list.append(ca)
            B_list.append(cb)
            pair.append(np.full(S, a * C + b))
    med = np.full((C, C), np.inf)
    if A_list:
        A = np.concatenate(A_list)
        B = np.concatenate(B_list)
        pr = np.concatenate(pair)
        cost, _, _ = _best_joins(win, A, _exit_mask_action(win, A, np.zeros_like(A), L, cfg),
                                 B, _entry_mask_action(win, B, L, cfg), cfg.velocity_weight)
        cost = cost.reshape(-1, S)
        med.reshape(-1)[pr.reshape(-1, S)[:, 0]] = np.median(cost, axis=1)
    ties = numpy_rng(cfg.seed, "compose", COMPOSE_VERSION, "preference-ties")
    pref = np.zeros((C, C))
    for a in range(C):
        order = np.lexsort((ties.permutation(C), med[a]))
        for r, b in enumerate(order):
            if not np.isfinite(med[a, b]):
                continue
            if r < cfg.n_frequent:
                pref[a, b] = cfg.frequent_weight
            elif r < cfg.n_frequent + cfg.n_rare:
                pref[a, b] = cfg.rare_weight
    # every tag needs a predecessor (lead-ins): the cheapest row into an uncovered column
    col_ties = numpy_rng(cfg.seed, "compose", COMPOSE_VERSION, "preference-columns")
    for b in range(C):
        if (pref[:, b] > 0).any() or not np.isfinite(med[:, b]).any():
            continue
        a = int(np.lexsort((col_ties.permutation(C), med[:, b]))[0])
        pref[a, b] = cfg.rare_weight if cfg.rare_weight > 0 else cfg.frequent_weight
    return pref, med


# ============================================================================ the walk
class _Seq:
    __slots__ = ("clips", "roles", "entry", "exit")

    def __init__(self):
        self.clips: list[int] = []
        self.roles: list[int] = []
        self.entry: list[int] = []   # local entry cut (-1: none, the lead-in)
        self.exit: list[int] = []    # local exit cut (-1: none, the lead-out)


def _draw(rng: np.random.Generator, weights: np.ndarray) -> int:
    return int(rng.choice(weights.shape[0], p=weights / weights.sum()))


def _walk_split(clips: ClipSet, win: _Windows, pref: np.ndarray, cfg: ComposeConfig,
                split: int) -> list[_Seq]:
    C = clips.n_classes
    L = np.asarray(clips.lengths, np.int64)
    labels = np.asarray(clips.labels, np.int64)
    members = np.flatnonzero(np.asarray(clips.split) == split)
    if members.size == 0:
        return []
    if members.size < 2:
        raise DataError(f"{clips.name}: the {('train', 'test')[split]} split has one clip; "
                        "composing sequences needs at least two (lead-ins/lead-outs reuse "
                        "another clip of the split)")
    rng = numpy_rng(cfg.seed, "compose", COMPOSE_VERSION, "walk", split)
    by_tag = [members[labels[members] == c] for c in range(C)]
    unused = [set(x.tolist()) for x in by_tag]
    n_left = int(members.size)
    vw = cfg.velocity_weight
    K = cfg.candidates_per_step

    def candidates(pool: np.ndarray) -> np.ndarray:
        if pool.size > K:
            return rng.choice(pool, K, replace=False)
        return pool

    def pick_tag(weights: np.ndarray, avail: np.ndarray) -> int:
        w = weights * avail
        if w.sum() > 0:
            return _draw(rng, w)
        return _draw(rng, avail.astype(np.float64))  # fallback: uniform over available tags

    seqs: list[_Seq] = []
    while n_left:
        sq = _Seq()
        n_target = int(rng.integers(cfg.min_actions, cfg.max_actions + 1))
        pool_all = np.array(sorted(set().union(*unused)), dtype=np.int64)
        first = int(rng.choice(pool_all))
        unused[labels[first]].discard(first)
        n_left -= 1
        # lead-in: tag ∝ the preference column of the first action's tag
        avail = np.array([(by_tag[c] != first).any() for c in range(C)])
        t = pick_tag(pref[:, labels[first]], avail)
        cand = candidates(by_tag[t][by_tag[t] != first])
        B = np.full(cand.size, first)
        cost, ii, jj = _best_joins(win, cand, win.ex_ok[cand], B,
                                   _entry_mask_action(win, B, L, cfg), vw)
        k = int(np.argmin(cost))
        sq.clips += [int(cand[k]), first]
        sq.roles += [ROLE_LEAD_IN, ROLE_ACTION]
        sq.entry += [-1, int(jj[k])]
        sq.exit += [int(ii[k])]
        cur = first
        n_act = 1
        while n_act < n_target:
            has = np.array([len(u) > 0 for u in unused])
            w = pref[labels[cur]] * has
            if not w.sum() > 0:
                break
            t = _draw(rng, w)
            cand = candidates(np.array(sorted(unused[t]), dtype=np.int64))
            A = np.full(cand.size, cur)
            cost, ii, jj = _best_joins(
                win, A, _exit_mask_action(win, A, np.full(cand.size, sq.entry[-1]), L, cfg),
                cand, _entry_mask_action(win, cand, L, cfg), vw)
            k = int(np.argmin(cost))
            nxt = int(cand[k])
            unused[t].discard(nxt)
            n_left -= 1
            sq.exit.append(int(ii[k]))
            sq.clips.append(nxt)
            sq.roles.append(ROLE_ACTION)
            sq.entry.append(int(jj[k]))
            cur = nxt
            n_act += 1
        # lead-out: tag ∝ the preference row of the last action's tag
        avail = np.array([(by_tag[c] != cur).any() for c in range(C)])
        t = pick_tag(pref[labels[cur]], avail)
        cand = candidates(by_tag[t][by_tag[t] != cur])
        A = np.full(cand.size, cur)
        cost, ii, jj = _best_joins(
            win, A, _exit_mask_action(win, A, np.full(cand.size, sq.entry[-1]), L, cfg),
            cand, win.en_ok[cand], vw)
        k = int(np.argmin(cost))
        sq.exit.append(int(ii[k]))
        sq.clips.append(int(cand[k]))
        sq.roles.append(ROLE_LEAD_OUT)
        sq.entry.append(int(jj[k]))
        sq.exit.append(-1)
        seqs.append(sq)
    return seqs


# ============================================================================ assembly
def _layout(clips: ClipSet, win: _Windows, cfg: ComposeConfig, walks: list[tuple[int, _Seq]]):
    """Segment and transition tables, with each segment's rigid transform."""
    L = np.asarray(clips.lengths, np.int64)
    labels = np.asarray(clips.labels, np.int64)
    n = cfg.blend_frames
    seg = collections.defaultdict(list)
    trans = collections.defaultdict(list)
    seq_len, seq_split = [], []
    for s, (split, sq) in enumerate(walks):
        cursor = 0
        yaw, off = 0.0, np.zeros(3)  # the sequence's world frame is its lead-in clip's own
        m = len(sq.clips)
        for p in range(m):
            c, role = sq.clips[p], sq.roles[p]
            if role == ROLE_LEAD_IN:
                end = sq.exit[p]
                start = max(0, end - cfg.lead_frames + 1)
            elif role == ROLE_LEAD_OUT:
                start = sq.entry[p]
                end = min(int(L[c]) - 1, start + cfg.lead_frames - 1)
            else:
                start, end = sq.entry[p], sq.exit[p]
            if p > 0:
                # align on the junction with the previous segment (A exits at i, B enters at j)
                pa, i, j = sq.clips[p - 1], sq.exit[p - 1], start
                ki = i - int(win.ex_first[pa])
                hA = float(win.ex_h[pa, ki]) + yaw
                rA = _rot_y(win.ex_root[pa, ki], yaw) + off
                vA = _rot_y(win.ex_rv[pa, ki], yaw)
                yaw_b = _wrap(hA - float(win.en_h[c, j]))
                vB = _rot_y(win.en_rv[c, j], yaw_b)
                target = rA + (n + 1) * 0.5 * (vA + vB)
                rB = _rot_y(win.en_root[c, j], yaw_b)
                yaw, off = yaw_b, np.array([target[0] - rB[0], 0.0, target[2] - rB[2]])
                trans["seq"].append(s)
                trans["start"].append(cursor)
                trans["length"].append(n)
                cursor += n
            length = end - start + 1
            seg["seq"].append(s)
            seg["pos"].append(p)
            seg["role"].append(role)
            seg["start"].append(cursor)
            seg["length"].append(length)
            seg["label"].append(int(labels[c]))
            seg["clip"].append(c)
            seg["clip_start"].append(start)
            seg["yaw"].append(yaw)
            seg["offset"].append(off)
            cursor += length
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


def _frames(clips: ClipSet, idx: dict) -> dict:
    """Composed rotations, root, joints and frame labels from the index arrays."""
    import roma
    import torch

    from repro.motion.rotations import quat_to_matrix
    from repro.motion.skeleton import forward_kinematics

    J = clips.skeleton.n_joints
    F = int(idx["seq_lengths"].sum())
    rot = np.zeros((F, J, 4), np.float32)
    root = np.zeros((F, 3), np.float64)
    label = np.full(F, -1, np.int64)
    # segment frames: the source frames under each segment's rigid transform
    lens = idx["seg_length"]
    if lens.size:
        ramp = np.arange(int(lens.sum()), dtype=np.int64) - np.repeat(np.cumsum(lens) - lens, lens)
        out = np.repeat(idx["seq_starts"][idx["seg_seq"]] + idx["seg_start"], lens) + ramp
        src = np.repeat(np.asarray(clips.starts, np.int64)[idx["seg_clip"]]
                        + idx["seg_clip_start"], lens) + ramp
        yaw = np.repeat(idx["seg_yaw"], lens)
        rot[out] = clips.rotations[src]
        rot[out, 0] = _quat_yaw_mul(yaw, np.asarray(clips.rotations[src, 0], np.float64))
        root[out] = (_rot_y(np.asarray(clips.root[src], np.float64), yaw)
                     + np.repeat(idx["seg_offset"], lens, axis=0))
        label[out] = np.repeat(idx["seg_label"], lens)
        del ramp, out, src, yaw
    # transitions: slerp / lerp strictly between the neighbouring frames
    tl = idx["trans_length"]
    if tl.size and int(tl.max()) > 0:
        n = int(tl.max())  # every transition has blend_frames frames
        first = idx["seq_starts"][idx["trans_seq"]] + idx["trans_start"]
        a, b = first - 1, first + n
        steps = torch.arange(1, n + 1, dtype=torch.float64) / (n + 1)
        q = roma.unitquat_slerp(torch.from_numpy(rot[a].astype(np.float64)),
                                torch.from_numpy(rot[b].astype(np.float64)), steps,
                                shortest_arc=True).numpy()             # (n, T, J, 4)
        rows = first[None, :] + np.arange(n)[:, None]                  # (n, T)
        rot[rows] = q
        s = steps.numpy()[:, None, None]
        root[rows] = root[a][None] + s * (root[b] - root[a])[None]
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
    win = _windows(clips, cfg.cut_window, cfg.heading_axis)
    pref, _ = _preference(clips, win, cfg)
    walks: list[tuple[int, _Seq]] = []
    for split in (TRAIN, TEST):
        walks += [(split, sq) for sq in _walk_split(clips, win, pref, cfg, split)]
    idx = _layout(clips, win, cfg, walks)
    idx["preference"] = pref
    fp = content_key({"version": COMPOSE_VERSION, "source": clips.fingerprint, "config": cfg,
                      "index": _index_sha(idx)})
    frames = _frames(clips, idx)
    for a in list(idx.values()) + list(frames.values()):
        a.setflags(write=False)
    return SequenceSet(clips=clips, config=cfg, name=name or f"{clips.name}-seq",
                       fingerprint=fp, **idx, **frames)


# ============================================================================ quality, card
def _foot_joints(seqs: SequenceSet) -> list[int]:
    names = seqs.skeleton.names
    if seqs.config.foot_joints is not None:
        out = []
        for n in seqs.config.foot_joints:
            if n not in names:
                raise ConfigError(f"compose config: foot joint {n!r} is not a joint of "
                                  f"{seqs.clips.name!r}")
            out.append(names.index(n))
        return out
    return [j for j, n in enumerate(names) if _FOOT_NAME.search(n)]


def _stats(x: np.ndarray) -> dict:
    if x.size == 0:
        return {"mean": None, "median": None, "n": 0}
    return {"mean": round(float(x.mean()), 4), "median": round(float(np.median(x)), 4),
            "n": int(x.size)}


def _junction_quality(seqs: SequenceSet) -> dict:
    F = seqs.n_frames
    cfg = seqs.config
    # piece id per frame: segments 0..A-1, transition frames -1; sequence id per frame
    piece = np.full(F, -1, np.int64)
    lens = seqs.seg_length
    if lens.size:
        ramp = np.arange(int(lens.sum())) - np.repeat(np.cumsum(lens) - lens, lens)
        rows = np.repeat(seqs.seq_starts[seqs.seg_seq] + seqs.seg_start, lens) + ramp
        piece[rows] = np.repeat(np.arange(lens.size), lens)
    seq_of = np.repeat(np.arange(len(seqs)), seqs.seq_lengths)
    out = {"units": {"velocity_jump": "cm/frame^2", "foot_slide": "cm/frame"},
           "foot_contact_m": cfg.foot_contact_m}
    feet = _foot_joints(seqs)
    out["foot_joints"] = [seqs.skeleton.names[j] for j in feet]
    ground = None
    if feet:
        cl = seqs.clips
        fy = np.asarray(cl.joints[:, feet, 1], np.float64)
        L = np.asarray(cl.lengths, np.int64)
        clip_min = np.full((len(cl), len(feet)), np.inf)
        nz = L > 0
        clip_min[nz] = np.minimum.reduceat(fy, np.asarray(cl.starts, np.int64)[nz], axis=0)
        ground = np.full((F, len(feet)), np.nan)
        ground[piece >= 0] = clip_min[seqs.seg_clip[piece[piece >= 0]]]
        # transition frames: the lower ground of the two neighbouring segments
        tl = seqs.trans_length
        if tl.size and int(tl.max()) > 0:
            first = seqs.seq_starts[seqs.trans_seq] + seqs.trans_start
            g = np.minimum(ground[first - 1], ground[first + tl])
            rows = np.repeat(first, tl) + (np.arange(int(tl.sum()))
                                           - np.repeat(np.cumsum(tl) - tl, tl))
            ground[rows] = np.repeat(g, tl, axis=0)
    acc_j, acc_i, slide_j, slide_i = [], [], [], []
    step = 65536
    for s0 in range(0, F, step):  # chunks of frames t (stencils reach back 2 frames)
        lo = max(0, s0 - 2)
        X = seqs.joints[lo:s0 + step].astype(np.float64) * 100.0  # cm
        t = np.arange(max(s0, 2), min(F, s0 + step))
        if t.size:
            x0, x1, x2 = X[t - 2 - lo], X[t - 1 - lo], X[t - lo]
            ok = seq_of[t - 2] == seq_of[t]
            acc = np.linalg.norm(x2 - 2.0 * x1 + x0, axis=-1).mean(axis=-1)
            p0, p1, p2 = piece[t - 2], piece[t - 1], piece[t]
            inside = ok & (p0 >= 0) & (p0 == p1) & (p1 == p2)
            acc_i.append(acc[inside])
            acc_j.append(acc[ok & ~inside])
        t = np.arange(max(s0, 1), min(F, s0 + step))
        if feet and t.size:
            ok = seq_of[t - 1] == seq_of[t]
            cur, prev = X[t - lo][:, feet], X[t - 1 - lo][:, feet]
            contact = (cur[..., 1] / 100.0 - ground[t]) < cfg.foot_contact_m
            speed = np.linalg.norm((cur - prev)[..., [0, 2]], axis=-1)  # (n, feet) cm/frame
            inside = ok & (piece[t - 1] >= 0) & (piece[t - 1] == piece[t])
            slide_i.append(speed[inside[:, None] & contact])
            slide_j.append(speed[(ok & ~inside)[:, None] & contact])
    cat = lambda xs: np.concatenate(xs) if xs else np.zeros(0)  # noqa: E731
    out["velocity_jump"] = {"junction": _stats(cat(acc_j)), "inside": _stats(cat(acc_i))}
    out["foot_slide"] = {"junction": _stats(cat(slide_j)), "inside": _stats(cat(slide_i))}
    for k in ("velocity_jump", "foot_slide"):
        j, i = out[k]["junction"]["mean"], out[k]["inside"]["mean"]
        out[k]["ratio_of_means"] = round(j / i, 3) if (j is not None and i) else None
    return out


def _pair_summary(counts: np.ndarray, pref: np.ndarray) -> dict:
    total = int(counts.sum())
    flat = np.sort(counts.reshape(-1))[::-1]
    k = max(1, int(round(0.1 * flat.size)))
    top = float(flat[:k].sum() / total) if total else None
    freq = float(counts[pref == pref.max()].sum() / total) if total and pref.max() > 0 else None
    return {"pairs": total, "zero_pairs": int((counts == 0).sum()), "cells": int(counts.size),
            "top10pct_pairs_mass": None if top is None else round(top, 4),
            "frequent_pairs_mass": None if freq is None else round(freq, 4)}


def _card(seqs: SequenceSet) -> dict:
    names = list(seqs.label_names)
    per_split = {}
    for sname, s in (("train", TRAIN), ("test", TEST)):
        sq = np.flatnonzero(seqs.seq_split == s)
        acts = np.bincount(seqs.seg_seq[seqs.segments(split=s)], minlength=len(seqs))[sq]
        per_split[sname] = {
            "sequences": int(sq.size),
            "clips": int((np.asarray(seqs.clips.split) == s).sum()),
            "segments": {r: int(seqs.segments(split=s, role=i).size)
                         for i, r in enumerate(ROLE_NAMES)},
            "actions_per_sequence": ({"min": int(acts.min()), "mean": round(float(acts.mean()), 3),
                                      "max": int(acts.max())} if acts.size else None),
            "frames": int(seqs.seq_lengths[sq].sum()),
        }
    acts = np.bincount(seqs.seg_seq[seqs.segments()], minlength=len(seqs))
    train_counts = seqs.tag_pair_counts(TRAIN)
    test_counts = seqs.tag_pair_counts(TEST)
    return {
        "schema": CARD_SCHEMA,
        "kind": "composed multi-action sequences",
        "name": seqs.name,
        "fingerprint": seqs.fingerprint,
        "compose_version": COMPOSE_VERSION,
        "source": {"name": seqs.clips.name, "fingerprint": seqs.clips.fingerprint,
                   "clips": len(seqs.clips), "frames": seqs.clips.n_frames},
        "stand_in": STAND_IN_NOTE,
        "config": seqs.config.model_dump(mode="json"),
        "fps": seqs.fps,
        "joints": seqs.skeleton.n_joints,
        "label_names": names,
        "sequences": {"total": len(seqs), "train": per_split["train"]["sequences"],
                      "test": per_split["test"]["sequences"]},
        "segments": {r: int(seqs.segments(role=i).size) for i, r in enumerate(ROLE_NAMES)},
        "actions_per_sequence": ({"min": int(acts.min()), "mean": round(float(acts.mean()), 3),
                                  "max": int(acts.max())} if acts.size else None),
        "frames": {"total": seqs.n_frames,
                   "transition": int((seqs.frame_label < 0).sum()),
                   "transitions": int(seqs.trans_seq.size)},
        "splits": per_split,
        "tag_pairs": {"label_names": names, "rows": "from (earlier segment)",
                      "columns": "to (next segment)",
                      "train": train_counts.tolist(), "test": test_counts.tolist(),
                      "train_summary": _pair_summary(train_counts, seqs.preference),
                      "test_summary": _pair_summary(test_counts, seqs.preference)},
        "preference": {"label_names": names, "matrix": seqs.preference.tolist(),
                       "nonzero": int((seqs.preference > 0).sum())},
        "junction_quality": seqs.junction_quality(),
    }


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
        keep = {k: v for k, v in hit._cache.items() if k == "junction_quality"}
        hit = dataclasses.replace(hit, name=name, _cache=keep)
    return hit


#: Sequence views: name → source data set (not registered data sets; see docs/data.md).
SEQUENCE_VIEWS = {"bandai2-seq": "bandai2", "bandai2-seq-mini": "bandai2-mini"}
_POINTER = "current.json"


def _check_view(name: str) -> str:
    if name not in SEQUENCE_VIEWS:
        near = difflib.get_close_matches(name, list(SEQUENCE_VIEWS), n=1)
        hint = f"; did you mean {near[0]!r}?" if near else ""
        raise ConfigError(f"unknown sequence view {name!r}{hint} "
                          f"(known: {', '.join(SEQUENCE_VIEWS)})")
    return SEQUENCE_VIEWS[name]


def _view_source(name: str) -> ClipSet:
    from repro.data.registry import load_clipset
    from repro.data.splits import marionette_clipset

    return marionette_clipset(load_clipset(_check_view(name)))


def load_view(name: str) -> SequenceSet:
    """The sequence view ``name``: its source ClipSet (registry) with Neural Marionette's test
    split (:func:`repro.data.splits.marionette_clipset`, seed 0, 20 % capped at 100 per class),
    composed with the default :class:`ComposeConfig`.  A missing source raises the registry's
    MissingDataError (naming ``repro data prepare bandai2``)."""
    return sequences_for(_view_source(name), ComposeConfig(), name=name)


def view_dir(name: str):
    """Folder of a prepared view: ``datasets_root()/<name>/``."""
    from repro.data.cache import dataset_dir

    _check_view(name)
    return dataset_dir(name)


def _npz_bytes(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **{k: np.ascontiguousarray(v) for k, v in arrays.items()})
    return buf.getvalue()


def prepare_view(name: str) -> dict:
    """Compose view ``name`` and write ``<view_dir>/<fingerprint>/{sequences.npz, card.json}``
    (index arrays and card, each atomically) and the ``current.json`` pointer.  Returns
    ``{"path", "fingerprint", "reused", "seconds", "card"}``."""
    import time

    from repro.store.atomic import atomic_write_bytes, atomic_write_json

    t0 = time.perf_counter()
    seqs = load_view(name)
    card = seqs.card()
    root = view_dir(name)
    folder = root / seqs.fingerprint
    reused = False
    try:
        reused = json.loads((folder / "card.json").read_text()) == card \
            and (folder / "sequences.npz").is_file()
    except (OSError, ValueError):
        reused = False
    if not reused:
        meta = {"schema": np.array(CARD_SCHEMA), "fingerprint": np.array(seqs.fingerprint)}
        atomic_write_bytes(folder / "sequences.npz", _npz_bytes({**seqs.index_arrays(), **meta}))
        atomic_write_json(folder / "card.json", card)
    atomic_write_json(root / _POINTER, {"fingerprint": seqs.fingerprint})
    return {"path": str(folder), "fingerprint": seqs.fingerprint, "reused": reused,
            "seconds": round(time.perf_counter() - t0, 3), "card": card}


def _stored_card(name: str) -> dict | None:
    root = view_dir(name)
    try:
        fp = json.loads((root / _POINTER).read_text())["fingerprint"]
        card = json.loads((root / str(fp) / "card.json").read_text())
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return card if isinstance(card, dict) and card.get("schema") == CARD_SCHEMA else None


def view_card(name: str) -> dict:
    """The card of view ``name``: the prepared one when it still matches the source, the
    compose version and the default config; otherwise composed now."""
    src = _view_source(name)
    card = _stored_card(name)
    if (card is not None and card.get("compose_version") == COMPOSE_VERSION
            and card.get("source", {}).get("fingerprint") == src.fingerprint
            and card.get("config") == ComposeConfig().model_dump(mode="json")):
        return card
    return sequences_for(src, ComposeConfig(), name=name).card()


def view_status(name: str):
    """A :class:`repro.data.registry.DatasetStatus` for a view: ready when its source is;
    ``fingerprint`` is the prepared view's (``None`` if not prepared)."""
    from repro.data.registry import DatasetStatus, get_entry

    st = get_entry(_check_view(name)).status()
    card = _stored_card(name)
    return DatasetStatus(st.prepared, str(view_dir(name)),
                         card.get("fingerprint") if card else None,
                         None if st.prepared else f"source {SEQUENCE_VIEWS[name]} is not ready: "
                         f"{st.missing}")
