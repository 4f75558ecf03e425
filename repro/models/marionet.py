"""MarioNet, the single-action generator of Neural Marionette (Wang et al.), Sec. 4.2.

Network (Sec. 4.2.1, Fig. 3; widths from supp. Table 2, read in docs/marionet.md):

- **Condition Encoder**: FC embeddings (``pose_encode``: pose → d, ``tag_embd``: one-hot tag →
  d, both ReLU) of the ``K`` initial poses, the current tag and the next tag, concatenated as
  ``K + 2`` tokens (+ sinusoidal positions) into a transformer encoder; the output at the
  current-tag token (the "action token", as in ACTOR) gives ``μ`` and ``log σ²`` through two
  independent FC layers; ``Z = μ + σ·ε`` (reparameterisation).
- **Time Unrolling**: a transformer decoder whose query is the reverse positional encoding
  (Rev-PE, time to arrival ``T − t``) of the ``T`` frames, plus the embedded current tag on
  every frame (**Tag Injection**), with key/value ``Z``; frame latents ``z_t ∈ R^d``.
- **Trajectory control**: ``z_t`` projected to ``d̃ = d − d_traj`` (``unroll_embd``, 224), the
  trajectory ``U_t ∈ R²`` embedded (``traj_embd``, 2 → 32) and encoded by a small transformer
  encoder; concatenated into the frame-level controls ``c_t ∈ R^d``.
- **Motion Decoder**: a causal transformer decoder; query = embedded poses ``P_0..P_{T−1}``
  (+ positions), key/value = the controls; output ``P*_1..P*_T`` through ``pose_decode``.
  ``P_0`` (the BOP) is the last initial pose.  Inference runs frame by frame on a cache of
  projected keys/values (:class:`repro.models.layers.DecoderCache`).

Training (Sec. 4.2.2, supp. Sec. 3): ``L = λ1·L_Recon(P') + λ2·L_Recon(P'') + λ_KL·L_KL``
(Eq. 2), ``L_Recon = λ_R·L_R + λ_D·L_D + λ_J·L_J`` (Eq. 1a), each term a per-frame squared
L2 plus ``λ_V`` × the same on frame differences (Eq. 1b-d).  ``R``: 6D local rotations,
``D``: root translation (metres), ``J``: joint positions from our forward kinematics on the
data set's skeleton (in place of SMPL).  Scheduled sampling (supp. Fig. 2): a second,
weight-sharing decoder pass on a per-frame mix of ground truth and first-pass predictions
(share ``ξ`` rising linearly 0 → 1 between the activate and accomplish epochs), used only when
the first pass is within ``ss_threshold_m`` (mean per-joint position error, metres) of the
ground truth; ``λ1/λ2 = 0.1/0.9`` then, ``1/0`` otherwise.

Ablation switches (Table 2): ``scheduled_sampling``, ``time_unrolling`` (off: ``Z`` broadcast
to every frame, plus the tag when Tag Injection is on), ``tag_injection``, ``next_tag`` (the
next-tag token zeroed at training and test).

Poses are ``J×6`` local 6D rotations followed by the root translation (``6J + 3``; 135 for
SMPL's 22 joints, 129 for the stand-in's 21), in each item's Marionette-normalised frame
(:mod:`repro.data.action_items`).  With ``standardize_poses`` (our choice; the paper is silent) the
pose FCs see z-scored features (training statistics, stored with the weights) while losses and
outputs stay in physical units.  Every choice the paper leaves open is listed in
docs/marionet.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import torch
import torch.nn.functional as F
from torch import nn

from repro.data.action_items import ActionItems, GeneratedItems, pad_last
from repro.models.base import Generator, register
from repro.models.baseline_io import check_items
from repro.models.layers import (Packing, TransformerDecoder, TransformerEncoder,
                                 sinusoidal_encoding)
from repro.models.marionet_config import MARIONET, MarioNetConfig
from repro.motion.motion import Motion
from repro.motion.rotations import matrix_to_6d, sixd_to_matrix
from repro.motion.skeleton import forward_kinematics
from repro.seeding import derive_seed, torch_generator
from repro.train.loop import to_device
from repro.train.schedules import linear_ramp
from repro import kernels


def _mlp(n_in: int, n_out: int) -> nn.Sequential:
    """One FC layer with ReLU (supp. Table 2's FC rows)."""
    return nn.Sequential(nn.Linear(n_in, n_out), nn.ReLU())


class MarioNetNet(nn.Module):
    """The three blocks of Fig. 3 (module docstring).  Shapes: poses (B, L, 6J+3), labels (B,),
    trajectories (B, T, 2), lengths (B,) action frames; padded frames are masked out."""

    def __init__(self, cfg: MarioNetConfig, n_joints: int, n_classes: int):
        super().__init__()
        self.cfg, self.n_joints, self.n_classes = cfg, n_joints, n_classes
        d, P = cfg.d_model, 6 * n_joints + 3
        self.pose_dim = P
        self.tag_embed = _mlp(n_classes, d)                      # tag_embd (31 → 256)
        self.pose_encode = _mlp(P, d)                            # pose_encode (135 → 256)
        if not cfg.share_pose_encoder:
            self.cond_pose_encode = _mlp(P, d)
        self.cond_encoder = TransformerEncoder(cfg.cond_layers, d, cfg.cond_heads, cfg.cond_ff,
                                               cfg.cond_dropout, cfg.cond_activation)
        self.mean_head = nn.Linear(d, d)                         # mean_embd
        self.logvar_head = nn.Linear(d, d)                       # std_embd (as log σ²)
        self.unroll = TransformerDecoder(cfg.unroll_layers, d, cfg.unroll_heads, cfg.unroll_ff,
                                         cfg.unroll_dropout, cfg.unroll_activation)
        self.unroll_proj = _mlp(d, d - cfg.traj_dim)             # unroll_embd (256 → 224)
        self.traj_embed = _mlp(2, cfg.traj_dim)                  # traj_embd (2 → 32)
        self.traj_encoder = TransformerEncoder(cfg.traj_layers, cfg.traj_dim, cfg.traj_heads,
                                               cfg.traj_ff, cfg.traj_dropout, cfg.traj_activation)
        self.decoder = TransformerDecoder(cfg.dec_layers, d, cfg.dec_heads, cfg.dec_ff,
                                          cfg.dec_dropout, cfg.dec_activation)
        self.pose_decode = nn.Linear(d, P)                       # pose_decode (256 → 135)
        # per-feature statistics of the training poses (identity until fit sets them)
        self.register_buffer("pose_mean", torch.zeros(P))
        self.register_buffer("pose_std", torch.ones(P))

    def embed_poses(self, poses, encoder=None) -> torch.Tensor:
        """FC embedding of poses in physical units (standardised first when configured)."""
        enc = self.pose_encode if encoder is None else encoder
        if self.cfg.standardize_poses:
            poses = (poses - self.pose_mean) / self.pose_std
        return enc(poses)

    def decode_poses(self, h, packing: Packing | None = None) -> torch.Tensor:
        """``pose_decode``, back to physical units (6D, metres).  With ``packing``, ``h`` holds
        the valid frames only (N, d) and the poses come back padded (B, T, P), the padded
        frames the rest pose (identity rotations, root at the origin: a proper input for
        forward kinematics, masked out of every loss)."""
        p = self.pose_decode(h)
        p = p * self.pose_std + self.pose_mean if self.cfg.standardize_poses else p
        if packing is None:
            return p
        eye = matrix_to_6d(torch.eye(3, dtype=p.dtype, device=p.device))
        return packing.unpack(p, torch.cat([eye.repeat(self.n_joints), p.new_zeros(3)]))

    # -- condition encoder ---------------------------------------------------------------------
    def embed_tags(self, labels: torch.Tensor) -> torch.Tensor:
        return self.tag_embed(F.one_hot(labels, self.n_classes).to(self.mean_head.weight.dtype))

    def encode(self, init_poses, labels, next_labels):
        """(μ, log σ², embedded current tag, embedded next tag), each (B, d)."""
        cfg = self.cfg
        K = init_poses.shape[1]
        tag = self.embed_tags(labels)
        nxt = self.embed_tags(next_labels)
        nxt_token = nxt if cfg.next_tag else nxt * 0.0     # ablation: zeroed, no gradient
        enc = self.pose_encode if cfg.share_pose_encoder else self.cond_pose_encode
        tokens = torch.cat([self.embed_poses(init_poses, enc), tag[:, None], nxt_token[:, None]],
                           dim=1)
        pos = sinusoidal_encoding(torch.arange(K + 2, device=tokens.device), cfg.d_model)
        h = self.cond_encoder(tokens + pos.to(tokens.dtype))
        action_token = h[:, K]
        return self.mean_head(action_token), self.logvar_head(action_token), tag, nxt

    # -- time unrolling and trajectory control ----------------------------------------------------
    @staticmethod
    def padding_mask(lengths: torch.Tensor, T: int) -> torch.Tensor:
        return torch.arange(T, device=lengths.device)[None, :] >= lengths[:, None]

    def unroll_query(self, tag, lengths, T: int) -> torch.Tensor:
        """Rev-PE of frames 1..T (time to arrival ``T_i − t``), plus the tag if injected."""
        rev = lengths[:, None] - 1 - torch.arange(T, device=lengths.device)[None, :]
        q = sinusoidal_encoding(rev, self.cfg.d_model).to(tag.dtype)
        return q + tag[:, None] if self.cfg.tag_injection else q

    def frame_latents(self, z, tag, lengths, T: int, packing: Packing | None = None) -> torch.Tensor:
        """(B, T, d) frame-level latents ``z_1..z_T`` (their valid frames (N, d) with
        ``packing``)."""
        cfg = self.cfg
        if not cfg.time_unrolling:  # ablation: Z broadcast to every frame
            frames = z[:, None].expand(-1, T, -1)
            frames = frames + tag[:, None] if cfg.tag_injection else frames
            return frames if packing is None else packing.pack(frames)
        q = self.unroll_query(tag, lengths, T)
        return self.unroll(q if packing is None else packing.pack(q), z[:, None], causal=False,
                           self_padding_mask=self.padding_mask(lengths, T), packing=packing)

    def controls(self, z, tag, trajectory, lengths, packing: Packing | None = None) -> torch.Tensor:
        """(B, T, d) frame-level controls ``[z̃_t ‖ u_t]`` (d̃ + d_traj); with ``packing``
        (:class:`~repro.models.layers.Packing` of the valid frames) those of the valid frames
        only, (N, d): every position-wise layer then skips the padded frames (issue 31)."""
        T = trajectory.shape[1]
        pad = self.padding_mask(lengths, T)
        latent = self.unroll_proj(self.frame_latents(z, tag, lengths, T, packing))
        u = self.traj_embed(trajectory)
        if self.cfg.traj_positional:
            u = u + sinusoidal_encoding(torch.arange(T, device=u.device), self.cfg.traj_dim).to(u.dtype)
        u = self.traj_encoder(u if packing is None else packing.pack(u), key_padding_mask=pad,
                              packing=packing)
        return torch.cat([latent, u], dim=-1)

    # -- motion decoder --------------------------------------------------------------------------
    def _query(self, poses, start: int, first_feature=None):
        x = self.embed_poses(poses)
        if first_feature is not None and start == 0:
            x = torch.cat([first_feature[:, None].to(x.dtype), x[:, 1:]], dim=1)
        pos = sinusoidal_encoding(torch.arange(start, start + x.shape[1], device=x.device),
                                  self.cfg.d_model)
        return x + pos.to(x.dtype)

    def decode(self, poses_in, controls, lengths, first_feature=None,
               packing: Packing | None = None) -> torch.Tensor:
        """Teacher-forced parallel pass: poses ``P_0..P_{T−1}`` (B, T, P) → ``P*_1..P*_T``.
        ``first_feature`` (B, d) replaces the BOP embedding (Shadow Start, Sec. 4.3.2).  With
        ``packing``, ``controls`` are the valid frames' (:meth:`controls` with the same
        packing) and only the valid frames are computed (the output is padded)."""
        if packing is None:
            T = controls.shape[1]
            y = self.decoder(self._query(poses_in, 0, first_feature), controls, causal=True,
                             mem_padding_mask=self.padding_mask(lengths, T))
            return self.decode_poses(y)
        if first_feature is not None:
            raise ValueError("a packed decode takes no first_feature (Shadow Start decodes unpacked)")
        T = poses_in.shape[1]
        if (packing.B, packing.T, len(packing.index)) != (poses_in.shape[0], T, controls.shape[0]):
            raise ValueError("packed decode: poses, controls and packing disagree in shape")
        x = self.embed_poses(packing.pack(poses_in))
        x = x + sinusoidal_encoding(packing.index % T, self.cfg.d_model).to(x.dtype)
        y = self.decoder(x, controls, causal=True, mem_padding_mask=self.padding_mask(lengths, T),
                         packing=packing, mem_packing=packing)
        return self.decode_poses(y, packing)

    def generate(self, bop, controls, lengths, *, use_cache: bool = True,
                 first_feature=None) -> torch.Tensor:
        """Frame-by-frame inference (Sec. 4.2.3): ``bop`` (B, P) → (B, T, P), T = controls'
        length.  ``use_cache=False`` recomputes the full causal pass at every step.

        The cached path (inference only) allocates everything once per call: the decoder's
        cache for ``T`` steps and its step weights (:meth:`TransformerDecoder.init_cache`),
        the ``T`` positional encodings and the output; each step embeds the previous pose, runs
        one token through the decoder and writes its pose in place.  It computes what
        :meth:`_query` + the parallel causal pass compute, step by step."""
        T = controls.shape[1]
        pad = self.padding_mask(lengths, T)
        if use_cache:
            with torch.inference_mode():
                cache = self.decoder.init_cache(controls, pad, max_len=T)
                pos = sinusoidal_encoding(torch.arange(T, device=controls.device),
                                          self.cfg.d_model).to(controls.dtype)
                out = controls.new_empty(bop.shape[0], T, self.pose_dim)
                prev = bop
                for t in range(T):
                    if t == 0 and first_feature is not None:   # Shadow Start: replaces the BOP
                        x = first_feature[:, None].to(controls.dtype)
                    else:
                        x = self.embed_poses(prev[:, None])
                    p = self.decode_poses(self.decoder.step(x + pos[t], cache))[:, 0]
                    out[:, t] = p
                    prev = p
                return out
        outs = []
        seq = bop[:, None]
        for t in range(T):
            y = self.decoder(self._query(seq, 0, first_feature), controls, causal=True,
                             mem_padding_mask=pad)
            p = self.decode_poses(y[:, -1])
            outs.append(p)
            seq = torch.cat([seq, p[:, None]], dim=1)
        return torch.stack(outs, dim=1)


# ---------------------------------------------------------------------------------------------
# poses and losses


def pack_poses(motion: Motion) -> torch.Tensor:
    """(B, T, 6J + 3): local 6D rotations (joint-major) then the root translation."""
    B, T = motion.batch_size, motion.n_frames
    return torch.cat([motion.rot6d.reshape(B, T, -1), motion.root], dim=-1)


def unpack_poses(poses: torch.Tensor, n_joints: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Inverse of :func:`pack_poses`: (rot6d (..., J, 6), root (..., 3))."""
    return poses[..., :-3].reshape(poses.shape[:-1] + (n_joints, 6)), poses[..., -3:]


def _term(pred, target, mask, lengths, lambda_v: float) -> torch.Tensor:
    """Eq. 1b-d for one quantity: (1/T) Σ_t ‖x_t − x̂_t‖² + λ_V (1/(T−1)) Σ_t ‖x'_t − x̂'_t‖²,
    per item, averaged over the batch.  pred/target (B, T, F), mask (B, T)."""
    m = mask.to(pred.dtype)
    e = ((pred - target) ** 2).sum(-1)
    pos = (e * m).sum(1) / lengths.to(pred.dtype)
    dv = (pred[:, 1:] - pred[:, :-1]) - (target[:, 1:] - target[:, :-1])
    ev = (dv ** 2).sum(-1) * m[:, 1:]
    vel = ev.sum(1) / (lengths - 1).clamp(min=1).to(pred.dtype)
    return (pos + lambda_v * vel).mean()


def local_joints(skeleton, rotmats: torch.Tensor) -> torch.Tensor:
    """Root-relative joint positions (..., J, 3) of Eq. 1a's joint term (FK with zero root
    translation; the root's rotation is kept)."""
    zero = torch.zeros(rotmats.shape[:-3] + (3,), dtype=rotmats.dtype, device=rotmats.device)
    return forward_kinematics(skeleton, rotmats, zero)


def reconstruction_loss(cfg: MarioNetConfig, skeleton, pred, target, target_joints, mask,
                        lengths) -> dict[str, torch.Tensor]:
    """Eq. 1a on poses (B, T, 6J+3); ``target_joints`` (B, T, J, 3) in ``cfg.joint_loss``'s
    space.  Also returns the mean per-joint world position error ``mpjpe`` (metres)."""
    J = skeleton.n_joints
    r_hat, d_hat = unpack_poses(pred, J)
    r, d = unpack_poses(target, J)
    jl_hat = local_joints(skeleton, sixd_to_matrix(r_hat))
    j_hat = jl_hat if cfg.joint_loss == "local" else jl_hat + d_hat[..., None, :]
    B, T = pred.shape[:2]
    L_R = _term(r_hat.reshape(B, T, -1), r.reshape(B, T, -1), mask, lengths, cfg.lambda_v)
    L_D = _term(d_hat, d, mask, lengths, cfg.lambda_v)
    L_J = _term(j_hat.reshape(B, T, -1), target_joints.reshape(B, T, -1), mask, lengths,
                cfg.lambda_v)
    with torch.no_grad():
        world_hat = jl_hat + d_hat[..., None, :]
        world = target_joints + (d[..., None, :] if cfg.joint_loss == "local" else 0.0)
        err = (world_hat - world).norm(dim=-1).mean(-1)
        mpjpe = (err * mask).sum() / mask.sum()
    total = cfg.lambda_r * L_R + cfg.lambda_d * L_D + cfg.lambda_j * L_J
    return {"total": total, "L_R": L_R, "L_D": L_D, "L_J": L_J, "mpjpe": mpjpe}


#: floor on a feature's standard deviation (6D units; metres for the root)
MIN_POSE_STD = 1e-2


def pose_statistics(data: dict) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-feature mean and standard deviation (floored at ``MIN_POSE_STD``) over every real
    pose of the training items: the initial frames and the valid action frames."""
    mask = torch.arange(data["target"].shape[1])[None, :] < data["lengths"][:, None]
    frames = torch.cat([data["init"].reshape(-1, data["init"].shape[-1]), data["target"][mask]])
    frames = frames.double()
    return frames.mean(0).float(), frames.std(0).clamp(min=MIN_POSE_STD).float()


def kl_divergence(mu, logvar) -> torch.Tensor:
    """KL(N(μ, σ²) ‖ N(0, I)), summed over latent dimensions, averaged over the batch."""
    return (-0.5 * (1 + logvar - mu ** 2 - logvar.exp()).sum(-1)).mean()


# ---------------------------------------------------------------------------------------------


@register
class MarioNet(Generator):
    """Neural Marionette's MarioNet behind the :class:`~repro.models.base.Generator` interface."""

    card = MARIONET
    uses = frozenset({"label", "length", "initial_motion", "next_label", "trajectory"})

    def __init__(self, config, skeleton, n_classes: int, fps: float):
        super().__init__(config, skeleton, n_classes, fps)
        self._build(derive_seed(0, self.method_id, "construct"))

    def _make_network(self) -> MarioNetNet:
        return MarioNetNet(self.config, self.skeleton.n_joints, self.n_classes)

    @property
    def network(self) -> MarioNetNet:
        return self.net

    # -- data --------------------------------------------------------------------------------
    def _check_items(self, items: ActionItems) -> None:
        if not isinstance(items, ActionItems):
            raise TypeError("MarioNet needs repro.data.action_items.ActionItems")
        check_items(self, items)

    def _tensors(self, items: ActionItems, with_targets: bool) -> dict[str, torch.Tensor]:
        out = {"init": pack_poses(items.initial).float(), "labels": items.labels,
               "next_labels": items.next_labels, "lengths": items.lengths,
               "trajectory": items.trajectory.float()}
        if with_targets:
            target = pack_poses(items.action).float()
            out["target"] = target
            r, d = unpack_poses(target, self.skeleton.n_joints)
            with torch.no_grad():
                jl = local_joints(self.skeleton, sixd_to_matrix(r))
            out["joints"] = jl if self.config.joint_loss == "local" else jl + d[..., None, :]
        return out

    @staticmethod
    def _crop(data: dict, idx: torch.Tensor) -> dict:
        T = int(data["lengths"][idx].max())
        b = {}
        for k, v in data.items():
            v = v[idx]
            b[k] = v[:, :T] if k in ("target", "joints", "trajectory") else v
        return b

    # -- training ------------------------------------------------------------------------------
    def training_step(self, net: MarioNetNet, batch: dict, epoch: int) -> dict[str, torch.Tensor]:
        """Loss of Eq. 2 on one batch (randomness from the global torch RNG, which the training
        loop seeds per epoch)."""
        cfg = self.config
        lengths = batch["lengths"]
        T = batch["target"].shape[1]
        mask = ~net.padding_mask(lengths, T)
        mu, logvar, tag, _ = net.encode(batch["init"], batch["labels"], batch["next_labels"])
        z = mu + torch.exp(0.5 * logvar) * torch.randn_like(mu)
        packing = Packing(mask) if cfg.packed_frames else None         # valid frames only
        ctrl = net.controls(z, tag, batch["trajectory"], lengths, packing)
        bop = batch["init"][:, -1:]
        gt_in = torch.cat([bop, batch["target"][:, :-1]], dim=1)       # P_0 .. P_{T-1}
        p1 = net.decode(gt_in, ctrl, lengths, packing=packing)          # P'_1 .. P'_T
        rec1 = reconstruction_loss(cfg, self.skeleton, p1, batch["target"], batch["joints"],
                                   mask, lengths)
        xi = linear_ramp(epoch, cfg.ss_activate_epoch, cfg.ss_accomplish_epoch)
        active = (cfg.scheduled_sampling and epoch >= cfg.ss_activate_epoch
                  and float(rec1["mpjpe"]) < cfg.ss_threshold_m)
        zero = p1.new_zeros(())
        if active:
            pred = p1.detach() if cfg.ss_detach else p1
            take = (torch.rand(p1.shape[:2], device=p1.device) < xi)[:, :-1, None]
            mixed = torch.where(take, pred[:, :-1], batch["target"][:, :-1])  # P^mix_1..P^mix_{T-1}
            p2 = net.decode(torch.cat([bop, mixed], dim=1), ctrl, lengths,
                            packing=packing)                                  # P''_1 .. P''_T
            rec2 = reconstruction_loss(cfg, self.skeleton, p2, batch["target"], batch["joints"],
                                       mask, lengths)["total"]
            lam1, lam2 = cfg.ss_lambda1, cfg.ss_lambda2
        else:
            rec2, lam1, lam2 = zero, 1.0, 0.0
        kl = kl_divergence(mu, logvar)
        loss = lam1 * rec1["total"] + lam2 * rec2 + cfg.lambda_kl * kl
        f = lambda x: p1.new_tensor(float(x))  # noqa: E731
        return {"loss": loss, "rec1": rec1["total"].detach(), "rec2": rec2.detach(),
                "L_R": rec1["L_R"].detach(), "L_D": rec1["L_D"].detach(),
                "L_J": rec1["L_J"].detach(), "kl": kl.detach(), "mpjpe": rec1["mpjpe"],
                "ss_active": f(active), "xi": f(xi if active else 0.0),
                "lambda1": f(lam1), "lambda2": f(lam2)}

    def plateau_rule(self):
        """The convergence rule (issue 32).  Scheduled sampling (supp. Sec. 3) moves the loss's
        weights (λ1 = 1, λ2 = 0 before it is active; 0.1 and 0.9 after) and the second pass's
        share ξ between the activate and accomplish epochs, so ``val_loss`` has one meaning
        only from ``ss_accomplish_epoch`` (ξ = 1), and only on epochs where sampling was active
        on every held-out batch (``val_ss_active`` = 1: the gate); the rule reads it there.
        The teacher-forced first pass's ``val_mpjpe`` would keep its meaning throughout, but it
        carries a tenth of the loss once sampling is active and may rise while the model
        improves.  Without scheduled sampling (an ablation) the loss never changes meaning."""
        from repro.train.plateau import PlateauRule

        if not self.config.scheduled_sampling:
            return PlateauRule()
        return PlateauRule(gate="val_ss_active", start_epoch=int(self.config.ss_accomplish_epoch))

    def fit(self, train_items: ActionItems, *, seed: int, ckpt_dir: str | Path | None = None,
            on_epoch: Callable[[int, dict[str, float]], None] | None = None,
            val_items: ActionItems | None = None):
        """Adam (lr 1e-4), batch 30, 1,000 epochs at paper scale (supp. Sec. 3), through the one
        training loop; weights are initialised from ``seed``.  With ``val_items`` each epoch
        also records Eq. 2's terms on them (``val_loss``, ``val_rec1``, ...; the scheduled
        sampling gate decided on the validation batch's own first-pass error)."""
        self._check_items(train_items)
        if val_items is not None:
            self._check_items(val_items)
        cfg = self.config
        self._build(derive_seed(seed, self.method_id, "init"))
        data = self._tensors(train_items, with_targets=True)
        if cfg.standardize_poses:
            mean, std = pose_statistics(data)
            self.net.pose_mean.copy_(mean)
            self.net.pose_std.copy_(std)
        opt = kernels.adam(self.net.parameters(), lr=cfg.lr)
        val_data = None if val_items is None else self._tensors(val_items, with_targets=True)
        return self._fit_batches(train_items, data, opt, seed=seed, ckpt_dir=ckpt_dir,
                                 on_epoch=on_epoch, val_items=val_items, val_data=val_data,
                                 grad_clip=cfg.grad_clip)

    # -- inference -------------------------------------------------------------------------------
    def _finish(self, items: ActionItems, poses: torch.Tensor) -> GeneratedItems:
        rot6d, root = unpack_poses(poses, self.skeleton.n_joints)
        rot6d = matrix_to_6d(sixd_to_matrix(rot6d))          # orthonormal 6D
        rot6d, root = pad_last(rot6d, items.lengths), pad_last(root, items.lengths)
        motion = Motion(root, rot6d, self.skeleton, self.fps)
        return GeneratedItems(items.to_world(motion), items.lengths.clone(), items.labels.clone())

    #: the label of the per-item noise stream (subclasses sharing MarioNet's weights keep it, so
    #: their plain passes are bitwise MarioNet's)
    noise_id = "marionet"

    @torch.no_grad()
    def generate_poses(self, cond_items: ActionItems, *, seed: int, use_mean: bool = False,
                       use_cache: bool | None = None,
                       first_feature: torch.Tensor | None = None) -> torch.Tensor:
        """The sampler's raw output: (N, T_max, 6J+3) decoder poses in each item's normalised
        frame (Sec. 4.2.3: ``Z ~ N(μ, σ²)``, or ``μ`` when ``use_mean``; controls from the
        Rev-PE of the item's duration and its trajectory; frame-by-frame decoding from the BOP).
        ``use_cache`` (default ``config.kv_cache``) picks the key/value-cached decoder or the
        full causal recomputation at every step.  Noise is drawn per item, in item order, from
        ``seed``, so results do not depend on ``sample_batch_size``.  ``first_feature`` (N, d)
        replaces each item's BOP embedding at decoder step 0 (Shadow Start, Sec. 4.3.2)."""
        self._check_items(cond_items)
        cfg, net = self.config, self.net
        net.eval()
        use_cache = cfg.kv_cache if use_cache is None else use_cache
        data = self._tensors(cond_items, with_targets=False)
        N, Tmax = len(cond_items), int(cond_items.lengths.max())
        if first_feature is not None and tuple(first_feature.shape) != (N, cfg.d_model):
            raise ValueError(f"first_feature must be ({N}, {cfg.d_model})")
        eps = torch.randn(N, cfg.d_model, generator=torch_generator(seed, self.noise_id, "z"))
        out = torch.zeros(N, Tmax, net.pose_dim)
        for idx, b, mu, ctrl in self._controlled_batches(data, N, eps, use_mean):
            ff = None if first_feature is None else first_feature[idx].to(mu.device)
            gen = net.generate(b["init"][:, -1], ctrl, b["lengths"], use_cache=use_cache,
                               first_feature=ff)
            out[idx, :gen.shape[1]] = gen.to(out.device)
        return out

    def _controlled_batches(self, data: dict, N: int, eps: torch.Tensor, use_mean: bool):
        """Batches of ``sample_batch_size`` items on the device, each with its latent mean
        ``mu`` and the decoder's control sequence from ``z`` (the mean, or drawn with ``eps``):
        yields (idx, batch, mu, controls); what sampling and the teacher-forced pass share."""
        net, size = self.net, self.config.sample_batch_size
        for s in range(0, N, size):
            idx = torch.arange(s, min(N, s + size))
            b = to_device(self._crop(data, idx), self.device)
            mu, logvar, tag, _ = net.encode(b["init"], b["labels"], b["next_labels"])
            z = mu if use_mean else mu + torch.exp(0.5 * logvar) * eps[idx].to(mu.device)
            yield idx, b, mu, net.controls(z, tag, b["trajectory"], b["lengths"])

    def finish(self, items: ActionItems, poses: torch.Tensor) -> GeneratedItems:
        """Raw poses (N, T_max, 6J+3) in the items' frames → world-frame GeneratedItems
        (6D orthonormalised by Gram-Schmidt, padding repeats the last valid frame, Eq. 5)."""
        return self._finish(items, poses)

    def sample(self, cond_items: ActionItems, *, seed: int, use_mean: bool = False,
               use_cache: bool | None = None) -> GeneratedItems:
        """One generated action per item, in the world frame (see :meth:`generate_poses`)."""
        poses = self.generate_poses(cond_items, seed=seed, use_mean=use_mean, use_cache=use_cache)
        with torch.no_grad():
            return self._finish(cond_items, poses)

    @torch.no_grad()
    def teacher_forced(self, items: ActionItems, *, seed: int, use_mean: bool = True) -> GeneratedItems:
        """One parallel decoder pass on the ground-truth poses (the training-time first pass;
        the basis of a teacher-forced joint position error)."""
        self._check_items(items)
        cfg, net = self.config, self.net
        net.eval()
        data = self._tensors(items, with_targets=True)
        N, Tmax = len(items), int(items.lengths.max())
        eps = torch.randn(N, cfg.d_model, generator=torch_generator(seed, self.method_id, "z"))
        out = torch.zeros(N, Tmax, net.pose_dim)
        for idx, b, mu, ctrl in self._controlled_batches(data, N, eps, use_mean):
            gt_in = torch.cat([b["init"][:, -1:], b["target"][:, :-1]], dim=1)
            out[idx, :ctrl.shape[1]] = net.decode(gt_in, ctrl, b["lengths"]).to(out.device)
        return self._finish(items, out)
