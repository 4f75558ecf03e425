"""``latent_modes``: modes discovered in a method's latent space, scored on real motions
(ODMO Table 3, §4.3.1; protocols.md §3.7) — plus, beyond the paper, against the stand-in's
ground-truth styles, and two calibration latents that learned nothing.

A replicate draws ``codes_per_class`` real training windows per class (the real reference-set
draw of :func:`repro.eval.protocols.odmo_common.real_set`, seeded by the replicate; the
reference's bank windows are such a draw, duplicates included), encodes them with the row's
model — ODMO: the LMP encoder's mean; ACTOR: its transformer encoder's mean μ given the
window (rotations) and the tag — and, per class, discovers modes with the GMM + silhouette
selection of :mod:`repro.metrics.modes` under ``k_rule``.  Default ``"discovery"``: the
rule of the released mode-discovery script (``cluster_multimodal``: K = 3..9, stop at the first
silhouette drop > 5 %, K = k_break − 1, 8 if it never stops, no component dropped) — no released
script computes Table 3, and that script is the release's one discovery of modes in real
sequences' codes; ``"paper"`` is supplement §2.2's (K = 3..11, first S_i > 0.95·S_{i+1}, < 10
dropped); ``"code"`` the sampler's (as "discovery" but K = 9 if it never stops and <= 10
dropped).  The rule is a *protocol* parameter, so a table shows both rules as column groups
(every row in a column under the same rule; ODMO's own ``k_rule`` is its sampler's, which
Table 3 never runs).  The small-component threshold of the dropping rules is scaled by
``n / reference_codes`` (n = codes drawn; :func:`repro.metrics.modes.small_scale`;
``reference_codes`` = the reference bank's codes per class, 2,560 HumanAct12, 410 UESTC), so a
multi-mode latent keeps its modes at small scales.
Windows of dropped components go to their most probable kept mode (``small_modes``).

Columns:

- ``mode_homogeneity`` (%, the paper's): 100 × mean over classes of (APD(G_c) −
  mode-APD(G_c)) / APD(G_c), APD on the flattened windows (:func:`repro.metrics.modes.mode_apd`),
  every drawn window;
- harness columns (not in the paper; the stand-in records each clip's performance style, 7
  per action, a ground truth of "modes" no paper data set has): ``style_ami`` and
  ``style_ari`` — adjusted mutual information and adjusted Rand index (scikit-learn; both
  chance-corrected: 0 for modes independent of the styles, whatever K) between the discovered
  modes and the windows' styles, per class then averaged over classes.  Windows with more
  than ``max_padded_share`` of their frames padded (a clip shorter than the window repeats
  its last frame, :func:`repro.data.odmo_items.padded_frames`) are left out of the style
  columns, since a frozen tail is a feature any latent of raw motion picks up and it follows
  the clip's length, not its style; the modes are still fitted on every window.

Rows with method ``"real"`` (``real_row_options``: the row's ``latent`` override):

- no ``latent``: the "Real Motions" row, one group per class (no modes): 0 by construction,
  as the paper prints;
- ``latent = "random"`` (harness calibration): codes drawn from N(0, I_D), D =
  ``calibration_dim``, independent of the windows;
- ``latent = "pca"`` (harness calibration): each window's raw local movement (joints minus
  the root joint, flattened over the window) projected on its first D principal components,
  the PCA fitted on the replicate's drawn windows (no training, no labels).

Both calibration latents go through the very scoring of the method rows (:meth:`LatentModes.score`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field

from repro.errors import ConfigError, DataError
from repro.eval.protocols import register
from repro.eval.protocols.odmo_common import OdmoContext, OdmoParams, OdmoProtocol, real_batch
from repro.seeding import derive_seed, numpy_rng

SAVE_FORMAT = 2
STYLE_METRICS = ("style_ami", "style_ari")
CALIBRATION_LATENTS = ("random", "pca")


class LatentModesParams(OdmoParams):
    codes_per_class: int = Field(250, ge=4, description="real windows per class encoded (not "
                                 "stated in the paper; the generation count by default)")
    k_rule: Literal["code", "paper", "discovery"] = Field(
        "discovery", description="K selection (repro.metrics.modes): the released "
        "mode-discovery script's rule by default, 'paper' for supplement §2.2's, 'code' for "
        "the released sampler's")
    reference_codes: int | None = Field(
        2560, ge=1, description="codes per class the small-component threshold (10) was set "
        "for: the reference bank's (2,560 HumanAct12, 410 UESTC); the threshold scales by "
        "codes / reference_codes (None: the unscaled 10)")
    small_modes: Literal["reassign", "exclude"] = Field(
        "reassign", description="windows of dropped components: to the nearest kept mode, or out")
    gmm_inits: int = Field(5, ge=1, description="GaussianMixture n_init (the reference's 5)")
    max_padded_share: float = Field(0.25, ge=0, le=1, description="style columns leave out "
                                    "windows with more than this share of padded frames")
    calibration_dim: int = Field(20, ge=1, description="D of the calibration latents (ODMO's "
                                 "latent size)")


@dataclass(frozen=True, eq=False)
class LatentSamples:
    """One replicate: the encoded real windows (``joints`` (N, T, J, 3), ``labels``,
    ``styles``, ``padded`` frames per window) and their codes (N, D)."""

    joints: np.ndarray
    labels: np.ndarray
    styles: np.ndarray
    codes: np.ndarray
    skeleton: object
    fps: float
    padded: np.ndarray

    def __len__(self) -> int:
        return int(self.labels.size)


def latent_codes(generator, pool, batch) -> np.ndarray:
    """(N, D) latent means of the windows ``batch`` of ``pool`` under ``generator``."""
    import torch

    if hasattr(generator, "latent_codes"):  # ODMO: the LMP encoder on xyz windows
        out = generator.latent_codes(batch.joints)
    elif hasattr(generator, "net") and hasattr(generator.net, "encode"):  # ACTOR
        from repro.models.baseline_io import pack_poses

        items = pool.action_items(batch)
        poses = pack_poses(items.action)
        rows = []
        generator.net.eval()
        with torch.no_grad():
            for s in range(0, len(items), 256):
                idx = torch.arange(s, min(len(items), s + 256))
                rows.append(generator.net.encode(poses[idx], items.labels[idx],
                                                 items.lengths[idx])[0])
        out = torch.cat(rows)
    else:
        who = getattr(generator, "method_id", type(generator).__name__)
        raise DataError(f"method {who!r} has no encoder whose latent space could hold modes")
    out = out.detach().cpu().numpy() if isinstance(out, torch.Tensor) else np.asarray(out)
    return out.astype(np.float64)


def calibration_codes(latent: str, joints: np.ndarray, dim: int, seed: int) -> np.ndarray:
    """(N, D) codes of a calibration row (module docstring): ``"random"`` N(0, I_D) seeded by
    ``seed``; ``"pca"`` the first D principal components of the windows' local movement
    (joints minus joint 0, flattened), fitted on these windows."""
    n = int(joints.shape[0])
    if latent == "random":
        return numpy_rng(seed, "latent_modes", "random-codes").standard_normal((n, int(dim)))
    if latent == "pca":
        from sklearn.decomposition import PCA

        x = np.asarray(joints, np.float64)
        lmp = (x - x[:, :, :1, :]).reshape(n, -1)
        d = min(int(dim), n, lmp.shape[1])
        return PCA(n_components=d, svd_solver="full").fit_transform(lmp)
    raise ConfigError(f"latent_modes: unknown calibration latent {latent!r} (use one of "
                      f"{', '.join(CALIBRATION_LATENTS)})")


@register
class LatentModes(OdmoProtocol):
    """ODMO Table 3 (module docstring)."""

    id = "latent_modes"
    Params = LatentModesParams
    params: LatentModesParams
    metrics = ("mode_homogeneity", *STYLE_METRICS)
    real_metrics = ("mode_homogeneity",)  # plus the style columns on a calibration row
    real_row_options = ("latent",)
    version = 2

    def test_items(self, clipset) -> OdmoContext:
        return self.context(clipset, self.params.codes_per_class)

    def windows(self, ctx: OdmoContext, seed: int):
        return real_batch(ctx.train, self.params.codes_per_class, seed, "latent_modes")

    def _samples(self, ctx: OdmoContext, b, codes: np.ndarray) -> LatentSamples:
        from repro.data.odmo_items import padded_frames

        return LatentSamples(b.joints, b.labels.astype(np.int64),
                             ctx.train.clipset.styles[b.indices].astype(np.int64),
                             np.asarray(codes, np.float64), ctx.train.skeleton, ctx.train.fps,
                             padded_frames(b))

    def generate(self, generator, ctx: OdmoContext, *, seed: int, replicate: int, need=None,
                 models=None, row_config=None) -> LatentSamples:
        b = self.windows(ctx, self.replicate_seed(seed, replicate))
        return self._samples(ctx, b, latent_codes(generator, ctx.train, b))

    # -- scoring ---------------------------------------------------------------------------------
    def _modes(self, codes: np.ndarray, seed: int):
        from repro.metrics.modes import discover_modes

        p = self.params
        return discover_modes(codes, rule=p.k_rule, seed=seed, small_modes=p.small_modes,
                              n_init=p.gmm_inits, reference_codes=p.reference_codes)

    def score(self, samples: LatentSamples, n_classes: int, seed: int) -> dict[str, float]:
        """Every column of one replicate (module docstring), the same for every row."""
        from sklearn.metrics import adjusted_mutual_info_score, adjusted_rand_score

        from repro.metrics.modes import mode_apd

        T = int(samples.joints.shape[1])
        usable_frames = samples.padded <= self.params.max_padded_share * T
        homog, ami, ari = [], [], []
        for c in range(n_classes):
            rows = np.flatnonzero(samples.labels == c)
            if rows.size < 4:
                raise DataError(f"latent modes: class {c} has {rows.size} windows (need 4)")
            codes, styles = samples.codes[rows], samples.styles[rows]
            gseed = derive_seed(seed, "latent_modes", "gmm", c) % (2 ** 31)
            modes = self._modes(codes, gseed)
            total, weighted = mode_apd(samples.joints[rows], modes.assignment)
            if total == 0.0:
                raise DataError(f"latent modes: class {c} has APD 0 (identical windows)")
            homog.append(100.0 * (total - weighted) / total)
            use = (modes.assignment >= 0) & usable_frames[rows]
            if use.sum() >= 2:
                ami.append(adjusted_mutual_info_score(styles[use], modes.assignment[use]))
                ari.append(adjusted_rand_score(styles[use], modes.assignment[use]))
        if not ami:
            raise DataError("latent modes: no class has two windows padded by at most "
                            f"{self.params.max_padded_share:.0%} (style columns)")
        return {"mode_homogeneity": float(np.mean(homog)), "style_ami": float(np.mean(ami)),
                "style_ari": float(np.mean(ari))}

    def measure(self, generated: LatentSamples, ctx: OdmoContext, evaluator, *, seed: int,
                clipset=None) -> dict[str, float]:
        return self.score(generated, ctx.train.n_classes, seed)

    def real_replicate(self, clipset, ctx: OdmoContext, evaluator, *, seed: int,
                       replicate: int, latent: str | None = None) -> dict[str, float]:
        """The "Real Motions" row (``latent`` None) or a calibration row (module docstring)."""
        from repro.metrics.modes import mode_apd

        s = self.replicate_seed(seed, replicate)
        b = self.windows(ctx, s)
        if latent is not None:
            codes = calibration_codes(latent, b.joints, self.params.calibration_dim, s)
            return self.score(self._samples(ctx, b, codes), ctx.train.n_classes, seed)
        vals = []
        for c in range(ctx.train.n_classes):
            rows = np.flatnonzero(b.labels == c)
            total, weighted = mode_apd(b.joints[rows], np.zeros(rows.size, dtype=np.int64))
            v = 100.0 * (total - weighted) / total if total else 0.0
            vals.append(0.0 if abs(v) < 1e-9 else v)  # one mode: equal up to float rounding
        return {"mode_homogeneity": float(np.mean(vals))}

    # -- keeping samples ---------------------------------------------------------------------------
    def save_generated(self, generated: LatentSamples, path) -> Path:
        from repro.eval.sample_files import save_samples

        meta = {"format": SAVE_FORMAT, "protocol": self.id, "fps": float(generated.fps),
                "skeleton": generated.skeleton.to_dict(), "kind": "latent_codes"}
        return save_samples(path, meta, {"joints": generated.joints, "labels": generated.labels,
                                         "styles": generated.styles, "codes": generated.codes,
                                         "padded": generated.padded})

    def load_generated(self, path) -> LatentSamples:
        from repro.eval.sample_files import load_samples

        meta, data, skeleton = load_samples(path, protocol=self.id, fmt=SAVE_FORMAT)
        try:
            return LatentSamples(data["joints"], data["labels"].astype(np.int64),
                                 data["styles"].astype(np.int64), data["codes"], skeleton,
                                 float(meta["fps"]), data["padded"].astype(np.int64))
        except KeyError as e:
            raise DataError(f"malformed samples (missing {e})", path) from None


__all__ = ["LatentModes", "LatentModesParams", "latent_codes", "calibration_codes",
           "CALIBRATION_LATENTS"]
