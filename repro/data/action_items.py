"""Single-action items: what a generator is conditioned on and trained against (data layer).

An item (Neural Marionette §3, Fig. 2; §4.1-4.2; supp. §3) is one action to generate with what
the generator is conditioned on:

- **initial motion** ``P^ini``: ``K = n_init`` (6) frames of motion before the action;
- **action**: the following ``T`` frames, ``T ≤ max_frames`` (the duration);
- **tag** ``A^curr``: the action's class; **next tag** ``A^next``: the class of what follows;
- **trajectory** ``U`` (supp. §1.4, F: frames → R²): the action's root ground-plane path
  ``(x, z)`` per frame, in the normalised frame; all zeros for in-place classes (§4.2.3).

Everything is expressed in the **Marionette-normalised frame** of the item (Alg. 1 / Eq. 3):
rotated by the inverse heading of the last initial frame ``P₋₁`` and moved so that its root is
at the origin (:func:`repro.motion.canon.marionette_normalize`; heading from the body's forward
axis, so ``P₋₁`` faces +Z).  ``ActionItems.canon`` holds the per-item transform and
:meth:`ActionItems.to_world` undoes it exactly (Eq. 5), which is how generators return motions
in the original world frame.

This module holds the containers every single-action family shares: :class:`ItemsConfig` (how
items are cut), :class:`ActionItems`, :class:`GeneratedItems` (a generator's output, or the real
actions shaped like one), :func:`pad_last` (the padding convention: frames past an item's
length repeat its last one) and :func:`condition_items` (conditions from arbitrary initial
motions, e.g. a multi-action chain's last generated frames, Alg. 1).  How items are *made* is
:mod:`repro.data.contexts` (Neural Marionette's, from composed sequences),
:meth:`repro.data.pairs.PairItems.as_action_items` (MultiAct's ``S_c``) and
:meth:`repro.data.odmo_items.WindowItems.action_items` (ODMO's windows).

Units: metres, radians, frames at the ClipSet's fps.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Sequence

from pydantic import BaseModel, ConfigDict, field_validator

from repro.config_errors import resolve_config
from repro.data.item_sources import ItemSet
from repro.keys import content_key
from repro.motion.canon import CanonParams, marionette_normalize, uncanonicalize
from repro.motion.motion import Motion

__all__ = ["ITEMS_VERSION", "ItemsConfig", "ActionItems", "GeneratedItems", "pad_last",
           "condition_items"]

#: Bumped when the construction of items changes (enters ``ActionItems.key``).
ITEMS_VERSION = 1


class ItemsConfig(BaseModel):
    """How items are cut from clips (every field enters the items' key; the in-place classes
    and the same-clip next tag are :mod:`repro.data.contexts`')."""

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
class ActionItems(ItemSet):
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

    def frames_basis(self) -> Motion:
        return self.initial

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
        import torch

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
        import torch

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
        import torch

        return torch.arange(self.motion.n_frames)[None, :] < self.lengths[:, None]


# ---------------------------------------------------------------------------------------------
# padding and conditions


def pad_last(x: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
    """Repeat each item's last valid frame (dim 1) past its length."""
    import torch

    T = x.shape[1]
    t = torch.minimum(torch.arange(T, device=lengths.device)[None, :], (lengths - 1).clamp(min=0)[:, None])
    return x[torch.arange(x.shape[0], device=x.device)[:, None], t]


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
    import torch

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
