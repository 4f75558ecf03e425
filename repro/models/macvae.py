"""MACVAE, the recurrent unit of MultiAct (Lee, Moon & Lee, AAAI 2023, "MultiAct: Long-Term 3D
Human Motion Generation from Multiple Action Labels"), behind the
:class:`~repro.models.base.Generator` interface, with every ablation of the paper (Table 1,
supp. Tables A and B) as a :class:`MACVAEConfig` field.

What it does (paper "MACVAE"): given a previous action motion ``S_p``, the next label ``a_c``
and the lengths ``l_t``, ``l_c``, generate the transition and the action ``[T̂, Ŝ_c]`` that
continue ``S_p``.  It reads and returns :mod:`repro.data.pairs` containers (``item_kind =
"pairs"``): training on :class:`PairItems` ``[S_p, T, S_c]``; sampling from ``S_p`` only (its
``T`` and ``S_c`` are never read), returning :class:`GeneratedPairs` in the world frame.

Networks: :mod:`repro.models.macvae_nets`.  Pose vectors: the ``6J + 3`` vectors of
:mod:`repro.models.baseline_io` (6D of every joint, the root's global rotation first, then the
root translation in metres): the paper's 315-d ``p`` for our skeleton.  The reference code
feeds axis-angle to its encoder and PrevNet (protocols.md §7 item 2); we use the paper's 6D.

**Canonicalisation** (paper "Face-front canonicalization"; :mod:`repro.motion.canon`):
training canonicalises the whole ``[S_p, T, S_c]`` anchored at frame ``l_p − 1`` (the last S_p
frame, the reference code's anchor); generation canonicalises ``S_p`` anchored at its last
valid frame, which gives S_p the same canonical frames as in training; the output is mapped
back by the exact inverse (:func:`~repro.motion.canon.uncanonicalize`).  ``"zero"``:
:func:`~repro.motion.canon.zero_canon` (the whole anchor rotation removed).  ``"none"``: the
raw world frame (no transform at all, so absolute positions and headings enter the network).

**Training** (paper "Training objectives"):
``L = L_V + L_P + λ_acc·L_acc + λ_KL·L_KL`` on the generated ``[T̂, Ŝ_c]`` against ``[T, S_c]``:

- ``L_P``: L1 of the pose vectors; ``L_V``: L1 of the joint positions by forward kinematics
  on the data set's skeleton, root translation included (canonical frame, metres).  We have no
  SMPL-H mesh, so FK joints stand in for the mesh vertices (our choice);
- ``L_acc`` (``acc_loss``): ``"squared_output"`` (the released code, ``utils/loss.py``
  ``AccelLoss`` called on the generated joints only in ``models/model.py``): the mean square of
  the generated joints' second differences ``x[t+1] − 2x[t] + x[t−1]`` over the triples of
  ``[S_p's last two frames, T̂, Ŝ_c]`` (the code runs it over the whole postprocessed sequence;
  S_p's frames are given here, so the triples that reach into ``[T̂, Ŝ_c]`` are the ones with a
  gradient); ``"l1_target"`` (our paper reading: "mesh vertex acceleration loss", no formula):
  L1 between the generated and the target second differences over triples inside
  ``[T, S_c]``;
- scored frames (``loss_frames``): ``"whole"`` (the code: its postprocessor's output covers
  ``[S_p, T, S_c]`` and every loss reads all of it, so S_p's postprocessed frames are pulled
  to the given S_p) or ``"generated"`` (the paper's sums over ``i = 1 .. l_t + l_c``);
- reduction (paper writes sums; our choice): each term is the mean over valid frames (triples
  for ``L_acc``) and their components, so the three terms are comparable means in their units
  whatever the batch or the lengths (the code means over every frame of the 120-frame padded
  window, padding included);
- ``L_KL = Σ KL(posterior ‖ prior)`` of Gaussians over the latents (``z_p`` and ``z_c``, or the
  single ``z``), summed over the ``d`` dimensions and averaged over the batch items (our
  choice); the reparameterisation noise comes from the training loop's per-epoch torch RNG.

AdamW (lr 5e-5, PyTorch's default weight decay 0.01: the paper names AdamW and no decay),
batch 16, no gradient clipping, no schedule; the paper trains 1,300 epochs (the reference
config 1,200: set ``epochs``).

**Sampling**: ``z = μ + σ·ε`` from the priors (``z = μ`` when ``use_mean``), ``ε`` drawn per item
from ``(seed, item index)`` alone (:func:`~repro.models.baseline_io.item_noise`), so an item's
sample depends neither on the sampling batch nor on how many items are sampled with it.  A
caller chaining steps (MultiAct's long-term generation) passes a different seed per step.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import ClassVar

import torch
import torch.nn.functional as F

from repro.data.action_items import pad_last
from repro.data.pairs import GeneratedPairs, PairItems
from repro.errors import DataError
from repro.models.base import Generator, register
from repro.models.baseline_io import (check_matches_model, item_noise, length_mask, pack_poses,
                                      pose_joints, unpack_poses)
from repro.models.macvae_config import MACVAE, MACVAEConfig  # noqa: F401 (MACVAEConfig re-exported)
from repro.models.macvae_nets import MACVAENet, hold_frames, kl_gaussians, take_frames
from repro.motion.canon import CanonParams, face_front, uncanonicalize, zero_canon
from repro.motion.motion import Motion
from repro.motion.rotations import matrix_to_6d, sixd_to_matrix
from repro.seeding import derive_seed
from repro.train.loop import to_device
from repro import kernels


@register
class MACVAE(Generator):
    """MACVAE behind the Generator interface (module docstring)."""

    card = MACVAE
    item_kind: ClassVar[str] = "pairs"
    uses = frozenset({"label", "length", "initial_motion"})

    def __init__(self, config, skeleton, n_classes: int, fps: float):
        super().__init__(config, skeleton, n_classes, fps)
        self._build(derive_seed(0, self.method_id, "construct"))

    def _make_network(self) -> MACVAENet:
        return MACVAENet(self.config, self.skeleton.n_joints, self.n_classes)

    @property
    def network(self) -> MACVAENet:
        return self.net

    def describe(self) -> dict:
        d = super().describe()
        d["config"] = {k: v for k, v in d["config"].items() if k not in self.inference_fields}
        return d

    # -- canonicalisation ---------------------------------------------------------------------
    def canonicalize(self, motion: Motion, anchor) -> tuple[Motion, CanonParams]:
        """``motion`` in the configured canonical frame anchored at ``anchor`` (one frame
        index per item); ``"none"`` returns it unchanged with identity params."""
        mode = self.config.canonicalization
        if mode == "face_front":
            return face_front(motion, anchor)
        if mode == "zero":
            return zero_canon(motion, anchor)
        B, T = motion.batch_size, motion.n_frames
        a = torch.remainder(torch.as_tensor(anchor, dtype=torch.long).reshape(-1).expand(B), T)
        eye = torch.eye(3, dtype=motion.dtype).expand(B, 3, 3).clone()
        return motion, CanonParams("none", eye, torch.zeros(B, 3, dtype=motion.dtype), a.clone())

    # -- checks ----------------------------------------------------------------------------------
    def _check_items(self, items) -> None:
        who = self.method_id
        if not isinstance(items, PairItems):
            raise TypeError(f"{who} needs repro.data.pairs.PairItems, got {type(items).__name__}")
        if items.skeleton != self.skeleton:
            raise DataError(f"{who}: items use a different skeleton")
        check_matches_model(who, items, "items", n_classes=self.n_classes, fps=self.fps,
                            empty="no items")

    # -- training ------------------------------------------------------------------------------
    def _tensors(self, items: PairItems) -> dict[str, torch.Tensor]:
        """Canonical ``[S_p, T, S_c]`` pose vectors (N, L, P) and FK joints (N, L, J, 3)."""
        canon, _ = self.canonicalize(items.motion, items.l_p - 1)
        seq = pack_poses(canon)
        with torch.no_grad():
            joints = pose_joints(self.skeleton, seq)
        return {"seq": seq, "joints": joints, "l_p": items.l_p, "l_t": items.l_t,
                "l_c": items.l_c, "a_p": items.prev_labels, "a_c": items.labels}

    @staticmethod
    def _crop(data: dict, idx: torch.Tensor) -> dict:
        L = int((data["l_p"] + data["l_t"] + data["l_c"])[idx].max())
        return {k: (v[idx][:, :L] if k in ("seq", "joints") else v[idx]) for k, v in data.items()}

    def plateau_rule(self):
        """The convergence rule (issue 32) reads ``val_loss`` and ``val_kl``: with λ_KL = 1e-5
        (the released code's weight) the loss is almost all reconstruction and barely moves
        with the prior tokens the generator samples from; the held-out KL measures them."""
        from repro.train.plateau import PlateauRule

        return PlateauRule(also=("val_kl",))

    def training_step(self, net: MACVAENet, batch: dict, epoch: int) -> dict[str, torch.Tensor]:
        """``L`` of the module docstring on one batch."""
        cfg = self.config
        seq, joints = batch["seq"], batch["joints"]
        l_p, l_t, l_c, a_p, a_c = (batch[k] for k in ("l_p", "l_t", "l_c", "a_p", "a_c"))
        n = l_t + l_c
        T = int(n.max())
        t = torch.arange(seq.shape[1], device=seq.device)[None]
        seg = torch.where(t < l_p[:, None], a_p[:, None],
                          torch.where(t < (l_p + l_t)[:, None], net.n_classes, a_c[:, None]))
        posts = net.encode(seq, seg, l_p, l_t, l_c)
        priors = net.prior(net.prevnet_input(seq, l_p, a_c), a_c)
        zs = [mu + torch.exp(0.5 * lv) * torch.randn_like(mu) for mu, lv in posts]
        raw = net.decode(zs, l_t, l_c)
        if cfg.loss_frames == "whole":       # code: the postprocessed [S_p, T̂, Ŝ_c] is scored
            start, m = torch.zeros_like(l_p), l_p + n
            out = net.postprocess_whole(seq, l_p, raw, n)
        else:                                # paper: the l_t + l_c generated frames
            start, m = l_p, n
            out = net.postprocess(seq, l_p, raw, n)
        W = out.shape[1]
        target = hold_frames(seq, start, m, W)
        target_j = hold_frames(joints, start, m, W)
        valid = length_mask(m, W)
        rec_p = F.l1_loss(out[valid], target[valid])
        safe = torch.where(valid[..., None], out, target)    # padded frames: valid rotations
        pj = pose_joints(self.skeleton, safe)
        rec_v = F.l1_loss(pj[valid], target_j[valid])
        rec_acc = self.acc_term(pj, target_j, joints, l_p, m,
                                prefix=cfg.loss_frames != "whole")
        kl = sum(kl_gaussians(mq, lq, mp, lp).mean() for (mq, lq), (mp, lp) in zip(posts, priors))
        loss = rec_v + rec_p + cfg.lambda_acc * rec_acc + cfg.lambda_kl * kl
        return {"loss": loss, "rec_v": rec_v.detach(), "rec_p": rec_p.detach(),
                "rec_acc": rec_acc.detach(), "kl": kl.detach()}

    def acc_term(self, pj, target_j, joints, l_p, n, prefix: bool = True) -> torch.Tensor:
        """``L_acc`` (module docstring, ``acc_loss``) of generated joints ``pj`` (B, T, J, 3)
        with ``n`` valid frames, against ``target_j`` (``"l1_target"``) or alone
        (``"squared_output"``; with ``prefix`` after S_p's last two frames of ``joints``
        (B, L, J, 3), when ``pj`` starts after S_p)."""
        T = pj.shape[1]
        if self.config.acc_loss == "squared_output":
            if prefix:
                pre = take_frames(joints, l_p - 2, 2).to(pj.dtype)   # index < 0 clamps to 0
                x, ok = torch.cat([pre, pj], dim=1), length_mask(n + 2, T + 2)[:, 2:]
            else:
                x, ok = pj, length_mask(n, T)[:, 2:]
            acc = x[:, 2:] - 2 * x[:, 1:-1] + x[:, :-2]
            return (acc[ok] ** 2).mean() if bool(ok.any()) else pj.new_zeros(())
        ok = length_mask(n, T)[:, 2:]
        if not bool(ok.any()):
            return pj.new_zeros(())
        acc = pj[:, 2:] - 2 * pj[:, 1:-1] + pj[:, :-2]
        acc_t = target_j[:, 2:] - 2 * target_j[:, 1:-1] + target_j[:, :-2]
        return F.l1_loss(acc[ok], acc_t[ok])

    def _optimizer(self, params):
        cfg = self.config
        cls = kernels.adamw if cfg.optimizer == "adamw" else kernels.adam
        return cls(params, lr=cfg.lr, weight_decay=cfg.weight_decay)

    def fit(self, train_items: PairItems, *, seed: int, ckpt_dir: str | Path | None = None,
            on_epoch: Callable[[int, dict[str, float]], None] | None = None,
            val_items: PairItems | None = None):
        """Train through the one training loop; initial weights from ``seed``."""
        return self._fit_items(train_items, type(self)._check_items, self._optimizer, seed=seed,
                               ckpt_dir=ckpt_dir, on_epoch=on_epoch, val_items=val_items)

    # -- inference -----------------------------------------------------------------------------
    def _noise(self, seed: int, N: int) -> torch.Tensor:
        shape = (self.net.n_latents, self.config.d_model)
        return torch.stack([item_noise(seed, self.method_id, shape, i) for i in range(N)])

    @torch.no_grad()
    def step(self, prev: Motion, prev_lengths, labels, l_t, l_c, *, seed: int,
             use_mean: bool = False) -> GeneratedPairs:
        """One MACVAE step: ``[T̂, Ŝ_c]`` continuing the world-frame previous motions ``prev``
        (N, W) (``prev_lengths`` valid frames each) for labels ``a_c`` and lengths ``l_t``,
        ``l_c`` (N,), in the world frame.  The network runs on its device (:attr:`device`):
        canonicalisation, the noise (drawn on the CPU) and the result stay on the CPU."""
        cfg, net = self.config, self.net
        net.eval()
        if not isinstance(prev, Motion) or prev.skeleton != self.skeleton:
            raise DataError(f"{self.method_id}: prev must be a Motion on the model's skeleton")
        if abs(prev.fps - self.fps) > 1e-6:
            raise DataError(f"{self.method_id}: prev is at {prev.fps} fps, the model at {self.fps}")
        N = prev.batch_size
        lp, labels, l_t, l_c = (torch.as_tensor(x, dtype=torch.long).reshape(-1)
                                for x in (prev_lengths, labels, l_t, l_c))
        if not all(x.numel() == N for x in (lp, labels, l_t, l_c)) or N == 0:
            raise ValueError(f"prev_lengths, labels, l_t, l_c need {N} entries each (N >= 1)")
        if int(lp.min()) < 1 or int(lp.max()) > prev.n_frames:
            raise ValueError(f"prev_lengths must lie in 1..{prev.n_frames}")
        if int(l_t.min()) < 0 or int(l_c.min()) < 1:
            raise ValueError("l_t must be >= 0 and l_c >= 1")
        if int(labels.min()) < 0 or int(labels.max()) >= self.n_classes:
            raise ValueError(f"labels must lie in 0..{self.n_classes - 1}")
        canon, params = self.canonicalize(prev, lp - 1)
        poses = pack_poses(canon)
        eps = self._noise(seed, N)
        n = l_t + l_c
        out = torch.zeros(N, int(n.max()), net.pose_dim)
        dev = self.device
        for s in range(0, N, cfg.sample_batch_size):
            idx = torch.arange(s, min(N, s + cfg.sample_batch_size))
            pp = poses[idx, :int(lp[idx].max())]
            pp, p_len, lab, lt, lc, nb, e = to_device(
                (pp, lp[idx], labels[idx], l_t[idx], l_c[idx], n[idx], eps[idx]), dev)
            priors = net.prior(net.prevnet_input(pp, p_len, lab), lab)
            zs = [mu if use_mean else mu + torch.exp(0.5 * lv) * e[:, k]
                  for k, (mu, lv) in enumerate(priors)]
            res = net.postprocess(pp, p_len, net.decode(zs, lt, lc), nb)
            out[idx, :res.shape[1]] = res.cpu()
        rot6d, root = unpack_poses(out, self.skeleton.n_joints)
        rot6d = matrix_to_6d(sixd_to_matrix(pad_last(rot6d, n)))
        local = Motion(pad_last(root, n).to(params.rotation.dtype),
                       rot6d.to(params.rotation.dtype), self.skeleton, self.fps)
        world = uncanonicalize(local, params).to(dtype=torch.float32)
        return GeneratedPairs(world, l_t, l_c)

    def sample(self, cond_items: PairItems, *, seed: int, use_mean: bool = False) -> GeneratedPairs:
        """:meth:`step` on the items' ``S_p``, ``a_c``, ``l_t``, ``l_c`` (their ``T``, ``S_c``
        and ``a_p`` are not read)."""
        self._check_items(cond_items)
        prev, l_p = cond_items.prev()
        return self.step(prev, l_p, cond_items.labels, cond_items.l_t, cond_items.l_c,
                         seed=seed, use_mean=use_mean)
