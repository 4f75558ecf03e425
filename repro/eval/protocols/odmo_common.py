"""What ODMO's three protocols share (``odmo_generation``, ``latent_modes``,
``trajectory_customisation``; ODMO MM'22 §4, supplement §2.5; protocols.md §1, §2.2, §3).

**Data** (protocols.md §3.1).  Every ODMO protocol reads xyz windows of ``window`` frames, the
first frame's root at the origin, no rotation, cut from the data set's stored split:
:class:`repro.data.odmo_items.WindowSource` (:meth:`OdmoProtocol.item_source`) makes the
training pool (train split only) and the test pool.  Its ``describe()`` is the training items'
description, so every ODMO protocol whose window fields agree trains one model per method
config (Tables 1, 3, 4 and S1 share ODMO's trainings).

**Paper data sets on the stand-in.**  ODMO's tables have one column group per data set
(HumanAct12, UESTC, CMU MoCap).  The stand-in has one data set, so a group is a set of
protocol parameters, recorded in the spec and printed in the footer: ``window`` (60 / 60 / 100
frames), ``y_weight`` (ODMO's per-data-set loss weight: 5 / 5 / 1), ``per_class`` (250 / 200 /
400 samples per class and set), ``bank_iters`` (the code bank's loader passes: 15 / 8 / 5),
``classifier`` (the A2M GRU 2×128 / ODMO's UESTC GRU 3×256 / 2×128) and ``fid_references``
(HumanAct12 and MoCap: the training split only; UESTC: train and test).  MoCap's division by
20 is a unit change of CMU's data and does not apply to metres (``scale`` 1).

**The recogniser** (protocols.md §2.2): the evaluator kind ``classifier`` at the window of the
group (``evaluator_overrides``), trained on the data set's train split (no scored test clip is
seen), raw heading (ODMO's convention: no rotation; the stand-in's classes have fixed
headings, so the recogniser may key on them — every method is scored in the same frame).

**Real reference sets** (protocols.md §3.2): ``per_class`` windows of every class, clips drawn
uniformly with replacement within the class, random starts (:func:`real_set`).  FID uses one
fixed real set per split, "real file 0", drawn from ``reference_seed`` (§3.4, §7-7: the
reference's variability is not in the interval); n-APD pairs generated set *i* with real set
*i* (§3.6), here the training-split set drawn from replicate *i*'s seed.

**The metric block** (§1, §3.4): ``acc`` (top-1, in % as the tables print it), ``fid`` /
``fid_train`` (against the training-split reference), ``fid_test`` (against the test-split
reference, when the group asks for it), ``div`` (200 pairs), ``multimod`` (20 same-class pairs
per class, divided by 20·C), each feature pass seeded.

**Generators.**  Window-trained methods (ODMO, DLow-Gen, Act-MoCoGAN) give joint positions by
``sample_windows(labels, n_frames, seed=..., pool=<training pool>)``; ODMO also takes the
group's ``bank_iters`` and the row's inference options (``sampling``, ``k_rule``,
``conventional_form``).  ACTOR and Action2Motion are conditioned on label-only items
(:func:`repro.data.odmo_items.label_condition_items`: tag, duration ``window``, identity
placement; the initial pose is a training-pool frame, never a scored clip) and their joints
are read by ``sample_joints`` (A2M-xyz) or forward kinematics of ``sample``.

Units: metres × ``scale``; FID in squared feature units; accuracy and n-APD in %.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Literal, Mapping

import numpy as np
from pydantic import Field

from repro.data.clip_draws import per_class_clips
from repro.data.clipset import TEST, TRAIN
from repro.data.odmo_items import WindowItems, WindowSource, label_condition_items
from repro.errors import ConfigError, DataError
from repro.eval.protocols.base import ItemParams, ItemProtocol
from repro.seeding import derive_seed, numpy_rng

SAVE_FORMAT = 1
SPLITS = {"train": TRAIN, "test": TEST}


class OdmoParams(ItemParams):
    """What every ODMO protocol reads (the HumanAct12 values of the reference by default).  The
    item fields (``window``, ``y_weight``, ``scale``, ``partner`` and the ``windows`` dict) are
    :class:`repro.data.odmo_items.WindowSource`'s."""

    ITEM_SOURCE: ClassVar[type] = WindowSource
    ITEM_FIELDS: ClassVar[Mapping[str, str]] = {
        "window": "window", "y_weight": "y_weight", "scale": "scale", "partner": "partner"}
    MORE_ITEM_FIELDS: ClassVar[str | None] = "windows"

    # how windows are made (WindowSource; enter the training items' key)
    window: int = Field(60, ge=2, description="T: 60 HumanAct12 / UESTC, 100 MoCap (§3.1)")
    y_weight: float = Field(5.0, gt=0, description="ODMO's y-axis loss weight (5; MoCap 1)")
    scale: float = Field(1.0, gt=0, description="position factor (MoCap /20 is CMU's unit)")
    partner: Literal["class_uniform", "sample_uniform"] = Field(
        "class_uniform", description="the contrastive partner of another class: uniform over "
        "classes (the reference's MoCap loader) or over samples (its HumanAct12 / UESTC ones)")
    windows: dict = Field(default_factory=dict, description="other WindowSource fields")
    # the reference's per-data-set settings (protocols.md §3.2-3.4)
    per_class: int = Field(250, ge=2, description="samples per class in each generated and "
                           "real set (250 HumanAct12, 200 UESTC, 400 MoCap)")
    bank_iters: int = Field(15, ge=1, description="code bank: loader passes of windows_per_epoch "
                            "windows (15 HumanAct12, 8 UESTC, 5 MoCap)")
    classifier: Literal["a2m_gru", "uestc_gru"] = Field(
        "a2m_gru", description="recogniser: A2M's 2×128 GRU, or ODMO's UESTC 3×256 GRU")
    fid_references: tuple[Literal["train", "test"], ...] = Field(
        ("train",), min_length=1, description="real splits FID is measured against")
    reference_seed: int = Field(0, description="seed of the fixed real set 0 (§3.4)")
    replicates: int | None = Field(None, ge=1, description="read by the engine (scale profile)")
    # the metric core (§1)
    div_pairs: int = Field(200, ge=1)
    multimod_pairs: int = Field(20, ge=1)
    fid_method: Literal["eigh", "scipy"] = Field("eigh", description="repro.metrics.fid method")


@dataclass(frozen=True, eq=False)
class OdmoSamples:
    """One replicate's generated windows: ``joints`` (N, T, J, 3) float32, ``labels`` (N,);
    trajectory customisation adds ``targets`` (N, 3), the requested end locations."""

    joints: np.ndarray
    labels: np.ndarray
    skeleton: object
    fps: float
    targets: np.ndarray | None = None

    def __post_init__(self) -> None:
        j = np.ascontiguousarray(np.asarray(self.joints, dtype=np.float32))
        y = np.asarray(self.labels, dtype=np.int64).reshape(-1)
        if j.ndim != 4 or j.shape[-1] != 3 or j.shape[0] != y.size:
            raise DataError(f"samples: joints {tuple(j.shape)} do not match {y.size} labels")
        if not np.isfinite(j).all():
            raise DataError("samples: generated joints contain NaN or infinity")
        object.__setattr__(self, "joints", j)
        object.__setattr__(self, "labels", y)
        if self.targets is not None:
            t = np.asarray(self.targets, dtype=np.float64)
            if t.shape != (y.size, 3):
                raise DataError(f"samples: targets {tuple(t.shape)}, expected ({y.size}, 3)")
            object.__setattr__(self, "targets", t)

    def __len__(self) -> int:
        return int(self.labels.size)


def save_samples(protocol_id: str, samples: OdmoSamples, path: str | Path) -> Path:
    """Write ``samples`` to the npz file ``path`` atomically (:mod:`repro.eval.sample_files`)."""
    from repro.eval.sample_files import save_samples as _save

    meta = {"format": SAVE_FORMAT, "protocol": protocol_id, "fps": float(samples.fps),
            "skeleton": samples.skeleton.to_dict(), "has_targets": samples.targets is not None,
            "kind": "joints"}
    arrays = {"joints": samples.joints, "labels": samples.labels}
    if samples.targets is not None:
        arrays["targets"] = samples.targets
    return _save(path, meta, arrays)


def load_samples(protocol_id: str, path: str | Path) -> OdmoSamples:
    """Read :func:`save_samples`' file (DataError naming it when it is not one)."""
    from repro.eval.sample_files import load_samples as _load

    meta, data, skeleton = _load(path, protocol=protocol_id, fmt=SAVE_FORMAT)
    try:
        return OdmoSamples(data["joints"], data["labels"], skeleton, float(meta["fps"]),
                           data.get("targets") if meta.get("has_targets") else None)
    except KeyError as e:
        raise DataError(f"malformed samples (missing {e})", path) from None


@dataclass(frozen=True, eq=False)
class OdmoContext:
    """What a replicate starts from: the training and test pools (:class:`WindowItems`) and
    the labels of the samples to generate (class-major, ``per_class`` each)."""

    train: WindowItems
    test: WindowItems | None
    labels: np.ndarray

    def __len__(self) -> int:
        return int(self.labels.size)

    @property
    def skeleton(self):
        return self.train.skeleton

    @property
    def label_names(self) -> tuple[str, ...]:
        return self.train.label_names


def real_batch(pool, per_class: int, seed: int, *tag):
    """ODMO's real reference set (protocols.md §3.2) as a WindowBatch: ``per_class`` windows
    of every class of ``pool`` (clips with replacement, random starts), classes in index order."""
    rng = numpy_rng(seed, "odmo", "real-set", *tag)
    return pool.random_cut(per_class_clips(pool.clipset, pool.indices, per_class, rng), rng)


def real_set(pool, per_class: int, seed: int, *tag):
    """:func:`real_batch` as (joints (N, T, J, 3), labels (N,))."""
    b = real_batch(pool, per_class, seed, *tag)
    return b.joints, b.labels.astype(np.int64)


class OdmoProtocol(ItemProtocol):
    """Base of the ODMO protocols (module docstring)."""

    Params = OdmoParams
    params: OdmoParams
    takes_models = True      # the engine passes the row's config (ODMO's inference options)
    #: printed under every ODMO table (repro.engine.runner)
    footer_note = ("Model selection: the reference code keeps the checkpoint with the best test "
                   "accuracy (protocols.md §3.9); the harness selects nothing on test data: "
                   "every model is its last epoch.")
    measure_uses_clipset = True

    # -- data --------------------------------------------------------------------------------
    @property
    def evaluator_kind(self) -> str:  # type: ignore[override]
        return self.params.classifier

    def evaluator_overrides(self) -> dict:
        """Evaluator settings this protocol needs over the scale's: its window."""
        return {"window": int(self.params.window)}

    def context(self, clipset, per_class: int) -> OdmoContext:
        src = self.item_source()
        train = src.train_items(clipset)
        test = src.pool(clipset, TEST) if "test" in self.params.fid_references else None
        classes = np.arange(train.n_classes)
        missing = sorted(set(classes.tolist()) - set(train.classes_present().tolist()))
        if missing:
            raise DataError(f"data set {clipset.name!r}: the training split has no clip of "
                            f"{', '.join(train.label_names[c] for c in missing)}")
        return OdmoContext(train, test, np.repeat(classes, per_class).astype(np.int64))

    def test_items(self, clipset) -> OdmoContext:
        return self.context(clipset, self.params.per_class)

    # -- generation ----------------------------------------------------------------------------
    def sample_joints(self, generator, labels, *, seed: int, pool, row_config=None) -> np.ndarray:
        """(N, window, J, 3) joint positions from ``generator`` for ``labels`` (module
        docstring: window-trained methods, or label-only items for ACTOR / A2M)."""
        import torch

        T = int(self.params.window)
        labels = np.asarray(labels, dtype=np.int64)
        if hasattr(generator, "sample_windows"):
            kw = {}
            if getattr(generator, "uses_code_bank", False):  # ODMO
                names = getattr(generator, "inference_fields", ())
                kw = {k: v for k, v in (row_config or {}).items() if k in names}
                kw["n_iter"] = self.params.bank_iters
            out = generator.sample_windows(torch.from_numpy(labels), T, seed=seed, pool=pool, **kw)
        else:
            from repro.motion.motion import Motion

            if pool.source.scale != 1.0:
                raise ConfigError("rotation-based methods need scale 1 windows")
            place = Motion.from_clipset(pool.clipset, pool.indices[:1], 0, 1)
            cond = label_condition_items(pool.label_names, labels, T, pool.skeleton, pool.fps,
                                         place)
            if hasattr(generator, "sample_joints"):
                out = generator.sample_joints(cond, seed=seed)
            else:
                out = generator.sample(cond, seed=seed).joints()
        out = out.detach().cpu().numpy() if isinstance(out, torch.Tensor) else np.asarray(out)
        who = getattr(generator, "method_id", type(generator).__name__)
        if out.shape[:2] != (labels.size, T) or out.shape[-1] != 3:
            raise DataError(f"generator {who!r}: samples of shape {tuple(out.shape)}, expected "
                            f"({labels.size}, {T}, J, 3)")
        return out[:, :T].astype(np.float32)

    # -- scoring -------------------------------------------------------------------------------
    @staticmethod
    def check_evaluator(evaluator, pool) -> None:
        if tuple(evaluator.label_names) != tuple(pool.label_names):
            raise DataError("the evaluator's classes differ from the data set's")
        if tuple(evaluator.joint_names) != tuple(pool.skeleton.names):
            raise DataError("the evaluator's joints differ from the data set's skeleton")

    def reference_stats(self, evaluator, ctx: OdmoContext, split: str):
        """Feature statistics of the fixed real set 0 of ``split`` (cached per process)."""
        from repro.metrics.fid import FeatureStats

        key = (evaluator.meta.get("store_key", id(evaluator)), self.key(), split)
        hit = _REFERENCE_CACHE.get(key)
        if hit is not None:
            return hit
        pool = ctx.train if split == "train" else ctx.test
        if pool is None:
            raise ConfigError(f"FID against {split!r} needs that split in fid_references")
        joints, _ = real_set(pool, self.params.per_class, self.params.reference_seed, split, 0)
        feats, _ = evaluator.encode(joints, None, seed=derive_seed(
            self.params.reference_seed, "odmo", "reference-features", split))
        stats = FeatureStats.of(feats)
        _REFERENCE_CACHE[key] = stats
        return stats

    def metric_block(self, joints, labels, evaluator, ctx: OdmoContext, *, seed: int) -> dict:
        """acc (%), fid / fid_train / fid_test, div, multimod of one set (module docstring)."""
        from repro.metrics.accuracy import accuracy
        from repro.metrics.diversity import diversity, multimodality
        from repro.metrics.fid import fid

        p = self.params
        self.check_evaluator(evaluator, ctx.train)
        y = np.asarray(labels, dtype=np.int64)
        feats, logits = evaluator.encode(joints, None, seed=derive_seed(seed, "odmo", "features"))
        out = {"acc": 100.0 * accuracy(logits, y, top_k=1).value,
               "div": diversity(feats, n_pairs=p.div_pairs, seed=derive_seed(seed, "odmo", "div")),
               "multimod": multimodality(feats, y, ctx.train.n_classes, per_class=p.multimod_pairs,
                                         seed=derive_seed(seed, "odmo", "multimod"))}
        for split in p.fid_references:
            v = fid(feats, self.reference_stats(evaluator, ctx, split), method=p.fid_method).value
            out[f"fid_{split}"] = v
            if split == p.fid_references[0]:
                out["fid"] = v
        return out

    # -- keeping samples -------------------------------------------------------------------------
    def save_generated(self, generated: OdmoSamples, path) -> Path:
        return save_samples(self.id, generated, path)

    def load_generated(self, path) -> OdmoSamples:
        return load_samples(self.id, path)


#: (evaluator store key, protocol key, split) -> FeatureStats of the fixed real set 0
_REFERENCE_CACHE: dict = {}
