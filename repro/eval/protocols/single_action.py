"""``single_action``: Neural Marionette's single-action protocol (Tables 1, 2 and Table 4's
single-action column; paper §5.1.1-5.1.4).

Items (§5.1.1, supp. §3; :mod:`repro.data.contexts`): the data set gets Marionette's test split
(per class ``min(test_cap_per_class, round(test_fraction·n))`` clips, :func:`marionette_split`)
and is composed into multi-action sequences split by source clip (:mod:`repro.data.sequences`,
the ``bandai2-seq`` view); every action of a test sequence yields one item: the initial motion
(``initial_frames`` = 6 frames before the action in its sequence: the transition, i.e. the
previous clip's own continuation carried onto the action's first frame, never the action's own
clip), the tag, the duration, the next tag (the
label of the following action in the sequence) and the trajectory (ground-plane root path of
root actions, zeros for in-place ones), in the item's Marionette-normalised frame.
``context = "same_clip"`` restores the earlier construction (the clip's own first frames and a
next tag from its own end pose: a leak, kept as a named option).  At most
``samples_per_class`` items per class are scored (a seeded choice, the same for every method
and replicate; ``None`` = all).

A replicate (:meth:`SingleAction.generate`) is one sampling pass of the trained generator over
all those items, seeded by ``(seed, replicate)``.  Columns (:meth:`SingleAction.measure`), all on
the evaluator's (the transformer recogniser's) features and logits:

- ``fid``: FID of the generated actions' features against the real ones (``fid_reference``:
  the real actions of the scored test items by default), squared feature units;
- ``acc``: top-1 recognition accuracy against the conditioning tag, fraction;
- ``div``: A2M diversity, mean distance of ``div_pairs`` (K = 200) random pairs, feature units;
- ``multimod``: A2M multimodality, ``multimod_pairs`` (20) same-tag pairs per class, summed
  over pairs and divided by 20·C, feature units;
- ``traj_err`` (Δ_Traj): per-frame L2 between the input trajectory and the generated root in
  the item's normalised frame, on the ground plane (``traj_plane = "xz"``) over the valid
  frames of root actions (``traj_items``), metres;
- ``jpe`` (Δ_JPE, undefined in the paper): mean per-joint position error against the test
  clip's real action, centimetres, of the generation named by ``jpe_mode`` (default ``"mean"``:
  free-running generation with the latent set to its mean, which exposes the train-test
  discrepancy the paper attributes Δ_JPE to);
- harness columns, in no paper (``memorisation``; :mod:`repro.eval.memorisation`, given the
  data set): ``nn_train_feat`` / ``nn_train_joint`` (distance of each sample to its nearest
  training action, in feature and in joint space) and ``precision``, ``recall``, ``density``,
  ``coverage`` of the samples' features against the real test features (k = ``prdc_k``).

Each action is shown to the evaluator as ``eval_clip`` says (default: its centred window of
the evaluator's ``window`` frames, shorter actions padded by repeating their last frame), the
same for real and generated actions.  The "Real Test Data" row
(:meth:`SingleAction.real_replicate`) scores, per replicate, a seeded per-tag bootstrap
resample of the real test actions (``real_resample``): ``fid``, ``acc``, ``div``, ``multimod``
and the two nearest-training distances (the level of fresh data);
Δ_Traj and Δ_JPE are "/" (the paper prints "/" for Δ_Traj; both are zero on real data).

Every choice the paper leaves open is a field of :class:`SingleActionParams` (docs/protocols.md).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Literal

import numpy as np
from pydantic import Field

from repro.data.action_items import ActionItems, GeneratedItems
from repro.data.clipset import TEST
from repro.errors import ConfigError, DataError
from repro.eval.memorisation import HARNESS_METRICS
from repro.eval.protocols import register
from repro.eval.protocols.marionette_common import MarionetteParams, MarionetteProtocol
from repro.eval.protocols.marionette_common import read_samples, write_samples
from repro.eval.protocols.marionette_common import evaluation_clips  # noqa: F401 (re-exported)
from repro.seeding import derive_seed, numpy_rng

SAVE_FORMAT = 1
METRICS = ("fid", "acc", "div", "multimod", "traj_err", "jpe", *HARNESS_METRICS)
REAL_METRICS = ("fid", "acc", "div", "multimod", "nn_train_feat", "nn_train_joint")


class SingleActionParams(MarionetteParams):
    """Parameters of :class:`SingleAction` (units: frames, fps, metres).

    The first group is what Neural Marionette fixes (the specs' ``protocol_params``), the
    second what the scale profile sets, the third our choices where the paper is silent; the
    item-source and shared scoring fields come from :class:`MarionetteParams`.
    """

    # fixed by the paper (§5.1.1, supp. §3)
    trajectory: Literal["input", "none"] = Field(
        "input", description="root actions get the test clip's trajectory as input ('none': zeros)")
    # the scale profile (and replicates, from MarionetteParams)
    samples_per_class: int | None = Field(
        None, ge=1, description="scored test items per class at most (None: all)")
    # open choices (docs/protocols.md; eval_clip, fid_method, memorisation, prdc_k: the shared
    # MarionetteParams)
    selection_seed: int = Field(0, description="seed of the samples_per_class choice")
    fid_reference: Literal["test_items", "train_items"] = Field(
        "test_items", description="real features FID compares with")
    div_pairs: int = Field(200, ge=1, description="K of Div (§5.1.2; A2M's 200)")
    multimod_pairs: int = Field(20, ge=1, description="same-tag pairs per class (A2M's 20)")
    traj_plane: Literal["xz", "xyz"] = Field(
        "xz", description="Δ_Traj on the ground plane (supp. §1.4) or in 3-D")
    traj_items: Literal["root_actions", "all"] = Field(
        "root_actions", description="items Δ_Traj averages over (in-place ones have no trajectory)")
    jpe_mode: Literal["mean", "sampled", "teacher_forced"] = Field(
        "mean", description="the generation Δ_JPE compares with the real action")
    real_resample: Literal["bootstrap", "none"] = Field(
        "bootstrap", description="Real row replicate: a per-tag bootstrap resample of the real "
        "test actions, or those actions themselves (only the pair draws vary)")


@dataclass(frozen=True, eq=False)
class SingleActionSamples(GeneratedItems):
    """One replicate's generated actions (world frame) plus, when Δ_JPE needs another pass
    (``jpe_mode`` "mean" or "teacher_forced"), that pass in ``reference``."""

    reference: GeneratedItems | None = None
    jpe_mode: str = "sampled"


# ---------------------------------------------------------------------------------------------
# helpers


def _cap(x: torch.Tensor, T: int) -> torch.Tensor:
    return x[:, :T]


# ---------------------------------------------------------------------------------------------


@register
class SingleAction(MarionetteProtocol):
    """Neural Marionette's single-action protocol (module docstring)."""

    id = "single_action"
    Params = SingleActionParams
    metrics = METRICS
    real_metrics = REAL_METRICS
    evaluator_kind = "transformer"
    version = 3  # 2: items from composed sequences (repro.data.contexts); 3: harness columns
    measure_uses_clipset = True  # the harness columns read the training items

    params: SingleActionParams

    # -- data (item_source, split_clipset, train_items: MarionetteProtocol) ------------------
    def test_items(self, clipset) -> ActionItems:
        """The scored items: one per test action, at most ``samples_per_class`` per class."""
        p = self.params
        src = self.item_source()

        def build():
            items = src.items(clipset, TEST)
            present = set(np.unique(items.labels.numpy()).tolist())
            missing = [items.label_names[c] for c in range(items.n_classes) if c not in present]
            if missing:
                raise DataError(f"data set {clipset.name!r}: the single_action test split has "
                                f"no item of {', '.join(missing)} (multimodality needs every tag)")
            return self._select(items)

        return src.cached_build("single_action_test", clipset, build,
                                samples_per_class=p.samples_per_class,
                                selection_seed=p.selection_seed)

    def _select(self, items: ActionItems) -> ActionItems:
        cap = self.params.samples_per_class
        if cap is None:
            return items
        labels = items.labels.numpy()
        keep = []
        for c in np.unique(labels).tolist():
            pos = np.flatnonzero(labels == c)
            if pos.size > cap:
                rng = numpy_rng(self.params.selection_seed, "single_action", "select", c)
                pos = np.sort(rng.choice(pos, size=cap, replace=False))
            keep.append(pos)
        keep = np.sort(np.concatenate(keep))
        return items if keep.size == len(items) else items.subset(keep)

    def condition_items(self, items: ActionItems) -> ActionItems:
        """What a generator is conditioned on: ``items`` (``trajectory = "none"``: with the
        trajectory zeroed, i.e. "not specified" in the paper's sense)."""
        import torch

        if self.params.trajectory == "none":
            return dataclasses.replace(items, trajectory=torch.zeros_like(items.trajectory))
        return items

    # -- generation -------------------------------------------------------------------------
    def generate(self, generator, items: ActionItems, *, seed: int, replicate: int,
                 need: Iterable[str] | None = None) -> SingleActionSamples:
        """Replicate ``replicate``: one action per item from ``generator`` (world frame), seeded
        by :meth:`replicate_seed`.  When Δ_JPE is needed (``need`` is None or names ``"jpe"``)
        and ``jpe_mode`` is not ``"sampled"``, the Δ_JPE pass is added as ``reference``."""
        s = self.replicate_seed(seed, replicate)
        cond = self.condition_items(items)
        who = getattr(generator, "method_id", type(generator).__name__)
        out = generator.sample(cond, seed=s)
        self._check_generated(out, items, f"generator {who!r}")
        mode = self.params.jpe_mode
        ref = None
        if (need is None or "jpe" in set(need)) and mode != "sampled":
            if mode == "mean":
                ref = generator.sample(cond, seed=s, use_mean=True)
            else:
                tf = getattr(generator, "teacher_forced", None)
                if tf is None:
                    raise ConfigError(f"jpe_mode 'teacher_forced': method {who!r} has no "
                                      "teacher-forced pass; use jpe_mode 'mean' or 'sampled'")
                ref = tf(cond, seed=s, use_mean=True)
            self._check_generated(ref, items, f"generator {who!r} ({mode} pass)")
            ref = GeneratedItems(ref.motion, ref.lengths, ref.labels)
        return SingleActionSamples(out.motion, out.lengths, out.labels, reference=ref,
                                   jpe_mode=mode)

    @staticmethod
    def _check_generated(gen, items: ActionItems, who: str) -> None:
        import torch

        if not isinstance(gen, GeneratedItems):
            raise DataError(f"{who}: expected GeneratedItems, got {type(gen).__name__}")
        if len(gen) != len(items):
            raise DataError(f"{who}: {len(gen)} samples for {len(items)} test items")
        if not torch.equal(gen.labels.cpu().long(), items.labels.cpu().long()):
            raise DataError(f"{who}: sample tags differ from the test items' tags")
        if not torch.equal(gen.lengths.cpu().long(), items.lengths.cpu().long()):
            raise DataError(f"{who}: sample durations differ from the test items' durations")
        if gen.motion.skeleton != items.skeleton:
            raise DataError(f"{who}: samples use a different skeleton than the test items")
        if gen.motion.n_frames < int(items.lengths.max()):
            raise DataError(f"{who}: samples have {gen.motion.n_frames} frames, the longest "
                            f"item needs {int(items.lengths.max())}")

    # -- scoring ----------------------------------------------------------------------------
    @staticmethod
    def _check_evaluator(evaluator, items: ActionItems) -> None:
        if tuple(evaluator.joint_names) != tuple(items.skeleton.names):
            raise DataError("the evaluator's joints differ from the items' skeleton "
                            f"({len(evaluator.joint_names)} vs {items.skeleton.n_joints} joints)")
        if tuple(evaluator.label_names) != tuple(items.label_names):
            raise DataError("the evaluator's classes differ from the items' tags "
                            f"({', '.join(evaluator.label_names)} vs {', '.join(items.label_names)})")

    def _feature_metrics(self, feats, logits, labels, n_classes: int, seed: int,
                         reference) -> dict[str, float]:
        from repro.metrics.accuracy import accuracy
        from repro.metrics.diversity import diversity, multimodality
        from repro.metrics.fid import fid

        p = self.params
        y = np.asarray(labels, dtype=np.int64)
        return {
            "fid": fid(feats, reference, method=p.fid_method).value,
            "acc": accuracy(logits, y, top_k=1).value,
            "div": diversity(feats, n_pairs=p.div_pairs, seed=derive_seed(seed, "div")),
            "multimod": multimodality(feats, y, n_classes, per_class=p.multimod_pairs,
                                      seed=derive_seed(seed, "multimod")),
        }

    def fid_reference(self, clipset, items: ActionItems, evaluator, *, seed: int):
        """The real feature statistics FID compares with (a :class:`FeatureStats`):
        ``fid_reference = "test_items"``: the real actions of ``items``; ``"train_items"``:
        the real actions of :meth:`train_items` (needs ``clipset``).  Compute once and pass to
        :meth:`measure` as ``reference`` to save the pass."""
        from repro.metrics.fid import FeatureStats

        self._check_evaluator(evaluator, items)
        if self.params.fid_reference == "train_items":
            if clipset is None:
                raise ConfigError("fid_reference 'train_items' needs the data set: pass "
                                  "measure(..., reference=protocol.fid_reference(clipset, ...))")
            items = self.train_items(clipset)
        return FeatureStats.of(self._real_features(evaluator, items, seed))

    def _real_features(self, evaluator, items: ActionItems, seed: int) -> np.ndarray:
        """The evaluator's features of ``items``' real actions (FID's reference pass)."""
        feats, _ = self._encode(evaluator, items.real(), derive_seed(seed, "single_action",
                                                                      "fid-reference"))
        return feats

    def memorisation(self, motion: GeneratedItems, feats, evaluator, clipset, *, seed: int,
                     real_feats=None) -> dict[str, float]:
        """The harness columns of :mod:`repro.eval.memorisation` for ``motion`` (features
        ``feats``): nearest-training distances against the protocol's training items, and,
        with ``real_feats``, precision/recall/density/coverage."""
        from repro.eval.memorisation import harness_columns

        return harness_columns(self, motion, feats, evaluator, clipset, real_feats=real_feats,
                               bank_seed=derive_seed(seed, "single_action", "train-bank"))

    def measure(self, generated: GeneratedItems, items: ActionItems, evaluator, *, seed: int,
                reference=None, clipset=None) -> dict[str, float]:
        """One replicate's ``{metric_id: value}`` (module docstring): ``fid``, ``acc``, ``div``,
        ``multimod`` always; ``traj_err`` when some scored item is a root action (or
        ``traj_items = "all"``); ``jpe`` when its pass is present (``jpe_mode``); with
        ``clipset`` (and ``memorisation``) the harness columns (:meth:`memorisation`).

        ``seed`` drives the evaluator's noise (random-h0 GRUs only) and the Div/Multimod pair
        draws; ``reference``: precomputed :meth:`fid_reference` statistics."""
        from repro.metrics.fid import FeatureStats

        self._check_generated(generated, items, "samples")
        self._check_evaluator(evaluator, items)
        feats, logits = self._encode(evaluator, generated, derive_seed(seed, "single_action",
                                                                        "features"))
        harness = clipset is not None and self.params.memorisation
        real_feats = self._real_features(evaluator, items, seed) if harness else None
        if reference is None:
            reference = FeatureStats.of(real_feats) if (
                real_feats is not None and self.params.fid_reference == "test_items") else \
                self.fid_reference(clipset, items, evaluator, seed=seed)
        out = self._feature_metrics(feats, logits, items.labels.numpy(), items.n_classes,
                                    derive_seed(seed, "single_action", "pairs"), reference)
        if harness:
            out.update(self.memorisation(generated, feats, evaluator, clipset, seed=seed,
                                         real_feats=real_feats))
        traj = self.trajectory_error(generated, items)
        if traj is not None:
            out["traj_err"] = traj
        jpe = self.joint_position_error(generated, items)
        if jpe is not None:
            out["jpe"] = jpe
        return out

    def trajectory_error(self, generated: GeneratedItems, items: ActionItems) -> float | None:
        """Δ_Traj (metres): the generated root, brought into each item's normalised frame, vs
        the input trajectory (``traj_plane = "xz"``) or the real root (``"xyz"``), averaged
        over valid frames of the items ``traj_items`` selects; None when none is selected."""
        import torch

        from repro.metrics.trajectory import trajectory_error

        p = self.params
        sel = ~items.in_place if p.traj_items == "root_actions" else \
            torch.ones(len(items), dtype=torch.bool)
        if not bool(sel.any()):
            return None
        T = int(items.lengths.max())
        root = items.canon.apply_points(_cap(generated.root, T).to(items.canon.rotation.dtype))
        target = _cap(items.trajectory, T) if p.traj_plane == "xz" else _cap(items.action.root, T)
        mask = _cap(items.valid_mask(), T)
        return trajectory_error(root[sel], target[sel].to(root.dtype), plane=p.traj_plane,
                                mask=mask[sel])

    def joint_position_error(self, generated: GeneratedItems, items: ActionItems) -> float | None:
        """Δ_JPE (cm) of the ``jpe_mode`` pass against the items' real actions over valid
        frames (mean over joints, frames, items); None when that pass is absent."""
        from repro.metrics.trajectory import joint_position_error

        mode = self.params.jpe_mode
        basis = generated if mode == "sampled" else getattr(generated, "reference", None)
        if basis is None:
            return None
        if mode != "sampled" and getattr(generated, "jpe_mode", mode) != mode:
            raise DataError(f"samples carry a {generated.jpe_mode!r} Δ_JPE pass, the protocol "
                            f"asks for {mode!r}")
        T = int(items.lengths.max())
        pred = _cap(basis.joints(), T)
        gt = _cap(items.real().joints(), T)
        return joint_position_error(pred, gt.to(pred.dtype), scale=100.0,
                                    mask=_cap(items.valid_mask(), T))

    # -- the real row -----------------------------------------------------------------------
    def real_resample(self, items: ActionItems, *, seed: int, replicate: int) -> np.ndarray:
        """Positions of replicate ``replicate``'s real set, tags in index order: per tag, as
        many items as the tag has, drawn uniformly with replacement (``real_resample =
        "bootstrap"``, a stratified bootstrap), or every item once (``"none"``)."""
        labels = items.labels.numpy()
        if self.params.real_resample == "none":
            return np.argsort(labels, kind="stable")
        rng = numpy_rng(seed, "single_action", "real", int(replicate))
        draw = []
        for c in np.unique(labels).tolist():
            pos = np.flatnonzero(labels == c)
            draw.append(pos[rng.integers(0, pos.size, size=pos.size)])
        return np.concatenate(draw)

    def real_replicate(self, clipset, items: ActionItems, evaluator, *, seed: int,
                       replicate: int, reference=None) -> dict[str, float]:
        """The "Real Test Data" row, replicate ``replicate``: :meth:`real_resample` of the real
        test actions scored like generated ones (``fid``, ``acc``, ``div``, ``multimod``; FID
        against :meth:`fid_reference`).  Δ_Traj and Δ_JPE are not produced ("/")."""
        self._check_evaluator(evaluator, items)
        rs = derive_seed(seed, "single_action", "real", int(replicate))
        sub = items.subset(self.real_resample(items, seed=seed, replicate=replicate))
        feats, logits = self._encode(evaluator, sub.real(), derive_seed(rs, "features"))
        if reference is None:
            reference = self.fid_reference(clipset, items, evaluator, seed=seed)
        out = self._feature_metrics(feats, logits, sub.labels.numpy(), items.n_classes,
                                    derive_seed(rs, "pairs"), reference)
        if clipset is not None and self.params.memorisation:  # the level of fresh real data
            mem = self.memorisation(sub.real(), feats, evaluator, clipset, seed=rs)
            out.update({k: mem[k] for k in ("nn_train_feat", "nn_train_joint")})
        return out

    # -- keeping samples --------------------------------------------------------------------
    def save_generated(self, generated: GeneratedItems, path: str | Path) -> Path:
        """Write ``generated`` (and its Δ_JPE pass as ``ref_*``) to the npz file ``path``,
        atomically (:func:`repro.eval.protocols.marionette_common.write_samples`; ``meta``
        adds ``jpe_mode`` and ``has_reference``)."""
        ref = getattr(generated, "reference", None)
        return write_samples(path, self.id, SAVE_FORMAT, generated,
                             meta={"jpe_mode": getattr(generated, "jpe_mode", "sampled"),
                                   "has_reference": ref is not None},
                             sets={"ref_": ref} if ref is not None else None)

    def load_generated(self, path: str | Path) -> SingleActionSamples:
        """Read a file written by :meth:`save_generated` (DataError naming it when it is not one)."""
        f = read_samples(path, self.id, SAVE_FORMAT)
        main = f.motion_set()
        ref = f.motion_set("ref_") if f.meta.get("has_reference") else None
        return SingleActionSamples(main.motion, main.lengths, main.labels, reference=ref,
                                   jpe_mode=str(f.meta.get("jpe_mode", "sampled")))
