"""ACTOR (Petrovich et al., ICCV 2021, "Action-Conditioned 3D Human Motion Synthesis with
Transformer VAE"), Neural Marionette's label-only reference row (Sec. 5.1.1: "it cannot take the
initial poses as input").

Network (Petrovich et al. Sec. 3, Fig. 2; sizes from the authors' training commands,
docs/baselines.md): a transformer VAE of width ``latent_dim`` (256), ``num_layers`` (8) layers
each side, 4 heads, feed-forward 1024, dropout 0.1, GELU, post-norm layers:

- **encoder**: the frames' pose vectors embedded by one FC layer, preceded by two learned
  action-specific tokens ``μ_a`` and ``Σ_a`` (``mu_query``/``sigma_query``, one row per class);
  sinusoidal positions (with dropout) over the ``T + 2`` tokens; padded frames masked; the
  outputs at the two tokens are ``μ`` and ``log σ²``;
- **decoder**: the memory is one token ``z + b_a`` (the learned action bias ``b_a``); the
  queries are the sinusoidal encodings of ``t = 0 .. T−1`` (the duration is given); a
  transformer decoder without causal mask (padded queries masked) and a final FC layer give
  the ``T`` pose vectors at once; padded frames are zeroed.

Poses are the 6D rotations of every joint (the root's global rotation included, ACTOR's
``--glob``) and the root translation (``--translation``), i.e. the pose vector of
:mod:`repro.models.baseline_io`, in the item's normalised frame.

Training (the authors' ``cvae_transformer_rc_rcxyz_kl``):
``L = λ_rc·MSE(P̂, P) + λ_rcxyz·MSE(J(P̂), J(P)) + λ_KL·KL(N(μ, σ²) ‖ N(0, I))``, the MSEs
averaged over valid frames and features, ``J`` the joint positions relative to the root
(metres; ACTOR's ``--no-vertstrans``) by forward kinematics on the data set's skeleton, the KL
summed over the batch and the latent dimensions (as the authors' ``compute_kl_loss``); AdamW
(lr 1e-4, PyTorch's default weight decay 0.01), batch 20.

Sampling: ``z ~ N(0, I)`` (``z = 0`` when ``use_mean``), decoded for the item's duration.

**Where an ACTOR motion starts** (our choice): ACTOR sees no initial motion, so its output is
produced in a canonical frame and placed in the world by the item's own inverse normalisation
(Eq. 5), exactly like every other method's output: the motion starts at the item's
canonical frame (the position and heading of the condition's last initial pose).  Training
targets are expressed in that same frame (the frame of the pose just before the action), which
is ACTOR's own convention up to one frame (it moves each sequence's first frame to the
origin).  This keeps the trajectory error (Table 1 prints one for ACTOR) measured in the
frame the trajectory is given in, and in Alg. 1 chains an ACTOR action begins where the
previous one ended, facing its way; it is placement, not conditioning: ACTOR's poses never
depend on the initial motion.  Units: metres, frames at the items' fps.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import torch
import torch.nn.functional as F
from torch import nn

from repro.data.action_items import ActionItems, GeneratedItems
from repro.models.actor_config import ACTOR, ACTORConfig
from repro.models.base import Generator, register
from repro.models.baseline_io import (check_items, item_noise, length_mask, pack_poses,
                                      pose_dim, pose_joints, to_generated)
from repro.models.layers import (Dropout, TransformerDecoder, TransformerEncoder,
                                 sinusoidal_encoding)
from repro.seeding import derive_seed
from repro.train.loop import to_device


class ACTORNet(nn.Module):
    """Encoder and decoder of the module docstring.  Poses (B, T, 6J+3), labels (B,),
    lengths (B,)."""

    def __init__(self, cfg: ACTORConfig, n_joints: int, n_classes: int):
        super().__init__()
        self.cfg, self.n_classes = cfg, n_classes
        d, P = cfg.latent_dim, pose_dim(n_joints)
        self.mu_query = nn.Parameter(torch.randn(n_classes, d))
        self.sigma_query = nn.Parameter(torch.randn(n_classes, d))
        self.action_bias = nn.Parameter(torch.randn(n_classes, d))
        self.skel_embed = nn.Linear(P, d)
        self.encoder = TransformerEncoder(cfg.num_layers, d, cfg.num_heads, cfg.ff_size,
                                          cfg.dropout, cfg.activation)
        self.decoder = TransformerDecoder(cfg.num_layers, d, cfg.num_heads, cfg.ff_size,
                                          cfg.dropout, cfg.activation)
        self.final = nn.Linear(d, P)
        self.pos_drop = Dropout(cfg.dropout)

    def _positions(self, x: torch.Tensor) -> torch.Tensor:
        pe = sinusoidal_encoding(torch.arange(x.shape[1], device=x.device), self.cfg.latent_dim)
        return self.pos_drop(x + pe.to(x.dtype))

    def encode(self, poses, labels, lengths) -> tuple[torch.Tensor, torch.Tensor]:
        """(μ, log σ²), each (B, latent_dim)."""
        B, T = poses.shape[:2]
        tokens = torch.cat([self.mu_query[labels][:, None], self.sigma_query[labels][:, None],
                            self.skel_embed(poses)], dim=1)
        pad = torch.cat([torch.zeros(B, 2, dtype=torch.bool, device=poses.device),
                         ~length_mask(lengths, T)], dim=1)
        h = self.encoder(self._positions(tokens), key_padding_mask=pad)
        return h[:, 0], h[:, 1]

    def decode(self, z, labels, lengths, T: int) -> torch.Tensor:
        """(B, T, 6J+3) poses for latent ``z`` (B, latent_dim); padded frames are zero."""
        B = z.shape[0]
        memory = (z + self.action_bias[labels])[:, None]
        queries = self._positions(z.new_zeros(B, T, self.cfg.latent_dim))
        valid = length_mask(lengths, T)
        y = self.decoder(queries, memory, causal=False, self_padding_mask=~valid)
        return self.final(y) * valid[..., None].to(y.dtype)


@register
class ACTOR(Generator):
    """ACTOR behind the :class:`~repro.models.base.Generator` interface (module docstring)."""

    card = ACTOR
    uses = frozenset({"label", "length"})

    def __init__(self, config, skeleton, n_classes: int, fps: float):
        super().__init__(config, skeleton, n_classes, fps)
        self._build(derive_seed(0, self.method_id, "construct"))

    def _make_network(self) -> ACTORNet:
        return ACTORNet(self.config, self.skeleton.n_joints, self.n_classes)

    @property
    def network(self) -> ACTORNet:
        return self.net

    # -- training ------------------------------------------------------------------------------
    def plateau_rule(self):
        """The convergence rule (issue 32) reads ``val_loss`` and ``val_kl``: λ_KL = 1e-5 (Sec.
        3.3) leaves the loss almost all reconstruction, blind to the per-action prior the
        generator samples from; the held-out KL measures it."""
        from repro.train.plateau import PlateauRule

        return PlateauRule(also=("val_kl",))

    def training_step(self, net: ACTORNet, batch: dict, epoch: int) -> dict[str, torch.Tensor]:
        """``L`` of the module docstring on one batch (reparameterisation noise from the global
        torch RNG, which the training loop seeds per epoch)."""
        cfg = self.config
        x, labels, lengths = batch["poses"], batch["labels"], batch["lengths"]
        T = x.shape[1]
        mu, logvar = net.encode(x, labels, lengths)
        z = mu + torch.exp(0.5 * logvar) * torch.randn_like(mu)
        out = net.decode(z, labels, lengths, T)
        valid = length_mask(lengths, T)
        rc = F.mse_loss(out[valid], x[valid])
        joints = pose_joints(self.skeleton, out[valid], with_root=False)  # padded frames are 0
        rcxyz = F.mse_loss(joints, batch["joints"][valid])
        kl = -0.5 * (1 + logvar - mu ** 2 - logvar.exp()).sum()
        loss = cfg.lambda_rc * rc + cfg.lambda_rcxyz * rcxyz + cfg.lambda_kl * kl
        return {"loss": loss, "rc": rc.detach(), "rcxyz": rcxyz.detach(), "kl": kl.detach()}

    def _tensors(self, items: ActionItems) -> dict[str, torch.Tensor]:
        poses = pack_poses(items.action)
        with torch.no_grad():
            joints = pose_joints(self.skeleton, poses, with_root=False)
        return {"poses": poses, "joints": joints, "labels": items.labels, "lengths": items.lengths}

    @staticmethod
    def _crop(data: dict, idx: torch.Tensor) -> dict:
        T = int(data["lengths"][idx].max())
        return {k: (v[idx][:, :T] if k in ("poses", "joints") else v[idx]) for k, v in data.items()}

    def fit(self, train_items: ActionItems, *, seed: int, ckpt_dir: str | Path | None = None,
            on_epoch: Callable[[int, dict[str, float]], None] | None = None,
            val_items: ActionItems | None = None):
        """AdamW (lr 1e-4), batch 20, through the one training loop; weights from ``seed``.
        ``val_items``: the same loss terms on held-out items enter each epoch's history
        (``val_*``)."""
        return self._fit_adamw(train_items, check_items, seed=seed, ckpt_dir=ckpt_dir,
                               on_epoch=on_epoch, val_items=val_items)

    # -- inference -----------------------------------------------------------------------------
    @torch.no_grad()
    def generate_poses(self, cond_items: ActionItems, *, seed: int,
                       use_mean: bool = False) -> torch.Tensor:
        """(N, T_max, 6J+3) poses in the canonical frame, from the tags and durations only
        (a CPU tensor; the noise is drawn on the CPU, the network runs on its device)."""
        check_items(self, cond_items)
        cfg, net = self.config, self.net
        net.eval()
        N, Tmax = len(cond_items), int(cond_items.lengths.max())
        eps = item_noise(seed, self.method_id, (N, cfg.latent_dim))
        out = torch.zeros(N, Tmax, pose_dim(self.skeleton.n_joints))
        dev = self.device
        for s in range(0, N, cfg.sample_batch_size):
            idx = torch.arange(s, min(N, s + cfg.sample_batch_size))
            lengths = cond_items.lengths[idx]
            T = int(lengths.max())
            z = torch.zeros_like(eps[idx]) if use_mean else eps[idx]
            out[idx, :T] = net.decode(*to_device((z, cond_items.labels[idx], lengths), dev),
                                      T).cpu()
        return out

    def sample(self, cond_items: ActionItems, *, seed: int, use_mean: bool = False) -> GeneratedItems:
        """One action per item, placed at the item's canonical frame in the world (module
        docstring)."""
        poses = self.generate_poses(cond_items, seed=seed, use_mean=use_mean)
        return to_generated(self, cond_items, poses)
