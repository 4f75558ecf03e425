"""Single-action items: what a generator is conditioned on and trained against.

One item per clip of a :class:`~repro.data.clipset.ClipSet` (Neural Marionette Sec. 4.1-4.2,
supp. Sec. 3):

- **initial motion** ``P^ini``: the first ``K = n_init`` (6) frames of the clip;
- **action**: the following ``T`` frames, ``T = min(len − K, max_frames)`` (the duration);
- **tag** ``A^curr``: the clip's class; **next tag** ``A^next``: see below;
- **trajectory** ``U`` (supp. Sec. 1.4, F: frames → R²): the action's root ground-plane path
  ``(x, z)`` per frame, in the normalised frame; all zeros for in-place classes (Sec. 4.2.3).

Everything is expressed in the **Marionette-normalised frame** of the item (Alg. 1 / Eq. 3):
rotated by the inverse heading of the last initial frame ``P₋₁`` and moved so that its root is
at the origin (:func:`repro.motion.canon.marionette_normalize`; heading from the body's forward
axis, so ``P₋₁`` faces +Z).  ``ActionItems.canon`` holds the per-item transform and
:meth:`ActionItems.to_world` undoes it exactly (Eq. 5), which is how generators return motions
in the original world frame.

Stand-in choices (docs/marionet.md):

- **in-place classes** are data-driven: a class is in place when the median, over its training
  clips, of the clip's net root ground-plane displacement (first to last frame) is below
  ``in_place_threshold_m`` (0.3 m), unless ``in_place_classes`` lists them explicitly;
- **next tag**: the stand-in's clips are single actions with no successor, so the successor
  is defined like a motion graph: the label of the *other* clip (from ``next_tag_pool``, the
  training clips by default) whose first pose is nearest to this item's last action pose, both
  poses heading- and position-normalised (joints relative to the root, rotated to face +Z),
  Euclidean distance on the flattened (J·3) joint vector; deterministic (ties → lowest index).

Units: metres, radians, frames at the ClipSet's fps.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Sequence

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, field_validator

from repro.config_errors import resolve_config
from repro.errors import ConfigError, DataError
from repro.keys import content_key
from repro.motion.canon import CanonParams, marionette_normalize, uncanonicalize
from repro.motion.heading import body_heading
from repro.motion.motion import Motion
from repro.motion.rotations import quat_to_matrix
from repro.motion.skeleton import Skeleton, forward_kinematics

#: Bumped when the construction of items changes (enters ``ActionItems.key``).
ITEMS_VERSION = 1


class ItemsConfig(BaseModel):
    """How items are cut from clips (every field enters the items' key)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    n_init: int = 6                                  # K initial frames (supp. Sec. 3)
    max_frames: int = 120                            # cap on the duration T (frames)
    min_frames: int = 1                              # clips with fewer action frames are skipped
    translation: Literal["xyz", "xz"] = "xyz"        # Alg. 1's D: full root position or ground part
    heading_axis: Literal["forward", "lateral"] = "forward"
    in_place_classes: tuple[str, ...] | None = None  # explicit list; None: data-driven
    in_place_threshold_m: float = 0.3                # median net ground displacement below = in place
    next_tag_pool: Literal["train", "all"] = "train"

    @field_validator("n_init", "max_frames", "min_frames")
    @classmethod
    def _positive(cls, v: int) -> int:
        if v < 1:
            raise ValueError("must be >= 1")
        return v

    @classmethod
    def resolve(cls, overrides=None) -> "ItemsConfig":
        """``overrides`` (None, an ItemsConfig or a mapping) over the defaults; a ConfigError
        names the bad field (:func:`repro.config_errors.resolve_config`)."""
        return resolve_config(cls, overrides, "items config: field")


@dataclass(frozen=True, eq=False)
class ActionItems:
    """A batch of single-action items (module docstring), padded to ``max(lengths)`` frames.

    ``initial`` (N, K) and ``action`` (N, T_max) are :class:`Motion` batches in each item's
    normalised frame; ``action`` past an item's length repeats its last frame.  ``trajectory``
    (N, T_max, 2) metres; ``lengths`` (N,) action frames; ``labels``/``next_labels``/``styles``
    (N,) int64; ``clip_index`` (N,) rows of the source ClipSet (-1 when not from one);
    ``segment_index`` (N,) the sequence segment each item is (items from composed sequences,
    :mod:`repro.data.contexts`; None otherwise);
    ``canon``: the normalisation (world → item frame).
    """

    initial: Motion
    action: Motion
    lengths: torch.Tensor
    labels: torch.Tensor
    next_labels: torch.Tensor
    trajectory: torch.Tensor
    in_place: torch.Tensor
    canon: CanonParams
    label_names: tuple[str, ...]
    styles: torch.Tensor | None = None
    clip_index: torch.Tensor | None = None
    segment_index: torch.Tensor | None = None
    in_place_classes: tuple[str, ...] = ()
    config: ItemsConfig = field(default_factory=ItemsConfig)
    source: str = ""
    n_skipped: int = 0

    def __post_init__(self) -> None:
        N = self.initial.batch_size
        if self.action.batch_size != N:
            raise ValueError("initial and action differ in batch size")
        if N and int(self.lengths.max()) > self.action.n_frames:
            raise ValueError("a length exceeds the padded action")
        if self.trajectory.shape != (N, self.action.n_frames, 2):
            raise ValueError(f"trajectory must be ({N}, {self.action.n_frames}, 2)")

    # -- basics --------------------------------------------------------------------------------
    def __len__(self) -> int:
        return self.initial.batch_size

    @property
    def skeleton(self) -> Skeleton:
        return self.initial.skeleton

    @property
    def fps(self) -> float:
        return self.initial.fps

    @property
    def n_classes(self) -> int:
        return len(self.label_names)

    @property
    def n_init(self) -> int:
        return self.initial.n_frames

    def key(self) -> str:
        """Content key: source fingerprint, construction config and version, the items chosen
        and, for items not cut from a ClipSet, a hash of their tensors."""
        rec = {"version": ITEMS_VERSION, "source": self.source,
               "config": self.config.model_dump(mode="json"),
               "clips": None if self.clip_index is None else self.clip_index.tolist(),
               "lengths": self.lengths.tolist(), "labels": self.labels.tolist(),
               "next_labels": self.next_labels.tolist()}
        if self.segment_index is not None:
            rec["segments"] = self.segment_index.tolist()
        if self.clip_index is None or not self.source:
            import hashlib

            h = hashlib.sha256()
            for t in (self.initial.root, self.initial.rot6d, self.action.root, self.action.rot6d,
                      self.trajectory, self.canon.rotation, self.canon.origin):
                h.update(t.detach().cpu().contiguous().numpy().tobytes())
            rec["tensors"] = h.hexdigest()
        return content_key(rec)

    def subset(self, index) -> "ActionItems":
        """Items ``index`` (a sequence/tensor of positions), padding cropped to their lengths."""
        idx = torch.as_tensor(index, dtype=torch.long).reshape(-1)
        T = int(self.lengths[idx].max()) if idx.numel() else 1
        opt = lambda t: None if t is None else t[idx]  # noqa: E731
        return ActionItems(
            initial=self.initial.select(idx), action=self.action.select(idx).slice_time(0, T),
            lengths=self.lengths[idx], labels=self.labels[idx], next_labels=self.next_labels[idx],
            trajectory=self.trajectory[idx, :T], in_place=self.in_place[idx],
            canon=self.canon.select(idx), label_names=self.label_names, styles=opt(self.styles),
            clip_index=opt(self.clip_index), segment_index=opt(self.segment_index),
            in_place_classes=self.in_place_classes,
            config=self.config, source=self.source, n_skipped=self.n_skipped)

    # -- frames ----------------------------------------------------------------------------
    def valid_mask(self) -> torch.Tensor:
        """(N, T_max) bool: True on an item's action frames."""
        T = self.action.n_frames
        return torch.arange(T)[None, :] < self.lengths[:, None]

    def to_world(self, motion: Motion) -> Motion:
        """Undo the normalisation of each item on a motion batch (N, T, ...) expressed in the
        items' frames (Eq. 5: ``P̂ = R_z·P̃ + D``)."""
        return uncanonicalize(motion, self.canon)

    def real(self) -> "GeneratedItems":
        """The ground-truth actions in the world frame, shaped like a generator's output."""
        return GeneratedItems(self.to_world(self.action), self.lengths.clone(), self.labels.clone())

    def initial_world(self) -> Motion:
        return self.to_world(self.initial)


@dataclass(frozen=True, eq=False)
class GeneratedItems:
    """Generated (or real) actions: ``motion`` (N, T_max) in the world frame, ``lengths`` (N,)
    valid frames per item (frames past it repeat the last valid frame), ``labels`` (N,)."""

    motion: Motion
    lengths: torch.Tensor
    labels: torch.Tensor

    def __len__(self) -> int:
        return self.motion.batch_size

    @property
    def root(self) -> torch.Tensor:
        return self.motion.root

    @property
    def rot6d(self) -> torch.Tensor:
        return self.motion.rot6d

    def joints(self) -> torch.Tensor:
        """(N, T_max, J, 3) world joint positions, metres."""
        return self.motion.joints()

    def valid_mask(self) -> torch.Tensor:
        return torch.arange(self.motion.n_frames)[None, :] < self.lengths[:, None]


# ---------------------------------------------------------------------------------------------
# construction


def pad_last(x: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
    """Repeat each item's last valid frame (dim 1) past its length."""
    T = x.shape[1]
    t = torch.minimum(torch.arange(T, device=lengths.device)[None, :], (lengths - 1).clamp(min=0)[:, None])
    return x[torch.arange(x.shape[0], device=x.device)[:, None], t]


def _pose_features(clips, rows: np.ndarray, axis: str) -> np.ndarray:
    """Heading- and position-normalised joint positions (n, J·3) of packed frame ``rows``."""
    q = torch.from_numpy(np.ascontiguousarray(clips.rotations[rows])).to(torch.float64)
    heading = body_heading(clips.skeleton, quat_to_matrix(q), axis=axis).numpy()
    j = np.asarray(clips.joints[rows], dtype=np.float64) - np.asarray(clips.root[rows],
                                                                      dtype=np.float64)[:, None]
    c, s = np.cos(-heading)[:, None], np.sin(-heading)[:, None]
    x, z = j[..., 0], j[..., 2]
    out = np.stack([c * x + s * z, j[..., 1], -s * x + c * z], axis=-1)  # Ry(-heading)
    return out.reshape(len(rows), -1)


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
    from repro.data.clipset import TRAIN

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

    from repro.data.clipset import TRAIN

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


def build_items(clips, split: int | None = None, config: ItemsConfig | dict | None = None,
                *, dtype: torch.dtype = torch.float32) -> ActionItems:
    """Single-action items from the clips of ``clips`` in ``split`` (TRAIN, TEST or None for
    all), one per clip long enough for ``n_init + min_frames`` frames (others are skipped and
    counted in ``n_skipped``)."""
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
    :func:`repro.data.contexts.sequence_items`."""
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


def condition_items(initial_world: Motion, labels: Sequence[int], next_labels: Sequence[int],
                    lengths: Sequence[int], label_names: Sequence[str], *,
                    trajectory: torch.Tensor | None = None, in_place: Sequence[bool] | None = None,
                    config: ItemsConfig | dict | None = None) -> ActionItems:
    """Condition items from arbitrary initial motions in the world frame (e.g. the last K
    generated frames of the previous action in a multi-action chain, Alg. 1).

    ``initial_world`` (N, K); ``trajectory`` (N, max(lengths), 2) in each item's normalised
    frame (zeros when None); the ``action`` of such items is a placeholder holding the
    normalised last initial pose (they carry conditions only, not targets).
    """
    config = ItemsConfig.resolve(config)
    N, K = initial_world.batch_size, initial_world.n_frames
    lengths = torch.as_tensor(lengths, dtype=torch.long).reshape(N)
    if N == 0 or int(lengths.min()) < 1:
        raise ValueError("condition_items needs at least one item and lengths >= 1")
    Tmax = int(lengths.max())
    norm, canon = marionette_normalize(initial_world, anchor=-1, heading_axis=config.heading_axis,
                                       translation=config.translation)
    last = norm.slice_time(K - 1, K)
    action = last.replace(root=last.root.expand(N, Tmax, 3).clone(),
                          rot6d=last.rot6d.expand(N, Tmax, *last.rot6d.shape[2:]).clone())
    if trajectory is None:
        trajectory = torch.zeros(N, Tmax, 2, dtype=norm.dtype)
    trajectory = torch.as_tensor(trajectory, dtype=norm.dtype)
    if trajectory.shape != (N, Tmax, 2):
        raise ValueError(f"trajectory must be ({N}, {Tmax}, 2), got {tuple(trajectory.shape)}")
    ip = torch.zeros(N, dtype=torch.bool) if in_place is None else \
        torch.as_tensor(in_place, dtype=torch.bool).reshape(N)
    return ActionItems(
        initial=norm, action=action, lengths=lengths,
        labels=torch.as_tensor(labels, dtype=torch.long).reshape(N),
        next_labels=torch.as_tensor(next_labels, dtype=torch.long).reshape(N),
        trajectory=trajectory, in_place=ip, canon=canon, label_names=tuple(label_names),
        config=config)


def local_joints(skeleton: Skeleton, rotmats: torch.Tensor) -> torch.Tensor:
    """Root-relative joint positions (..., J, 3) (FK with zero root translation; the root's
    rotation is kept)."""
    zero = torch.zeros(rotmats.shape[:-3] + (3,), dtype=rotmats.dtype, device=rotmats.device)
    return forward_kinematics(skeleton, rotmats, zero)
