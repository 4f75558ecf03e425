"""ODMO's training data: fixed-length xyz windows of a clip pool, drawn afresh every epoch.

ODMO (MM'22) §3.1, §4.1 and protocols.md §3.1, §3.9 (the reference loaders
``dataloader_samplestart_rotate2xz[_pairwise].py``): a model sees windows of ``T`` frames of
joint positions, the first frame's root at the origin, no rotation; every "epoch" is one
class-balanced draw (ODMO's WeightedRandomSampler, class weight ∝ 1/count) of
``windows_per_epoch`` windows with random starts (:mod:`repro.data.windows`).  The contrastive
encoder trains on *pairs*: the partner has the anchor's class with probability 0.5
(``same_class_p``), otherwise another class.  A same-class partner is another *clip* of the
class, never the anchor's own (the reference's pairwise loaders draw it from another sample;
a class with a single clip in the pool — e.g. a small validation hold-out — pairs the anchor
with another random window of its own clip, the only same-class choice).

:class:`WindowSource` (an :class:`repro.data.item_sources.ItemSource`) describes how the pool
is made from a prepared clip set (any clip set: it only reads ``joints``, ``lengths``,
``labels``, ``styles`` and the data set's stored ``split``); its
:meth:`~WindowSource.describe` enters the training key of every method trained on windows
(``builder = "odmo_windows"``, :func:`repro.engine.steps.training_items`), so every ODMO
protocol (Tables 1-4, S1) with equal fields shares one model.  :class:`WindowItems` is the
pool itself: the training clips, never a test clip.

Choices recorded here (docs/odmo.md):

- **Partner class.**  The reference draws the different-class partner uniformly over classes
  for MoCap and uniformly over samples for HumanAct12/UESTC; we draw it uniformly over the
  *other classes* then uniformly over that class's clips (``partner = "class_uniform"``),
  or uniformly over the other classes' clips (``"sample_uniform"``).
- **Fixed windows for rotation methods.**  ACTOR and Action2Motion train on
  :class:`~repro.data.action_items.ActionItems` (a fixed item set).  :meth:`WindowItems.as_action_items`
  cuts ``action_windows_per_clip`` windows per pool clip at seeded random starts (the same
  distribution as an epoch's draw), in the same frame: the window's first-frame root at the
  origin, no rotation (``canon`` = a pure translation), so their samples land in ODMO's frame.
  Their ``initial`` motion is one frame, the window's first (read only by methods that use an
  initial pose; the ODMO rows switch it off).
- **Padding.**  A clip shorter than the window is padded with its last frame
  (:mod:`repro.data.windows`); :func:`padded_frames` gives each drawn window's count of such
  frames (Table 3's style columns leave out windows padded beyond a stated share).
- ``scale`` multiplies positions (ODMO divides CMU MoCap by 20, a unit change of that data;
  the stand-in is in metres, so 1).  ``y_weight`` is ODMO's per-data-set weight of the
  vertical axis in the trajectory and motion losses (``param_*.py``: 5 HumanAct12/UESTC,
  1 MoCap); it lives here because it belongs to the data set, not to a table row.

Units: metres × ``scale``, frames at the clip set's fps.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from repro.data.action_items import ActionItems, ItemsConfig
from repro.data.clip_draws import balanced_clips
from repro.data.clipset import TEST, TRAIN
from repro.data.item_sources import ItemSet, ItemSource
from repro.data.windows import WindowBatch, cut_windows, window_starts
from repro.errors import ConfigError, DataError
from repro.keys import content_key
from repro.motion.canon import CanonParams, root_to_origin
from repro.motion.motion import Motion
from repro.seeding import numpy_rng

__all__ = ["WindowSource", "WindowItems", "WINDOWS_VERSION", "padded_frames"]

#: bumped when the construction of windows changes (enters ``describe()``); 2: a same-class
#: partner is never the anchor's own clip (issue 27)
WINDOWS_VERSION = 2


def padded_frames(batch: WindowBatch) -> np.ndarray:
    """(N,) int64: frames of each window that repeat its clip's last frame (window − valid)."""
    return (int(batch.joints.shape[1]) - np.asarray(batch.valid, dtype=np.int64)).astype(np.int64)


class WindowSource(ItemSource):
    """How ODMO's window pool is made from a data set (module docstring).  Every field enters
    :meth:`describe` and so the content keys of the models trained on it."""

    VERSION: ClassVar[int] = WINDOWS_VERSION
    VERSION_MAY_BE_ABSENT: ClassVar[bool] = False  # every window description carries it
    ITEM_KIND: ClassVar[str] = "windows"

    builder: Literal["odmo_windows"] = "odmo_windows"  # the engine dispatches on this
    window: int = Field(60, ge=2)            # T: 60 HumanAct12 / UESTC, 100 MoCap (§3.1)
    split: Literal["dataset"] = "dataset"    # the data set's stored train / test split
    include_last: bool = False               # the reference's exclusive start bound (§3.1)
    scale: float = Field(1.0, gt=0)          # position factor (MoCap: 1/20; metres: 1)
    y_weight: float = Field(5.0, gt=0)       # ODMO's y-axis loss weight for this data set
    partner: Literal["class_uniform", "sample_uniform"] = "class_uniform"
    same_class_p: float = Field(0.5, ge=0, le=1)  # P(partner has the anchor's class)
    action_windows_per_clip: int = Field(4, ge=1)  # fixed windows per clip (ACTOR, A2M)
    seed: int = 0                            # seeds the fixed windows

    def split_clipset(self, clipset):
        """The clip set with the split the windows use (the data set's own)."""
        return clipset

    def pool(self, clipset, split: int) -> "WindowItems":
        """The clips of ``split`` (TRAIN or TEST) as a window pool."""
        if split not in (TRAIN, TEST):
            raise ValueError(f"split must be TRAIN or TEST, got {split!r}")
        idx = clipset.indices(split=split)
        if idx.size == 0:
            raise DataError(f"data set {clipset.name!r}: no {'train' if split == TRAIN else 'test'}"
                            " clip for ODMO's windows")
        return WindowItems(clipset, idx, self)

    def train_items(self, clipset) -> "WindowItems":
        """The training pool: every clip of the train split (never a test clip)."""
        return self.pool(clipset, TRAIN)


@dataclass(frozen=True, eq=False)
class WindowItems(ItemSet):
    """A pool of clips to cut ODMO windows from (module docstring).

    ``indices`` (N,) clip rows of ``clipset``; ``labels``, ``styles``, ``clip_index`` (N,) int64
    tensors (one per pool clip; ``clip_index`` is what :func:`repro.train.validation.holdout`
    groups by).  Draws return :class:`~repro.data.windows.WindowBatch` es (positions × scale)."""

    clipset: object
    indices: np.ndarray
    source: WindowSource

    def __post_init__(self) -> None:
        idx = np.asarray(self.indices, dtype=np.int64).reshape(-1)
        object.__setattr__(self, "indices", idx)

    # -- basics ----------------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self.indices.size)

    @property
    def window(self) -> int:
        return self.source.window

    @property
    def y_weight(self) -> float:
        return self.source.y_weight

    def frames_basis(self):
        return self.clipset

    @property
    def n_joints(self) -> int:
        return self.clipset.skeleton.n_joints

    @property
    def label_names(self) -> tuple[str, ...]:
        return tuple(self.clipset.label_names)

    @property
    def style_names(self) -> tuple[str, ...]:
        return tuple(self.clipset.style_names)

    @property
    def labels(self) -> torch.Tensor:
        import torch

        return torch.from_numpy(self.clipset.labels[self.indices].astype(np.int64))

    @property
    def styles(self) -> torch.Tensor:
        import torch

        return torch.from_numpy(self.clipset.styles[self.indices].astype(np.int64))

    @property
    def clip_index(self) -> torch.Tensor:
        import torch

        return torch.from_numpy(self.indices.copy())

    def key(self) -> str:
        """Content key of the pool: source, data fingerprint, clip rows."""
        return content_key({"windows": self.source.describe(),
                            "data": str(self.clipset.fingerprint),
                            "clips": content_key(self.indices.tolist())})

    def subset(self, index) -> "WindowItems":
        pos = np.asarray(index, dtype=np.int64).reshape(-1)
        return WindowItems(self.clipset, self.indices[pos], self.source)

    def classes_present(self) -> np.ndarray:
        return np.unique(self.clipset.labels[self.indices])

    # -- windows ---------------------------------------------------------------------------
    def cut(self, clips, starts) -> WindowBatch:
        """Windows of the given clip rows and starts (positions × ``scale``)."""
        b = cut_windows(self.clipset, clips, starts, self.window)
        if self.source.scale != 1.0:
            s = np.float32(self.source.scale)
            b = WindowBatch(joints=b.joints * s, origin=b.origin * s, indices=b.indices,
                            starts=b.starts, valid=b.valid, labels=b.labels)
        return b

    def random_cut(self, clips, rng: np.random.Generator) -> WindowBatch:
        """One window per clip row in ``clips`` at a random start (§3.1)."""
        clips = np.asarray(clips, dtype=np.int64)
        starts = window_starts(self.clipset.lengths[clips], self.window, rng,
                               include_last=self.source.include_last)
        return self.cut(clips, starts)

    def balanced_clips(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` clip rows, a class uniformly then a clip of it uniformly (with replacement;
        :func:`repro.data.clip_draws.balanced_clips`' ``"class_first"`` recipe)."""
        return balanced_clips(self.clipset, self.indices, n, rng, recipe="class_first")

    def draw(self, n: int, rng: np.random.Generator) -> WindowBatch:
        """One epoch's class-balanced draw of ``n`` windows."""
        return self.random_cut(self.balanced_clips(n, rng), rng)

    def partner_clips(self, anchors: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """A partner clip per anchor clip row: same class w.p. ``same_class_p``, else another
        class (``partner`` rule); a class with no other class present pairs with itself.  A
        same-class partner is another clip of the class, never the anchor's own, unless the
        class has no other clip in this pool (module docstring)."""
        anchors = np.asarray(anchors, dtype=np.int64)
        labels = self.clipset.labels
        pool_labels = labels[self.indices]
        classes = np.unique(pool_labels)
        same = rng.random(anchors.size) < self.source.same_class_p
        out = np.empty_like(anchors)
        for i, a in enumerate(anchors):
            c = labels[a]
            if same[i] or classes.size < 2:
                pool = self.indices[(pool_labels == c) & (self.indices != a)]
                if pool.size == 0:  # the class's only clip in this pool: another window of it
                    pool = np.array([a], dtype=np.int64)
            elif self.source.partner == "class_uniform":
                others = classes[classes != c]
                pool = self.indices[pool_labels == others[rng.integers(0, others.size)]]
            else:
                pool = self.indices[pool_labels != c]
            out[i] = pool[rng.integers(0, pool.size)]
        return out

    def draw_pairs(self, n: int, rng: np.random.Generator) -> tuple[WindowBatch, WindowBatch]:
        """``n`` (anchor, partner) windows: anchors class-balanced, partners by
        :meth:`partner_clips` (ODMO's pairwise loader)."""
        a = self.balanced_clips(n, rng)
        p = self.partner_clips(a, rng)
        return self.random_cut(a, rng), self.random_cut(p, rng)

    def fixed_windows(self) -> WindowBatch:
        """``action_windows_per_clip`` windows per pool clip at seeded random starts (the
        fixed set rotation-based methods train on), clip-major."""
        k = self.source.action_windows_per_clip
        clips = np.repeat(self.indices, k)
        rng = numpy_rng(self.source.seed, "odmo_windows", "fixed")
        return self.random_cut(clips, rng)

    def as_action_items(self) -> ActionItems:
        """:meth:`fixed_windows` as :class:`~repro.data.action_items.ActionItems` (ACTOR and
        Action2Motion train on them; :meth:`action_items`)."""
        return self.action_items(self.fixed_windows())

    def action_items(self, b: WindowBatch) -> ActionItems:
        """Windows ``b`` as :class:`~repro.data.action_items.ActionItems` (module docstring):
        rotations from the clip set, the window's first-frame root at the origin, no rotation;
        duration ``window`` for all; initial motion = the window's first frame; next tag = the
        item's own tag (unused by these methods)."""
        import torch

        if self.source.scale != 1.0:
            raise ConfigError("windows with scale != 1 have no rotation form (ACTOR, A2M need one)")
        m = Motion.from_clipset(self.clipset, b.indices, b.starts, self.window, pad=True)
        m, canon = root_to_origin(m, 0)
        N, T = m.batch_size, m.n_frames
        labels = torch.from_numpy(b.labels.astype(np.int64))
        return ActionItems(
            initial=m.slice_time(0, 1), action=m, lengths=torch.full((N,), T, dtype=torch.long),
            labels=labels, next_labels=labels.clone(),
            trajectory=m.root[..., [0, 2]].clone(), in_place=torch.zeros(N, dtype=torch.bool),
            canon=canon, label_names=self.label_names,
            styles=torch.from_numpy(self.clipset.styles[b.indices].astype(np.int64)),
            clip_index=torch.from_numpy(b.indices.copy()),
            config=ItemsConfig(n_init=1, max_frames=T), source=self.key())


def label_condition_items(label_names, labels, window: int, skeleton, fps: float,
                          placeholder) -> ActionItems:
    """Label-only condition items for ACTOR / Action2Motion in ODMO's protocols: tag and
    duration ``window`` per item, identity canon (samples come back in the window frame),
    initial motion = ``placeholder`` (a (1, 1) Motion from the *training* pool, never from a
    scored clip; read only by methods that use an initial pose)."""
    import torch

    labels = torch.as_tensor(np.asarray(labels, np.int64))
    N = int(labels.numel())
    init = placeholder.select(torch.zeros(N, dtype=torch.long))
    init = init.replace(root=torch.zeros_like(init.root))
    action = init.replace(root=init.root.expand(N, window, 3).clone(),
                          rot6d=init.rot6d.expand(N, window, *init.rot6d.shape[2:]).clone())
    eye = torch.eye(3, dtype=init.dtype).expand(N, 3, 3).clone()
    canon = CanonParams("root_to_origin", eye, torch.zeros(N, 3, dtype=init.dtype),
                        torch.zeros(N, dtype=torch.long), {"translation": "xyz"})
    return ActionItems(
        initial=init, action=action, lengths=torch.full((N,), int(window), dtype=torch.long),
        labels=labels, next_labels=labels.clone(), trajectory=torch.zeros(N, window, 2),
        in_place=torch.zeros(N, dtype=torch.bool), canon=canon, label_names=tuple(label_names),
        config=ItemsConfig(n_init=1, max_frames=int(window)))
