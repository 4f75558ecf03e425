"""Neural Marionette's items and their context, built once for every protocol (data layer).

An *item* (:class:`repro.data.action_items.ActionItems`) is one action to generate with what the
generator is conditioned on: the previous motion ``P^ini`` (``n_init`` = 6 frames), the tag,
the duration, the next tag and the trajectory (Neural Marionette §3, Fig. 2; §4.2).  BABEL-MAG
takes the previous motion and the next tag from the recording the action sits in.  The
stand-in's clips are single actions, so the context comes from the **composed sequences**
(:mod:`repro.data.sequences`, the ``bandai2-seq`` view): an item is one ``ROLE_ACTION``
segment; ``P^ini`` is the ``n_init`` frames before it in its sequence (the transition: the
previous clip's own recorded continuation carried onto this segment's first frame, and before
it the previous segment's end); the next tag is the label of the segment after it.  Neither
ever comes from the clip being generated (``tests/test_contexts.py``).

:class:`ActionSource` (an :class:`repro.data.item_sources.ItemSource`) is the one description
of how these items are made (split, composition, item construction, context), shared by the
``single_action``, ``multi_action`` and ``ss_ar`` protocols and by the engine's training step,
so a model trained for one table serves every table whose items are described the same way
(its ``describe()`` enters the training key).

``context = "same_clip"`` is the earlier construction, kept as a named, recorded option
(:func:`build_items`): one item per clip, ``P^ini`` the first ``n_init`` frames of the clip
itself, the action the following ``T = min(len − K, max_frames)`` frames, and a motion-graph
next tag derived from the clip's own end pose (:func:`next_tags`) — a leak, since both come
from the action being generated.

Each item is expressed in the world frame of its source clip (the context is mapped by the
inverse of the segment's placement in the sequence), so an item's real action is exactly the
recorded clip's segment (``max_action_frames`` ≤ every profile's ``max_frames``: whole, never
truncated) and evaluators that see absolute heading are unaffected.  Both constructions end in
:func:`items_from_windows` (Marionette normalisation at ``P₋₁``, Alg. 1 / Eq. 3).

Stand-in choices (docs/marionet.md):

- **in-place classes** are data-driven: a class is in place when the median, over its training
  clips, of the clip's net root ground-plane displacement (first to last frame) is below
  ``in_place_threshold_m`` (0.3 m), unless ``in_place_classes`` lists them explicitly
  (:func:`in_place_classes`);
- **same-clip next tag**: the successor is defined like a motion graph: the label of the
  *other* clip (from ``next_tag_pool``, the training clips by default) whose first pose is
  nearest to this item's last action pose, both poses heading- and position-normalised (joints
  relative to the root, rotated to face +Z), Euclidean distance on the flattened (J·3) joint
  vector; deterministic (ties → lowest index).

Units: metres, radians, frames at the ClipSet's fps.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from repro.data.action_items import ActionItems, ItemsConfig, pad_last
from repro.data.clipset import TRAIN
from repro.data.item_sources import ItemSource
from repro.errors import ConfigError, DataError
from repro.motion.canon import marionette_normalize
from repro.motion.heading import body_heading
from repro.motion.motion import Motion
from repro.motion.rotations import quat_to_6d, quat_to_matrix

__all__ = ["CONTEXT_VERSION", "ActionSource", "sequence_items", "build_items",
           "items_from_windows", "in_place_classes", "next_tags"]

#: Bumped when sequence items are built differently (enters :meth:`ActionSource.describe`).
CONTEXT_VERSION = 2


class ActionSource(ItemSource):
    """How Neural Marionette's items are made from a data set (module docstring; every field
    enters content keys)."""

    VERSION_FIELD: ClassVar[str] = "context_version"
    VERSION: ClassVar[int] = CONTEXT_VERSION

    context: Literal["sequence", "same_clip"] = "sequence"
    fps: float = 30.0
    split: Literal["marionette", "dataset"] = "marionette"
    split_seed: int = 0
    test_fraction: float = Field(0.2, gt=0, lt=1)
    test_cap_per_class: int = Field(100, ge=1)
    n_init: int = Field(6, ge=1)
    max_frames: int = Field(120, ge=1)
    compose: dict = Field(default_factory=dict)   # repro.data.sequences.ComposeConfig overrides

    @model_validator(mode="after")
    def _compose_is_valid(self):
        # Since COMPOSE_VERSION 2 a transition is the previous clip's own recorded continuation
        # (carried smoothly onto the next segment's first frame), never a synthetic ramp, so
        # P^ini holds the previous recording's motion whatever blend_frames is (issue 26; the
        # card's junction numbers say how close to recorded motion it stays).
        if self.context == "sequence":
            from repro.data.sequences import ComposeConfig

            ComposeConfig.resolve(self.compose)  # a bad override: one ConfigError line
        return self

    def describe_fields(self) -> dict:
        """The fields, the composition fully resolved (``same_clip``: no composition)."""
        d = self.model_dump(mode="json")
        if self.context == "sequence":
            from repro.data.sequences import ComposeConfig

            d["compose"] = ComposeConfig(**self.compose).model_dump(mode="json")
        else:
            d.pop("compose")
        return d

    # -- the pieces -------------------------------------------------------------------------
    def items_config(self) -> ItemsConfig:
        return ItemsConfig(n_init=self.n_init, max_frames=self.max_frames)

    def split_clipset(self, clipset):
        """``clipset`` with the protocol's train/test split (Marionette's per class, §5.1.1,
        or the data set's stored one); the frame rate must be ``fps`` (supp. §3)."""
        if abs(float(clipset.fps) - self.fps) > 1e-6:
            raise DataError(f"Neural Marionette's protocols: the protocol expects {self.fps:g} "
                            f"fps (supp. §3); data set {clipset.name!r} is at {clipset.fps:g} fps")
        if self.split == "dataset":
            return clipset
        from repro.data.splits import marionette_clipset

        return marionette_clipset(clipset, seed=self.split_seed, fraction=self.test_fraction,
                                  cap=self.test_cap_per_class)

    def sequences(self, clipset):
        """The composed sequences of the split clip set (in-process cached)."""
        from repro.data.sequences import ComposeConfig, sequences_for

        return sequences_for(self.split_clipset(clipset), ComposeConfig(**self.compose))

    def items(self, clipset, split: int) -> ActionItems:
        """Every item of ``split`` (TRAIN or TEST), in-process cached."""
        def build():
            if self.context == "same_clip":
                return build_items(self.split_clipset(clipset), split, self.items_config())
            return sequence_items(self.sequences(clipset), split, self.items_config())

        return self.cached_build("items", clipset, build, split=int(split))

    def train_items(self, clipset) -> ActionItems:
        return self.items(clipset, TRAIN)


def sequence_items(seqs, split: int | None, config=None, *,
                   dtype: torch.dtype | None = None):
    """One item per ``ROLE_ACTION`` segment of the sequences of ``split`` (module docstring).

    ``P^ini``: :meth:`SequenceSet.context` (``n_init`` frames before the segment, in the source
    clip's frame); the action: the source clip from the segment's cut, ``T = min(length,
    max_frames)`` frames; the next tag: the following segment's label; ``clip_index``: the source
    clip; ``segment_index``: the segment.  Everything Marionette-normalised at ``P₋₁`` as in
    :func:`build_items`.  ``dtype``: None is float32."""
    import torch

    from repro.data.sequences import ROLE_ACTION

    dtype = torch.float32 if dtype is None else dtype
    config = ItemsConfig.resolve(config)
    K = config.n_init
    clips = seqs.clips
    segs = seqs.segments(split=split, role=ROLE_ACTION)
    lens = seqs.seg_length[segs].astype(np.int64)
    # an action needs min_frames frames and K frames before it in its sequence
    keep = (lens >= config.min_frames) & (seqs.seg_start[segs] >= K)
    n_skipped = int((~keep).sum())
    segs, lens = segs[keep], lens[keep]
    if segs.size == 0:
        raise DataError(f"sequences {seqs.name!r}: no action segment has the {config.min_frames} "
                        "frames an item needs")
    T = np.minimum(lens, config.max_frames)
    Tmax = int(T.max())
    N, J = segs.size, clips.skeleton.n_joints
    rot = np.empty((N, K + Tmax, J, 4), np.float32)
    root = np.empty((N, K + Tmax, 3), np.float32)
    src = seqs.seg_clip[segs].astype(np.int64)
    cut = seqs.seg_clip_start[segs].astype(np.int64)
    for i, a in enumerate(segs.tolist()):
        r, d = seqs.context(a, K)
        rot[i, :K], root[i, :K] = r, d
        rows = clips.starts[src[i]] + cut[i] + np.minimum(np.arange(Tmax), T[i] - 1)
        rot[i, K:], root[i, K:] = clips.rotations[rows], clips.root[rows]
    whole = Motion(torch.from_numpy(root).to(dtype), quat_to_6d(torch.from_numpy(rot).to(dtype)),
                   clips.skeleton, clips.fps)
    nxt = seqs.next_labels(segs).astype(np.int64)
    if (nxt < 0).any():
        raise DataError(f"sequences {seqs.name!r}: an action segment has no successor")
    return items_from_windows(whole, T, seqs.seg_label[segs], nxt, clips, config,
                              clip_index=src, segment_index=segs, source=str(seqs.fingerprint),
                              n_skipped=n_skipped)


def build_items(clips, split: int | None = None, config: ItemsConfig | dict | None = None,
                *, dtype: torch.dtype | None = None) -> ActionItems:
    """Single-action items from the clips of ``clips`` in ``split`` (TRAIN, TEST or None for
    all), one per clip long enough for ``n_init + min_frames`` frames (others are skipped and
    counted in ``n_skipped``); the ``same_clip`` context (module docstring).  ``dtype``: None
    is float32."""
    config = ItemsConfig.resolve(config)
    K = config.n_init
    idx = clips.indices(split=split)
    lens = clips.lengths[idx].astype(np.int64)
    keep = lens >= K + config.min_frames
    n_skipped = int((~keep).sum())
    idx, lens = idx[keep], lens[keep]
    if idx.size == 0:
        raise DataError(f"ClipSet {clips.name!r}: no clip has the {K} + {config.min_frames} "
                        "frames an item needs")
    T = np.minimum(lens - K, config.max_frames)
    Tmax = int(T.max())
    whole = Motion.from_clipset(clips, idx, 0, K + Tmax, pad=True, dtype=dtype)
    nxt, _ = next_tags(clips, idx, K + T - 1, config)
    return items_from_windows(whole, T, clips.labels[idx], nxt, clips, config, clip_index=idx,
                              source=str(clips.fingerprint), n_skipped=n_skipped)


def items_from_windows(whole: Motion, lengths, labels, next_labels, clips, config: ItemsConfig,
                       *, clip_index, segment_index=None, source: str,
                       n_skipped: int = 0) -> ActionItems:
    """Items from world-frame windows ``whole`` (N, K + T_max): the first ``K = n_init`` frames
    are the initial motion, the next ``lengths`` (N,) frames the action (frames past it are
    padded with its last one); Marionette-normalised at ``P₋₁``; trajectory and in-place
    classes as in the module docstring.  The one tail of :func:`build_items` and of
    :func:`sequence_items`."""
    import torch

    K = config.n_init
    Tmax = whole.n_frames - K
    lengths = torch.as_tensor(np.asarray(lengths, np.int64))
    norm, canon = marionette_normalize(whole, anchor=K - 1, heading_axis=config.heading_axis,
                                       translation=config.translation)
    initial = norm.slice_time(0, K)
    act = norm.slice_time(K, K + Tmax)
    action = act.replace(root=pad_last(act.root, lengths), rot6d=pad_last(act.rot6d, lengths))

    names = tuple(clips.label_names)
    inplace_names = in_place_classes(clips, config)
    inplace_ids = [names.index(n) for n in inplace_names]
    labels = np.asarray(labels, np.int64)
    in_place = torch.from_numpy(np.isin(labels, inplace_ids))
    traj = action.root[..., [0, 2]].clone()
    traj[in_place] = 0.0
    clip_index = np.asarray(clip_index, np.int64)
    return ActionItems(
        initial=initial, action=action, lengths=lengths, labels=torch.from_numpy(labels),
        next_labels=torch.from_numpy(np.asarray(next_labels, np.int64)), trajectory=traj,
        in_place=in_place, canon=canon, label_names=names,
        styles=torch.from_numpy(clips.styles[clip_index].astype(np.int64)),
        clip_index=torch.from_numpy(clip_index),
        segment_index=None if segment_index is None else
        torch.from_numpy(np.asarray(segment_index, np.int64)),
        in_place_classes=inplace_names, config=config, source=source, n_skipped=n_skipped)


def in_place_classes(clips, config: ItemsConfig | None = None) -> tuple[str, ...]:
    """Names of the in-place classes (module docstring), from ``config.in_place_classes`` or
    the median net ground-plane root displacement of each class's training clips."""
    config = config or ItemsConfig()
    names = tuple(clips.label_names)
    if config.in_place_classes is not None:
        unknown = [c for c in config.in_place_classes if c not in names]
        if unknown:
            raise ConfigError(f"items config: in_place_classes {unknown} are not classes of "
                              f"{clips.name!r} ({', '.join(names)})")
        return tuple(c for c in names if c in config.in_place_classes)
    out = []
    for lab, name in enumerate(names):
        idx = clips.indices(split=TRAIN, label=lab)
        if idx.size == 0:
            idx = clips.indices(label=lab)
        if idx.size == 0:
            continue
        first = clips.root[clips.starts[idx]][:, [0, 2]].astype(np.float64)
        last = clips.root[clips.starts[idx] + clips.lengths[idx] - 1][:, [0, 2]].astype(np.float64)
        if float(np.median(np.linalg.norm(last - first, axis=1))) < config.in_place_threshold_m:
            out.append(name)
    return tuple(out)


def next_tags(clips, item_clips: np.ndarray, end_frames: np.ndarray,
              config: ItemsConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Motion-graph successors (module docstring): for each clip ``item_clips[i]`` whose action
    ends at its frame ``end_frames[i]``, the (label, clip index) of the nearest other clip's
    first pose.  Candidates: training clips (``next_tag_pool="train"``) or all clips."""
    from scipy.spatial import cKDTree

    config = config or ItemsConfig()
    pool = clips.indices(split=TRAIN) if config.next_tag_pool == "train" else clips.indices()
    if pool.size < 2:
        pool = clips.indices()
    if pool.size < 2:
        raise DataError(f"ClipSet {clips.name!r}: a next tag needs at least two clips")
    cand = _pose_features(clips, clips.starts[pool].astype(np.int64), config.heading_axis)
    query = _pose_features(clips, (clips.starts[item_clips] + end_frames).astype(np.int64),
                           config.heading_axis)
    tree = cKDTree(cand)
    _, nn = tree.query(query, k=2)
    first = pool[nn[:, 0]]
    pick = np.where(first == item_clips, pool[nn[:, 1]], first)
    return clips.labels[pick].astype(np.int64), pick.astype(np.int64)


def _pose_features(clips, rows: np.ndarray, axis: str) -> np.ndarray:
    """Heading- and position-normalised joint positions (n, J·3) of packed frame ``rows``."""
    import torch

    q = torch.from_numpy(np.ascontiguousarray(clips.rotations[rows])).to(torch.float64)
    heading = body_heading(clips.skeleton, quat_to_matrix(q), axis=axis).numpy()
    j = np.asarray(clips.joints[rows], dtype=np.float64) - np.asarray(clips.root[rows],
                                                                      dtype=np.float64)[:, None]
    c, s = np.cos(-heading)[:, None], np.sin(-heading)[:, None]
    x, z = j[..., 0], j[..., 2]
    out = np.stack([c * x + s * z, j[..., 1], -s * x + c * z], axis=-1)  # Ry(-heading)
    return out.reshape(len(rows), -1)
