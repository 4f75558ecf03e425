"""The three networks of ODMO (Lu et al., ACM MM'22, §3.2, Fig. 2, supplement Table S2) with the
layer shapes of the released code (``src/modules/models.py``: LMPEncoder, TrajGenerator,
MotionGenerator; ``src/modules/ensemble.py``: the forward pass); the method (losses, training,
code bank, sampling) is :mod:`repro.models.odmo`.

Tensors are batch-first; ``J`` joints, ``C`` classes, ``D`` the latent size (20), ``T`` frames,
``H`` = ``hidden`` (128), ``E`` = the embedding width (``embed``; ``None`` = ``H``, the code's).
Poses are absolute xyz of all joints flattened to ``J·3`` per frame (the window frame: the first
frame's root at the origin), in the data set's units.  Table S2 names the layers but not every
width; where it is silent the code decides (``"code"`` shapes, the default); the harness's
earlier shapes stay as named variants (``"compact"``, ``"repeat"``), not the paper's nor the code's.

- :class:`LMPEncoder` ``Es_θ`` (Table S2 "LMP encoder"): the local movement profile (each joint
  minus the root joint, per frame, :func:`lmp`, §3.1) through one LSTM layer of ``enc_hidden``
  (64) units; its last step goes through the feature layers.  ``head="code"``: FC ``F`` + BN +
  PReLU, FC ``F`` + BN + PReLU, FC → 2·D split into ``μ`` and ``log σ²`` (the code: ``F`` = 256).
  ``head="compact"`` (harness variant): one FC ``F`` + BN + PReLU and two FC heads.
- :class:`TrajectoryGenerator` ``Gr_φ`` (§3.2(ii), Eq. 2, Table S2 "2 FC with PReLU in between",
  "3 FC with PReLU"): input ``x = [one-hot(c) ⊗ z (C·D, flattened outer product), r_e (3)]``.
  ``inputs="code"``: expand = FC(C·D+3 → (C·D+3)·(T−1)) + PReLU, reshaped to ``T − 1`` steps of
  ``C·D + 3`` (a learned input per step, so the network is built for one window length ``T``),
  embedding FC → ``E`` (no activation), 2 LSTM × ``H``, 3 × (FC ``H`` + PReLU), FC → 3; the code
  uses *one* PReLU module for every activation of this network.  ``inputs="repeat"`` (harness
  variant, any ``T``): FC ``E`` + PReLU + FC ``E`` on ``x`` once, repeated over the ``T − 1``
  steps, separate PReLUs.  The output is ``T − 1`` velocities; the trajectory is their
  cumulative sum after a leading 0 (the code's ``to_location``; ``r̂_1 = 0``: a window starts at
  the origin, Eq. 2's ``r_0 = 0`` makes the first velocity 0).
- :class:`MotionGenerator` ``Gm_ψ`` (§3.2(iii), Eq. 3, Seq2Seq, Table S2): the trajectory encoder
  embeds each of the ``T`` root positions (FC 3 → ``E`` + PReLU) and runs 2 LSTM layers × ``H``;
  its final ``(h, c)`` is the decoder's initial state ``h_0`` — the *only* way the trajectory
  reaches the decoder (paper and code agree).  The decoder, at step ``t`` (0-based), embeds
  (FC → ``E`` + PReLU) ``[m̃_{t−1} (J·3), one-hot(c) ⊗ z (C·D), (t+1)/T]``, runs 2 LSTM layers ×
  ``H`` one step, and an FC gives the pose ``m̂_t``.  The time input is the code's (its counter
  is incremented before use, so the first step reads 1/T; the paper lists only the previous
  pose and the class code: ``time=False``, the config's ``decoder_time``); the
  code shares *one* PReLU between the encoder's and the decoder's embedding.  ``m̃_{−1}`` is the
  zero pose (the code's); teacher forcing is decided **per step** (one Bernoulli(tf) draw per
  step, shared by the batch, as the code's ``random.random() < tf_rate``; from the global torch
  RNG, which the training loop seeds per epoch); a fed-back prediction is *not* detached.  The
  part of the decoder embedding that does not depend on the previous pose (class code and time)
  is computed once per forward for all steps (same function, fewer operations per step).

The per-term loss formulas (:func:`contrastive_loss`, :func:`kl_term`, :func:`squared_error`)
live here too; how :mod:`repro.models.odmo` combines them is documented there.
"""

from __future__ import annotations

import functools
import math

import torch
import torch.nn.functional as F
from torch import nn

from repro import kernels
from repro.errors import ConfigError


def lmp(joints: torch.Tensor) -> torch.Tensor:
    """Local movement profile (§3.1): ``joints`` (N, T, J, 3) minus the root joint (joint 0) of
    each frame, flattened to (N, T, J·3) (the root's own three entries are 0)."""
    return (joints - joints[:, :, :1]).flatten(2)


def class_code(labels: torch.Tensor, z: torch.Tensor, n_classes: int) -> torch.Tensor:
    """``one-hot(c) ⊗ z`` flattened: (N, C·D), the block of class ``c`` holds ``z``, the rest 0."""
    onehot = torch.nn.functional.one_hot(labels.long(), n_classes).to(z.dtype)
    return (onehot[:, :, None] * z[:, None, :]).flatten(1)


class LMPEncoder(nn.Module):
    """``Es_θ``: LMP (N, T, J·3) → (μ, log σ²), each (N, D) (module docstring)."""

    def __init__(self, in_dim: int, hidden: int, feature: int, latent: int, *,
                 head: str = "code"):
        super().__init__()
        self.latent, self.head = int(latent), head
        self.lstm = nn.LSTM(in_dim, hidden, num_layers=1, batch_first=True)
        if head == "code":
            self.feature = nn.Sequential(
                nn.Linear(hidden, feature), nn.BatchNorm1d(feature), nn.PReLU(),
                nn.Linear(feature, feature), nn.BatchNorm1d(feature), nn.PReLU(),
                nn.Linear(feature, 2 * latent))
        elif head == "compact":
            self.feature = nn.Sequential(nn.Linear(hidden, feature), nn.BatchNorm1d(feature),
                                         nn.PReLU())
            self.mu = nn.Linear(feature, latent)
            self.logvar = nn.Linear(feature, latent)
        else:
            raise ConfigError(f"odmo: unknown encoder head {head!r}")

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out, _ = self.lstm(x)
        h = self.feature(out[:, -1])
        if self.head == "code":
            return h[:, :self.latent], h[:, self.latent:]
        return self.mu(h), self.logvar(h)


class TrajectoryGenerator(nn.Module):
    """``Gr_φ``: (class code (N, C·D), end point (N, 3)) → velocities (N, T−1, 3) and the
    trajectory (N, T, 3) with ``r̂_1 = 0`` (module docstring).  ``window``: the ``T`` the
    ``"code"`` input expansion is built for (``None`` only with ``inputs="repeat"``)."""

    def __init__(self, cond_dim: int, embed: int, hidden: int, *, inputs: str = "code",
                 window: int | None = None):
        super().__init__()
        self.inputs, self.window = inputs, window
        in_dim = cond_dim + 3
        if inputs == "code":
            if window is None or int(window) < 2:
                raise ConfigError(f"odmo: the code's trajectory generator needs a window of at "
                                  f"least 2 frames, got {window}")
            self.act = nn.PReLU()  # the code's one activation module of this network
            self.expand = nn.Linear(in_dim, in_dim * (int(window) - 1))
            self.embed = nn.Linear(in_dim, embed)
            acts = [self.act] * 3
        elif inputs == "repeat":
            self.embed = nn.Sequential(nn.Linear(in_dim, embed), nn.PReLU(),
                                       nn.Linear(embed, embed))
            acts = [nn.PReLU() for _ in range(3)]
        else:
            raise ConfigError(f"odmo: unknown trajectory input {inputs!r}")
        self.lstm = nn.LSTM(embed, hidden, num_layers=2, batch_first=True)
        self.feature = nn.Sequential(nn.Linear(hidden, hidden), acts[0],
                                     nn.Linear(hidden, hidden), acts[1],
                                     nn.Linear(hidden, hidden), acts[2])
        self.out = nn.Linear(hidden, 3)

    def forward(self, cond: torch.Tensor, end: torch.Tensor,
                n_frames: int) -> tuple[torch.Tensor, torch.Tensor]:
        if n_frames < 2:
            raise ConfigError(f"odmo: a trajectory needs at least 2 frames, got {n_frames}")
        x = torch.cat([cond, end.to(cond.dtype)], dim=-1)
        if self.inputs == "code":
            if int(n_frames) != int(self.window):
                raise ConfigError(
                    f"odmo: this network was built for windows of {self.window} frames (the "
                    f"code's trajectory generator expands its input per frame), asked for "
                    f"{n_frames}; train for that window length or use trajectory_input="
                    f"'repeat'")
            x = self.act(self.expand(x)).unflatten(1, (int(n_frames) - 1, x.shape[1]))
            x = self.embed(x)
        else:
            x = self.embed(x)[:, None].expand(-1, int(n_frames) - 1, -1).contiguous()
        h, _ = self.lstm(x)
        vel = self.out(self.feature(h))
        traj = torch.cat([vel.new_zeros(vel.shape[0], 1, 3), torch.cumsum(vel, dim=1)], dim=1)
        return vel, traj


class MotionGenerator(nn.Module):
    """``Gm_ψ``: trajectory (N, T, 3) + class code (N, C·D) → poses (N, T, J·3) (module
    docstring: the trajectory enters through ``h_0`` only)."""

    def __init__(self, pose_dim: int, cond_dim: int, embed: int, hidden: int, *,
                 time: bool = True):
        super().__init__()
        self.pose_dim, self.time = pose_dim, bool(time)
        self.act = nn.PReLU()  # the code's one PReLU of both embeddings
        self.traj_embed = nn.Linear(3, embed)
        self.traj_lstm = nn.LSTM(embed, hidden, num_layers=2, batch_first=True)
        self.dec_embed = nn.Linear(pose_dim + cond_dim + int(self.time), embed)
        self.dec_lstm = nn.LSTM(embed, hidden, num_layers=2, batch_first=True)
        self.out = nn.Linear(hidden, pose_dim)

    @staticmethod
    def time_input(n_frames: int, like: torch.Tensor) -> torch.Tensor:
        """(T,): the decoder's time feature, ``(t + 1)/T`` at step ``t`` (the code's counter,
        incremented before use)."""
        return torch.arange(1, int(n_frames) + 1, dtype=like.dtype, device=like.device) / n_frames

    def forward(self, traj: torch.Tensor, cond: torch.Tensor, *, tf: float = 0.0,
                target: torch.Tensor | None = None) -> torch.Tensor:
        """Autoregressive decoding over ``traj``'s ``T`` steps.  With ``tf > 0`` and ``target``
        (N, T, J·3), each step feeds the real previous pose with probability ``tf``."""
        N, T = traj.shape[:2]
        _, state = self.traj_lstm(self.act(self.traj_embed(traj)))
        use_real = None
        if tf > 0.0:
            if target is None:
                raise ValueError("teacher forcing needs the target poses")
            use_real = torch.rand(T) < tf if tf < 1.0 else torch.ones(T, dtype=torch.bool)
            use_real = use_real.tolist()  # read once, not one tensor read per frame
        # embedding of [prev, cond, time] = W_prev·prev + (W_cond·cond + w_time·time + b): the
        # second part, independent of the recurrence, once for all T steps
        w, P = self.dec_embed.weight, self.pose_dim
        w_prev = w[:, :P].contiguous()
        if self.time:
            fixed = F.linear(cond, w[:, P:-1], self.dec_embed.bias)[:, None] + \
                self.time_input(T, traj)[None, :, None] * w[:, -1]
        else:  # the paper's reading: [prev, class code] only
            fixed = F.linear(cond, w[:, P:], self.dec_embed.bias)[:, None].expand(N, T, -1)
        prev = traj.new_zeros(N, P)
        outs = []
        fixed_steps = fixed.unbind(1)  # one view per step; backward stacks their gradients once
        # the decoder LSTM one step at a time: torch.lstm is what nn.LSTM.forward calls on the
        # CPU, without the module's per-call argument checks (bitwise the same; issue 31)
        lstm = self.dec_lstm
        weights = [w for layer in lstm.all_weights for w in layer]
        step = functools.partial(torch.lstm, params=weights, has_biases=lstm.bias,
                                 num_layers=lstm.num_layers, dropout=float(lstm.dropout),
                                 train=self.training, bidirectional=False, batch_first=True)
        for t in range(T):
            x = self.act(F.linear(prev, w_prev) + fixed_steps[t])
            h, *state = step(x[:, None], state)
            pose = self.out(h[:, 0])
            outs.append(pose)
            prev = target[:, t] if use_real is not None and use_real[t] else pose
        return torch.stack(outs, dim=1)


class ODMONet(nn.Module):
    """Every learned piece of ODMO: ``encoder``, ``trajectory``, ``motion`` (module docstring).
    ``embed=None``: embedding widths = ``hidden`` (the code); ``window``: the ``T`` the code's
    trajectory generator is built for."""

    def __init__(self, n_joints: int, n_classes: int, *, latent: int = 20, enc_hidden: int = 64,
                 enc_feature: int = 256, embed: int | None = None, hidden: int = 128,
                 encoder_head: str = "code", trajectory_input: str = "code",
                 window: int | None = None, decoder_time: bool = True):
        super().__init__()
        self.n_joints, self.n_classes, self.latent = int(n_joints), int(n_classes), int(latent)
        pose_dim, cond_dim = 3 * self.n_joints, self.n_classes * self.latent
        embed = hidden if embed is None else embed
        self.encoder = LMPEncoder(pose_dim, enc_hidden, enc_feature, latent, head=encoder_head)
        self.trajectory = TrajectoryGenerator(cond_dim, embed, hidden, inputs=trajectory_input,
                                              window=window)
        self.motion = MotionGenerator(pose_dim, cond_dim, embed, hidden, time=decoder_time)

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
    """``err`` (N, T, ..., 3): squared error with the y coordinate's multiplied by ``y_weight``,
    reduced per window, then averaged over the batch.  ``"code"``: per frame the mean over the
    frame's coordinates (all ``J·3`` of a pose, the 3 of a root), summed over frames (the
    released trainer's ``mean(-1)`` then ``sum(-1)``); ``"sum"``: summed over frames and
    coordinates (the paper's ``Σ_t ‖·‖²``, Eq. 2-4); ``"mean"``: averaged over both (a harness
    variant, neither reading)."""
    sq = (err ** 2 * err.new_tensor([1.0, float(y_weight), 1.0])).flatten(2)
    if reduction == "code":
        per = sq.mean(2).sum(1)
    elif reduction == "sum":
        per = sq.sum((1, 2))
    elif reduction == "mean":
        per = sq.mean((1, 2))
    else:
        raise ConfigError(f"odmo: unknown loss reduction {reduction!r}")
    return per.mean()
