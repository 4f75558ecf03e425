"""``latent_modes``: modes discovered in a method's latent space, scored on real motions
(ODMO Table 3, §4.3.1; protocols.md §3.7) — plus, beyond the paper, against the stand-in's
ground-truth styles.

A replicate draws ``codes_per_class`` real training windows per class (the real reference-set
draw of :func:`repro.eval.protocols.odmo_common.real_set`, seeded by the replicate; the
reference's bank windows are such a draw, duplicates included), encodes them with the row's
model — ODMO: the LMP encoder's mean; ACTOR: its transformer encoder's mean μ given the
window (rotations) and the tag — and, per class, discovers modes with the GMM + silhouette
selection of :mod:`repro.metrics.modes` under ``k_rule`` (default ``"paper"``: supplement
§2.2's rule, K = 3..11, components below 10 codes dropped and their windows reassigned to
the most probable kept mode; no released script computes Table 3, so the paper's definition
is followed; ``"code"`` and ``"discovery"`` are the reference's sampler and discovery-script
rules).

Columns:

- ``mode_homogeneity`` (%, the paper's): 100 × mean over classes of (APD(G_c) −
  mode-APD(G_c)) / APD(G_c), APD on the flattened windows (:func:`repro.metrics.modes.mode_apd`);
- harness columns (not in the paper; the stand-in records each clip's performance style, 7
  per action, a ground truth of "modes" no paper data set has): ``style_nmi`` and
  ``style_ari`` — normalised mutual information and adjusted Rand index (scikit-learn) between
  the discovered modes and the windows' styles, per class then averaged over classes;
  ``style_coverage`` (%) — per class, ``codes_per_class`` codes are drawn by ODMO's
  mode-preserving sampler from that class's codes (the same sampler on either latent space,
  :func:`repro.models.odmo.mode_preserving_codes`, drawing from the very GMM the modes were
  discovered with, ``gmm_inits`` initialisations), each takes the style of its nearest
  encoded window of the class, and the share of the class's styles present among them is
  averaged over classes.

The "Real Motions" row is one group per class (no modes): its mode-homogeneity is computed
with every window in one mode, 0 by construction, as the paper prints.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from pydantic import Field

from repro.errors import DataError
from repro.eval.protocols import register
from repro.eval.protocols.odmo_common import OdmoContext, OdmoParams, OdmoProtocol, real_batch
from repro.seeding import derive_seed

SAVE_FORMAT = 1
STYLE_METRICS = ("style_nmi", "style_ari", "style_coverage")


class LatentModesParams(OdmoParams):
    codes_per_class: int = Field(250, ge=4, description="real windows per class encoded (not "
                                 "stated in the paper; the generation count by default)")
    k_rule: Literal["paper", "code", "discovery"] = Field(
        "paper", description="K selection (repro.metrics.modes): the paper's rule by default")
    small_modes: Literal["reassign", "exclude"] = Field(
        "reassign", description="windows of dropped components: to the nearest kept mode, or out")
    gmm_inits: int = Field(5, ge=1, description="GaussianMixture n_init (the reference's 5)")


@dataclass(frozen=True, eq=False)
class LatentSamples:
    """One replicate: the encoded real windows (``joints`` (N, T, J, 3), ``labels``,
    ``styles``) and their codes (N, D); ``model`` says whose latent space."""

    joints: np.ndarray
    labels: np.ndarray
    styles: np.ndarray
    codes: np.ndarray
    skeleton: object
    fps: float

    def __len__(self) -> int:
        return int(self.labels.size)


def latent_codes(generator, pool, batch) -> np.ndarray:
    """(N, D) latent means of the windows ``batch`` of ``pool`` under ``generator``."""
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


@register
class LatentModes(OdmoProtocol):
    """ODMO Table 3 (module docstring)."""

    id = "latent_modes"
    Params = LatentModesParams
    params: LatentModesParams
    metrics = ("mode_homogeneity", *STYLE_METRICS)
    real_metrics = ("mode_homogeneity",)
    version = 1

    def test_items(self, clipset) -> OdmoContext:
        return self.context(clipset, self.params.codes_per_class)

    def windows(self, ctx: OdmoContext, seed: int):
        return real_batch(ctx.train, self.params.codes_per_class, seed, "latent_modes")

    def generate(self, generator, ctx: OdmoContext, *, seed: int, replicate: int, need=None,
                 models=None, row_config=None) -> LatentSamples:
        s = self.replicate_seed(seed, replicate)
        b = self.windows(ctx, s)
        codes = latent_codes(generator, ctx.train, b)
        return LatentSamples(b.joints, b.labels.astype(np.int64),
                             ctx.train.clipset.styles[b.indices].astype(np.int64), codes,
                             ctx.train.skeleton, ctx.train.fps)

    # -- scoring ---------------------------------------------------------------------------------
    def _modes(self, codes: np.ndarray, seed: int):
        from repro.metrics.modes import discover_modes

        p = self.params
        return discover_modes(codes, rule=p.k_rule, seed=seed, small_modes=p.small_modes,
                              n_init=p.gmm_inits)

    def measure(self, generated: LatentSamples, ctx: OdmoContext, evaluator, *, seed: int,
                clipset=None) -> dict[str, float]:
        from sklearn.metrics import adjusted_rand_score, normalized_mutual_info_score

        from repro.metrics.modes import mode_apd
        from repro.models.odmo import mode_preserving_codes

        p = self.params
        homog, nmi, ari, cover = [], [], [], []
        for c in range(ctx.train.n_classes):
            rows = np.flatnonzero(generated.labels == c)
            if rows.size < 4:
                raise DataError(f"latent modes: class {c} has {rows.size} windows (need 4)")
            codes, styles = generated.codes[rows], generated.styles[rows]
            gseed = derive_seed(seed, "latent_modes", "gmm", c) % (2 ** 31)
            modes = self._modes(codes, gseed)
            total, weighted = mode_apd(generated.joints[rows], modes.assignment)
            if total == 0.0:
                raise DataError(f"latent modes: class {c} has APD 0 (identical windows)")
            homog.append(100.0 * (total - weighted) / total)
            inside = modes.assignment >= 0
            nmi.append(normalized_mutual_info_score(styles[inside], modes.assignment[inside]))
            ari.append(adjusted_rand_score(styles[inside], modes.assignment[inside]))
            drawn = mode_preserving_codes(codes, p.codes_per_class, rule=p.k_rule, seed=gseed,
                                          rng=np.random.default_rng(gseed), modes=modes)
            d2 = ((drawn[:, None, :] - codes[None, :, :]) ** 2).sum(-1)
            hit = np.unique(styles[np.argmin(d2, axis=1)])
            cover.append(100.0 * hit.size / np.unique(styles).size)
        return {"mode_homogeneity": float(np.mean(homog)), "style_nmi": float(np.mean(nmi)),
                "style_ari": float(np.mean(ari)), "style_coverage": float(np.mean(cover))}

    def real_replicate(self, clipset, ctx: OdmoContext, evaluator, *, seed: int,
                       replicate: int) -> dict[str, float]:
        from repro.metrics.modes import mode_apd

        b = self.windows(ctx, seed)
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
                                         "styles": generated.styles, "codes": generated.codes})

    def load_generated(self, path) -> LatentSamples:
        from repro.eval.sample_files import load_samples

        meta, data, skeleton = load_samples(path, protocol=self.id, fmt=SAVE_FORMAT)
        try:
            return LatentSamples(data["joints"], data["labels"].astype(np.int64),
                                 data["styles"].astype(np.int64), data["codes"], skeleton,
                                 float(meta["fps"]))
        except KeyError as e:
            raise DataError(f"malformed samples (missing {e})", path) from None


__all__ = ["LatentModes", "LatentModesParams", "latent_codes"]
