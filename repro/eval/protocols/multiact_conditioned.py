"""``multiact_conditioned``: one generated action per test pair, scored on ``Ŝ_c`` (MultiAct
Tables 1, 2, A, B; paper §5 "Ablation study", "Comparison with state-of-the-art methods";
protocols.md §4.3-4.6).  Shared pieces: items, the scoring frame, the recogniser input and the
metric block in :mod:`repro.eval.protocols.multiact_common`; blinding and the ACTOR path in
:mod:`repro.eval.protocols.multiact_conditions`.

**Test items** (:meth:`MultiActConditioned.test_items`): ``prev_motion_source = "test"``
(the paper's "unseen previous motions", every table's setting): ``per_label`` test pairs per
``S_c`` label (labels with fewer pairs repeated, §4.1); ``"train"`` (the reference's "seen"
loader): the training pairs themselves; ``"actor"``: the test pairs with ``S_p`` replaced by
ACTOR's action for ``a_p`` (a row's method config may ask for it, e.g. ``prev_motion_source =
"actor"``; the test items stay the test pairs).

**A replicate** (:meth:`generate`): the same conditions every replicate, only the sampling seed
changes (§4.3).  A pair generator (MACVAE) gets the blinded pairs (``S_p``, ``a_c``, ``l_t``,
``l_c``) and returns ``[T̂, Ŝ_c]``; ACTOR gets ``a_c`` and ``l_c`` only.

**Columns** (:meth:`measure`) on ``Ŝ_c`` (labels ``a_c``), each scored face-front at the last
frame of its ``S_p``:

- ``fid_train``: against the real ``S_c`` of the training pairs (``train_per_label`` per label,
  the fixed 1,060 of the reference);
- ``fid_test``: against a fresh ``per_label``-per-label draw of test pairs (all valid test
  pairs, "All-GT" val), redrawn every replicate, seeded from the measure seed (§4.3);
- ``acc`` / ``acc_top5``: top-1 / top-5 with label merging (``label_merge``);
- ``div`` (200 pairs), ``multimod`` (20 per label / 20·C, early break).

**Real rows** (:meth:`real_replicate`, ``split`` from the row's overrides): per replicate two
independent draws: ``split = "test"`` (Real-test): a ``per_label`` draw of test pairs plays the
generated set, FID_train against the training pairs, FID_test against an independent test
draw; ``split = "train"`` (Real-train): a ``per_label`` draw of the training pairs (the whole
training set when ``per_label = train_per_label``, as in the reference) plays the generated
set, FID_train against the training pairs (so with ``per_label = train_per_label`` it is
recogniser noise only: 0 for a deterministic recogniser, §1.5), FID_test against a fresh test
draw.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Literal

from repro.data.clipset import TEST, TRAIN
from repro.data.pairs import PairItems
from repro.errors import ConfigError
from repro.eval.protocols import register
from repro.eval.protocols.multiact_common import (
    METRIC_BLOCK,
    MultiActParams,
    MultiActProtocol,
    MultiActSamples,
)
from repro.seeding import derive_seed


class MultiActConditionedParams(MultiActParams):
    """Parameters of :class:`MultiActConditioned` (all shared with the other MultiAct
    protocols, :class:`~repro.eval.protocols.multiact_common.MultiActParams`)."""


@register
class MultiActConditioned(MultiActProtocol):
    """MultiAct's single-step protocol (module docstring)."""

    id = "multiact_conditioned"
    Params = MultiActConditionedParams
    metrics = METRIC_BLOCK
    real_metrics = METRIC_BLOCK
    real_row_options = ("split",)
    version = 1

    params: MultiActConditionedParams

    # -- generation -------------------------------------------------------------------------
    def generate(self, generator, items: PairItems, *, seed: int, replicate: int,
                 need: Iterable[str] | None = None, models: Mapping | None = None,
                 row_config: Mapping | None = None) -> MultiActSamples:
        """Replicate ``replicate``: one ``[T̂, Ŝ_c]`` (ACTOR: ``Ŝ_c``) per item."""
        return self.generate_pairs(generator, items, seed=self.replicate_seed(seed, replicate),
                                   models=models, row_config=row_config)

    # -- scoring ----------------------------------------------------------------------------
    def train_reference(self, clipset, evaluator, *, seed: int):
        """FeatureStats of the training pairs' real ``S_c`` (FID_train's reference)."""
        from repro.metrics.fid import FeatureStats

        feats, _ = self.real_features(evaluator, self.train_items(clipset), "action",
                                      derive_seed(seed, self.id, "fid-train-reference"))
        return FeatureStats.of(feats)

    def test_reference(self, clipset, evaluator, *, seed: int, tag: str = "fid-test-reference"):
        """FeatureStats of a fresh ``per_label`` draw of test pairs (seeded by ``seed``)."""
        from repro.metrics.fid import FeatureStats

        ref = self.item_source().reference(clipset, TEST, self.params.per_label,
                                           derive_seed(seed, self.id, tag, "draw"))
        feats, _ = self.real_features(evaluator, ref, "action", derive_seed(seed, self.id, tag))
        return FeatureStats.of(feats)

    def measure(self, generated: MultiActSamples, items: PairItems, evaluator, *, seed: int,
                clipset=None) -> dict[str, float]:
        """One replicate's six columns (module docstring); ``seed`` (the replicate's) seeds the
        FID_test reference draw, the recogniser noise and the Div/Multimod pairs."""
        if clipset is None:
            raise ConfigError(f"protocol {self.id!r} measures with the data set")
        self.check_samples(generated, items.key(), len(items))
        self.check_evaluator(evaluator, items.label_names, items.skeleton)
        seg, l_c = generated.action()
        feats, logits = self.encode(evaluator, seg, l_c, generated.anchor,
                                    derive_seed(seed, self.id, "features"))
        return self.metric_block(
            feats, logits, generated.labels.numpy(), items.label_names,
            seed=derive_seed(seed, self.id, "pairs"),
            train_ref=self.train_reference(clipset, evaluator, seed=seed),
            test_ref=self.test_reference(clipset, evaluator, seed=seed))

    def real_replicate(self, clipset, items: PairItems, evaluator, *, seed: int, replicate: int,
                       split: Literal["train", "test"] = "test") -> dict[str, float]:
        """Real-train / Real-test, replicate ``replicate`` (module docstring)."""
        if split not in ("train", "test"):
            raise ConfigError(f"protocol {self.id!r}: a real row's split must be 'train' or "
                              f"'test', got {split!r}")
        self.check_evaluator(evaluator, items.label_names, items.skeleton)
        rs = derive_seed(seed, self.id, "real", int(replicate))
        src = self.item_source()
        real = src.reference(clipset, TRAIN if split == "train" else TEST, self.params.per_label,
                             derive_seed(rs, "real-set"))
        feats, logits = self.real_features(evaluator, real, "action", derive_seed(rs, "features"))
        return self.metric_block(
            feats, logits, real.labels.numpy(), real.label_names, seed=derive_seed(rs, "pairs"),
            train_ref=self.train_reference(clipset, evaluator, seed=rs),
            test_ref=self.test_reference(clipset, evaluator, seed=rs))


__all__ = ["MultiActConditioned", "MultiActConditionedParams"]
