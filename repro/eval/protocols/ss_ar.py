"""``ss_ar``: NEURAL MARIONETTE's pipeline with Shadow Start and Action Revision (Table 5,
Fig. 10; paper §4.3.2, Alg. 1, §5.2.6).

The multi-action protocol (:mod:`repro.eval.protocols.multi_action`: the overall test set,
the chained generation, the columns) with one difference in generation: a generator that
offers the schemes (:class:`repro.models.neural_marionette.NeuralMarionette`) gets

- the **Shadow Start** bank: the BOP embeddings of the training items
  (``set_shadow_bank(train_items)``, Eq. 6's candidate set);
- the **Action Revision** classifier ``F_c``: ``classify(actions) -> correct``.

**Which network F_c is** (NEURAL MARIONETTE has no released code, so its text decides; two
readings, both run as Table 5 / Fig. 10 rows):

- ``"evaluator"`` (the default): the recognition network ``N`` that scores Acc.  §1 calls the
  pipeline "recognition-guaranteed", §5.2.6 says "with the help of a recognition network" (the
  name §5.1.2 gives ``N``) and "an action may fail only when both normal generation and
  re-generation using a projected BOP do not work" — true only when the network that triggers
  the revision is the one that scores: then Acc = a + (1 − a)·r (a: plain accuracy, r: the
  revisions' accuracy) by construction.
- ``"independent"``: a classifier of its own, ``revision_classifier_kind`` (an Action2Motion
  GRU, another architecture than the scorer) trained with ``revision_classifier_seed`` (1) on
  the same training split and heading mode, so that a revision is not scored correct because
  the scorer accepted it.

A row chooses with the method's inference field ``revision_classifier`` (unset: this
protocol's ``revision_classifier``); an independent ``F_c`` is asked of the engine's evaluator
factory with the band's (kind, seed), so every row of a band that reads it shares one
classifier, trained once.  A plain generator (the MARIONET row) runs the pure generative
pipeline.  The fraction of actions Action Revision regenerated is kept with the samples
(``revised``) and reported as the ``revised`` value of each replicate.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field

from repro.errors import ConfigError
from repro.eval.protocols import register
from repro.eval.protocols.multi_action import MultiAction, MultiActionParams
from repro.seeding import derive_seed


#: the footer line of every ss_ar table: the reading switches (the spec notes say the same)
FOOTER_NOTE = (
    "Readings (NEURAL MARIONETTE has no code; docs/multi_action.md): its unmarked rows revise "
    "with F_c = the scoring network (revision_classifier = \"evaluator\", §5.2.6) and take "
    "Shadow Start's literal unit-norm L2 step (ss_norm = \"unit\"); rows marked '(F_c: "
    "independent classifier)' revise with an Action2Motion GRU trained with seed 1 on the same "
    "split (revision_classifier = \"independent\"); rows marked '(SS step: embedding norm)' "
    "rescale f0* to the mean norm of the N retrieved training BOP embeddings "
    "(ss_norm = \"neighbours\"). Every row samples the same trained MarioNet. Under the "
    "default F_c an action is kept whenever either pass satisfies the scorer (Acc = a + "
    "(1 − a)·r; a: the first pass's accuracy, r: the revisions'), so NEURAL MARIONETTE's lead "
    "over MARIONET in Acc and QR is partly built in; "
    "the '(F_c: independent classifier)' rows are the check that is not.")


class SsArParams(MultiActionParams):
    pipeline: Literal["pure_generative", "neural_marionette"] = "neural_marionette"
    revision_classifier: Literal["independent", "evaluator"] = Field(
        "evaluator", description="F_c of Action Revision when the row does not choose: the "
        "scoring evaluator itself (§5.2.6) or a classifier of its own "
        "(revision_classifier_kind, _seed)")
    revision_classifier_kind: Literal["a2m_gru", "transformer", "uestc_gru"] = Field(
        "a2m_gru", description="architecture of an independent F_c (another than the scorer's)")
    revision_classifier_seed: int = Field(1, description="training seed of an independent F_c")


@register
class SsAr(MultiAction):
    """Table 5 / Fig. 10 (module docstring)."""

    id = "ss_ar"
    Params = SsArParams
    version = 2  # 2: F_c chosen per row (the method's revision_classifier); default evaluator
    footer_note = FOOTER_NOTE

    params: SsArParams

    def replicate_seed(self, seed: int, replicate: int) -> int:
        """Table 3's seeds: the MARIONET row here is the pure pipeline's sample, bitwise."""
        return derive_seed(seed, "protocol", MultiAction.id, "replicate", int(replicate))

    def fc_reading(self, generator) -> str:
        """Which ``F_c`` revises ``generator``'s actions: its config's ``revision_classifier``
        when set (a table row's reading), else this protocol's."""
        cfg = getattr(generator, "config", None)
        own = getattr(cfg, "revision_classifier", None)
        return own if own is not None else self.params.revision_classifier

    def fc_request(self, reading: str) -> tuple[str, int] | None:
        """The ``(kind, seed)`` the evaluator factory is asked for under ``reading`` (None: the
        scoring evaluator itself); the same for every row of the band."""
        if reading == "evaluator":
            return None
        return self.params.revision_classifier_kind, int(self.params.revision_classifier_seed)

    def revision_classifier(self, evaluator, evaluator_factory=None, reading: str | None = None):
        """``F_c`` under ``reading`` (default: the protocol's): a classifier of
        ``revision_classifier_kind`` trained with ``revision_classifier_seed`` on the same
        training split and heading mode (``evaluator_factory(kind, seed)``, given by the
        engine), or the evaluator itself."""
        request = self.fc_request(reading or self.params.revision_classifier)
        if request is None:
            return evaluator
        if evaluator_factory is None:
            raise ConfigError("revision_classifier 'independent' needs the engine's evaluator "
                              "factory")
        return evaluator_factory(*request)

    def _sampler(self, generator, clipset, evaluator, evaluator_factory=None):
        import torch

        if not hasattr(generator, "set_shadow_bank"):
            return _pure(generator)  # the pure generative pipeline for a plain generator
        if self.params.pipeline != "neural_marionette":
            raise ConfigError(f"protocol {self.id!r}: pipeline must be 'neural_marionette'")
        generator.set_shadow_bank(self.train_items(clipset))
        fc = None
        if getattr(generator, "needs_classifier", False):  # only AR rows build (or train) F_c
            fc = self.revision_classifier(evaluator, evaluator_factory,
                                          self.fc_reading(generator))

        def classify(actions):
            _, logits = self._encode(fc, actions, derive_seed(0, MultiAction.id, "revision"))
            return torch.from_numpy(np.asarray(logits).argmax(1) == actions.labels.numpy())

        def fn(cond, seed):
            out = generator.sample(cond, seed=seed, classify=classify if fc is not None else None)
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
    import torch

    def fn(cond, seed):
        return generator.sample(cond, seed=seed), torch.zeros(len(cond), dtype=torch.bool)

    return fn
