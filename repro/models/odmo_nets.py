"""The three networks of ODMO (Lu et al., ACM MM'22, §3.2, Fig. 2, supplement Table S2); the
method (losses, training, code bank, sampling) is :mod:`repro.models.odmo`.

Tensors are batch-first; ``J`` joints, ``C`` classes, ``D`` the latent size (20), ``T`` frames.
Poses are absolute xyz of all joints flattened to ``J·3`` per frame (the window frame: the first
frame's root at the origin), in the data set's units.

- :class:`LMPEncoder` ``Es_θ`` (Table S2 "LMP encoder"): the local movement profile (each joint
  minus the root joint, per frame, :func:`lmp`) through one LSTM layer of ``enc_hidden`` (64)
  units; its *last* step goes through the feature layer (FC + BatchNorm + PReLU, width
  ``enc_feature``: the table gives no width, ours 64) and two FC output heads, ``μ`` (D) and
  ``log σ²`` (D).
- :class:`TrajectoryGenerator` ``Gr_φ`` (Table S2): per step the input ``[one-hot(c) ⊗ z (C·D,
  flattened outer product), r_e (3)]`` is repeated over ``T − 1`` steps; embedding = FC, PReLU,
  FC (width ``embed``, ours 128); 2 LSTM layers × ``hidden`` (128); feature = 3 × (FC + PReLU)
  of width ``hidden``; output FC → a velocity (3) per step.  The root trajectory is the
  cumulative sum of the ``T − 1`` velocities with a leading 0 (``r̂_1 = 0``: a window starts at
  the origin; Eq. 2's ``r_0 = 0`` makes the first velocity 0).
- :class:`MotionGenerator` ``Gm_ψ`` (Seq2Seq, Table S2): the trajectory encoder embeds each of the
  ``T`` root positions (FC + PReLU) and runs 2 LSTM layers × ``hidden``; its final ``(h, c)`` is the
  decoder's initial state.  The decoder, at step ``t``, embeds (FC + PReLU) ``[m̃_{t−1} (J·3),
  one-hot(c) ⊗ z (C·D), r̂_t (3)]``, runs 2 LSTM layers × ``hidden`` one step, and an FC gives the
  pose ``m̂_t`` (J·3, absolute xyz).  Choices: the class/code input is the same outer product the
  trajectory generator reads (not ``[one-hot, z]``); ``m̃_0`` (before the first frame) is the
  zero pose; teacher forcing is decided **per step** (one Bernoulli(tf) draw per time step,
  shared by the batch, from the global torch RNG, which the training loop seeds per epoch);
  a fed-back prediction is *not* detached (gradients flow through the recurrence).

The per-term loss formulas (:func:`contrastive_loss`, :func:`kl_term`, :func:`squared_error`)
live here too; how :mod:`repro.models.odmo` combines them is documented there.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from repro import kernels


def lmp(joints: torch.Tensor) -> torch.Tensor:
    """Local movement profile (§3.1): ``joints`` (N, T, J, 3) minus the root joint (joint 0) of
    each frame, flattened to (N, T, J·3) (the root's own three entries are 0)."""
    return (joints - joints[:, :, :1]).flatten(2)


def class_code(labels: torch.Tensor, z: torch.Tensor, n_classes: int) -> torch.Tensor:
    """``one-hot(c) ⊗ z`` flattened: (N, C·D), the block of class ``c`` holds ``z``, the rest 0."""
    onehot = torch.nn.functional.one_hot(labels.long(), n_classes).to(z.dtype)
    return (onehot[:, :, None] * z[:, None, :]).flatten(1)


class LMPEncoder(nn.Module):
    """``Es_θ``: LMP (N, T, J·3) → (μ, log σ²), each (N, D)."""

    def __init__(self, in_dim: int, hidden: int, feature: int, latent: int):
        super().__init__()
        self.lstm = nn.LSTM(in_dim, hidden, num_layers=1, batch_first=True)
        self.feature = nn.Sequential(nn.Linear(hidden, feature), nn.BatchNorm1d(feature),
                                     nn.PReLU())
        self.mu = nn.Linear(feature, latent)
        self.logvar = nn.Linear(feature, latent)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out, _ = self.lstm(x)
        h = self.feature(out[:, -1])
        return self.mu(h), self.logvar(h)


class TrajectoryGenerator(nn.Module):
    """``Gr_φ``: (class code (N, C·D), end point (N, 3)) → velocities (N, T−1, 3) and the
    trajectory (N, T, 3) with ``r̂_1 = 0``."""

    def __init__(self, cond_dim: int, embed: int, hidden: int):
        super().__init__()
        self.embed = nn.Sequential(nn.Linear(cond_dim + 3, embed), nn.PReLU(),
                                   nn.Linear(embed, embed))
        self.lstm = nn.LSTM(embed, hidden, num_layers=2, batch_first=True)
        self.feature = nn.Sequential(nn.Linear(hidden, hidden), nn.PReLU(),
                                     nn.Linear(hidden, hidden), nn.PReLU(),
                                     nn.Linear(hidden, hidden), nn.PReLU())
        self.out = nn.Linear(hidden, 3)

    def forward(self, cond: torch.Tensor, end: torch.Tensor,
                n_frames: int) -> tuple[torch.Tensor, torch.Tensor]:
        if n_frames < 2:
            raise ValueError(f"a trajectory needs at least 2 frames, got {n_frames}")
        x = torch.cat([cond, end.to(cond.dtype)], dim=-1)
        x = self.embed(x)[:, None].expand(-1, n_frames - 1, -1)
        h, _ = self.lstm(x.contiguous())
        vel = self.out(self.feature(h))
        traj = torch.cat([vel.new_zeros(vel.shape[0], 1, 3), torch.cumsum(vel, dim=1)], dim=1)
        return vel, traj


class MotionGenerator(nn.Module):
    """``Gm_ψ``: trajectory (N, T, 3) + class code (N, C·D) → poses (N, T, J·3)."""

    def __init__(self, pose_dim: int, cond_dim: int, embed: int, hidden: int):
        super().__init__()
        self.pose_dim = pose_dim
        self.traj_embed = nn.Sequential(nn.Linear(3, embed), nn.PReLU())
        self.traj_lstm = nn.LSTM(embed, hidden, num_layers=2, batch_first=True)
        self.dec_embed = nn.Sequential(nn.Linear(pose_dim + cond_dim + 3, embed), nn.PReLU())
        self.dec_lstm = nn.LSTM(embed, hidden, num_layers=2, batch_first=True)
        self.out = nn.Linear(hidden, pose_dim)

    def forward(self, traj: torch.Tensor, cond: torch.Tensor, *, tf: float = 0.0,
                target: torch.Tensor | None = None) -> torch.Tensor:
        """Autoregressive decoding over ``traj``'s ``T`` steps.  With ``tf > 0`` and ``target``
        (N, T, J·3), each step feeds the real previous pose with probability ``tf``."""
        N, T = traj.shape[:2]
        _, state = self.traj_lstm(self.traj_embed(traj))
        use_real = None
        if tf > 0.0:
            if target is None:
                raise ValueError("teacher forcing needs the target poses")
            use_real = torch.rand(T) < tf if tf < 1.0 else torch.ones(T, dtype=torch.bool)
            use_real = use_real.tolist()  # read once, not one tensor read per frame
        prev = traj.new_zeros(N, self.pose_dim)
        outs = []
        for t in range(T):
            x = self.dec_embed(torch.cat([prev, cond, traj[:, t]], dim=-1))
            h, state = self.dec_lstm(x[:, None], state)
            pose = self.out(h[:, 0])
            outs.append(pose)
            prev = target[:, t] if use_real is not None and use_real[t] else pose
        return torch.stack(outs, dim=1)


class ODMONet(nn.Module):
    """Every learned piece of ODMO: ``encoder``, ``trajectory``, ``motion``."""

    def __init__(self, n_joints: int, n_classes: int, *, latent: int = 20, enc_hidden: int = 64,
                 enc_feature: int = 64, embed: int = 128, hidden: int = 128):
        super().__init__()
        self.n_joints, self.n_classes, self.latent = int(n_joints), int(n_classes), int(latent)
        pose_dim, cond_dim = 3 * self.n_joints, self.n_classes * self.latent
        self.encoder = LMPEncoder(pose_dim, enc_hidden, enc_feature, latent)
        self.trajectory = TrajectoryGenerator(cond_dim, embed, hidden)
        self.motion = MotionGenerator(pose_dim, cond_dim, embed, hidden)

    def encode(self, joints: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(μ, log σ²) of windows ``joints`` (N, T, J, 3)."""
        return self.encoder(lmp(joints))

    def generate(self, z: torch.Tensor, labels: torch.Tensor, end: torch.Tensor, n_frames: int,
                 *, tf: float = 0.0, target: torch.Tensor | None = None):
        """Decode codes: returns (velocities (N, T−1, 3), trajectory r̂ (N, T, 3), poses
        (N, T, J, 3)).  ``target`` (N, T, J, 3) is only read for teacher forcing."""
        cond = class_code(labels, z, self.n_classes)
        vel, traj = self.trajectory(cond, end, n_frames)
        tgt = None if target is None else target.flatten(2)
        poses = self.motion(traj, cond, tf=tf, target=tgt)
        return vel, traj, poses.unflatten(2, (self.n_joints, 3))


# -- loss terms ----------------------------------------------------------------------------------

def contrastive_loss(mu1: torch.Tensor, mu2: torch.Tensor, same: torch.Tensor, *,
                     margin: float = 5.0, form: str = "code") -> torch.Tensor:
    """Per-pair contrastive term (:mod:`repro.models.odmo` docstring), shape (B,)."""
    d2 = ((mu1 - mu2) ** 2).sum(-1)
    d = kernels.sqrt(d2.clamp_min(1e-12))  # host-independent bits (repro.kernels)
    far = F.relu(margin - d) ** 2
    if form == "code":
        near, far = 0.5 * F.relu(d2 - 0.25), 0.5 * far
    elif form == "paper":
        near = d2
    else:
        raise ValueError(f"unknown contrastive form {form!r}")
    return torch.where(same.bool(), near, far)


def kl_term(logvar: torch.Tensor, *, form: str = "code", sigma2: float = 0.05,
            reading: str = "std") -> torch.Tensor:
    """Per-window variance regulariser (N,), summed over latent dims (:mod:`repro.models.odmo`
    docstring)."""
    if reading not in ("std", "variance"):
        raise ValueError(f"unknown sigma reading {reading!r}")
    v = sigma2 ** 2 if reading == "std" else sigma2
    if form == "code":
        per = 0.5 * math.log(v) - 0.5 * logvar + logvar.exp() / (2.0 * v) - 0.5
    elif form == "paper":
        per = -logvar + logvar.exp() / v
    else:
        raise ValueError(f"unknown KL form {form!r}")
    return per.sum(-1)


def squared_error(err: torch.Tensor, y_weight: float, reduction: str) -> torch.Tensor:
    """``err`` (N, ..., 3): y-weighted squared error, summed (or averaged) over everything but
    the batch, then averaged over the batch."""
    sq = err ** 2 * err.new_tensor([1.0, float(y_weight), 1.0])
    per = sq.flatten(1).sum(1) if reduction == "sum" else sq.flatten(1).mean(1)
    return per.mean()
