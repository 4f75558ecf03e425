"""``ss_ar``: NEURAL MARIONETTE's pipeline with Shadow Start and Action Revision (Table 5,
Fig. 10; paper §4.3.2, Alg. 1, §5.2.6).

The multi-action protocol (:mod:`repro.eval.protocols.multi_action`: the overall test set,
the chained generation, the columns) with one difference in generation: a generator that
offers the schemes (:class:`repro.models.neural_marionette.NeuralMarionette`) gets

- the **Shadow Start** bank: the BOP embeddings of the training items
  (``set_shadow_bank(train_items)``, Eq. 6's candidate set);
- the **Action Revision** classifier ``F_c``: ``classify(actions) -> correct``.  The paper
  names "an action classifier F_c" without saying whether it is the recognition network that
  scores Acc.  If it were, every action AR keeps would be scored correct by construction
  (Acc = a + (1 − a)·r), so the default is an independent classifier: another architecture
  (``revision_classifier_kind = "a2m_gru"``) trained with another seed on the same training
  split; ``revision_classifier = "evaluator"`` is the optimistic reading, kept as an option.

A plain generator (the MARIONET row) runs the pure generative pipeline.  The fraction of
actions Action Revision regenerated is kept with the samples (``revised``) and reported as the
``revised`` value of each replicate.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import torch
from pydantic import Field

from repro.errors import ConfigError
from repro.eval.protocols import register
from repro.eval.protocols.multi_action import MultiAction, MultiActionParams
from repro.seeding import derive_seed


class SsArParams(MultiActionParams):
    pipeline: Literal["pure_generative", "neural_marionette"] = "neural_marionette"
    revision_classifier: Literal["independent", "evaluator"] = Field(
        "independent", description="F_c of Action Revision: a classifier of its own "
        "(revision_classifier_kind, _seed) or the scoring evaluator itself")
    revision_classifier_kind: Literal["a2m_gru", "transformer", "uestc_gru"] = Field(
        "a2m_gru", description="architecture of an independent F_c (another than the scorer's)")
    revision_classifier_seed: int = Field(1, description="training seed of an independent F_c")


@register
class SsAr(MultiAction):
    """Table 5 / Fig. 10 (module docstring)."""

    id = "ss_ar"
    Params = SsArParams
    version = 1

    params: SsArParams

    def replicate_seed(self, seed: int, replicate: int) -> int:
        """Table 3's seeds: the MARIONET row here is the pure pipeline's sample, bitwise."""
        return derive_seed(seed, "protocol", MultiAction.id, "replicate", int(replicate))

    def revision_classifier(self, evaluator, evaluator_factory=None):
        """``F_c``: a classifier of ``revision_classifier_kind`` trained with
        ``revision_classifier_seed`` on the same training split and heading mode
        (``evaluator_factory(kind, seed)``, given by the engine), or the evaluator itself."""
        if self.params.revision_classifier == "evaluator":
            return evaluator
        if evaluator_factory is None:
            raise ConfigError("revision_classifier 'independent' needs the engine's evaluator "
                              "factory")
        return evaluator_factory(self.params.revision_classifier_kind,
                                 self.params.revision_classifier_seed)

    def _sampler(self, generator, clipset, evaluator, evaluator_factory=None):
        if not hasattr(generator, "set_shadow_bank"):
            return _pure(generator)  # the pure generative pipeline for a plain generator
        if self.params.pipeline != "neural_marionette":
            raise ConfigError(f"protocol {self.id!r}: pipeline must be 'neural_marionette'")
        generator.set_shadow_bank(self.train_items(clipset))
        fc = self.revision_classifier(evaluator, evaluator_factory)

        def classify(actions):
            _, logits = self._encode(fc, actions, derive_seed(0, MultiAction.id, "revision"))
            return torch.from_numpy(np.asarray(logits).argmax(1) == actions.labels.numpy())

        def fn(cond, seed):
            out = generator.sample(cond, seed=seed,
                                   classify=classify if getattr(generator, "needs_classifier",
                                                                False) else None)
            rev = getattr(out, "revised", None)
            if rev is None:
                rev = torch.zeros(len(cond), dtype=torch.bool)
            return out, rev

        return fn

    def measure(self, generated, items, evaluator, *, seed: int, clipset=None,
                reference=None) -> dict[str, float]:
        out = super().measure(generated, items, evaluator, seed=seed, clipset=clipset,
                              reference=reference)
        if generated.revised is not None:
            S, L = generated.n_sequences, generated.n_actions
            f = self.params.score_from_action - 1
            out["revised"] = float(generated.revised.reshape(S, L)[:, f:].float().mean())
        return out


def _pure(generator):
    def fn(cond, seed):
        return generator.sample(cond, seed=seed), torch.zeros(len(cond), dtype=torch.bool)

    return fn
