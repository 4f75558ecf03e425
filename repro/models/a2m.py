"""Action2Motion (Guo et al., ACM MM 2020) as Neural Marionette adapted it (supp. Sec. 4.1):
"(1) replacing lie algebra representation of the joint rotations with 6D continuous
representation; (2) providing A2M with the same initial pose as our setting rather than a rest
pose".

Network (Guo et al. Sec. 3, Fig. 2; sizes from the authors' code, docs/baselines.md): a temporal
conditional VAE of three GRU networks run frame by frame, each an input FC embedding, a stack
of GRU cells (hidden 128) and FC heads:

- **posterior** ``q(z_t | x_{≤t}, a)`` (1 layer): input ``[x_t, c_t]`` → ``μ_t, log σ²_t``
  (``dim_z`` = 30);
- **prior** ``p(z_t | x_{<t}, a)`` (1 layer, the learned per-frame prior): input
  ``[x_{t−1}, c_t]`` → ``μ^p_t, log (σ^p_t)²``;
- **decoder** ``p(x_t | z_{≤t}, x_{<t}, a)`` (2 layers): input ``[x_{t−1}, c_t, z_t]`` → ``x̂_t``;

with the condition ``c_t = [one-hot tag, t/(T−1)]`` (the "time counter"; ``time_counter``).
``x_0`` is the last initial pose ``P₋₁`` (``initial_pose``, NM's adaptation) or the rest pose
(identity rotations, root at the origin; A2M's zero Lie vector).

Pose parameters ``x_t`` (``representation``):

- ``"6d"`` (NM's adaptation, default): the pose vector of :mod:`repro.models.baseline_io`,
  ``J×6`` local 6D rotations then the root translation; the decoder's head is linear;
- ``"lie"`` (A2M's own): per-joint rotation vectors (axis × angle, the Lie algebra so(3); the
  root's included since our root carries the heading) then the root translation; the head is
  A2M's ``DecoderGRULie`` (root linear; rotations ``π·tanh(FC(tanh(h)))``);
- ``"xyz"`` (A2M's xyz training, ODMO's "A2M-xyz" row): all ``J`` joints' positions in metres,
  joint-major (``3J`` numbers, the items' frame); the head is linear.  See "ODMO's baselines".

Training (Guo et al. Eq. 5; the authors' trainer): for each frame,
``L_t = MSE(FK(x̂_t), FK(x_t)) + λ_KL·KL(q(z_t) ‖ p(z_t)) [+ λ_param·MSE(x̂_t, x_t)]``, the
reconstruction on joint positions in metres (root translation included) by forward kinematics
on the data set's skeleton (A2M's default ``mse_lie``: joints from the generated parameters and
the target's bones), the KL summed over latent dimensions; ``L = Σ_t L_t`` over each item's
frames, averaged over the batch.  ``z_t`` comes from the posterior (reparameterised).  With
probability ``self_feed_ratio`` (0.6; the authors' ``--tf_ratio``, whose flag feeds the
prediction back) a batch feeds the decoder's own prediction ``x̂_{t}`` (with gradient) as the
next ``x_t``; otherwise the data.  Adam, lr 2e-4, weight decay 1e-5, batch 128.  Computed
(issue 31) with the posterior, whose inputs are all data, over the whole sequence at once
(``torch.gru`` over its own cells' weights); a teacher-forced batch runs the prior and the
decoder the same way, a self-fed one frame by frame.  Per frame the same values as running
every network frame by frame up to rounding (all frames' input gates in one product); the
weights' gradients sum the frames' terms in another order.  The posterior's noise is one draw
of (T, B, ``dim_z``), frame-major: the same numbers as one draw per frame when ``B·dim_z`` is a
multiple of 16 (torch's CPU normal fills blocks of 16), other N(0, 1) numbers otherwise (a
short last batch).  On CUDA ``torch.gru`` packs the cells' separate weights per call (cuDNN
wants one buffer): correct, a little slower than one packed module would be.

Sampling: ``z_t ~ p(z_t | x_{<t}, a)`` (``μ^p_t`` when ``use_mean``), ``x̂_t`` fed back; noise
drawn per item from the seed.  :meth:`A2M.sample` returns rotations (a GeneratedItems);
:meth:`A2M.sample_joints` returns joint positions (N, T_max, J, 3) for every representation,
both in the world frame.  Units: metres, frames at the items' fps.

ODMO's baselines
----------------
ODMO (Lu et al., MM 2022, §4.2.3 and supp. §2.4) compares against "A2M-xyz" and "A2M-Lie":
Action2Motion trained on joint xyz coordinates and on its Lie-algebra representation, "with
their default parameters" (trained by the ODMO authors on MoCap and UESTC; the released model on
HumanAct12).  ODMO re-scores both with its own pipeline on joint positions (protocols.md §6), so
both rows are read through :meth:`A2M.sample_joints`.  Here:

- **A2M-Lie** = ``representation = "lie", initial_pose = False``: A2M's own setting, the rest-pose
  start ``x_0`` = zero Lie vector (identity rotations, root at the origin), the joint-position
  loss by FK; the initial motion is never read (``uses`` = label, length).
- **A2M-xyz** = ``representation = "xyz", initial_pose = False``: ``x_t`` = the ``J`` joints'
  positions (``3J``, metres) in the item's frame, no forward kinematics anywhere in the
  network or its loss; the reconstruction term is the MSE on those positions directly (per
  frame the mean over ``J×3``, the same quantity and scale as the FK loss of the rotation
  paths); ``x_0`` = the zero vector (A2M's xyz start), or with ``initial_pose`` the joint
  positions of the last initial frame.  ``lambda_param`` would add the same MSE a second time
  (the parameters *are* the positions).  A motion of rotations cannot be made from positions,
  so :meth:`A2M.sample` and :meth:`A2M.generate_poses` raise ``ConfigError`` for ``"xyz"``;
  use :meth:`A2M.sample_joints`.
- Items: ODMO's rows train on :meth:`repro.data.odmo_items.WindowItems.as_action_items` (fixed
  windows of ``window`` frames, the window's first-frame root at the origin, no rotation, one
  initial frame: ``n_init = 1``), A2M's own pre-processing (protocols.md §3.1: root(frame 0) at
  the origin, no rotation).  ``sample_joints`` maps back with the items' canon
  (``canon.invert_points``); with :func:`repro.data.odmo_items.label_condition_items` (identity
  canon) the samples stay in the window frame ODMO scores in.
- Hyper-parameters: the Config defaults (A2M's HumanAct12 command: hidden 128, ``dim_z`` 30,
  λ_KL 1e-3, batch 128, lr 2e-4, time counter on, ``tf_ratio`` 0.6).  ``epochs`` is the only
  budget knob; the paper does not state one for its retrained A2M models.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Callable

import torch
import torch.nn.functional as F
from torch import nn

from repro.data.action_items import ActionItems, GeneratedItems, pad_last
from repro.errors import ConfigError
from repro.models.a2m_config import A2M, A2MConfig
from repro.models.base import Generator, register
from repro.models.baseline_io import (check_items, item_noise, length_mask, pack_poses,
                                      pose_joints, to_generated, unpack_poses)
from repro.motion.rotations import (axis_angle_to_matrix, matrix_to_6d, matrix_to_axis_angle,
                                    sixd_to_matrix)
from repro.seeding import derive_seed
from repro.train.loop import to_device
from repro import kernels


class StackedGRU(nn.Module):
    """FC embedding → stacked GRU cells, the trunk of A2M's networks (a subclass adds its heads
    after this ``__init__``, so the parameters are made embedding, cells, heads)."""

    def __init__(self, n_in: int, hidden: int, layers: int):
        super().__init__()
        self.embed = nn.Linear(n_in, hidden)
        self.cells = nn.ModuleList(nn.GRUCell(hidden, hidden) for _ in range(layers))

    def init_hidden(self, B: int, like: torch.Tensor) -> list[torch.Tensor]:
        return [like.new_zeros(B, c.hidden_size) for c in self.cells]

    def trunk(self, x, hidden):
        """(last cell's output, every cell's new hidden state)."""
        h = self.embed(x)
        new = []
        for cell, hc in zip(self.cells, hidden):
            h = cell(h, hc)
            new.append(h)
        return h, new

    def trunk_sequence(self, x, hidden):
        """:meth:`trunk` over a whole sequence of known inputs ``x`` (B, T, n_in) at once: the
        embedding of every frame in one product, then the same stacked GRU cells (the cells'
        own weights, in ``torch.gru``'s layer order) as one fused recurrence, each layer's
        input gates of all frames in one product.  Per frame :meth:`trunk`'s values up to rounding
        run frame by frame; the weights' gradients are summed over the frames inside one
        product instead of frame by frame (issue 31; tests/test_baselines.py).  (last cell's outputs
        (B, T, H), every cell's final hidden state)."""
        weights = [w for c in self.cells for w in (c.weight_ih, c.weight_hh, c.bias_ih, c.bias_hh)]
        out, last = torch.gru(self.embed(x), torch.stack(hidden), weights, True, len(self.cells),
                              0.0, self.training, False, True)
        return out, list(last.unbind(0))


class GaussianGRU(StackedGRU):
    """FC embedding → stacked GRU cells → (μ, log σ²) heads (A2M's prior/posterior networks)."""

    def __init__(self, n_in: int, n_out: int, hidden: int, layers: int):
        super().__init__(n_in, hidden, layers)
        self.mu = nn.Linear(hidden, n_out)
        self.logvar = nn.Linear(hidden, n_out)

    def forward(self, x, hidden, sequence: bool = False):
        """(μ, log σ², new hidden states) of one frame ``x`` (B, n_in), or of every frame of a
        known sequence (B, T, n_in) with ``sequence`` (:meth:`trunk_sequence`)."""
        h, new = (self.trunk_sequence if sequence else self.trunk)(x, hidden)
        return self.mu(h), self.logvar(h), new


class DecoderGRU(StackedGRU):
    """FC embedding → stacked GRU cells → pose parameters (A2M's generator).  With ``lie`` the
    head is ``DecoderGRULie``'s: root linear, rotations ``π·tanh(FC(tanh(h)))``."""

    def __init__(self, n_in: int, n_out: int, hidden: int, layers: int, lie: bool):
        super().__init__(n_in, hidden, layers)
        self.out = nn.Linear(hidden, n_out)
        self.lie = lie
        if lie:
            self.out_lie = nn.Linear(n_out - 3, n_out - 3)

    def forward(self, x, hidden, sequence: bool = False):
        """(pose parameters, new hidden states) of one frame, or of a known sequence with
        ``sequence`` (as :meth:`GaussianGRU.forward`)."""
        h, new = (self.trunk_sequence if sequence else self.trunk)(x, hidden)
        y = self.out(h)
        if self.lie:
            rot = math.pi * torch.tanh(self.out_lie(torch.tanh(y[..., :-3])))
            y = torch.cat([rot, y[..., -3:]], dim=-1)
        return y, new


class A2MNet(nn.Module):
    """The three GRU networks (module docstring)."""

    def __init__(self, cfg: A2MConfig, n_params: int, n_classes: int):
        super().__init__()
        self.cfg, self.n_params, self.n_classes = cfg, n_params, n_classes
        n_cond = n_classes + (1 if cfg.time_counter else 0)
        n_in = n_params + n_cond
        self.posterior = GaussianGRU(n_in, cfg.dim_z, cfg.hidden, cfg.posterior_layers)
        self.prior = GaussianGRU(n_in, cfg.dim_z, cfg.hidden, cfg.prior_layers)
        self.decoder = DecoderGRU(n_in + cfg.dim_z, n_params, cfg.hidden, cfg.decoder_layers,
                                  cfg.representation == "lie")

    def condition(self, onehot: torch.Tensor, t: int, lengths: torch.Tensor) -> torch.Tensor:
        """``c_t``: the one-hot tag, plus ``t/(T−1)`` per item when the time counter is on."""
        if not self.cfg.time_counter:
            return onehot
        tc = t / (lengths - 1).clamp(min=1).to(onehot.dtype)
        return torch.cat([onehot, tc[:, None]], dim=-1)

    def conditions(self, onehot: torch.Tensor, T: int, lengths: torch.Tensor) -> torch.Tensor:
        """(B, T, n_cond): :meth:`condition` of frames ``0..T-1`` at once (training builds
        them once per batch, not once per frame).  Bitwise the same values: ``t / d`` is
        ``d.reciprocal() * t`` in torch, which is what this computes for every ``t``."""
        frames = onehot[:, None].expand(-1, T, -1)
        if not self.cfg.time_counter:
            return frames
        recip = (lengths - 1).clamp(min=1).to(onehot.dtype).reciprocal()
        tc = recip[:, None] * torch.arange(T, dtype=onehot.dtype, device=onehot.device)
        return torch.cat([frames, tc[..., None]], dim=-1)


def kl_gaussians(mu1, logvar1, mu2, logvar2) -> torch.Tensor:
    """KL(N(μ₁, σ₁²) ‖ N(μ₂, σ₂²)) summed over the last dimension (A2M's ``kl_criterion``)."""
    return (0.5 * (logvar2 - logvar1)
            + (logvar1.exp() + (mu1 - mu2) ** 2) / (2 * logvar2.exp()) - 0.5).sum(-1)


@register
class A2M(Generator):
    """Action2Motion (NM-adapted) behind the :class:`~repro.models.base.Generator` interface."""

    card = A2M
    uses = frozenset({"label", "length", "initial_motion"})

    def __init__(self, config, skeleton, n_classes: int, fps: float):
        super().__init__(config, skeleton, n_classes, fps)
        if not self.config.initial_pose:
            self.uses = frozenset({"label", "length"})  # A2M's own: starts from the rest pose
        J = skeleton.n_joints
        if self.config.representation == "xyz":
            self.n_params = 3 * J                       # joint positions only
        else:
            self.n_params = (6 if self.config.representation == "6d" else 3) * J + 3
        self._build(derive_seed(0, self.method_id, "construct"))

    def _make_network(self) -> A2MNet:
        return A2MNet(self.config, self.n_params, self.n_classes)

    @property
    def network(self) -> A2MNet:
        return self.net

    # -- representation ------------------------------------------------------------------------
    def to_params(self, poses: torch.Tensor) -> torch.Tensor:
        """Pose vectors (..., 6J+3) → the representation's parameters (..., n_params); for
        ``xyz`` the joint positions by forward kinematics, flattened joint-major."""
        if self.config.representation == "6d":
            return poses
        if self.config.representation == "xyz":
            joints = pose_joints(self.skeleton, poses)
            return joints.reshape(joints.shape[:-2] + (-1,))
        rot6d, root = unpack_poses(poses, self.skeleton.n_joints)
        aa = matrix_to_axis_angle(sixd_to_matrix(rot6d))
        return torch.cat([aa.reshape(aa.shape[:-2] + (-1,)), root], dim=-1)

    def to_poses(self, params: torch.Tensor) -> torch.Tensor:
        """Parameters (..., n_params) → pose vectors (..., 6J+3) (rotations not orthonormalised
        for ``6d``; the pose-vector readers apply Gram-Schmidt)."""
        if self.config.representation == "6d":
            return params
        self._need_rotations()
        J = self.skeleton.n_joints
        aa = params[..., :-3].reshape(params.shape[:-1] + (J, 3))
        rot6d = matrix_to_6d(axis_angle_to_matrix(aa))
        return torch.cat([rot6d.reshape(rot6d.shape[:-2] + (-1,)), params[..., -3:]], dim=-1)

    def to_joints(self, params: torch.Tensor) -> torch.Tensor:
        """Parameters (..., n_params) → joint positions (..., J, 3) in the items' frame (FK of
        the pose vector; for ``xyz`` a reshape)."""
        if self.config.representation == "xyz":
            return params.reshape(params.shape[:-1] + (self.skeleton.n_joints, 3))
        return pose_joints(self.skeleton, self.to_poses(params))

    def start_params(self, items: ActionItems) -> torch.Tensor:
        """``x_0`` (N, n_params): the last initial pose, or the rest pose (module docstring;
        for ``xyz`` without the initial pose, A2M's zero vector)."""
        if self.config.initial_pose:
            return self.to_params(pack_poses(items.initial)[:, -1])
        J, N = self.skeleton.n_joints, len(items)
        if self.config.representation == "xyz":
            return torch.zeros(N, self.n_params)
        rest = torch.eye(3).expand(N, J, 3, 3)
        poses = torch.cat([matrix_to_6d(rest).reshape(N, -1), torch.zeros(N, 3)], dim=-1)
        return self.to_params(poses)

    # -- training ------------------------------------------------------------------------------
    def training_step(self, net: A2MNet, batch: dict, epoch: int) -> dict[str, torch.Tensor]:
        """``L`` of the module docstring on one batch (posterior noise and the self-feeding
        draw from the global torch RNG, which the training loop seeds per epoch)."""
        cfg = self.config
        x, lengths = batch["params"], batch["lengths"]
        B, T = x.shape[:2]
        mask = length_mask(lengths, T).to(x.dtype)
        onehot = F.one_hot(batch["labels"], self.n_classes).to(x.dtype)
        h_post = net.posterior.init_hidden(B, x)
        h_prior = net.prior.init_hidden(B, x)
        h_dec = net.decoder.init_hidden(B, x)
        self_feed = bool(torch.rand(()) < cfg.self_feed_ratio)
        conds = net.conditions(onehot, T, lengths)
        # the posterior reads only the data: all frames at once (issue 31); its noise drawn
        # frame-major (one draw per frame gave the same numbers when B·dim_z % 16 == 0)
        mu, logvar, _ = net.posterior(torch.cat([x, conds], -1), h_post, sequence=True)
        z = mu + torch.exp(0.5 * logvar) * torch.randn(
            T, B, cfg.dim_z, dtype=mu.dtype, device=mu.device).transpose(0, 1)
        if self_feed:   # each frame's input is the previous prediction: frame by frame
            prev = batch["start"]
            preds, mus_p, logvars_p = [], [], []
            for c, z_t in zip(conds.unbind(1), z.unbind(1)):
                mu_p, logvar_p, h_prior = net.prior(torch.cat([prev, c], -1), h_prior)
                prev, h_dec = net.decoder(torch.cat([prev, c, z_t], -1), h_dec)
                preds.append(prev)
                mus_p.append(mu_p)
                logvars_p.append(logvar_p)
            pred = torch.stack(preds, 1)                               # (B, T, n_params)
            mu_p, logvar_p = torch.stack(mus_p, 1), torch.stack(logvars_p, 1)
        else:           # teacher forcing: every input known, the two networks over the sequence
            prevs = torch.cat([batch["start"][:, None], x[:, :-1]], 1)
            mu_p, logvar_p, _ = net.prior(torch.cat([prevs, conds], -1), h_prior, sequence=True)
            pred, _ = net.decoder(torch.cat([prevs, conds, z], -1), h_dec, sequence=True)
        kl = (kl_gaussians(mu, logvar, mu_p, logvar_p) * mask).sum(1).mean()
        if cfg.representation == "xyz":                                # positions: no FK
            joints = pred.reshape(B, T, self.skeleton.n_joints, 3)
        else:
            joints = pose_joints(self.skeleton, self.to_poses(pred))   # (B, T, J, 3)
        rec = ((((joints - batch["joints"]) ** 2).mean((-1, -2))) * mask).sum(1).mean()
        loss = rec + cfg.lambda_kld * kl
        out = {"rec": rec.detach(), "kl": kl.detach()}
        if cfg.lambda_param > 0:
            par = ((((pred - x) ** 2).mean(-1)) * mask).sum(1).mean()
            loss = loss + cfg.lambda_param * par
            out["param"] = par.detach()
        with torch.no_grad():
            err = (joints - batch["joints"]).norm(dim=-1).mean(-1)
            out["mpjpe"] = (err * mask).sum() / mask.sum()
        out["self_feed"] = x.new_tensor(float(self_feed))
        return {"loss": loss, **out}

    def _tensors(self, items: ActionItems) -> dict[str, torch.Tensor]:
        target = pack_poses(items.action)
        with torch.no_grad():
            joints = pose_joints(self.skeleton, target)
        if self.config.representation == "xyz":
            params = joints.reshape(joints.shape[:2] + (-1,))         # the positions themselves
            with torch.no_grad():
                start = self.start_params(items)
        else:
            params, start = self.to_params(target), self.start_params(items)
        return {"params": params, "joints": joints, "lengths": items.lengths,
                "labels": items.labels, "start": start}

    @staticmethod
    def _crop(data: dict, idx: torch.Tensor) -> dict:
        T = int(data["lengths"][idx].max())
        return {k: (v[idx][:, :T] if k in ("params", "joints") else v[idx]) for k, v in data.items()}

    def fit(self, train_items: ActionItems, *, seed: int, ckpt_dir: str | Path | None = None,
            on_epoch: Callable[[int, dict[str, float]], None] | None = None,
            val_items: ActionItems | None = None):
        """Adam (lr 2e-4, weight decay 1e-5), batch 128, through the one training loop; weights
        initialised from ``seed``.  ``val_items``: the same loss terms on held-out items enter
        each epoch's history (``val_*``)."""
        cfg = self.config
        return self._fit_items(
            train_items, check_items,
            lambda params: kernels.adam(params, lr=cfg.lr, betas=(0.9, 0.999),
                                        weight_decay=cfg.weight_decay),
            seed=seed, ckpt_dir=ckpt_dir, on_epoch=on_epoch, val_items=val_items)

    # -- inference -----------------------------------------------------------------------------
    @torch.no_grad()
    def generate_params(self, cond_items: ActionItems, *, seed: int,
                        use_mean: bool = False) -> torch.Tensor:
        """(N, T_max, n_params) raw parameters in the items' normalised frames (module
        docstring); frames past an item's length are left as generated.  The network runs on
        its device (:attr:`device`); the noise is drawn on the CPU and moved there, and the
        result is a CPU tensor."""
        check_items(self, cond_items)
        cfg, net = self.config, self.net
        net.eval()
        N, Tmax = len(cond_items), int(cond_items.lengths.max())
        eps = item_noise(seed, self.method_id, (N, Tmax, cfg.dim_z))   # drawn on the CPU
        start = self.start_params(cond_items)
        out = torch.zeros(N, Tmax, self.n_params)
        dev = self.device
        for s in range(0, N, cfg.sample_batch_size):
            idx = torch.arange(s, min(N, s + cfg.sample_batch_size))
            T = int(cond_items.lengths[idx].max())
            lengths, labels, prev, e = to_device(
                (cond_items.lengths[idx], cond_items.labels[idx], start[idx], eps[idx]), dev)
            onehot = F.one_hot(labels, self.n_classes).float()
            B = idx.numel()
            h_prior = net.prior.init_hidden(B, prev)
            h_dec = net.decoder.init_hidden(B, prev)
            steps = []
            for t in range(T):
                c = net.condition(onehot, t, lengths)
                mu_p, logvar_p, h_prior = net.prior(torch.cat([prev, c], -1), h_prior)
                z = mu_p if use_mean else mu_p + torch.exp(0.5 * logvar_p) * e[:, t]
                prev, h_dec = net.decoder(torch.cat([prev, c, z], -1), h_dec)
                steps.append(prev)
            if steps:
                out[idx, :T] = torch.stack(steps, 1).cpu()   # one copy back per batch
        return out

    def generate_poses(self, cond_items: ActionItems, *, seed: int,
                       use_mean: bool = False) -> torch.Tensor:
        """(N, T_max, 6J+3) poses in the items' normalised frames (module docstring);
        ConfigError for ``xyz`` (no rotations)."""
        self._need_rotations()
        return self.to_poses(self.generate_params(cond_items, seed=seed, use_mean=use_mean))

    def _need_rotations(self) -> None:
        if self.config.representation == "xyz":
            raise ConfigError(f"{self.method_id} with representation 'xyz' emits joint positions "
                              "(a Motion needs rotations); use sample_joints")

    def sample(self, cond_items: ActionItems, *, seed: int, use_mean: bool = False) -> GeneratedItems:
        """One action per item, in the world frame (see :meth:`generate_poses`); ConfigError
        for ``xyz`` (use :meth:`sample_joints`)."""
        self._need_rotations()
        poses = self.generate_poses(cond_items, seed=seed, use_mean=use_mean)
        return to_generated(self, cond_items, poses)

    def sample_joints(self, cond_items: ActionItems, *, seed: int,
                      use_mean: bool = False) -> torch.Tensor:
        """(N, T_max, J, 3) float32 joint positions in metres, in the world frame, one action
        per item, same seed → same bytes.  ``6d`` / ``lie``: ``self.sample(...).joints()``.
        ``xyz``: the generated positions, frames past an item's length repeating its last
        valid frame (as :meth:`sample` does), mapped back by the items' inverse normalisation
        (``cond_items.canon.invert_points``; for ODMO's windows a translation by the window's
        first-frame root)."""
        if self.config.representation != "xyz":
            return self.sample(cond_items, seed=seed, use_mean=use_mean).joints()
        params = self.generate_params(cond_items, seed=seed, use_mean=use_mean)
        joints = pad_last(self.to_joints(params.float()), cond_items.lengths)
        return cond_items.canon.invert_points(joints)
