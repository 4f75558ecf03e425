"""Evaluator settings: what a scale profile's ``[<scale>.evaluator]`` table may hold.

The dict is validated by :class:`EvaluatorSettings` (pydantic, unknown keys refused), with
defaults per scale from :data:`SCALE_DEFAULTS` overlaid by the profile's own keys (when
``repro.specs.scales`` is available).  Units: ``window`` in frames (30 fps on bandai2),
learning rate per Adam step, counts are windows.

Where the papers fix a value it is used at every scale:

- A2M GRU (ODMO supp. Table S3; protocols.md §2.1): 2 GRU layers × 128, a 30-d tanh feature
  layer, a linear classifier; UESTC variant (ODMO supp. Table S4): 3 GRU layers × 256;
  MultiAct's BABEL recogniser (protocols.md §2.3): 4 GRU layers × 256 (``multiact_gru``).
- Input: windows of ``window`` frames, first-frame root at the origin, absolute coordinates
  (protocols.md §2.1, §3.1); ``heading = "raw"`` is the A2M/ODMO convention.
- Paper-scale training (protocols.md §2.2, ODMO ``train_classifiers_a2m.py``): Adam 1e-3,
  cross-entropy, 15,000 epochs of one class-balanced draw of 2,048 windows.

The transformer recogniser (Neural Marionette §5.1.2 names one but gives no architecture) is
our choice; its shape is configurable here and recorded in the fingerprint.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from repro.errors import ConfigError, SpecError

KINDS = ("a2m_gru", "uestc_gru", "multiact_gru", "transformer")
Kind = Literal["a2m_gru", "uestc_gru", "multiact_gru", "transformer"]
Heading = Literal["raw", "yaw_augment", "remove"]
HiddenInit = Literal["zero", "learned", "random"]
Readout = Literal["last_step", "last_valid"]

# GRU shapes fixed by the papers (ODMO supp. Tables S3/S4; MultiAct's evaluate/load_classifier.py,
# protocols.md §2.3).
GRU_SHAPES = {"a2m_gru": {"layers": 2, "hidden": 128}, "uestc_gru": {"layers": 3, "hidden": 256},
              "multiact_gru": {"layers": 4, "hidden": 256}}


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class TransformerShape(_Strict):
    """Shape of the transformer recogniser (our choice; docs/evaluators.md)."""

    d_model: int = Field(128, ge=8)
    heads: int = Field(4, ge=1)
    layers: int = Field(4, ge=1)
    ff: int = Field(256, ge=8)
    dropout: float = Field(0.1, ge=0.0, lt=1.0)


class TrainSettings(_Strict):
    """How an evaluator is trained (through :func:`repro.train.train`)."""

    epochs: int = Field(ge=1)
    windows_per_epoch: int = Field(ge=1, description="class-balanced windows drawn per epoch")
    batch_size: int = Field(ge=1)
    lr: float = Field(1e-3, gt=0)
    weight_decay: float = Field(0.0, ge=0)
    class_balanced: bool = True
    grad_clip: float | None = Field(None, gt=0)
    checkpoint_every: int = Field(10, ge=1)
    threads: int = Field(1, ge=1, description="torch CPU threads for training and inference "
                         "(a fixed count keeps float reductions, hence weights, reproducible)")


class RealSettings(_Strict):
    """The real-data rows (``repro eval real``) and their gate."""

    per_class: int = Field(ge=2, description="windows per class in each replicate's real set")
    replicates: int = Field(ge=2)
    ci_method: Literal["z_sem", "t_sem", "z_sd_sqrt_nm1", "z_var", "none"] = Field(
        "z_sd_sqrt_nm1", description="paper-style ± (repro.stats.intervals; default ODMO's)")
    bootstrap: Literal["percentile", "bca"] = Field("bca", description="bootstrap interval method")
    gate_margin: float = Field(0.05, ge=0, le=1,
                               description="real accuracy may fall this far below test accuracy")
    max_fid: float = Field(1.0, gt=0, description="gate: FID(train, test) of real data above this fails")


class EvaluatorSettings(_Strict):
    """Everything that configures the evaluation classifiers at one scale."""

    window: int = Field(60, ge=2, description="frames per evaluated window (T)")
    heading: Heading = "raw"
    hidden_init: HiddenInit = "zero"
    readout: Readout = "last_step"
    feature_dim: int = Field(30, ge=2)
    include_last: bool = Field(False, description="random window starts may reach len − T "
                               "(False: the reference's exclusive bound)")
    min_window: int | None = Field(None, ge=2, description=(
        "training windows keep a valid length drawn uniformly in [min_window, window] (the rest "
        "padded by repeating the last frame, as scoring pads a shorter action); None: window. "
        "The Neural Marionette protocols set it to the composed actions' shortest length "
        "(issue 26), so the recogniser reads actions as short as those it scores"))
    test_stride: int | None = Field(None, ge=1, description="test-window stride; None = window // 2")
    facing_joints: tuple[str, str] | None = Field(
        None, description="left hip, right hip whose line gives the heading (heading = remove)")
    transformer: TransformerShape = TransformerShape()
    train: TrainSettings
    real: RealSettings

    def stride(self) -> int:
        return self.test_stride or max(1, self.window // 2)


# Defaults per scale.  quick: bandai2-mini, ≤ 1-2 min on a 2-core CPU; medium: bandai2,
# ≤ ~10 min; paper: ODMO's classifier recipe (GPU).  quick/medium use batches of 64 (4x the
# updates of batch 256 for the same CPU time: 94% test top-1 after 60 epochs instead of ~81%)
# and clip the gradient norm at 1 (batch 256 without clipping showed loss spikes).
SCALE_DEFAULTS: dict[str, dict] = {
    "quick": {
        "transformer": {"d_model": 64, "heads": 4, "layers": 2, "ff": 128, "dropout": 0.1},
        "train": {"epochs": 60, "windows_per_epoch": 1024, "batch_size": 64, "grad_clip": 1.0,
                  "checkpoint_every": 10},
        "real": {"per_class": 40, "replicates": 5, "max_fid": 3.0},
    },
    "medium": {
        "transformer": {"d_model": 64, "heads": 4, "layers": 2, "ff": 128, "dropout": 0.1},
        "train": {"epochs": 100, "windows_per_epoch": 2048, "batch_size": 64, "grad_clip": 1.0,
                  "checkpoint_every": 10},
        "real": {"per_class": 100, "replicates": 10},
    },
    # issue 32: the generators train to a plateau; the recognisers that score them as medium's
    "converged": {
        "transformer": {"d_model": 64, "heads": 4, "layers": 2, "ff": 128, "dropout": 0.1},
        "train": {"epochs": 100, "windows_per_epoch": 2048, "batch_size": 64, "grad_clip": 1.0,
                  "checkpoint_every": 10},
        "real": {"per_class": 100, "replicates": 10},
    },
    "paper": {
        "transformer": {"d_model": 128, "heads": 4, "layers": 4, "ff": 256, "dropout": 0.1},
        "train": {"epochs": 15000, "windows_per_epoch": 2048, "batch_size": 2048,
                  "checkpoint_every": 500},
        "real": {"per_class": 250, "replicates": 10},
    },
}


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def _profile_evaluator(scale: str) -> tuple[dict, str | None]:
    """The ``evaluator`` table of the scale profile (``tables/scales.toml``); empty when that
    file does not exist (the code defaults above then apply alone)."""
    from repro.specs.scales import resolve_scale, scales_path

    path = scales_path()
    if not path.is_file():
        return {}, None
    prof = resolve_scale(scale)
    return dict(prof.evaluator or {}), str(path)


def parse_settings(raw: dict, *, file: str | None = None, location: str = "evaluator") -> EvaluatorSettings:
    """Validate a raw ``evaluator`` dict; errors name the file, table and field."""
    try:
        return EvaluatorSettings.model_validate(raw)
    except ValidationError as e:
        err = e.errors()[0]
        field = ".".join(str(p) for p in err["loc"])
        raise SpecError(f"{field}: {err['msg']}", file, location) from None


def resolve_settings(scale: str, overrides: dict | None = None) -> EvaluatorSettings:
    """Settings for ``scale``: code defaults, then the profile's ``evaluator`` table, then
    ``overrides`` (for tests and the CLI)."""
    if scale not in SCALE_DEFAULTS:
        raise ConfigError(f"unknown scale {scale!r} (choose from {', '.join(SCALE_DEFAULTS)})")
    profile, src = _profile_evaluator(scale)
    raw = _merge(_merge(SCALE_DEFAULTS[scale], profile), overrides or {})
    return parse_settings(raw, file=src, location=f"{scale}.evaluator")


def architecture(kind: str, settings) -> dict:
    """The architecture description that enters the fingerprint (of the networks
    :func:`repro.eval.classifiers.build_module` builds; here, torch-free, so that a plan keys
    its evaluators without importing torch)."""
    if kind in GRU_SHAPES:
        return {"net": "gru", **GRU_SHAPES[kind], "feature_dim": settings.feature_dim,
                "feature_act": "tanh", "hidden_init": settings.hidden_init,
                "readout": settings.readout}
    return {"net": "transformer", **settings.transformer.model_dump(),
            "feature_dim": settings.feature_dim, "feature_act": "tanh", "readout": "class_token",
            "positions": "sinusoidal", "norm_first": True, "activation": "gelu"}
