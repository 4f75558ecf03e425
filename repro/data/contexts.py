"""Items and their context, built once for every Neural Marionette protocol (data layer).

An *item* (:class:`repro.models.items.ActionItems`) is one action to generate with what the
generator is conditioned on: the previous motion ``P^ini`` (``n_init`` = 6 frames), the tag,
the duration, the next tag and the trajectory (Neural Marionette §3, Fig. 2; §4.2).  BABEL-MAG
takes the previous motion and the next tag from the recording the action sits in.  The
stand-in's clips are single actions, so the context comes from the **composed sequences**
(:mod:`repro.data.sequences`, the ``bandai2-seq`` view): an item is one ``ROLE_ACTION``
segment; ``P^ini`` is the ``n_init`` frames before it in its sequence (the transition: the
previous clip's own recorded continuation carried onto this segment's first frame, and before
it the previous segment's end); the next tag is the label of the segment after it.  Neither
ever comes from the clip being generated (``tests/test_contexts.py``).

:class:`ItemSource` is the one description of how items are made (split, composition, item
construction, context), shared by the ``single_action``, ``multi_action`` and ``ss_ar``
protocols and by the engine's training step, so a model trained for one table serves every
table whose items are described the same way (its ``describe()`` enters the training key).

``context = "same_clip"`` is the earlier construction, kept as a named, recorded option: the
first ``n_init`` frames of the clip itself and a motion-graph next tag derived from the clip's
own end pose (:func:`repro.models.items.build_items`) — a leak, since both come from the
action being generated.

Each item is expressed in the world frame of its source clip (the context is mapped by the
inverse of the segment's placement in the sequence), so an item's real action is exactly the
recorded clip's segment (``max_action_frames`` ≤ every profile's ``max_frames``: whole, never
truncated) and evaluators that see absolute heading are unaffected.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Literal

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, model_validator

from repro.errors import DataError
from repro.keys import content_key

#: Bumped when sequence items are built differently (enters :meth:`ItemSource.describe`).
CONTEXT_VERSION = 2


class ItemSource(BaseModel):
    """How a protocol's items are made from a data set (every field enters content keys)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

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

    def describe(self) -> dict:
        d = self.model_dump(mode="json")
        if self.context == "sequence":
            from repro.data.sequences import ComposeConfig

            d["compose"] = ComposeConfig(**self.compose).model_dump(mode="json")
            d["context_version"] = CONTEXT_VERSION
        else:
            d.pop("compose")
        return d

    def key(self) -> str:
        return content_key(self.describe())

    @classmethod
    def make(cls, where: str, **fields) -> "ItemSource":
        """``ItemSource(**fields)``; a bad value is a ConfigError naming ``where`` and the field."""
        from repro.config_errors import resolve_config

        return resolve_config(cls, fields, f"{where}:", unnamed="parameters", quote=False)

    @classmethod
    def from_description(cls, d: dict) -> "ItemSource":
        """The source :meth:`describe` wrote (a training job's config)."""
        d = dict(d)
        version = d.pop("context_version", CONTEXT_VERSION)
        if version != CONTEXT_VERSION:
            raise DataError(f"items were described by context version {version}, this code "
                            f"builds version {CONTEXT_VERSION}")
        return cls(**d)

    # -- the pieces -------------------------------------------------------------------------
    def items_config(self):
        from repro.models.items import ItemsConfig

        return ItemsConfig(n_init=self.n_init, max_frames=self.max_frames)

    def split_clipset(self, clipset):
        """``clipset`` with the protocol's train/test split (the evaluator trains on this one
        too, so that no scored test clip was seen by the recogniser)."""
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

    def items(self, clipset, split: int):
        """Every item of ``split`` (TRAIN or TEST)."""
        key = content_key({"source": self.describe(), "data": clipset.fingerprint,
                           "split": int(split)})

        def build():
            if self.context == "same_clip":
                from repro.models.items import build_items

                return build_items(self.split_clipset(clipset), split, self.items_config())
            return sequence_items(self.sequences(clipset), split, self.items_config())

        return cached(key, build)

    def train_items(self, clipset):
        from repro.data.clipset import TRAIN

        return self.items(clipset, TRAIN)


# Items are immutable in use and cost seconds to build: keep the last few per process.
_CACHE: "OrderedDict[str, object]" = OrderedDict()
_CACHE_SIZE = 8


def cached(key: str, build):
    """``build()`` through a small in-process LRU (8 entries) keyed by the content key ``key``:
    the items and test sets the Neural Marionette protocols build from one composition."""
    hit = _CACHE.get(key)
    if hit is not None:
        _CACHE.move_to_end(key)
        return hit
    out = build()
    _CACHE[key] = out
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return out


def sequence_items(seqs, split: int | None, config=None, *, dtype: torch.dtype = torch.float32):
    """One item per ``ROLE_ACTION`` segment of the sequences of ``split`` (module docstring).

    ``P^ini``: :meth:`SequenceSet.context` (``n_init`` frames before the segment, in the source
    clip's frame); the action: the source clip from the segment's cut, ``T = min(length,
    max_frames)`` frames; the next tag: the following segment's label; ``clip_index``: the source
    clip; ``segment_index``: the segment.  Everything Marionette-normalised at ``P₋₁`` as in
    :func:`repro.models.items.build_items`."""
    from repro.data.sequences import ROLE_ACTION
    from repro.models.items import ItemsConfig, items_from_windows
    from repro.motion.motion import Motion
    from repro.motion.rotations import quat_to_6d

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
