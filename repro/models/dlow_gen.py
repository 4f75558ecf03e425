"""DLow-Gen: DLow (Yuan & Kitani, ECCV 2020, "DLow: Diversifying Latent Flows for Diverse Human
Motion Prediction") turned into an action-conditioned generator, the ODMO baseline (ODMO MM'22
§4.2.3, supplement §2.4).

**What the ODMO paper says.**  §4.2.3: "a slightly modified version of a SOTA probabilistic
prediction model, DLow (DLow-Gen): we replaced the initial frames of the given motion sequence
with its activity category label".  Supp. §2.4: "we adapted it to motion generation task by
replacing the motion history condition as the class one-hot encoding.  We trained the Gen-DLow
(both VAE and DLow) in much more epochs (5000, 600) than the default parameter (500, 500)".
Nothing else (no code of the adaptation is released; protocols.md has no DLow-Gen section).

**What DLow's released code does** (repository ``Khrylx/DLow``: ``models/motion_pred.py``
``VAE`` and ``NFDiag``, ``motion_pred/exp_vae.py``, ``motion_pred/exp_dlow.py``,
``motion_pred/cfg/h36m_nsamp10.yml``, ``motion_pred/utils/config.py``; facts only, our code is
our own), Human3.6M setting, every value below is a default of this module:

*Stage 1, a conditional VAE* (``VAE``, ``rnn_type: gru``, uni-directional encoders,
``use_drnn_mlp: true``; ``nh_rnn`` 128, ``nh_mlp`` [300, 200], ``nz`` 128; DLow's ``MLP`` is
Linear+tanh per hidden layer):

- history encoder ``h_x``: the last hidden state of a GRU (128) over the observed frames;
- future encoder ``h_y``: the last hidden state of a GRU (128) over the future frames;
- ``MLP([h_x, h_y])`` (256 → 300 → 200, tanh) → ``μ``, ``log σ²`` (linear, ``nz``);
- decoder: a GRU cell (128) whose initial state is ``MLP(h_x)`` (128 → 300 → 200 → 128,
  tanh); at step ``t`` its input is ``[h_x, z, ŷ_{t−1}]`` (``ŷ_{−1}`` = the last observed
  pose), its output goes through ``MLP`` (128 → 300 → 200, tanh) and a linear head to the
  pose ``ŷ_t`` (the next input: fully autoregressive, no teacher forcing);
- loss per batch of ``B``: ``Σ‖ŷ − y‖²/B + λ_v·Σ‖x_{last} − ŷ_0‖²/B + β·KL(q(z|x,y) ‖ N(0,I))``
  (the KL summed over ``nz`` and the batch, divided by ``B``), ``β`` = 0.1, ``λ_v`` = 1000;
  ``z`` reparameterised; Adam lr 1e-3; batch 64; 500 epochs, an epoch being
  ``5000 // 64`` = 78 batches of windows (subject, then action, then start drawn uniformly;
  ``Dataset.sampling_generator``), the learning rate constant for 100 epochs
  (``num_vae_epoch_fix``) then decayed linearly (``lr·(1 − max(0, e − fix)/(epochs − fix +
  1))``, DLow's ``get_scheduler('lambda')``).

*Stage 2, DLow* (``NFDiag``, the H36M config's ``model_name``): the VAE is frozen (loaded,
``eval()``, only the DLow network in the optimiser).  A second history encoder (GRU 128) →
``MLP`` (128 → 1024 → 512, tanh, ``dlow_specs.nh_mlp``) → two linear heads giving, for each
of the ``nk`` = 10 flows (``h36m_nsamp10.yml``), a diagonal ``a_k`` and ``b_k`` (``nz`` each);
one ``ε ~ N(0, I)`` per condition is shared by the flows: ``z_k = a_k ⊙ ε + b_k``.  Each
``z_k`` is decoded by the frozen VAE decoder and the loss is

``L = λ_kl·KL + λ_j·L_div + λ_recon·L_recon`` with

- ``KL = −½ Σ (1 + log a² − b² − a²) / (B·nk)``: KL(N(b_k, diag a_k²) ‖ N(0, I)) summed over
  ``nz``, averaged over the ``B·nk`` codes; ``λ_kl`` = 1 (config default);
- ``L_div``: for each condition, the mean over the ``nk(nk−1)/2`` pairs of decoded futures of
  ``exp(−d²/d_scale)``, ``d²`` the squared Euclidean distance of the flattened (frames × pose)
  vectors; averaged over the batch; ``d_scale`` = 100, ``λ_j`` = 25;
- ``L_recon``: for each condition, ``min_k Σ_{t} ‖ŷ_{k,t} − y_t‖²`` (the closest flow),
  averaged over the batch; ``λ_recon`` = 2.0.

Adam lr 1e-4, batch 64, 500 epochs of 78 batches, the same schedule (fix 100).  DLow
computes in float64, on Human3.6M's 17 joints at 50 fps (25 observed, 100 predicted frames),
positions relative to the root with the root joint itself dropped, not normalised.

**Our adaptation** (choices where ODMO is silent; all recorded):

- **Condition.**  Both history encoders become an embedding of the class one-hot into the
  history feature size: ``h_x = tanh(W·onehot + c)`` (128; tanh keeps it in the range of the
  GRU state it replaces).  The VAE and the DLow network have one embedding each, as they
  have one history GRU each.
- **Data.**  ODMO's windows (:class:`repro.data.odmo_items.WindowItems`): ``T`` frames of all
  ``J`` joints' positions, flattened to ``J·3`` per frame, the first frame's root at the
  origin (the root is kept: the generated motion must carry its trajectory).  The whole
  window is the "future"; units metres × ``scale``; float32.
- **First decoder input** ``ŷ_{−1}``: there is no observed pose, so a zero vector.
- **λ_v dropped.**  DLow's continuity term ``‖x_{last} − ŷ_0‖²`` ties the first predicted
  frame to the last observed one; with no observed frame it has no target, so it is not used.
- **Epochs.**  ``vae_epochs`` = 5000 and ``dlow_epochs`` = 600 (ODMO supp. §2.4; "(5000,600)"
  read as (VAE, DLow) as the sentence orders them).  An epoch is ODMO's class-balanced draw
  of ``windows_per_epoch`` = 2048 windows (ODMO's loader; DLow's own epoch is 78 × 64 = 4,992
  windows), cut into batches of 64 in draw order (DLow's batch, both stages): 32 optimiser
  steps per epoch, so 160,000 (VAE) and 19,200 (DLow) steps at paper scale.  The
  learning-rate schedule keeps DLow's ``num_*_epoch_fix`` = 100, then decays linearly to the
  stage's last epoch (how ODMO scheduled its longer runs is not stated).
- **Diversity scale.**  ``d_scale`` stays 100 (units², here m²), although ``d²`` now runs
  over ``T·J·3`` numbers (HumanAct12: 60·24·3 = 4,320; DLow's H36M futures: 100·16·3 =
  4,800, a comparable length).
- **Both stages in one** :meth:`DLowGen.fit`: each runs through the one training loop
  (:func:`repro.train.loop.train`) with its own checkpoint folder (``ckpt_dir/"vae"``,
  ``ckpt_dir/"dlow"``), its own loop seed (``derive_seed(seed, "dlow_gen", stage)``) and its
  own window draws (``numpy_rng(seed, "dlow_gen", stage, "epoch", e)``); the weights of both
  are initialised together from ``derive_seed(seed, "dlow_gen", "init")``.  During stage 2
  the VAE's parameters have ``requires_grad`` off and are not in the optimiser.  The returned
  history is stage 1's records then stage 2's, each with ``stage`` ("vae" / "dlow"),
  ``stage_epoch`` and ``epoch`` = the running index over both stages.
- **One sample per label** (DLow gives ``nk`` samples per condition).  The items of one class,
  in the order given, form consecutive groups of ``nk``; a group shares one ``ε`` (drawn for
  the group's first item from the seed: ``item_noise``) and its ``r``-th member uses flow
  ``k = r mod nk``.  So a class's samples cover all flows in DLow's own ``nk``-sets,
  whatever the order of the labels.

Units: positions in metres × the window source's ``scale``, frames at the data set's fps.
"""

from __future__ import annotations

from collections.abc import Callable
from itertools import pairwise
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from repro.errors import ConfigError
from repro.models.base import Generator, register
from repro.models.baseline_io import check_matches_model, item_noise
from repro.models.dlow_gen_config import DLOW_GEN, DLowGenConfig
from repro.seeding import derive_seed, numpy_rng
from repro import kernels

STAGES = ("vae", "dlow")


# ---------------------------------------------------------------------------------------------
# networks


class TanhMLP(nn.Module):
    """Linear + tanh per hidden size (DLow's ``MLP``); ``out_dim`` = the last size."""

    def __init__(self, n_in: int, sizes: tuple[int, ...]):
        super().__init__()
        dims = (n_in,) + tuple(sizes)
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in pairwise(dims))
        self.out_dim = dims[-1]

    def forward(self, x):
        for lin in self.layers:
            x = torch.tanh(lin(x))
        return x


class LabelEmbedding(nn.Module):
    """The history encoder's replacement: ``tanh(W·onehot + c)`` of size ``nh_rnn``."""

    def __init__(self, n_classes: int, size: int):
        super().__init__()
        self.n_classes = n_classes
        self.lin = nn.Linear(n_classes, size)

    def forward(self, labels: torch.Tensor) -> torch.Tensor:
        onehot = F.one_hot(labels, self.n_classes).to(self.lin.weight.dtype)
        return torch.tanh(self.lin(onehot))


class CondVAE(nn.Module):
    """Stage 1 (module docstring): label embedding, future GRU encoder, autoregressive GRU
    decoder with MLP head."""

    def __init__(self, cfg: DLowGenConfig, ny: int, n_classes: int):
        super().__init__()
        self.ny, self.nz = ny, cfg.nz
        h = cfg.nh_rnn
        self.x_enc = LabelEmbedding(n_classes, h)
        self.e_rnn = nn.GRU(ny, h, batch_first=True)
        self.e_mlp = TanhMLP(2 * h, cfg.nh_mlp)
        self.e_mu = nn.Linear(self.e_mlp.out_dim, cfg.nz)
        self.e_logvar = nn.Linear(self.e_mlp.out_dim, cfg.nz)
        self.drnn_mlp = TanhMLP(h, tuple(cfg.nh_mlp) + (h,))
        self.d_rnn = nn.GRUCell(ny + cfg.nz + h, h)
        self.d_mlp = TanhMLP(h, cfg.nh_mlp)
        self.d_out = nn.Linear(self.d_mlp.out_dim, ny)

    def encode(self, labels: torch.Tensor, y: torch.Tensor):
        """``(μ, log σ²)`` of ``q(z | label, y)``; ``y`` (B, T, ny)."""
        h_x = self.x_enc(labels)
        _, h_y = self.e_rnn(y)
        h = self.e_mlp(torch.cat([h_x, h_y[-1]], dim=-1))
        return self.e_mu(h), self.e_logvar(h)

    def decode(self, labels: torch.Tensor, z: torch.Tensor, n_frames: int) -> torch.Tensor:
        """(B, n_frames, ny) poses, fed back frame by frame from a zero first input."""
        h_x = self.x_enc(labels)
        hx = self.drnn_mlp(h_x)
        prev = z.new_zeros(z.shape[0], self.ny)
        out = []
        for _ in range(int(n_frames)):
            hx = self.d_rnn(torch.cat([h_x, z, prev], dim=-1), hx)
            prev = self.d_out(self.d_mlp(hx))
            out.append(prev)
        return torch.stack(out, dim=1)


class DLowFlows(nn.Module):
    """Stage 2 (``NFDiag``): label embedding → MLP → diagonal affine maps of ``nk`` flows."""

    def __init__(self, cfg: DLowGenConfig, n_classes: int):
        super().__init__()
        self.nz, self.nk = cfg.nz, cfg.nk
        self.x_enc = LabelEmbedding(n_classes, cfg.nh_rnn)
        self.mlp = TanhMLP(cfg.nh_rnn, cfg.dlow_nh_mlp)
        self.head_a = nn.Linear(self.mlp.out_dim, cfg.nz * cfg.nk)
        self.head_b = nn.Linear(self.mlp.out_dim, cfg.nz * cfg.nk)

    def forward(self, labels: torch.Tensor, eps: torch.Tensor):
        """``z`` (B, nk, nz) = ``a ⊙ ε + b`` with one ``ε`` (B, nz) per condition; also
        ``a``, ``b`` (B, nk, nz)."""
        h = self.mlp(self.x_enc(labels))
        a = self.head_a(h).view(-1, self.nk, self.nz)
        b = self.head_b(h).view(-1, self.nk, self.nz)
        return a * eps[:, None, :] + b, a, b


class DLowGenNet(nn.Module):
    """Both stages' weights in one module (saved and loaded together)."""

    def __init__(self, cfg: DLowGenConfig, ny: int, n_classes: int):
        super().__init__()
        self.vae = CondVAE(cfg, ny, n_classes)
        self.dlow = DLowFlows(cfg, n_classes)


# ---------------------------------------------------------------------------------------------
# losses


def vae_kl(mu: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
    """KL(N(μ, σ²) ‖ N(0, I)) summed over all elements."""
    return -0.5 * (1 + logvar - mu.pow(2) - logvar.exp()).sum()


def flow_kl(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """KL(N(b, diag a²) ‖ N(0, I)) summed over all elements (DLow's ``NFDiag.get_kl``)."""
    var = a.pow(2)
    return -0.5 * (1 + var.log() - b.pow(2) - var).sum()


def diversity_energy(y: torch.Tensor, d_scale: float) -> torch.Tensor:
    """Mean over conditions of the mean over sample pairs of ``exp(−d²/d_scale)``; ``y``
    (B, K, D) flattened samples, ``d²`` squared Euclidean distances."""
    K = y.shape[1]
    sq = y.pow(2).sum(-1)
    d2 = (sq[:, :, None] + sq[:, None, :] - 2 * y @ y.transpose(1, 2)).clamp_min(0)
    iu = torch.triu_indices(K, K, offset=1, device=y.device)
    return torch.exp(-d2[:, iu[0], iu[1]] / d_scale).mean()


def min_of_k_recon(y_g: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Mean over conditions of ``min_k ‖y_k − y‖²``; ``y_g`` (B, K, D), ``y`` (B, D)."""
    return (y_g - y[:, None]).pow(2).sum(-1).min(dim=1).values.mean()


def linear_decay(epochs: int, fix: int) -> Callable[[int], float]:
    """DLow's schedule factor: 1 for ``fix`` epochs, then linear towards 0 at ``epochs``."""
    span = float(max(epochs - fix, 0) + 1)
    return lambda e: 1.0 - max(0, e - fix) / span


# ---------------------------------------------------------------------------------------------


@register
class DLowGen(Generator):
    """DLow-Gen (module docstring) behind the :class:`~repro.models.base.Generator` interface:
    trains on ODMO's windows, samples joint positions with :meth:`sample_windows`."""

    card = DLOW_GEN
    item_kind = "windows"
    # ``uses``: Generator's default, the label and the length

    def __init__(self, config, skeleton, n_classes: int, fps: float):
        super().__init__(config, skeleton, n_classes, fps)
        self.ny = 3 * skeleton.n_joints
        self._build(derive_seed(0, self.method_id, "construct"))

    def _make_network(self) -> DLowGenNet:
        return DLowGenNet(self.config, self.ny, self.n_classes)

    @property
    def network(self) -> DLowGenNet:
        return self.net

    # -- data ----------------------------------------------------------------------------------
    def _check_windows(self, items) -> None:
        from repro.data.odmo_items import WindowItems

        who = self.method_id
        if not isinstance(items, WindowItems):
            raise TypeError(f"{who} trains on repro.data.odmo_items.WindowItems, "
                            f"got {type(items).__name__}")
        check_matches_model(who, items, "windows", n_joints=self.skeleton.n_joints,
                            n_classes=self.n_classes, fps=self.fps,
                            empty="no clips in the window pool")

    @staticmethod
    def _batch_of(wb) -> dict[str, torch.Tensor]:
        """A WindowBatch as tensors: ``y`` (N, T, J·3) float32, ``labels`` (N,) int64."""
        return {"y": torch.from_numpy(np.ascontiguousarray(wb.flat(), dtype=np.float32)),
                "labels": torch.from_numpy(np.asarray(wb.labels, dtype=np.int64))}

    @staticmethod
    def _chunks(data: dict, size: int):
        n = data["labels"].shape[0]
        for s in range(0, n, size):
            yield {k: v[s:s + size] for k, v in data.items()}

    # -- training steps ------------------------------------------------------------------------
    def vae_step(self, vae: CondVAE, batch: dict, epoch: int) -> dict[str, torch.Tensor]:
        """Stage 1 loss ``Σ‖ŷ − y‖²/B + β·KL/B`` (posterior noise from the global torch RNG,
        which the training loop seeds per epoch)."""
        y, labels = batch["y"], batch["labels"]
        B, T = y.shape[:2]
        mu, logvar = vae.encode(labels, y)
        z = mu + torch.exp(0.5 * logvar) * torch.randn_like(mu)
        y_r = vae.decode(labels, z, T)
        mse = (y_r - y).pow(2).sum() / B
        kld = vae_kl(mu, logvar) / B
        loss = mse + self.config.beta * kld
        with torch.no_grad():
            err = (y_r - y).view(B, T, -1, 3).norm(dim=-1).mean()
        return {"loss": loss, "mse": mse.detach(), "kld": kld.detach(), "mpjpe": err}

    def dlow_step(self, dlow: DLowFlows, batch: dict, epoch: int) -> dict[str, torch.Tensor]:
        """Stage 2 loss ``λ_kl·KL + λ_j·L_div + λ_recon·L_recon`` through the frozen VAE
        decoder (``ε`` from the global torch RNG); a term with weight 0 is logged, not added."""
        cfg, vae = self.config, self.net.vae
        y, labels = batch["y"], batch["labels"]
        B, T = y.shape[:2]
        K = cfg.nk
        eps = torch.randn(B, cfg.nz, dtype=y.dtype, device=y.device)
        z, a, b = dlow(labels, eps)
        kld = flow_kl(a, b) / (B * K)
        y_g = vae.decode(labels.repeat_interleave(K), z.reshape(B * K, cfg.nz), T)
        y_g = y_g.reshape(B, K, T * self.ny)
        div = diversity_energy(y_g, cfg.d_scale)
        rec = min_of_k_recon(y_g, y.reshape(B, T * self.ny))
        loss = y.new_zeros(())
        for w, term in ((cfg.lambda_kl, kld), (cfg.lambda_j, div), (cfg.lambda_recon, rec)):
            if w > 0:
                loss = loss + w * term
        with torch.no_grad():
            err = (y_g.view(B, K, T, -1, 3) - y.view(B, 1, T, -1, 3)).norm(dim=-1).mean((2, 3))
            mink = err.min(dim=1).values.mean()
        return {"loss": loss, "kld": kld.detach(), "div": div.detach(), "recon": rec.detach(),
                "min_mpjpe": mink}

    def _window_validator(self, step, data: dict):
        """The loop's ``validate``: ``step`` on the fixed validation windows in batches, each
        scalar averaged over windows."""
        n = int(data["labels"].shape[0])
        size = self.config.batch_size

        def validate(model, epoch):
            sums: dict[str, float] = {}
            for chunk in self._chunks(data, size):
                out = step(model, chunk, epoch)
                w = int(chunk["labels"].shape[0])
                for k, v in out.items():
                    sums[k] = sums.get(k, 0.0) + w * float(v)
            return {k: v / max(n, 1) for k, v in sums.items()}

        return validate

    # -- fit -----------------------------------------------------------------------------------
    def fit(self, train_items, *, seed: int, ckpt_dir: str | Path | None = None,
            on_epoch: Callable[[int, dict], None] | None = None, val_items=None):
        """Stage 1 (VAE, ``vae_epochs``) then stage 2 (DLow, ``dlow_epochs``), each through the
        one training loop (module docstring); returns a TrainResult whose history holds both
        stages' records (``stage``, ``stage_epoch``; ``epoch`` runs over both)."""
        from repro.train.loop import TrainResult, train

        self._check_windows(train_items)
        if val_items is not None:
            self._check_windows(val_items)
        cfg = self.config
        self._build(derive_seed(seed, self.method_id, "init"))
        val_data = None
        if val_items is not None:
            rng = numpy_rng(seed, self.method_id, "validation")
            val_data = self._batch_of(val_items.draw(cfg.val_windows, rng))
        base_cfg = self.train_config(train_items, seed, val_items)
        history: list[dict] = []
        results = []
        vae, dlow = self.net.vae, self.net.dlow
        plan = (("vae", vae, self.vae_step, cfg.vae_lr, cfg.vae_epochs, cfg.vae_epochs_fix),
                ("dlow", dlow, self.dlow_step, cfg.dlow_lr, cfg.dlow_epochs, cfg.dlow_epochs_fix))
        offset = 0
        for stage, module, step, lr, epochs, fix in plan:
            def batches(epoch, gen, stage=stage):
                rng = numpy_rng(seed, self.method_id, stage, "epoch", epoch)
                data = self._batch_of(train_items.draw(cfg.windows_per_epoch, rng))
                yield from self._chunks(data, cfg.batch_size)

            def relabel(rec, stage=stage, offset=offset):
                return {**rec, "epoch": offset + int(rec["epoch"]),
                        "stage_epoch": int(rec["epoch"]), "stage": stage}

            def hook(epoch, rec, relabel=relabel):
                if on_epoch is not None:
                    r = relabel(rec)
                    on_epoch(r["epoch"], r)

            opt = kernels.adam(module.parameters(), lr=lr)
            sched = torch.optim.lr_scheduler.LambdaLR(opt, linear_decay(epochs, fix))
            validate = None if val_data is None else self._window_validator(step, val_data)
            frozen = [vae] if stage == "dlow" else []
            for m in frozen:
                m.eval()
                m.requires_grad_(False)
            try:
                res = train(module, opt, batches=batches, step=step, epochs=epochs,
                            seed=derive_seed(seed, self.method_id, stage),
                            config={**base_cfg, "stage": stage},
                            ckpt_dir=None if ckpt_dir is None else Path(ckpt_dir) / stage,
                            on_epoch=hook, scheduler=sched,
                            validate=validate)
            finally:
                for m in frozen:
                    m.requires_grad_(True)
            history.extend(relabel(r) for r in res.history)
            results.append(res)
            offset += len(res.history)  # the stage's epochs (fewer when it stopped at a plateau)
        r_vae, r_dlow = results
        n_vae = len(r_vae.history)  # the VAE's epochs (fewer than its cap at a plateau)
        if r_vae.resumed_from is not None and r_vae.resumed_from < n_vae:
            resumed = r_vae.resumed_from
        elif r_vae.resumed_from is not None or r_dlow.resumed_from is not None:
            resumed = n_vae + (r_dlow.resumed_from or 0)
        else:
            resumed = None
        self.net.eval()
        reasons = [r.stopped_by for r in results]
        stopped_by = next((r for r in reasons if r != "plateau"), "plateau")
        return TrainResult(epochs=offset, resumed_from=resumed, history=history,
                           seconds=sum(r.seconds for r in results), stopped_by=stopped_by)

    # -- inference -----------------------------------------------------------------------------
    def flow_assignment(self, labels: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Per item: the flow ``k`` it uses and the item whose ``ε`` it shares (module
        docstring: groups of ``nk`` consecutive items of one class)."""
        K = self.config.nk
        N = labels.numel()
        flow = torch.empty(N, dtype=torch.long)
        leader = torch.empty(N, dtype=torch.long)
        for c in torch.unique(labels).tolist():
            pos = torch.nonzero(labels == c).flatten()
            r = torch.arange(pos.numel())
            flow[pos] = r % K
            leader[pos] = pos[r - r % K]
        return flow, leader

    @torch.no_grad()
    def sample_windows(self, labels, n_frames: int, *, seed: int, pool=None) -> torch.Tensor:
        """(N, n_frames, J, 3) float32 joint positions in the window frame, one per label
        (module docstring: shared ``ε`` per group of ``nk`` same-class items, flow
        ``r mod nk``); noise from ``seed`` only.  ``pool`` is not used."""
        cfg, net = self.config, self.net
        labels = torch.as_tensor(np.asarray(labels, dtype=np.int64)).reshape(-1)
        if int(n_frames) < 1:
            raise ConfigError(f"{self.method_id}: n_frames must be >= 1, got {n_frames}")
        N = labels.numel()
        if N and (int(labels.min()) < 0 or int(labels.max()) >= self.n_classes):
            raise ConfigError(f"{self.method_id}: labels must lie in [0, {self.n_classes})")
        net.eval()
        flow, leader = self.flow_assignment(labels)
        eps = item_noise(seed, self.method_id, (N, cfg.nz))[leader]
        dev = next(net.parameters()).device
        out = torch.empty(N, int(n_frames), self.ny)
        for s in range(0, N, cfg.sample_batch_size):
            sl = slice(s, min(N, s + cfg.sample_batch_size))
            lab = labels[sl].to(dev)
            z, _, _ = net.dlow(lab, eps[sl].to(dev))
            zk = z[torch.arange(z.shape[0], device=dev), flow[sl].to(dev)]
            out[sl] = net.vae.decode(lab, zk, int(n_frames)).float().cpu()
        return out.view(N, int(n_frames), -1, 3)

    def sample(self, cond_items, *, seed: int, use_mean: bool = False):
        raise ConfigError("dlow_gen emits joint positions; use sample_windows")
