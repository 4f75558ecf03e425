"""ODMO (Lu et al., ACM MM'22, "Action-conditioned On-demand Motion Generation"): §3, supp.
§2.1-2.3, §3, Table S2; reference-code facts: protocols.md §3.3, §3.5, §3.8, §3.9, §7.

Networks: :mod:`repro.models.odmo_nets` (LMP encoder ``Es_θ``, trajectory generator ``Gr_φ``,
motion generator ``Gm_ψ``, latent ``D = 20``), with the released code's layer shapes by default
(``encoder_head``, ``trajectory_input``, ``embed``: harness variants, Table S2 being silent on
those widths).  Data: windows of ``T`` frames of absolute joint xyz
(:class:`~repro.data.odmo_items.WindowItems`, first-frame root at the origin, data-set units).
**Window length.**  The code's trajectory generator expands its input to one learned input per
frame, so the network is built for one ``T`` (the code's ``motion_length``): ``window`` (``None``
= the training items' window length, adopted by :meth:`ODMO.fit` and then part of the saved
config, so a loaded model rebuilds the same network).  An untrained model with ``window=None``
has no network yet (under ``trajectory_input="code"``); decoding another number of frames is a
ConfigError.

Where the paper and the released code disagree the default is the code's reading and the
paper's is a switch (docs/odmo.md lists every line); the harness's earlier choices that were
neither stay as named harness variants.

**Losses** (Eq. 1-5; window ``x``, root ``r_t = x_t[0]``, ``z = μ + e^{logvar/2}·ε``, the
reference's ``rsample + mu``):

- ``L_mre`` (Eq. 3): squared error of the generated poses (all joints, absolute xyz);
- ``L_r`` (``traj_loss``): ``traj_target="position"`` (default, the code: ``to_location`` of the
  predicted velocities, a leading 0 then the cumulative sum, against the real root positions,
  ``T`` frames) or ``"velocity"`` (Eq. 2, the paper: the ``T − 1`` predicted velocities against
  ``r_t − r_{t−1}``; ``r̂_1 = 0`` is built in: Eq. 2's first term ``r_1 − r_0`` is 0);
- ``L_cons`` (Eq. 4, ``cons_loss``): squared distance of ``Gr``'s ``r̂_t`` to ``Gm``'s root joint
  (not y-weighted).  The reference adds it *into* its trajectory loss, so its "−L_traj" row drops
  both; we keep two switches (−L_traj: both false; −L_cons: ``cons_loss`` false);
- y weight: the y coordinate's squared error in ``L_mre`` and ``L_r`` is multiplied by
  ``y_weight`` (the reference's ``y_weights``; ``None`` → ``items.y_weight``, 5 HumanAct12 /
  UESTC, 1 MoCap); Eq. 2-3 weight no axis, so the paper's reading is ``y_weight = 1``;
- decoder time input (``decoder_time``): the code feeds ``(t+1)/T`` to each decoder step
  (default); §3.2(iii) lists only the previous pose and one-hot ⊗ z (``False``);
- reduction (:func:`~repro.models.odmo_nets.squared_error`): ``"code"`` (default; the released
  trainer: per frame the y-weighted squared error averaged over the frame's coordinates, then
  summed over frames), ``"sum"`` (the paper's Σ_t ‖·‖², summed over frames and coordinates) or
  ``"mean"`` (averaged over both; a harness variant, neither reading);
- pairs: every term is per *pair*, averaged over the batch's pairs (Eq. 1 is the pair's
  contrastive term plus KL(P1) + KL(P2); footnote 1 makes the other terms per motion, so a pair
  carries both motions' terms; the code sums the two windows' terms and averages over the
  batch): the per-window means are doubled (``PAIR``);
- contrastive (``contrastive``; Eq. 1's first two lines; ``d = ‖μ_1 − μ_2‖``, margin α = 5),
  averaged over pairs: ``contrastive_form="code"`` (default) same class ``0.5·relu(d² − 0.25)``,
  other class ``0.5·relu(α − d)²``; ``"paper"`` ``d²`` and ``relu(α − d)²``.
  ``contrastive=False`` is the −L_es ablation: the code drops the term (its ``use_contrastive``)
  and nothing takes its place (default, ``classic_mu_prior=False``); ``classic_mu_prior=True``
  is the paper's reading "ODMO becomes a classic VAE" (§4.2.4): the standard VAE's prior on μ,
  ``μᵀμ`` per window (supp. §3.1: the KL to N(0, I) splits into (a) μᵀμ and (b) the Σ term;
  ODMO replaces (a) by the contrastive prior and rescales (b) by σ²).  The KL below stays as
  configured either way;
- KL (averaged over windows).  Prior variance ``v = sigma2²`` (``sigma_reading="std"``, default,
  the reference's reading) or ``v = sigma2`` (``"variance"``).  ``kl_form="code"`` (default):
  ``KL(N(0, e^{logvar}) ‖ N(0, v))`` summed over latent dims (the mean excluded, as the reference);
  ``"paper"``: ``−ln det Σ + Tr(Σ)/v`` (Eq. 1), per window.  Combinations: code/std = the reference (std 0.05,
  var 0.0025); code/variance = that KL with the paper's σ² = 0.05; paper/std = Eq. 1 with
  σ² = 0.0025; paper/variance = Eq. 1 as printed.  Both are minimal at ``e^{logvar} = v``;
- ``L = λ_mre·L_mre + λ_r·L_r + λ_cons·L_cons + λ_es·contrastive + λ_kl·KL``, all λ = 1 (Eq. 5);
  the step's dict holds the unweighted terms (a switched-off term is absent).  Balance: with
  ``"sum"`` the reconstruction is ``J·3`` times the code's per frame (the contrastive and KL
  terms unchanged), so the paper's sums weight reconstruction far more against them; with
  ``"mean"`` it is ``T`` times smaller than the code's.

**Training** (supp. §2.1, protocols.md §3.9): each epoch draws ``windows_per_epoch`` (2,048)
(anchor, partner) pairs (``train_items.draw_pairs``, numpy generator from (seed, epoch)); the
anchors and the partners are encoded as two batches, as the code's two model calls (its
encoder's BatchNorm normalises each side over its own batch), then both go through the
generators as one batch (no other layer sees the batch; one teacher-forcing draw per step
serves both, where the code draws per call): reconstruction on both, contrastive on the pair; batches of ``batch_size`` (512) pairs; Adam
lr 1e-3, gradient-norm clip 1; ``epochs`` = the reference's 100,000.  ``Gr`` gets the real end
location (root at the last frame; zeros when ``use_end`` is false, the −r_e ablation, in training
and sampling) and the posterior sample ``z``; ``Gm`` gets the *predicted* trajectory ``r̂`` (the
paper's guidance trajectory T̂, Eq. 3; the code's ``pred_traj``) through its trajectory
encoder's final state ``h_0``, not detached, so ``L_mre`` also trains ``Gr`` (what keeps
``Gr`` trained in the −L_traj row).  Teacher forcing ``tf``: linear from ``tf_start`` 1.0 to
``tf_end`` 0.3 over ``tf_decay_epochs`` (4,000), then constant; drawn per step (odmo_nets).  The
reference keeps the checkpoint with the best *test* accuracy after epoch 5,000 (§7 item 14); we
keep the last epoch.  Validation: the same terms on a fixed seeded draw of ``val_pairs`` pairs.

**Inference** (protocols.md §3.3, §3.5): a *bank* of μ of ``bank_iters`` × ``windows_per_epoch``
class-balanced pool windows (``pool.draw``) with end locations.  ``sampling="mode_preserving"``,
per class: :func:`repro.metrics.modes.select_k` on the unique codes under ``k_rule``, a GMM(K)
refit with the same settings (full covariance, k-means, ``n_init`` 5, same seed), components
holding too few unique codes dropped per the rule (code ``<= 10``, paper ``< 10``,
"discovery": only empty ones; if all are small the largest stays), the threshold scaled by the
per-epoch draw against the reference's (``windows_per_epoch / 2048``, which gives the code's
absolute 10 at the paper's settings whatever the bank's passes and classes; 0.625
at quick, only empty components dropped, 1.25 at medium, single-code components dropped;
:func:`mode_preserving_codes`), ``floor(n·count/Σcount)`` draws per kept component,
the remainder to the first; under ``k_min + 1`` distinct codes one Gaussian (our fallback).
``"conventional"`` (ODMO_conv), ``conventional_form="code"``: the reference's "standard" (one
C-component GMM over all unique codes, k-means, tol 1e-4, max_iter 200, warm start; each class
keeps its codes in its majority component; two warm-started refits on the kept codes; each class
draws from its majority component); ``"paper"``: one Gaussian per class ("|C| GMMs").  End
point: 1-NN among the class's bank codes (Euclidean, duplicates included).  Decoding: ``Gr`` then
``Gm`` with tf = 0.  GMM seeds and draws derive from the call's seed (the reference fixes
random_state 0 and varies the bank).  ``sampling``, ``k_rule``, ``conventional_form`` and
``bank_iters`` are ``inference_fields``: ``fit`` never reads them; :meth:`describe` (the
training key) leaves them out.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, ClassVar, Mapping

import numpy as np
import torch

from repro.data.odmo_items import WindowItems
from repro.errors import ConfigError, DataError
from repro.models.base import Generator, register
from repro.models.odmo_config import ODMO, ODMOConfig  # noqa: F401 (ODMOConfig re-exported)
from repro.models.odmo_nets import ODMONet, contrastive_loss, kl_term, squared_error
from repro.seeding import derive_seed, numpy_rng
from repro.train.loop import to_device
from repro import kernels

_U32 = 2 ** 32
#: windows per pair: per-window means × PAIR = per-pair sums (Eq. 1, footnote 1)
PAIR = 2.0
#: the reference's pairs per epoch (protocols.md §3.9): its code bank of ``num_itr`` epochs'
#: windows is what the sampler's small-component threshold of 10 was set for
REFERENCE_WINDOWS_PER_EPOCH = 2048

# The paper's reading of every paper ↔ code difference (docs/odmo.md, "Paper ↔ code readings"),
# as ODMOConfig values: what a spec's "(paper reading)" row sets.  Training: every such row;
# sampling: where the row samples modes (k_rule) or samples conventionally (conventional_form);
# classic_mu_prior where the row drops the contrastive term (−L_es).
PAPER_TRAINING_READINGS: dict[str, object] = {
    "traj_target": "velocity", "reduction": "sum", "contrastive_form": "paper",
    "kl_form": "paper", "sigma_reading": "variance", "y_weight": 1.0, "decoder_time": False}
PAPER_SAMPLING_READINGS: dict[str, object] = {"k_rule": "paper", "conventional_form": "paper"}
PAPER_ABLATION_READINGS: dict[str, object] = {"classic_mu_prior": True}


# -- the code bank and code sampling (numpy) -------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Bank:
    """Encoded training windows: ``codes`` (M, D) float64 μ, ``ends`` (M, 3) float64 root xyz of
    the last frame, ``labels``, ``styles``, ``clips`` (clip rows), ``starts``: (M,) int64."""

    codes: np.ndarray
    ends: np.ndarray
    labels: np.ndarray
    styles: np.ndarray
    clips: np.ndarray
    starts: np.ndarray

    def __len__(self) -> int:
        return int(self.labels.shape[0])


def _gmm(k: int, seed: int, **kw):
    from sklearn.mixture import GaussianMixture

    return GaussianMixture(n_components=k, covariance_type="full", init_params="kmeans",
                           random_state=int(seed) % _U32, **kw)


def _fit(gmm, x: np.ndarray):
    from sklearn.exceptions import ConvergenceWarning
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1), warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        return gmm.fit(x)


def _gaussian(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    cov = np.cov(x, rowvar=False) if x.shape[0] > 1 else np.zeros((x.shape[1], x.shape[1]))
    return x.mean(0), np.atleast_2d(cov) + 1e-6 * np.eye(x.shape[1])


def mode_preserving_codes(codes: np.ndarray, n: int, *, rule: str, seed: int,
                          rng: np.random.Generator, modes=None,
                          bank_scale: float | None = None) -> np.ndarray:
    """``n`` codes of one class by mode-preserving sampling (module docstring): the GMM, its
    kept components and their counts are :func:`repro.metrics.modes.discover_modes`' fit of the
    class's distinct codes (K chosen under ``rule``, ``n_init`` 5, ``random_state`` from
    ``seed``); ``modes``: that result when the caller already has it, so it is not fitted
    twice.  ``bank_scale``: the per-epoch draw relative to the reference's (``windows_per_epoch
    / 2048``, :data:`REFERENCE_WINDOWS_PER_EPOCH`; not the bank's per-class size, which also
    depends on the passes and the classes: the ratio gives the code's absolute 10 at the
    paper's settings); the small-component threshold (the code's ``<= 10``, the paper's
    ``< 10``) is scaled by it, so a small bank keeps its modes (issue 27; ``None``: the
    published 10).  Table 3 scales per class instead (:mod:`repro.eval.protocols.latent_modes`)."""
    from repro.metrics.modes import RULES, discover_modes

    if rule not in RULES:
        raise ConfigError(f"odmo: unknown K rule {rule!r} (use one of {sorted(RULES)})")
    spec, uniq = RULES[rule], np.unique(np.asarray(codes, np.float64), axis=0)
    if uniq.shape[0] < spec.k_min + 1:
        return rng.multivariate_normal(*_gaussian(uniq), size=int(n))
    if modes is None:
        # the threshold scales by codes drawn / reference: bank_scale exactly
        ref = None if bank_scale is None else len(codes) / float(bank_scale)
        modes = discover_modes(codes, rule=rule, seed=int(seed) % _U32, n_init=5,
                               reference_codes=ref)
    gmm, counts, kept = modes.mixture, modes.counts, np.asarray(modes.kept, dtype=np.int64)
    alloc = (int(n) * counts[kept]) // counts[kept].sum()
    alloc[0] += int(n) - int(alloc.sum())
    parts = [rng.multivariate_normal(gmm.means_[c], gmm.covariances_[c], size=int(m))
             for c, m in zip(kept, alloc)]
    return np.concatenate(parts, axis=0) if parts else np.zeros((0, codes.shape[1]))


def conventional_gaussians(codes: np.ndarray, labels: np.ndarray, *, form: str,
                           seed: int) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """class → (mean, covariance) of the conventional sampler (module docstring)."""
    codes, labels = np.asarray(codes, np.float64), np.asarray(labels, np.int64)
    classes = np.unique(labels)
    if form == "paper":
        return {int(c): _gaussian(np.unique(codes[labels == c], axis=0)) for c in classes}
    if form != "code":
        raise ConfigError(f"odmo: unknown conventional form {form!r}")
    uniq, first = np.unique(codes, axis=0, return_index=True)
    ulab = labels[first]
    if uniq.shape[0] < classes.size:
        raise DataError(f"odmo: {uniq.shape[0]} distinct codes for {classes.size} components")
    gmm = _fit(_gmm(classes.size, seed, tol=1e-4, max_iter=200, warm_start=True), uniq)
    pred = gmm.predict(uniq)
    keep = np.zeros(uniq.shape[0], bool)
    for c in classes:
        rows = ulab == c
        keep |= rows & (pred == np.bincount(pred[rows]).argmax())
    for _ in range(2):  # the reference's two warm-started refits on the kept codes
        _fit(gmm, uniq[keep])
    pred, klab = gmm.predict(uniq[keep]), ulab[keep]
    out = {}
    for c in classes:
        m = int(np.bincount(pred[klab == c], minlength=classes.size).argmax())
        out[int(c)] = (gmm.means_[m], gmm.covariances_[m])
    return out


# -- the method ------------------------------------------------------------------------------------

@register
class ODMO(Generator):
    """ODMO behind the Generator interface (module docstring); emits joint positions."""

    card = ODMO
    item_kind: ClassVar[str] = "windows"
    uses_code_bank: ClassVar[bool] = True  # protocols pass inference fields to sample_windows
    uses = frozenset({"label", "length"})

    def __init__(self, config, skeleton, n_classes: int, fps: float):
        super().__init__(config, skeleton, n_classes, fps)
        self.net: ODMONet | None = None
        if not self._needs_window():
            self._build(derive_seed(0, self.method_id, "construct"))

    def _needs_window(self) -> bool:
        """True while the network cannot be built: the code's trajectory input and no window
        length yet (module docstring, "Window length")."""
        return self.config.trajectory_input == "code" and self.config.window is None

    def _make_network(self) -> ODMONet:
        c = self.config
        return ODMONet(self.skeleton.n_joints, self.n_classes, latent=c.latent_dim,
                       enc_hidden=c.enc_hidden, enc_feature=c.enc_feature, embed=c.embed,
                       hidden=c.hidden, encoder_head=c.encoder_head,
                       trajectory_input=c.trajectory_input, window=c.window,
                       decoder_time=c.decoder_time)

    @property
    def network(self) -> ODMONet:
        if self.net is None:
            raise ConfigError("odmo: the code's trajectory generator is built for one window "
                              "length: set the config's window, or fit the model first")
        return self.net

    def describe(self) -> dict:
        d = super().describe()
        d["config"] = {k: v for k, v in d["config"].items() if k not in self.inference_fields}
        return d

    def _check_items(self, items) -> None:
        if not isinstance(items, WindowItems):
            raise TypeError(f"odmo needs WindowItems, got {type(items).__name__}")
        if (items.n_joints, items.n_classes) != (self.skeleton.n_joints, self.n_classes):
            raise ConfigError(f"odmo: items have {items.n_joints} joints and {items.n_classes} "
                              f"classes, the model {self.skeleton.n_joints} and {self.n_classes}")
        if len(items) == 0:
            raise DataError("odmo: no items")
        w = self.config.window
        if self.config.trajectory_input == "code" and w is not None and items.window != w:
            raise ConfigError(f"odmo: the model is built for windows of {w} frames, the items "
                              f"have {items.window}")

    # -- training ------------------------------------------------------------------------------
    def plateau_rule(self):
        """The convergence rule (issue 32) reads ``val_loss`` only from the end of the
        teacher-forcing decay (``tf_decay_epochs``): while the share of teacher-forced steps
        falls, the loss measures a changing task (Sec. 4; the released code's schedule)."""
        from repro.train.plateau import PlateauRule

        return PlateauRule(start_epoch=int(self.config.tf_decay_epochs))

    def teacher_forcing(self, epoch: int) -> float:
        """tf at ``epoch``: linear from ``tf_start`` to ``tf_end`` over ``tf_decay_epochs``."""
        c = self.config
        frac = min(max(epoch, 0) / c.tf_decay_epochs, 1.0) if c.tf_decay_epochs > 0 else 1.0
        return float(c.tf_start + (c.tf_end - c.tf_start) * frac)

    def _pair_batches(self, anchor, partner, y_weight: float) -> list[dict]:
        """(anchor, partner) WindowBatches cut into training batches of ``batch_size`` pairs."""
        a, p = torch.from_numpy(anchor.joints), torch.from_numpy(partner.joints)
        la = torch.from_numpy(np.asarray(anchor.labels, np.int64))
        lp = torch.from_numpy(np.asarray(partner.labels, np.int64))
        bs = self.config.batch_size
        return [{"anchor": a[s:s + bs], "partner": p[s:s + bs], "labels_a": la[s:s + bs],
                 "labels_p": lp[s:s + bs], "y_weight": y_weight} for s in range(0, len(a), bs)]

    def training_step(self, net: ODMONet, batch: dict, epoch: int) -> dict[str, torch.Tensor]:
        """``L`` of the module docstring on one batch of pairs (posterior and teacher-forcing
        noise from the global torch RNG, which the training loop seeds per epoch)."""
        c = self.config
        B, T = batch["anchor"].shape[:2]
        x = torch.cat([batch["anchor"], batch["partner"]])
        labels = torch.cat([batch["labels_a"], batch["labels_p"]])
        yw = float(batch.get("y_weight", 1.0))
        # two encoder calls, as the code's one_batch: BatchNorm statistics per side
        (mu_a, lv_a), (mu_p, lv_p) = net.encode(batch["anchor"]), net.encode(batch["partner"])
        mu, logvar = torch.cat([mu_a, mu_p]), torch.cat([lv_a, lv_p])
        z = mu + torch.exp(0.5 * logvar) * torch.randn_like(mu)
        root = x[:, :, 0]
        end = root[:, -1] if c.use_end else torch.zeros_like(root[:, -1])
        vel, traj, poses = net.generate(z, labels, end, T, tf=self.teacher_forcing(epoch),
                                        target=x)
        # per pair (Eq. 1: the pair's contrastive term + KL(P1) + KL(P2); footnote 1: the
        # per-motion terms for both motions), averaged over the batch's pairs: the window
        # means below are doubled (PAIR) to be sums over the pair's two windows
        terms = {"mre": (c.lambda_mre, PAIR * squared_error(poses - x, yw, c.reduction))}
        if c.traj_loss:  # the code: positions (to_location); Eq. 2: velocities
            err = traj - root if c.traj_target == "position" else \
                vel - (root[:, 1:] - root[:, :-1])
            terms["traj"] = (c.lambda_r, PAIR * squared_error(err, yw, c.reduction))
        if c.cons_loss:
            terms["cons"] = (c.lambda_cons, PAIR * squared_error(traj - poses[:, :, 0], 1.0,
                                                                 c.reduction))
        if c.contrastive:
            same = batch["labels_a"] == batch["labels_p"]
            terms["contrastive"] = (c.lambda_es, contrastive_loss(
                mu[:B], mu[B:], same, margin=c.margin, form=c.contrastive_form).mean())
        elif c.classic_mu_prior:  # "a classic VAE": the standard prior's μᵀμ (supp. §3.1 (a))
            terms["mu_prior"] = (c.lambda_es, PAIR * (mu ** 2).sum(1).mean())
        terms["kl"] = (c.lambda_kl, PAIR * kl_term(logvar, form=c.kl_form, sigma2=c.sigma2,
                                                   reading=c.sigma_reading).mean())
        loss = sum(w * v for w, v in terms.values())
        return {"loss": loss, **{k: v.detach() for k, (_, v) in terms.items()}}

    def fit(self, train_items: WindowItems, *, seed: int, ckpt_dir: str | Path | None = None,
            on_epoch: Callable[[int, dict[str, float]], None] | None = None,
            val_items: WindowItems | None = None):
        """Train from ``seed`` (module docstring) through the one training loop."""
        from repro.train.loop import train

        self._check_items(train_items)
        if val_items is not None:
            self._check_items(val_items)
        if self._needs_window():  # the network is built for the items' window length
            self.config = self.config.model_copy(update={"window": int(train_items.window)})
        c = self.config
        self._build(derive_seed(seed, self.method_id, "init"))
        yw = float(c.y_weight if c.y_weight is not None else train_items.y_weight)
        opt = kernels.adam(self.net.parameters(), lr=c.lr)

        def batches(epoch, gen):
            rng = numpy_rng(seed, self.method_id, "epoch", epoch)
            return self._pair_batches(*train_items.draw_pairs(c.windows_per_epoch, rng), yw)

        validate = None
        if val_items is not None:
            vb = self._pair_batches(*val_items.draw_pairs(
                c.val_pairs, numpy_rng(seed, self.method_id, "validation")), yw)

            def validate(model, epoch):
                sums: dict[str, float] = {}
                for b in vb:
                    for k, v in self.training_step(model, b, epoch).items():
                        sums[k] = sums.get(k, 0.0) + len(b["anchor"]) * float(v)
                return {k: v / c.val_pairs for k, v in sums.items()}

        result = train(self.net, opt, batches=batches, step=self.training_step, epochs=c.epochs,
                       seed=seed, config=self.train_config(train_items, seed, val_items),
                       ckpt_dir=ckpt_dir, on_epoch=on_epoch, validate=validate,
                       grad_clip=c.grad_clip)
        self.net.eval()
        return result

    # -- inference -----------------------------------------------------------------------------
    @torch.no_grad()
    def latent_codes(self, batch_joints) -> np.ndarray:
        """μ (N, D) float64 of windows ``batch_joints`` (N, T, J, 3), computed on their LMP."""
        x = torch.as_tensor(np.asarray(batch_joints, np.float32))
        self.network.eval()
        bs = self.config.sample_batch_size
        out = [self.net.encode(x[s:s + bs].to(self.device))[0].cpu() for s in range(0, x.shape[0], bs)]
        return torch.cat(out).double().numpy() if out else np.zeros((0, self.config.latent_dim))

    def bank(self, pool: WindowItems, *, n_iter: int, seed: int) -> Bank:
        """μ, end location, label, style, clip and start of ``n_iter × windows_per_epoch``
        class-balanced windows of ``pool`` (module docstring)."""
        self._check_items(pool)
        rng = numpy_rng(seed, self.method_id, "bank")
        parts = []
        for _ in range(int(n_iter)):
            b = pool.draw(self.config.windows_per_epoch, rng)
            parts.append((self.latent_codes(b.joints), b.joints[:, -1, 0].astype(np.float64),
                          np.asarray(b.labels, np.int64),
                          np.asarray(pool.clipset.styles[b.indices], np.int64),
                          np.asarray(b.indices, np.int64), np.asarray(b.starts, np.int64)))
        return Bank(*(np.concatenate(col) for col in zip(*parts)))

    def sample_codes(self, bank: Bank, counts: Mapping[int, int] | int, *,
                     sampling: str | None = None, rule: str | None = None,
                     conventional_form: str | None = None,
                     seed: int) -> tuple[np.ndarray, np.ndarray]:
        """Codes (N, D) float64 and labels (N,), grouped by class in increasing order;
        ``counts`` = codes per class (a mapping, or one count for every class in the bank)."""
        c = self.config
        sampling, rule = sampling or c.sampling, rule or c.k_rule
        if isinstance(counts, (int, np.integer)):
            counts = {int(k): int(counts) for k in np.unique(bank.labels)}
        classes = sorted(int(k) for k, n in counts.items() if int(n) > 0)
        missing = [k for k in classes if not np.any(bank.labels == k)]
        if missing:
            raise DataError(f"odmo: no bank code of class(es) {missing}")
        if sampling == "conventional":
            gauss = conventional_gaussians(bank.codes, bank.labels, seed=derive_seed(
                seed, self.method_id, "gmm"), form=conventional_form or c.conventional_form)
        elif sampling != "mode_preserving":
            raise ConfigError(f"odmo: unknown sampling {sampling!r}")
        codes = []
        for k in classes:
            n, rng = int(counts[k]), numpy_rng(seed, self.method_id, "codes", k)
            if sampling == "conventional":
                codes.append(rng.multivariate_normal(*gauss[k], size=n))
            else:
                codes.append(mode_preserving_codes(
                    bank.codes[bank.labels == k], n, rule=rule, rng=rng,
                    seed=derive_seed(seed, self.method_id, "gmm", k),
                    bank_scale=c.windows_per_epoch / REFERENCE_WINDOWS_PER_EPOCH))
        labels = np.concatenate([np.full(int(counts[k]), k, np.int64) for k in classes] or
                                [np.zeros(0, np.int64)])
        out = np.concatenate(codes) if codes else np.zeros((0, c.latent_dim))
        return out.astype(np.float64), labels

    @staticmethod
    def end_points(codes, labels, bank: Bank) -> np.ndarray:
        """(N, 3): the end location of each code's nearest bank code of its class (1-NN)."""
        from scipy.spatial.distance import cdist

        codes, labels = np.asarray(codes, np.float64), np.asarray(labels, np.int64)
        out = np.zeros((labels.shape[0], 3))
        for k in np.unique(labels):
            rows, pool = labels == k, np.flatnonzero(bank.labels == k)
            if pool.size == 0:
                raise DataError(f"odmo: no bank code of class {int(k)}")
            near = np.argmin(cdist(codes[rows], bank.codes[pool]), axis=1)
            out[rows] = bank.ends[pool[near]]
        return out

    @torch.no_grad()
    def decode(self, codes, labels, ends, n_frames: int, *,
               use_end: bool | None = None) -> torch.Tensor:
        """(N, n_frames, J, 3): ``Gr`` then ``Gm`` with tf = 0; ends are zeroed when the config's
        ``use_end`` (or the ``use_end`` given here) is false."""
        z = torch.as_tensor(np.asarray(codes, np.float32))
        lab = torch.as_tensor(np.asarray(labels, np.int64))
        e = torch.as_tensor(np.asarray(ends, np.float32)).reshape(-1, 3)
        if not (self.config.use_end and (use_end is None or use_end)):
            e = torch.zeros_like(e)
        self.network.eval()
        bs, J = self.config.sample_batch_size, self.skeleton.n_joints
        out = torch.zeros(z.shape[0], int(n_frames), J, 3)
        for s in range(0, z.shape[0], bs):
            out[s:s + bs] = self.net.generate(*to_device((z[s:s + bs], lab[s:s + bs], e[s:s + bs]),
                                                         self.device), int(n_frames))[2].cpu()
        return out

    def sample_windows(self, labels, n_frames: int, *, seed: int, pool: WindowItems | None = None,
                       sampling: str | None = None, rule: str | None = None,
                       n_iter: int | None = None, k_rule: str | None = None,
                       conventional_form: str | None = None,
                       bank_iters: int | None = None) -> torch.Tensor:
        """One window (n_frames, J, 3) per label, in ``labels``' order: bank of ``pool``, codes
        per class, 1-NN end points, decoding (module docstring); randomness from ``seed`` only.
        Options override the config's inference fields (``k_rule``, ``bank_iters`` are the
        config's names for ``rule``, ``n_iter``; a protocol may pass either)."""
        if pool is None:
            raise ConfigError("odmo: sample_windows needs the training pool (pool=...)")
        lab = np.asarray(labels, np.int64).reshape(-1)
        if lab.size == 0:
            return torch.zeros(0, int(n_frames), self.skeleton.n_joints, 3)
        n_iter = n_iter or bank_iters or self.config.bank_iters
        bank = self.bank(pool, n_iter=n_iter, seed=seed)
        classes, n = np.unique(lab, return_counts=True)
        codes, code_labels = self.sample_codes(
            bank, dict(zip(classes.tolist(), n.tolist())), sampling=sampling,
            rule=rule or k_rule, conventional_form=conventional_form, seed=seed)
        poses = self.decode(codes, code_labels, self.end_points(codes, code_labels, bank),
                            n_frames)
        out = torch.empty_like(poses)
        out[torch.from_numpy(np.argsort(lab, kind="stable"))] = poses
        return out

    def sample(self, cond_items, *, seed: int, use_mean: bool = False):
        raise ConfigError("odmo emits joint positions; use sample_windows")
