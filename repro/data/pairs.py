"""MultiAct's training and test samples ``[S_p, T, S_c]`` from composed sequences (data layer).

MultiAct (AAAI'23, "MACVAE"; protocols.md §4.1) trains and tests on BABEL samples made of a
previous action ``S_p`` (label ``a_p``), a transition ``T`` and the current action ``S_c``
(label ``a_c``), at 20 fps.  The stand-in's sequences come from :mod:`repro.data.sequences`
(composed from real single-action clips), so a sample is two consecutive ``ROLE_ACTION``
segments of one sequence with the composed transition between them.

Containers (this module; the builder is :class:`repro.data.pairs_build.PairSource`):

- :class:`PairItems`: N samples packed in one :class:`~repro.motion.motion.Motion` of
  ``max(l_p + l_t + l_c)`` frames in the **world frame of their sequence**; frames
  ``0 .. l_p−1`` are ``S_p``, ``l_p .. l_p+l_t−1`` are ``T``, then ``l_c`` frames of ``S_c``;
  past ``l_p + l_t + l_c`` each item repeats its last frame.  The world frame is kept, never
  re-based: ``S_p`` has the position and heading it has in its sequence (the composer places
  each sequence with a seeded world yaw and ground offset), while a label-only generator's
  unplaced ``Ŝ_c`` lives at the origin facing +Z (``S_c``'s canonical frame; MultiAct Table 3's
  "w. o. align"); :mod:`repro.data.pair_fidelity` measures the spread.  What a generator may be
  conditioned on is ``S_p``, ``a_c``, ``l_t`` and ``l_c`` (``a_p`` only for the baselines that
  regenerate ``S_p`` from its label); ``T`` and ``S_c`` are targets and references only.
- :class:`GeneratedPairs`: what a MultiAct-style generator returns for N conditions:
  ``[T̂, Ŝ_c]`` in the world frame, continuing the given previous motion.

Units: metres, frames at ``fps`` (20 for MultiAct).
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from repro.data.action_items import ActionItems, ItemsConfig
from repro.data.item_sources import ItemSet
from repro.keys import content_key
from repro.motion.canon import marionette_normalize
from repro.motion.motion import Motion

#: Bumped when pairs are built differently (enters :meth:`PairItems.key` via ``source``).
PAIRS_VERSION = 1


def _long(x, n: int, name: str) -> torch.Tensor:
    import torch

    t = torch.as_tensor(np.asarray(x), dtype=torch.long).reshape(-1)
    if t.numel() != n:
        raise ValueError(f"{name} must have {n} entries, got {t.numel()}")
    return t


def gather_frames(motion: Motion, start: torch.Tensor, length: torch.Tensor,
                  width: int | None = None) -> Motion:
    """Per item ``b``, frames ``start[b] .. start[b]+length[b]−1`` of ``motion`` left-aligned
    into ``width`` (default ``max(length)``) frames; past ``length[b]`` the last one repeats."""
    import torch

    start = torch.as_tensor(start, dtype=torch.long)
    length = torch.as_tensor(length, dtype=torch.long)
    W = int(length.max()) if width is None else int(width)
    t = torch.arange(W).unsqueeze(0)
    idx = start.unsqueeze(1) + torch.minimum(t, (length - 1).clamp(min=0).unsqueeze(1))
    idx = idx.clamp(0, motion.n_frames - 1)
    b = torch.arange(motion.batch_size).unsqueeze(1)
    return motion.replace(root=motion.root[b, idx], rot6d=motion.rot6d[b, idx])


def last_frames(motion: Motion, lengths: torch.Tensor, k: int) -> Motion:
    """The last ``k`` valid frames of each item (``lengths`` valid frames each); an item with
    fewer than ``k`` frames repeats its first frame at the front."""
    import torch

    lengths = torch.as_tensor(lengths, dtype=torch.long)
    t = torch.arange(k).unsqueeze(0)
    idx = (lengths.unsqueeze(1) - k + t).clamp(min=0)
    b = torch.arange(motion.batch_size).unsqueeze(1)
    return motion.replace(root=motion.root[b, idx], rot6d=motion.rot6d[b, idx])


@dataclass(frozen=True, eq=False)
class PairItems(ItemSet):
    """N MultiAct samples (module docstring).  ``l_p``, ``l_t``, ``l_c``, ``prev_labels``
    (``a_p``), ``labels`` (``a_c``) are (N,) int64; ``segment_index`` (N,) the ``S_c`` segment
    of the source :class:`~repro.data.sequences.SequenceSet` (-1 when not from one);
    ``source``: what built them (the builder's description and the sequences' fingerprint);
    ``clip_index`` (N,) ``S_c``'s source clip in the data set's ClipSet, or None (the
    validation hold-out groups by it, :mod:`repro.train.validation`)."""

    motion: Motion
    l_p: torch.Tensor
    l_t: torch.Tensor
    l_c: torch.Tensor
    prev_labels: torch.Tensor
    labels: torch.Tensor
    label_names: tuple[str, ...]
    segment_index: torch.Tensor | None = None
    source: str = ""
    clip_index: torch.Tensor | None = None

    def __post_init__(self) -> None:
        import torch

        N = self.motion.batch_size
        if self.clip_index is not None:
            object.__setattr__(self, "clip_index", _long(self.clip_index, N, "clip_index"))
        for name in ("l_p", "l_t", "l_c", "prev_labels", "labels"):
            object.__setattr__(self, name, _long(getattr(self, name), N, name))
        seg = self.segment_index
        object.__setattr__(self, "segment_index",
                           torch.full((N,), -1, dtype=torch.long) if seg is None
                           else _long(seg, N, "segment_index"))
        object.__setattr__(self, "label_names", tuple(self.label_names))
        if N and int(torch.minimum(self.l_p, self.l_c).min()) < 1:
            raise ValueError("every S_p and S_c needs at least one frame")
        if N and int(self.l_t.min()) < 0:
            raise ValueError("l_t must be >= 0")
        if N and int((self.l_p + self.l_t + self.l_c).max()) > self.motion.n_frames:
            raise ValueError("l_p + l_t + l_c exceeds the packed frames")

    def __len__(self) -> int:
        return self.motion.batch_size

    def frames_basis(self) -> Motion:
        return self.motion

    @property
    def total(self) -> torch.Tensor:
        """``l_p + l_t + l_c`` per item."""
        return self.l_p + self.l_t + self.l_c

    def key(self) -> str:
        """Content key of the arrays and the description (what a training's resume guard and
        sample caches compare)."""
        h = content_key({
            "version": PAIRS_VERSION, "source": self.source, "labels": list(self.label_names),
            "skeleton": self.skeleton.fingerprint(), "fps": self.fps,
            "arrays": [_sha(t) for t in (self.motion.root, self.motion.rot6d, self.l_p, self.l_t,
                                         self.l_c, self.prev_labels, self.labels,
                                         self.segment_index)]})
        return h

    def subset(self, index) -> "PairItems":
        import torch

        idx = torch.as_tensor(np.asarray(index), dtype=torch.long).reshape(-1)
        return PairItems(self.motion.select(idx), self.l_p[idx], self.l_t[idx], self.l_c[idx],
                         self.prev_labels[idx], self.labels[idx], self.label_names,
                         self.segment_index[idx], self.source,
                         None if self.clip_index is None else self.clip_index[idx])

    # -- the parts (left-aligned, padded by repeating each item's last frame) ------------------
    def prev(self) -> tuple[Motion, torch.Tensor]:
        """``S_p`` (N, max l_p) and ``l_p``."""
        import torch

        return gather_frames(self.motion, torch.zeros_like(self.l_p), self.l_p), self.l_p

    def transition(self) -> tuple[Motion, torch.Tensor]:
        """``T`` (N, max(l_t, 1)) and ``l_t`` (an item with ``l_t = 0`` holds its first S_c
        frame as padding)."""
        return gather_frames(self.motion, self.l_p, self.l_t.clamp(min=1)), self.l_t

    def action(self) -> tuple[Motion, torch.Tensor]:
        """``S_c`` (N, max l_c) and ``l_c``."""
        return gather_frames(self.motion, self.l_p + self.l_t, self.l_c), self.l_c

    def target(self) -> tuple[Motion, torch.Tensor]:
        """``[T, S_c]`` (N, max(l_t + l_c)) and ``l_t + l_c``."""
        n = self.l_t + self.l_c
        return gather_frames(self.motion, self.l_p, n), n

    # -- label-only generators -------------------------------------------------------------
    def as_action_items(self, n_init: int = 4) -> ActionItems:
        """These pairs as single-action :class:`~repro.data.action_items.ActionItems`, for
        label-only generators (ACTOR in MultiAct's Tables 1-3): ``action`` = ``S_c``
        (``lengths = l_c``), ``initial`` = the last ``n_init`` frames of ``S_p``; every item is
        Marionette-normalised at the last ``S_p`` frame (``canon``), so ``to_world`` of a
        generated action starts where ``S_p`` ended, facing its way.  That is placement only:
        ACTOR never sees the poses.  ``labels`` = ``a_c``; ``next_labels`` = ``a_c`` too (a
        placeholder: no label-only generator reads it); ``trajectory`` = the action's root
        ground path in the item frame, ``in_place`` all False (no class statistics here);
        ``clip_index`` / ``segment_index`` carried over."""
        import torch

        K = int(n_init)
        if K < 1:
            raise ValueError("n_init must be >= 1")
        N = len(self)
        if N == 0:
            raise ValueError("as_action_items needs at least one pair")
        act, l_c = self.action()
        config = ItemsConfig(n_init=K, max_frames=max(ItemsConfig().max_frames, act.n_frames))
        whole = Motion.cat_time([last_frames(self.motion, self.l_p, K), act])
        norm, canon = marionette_normalize(whole, anchor=K - 1, heading_axis=config.heading_axis,
                                           translation=config.translation)
        action = norm.slice_time(K, None)
        return ActionItems(
            initial=norm.slice_time(0, K), action=action, lengths=l_c.clone(),
            labels=self.labels.clone(), next_labels=self.labels.clone(),
            trajectory=action.root[..., [0, 2]].clone(),
            in_place=torch.zeros(N, dtype=torch.bool), canon=canon, label_names=self.label_names,
            clip_index=None if self.clip_index is None else self.clip_index.clone(),
            segment_index=self.segment_index.clone(), config=config,
            source=f"{self.source}|actions:n_init={K}" if self.source else "")


@dataclass(frozen=True, eq=False)
class GeneratedPairs:
    """Generated ``[T̂, Ŝ_c]`` per condition, world frame: ``motion`` (N, max(l_t + l_c)),
    padded by repeating each item's last frame; ``l_t``, ``l_c`` (N,) int64."""

    motion: Motion
    l_t: torch.Tensor
    l_c: torch.Tensor

    def __post_init__(self) -> None:
        N = self.motion.batch_size
        object.__setattr__(self, "l_t", _long(self.l_t, N, "l_t"))
        object.__setattr__(self, "l_c", _long(self.l_c, N, "l_c"))
        if N and int((self.l_t + self.l_c).max()) > self.motion.n_frames:
            raise ValueError("l_t + l_c exceeds the generated frames")

    def __len__(self) -> int:
        return self.motion.batch_size

    def transition(self) -> tuple[Motion, torch.Tensor]:
        import torch

        return gather_frames(self.motion, torch.zeros_like(self.l_t), self.l_t.clamp(min=1)), self.l_t

    def action(self) -> tuple[Motion, torch.Tensor]:
        return gather_frames(self.motion, self.l_t, self.l_c), self.l_c

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {"root": self.motion.root.detach().cpu().numpy().astype(np.float32),
                "rot6d": self.motion.rot6d.detach().cpu().numpy().astype(np.float32),
                "l_t": self.l_t.numpy(), "l_c": self.l_c.numpy(),
                "fps": np.array(self.motion.fps)}

    @classmethod
    def from_arrays(cls, arrays, skeleton) -> "GeneratedPairs":
        import torch

        m = Motion(torch.from_numpy(np.asarray(arrays["root"])),
                   torch.from_numpy(np.asarray(arrays["rot6d"])), skeleton, float(arrays["fps"]))
        return cls(m, arrays["l_t"], arrays["l_c"])

    @staticmethod
    def cat(parts: "list[GeneratedPairs]") -> "GeneratedPairs":
        """One batch from several (padded to the longest, repeating last frames)."""
        import torch

        W = max(p.motion.n_frames for p in parts)
        ms = [gather_frames(p.motion, torch.zeros_like(p.l_t), p.l_t + p.l_c, W) for p in parts]
        return GeneratedPairs(Motion.cat_batch(ms), torch.cat([p.l_t for p in parts]),
                              torch.cat([p.l_c for p in parts]))


def _sha(t: torch.Tensor) -> str:
    import hashlib

    a = np.ascontiguousarray(t.detach().cpu().numpy())
    return hashlib.sha256(a.tobytes() + str(a.dtype).encode() + str(a.shape).encode()).hexdigest()


def save_npz(path: str | Path, arrays: dict) -> Path:
    """Write ``arrays`` to ``path`` atomically (npz)."""
    from repro.store.atomic import atomic_write_bytes

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(Path(path), buf.getvalue())
    return Path(path)

