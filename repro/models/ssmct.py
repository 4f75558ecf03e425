"""SSMCT (Duan et al. 2021, "Single-Shot Motion Completion with Transformer", arXiv 2103.00776),
the in-betweening half of MultiAct's "ACTOR + SSMCT" baseline (MultiAct Table 3, Fig. 6:
"SSMCT connects the individually generated action motion from ACTOR"; the MultiAct authors
trained it on BABEL and published no code or settings for it, protocols.md §8).

**What we could establish about SSMCT** (the paper body was not reachable from here, so no
number below is quoted from it; sources: the abstract (arXiv / ar5iv); the authors' project
README (FuxiCV/SSMCT: LaFAN1 results at transition length 30; the code was never released,
issues #4-#9); a secondary summary of the paper (paperium); reading notes on the authors'
follow-up "A Unified Framework for Real Time Motion Completion" (ttrkaya/notes_in_between);
and the one public *unofficial* re-implementation, xiaogangpeng/SSMCT, whose LaFAN1 config we
read for sizes only):

- completion as sequence-to-sequence prediction, **non-autoregressive**: all missing frames of
  a window come out of one forward pass (abstract);
- a **standard transformer encoder** with self-attention, BERT-like, no causal mask (abstract;
  notes: "BERT based");
- a **trainable mixture embedding**: a trained (BERT-style, not sinusoidal) positional
  embedding plus a learned **keyframe embedding** telling known from missing frames
  (abstract; summary; notes on the follow-up);
- per-frame pose vectors turned into tokens by a **1-D convolution**, and tokens back into poses
  by another (summary; notes on the follow-up);
- missing frames **filled by interpolation** before entering the network (linear for positions,
  slerp for rotations): the input convention later work ascribes to SSMCT-style models (Mo et
  al. 2023, CITL); the network predicts absolute poses, not a delta from the interpolation (the
  Delta-interpolator paper, Oreshkin et al., presents the delta mode as its departure);
- losses: L1 reconstruction of rotations/root plus a kinematic (forward-kinematics position)
  loss (notes on the follow-up; unofficial config);
- LaFAN1 benchmark setting (Harvey et al. 2020, which SSMCT reports on): **10 context frames**,
  the transition, **1 target keyframe**;
- sizes (unofficial config only): 8 layers, 8 heads, d_model 256, feed-forward 512, dropout
  0.1, lr 1e-4 with weight decay 1e-5, batch 128; loss weights 1.0 on rotations and 1.0 on FK
  positions.

**This module** (a :class:`~repro.models.base.Generator` trained on
:class:`~repro.data.pairs.PairItems`, ``item_kind = "pairs"``):

- **window** per pair: the last ``context_frames`` (10, LaFAN1) frames of ``S_p``, then the
  ``l_t`` missing transition frames, then the first ``target_frames`` frames of ``S_c`` as
  keyframes.  ``target_frames`` defaults to **2** (our choice; LaFAN1 uses 1): in MultiAct's
  pipeline ``S_c`` is entirely known (ACTOR made it), and two frames give the in-betweener the
  action's initial velocity.  An ``S_p`` shorter than the context repeats its first frame in
  front (:func:`repro.data.pairs.last_frames`); an ``S_c`` shorter than the keyframes repeats its
  last frame.  Windows of a batch are padded to the longest by repeating their last frame and
  the padded tokens are masked out of attention;
- **frame**: MultiAct's face-front canonical frame anchored at ``S_p``'s last frame
  (:func:`repro.motion.canon.face_front`, its defaults: lateral heading axis, full 3-D anchor
  translation), the frame MACVAE sees, so both in-betweeners are compared on equal terms and the
  output is invariant to the world's yaw and translation;
- **input**: the pose vector of :mod:`repro.models.baseline_io` (6-D local rotations with the
  root's global one, root translation in metres: ``6J + 3``); missing frames initialised by
  interpolating between the last context frame and the first keyframe, frame ``k`` of ``l_t``
  at weight ``k / (l_t + 1)``: slerp of every joint's rotation (shortest arc,
  :func:`repro.motion.resample.slerp`), linear root;
- **network**: ``Conv1d(6J+3 → d_model, kernel_size)`` (replicate padding), plus the learned
  positional embedding (``max_window`` rows) and the learned keyframe embedding (3 kinds:
  known / missing / padding), LayerNorm and dropout (BERT's embedding block); ``layers``
  post-norm encoder layers (:class:`repro.models.layers.TransformerEncoder`, GELU, no causal
  mask); ``Conv1d(d_model → 6J+3, kernel_size)``.  ``kernel_size`` 3 and the single convolution
  on each side are our choice (SSMCT's kernel sizes were not found);
- **output**: the prediction replaces only the missing frames; context and keyframes are
  passed through.  6-D outputs are orthonormalised by Gram-Schmidt;
- **loss** (missing frames only, mean over valid missing frames): ``λ_pose·L1(P̂, P) +
  λ_pos·L1(FK(P̂), FK(P))``, the FK positions global in the canonical frame (root translation
  included, metres), weights 1 and 1 (unofficial config; paper weights not found);
- **training**: AdamW (lr 1e-4, weight decay 1e-5, the unofficial config), batch 128,
  ``epochs`` 1,200 (our choice: MultiAct's own schedule on the same pairs, protocols.md §4.2;
  the unofficial LaFAN1 config runs 10,000 on a much larger data set);
- **inference** is deterministic: no noise, ``seed`` and ``use_mean`` are accepted for the
  interface and ignored.

:meth:`SSMCT.inbetween` is what the composite baselines call (world frame in and out).
:meth:`SSMCT.sample` on PairItems in-betweens each pair's ``S_p`` and its *real* ``S_c`` (the
in-betweening task itself; it reads ``S_c``'s first frames by design) and returns ``[T̂, S_c]``.

Units: metres, frames at the pairs' fps (20 for MultiAct).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from repro.data.action_items import pad_last
from repro.data.pairs import GeneratedPairs, PairItems, gather_frames, last_frames
from repro.errors import ConfigError, DataError
from repro.models.base import Generator, register
from repro.models.baseline_io import (
    check_matches_model,
    length_mask,
    pack_poses,
    pose_dim,
    pose_joints,
    unpack_poses,
)
from repro.models.layers import Conv1d, Dropout, TransformerEncoder
from repro.models.ssmct_config import SSMCT, SSMCTConfig
from repro.motion.canon import canonicalize_with, face_front, uncanonicalize
from repro.motion.motion import Motion
from repro.motion.resample import slerp
from repro.motion.rotations import (
    matrix_to_6d,
    quat_to_6d,
    sixd_to_matrix,
    sixd_to_quat,
)
from repro.seeding import derive_seed
from repro.train.loop import to_device

#: keyframe-embedding kinds
KNOWN, MISSING, PADDING = 0, 1, 2


class SSMCTNet(nn.Module):
    """Conv1d → mixture embedding → transformer encoder → Conv1d (module docstring).
    ``x`` (B, W, 6J+3) windows, ``kind`` (B, W) KNOWN/MISSING/PADDING, ``lengths`` (B,)."""

    def __init__(self, cfg: SSMCTConfig, n_joints: int):
        super().__init__()
        d, P, k = cfg.d_model, pose_dim(n_joints), cfg.kernel_size
        self.conv_in = Conv1d(P, d, k, padding=k // 2, padding_mode="replicate")
        self.position = nn.Embedding(cfg.max_window, d)
        self.keyframe = nn.Embedding(3, d)
        self.norm = nn.LayerNorm(d)
        self.drop = Dropout(cfg.dropout)
        self.encoder = TransformerEncoder(cfg.layers, d, cfg.heads, cfg.ff_size, cfg.dropout,
                                          cfg.activation)
        self.conv_out = Conv1d(d, P, k, padding=k // 2, padding_mode="replicate")

    def forward(self, x: torch.Tensor, kind: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        W = x.shape[1]
        h = self.conv_in(x.transpose(1, 2)).transpose(1, 2)
        h = h + self.position.weight[:W] + self.keyframe(kind)
        h = self.drop(self.norm(h))
        h = self.encoder(h, key_padding_mask=~length_mask(lengths, W))
        h = pad_last(h, lengths)  # padded tokens never reach a valid frame through conv_out
        return self.conv_out(h.transpose(1, 2)).transpose(1, 2)


# ---------------------------------------------------------------------------------------------
# windows


def interpolate_frames(a: Motion, b: Motion, l_t) -> Motion:
    """Frames strictly between ``a`` (B, 1) and ``b`` (B, 1): frame ``k = 1 .. l_t`` of item
    ``i`` at weight ``k / (l_t[i] + 1)``, slerp of every joint's local rotation (joint 0's being
    global), linear root.  (B, max(l_t, 1)); past ``l_t`` the last frame repeats; an item with
    ``l_t = 0`` holds ``b``."""
    l_t = torch.as_tensor(l_t, dtype=torch.long).reshape(-1)
    W = max(int(l_t.max()) if l_t.numel() else 1, 1)
    k = torch.minimum(torch.arange(1, W + 1)[None, :], l_t.clamp(min=1)[:, None])
    w = k.to(torch.float64) / (l_t[:, None] + 1).to(torch.float64)
    w = torch.where(l_t[:, None] == 0, torch.ones_like(w), w)                # (B, W)
    qa = sixd_to_quat(a.rot6d[:, :1].to(torch.float64))                      # (B, 1, J, 4)
    qb = sixd_to_quat(b.rot6d[:, :1].to(torch.float64))
    J = qa.shape[2]
    q = slerp(qa.expand(-1, W, -1, -1), qb.expand(-1, W, -1, -1), w[..., None].expand(-1, W, J))
    ra, rb = a.root[:, :1].to(torch.float64), b.root[:, :1].to(torch.float64)
    root = (1 - w[..., None]) * ra + w[..., None] * rb
    dt = a.dtype
    return a.replace(root=root.to(dt), rot6d=quat_to_6d(q).to(dt))


def _assemble(ctx: torch.Tensor, mid: torch.Tensor, keys: torch.Tensor, l_t: torch.Tensor):
    """Windows ``[ctx (C), mid (first l_t), keys (K)]`` per item, padded with the last key.
    ``ctx`` (B, C, ...), ``mid`` (B, M ≥ max l_t, ...), ``keys`` (B, K, ...) → (B, W, ...),
    ``kind`` (B, W), ``lengths`` (B,)."""
    B, C, K = ctx.shape[0], ctx.shape[1], keys.shape[1]
    lengths = C + l_t + K
    W = int(lengths.max())
    t = torch.arange(W)[None, :].expand(B, W)
    src = torch.cat([ctx, mid, keys], dim=1)
    M = mid.shape[1]
    in_mid = (t >= C) & (t < C + l_t[:, None])
    key_j = (t - C - l_t[:, None]).clamp(0, K - 1)
    idx = torch.where(t < C, t, torch.where(in_mid, t, C + M + key_j))
    out = src[torch.arange(B)[:, None], idx]
    kind = torch.full((B, W), KNOWN, dtype=torch.long)
    kind[in_mid] = MISSING
    kind[t >= lengths[:, None]] = PADDING
    return out, kind, lengths


def join_pairs(transition: Motion, l_t, action: Motion, l_c) -> GeneratedPairs:
    """``[T, S_c]`` per item as :class:`~repro.data.pairs.GeneratedPairs`: the first ``l_t``
    frames of ``transition`` (N, ≥ max l_t) then the first ``l_c`` of ``action`` (N, ≥ max l_c),
    padded to ``max(l_t + l_c)`` by repeating each item's last frame."""
    l_t = torch.as_tensor(l_t, dtype=torch.long).reshape(-1)
    l_c = torch.as_tensor(l_c, dtype=torch.long).reshape(-1)
    N, Wt = transition.batch_size, transition.n_frames
    both = Motion.cat_time([transition, action.to(dtype=transition.dtype)])
    W = int((l_t + l_c).max())
    t = torch.minimum(torch.arange(W)[None, :], (l_t + l_c - 1)[:, None])
    idx = torch.where(t < l_t[:, None], t, Wt + t - l_t[:, None])
    b = torch.arange(N)[:, None]
    return GeneratedPairs(both.replace(root=both.root[b, idx], rot6d=both.rot6d[b, idx]), l_t, l_c)


def _check_pairs(gen, items) -> None:
    who = gen.method_id
    if not isinstance(items, PairItems):
        raise TypeError(f"{who} needs repro.data.pairs.PairItems, got {type(items).__name__}")
    check_matches_model(who, items, "pairs", skeleton=gen.skeleton, fps=gen.fps,
                        empty="no pairs")


@register
class SSMCT(Generator):
    """SSMCT behind the :class:`~repro.models.base.Generator` interface (module docstring)."""

    card = SSMCT
    item_kind = "pairs"
    #: the previous motion and the lengths (and, as an in-betweener, the next action's first
    #: ``target_frames`` frames, which are no condition field of single-action items)
    uses = frozenset({"initial_motion", "length"})

    def __init__(self, config, skeleton, n_classes: int, fps: float):
        super().__init__(config, skeleton, n_classes, fps)
        self._build(derive_seed(0, self.method_id, "construct"))

    def _make_network(self) -> SSMCTNet:
        return SSMCTNet(self.config, self.skeleton.n_joints)

    @property
    def network(self) -> SSMCTNet:
        return self.net

    # -- windows -------------------------------------------------------------------------------
    def _check_window(self, l_t: torch.Tensor) -> None:
        cfg = self.config
        W = cfg.context_frames + int(l_t.max()) + cfg.target_frames
        if W > cfg.max_window:
            raise ConfigError(f"ssmct: a window of {cfg.context_frames} context + "
                              f"{int(l_t.max())} transition + {cfg.target_frames} target frames "
                              f"exceeds max_window {cfg.max_window}; raise max_window")

    def _inputs(self, ctx: Motion, keys: Motion, l_t: torch.Tensor):
        """Network inputs for canonical-frame context (B, C) and keyframes (B, K): poses
        (B, W, 6J+3) with the missing frames interpolated, kinds, lengths."""
        mid = interpolate_frames(ctx.slice_time(-1), keys.slice_time(0, 1), l_t)
        return _assemble(pack_poses(ctx), pack_poses(mid), pack_poses(keys), l_t)

    def _tensors(self, items: PairItems) -> dict[str, torch.Tensor]:
        """Training windows of every pair, in the face-front frame at ``S_p``'s last frame."""
        cfg = self.config
        self._check_window(items.l_t)
        canon, _ = face_front(items.motion, anchor=items.l_p - 1)
        ctx = last_frames(canon, items.l_p, cfg.context_frames)
        keys = gather_frames(canon, items.l_p + items.l_t,
                             items.l_c.clamp(max=cfg.target_frames), cfg.target_frames)
        real_mid = gather_frames(canon, items.l_p, items.l_t.clamp(min=1))
        inp, kind, lengths = self._inputs(ctx, keys, items.l_t)
        target, _, _ = _assemble(pack_poses(ctx), pack_poses(real_mid), pack_poses(keys),
                                 items.l_t)
        with torch.no_grad():
            joints = pose_joints(self.skeleton, target)
        return {"inp": inp, "target": target, "joints": joints, "kind": kind,
                "lengths": lengths}

    @staticmethod
    def _crop(data: dict, idx: torch.Tensor) -> dict:
        W = int(data["lengths"][idx].max())
        return {k: (v[idx] if k == "lengths" else v[idx][:, :W]) for k, v in data.items()}

    # -- training ------------------------------------------------------------------------------
    def training_step(self, net: SSMCTNet, batch: dict, epoch: int) -> dict[str, torch.Tensor]:
        """L1 on pose vectors and on FK joint positions of the missing frames."""
        cfg = self.config
        out = net(batch["inp"], batch["kind"], batch["lengths"])
        miss = batch["kind"] == MISSING
        if not bool(miss.any()):  # every pair of the batch has l_t = 0: nothing to predict
            zero = out.sum() * 0.0
            return {"loss": zero, "pose": zero.detach(), "pos": zero.detach()}
        pose = F.l1_loss(out[miss], batch["target"][miss])
        pos = F.l1_loss(pose_joints(self.skeleton, out[miss]), batch["joints"][miss])
        loss = cfg.lambda_pose * pose + cfg.lambda_pos * pos
        return {"loss": loss, "pose": pose.detach(), "pos": pos.detach()}

    def fit(self, train_items: PairItems, *, seed: int, ckpt_dir: str | Path | None = None,
            on_epoch: Callable[[int, dict[str, float]], None] | None = None,
            val_items: PairItems | None = None):
        """AdamW through the one training loop; weights from ``seed``; ``val_items`` give the
        ``val_*`` curve only."""
        return self._fit_adamw(train_items, _check_pairs, seed=seed, ckpt_dir=ckpt_dir,
                               on_epoch=on_epoch, val_items=val_items)

    # -- inference -----------------------------------------------------------------------------
    @torch.no_grad()
    def _complete(self, inp: torch.Tensor, kind: torch.Tensor, lengths: torch.Tensor):
        """Network predictions pasted into the missing frames, in sampling batches (the
        network runs on its device; inputs and result are CPU tensors)."""
        net, bs, dev = self.net, self.config.sample_batch_size, self.device
        net.eval()
        out = inp.clone()
        for s in range(0, inp.shape[0], bs):
            sl = slice(s, min(inp.shape[0], s + bs))
            W = int(lengths[sl].max())
            pred = net(*to_device((inp[sl, :W], kind[sl, :W], lengths[sl]), dev)).cpu()
            miss = kind[sl, :W] == MISSING
            out[sl, :W] = torch.where(miss[..., None], pred, inp[sl, :W])
        return out

    @torch.no_grad()
    def inbetween(self, prev: Motion, prev_lengths, nxt: Motion, l_t, *, seed: int = 0) -> Motion:
        """The ``l_t`` transition frames from the world-frame previous motion ``prev`` (N, ·)
        with ``prev_lengths`` valid frames to the world-frame following action ``nxt`` (N, ·)
        (its first ``target_frames`` frames are the keyframes).  Returns (N, max(l_t, 1))
        world-frame frames, past an item's ``l_t`` repeating its last (an item with ``l_t = 0``
        holds ``nxt``'s first frame).  Deterministic: ``seed`` is ignored."""
        del seed
        cfg = self.config
        if prev.skeleton != self.skeleton or nxt.skeleton != self.skeleton:
            raise DataError("ssmct: motions use a different skeleton than the model")
        N = prev.batch_size
        if nxt.batch_size != N:
            raise ValueError("prev and nxt differ in batch size")
        prev_lengths = torch.as_tensor(prev_lengths, dtype=torch.long).reshape(N)
        l_t = torch.as_tensor(l_t, dtype=torch.long).reshape(N)
        if N and int(l_t.min()) < 0:
            raise ValueError("l_t must be >= 0")
        self._check_window(l_t)
        ctx_w = last_frames(prev, prev_lengths, cfg.context_frames).to(dtype=torch.float32)
        K = cfg.target_frames
        keys_w = gather_frames(nxt, torch.zeros(N, dtype=torch.long),
                               torch.full((N,), min(K, nxt.n_frames), dtype=torch.long), K)
        keys_w = keys_w.to(dtype=torch.float32)
        ctx, params = face_front(ctx_w, anchor=-1)
        keys = canonicalize_with(keys_w, params)
        inp, kind, lengths = self._inputs(ctx, keys, l_t)
        done = self._complete(inp, kind, lengths)
        C, W = cfg.context_frames, max(int(l_t.max()), 1)
        t = C + torch.minimum(torch.arange(W)[None, :], (l_t - 1).clamp(min=0)[:, None])
        t = torch.where(l_t[:, None] == 0, torch.full_like(t, C), t)  # l_t = 0: first key
        frames = done[torch.arange(N)[:, None], t]
        rot6d, root = unpack_poses(frames, self.skeleton.n_joints)
        rot6d = matrix_to_6d(sixd_to_matrix(rot6d))
        out = Motion(root, rot6d, self.skeleton, self.fps)
        return uncanonicalize(out, params).to(dtype=prev.dtype)

    def sample(self, cond_items: PairItems, *, seed: int, use_mean: bool = False) -> GeneratedPairs:
        """``[T̂, S_c]`` per pair: the transition in-betweened from ``S_p`` to the pair's real
        ``S_c`` (an in-betweener reads ``S_c``'s first frames), followed by that ``S_c``."""
        _check_pairs(self, cond_items)
        prev, l_p = cond_items.prev()
        act, l_c = cond_items.action()
        T = self.inbetween(prev, l_p, act, cond_items.l_t, seed=seed)
        return join_pairs(T, cond_items.l_t, act, l_c)
