"""NEURAL MARIONETTE's inference-time schemes on a trained MarioNet (Wang et al., Sec. 4.3.2).

:class:`NeuralMarionette` is MarioNet's network plus two schemes applied when sampling; it
trains no network of its own (``trains_as = "marionet"``: the engine trains the row as MarioNet
with the config minus :data:`INFERENCE_FIELDS` and loads those weights, so a Table 5 row shares
Table 1's MarioNet; :meth:`NeuralMarionette.fit` does the same in-process).

- **Shadow Start (SS)**, Eq. 6: the BOP embedding ``f0 = FC(P_0)`` (``MarioNetNet.embed_poses``
  of the last initial pose, in the item's normalised frame) is replaced at decoder step 0 by its
  least-squares projection ``f0* = Φ*·F̃`` onto the span of the ``N = ss_neighbours`` nearest
  (L2, embedding space) training BOP embeddings ``F̃`` of the item's current tag, then
  L2-normalised (``ss_l2_normalize``) onto a sphere whose radius ``ss_norm`` reads: ``"unit"``
  (``f0*/‖f0*‖``, the literal "L2-normalization", the default), ``"neighbours"`` (the
  *embedding-norm* reading: the mean norm of the ``N`` retrieved training embeddings ``F̃``,
  the "meaningful region" §4.3.2 projects towards) or ``"match"`` (``‖f0‖``, the drifting
  embedding's own norm).  The condition encoder still sees the real initial motion.  The
  candidate set ("shadow bank") is the training items' BOPs, given by
  :meth:`NeuralMarionette.set_shadow_bank`; it is not saved with the weights.
- **Action Revision (AR)**: every item is generated plainly; ``classify(generated)`` (passed in
  by the protocol: the paper's ``F_c``) says which are recognised as their tag; exactly the
  others are regenerated **once** with Shadow Start, with noise from
  ``derive_seed(seed, "revision")``; no second check.  Which classifier ``F_c`` is, is the
  protocol's to build; ``revision_classifier`` (an inference field, so a table row can choose
  it without a training of its own) asks the ``ss_ar`` protocol for the scoring network
  (``"evaluator"``) or an independent classifier (``"independent"``); unset, the protocol's
  parameter decides.

``shadow_start``: ``"never"`` (plain MarioNet, bitwise), ``"always"`` (MarioNet+SS) or
``"on_revision"`` (with ``action_revision``: NEURAL MARIONETTE, or NEURAL MARIONETTE* without
the L2 step).  :meth:`NeuralMarionette.sample` returns a :class:`RevisedItems` (a
:class:`~repro.data.action_items.GeneratedItems` with ``revised`` and ``shadow_start`` masks).
Every open choice is listed in docs/marionet.md ("NEURAL MARIONETTE: Shadow Start and Action
Revision").
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import torch
from pydantic import BaseModel

from repro.data.action_items import ActionItems, GeneratedItems
from repro.errors import ConfigError, DataError
from repro.models.base import register
from repro.models.marionet import MarioNet, MarioNetConfig, pack_poses
from repro.models.neural_marionette_config import (INFERENCE_FIELDS, NEURAL_MARIONETTE,
                                                   NeuralMarionetteConfig)
from repro.seeding import derive_seed


@dataclass(frozen=True, eq=False)
class RevisedItems(GeneratedItems):
    """What :meth:`NeuralMarionette.sample` returns: the generated actions (world frame) plus

    - ``revised`` (N,) bool: the action is an Action Revision regeneration (its plain pass was
      not recognised as its tag); all False under ``"never"`` and ``"always"``;
    - ``shadow_start`` (N,) bool: the returned action was generated with Shadow Start (all True
      under ``"always"``, ``== revised`` under ``"on_revision"``, all False under ``"never"``).

    ``revised.float().mean()`` is the revision rate."""

    revised: torch.Tensor | None = None
    shadow_start: torch.Tensor | None = None


def _as_mask(value, n: int) -> torch.Tensor:
    """A classifier's answer as a bool tensor (n,); 0/1 numbers are accepted."""
    if isinstance(value, torch.Tensor):
        t = value.detach().cpu()
    else:
        t = torch.as_tensor(np.asarray(value))
    t = t.reshape(-1) if t.dim() > 1 and t.numel() == n else t
    if t.shape != (n,):
        raise DataError(f"neural_marionette: classify returned shape {tuple(t.shape)}, "
                        f"expected ({n},) (True = recognised as its tag)")
    if t.dtype != torch.bool:
        if not bool(((t == 0) | (t == 1)).all()):
            raise DataError("neural_marionette: classify must return booleans "
                            "(True = recognised as its tag)")
        t = t != 0
    return t


@register
class NeuralMarionette(MarioNet):
    """MarioNet's trained network + Shadow Start / Action Revision (module docstring)."""

    card = NEURAL_MARIONETTE
    # the sampler's noise stream is MarioNet's (``noise_id``), so "never" is bitwise MarioNet.sample

    def __init__(self, config, skeleton, n_classes: int, fps: float):
        super().__init__(config, skeleton, n_classes, fps)
        self._bank_poses: torch.Tensor | None = None    # (M, 6J+3) training BOPs, item frame
        self._bank_labels: torch.Tensor | None = None   # (M,)
        self._bank_key: str | None = None

    # -- relation to MarioNet ------------------------------------------------------------------
    @property
    def needs_classifier(self) -> bool:
        """True when :meth:`sample` needs ``classify`` (Action Revision)."""
        return bool(self.config.action_revision)

    @property
    def needs_shadow_bank(self) -> bool:
        """True when sampling may use Shadow Start (so :meth:`set_shadow_bank` is required)."""
        return self.config.shadow_start != "never"

    @classmethod
    def split_config(cls, config: BaseModel | Mapping[str, Any] | None
                     ) -> tuple[dict[str, Any], dict[str, Any]]:
        """(MarioNet training overrides, inference options) of a neural_marionette config."""
        d = config.model_dump() if isinstance(config, BaseModel) else dict(config or {})
        return ({k: v for k, v in d.items() if k not in INFERENCE_FIELDS},
                {k: v for k, v in d.items() if k in INFERENCE_FIELDS})

    def training_config(self) -> MarioNetConfig:
        """The MarioNet config this method's weights come from (``INFERENCE_FIELDS`` stripped)."""
        return MarioNetConfig.resolve(self.split_config(self.config)[0], where=self.method_id)

    @classmethod
    def from_marionet(cls, marionet: MarioNet, options: Mapping[str, Any] | None = None
                      ) -> "NeuralMarionette":
        """A NeuralMarionette with a copy of ``marionet``'s weights (its ``state_dict``) and
        config, plus ``options`` (inference fields; a training field may only repeat the
        MarioNet's value).  The shadow bank is not carried over: call :meth:`set_shadow_bank`."""
        if not isinstance(marionet, MarioNet):
            raise TypeError("from_marionet needs a repro.models.marionet.MarioNet")
        base = cls.split_config(marionet.config)[0]
        config = cls.Config.resolve({**base, **dict(options or {})}, where=cls.method_id)
        changed = sorted(k for k, v in cls.split_config(config)[0].items() if base[k] != v)
        if changed:
            raise ConfigError(f"{cls.method_id}: option(s) {changed} are MarioNet training "
                              "fields that differ from the trained model's; only "
                              f"{sorted(INFERENCE_FIELDS)} may change at inference")
        gen = cls(config, marionet.skeleton, marionet.n_classes, marionet.fps)
        gen.network.load_state_dict(marionet.network.state_dict())
        gen.network.eval()
        return gen

    def fit(self, train_items: ActionItems, *, seed: int, ckpt_dir: str | Path | None = None,
            on_epoch: Callable[[int, dict[str, float]], None] | None = None,
            val_items: ActionItems | None = None):
        """Train **as MarioNet** (same seed derivation, resume guard and checkpoints as
        ``MarioNet(self.training_config()).fit``, hence the same weights; ``val_items`` passed
        on), copy the weights, and set the shadow bank from ``train_items``."""
        base = MarioNet(self.training_config(), self.skeleton, self.n_classes, self.fps)
        result = base.fit(train_items, seed=seed, ckpt_dir=ckpt_dir, on_epoch=on_epoch,
                          val_items=val_items)
        self.net.load_state_dict(base.network.state_dict())
        self.net.eval()
        self.set_shadow_bank(train_items)
        return result

    # -- Shadow Start (Eq. 6) ------------------------------------------------------------------
    def set_shadow_bank(self, train_items: ActionItems) -> None:
        """Eq. 6's candidates: the BOPs ``P̃`` (last initial frame, each item's normalised frame)
        of the training items, grouped by their current tag.  Their embeddings ``FC(P̃)`` are
        computed with the current weights whenever Shadow Start runs.  Not saved with the
        generator: rebuild it after :meth:`load`."""
        self._check_items(train_items)
        self._bank_poses = pack_poses(train_items.initial).float()[:, -1].clone()
        self._bank_labels = train_items.labels.clone()
        self._bank_key = train_items.key()

    @property
    def shadow_bank_key(self) -> str | None:
        """Content key of the items the bank was built from (None: no bank)."""
        return self._bank_key

    def _require_bank(self) -> None:
        if self._bank_poses is None:
            raise ConfigError(f"{self.method_id}: Shadow Start needs the training BOPs: call "
                              "set_shadow_bank(train_items) first (the bank is not saved with "
                              "the weights)")

    @torch.no_grad()
    def bank_embeddings(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(F̃ (M, d) = FC(P̃) of every bank BOP, labels (M,))."""
        self._require_bank()
        self.net.eval()
        return self.net.embed_poses(self._bank_poses), self._bank_labels

    @torch.no_grad()
    def bop_embeddings(self, cond_items: ActionItems) -> torch.Tensor:
        """``f0 = FC(P_0)`` (N, d): what the decoder's first query embeds for each item."""
        self._check_items(cond_items)
        self.net.eval()
        return self.net.embed_poses(pack_poses(cond_items.initial).float()[:, -1])

    @torch.no_grad()
    def shadow_start_features(self, cond_items: ActionItems) -> torch.Tensor:
        """``f0*`` (N, d) of each item (Eq. 6 + the L2 step).

        ``f0 = FC(P_0)``; ``F̃`` = the ``min(N, M_tag)`` bank embeddings of the item's current
        tag nearest to ``f0`` (L2; ties → lowest bank index); ``Φ* = argmin ‖f0 − Φ·F̃‖²``
        (float64 SVD least squares, rank-deficient safe: the minimum-norm solution),
        ``f0* = Φ*·F̃``; then, when ``ss_l2_normalize``, ``f0*·r/‖f0*‖`` with the radius
        ``r`` = 1 (``ss_norm="unit"``), ``mean_i ‖f̃^i‖`` over the rows of ``F̃``
        (``"neighbours"``) or ``‖f0‖`` (``"match"``); a zero ``f0*`` stays zero."""
        cfg = self.config
        self._require_bank()
        f0 = self.bop_embeddings(cond_items)
        bank, bank_labels = self.bank_embeddings()
        out = torch.empty_like(f0)
        by_tag: dict[int, torch.Tensor] = {}
        for i in range(len(cond_items)):
            tag = int(cond_items.labels[i])
            if tag not in by_tag:
                cand = bank[bank_labels == tag].double()
                if cand.shape[0] == 0:
                    raise DataError(f"{self.method_id}: Shadow Start found no training BOP of "
                                    f"tag {tag} ({cond_items.label_names[tag]!r}) in the "
                                    "shadow bank")
                by_tag[tag] = cand
            cand = by_tag[tag]
            f = f0[i].double()
            k = min(cfg.ss_neighbours, cand.shape[0])
            dist = (cand - f).square().sum(-1)
            near = torch.argsort(dist, stable=True)[:k]
            Ft = cand[near]                                       # (k, d): rows f̃^i
            phi = torch.linalg.lstsq(Ft.T, f[:, None], driver="gelsd").solution[:, 0]
            proj = phi @ Ft
            if cfg.ss_l2_normalize:
                norm = proj.norm()
                if float(norm) > 0.0:
                    proj = proj / norm * self._ss_radius(f, Ft)
            out[i] = proj.to(out.dtype)
        return out

    def _ss_radius(self, f0: torch.Tensor, Ft: torch.Tensor):
        """The radius of the L2 step's sphere (``ss_norm``; §4.3.2 "project pose to a compact
        hyper-sphere space"): 1, the mean norm of the retrieved training embeddings ``F̃`` (k, d)
        or the norm of ``f0``."""
        if self.config.ss_norm == "unit":
            return 1.0
        if self.config.ss_norm == "neighbours":
            return Ft.norm(dim=1).mean()
        return f0.norm()

    # -- sampling ------------------------------------------------------------------------------

    @staticmethod
    def revision_seed(seed: int) -> int:
        """The seed of the Action Revision pass (its own noise stream)."""
        return derive_seed(seed, "revision")

    def _generated(self, cond_items: ActionItems, poses: torch.Tensor) -> GeneratedItems:
        with torch.no_grad():
            return self._finish(cond_items, poses)

    def sample(self, cond_items: ActionItems, *, seed: int, use_mean: bool = False,
               use_cache: bool | None = None,
               classify: Callable[[GeneratedItems], Any] | None = None) -> RevisedItems:
        """One action per item, world frame, as a :class:`RevisedItems`.

        - ``"never"``: exactly :meth:`MarioNet.sample` (same weights and seed → same bits);
        - ``"always"``: every item generated with ``first_feature = shadow_start_features``
          (same noise as the plain pass);
        - ``"on_revision"``: the plain pass; ``classify(generated)`` → (N,) bool (True =
          recognised as its tag), called exactly once; the others are regenerated once, as
          their own :meth:`ActionItems.subset` (in item order) with Shadow Start and seed
          :meth:`revision_seed` (``seed``); the recognised ones are returned untouched.
        """
        cfg = self.config
        N = len(cond_items)
        none = torch.zeros(N, dtype=torch.bool)
        if cfg.shadow_start == "never":
            plain = self._generated(cond_items, self.generate_poses(
                cond_items, seed=seed, use_mean=use_mean, use_cache=use_cache))
            return self._wrap(plain, none, none)
        if cfg.shadow_start == "always":
            ff = self.shadow_start_features(cond_items)
            gen = self._generated(cond_items, self.generate_poses(
                cond_items, seed=seed, use_mean=use_mean, use_cache=use_cache, first_feature=ff))
            return self._wrap(gen, none, ~none)
        # "on_revision" (the config guarantees action_revision)
        if classify is None:
            raise ConfigError(f"{self.method_id}: action_revision needs a classifier: pass "
                              "classify=(GeneratedItems -> (N,) bool, True = recognised)")
        self._require_bank()  # fail before the plain pass, not after it
        plain = self._generated(cond_items, self.generate_poses(
            cond_items, seed=seed, use_mean=use_mean, use_cache=use_cache))
        correct = _as_mask(classify(plain), N)
        bad = torch.nonzero(~correct).reshape(-1)
        if bad.numel() == 0:
            return self._wrap(plain, none, none)
        sub = cond_items.subset(bad)
        ff = self.shadow_start_features(sub)
        rev = self._generated(sub, self.generate_poses(
            sub, seed=self.revision_seed(seed), use_mean=use_mean, use_cache=use_cache,
            first_feature=ff))
        T = plain.motion.n_frames   # the subset's frames past its longest item repeat its last

        def pad(x):
            return torch.cat([x, x[:, -1:].expand((-1, T - x.shape[1]) + x.shape[2:])], 1)

        root, rot6d = plain.motion.root.clone(), plain.motion.rot6d.clone()
        root[bad] = pad(rev.motion.root)
        rot6d[bad] = pad(rev.motion.rot6d)
        revised = none.clone()
        revised[bad] = True
        merged = GeneratedItems(plain.motion.replace(root=root, rot6d=rot6d),
                                plain.lengths, plain.labels)
        return self._wrap(merged, revised, revised.clone())

    @staticmethod
    def _wrap(g: GeneratedItems, revised: torch.Tensor, ss: torch.Tensor) -> RevisedItems:
        return RevisedItems(g.motion, g.lengths, g.labels, revised=revised, shadow_start=ss)
