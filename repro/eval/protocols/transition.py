"""``transition``: FID of generated transitions (MultiAct Table 3; paper "Comparison with
state-of-the-art methods (Transition)", supp. "Evaluation metrics"; protocols.md §4.7).
Shared pieces: :mod:`repro.eval.protocols.multiact_common`,
:mod:`repro.eval.protocols.multiact_conditions`.

**Items**: ``per_label`` test pairs per ``S_c`` label, as ``multiact_conditioned``'s unseen set.

**Rows** (where ``S_p`` comes from, :meth:`MultiActProtocol.prev_source`):

- MACVAE, ``prev_motion_source = "test"`` ("Ours (prev. motion from testset)"): the real test
  ``S_p``; the generator gets the blinded pair and returns ``[T̂, Ŝ_c]``;
- MACVAE, ``prev_motion_source = "actor"`` ("prev. motion from ACTOR"): ``S_p`` = ACTOR's action
  for ``a_p`` of length ``l_p`` (the extra model ``"actor"``), placed where the real ``S_p``
  starts in the world (:func:`~repro.eval.protocols.multiact_conditions.place_at`), then MACVAE's
  ``step``;
- ACTOR + SSMCT (``align`` in the method config) and ACTOR + interpolation: ``S_p`` = the
  composite's own ``actor_motion(a_p, l_p)`` placed the same way, then its ``step`` (ACTOR's
  ``Ŝ_c`` joined by the in-betweener; "w. o. align" leaves ``Ŝ_c`` at the origin facing +Z, so
  ``S_p`` may end anywhere, facing any way: the paper's "seeing the opposite direction").

Lengths ``l_t``, ``l_c`` are the test pair's (the generated transition is as long as the real
one, §4.7).  A label-only method (ACTOR alone) makes no transition and is refused.

**Columns** (:meth:`measure`), on ``T̂`` only, scored face-front at the last frame of the
``S_p`` used (every segment fed to the recogniser as ``eval_clip`` says):

- ``fid_train``: against the real transitions of the training pairs (the reference's
  "gt_seen" transitions, ``train_per_label`` per label);
- ``fid_test``: against the real transitions of the same test pairs (fixed across replicates).

The paper's Table 3 has no Real row; :meth:`real_replicate` still gives the level of real data
(a fresh ``per_label`` draw of test pairs' transitions against the same two references).
``segment`` is a label of the spec (the part of the pair the columns read) and must be
``"transition"``; it does not enter content keys.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import ClassVar, Literal

from pydantic import Field

from repro.data.clipset import TEST
from repro.data.pairs import PairItems
from repro.errors import ConfigError
from repro.eval.protocols import register
from repro.eval.protocols.multiact_common import (
    MultiActParams,
    MultiActProtocol,
    MultiActSamples,
)
from repro.seeding import derive_seed

METRICS = ("fid_train", "fid_test")


class TransitionParams(MultiActParams):
    """Parameters of :class:`Transition` (:class:`MultiActParams` plus ``segment``)."""

    UNKEYED: ClassVar[frozenset[str]] = frozenset({"replicates", "segment"})

    segment: Literal["transition"] = Field("transition", description="the part the columns "
                                           "read (a spec label; not keyed)")


@register
class Transition(MultiActProtocol):
    """MultiAct's transition protocol (module docstring)."""

    id = "transition"
    Params = TransitionParams
    metrics = METRICS
    real_metrics = METRICS
    version = 2                 # 2: a generated S_p is placed where the real S_p starts (issue 26)

    params: TransitionParams

    def generate(self, generator, items: PairItems, *, seed: int, replicate: int,
                 need: Iterable[str] | None = None, models: Mapping | None = None,
                 row_config: Mapping | None = None) -> MultiActSamples:
        """Replicate ``replicate``: one ``[T̂, Ŝ_c]`` per test pair (module docstring)."""
        return self.generate_pairs(generator, items, seed=self.replicate_seed(seed, replicate),
                                   models=models, row_config=row_config, need_transitions=True)

    def references(self, clipset, items: PairItems, evaluator, *, seed: int):
        """(train, test) FeatureStats of real transitions: the training pairs' and ``items``'."""
        from repro.metrics.fid import FeatureStats

        s = derive_seed(seed, self.id, "reference")
        tr, _ = self.real_features(evaluator, self.train_items(clipset), "transition",
                                   derive_seed(s, "train"))
        te, _ = self.real_features(evaluator, items, "transition", derive_seed(s, "test"))
        return FeatureStats.of(tr), FeatureStats.of(te)

    def measure(self, generated: MultiActSamples, items: PairItems, evaluator, *, seed: int,
                clipset=None) -> dict[str, float]:
        if clipset is None:
            raise ConfigError(f"protocol {self.id!r} measures with the data set")
        self.check_samples(generated, items.key(), len(items))
        self.check_evaluator(evaluator, items.label_names, items.skeleton)
        if not generated.transitions:
            raise ConfigError(f"protocol {self.id!r}: the samples hold no transitions")
        seg, l_t = generated.transition()
        feats, _ = self.encode(evaluator, seg, l_t, generated.anchor,
                               derive_seed(seed, self.id, "features"))
        train_ref, test_ref = self.references(clipset, items, evaluator, seed=seed)
        return {"fid_train": self.fid(feats, train_ref), "fid_test": self.fid(feats, test_ref)}

    def real_replicate(self, clipset, items: PairItems, evaluator, *, seed: int,
                       replicate: int) -> dict[str, float]:
        """Real transitions of a fresh ``per_label`` draw of test pairs, scored like
        generated ones (not in the paper's table)."""
        self.check_evaluator(evaluator, items.label_names, items.skeleton)
        rs = derive_seed(seed, self.id, "real", int(replicate))
        real = self.item_source().reference(clipset, TEST, self.params.per_label,
                                            derive_seed(rs, "real-set"))
        feats, _ = self.real_features(evaluator, real, "transition", derive_seed(rs, "features"))
        train_ref, test_ref = self.references(clipset, items, evaluator, seed=seed)
        return {"fid_train": self.fid(feats, train_ref), "fid_test": self.fid(feats, test_ref)}
