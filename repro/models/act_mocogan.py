"""Act-MoCoGAN: MoCoGAN (Tulyakov et al., CVPR 2018) on joint positions, the GAN baseline of
ODMO (MM '22) Tables 1-2.

What the paper says.  ODMO §4.2.3: "we also include a GAN model as modified in [9]
(Action2Motion), MoCoGAN [30] (Act-MoCoGAN) ... we trained it on our three datasets following
their architecture"; supp. §2.4: "we followed their default architecture while replacing the
image generator with pose generator and modified the image, video discriminators accordingly, as
introduced in A2M paper.  We trained the Act-MoCoGAN by tweaking the hyper-parameters so that it
achieves the best generative results".  No size, loss weight or schedule is given, and ODMO's
code release has no Act-MoCoGAN (protocols.md lists none).

MoCoGAN's code (``sergeytulyakov/mocogan``, ``src/models.py``, ``src/trainers.py``,
``src/train.py``; facts used, no code taken):

- the latent of a video of ``T`` frames is, per frame ``t``, ``[z_C, z_A, z_M(t)]``: a content
  code ``z_C ~ N(0, I)`` (``dim_z_content`` 50) shared by all frames, the category one-hot
  ``z_A`` (``dim_z_category``: the number of classes), and a motion code ``z_M(t) = h_t`` of a
  GRU cell (input and hidden ``dim_z_motion`` 10) run on per-frame noise ``ε(t) ~ N(0, I)``
  from a Gaussian initial state ``h_0 ~ N(0, I)``;
- the image generator ``G_I`` maps each frame's latent independently to an image; the image
  discriminator ``D_I`` judges single frames (unconditional ``PatchImageDiscriminator``), the
  video discriminator ``D_V`` judges clips (``CategoricalVideoDiscriminator``: one real/fake
  logit plus ``dim_z_category`` class logits, an auxiliary classification head);
- losses (BCE with logits, non-saturating): ``D_I``: ``BCE(D_I(x), 1) + BCE(D_I(G), 0)``;
  ``D_V``: the same on clips ``+ CE(class head on real clips, their categories)``
  (``--use_categories``); ``G``: ``BCE(D_I(G), 1) + BCE(D_V(G), 1) + CE(class head on fake
  clips, the generated categories)`` (``--use_infogan``);
- one iteration updates ``D_I``, then ``D_V``, then ``G`` (each on fresh fakes); Adam lr 2e-4,
  betas (0.5, 0.999), weight decay 1e-5 for all three; 100,000 iterations by default; the
  authors' run scripts use image batch = video batch = 32.

Action2Motion's released ``models/motion_gan.py`` (``EricGuo5513/action-to-motion``; its Act-MoCoGAN; its trainer and option
files are not released, so its sizes are unknown): ``PoseDiscriminator`` is an MLP
``Linear(J·3, h) → LeakyReLU(0.2) → Linear(h, 1)`` on one pose offset by its own root
(``sample_poses`` subtracts the pose's first joint for xyz); ``CategoricalMotionDiscriminator``
is a GRU over the sequence, its last output → ``Linear(h, 30) → tanh → Linear(30, 1 + C)``
(logit, class logits).  Its generator differs from MoCoGAN's (a 2-layer GRU over
``[GRU(noise), one-hot]``, no content code); the ODMO supplement says "their default
architecture while replacing the image generator with pose generator", which we read as
MoCoGAN's per-frame generator with poses for images (choice; see below).

This module (choices where the sources are silent, units metres and frames):

- **Pose generator** ``G_I``: an MLP (``g_layers`` hidden layers of ``g_hidden`` units, ReLU;
  MoCoGAN's generator activation; no BatchNorm so that eval-mode sampling equals training-mode
  generation) from ``[z_C, one-hot, z_M(t)]`` to the ``J·3`` joint positions of frame ``t``,
  linear output (metres are not bounded like MoCoGAN's tanh pixels).  The window frame is
  imposed at the output: the generated first frame's root joint (joint 0) is subtracted from
  every joint of every frame, so every generated window starts at the origin like the
  training windows (:mod:`repro.data.odmo_items`).
- **Conditioning**: the fakes of a batch take the real batch's labels (class-balanced draws),
  not uniform random categories (MoCoGAN's unconditional sampler); ``D_V`` carries MoCoGAN's /
  A2M's auxiliary class head (``use_categories``, ``use_infogan`` switch its two CE terms);
  ``D_I`` is unconditional as in both codes, or sees the one-hot too (``di_class``).
- **D_I** (A2M's ``PoseDiscriminator``): one hidden layer of ``di_hidden`` = 256 units (choice);
  its input is the pose minus its own root (``di_root_relative``, A2M's offset) and, with
  ``di_class``, the one-hot.  Image batch: one frame drawn uniformly per real window and one per
  fake window (image batch = video batch = ``batch_size``, the authors' scripts' equal batches).
- **D_V** (A2M's ``CategoricalMotionDiscriminator``): GRU (``dv_layers`` = 2 layers of
  ``dv_hidden`` = 128, choice; zero initial state instead of A2M's random one, so the critic is
  deterministic) over the ``T`` frames' flattened positions, last output ``→ Linear(·, 30) →
  tanh → Linear(30, 1 + C)``.
- **One optimiser, simultaneous updates.**  The training loop takes one loss and one optimiser,
  so :meth:`ActMoCoGAN.losses` returns the discriminators' terms on *detached* fakes and the
  generator's terms computed through the discriminators with their parameters frozen
  (``requires_grad`` off while those terms are built): ``loss = L_D + L_G`` then gives every
  discriminator parameter exactly ``∇L_D`` and every generator parameter exactly ``∇L_G``.  One
  Adam over all parameters with MoCoGAN's shared settings equals the three optimisers (Adam is
  per parameter).  The difference from MoCoGAN is the order: ``G``'s gradient is taken against
  the discriminators *before* this batch's update (simultaneous instead of alternating), and
  the fakes for ``D_I``, ``D_V`` and ``G`` are one draw.  This keeps the loop's exact resume.
  The history's ``loss`` is that sum (not a quality curve); ``loss_d``, ``loss_g``, each term
  and the discriminators' accuracies (``acc_image``, ``acc_video``: real > 0 and fake < 0
  logits, averaged; ``acc_category``: ``D_V``'s class head on real windows) are logged.
- **No instance noise** (MoCoGAN's ``--use_noise`` is off by default).
- **Training data**: every epoch draws ``windows_per_epoch`` (2,048, ODMO's reference) fresh
  class-balanced windows of the pool (``numpy_rng(seed, "act_mocogan", "epoch", e)``), in
  batches of ``batch_size`` (512, ODMO's); ``epochs`` 25,000 = MoCoGAN's default 100,000
  iterations at 4 batches per epoch.  Positions are the windows' metres, not normalised.
- **Sampling**: ``sample_windows`` runs the generator for any ``n_frames`` (the motion GRU is
  unrolled that long) with ``z_C``, ``h_0`` and ``ε`` drawn per item from the seed only.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from repro.errors import ConfigError
from repro.models.act_mocogan_config import ACT_MOCOGAN, ActMoCoGANConfig
from repro.models.base import Generator, epoch_batches, register
from repro.models.baseline_io import check_matches_model, item_noise
from repro.seeding import derive_seed, numpy_rng
from repro.train.loop import to_device
from repro import kernels

#: loss terms of the discriminators / of the generator (keys of :meth:`ActMoCoGAN.losses`)
D_TERMS = ("d_image", "d_video", "d_category")
G_TERMS = ("g_image", "g_video", "g_category")


class PoseGenerator(nn.Module):
    """``G_I``: per-frame latent → J·3 positions (MLP, ReLU, linear output)."""

    def __init__(self, n_in: int, n_out: int, hidden: int, layers: int):
        super().__init__()
        mods: list[nn.Module] = []
        width = n_in
        for _ in range(layers):
            mods += [nn.Linear(width, hidden), nn.ReLU()]
            width = hidden
        mods.append(nn.Linear(width, n_out))
        self.main = nn.Sequential(*mods)

    def forward(self, z):
        return self.main(z)


class ImageDiscriminator(nn.Module):
    """``D_I``: one pose (+ one-hot) → real/fake logit (A2M's PoseDiscriminator)."""

    def __init__(self, n_in: int, hidden: int):
        super().__init__()
        self.main = nn.Sequential(nn.Linear(n_in, hidden), nn.LeakyReLU(0.2),
                                  nn.Linear(hidden, 1))

    def forward(self, x):
        return self.main(x).squeeze(-1)


class VideoDiscriminator(nn.Module):
    """``D_V``: a window (B, T, J·3) → (real/fake logit (B,), class logits (B, C)) (A2M's
    CategoricalMotionDiscriminator, zero initial state)."""

    def __init__(self, n_in: int, hidden: int, layers: int, head: int, n_classes: int):
        super().__init__()
        self.rnn = nn.GRU(n_in, hidden, layers, batch_first=True)
        self.fc1 = nn.Linear(hidden, head)
        self.fc2 = nn.Linear(head, 1 + n_classes)

    def forward(self, x):
        out, _ = self.rnn(x)
        h = self.fc2(torch.tanh(self.fc1(out[:, -1])))
        return h[:, 0], h[:, 1:]


class ActMoCoGANNet(nn.Module):
    """Generator (motion GRU cell + pose generator) and the two discriminators."""

    def __init__(self, cfg: ActMoCoGANConfig, n_joints: int, n_classes: int):
        super().__init__()
        self.cfg, self.n_joints, self.n_classes = cfg, n_joints, n_classes
        n_pose = 3 * n_joints
        self.motion = nn.GRUCell(cfg.dim_z_motion, cfg.dim_z_motion)
        self.pose = PoseGenerator(cfg.dim_z_content + n_classes + cfg.dim_z_motion, n_pose,
                                  cfg.g_hidden, cfg.g_layers)
        self.d_image = ImageDiscriminator(n_pose + (n_classes if cfg.di_class else 0),
                                          cfg.di_hidden)
        self.d_video = VideoDiscriminator(n_pose, cfg.dv_hidden, cfg.dv_layers, cfg.dv_head,
                                          n_classes)

    def generator_parameters(self):
        return [*self.motion.parameters(), *self.pose.parameters()]

    def discriminator_parameters(self):
        return [*self.d_image.parameters(), *self.d_video.parameters()]

    def generate(self, labels, z_content, h0, eps) -> torch.Tensor:
        """(B, T, J, 3) windows from labels (B,), ``z_C`` (B, dc), ``h_0`` (B, dm) and
        ``ε`` (B, T, dm); the first frame's root at the origin."""
        B, T = eps.shape[:2]
        h, zm = h0, []
        for t in range(T):
            h = self.motion(eps[:, t], h)
            zm.append(h)
        onehot = F.one_hot(labels, self.n_classes).to(eps.dtype)
        z = torch.cat([z_content[:, None].expand(B, T, -1), onehot[:, None].expand(B, T, -1),
                       torch.stack(zm, 1)], dim=-1)
        x = self.pose(z).reshape(B, T, self.n_joints, 3)
        return x - x[:, :1, :1, :]

    def image_input(self, poses, labels) -> torch.Tensor:
        """``D_I``'s input for poses (B, J, 3): flattened, root-relative if configured, plus the
        one-hot with ``di_class``."""
        if self.cfg.di_root_relative:
            poses = poses - poses[:, :1]
        x = poses.reshape(poses.shape[0], -1)
        if self.cfg.di_class:
            x = torch.cat([x, F.one_hot(labels, self.n_classes).to(x.dtype)], dim=-1)
        return x


@contextlib.contextmanager
def frozen(params):
    """Parameters that do not require grad inside the block (so a loss built there sends no
    gradient to them); their previous flags are restored after."""
    params = list(params)
    flags = [p.requires_grad for p in params]
    for p in params:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p, f in zip(params, flags):
            p.requires_grad_(f)


@register
class ActMoCoGAN(Generator):
    """Act-MoCoGAN behind the Generator interface (window-trained, emits joint positions)."""

    card = ACT_MOCOGAN
    item_kind = "windows"

    def __init__(self, config, skeleton, n_classes: int, fps: float):
        super().__init__(config, skeleton, n_classes, fps)
        self.n_joints = skeleton.n_joints
        self._build(derive_seed(0, self.method_id, "construct"))

    def _make_network(self) -> ActMoCoGANNet:
        return ActMoCoGANNet(self.config, self.n_joints, self.n_classes)

    @property
    def network(self) -> ActMoCoGANNet:
        return self.net

    # -- training ------------------------------------------------------------------------------
    def losses(self, net: ActMoCoGANNet, batch: dict) -> dict[str, torch.Tensor]:
        """The loss terms (with graph) and accuracies (detached) of one batch (module
        docstring): ``D_TERMS`` on detached fakes, ``G_TERMS`` through frozen discriminators.
        Noise and the frames shown to ``D_I`` come from the global torch RNG (seeded per epoch
        by the training loop)."""
        cfg = self.config
        real, labels = batch["joints"], batch["labels"]
        B, T = real.shape[:2]
        z_c = torch.randn(B, cfg.dim_z_content, dtype=real.dtype, device=real.device)
        h0 = torch.randn(B, cfg.dim_z_motion, dtype=real.dtype, device=real.device)
        eps = torch.randn(B, T, cfg.dim_z_motion, dtype=real.dtype, device=real.device)
        fake = net.generate(labels, z_c, h0, eps)                    # (B, T, J, 3)
        rows = torch.arange(B, device=real.device)
        real_pose = real[rows, torch.randint(0, T, (B,), device=real.device)]
        fake_pose = fake[rows, torch.randint(0, T, (B,), device=real.device)]
        ones, zeros = real.new_ones(B), real.new_zeros(B)
        bce = F.binary_cross_entropy_with_logits

        # discriminators: real vs detached fakes
        li_real = net.d_image(net.image_input(real_pose, labels))
        li_fake = net.d_image(net.image_input(fake_pose.detach(), labels))
        lv_real, cat_real = net.d_video(real.reshape(B, T, -1))
        lv_fake, _ = net.d_video(fake.detach().reshape(B, T, -1))
        out = {"d_image": bce(li_real, ones) + bce(li_fake, zeros),
               "d_video": bce(lv_real, ones) + bce(lv_fake, zeros)}
        if cfg.use_categories:
            out["d_category"] = F.cross_entropy(cat_real, labels)

        # generator: through the discriminators with their parameters frozen
        with frozen(net.discriminator_parameters()):
            gi = net.d_image(net.image_input(fake_pose, labels))
            gv, cat_fake = net.d_video(fake.reshape(B, T, -1))
            out["g_image"] = bce(gi, ones)
            out["g_video"] = bce(gv, ones)
            if cfg.use_infogan:
                out["g_category"] = F.cross_entropy(cat_fake, labels)

        with torch.no_grad():
            out["acc_image"] = 0.5 * ((li_real > 0).float().mean() + (li_fake < 0).float().mean())
            out["acc_video"] = 0.5 * ((lv_real > 0).float().mean() + (lv_fake < 0).float().mean())
            out["acc_category"] = (cat_real.argmax(-1) == labels).float().mean()
        return out

    def training_step(self, net: ActMoCoGANNet, batch: dict, epoch: int) -> dict[str, torch.Tensor]:
        """``loss = L_D + L_G`` (disjoint gradients, module docstring) and the detached terms."""
        terms = self.losses(net, batch)
        d = sum(terms[k] for k in D_TERMS if k in terms)
        g = sum(terms[k] for k in G_TERMS if k in terms)
        rec = {k: v.detach() for k, v in terms.items()}
        return {"loss": d + g, "loss_d": d.detach(), "loss_g": g.detach(), **rec}

    def make_optimizer(self, net: ActMoCoGANNet | None = None) -> torch.optim.Optimizer:
        """One Adam over generator and discriminators with MoCoGAN's shared settings."""
        cfg = self.config
        net = self.net if net is None else net
        return kernels.adam(net.parameters(), lr=cfg.lr, betas=(cfg.beta1, cfg.beta2),
                                weight_decay=cfg.weight_decay)

    def _check_windows(self, items, what: str) -> None:
        from repro.data.odmo_items import WindowItems

        who = self.method_id
        if not isinstance(items, WindowItems):
            raise TypeError(f"{who} trains on repro.data.odmo_items.WindowItems ({what}), "
                            f"got {type(items).__name__}")
        check_matches_model(who, items, what, empty=f"no {what} clips")
        check_matches_model(who, items, what, n_joints=self.n_joints, n_classes=self.n_classes,
                            fps=self.fps)

    @staticmethod
    def _window_tensors(wb) -> dict[str, torch.Tensor]:
        return {"joints": torch.from_numpy(np.ascontiguousarray(wb.joints, dtype=np.float32)),
                "labels": torch.from_numpy(np.asarray(wb.labels, dtype=np.int64))}

    def plateau_rule(self):
        """No convergence rule (issue 32): the held-out adversarial loss measures the balance
        of generator and discriminators, not the generator's quality, and no other held-out
        quantity does; Act-MoCoGAN trains to its cap and never counts as converged."""
        from repro.train.plateau import PlateauRule

        return PlateauRule(metric=None)

    def fit(self, train_items, *, seed: int, ckpt_dir: str | Path | None = None,
            on_epoch: Callable[[int, dict[str, float]], None] | None = None,
            val_items=None):
        """Train on fresh class-balanced windows of ``train_items`` every epoch through the one
        training loop (weights initialised from ``seed``).  ``val_items``: the same terms on a
        fixed seeded draw of ``val_windows`` held-out windows enter the history (``val_*``)."""
        from repro.train.loop import train

        self._check_windows(train_items, "training items")
        if val_items is not None:
            self._check_windows(val_items, "validation items")
        cfg = self.config
        self._build(derive_seed(seed, self.method_id, "init"))
        opt = self.make_optimizer()

        def batches(epoch, gen):
            wb = train_items.draw(cfg.windows_per_epoch, numpy_rng(seed, self.method_id, "epoch",
                                                                     epoch))
            data = self._window_tensors(wb)
            for idx in epoch_batches(len(wb), cfg.batch_size, gen):
                yield {k: v[idx] for k, v in data.items()}

        validate = None
        if val_items is not None:
            vb = val_items.draw(cfg.val_windows, numpy_rng(seed, self.method_id, "validation"))
            vdata = self._window_tensors(vb)
            validate = self._validator(vdata, len(vb), cfg.batch_size)

        result = train(self.net, opt, batches=batches, step=self.training_step,
                       epochs=cfg.epochs, seed=seed,
                       config=self.train_config(train_items, seed, val_items),
                       ckpt_dir=ckpt_dir, on_epoch=on_epoch, validate=validate)
        self.net.eval()
        return result

    @staticmethod
    def _crop(data: dict, idx: torch.Tensor) -> dict:
        return {k: v[idx] for k, v in data.items()}

    # -- inference -----------------------------------------------------------------------------
    @torch.no_grad()
    def sample_windows(self, labels, n_frames: int, *, seed: int, pool=None) -> torch.Tensor:
        """One generated window per label: (N, n_frames, J, 3) float32 joint positions in the
        window frame (first-frame root at the origin), noise drawn per item from ``seed``
        only.  ``pool`` is unused (only ODMO reads its training pool)."""
        labels = torch.as_tensor(np.asarray(labels, dtype=np.int64)).reshape(-1)
        n_frames = int(n_frames)
        if n_frames < 1:
            raise ConfigError(f"{self.method_id}: n_frames must be >= 1, got {n_frames}")
        if labels.numel() and (int(labels.min()) < 0 or int(labels.max()) >= self.n_classes):
            raise ConfigError(f"{self.method_id}: labels must lie in [0, {self.n_classes})")
        cfg, net = self.config, self.net
        net.eval()
        N = labels.numel()
        z_c = item_noise(seed, self.method_id, (N, cfg.dim_z_content), "content")
        h0 = item_noise(seed, self.method_id, (N, cfg.dim_z_motion), "h0")
        eps = item_noise(seed, self.method_id, (N, n_frames, cfg.dim_z_motion), "motion")
        out = torch.zeros(N, n_frames, self.n_joints, 3)
        for s in range(0, N, cfg.sample_batch_size):
            sl = slice(s, min(N, s + cfg.sample_batch_size))
            out[sl] = net.generate(*to_device((labels[sl], z_c[sl], h0[sl], eps[sl]), self.device)).cpu()
        return out

    def sample(self, cond_items, *, seed: int, use_mean: bool = False):
        raise ConfigError("act_mocogan emits joint positions; use sample_windows")
