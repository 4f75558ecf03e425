"""MANN (Zhang et al., SIGGRAPH 2018, "Mode-Adaptive Neural Networks for Quadruped Motion
Control") as Neural Marionette adapted it (supp. Sec. 4.1): autoregressive next-pose
prediction from the previous pose, the action tag and the trajectory.

Network (Zhang et al. Sec. 4; sizes from the authors' code, docs/baselines.md):

- **Gating network** Ω: 3 fully connected layers (``gating_hidden`` = 32 units, ELU, dropout),
  softmax over ``n_experts`` (8) blending coefficients ``ω`` (Eq. 1-2);
- **Motion prediction network** Φ: 3 fully connected layers (``hidden`` = 512 units, ELU,
  dropout) whose weights are blended per frame from the experts, ``α = Σ_k ω_k α_k`` (Eq. 3).
  Because every layer is linear before its activation, ``(Σ_k ω_k α_k)·x = Σ_k ω_k (α_k·x)``;
  we evaluate the right-hand side (the same function, without a per-sample weight matrix).

Adaptation to human action generation (MANN has no tag, duration or 6D pose; our choices,
docs/baselines.md):

- frame ``t`` (1..T) is predicted from the previous two poses ``P_{t−1}``, ``P_{t−2}`` (the last
  two initial poses start the chain), the one-hot tag and the trajectory;
- **input** ``x_t``: local 6D rotations of ``P_{t−1}`` (6J); its joint positions relative to the
  root (3J, metres); joint velocities ``J(P_{t−1}) − J(P_{t−2})`` (3J, m/frame); the root height
  (1); a trajectory window like MANN's (12 samples over 2 s: offsets ``traj_step·k``,
  ``k = −traj_past .. traj_future − 1`` frames around ``t``) of the control path (the initial
  root's ground positions, then the trajectory ``U``) relative to the previous root, plus the
  path's per-frame velocity at each sample (4 × 12); the one-hot tag (C); optionally the
  progress ``t/T`` (``progress_input``; off by default: MANN has no clock);
- **gating input** (MANN: foot velocities, desired velocity, action variables): the velocities
  of the skeleton's end effectors (its leaf joints), the desired velocity (the path's velocity
  at ``t``) and the tag, taken as columns of the normalised input, as in MANN;
- **output** ``y_t``: local 6D rotations of ``P_t`` (6J) and the root displacement
  ``root_t − root_{t−1}`` (3, metres);
- inputs and outputs are normalised by their training mean and standard deviation (kept in the
  weights), as MANN does.

Everything is in the item's Marionette-normalised frame (items.py); samples go back to the world
with the item's inverse normalisation.  MANN is deterministic: ``seed`` and ``use_mean`` do not
change its output.

Training (Zhang et al. Sec. 6; the authors' code): loss ``L = mean ‖ŷ_t − y_t‖²`` over the
normalised output (Eq. 4), teacher forcing (each pair ``(x_t, y_t)`` from the data), AdamW with
warm restarts (Loshchilov & Hutter): learning rate 1e-4 and weight decay 2.5e-3 both scaled by
``η = ½(1 + cos(π·min(T_cur, 0.9)))`` per batch, restarts after 10, 30, 70, 150 epochs
(``T_e = 10``, ``T_mult = 2``), the weight decay normalised by ``√(batches per epoch · T_e)``;
batch 32, 150 epochs, dropout 0.3 (keep probability 0.7).

Units: metres, frames at the items' fps.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Callable

import torch
import torch.nn.functional as F
from torch import nn

from repro.data.action_items import ActionItems, GeneratedItems, pad_last
from repro.models.base import Generator, epoch_batches, register
from repro.models.baseline_io import (check_items, pack_poses, pose_joints, to_generated,
                                      unpack_poses)
from repro.models.layers import Dropout
from repro.models.mann_config import MANN, MANNConfig
from repro.motion.rotations import matrix_to_6d, sixd_to_matrix
from repro.seeding import derive_seed
from repro import kernels

#: The authors' SGDR caps the cosine phase at 0.9 of a period (``H_cur``) until the restart.
SGDR_PHASE_CAP = 0.9
#: Standard deviations below this are replaced by 1 when normalising (constant features).
STD_FLOOR = 1e-5


def sgdr_factor(epoch: int, batch: int, n_batches: int, period: int, mult: int) -> float:
    """``η`` of cosine annealing with warm restarts at batch ``batch`` of epoch ``epoch``: the
    phase runs over a cycle of ``period·mult^i`` epochs, capped at :data:`SGDR_PHASE_CAP`."""
    start, length = 0, period
    while epoch >= start + length:
        start, length = start + length, length * mult
    phase = ((epoch - start) * n_batches + batch) / (length * max(n_batches, 1))
    return 0.5 * (1.0 + math.cos(math.pi * min(phase, SGDR_PHASE_CAP)))


class ExpertLinear(nn.Module):
    """A fully connected layer whose weights are a per-sample blend of ``K`` experts' weights
    (Zhang et al. Eq. 3).  ``alpha`` (K, out, in) Glorot-uniform, ``beta`` (K, out) zeros, as in
    the authors' code."""

    def __init__(self, n_experts: int, n_in: int, n_out: int):
        super().__init__()
        bound = math.sqrt(6.0 / (n_in + n_out))
        self.alpha = nn.Parameter(torch.empty(n_experts, n_out, n_in).uniform_(-bound, bound))
        self.beta = nn.Parameter(torch.zeros(n_experts, n_out))

    def forward(self, x: torch.Tensor, omega: torch.Tensor) -> torch.Tensor:
        """x (B, in), omega (B, K) → (B, out) = Σ_k ω_k (α_k x + β_k)."""
        K, n_out, n_in = self.alpha.shape
        y = (x @ self.alpha.reshape(K * n_out, n_in).T).view(x.shape[0], K, n_out)
        return torch.bmm(omega[:, None, :], y)[:, 0] + omega @ self.beta


class MANNNet(nn.Module):
    """Gating network + expert-blended motion prediction network, with the input/output
    normalisation statistics as buffers (set by :meth:`MANN.fit`)."""

    def __init__(self, cfg: MANNConfig, n_in: int, n_out: int, gating_index: torch.Tensor):
        super().__init__()
        self.cfg, self.n_in, self.n_out = cfg, n_in, n_out
        g = int(gating_index.numel())
        h, gh, K = cfg.hidden, cfg.gating_hidden, cfg.n_experts
        self.register_buffer("gating_index", gating_index.clone().long())
        self.register_buffer("x_mean", torch.zeros(n_in))
        self.register_buffer("x_std", torch.ones(n_in))
        self.register_buffer("y_mean", torch.zeros(n_out))
        self.register_buffer("y_std", torch.ones(n_out))
        self.gate0, self.gate1, self.gate2 = nn.Linear(g, gh), nn.Linear(gh, gh), nn.Linear(gh, K)
        for lin in (self.gate0, self.gate1, self.gate2):  # Glorot-uniform, zero bias (authors')
            nn.init.xavier_uniform_(lin.weight)
            nn.init.zeros_(lin.bias)
        self.layer0 = ExpertLinear(K, n_in, h)
        self.layer1 = ExpertLinear(K, h, h)
        self.layer2 = ExpertLinear(K, h, n_out)
        self.drop = Dropout(cfg.dropout)

    def blend(self, xn: torch.Tensor) -> torch.Tensor:
        """Blending coefficients ω (B, K) from the normalised input's gating columns."""
        g = self.drop(xn[:, self.gating_index])
        g = self.drop(F.elu(self.gate0(g)))
        g = self.drop(F.elu(self.gate1(g)))
        return torch.softmax(self.gate2(g), dim=-1)

    def forward(self, xn: torch.Tensor) -> torch.Tensor:
        """Normalised input (B, n_in) → normalised output (B, n_out)."""
        omega = self.blend(xn)
        h = self.drop(xn)
        h = self.drop(F.elu(self.layer0(h, omega)))
        h = self.drop(F.elu(self.layer1(h, omega)))
        return self.layer2(h, omega)

    def normalise_x(self, x):
        return (x - self.x_mean) / self.x_std

    def denormalise_y(self, yn):
        return yn * self.y_std + self.y_mean


class MANNFeatures:
    """Builds MANN's input and output vectors (module docstring) for one skeleton and config."""

    def __init__(self, cfg: MANNConfig, skeleton, n_classes: int):
        self.cfg, self.skeleton, self.n_classes = cfg, skeleton, n_classes
        J = skeleton.n_joints
        self.J = J
        self.leaves = [j for j in range(J) if not skeleton.children(j)]
        self.offsets = torch.tensor(cfg.offsets(), dtype=torch.long)
        n_off = len(cfg.offsets())
        # column layout of x
        self.c_rot = (0, 6 * J)
        self.c_pos = (self.c_rot[1], self.c_rot[1] + 3 * J)
        self.c_vel = (self.c_pos[1], self.c_pos[1] + 3 * J)
        self.c_height = self.c_vel[1]
        self.c_traj = (self.c_height + 1, self.c_height + 1 + 2 * n_off)
        self.c_tvel = (self.c_traj[1], self.c_traj[1] + 2 * n_off)
        self.c_tag = (self.c_tvel[1], self.c_tvel[1] + n_classes)
        self.n_in = self.c_tag[1] + (1 if cfg.progress_input else 0)
        self.n_out = 6 * J + 3
        zero = cfg.offsets().index(0)
        leaf_cols = [self.c_vel[0] + 3 * j + a for j in self.leaves for a in range(3)]
        desired = [self.c_tvel[0] + 2 * zero + a for a in range(2)]
        tag_cols = list(range(*self.c_tag))
        self.gating_index = torch.tensor(leaf_cols + desired + tag_cols, dtype=torch.long)

    def control_path(self, items: ActionItems) -> torch.Tensor:
        """(N, K + T_max, 2): the initial roots' ground positions, then the trajectory ``U``
        (padded past each item's length with its last value)."""
        init = items.initial.root[..., [0, 2]].float()
        traj = pad_last(items.trajectory.float(), items.lengths)
        return torch.cat([init, traj], dim=1)

    def window(self, path: torch.Tensor, rows: torch.Tensor, t: torch.Tensor, K: int,
               lengths: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Path samples (M, n_off, 2) at frames ``t + offsets`` and the path's velocity there,
        for pairs (item ``rows``, action frame ``t``), indices clamped to the item's frames."""
        idx = (K - 1 + t)[:, None] + self.offsets[None, :]
        hi = (K - 1 + lengths[rows])[:, None]
        cur = torch.minimum(idx.clamp(min=0), hi)
        prev = torch.minimum((idx - 1).clamp(min=0), hi)
        p = path[rows[:, None], cur]
        return p, p - path[rows[:, None], prev]

    def inputs(self, prev: torch.Tensor, world: torch.Tensor, world2: torch.Tensor,
               pts: torch.Tensor, pts_vel: torch.Tensor, labels: torch.Tensor,
               progress: torch.Tensor | None) -> torch.Tensor:
        """x (M, n_in) from the pose vectors ``prev`` = P_{t−1} (M, 6J+3), the joint positions
        ``world`` of P_{t−1} and ``world2`` of P_{t−2} (M, J, 3), the trajectory window
        (M, n_off, 2) and its velocities, tags (M,) and progress (M,) or None."""
        M = prev.shape[0]
        rot6d, root = unpack_poses(prev, self.J)
        rel = pts - root[:, None, [0, 2]]
        parts = [rot6d.reshape(M, -1), (world - root[:, None]).reshape(M, -1),
                 (world - world2).reshape(M, -1), root[:, 1:2], rel.reshape(M, -1),
                 pts_vel.reshape(M, -1), F.one_hot(labels, self.n_classes).to(prev.dtype)]
        if self.cfg.progress_input:
            parts.append(progress[:, None].to(prev.dtype))
        return torch.cat(parts, dim=-1)

    @staticmethod
    def outputs(prev: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """y (M, 6J+3): the target's 6D rotations, then its root displacement from ``prev``."""
        return torch.cat([target[:, :-3], target[:, -3:] - prev[:, -3:]], dim=-1)

    def training_pairs(self, items: ActionItems, chunk: int = 8192):
        """(X (M, n_in), Y (M, n_out)) for every action frame of every item (teacher forcing:
        the previous poses come from the data)."""
        K = items.n_init
        seq = torch.cat([pack_poses(items.initial), pack_poses(items.action)], dim=1)
        path = self.control_path(items)
        lengths = items.lengths
        rows = torch.repeat_interleave(torch.arange(len(items)), lengths)
        t = torch.cat([torch.arange(1, int(n) + 1) for n in lengths])
        X, Y = [], []
        with torch.no_grad():
            world = pose_joints(self.skeleton, seq)                     # (N, K + T, J, 3)
            for s in range(0, rows.numel(), chunk):
                r, tt = rows[s:s + chunk], t[s:s + chunk]
                i1, i2 = K - 2 + tt, (K - 3 + tt).clamp(min=0)
                prev = seq[r, i1]
                pts, vel = self.window(path, r, tt, K, lengths)
                prog = tt.float() / lengths[r].float()
                X.append(self.inputs(prev, world[r, i1], world[r, i2], pts, vel,
                                     items.labels[r], prog))
                Y.append(self.outputs(prev, seq[r, K - 1 + tt]))
        return torch.cat(X), torch.cat(Y)


@register
class MANN(Generator):
    """MANN behind the :class:`~repro.models.base.Generator` interface (module docstring)."""

    card = MANN
    uses = frozenset({"label", "length", "initial_motion", "trajectory"})

    def __init__(self, config, skeleton, n_classes: int, fps: float):
        super().__init__(config, skeleton, n_classes, fps)
        self.features = MANNFeatures(self.config, skeleton, self.n_classes)
        self._build(derive_seed(0, self.method_id, "construct"))

    def _make_network(self) -> MANNNet:
        f = self.features
        return MANNNet(self.config, f.n_in, f.n_out, f.gating_index)

    @property
    def network(self) -> MANNNet:
        return self.net

    # -- training ------------------------------------------------------------------------------
    def fit(self, train_items: ActionItems, *, seed: int, ckpt_dir: str | Path | None = None,
            on_epoch: Callable[[int, dict[str, float]], None] | None = None,
            val_items: ActionItems | None = None):
        """Teacher-forced frame pairs, normalised; AdamWR (module docstring) through the one
        training loop; weights initialised from ``seed``.  With ``val_items`` each epoch also
        records ``val_loss``: the same normalised MSE (training statistics) over every
        teacher-forced frame pair of the held-out items."""
        from repro.train.loop import train

        check_items(self, train_items)
        if val_items is not None:
            check_items(self, val_items)
        cfg = self.config
        self._build(derive_seed(seed, self.method_id, "init"))
        X, Y = self.features.training_pairs(train_items)
        net = self.net
        with torch.no_grad():
            for name, data in (("x", X), ("y", Y)):
                mean = data.mean(0)
                std = data.std(0, unbiased=False)
                std = torch.where(std < STD_FLOOR, torch.ones_like(std), std)
                getattr(net, f"{name}_mean").copy_(mean)
                getattr(net, f"{name}_std").copy_(std)
            Xn, Yn = net.normalise_x(X), (Y - net.y_mean) / net.y_std
        n = Xn.shape[0]
        drop_last = n >= cfg.batch_size
        n_batches = n // cfg.batch_size if drop_last else 1
        wd_norm = cfg.weight_decay / math.sqrt(n_batches * cfg.restart_period)
        opt = kernels.adamw(net.parameters(), lr=cfg.lr, weight_decay=wd_norm / cfg.lr)

        def batches(epoch, gen):
            for b, idx in enumerate(epoch_batches(n, cfg.batch_size, gen, drop_last=drop_last)):
                yield b, Xn[idx], Yn[idx]

        def step(model, batch, epoch):
            b, xb, yb = batch
            eta = sgdr_factor(epoch, b, n_batches, cfg.restart_period, cfg.restart_mult)
            for group in opt.param_groups:
                group["lr"] = cfg.lr * eta
            loss = F.mse_loss(model(xb), yb)
            return {"loss": loss, "lr": loss.new_tensor(cfg.lr * eta)}

        validate = None
        if val_items is not None:
            Xv, Yv = self.features.training_pairs(val_items)
            with torch.no_grad():
                Xv, Yv = net.normalise_x(Xv), (Yv - net.y_mean) / net.y_std
            m = Xv.shape[0]

            def validate(model, epoch):
                total = 0.0
                for s in range(0, m, cfg.batch_size):
                    xb, yb = Xv[s:s + cfg.batch_size], Yv[s:s + cfg.batch_size]
                    total += float(F.mse_loss(model(xb), yb)) * xb.shape[0]
                return {"loss": total / max(m, 1)}

        result = train(net, opt, batches=batches, step=step, epochs=cfg.epochs, seed=seed,
                       config=self.train_config(train_items, seed, val_items),
                       ckpt_dir=ckpt_dir, on_epoch=on_epoch, validate=validate)
        net.eval()
        return result

    # -- inference -----------------------------------------------------------------------------
    @torch.no_grad()
    def generate_poses(self, cond_items: ActionItems) -> torch.Tensor:
        """(N, T_max, 6J+3) poses in the items' normalised frames, frame by frame: each
        prediction (6D made orthonormal) becomes the next step's previous pose."""
        check_items(self, cond_items)
        cfg, net, f = self.config, self.net, self.features
        net.eval()
        K, N = cond_items.n_init, len(cond_items)
        Tmax = int(cond_items.lengths.max())
        init = pack_poses(cond_items.initial)
        path = f.control_path(cond_items)
        out = torch.zeros(N, Tmax, f.n_out)
        for s in range(0, N, cfg.sample_batch_size):
            rows = torch.arange(s, min(N, s + cfg.sample_batch_size))
            lengths = cond_items.lengths
            prev = init[rows, K - 1]
            world = pose_joints(self.skeleton, prev)
            world2 = pose_joints(self.skeleton, init[rows, max(K - 2, 0)])
            for t in range(1, int(lengths[rows].max()) + 1):
                tt = torch.full((rows.numel(),), t, dtype=torch.long)
                pts, vel = f.window(path, rows, tt, K, lengths)
                x = f.inputs(prev, world, world2, pts, vel, cond_items.labels[rows],
                             tt.float() / lengths[rows].float())
                y = net.denormalise_y(net(net.normalise_x(x.to(self.device)))).to(x.device)
                rot6d = matrix_to_6d(sixd_to_matrix(y[:, :-3].reshape(-1, self.skeleton.n_joints, 6)))
                pose = torch.cat([rot6d.reshape(rows.numel(), -1), prev[:, -3:] + y[:, -3:]], -1)
                out[rows, t - 1] = pose
                prev, world2, world = pose, world, pose_joints(self.skeleton, pose)
        return out

    def sample(self, cond_items: ActionItems, *, seed: int, use_mean: bool = False) -> GeneratedItems:
        """One action per item in the world frame; deterministic (``seed``/``use_mean`` unused:
        MANN has no latent variable)."""
        poses = self.generate_poses(cond_items)
        with torch.no_grad():
            return to_generated(self, cond_items, poses)
