"""``nearest_clip``: a HARNESS REFERENCE METHOD, NOT A METHOD OF ANY PAPER.

Retrieval instead of generation, to prove the evaluation pipeline end to end before (and
beside) the papers' models: given a condition (tag, initial motion, duration), return the real
*training* action of the same tag whose initial motion is nearest to the condition's, cut or
padded to the requested duration.  Its numbers say what copying real training data scores
under a protocol; they are never to be read as, or compared as if they were, a paper's result.

- ``fit``: index the training items per tag: the initial motion's joint positions in the
  item's Marionette-normalised frame (last initial pose at the origin facing +Z; so the match
  ignores where and which way the body stood), the last ``match_frames`` initial frames (all
  K by default) flattened, plus the action that followed (normalised frame).  No learning.
- ``sample``: for each condition, Euclidean distance (float64) to every indexed item of its
  tag; the nearest wins; exact ties are broken by a draw seeded by ``(seed, item)`` (so the
  seed matters only there).  The retrieved action is cut to the requested duration, or padded
  by repeating its last frame, and mapped into the world with the *condition's* normalisation
  (Alg. 1's inverse), so it continues from the condition's last initial pose.
- reads ``label``, ``initial_motion``, ``length``; ignores next tag and trajectory.

Its "weights" are the indexed training data (buffers of :class:`NearestClipIndex`), so
``save``/``load`` keep the index.  Units: metres, frames.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import torch
from torch import nn

from repro.data.action_items import ActionItems, GeneratedItems, pad_last
from repro.errors import ConfigError, DataError
from repro.models.base import Generator, register
from repro.models.baseline_io import check_matches_model
from repro.models.nearest_clip_config import NEAREST_CLIP, NearestClipConfig  # noqa: F401
from repro.motion.motion import Motion
from repro.seeding import numpy_rng

_BUFFERS = ("features", "labels", "lengths", "root", "rot6d", "n_init")


class NearestClipIndex(nn.Module):
    """The index: per training item, the match feature (M, D) and the action (normalised frame:
    ``root`` (M, T, 3), ``rot6d`` (M, T, J, 6), ``lengths`` (M,), ``labels`` (M,)).  Buffers
    change shape when loaded (the index is data, not fixed-shape weights)."""

    def __init__(self, n_joints: int):
        super().__init__()
        self.register_buffer("features", torch.zeros(0, 0))
        self.register_buffer("labels", torch.zeros(0, dtype=torch.long))
        self.register_buffer("lengths", torch.zeros(0, dtype=torch.long))
        self.register_buffer("root", torch.zeros(0, 1, 3))
        self.register_buffer("rot6d", torch.zeros(0, 1, n_joints, 6))
        self.register_buffer("n_init", torch.zeros((), dtype=torch.long))

    @property
    def size(self) -> int:
        return int(self.labels.shape[0])

    def _load_from_state_dict(self, state_dict, prefix, local_metadata, strict, missing_keys,
                              unexpected_keys, error_msgs):
        for name in _BUFFERS:
            key = prefix + name
            if key in state_dict:
                self._buffers[name] = state_dict[key].detach().clone()
            elif strict:
                missing_keys.append(key)
        for key in state_dict:
            if key.startswith(prefix) and key[len(prefix):] not in _BUFFERS:
                unexpected_keys.append(key)


def _match_features(items: ActionItems, frames: int | None) -> torch.Tensor:
    """(N, m·J·3) float64: joint positions of the last ``frames`` initial frames, normalised frame."""
    j = items.initial.joints().to(torch.float64)
    if frames is not None:
        if frames > j.shape[1]:
            raise ConfigError(f"nearest_clip: match_frames {frames} exceeds the "
                              f"{j.shape[1]} initial frames")
        j = j[:, -frames:]
    return j.reshape(j.shape[0], -1)


@register
class NearestClip(Generator):
    """Harness reference retrieval (module docstring): NOT a paper method."""

    card = NEAREST_CLIP
    uses = frozenset({"label", "initial_motion", "length"})

    def __init__(self, config, skeleton, n_classes: int, fps: float):
        super().__init__(config, skeleton, n_classes, fps)
        self.index = NearestClipIndex(skeleton.n_joints)

    @property
    def network(self) -> NearestClipIndex:
        return self.index

    def _check_items(self, items: ActionItems) -> None:
        if not isinstance(items, ActionItems):
            raise TypeError("nearest_clip needs repro.data.action_items.ActionItems")
        if items.skeleton != self.skeleton:
            raise DataError("nearest_clip: items use a different skeleton than the model")
        check_matches_model("nearest_clip", items, "items", n_classes=self.n_classes,
                            fps=self.fps, empty="no items")

    def fit(self, train_items: ActionItems, *, seed: int, ckpt_dir: str | Path | None = None,
            on_epoch: Callable[[int, dict[str, float]], None] | None = None,
            val_items: ActionItems | None = None):
        """Index ``train_items`` (no training; ``seed``, ``ckpt_dir``, ``on_epoch`` and
        ``val_items`` unused: there is no curve to draw)."""
        from repro.train.loop import TrainResult

        t0 = time.perf_counter()
        self._check_items(train_items)
        idx = self.index
        idx.features = _match_features(train_items, self.config.match_frames).to(torch.float32)
        idx.labels = train_items.labels.clone().long()
        idx.lengths = train_items.lengths.clone().long()
        idx.root = train_items.action.root.detach().clone()
        idx.rot6d = train_items.action.rot6d.detach().clone()
        idx.n_init = torch.tensor(train_items.n_init, dtype=torch.long)
        return TrainResult(epochs=0, resumed_from=None, history=[],
                           seconds=time.perf_counter() - t0)

    def retrieve(self, cond_items: ActionItems, *, seed: int) -> torch.Tensor:
        """(N,) index rows chosen for the conditions (nearest initial motion of the same tag)."""
        idx = self.index
        if idx.size == 0:
            raise DataError("nearest_clip: not fitted (the index is empty)")
        if cond_items.n_init != int(idx.n_init):
            raise DataError(f"nearest_clip: conditions have {cond_items.n_init} initial frames, "
                            f"the index {int(idx.n_init)}")
        query = _match_features(cond_items, self.config.match_frames)
        bank = idx.features.to(torch.float64)
        labels = idx.labels
        out = torch.empty(len(cond_items), dtype=torch.long)
        for c in torch.unique(cond_items.labels).tolist():
            rows = torch.nonzero(labels == c).reshape(-1)
            if rows.numel() == 0:
                raise DataError(f"nearest_clip: no training action of tag "
                                f"{cond_items.label_names[c]!r} to retrieve")
            qi = torch.nonzero(cond_items.labels == c).reshape(-1)
            cand = bank[rows]
            for i in qi.tolist():
                # squared distances by differences: same ranking and ties as the distance,
                # without torch's square root, whose bits depend on the CPU (repro.kernels)
                d = ((cand - query[i]) ** 2).sum(-1)
                ties = torch.nonzero(d == d.min()).reshape(-1)
                pick = ties[0] if ties.numel() == 1 else \
                    ties[int(numpy_rng(seed, self.method_id, "tie", i).integers(ties.numel()))]
                out[i] = rows[pick]
        return out

    @torch.no_grad()
    def sample(self, cond_items: ActionItems, *, seed: int, use_mean: bool = False) -> GeneratedItems:
        """One retrieved action per condition, in the world frame (module docstring);
        ``use_mean`` changes nothing (retrieval has no latent)."""
        self._check_items(cond_items)
        pick = self.retrieve(cond_items, seed=seed)
        idx = self.index
        lengths = cond_items.lengths.long()
        T = int(lengths.max())
        src_len = idx.lengths[pick]
        # frame t of item i: the retrieved action's frame min(t, its length − 1)
        t = torch.minimum(torch.arange(T)[None, :], (src_len - 1)[:, None])
        root = idx.root[pick[:, None], t]
        rot6d = idx.rot6d[pick[:, None], t]
        dtype = cond_items.initial.dtype
        root, rot6d = pad_last(root, lengths).to(dtype), pad_last(rot6d, lengths).to(dtype)
        motion = Motion(root, rot6d, self.skeleton, self.fps)
        return GeneratedItems(cond_items.to_world(motion), lengths.clone(),
                              cond_items.labels.clone())

    def describe(self) -> dict:
        d = super().describe()
        d["note"] = "harness reference retrieval, not a paper method"
        return d


__all__ = ["NearestClip", "NearestClipConfig", "NearestClipIndex"]
