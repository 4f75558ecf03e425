"""NEURAL MARIONETTE's configuration (Wang et al., Sec. 4.3.2), torch-free so that a table's plan
reads it without importing the network (issue 31); the method and the sources of its defaults:
:mod:`repro.models.neural_marionette`."""

from __future__ import annotations

from typing import Literal

from pydantic import model_validator

from repro.models.base import MethodCard, register_card
from repro.models.marionet_config import MarioNetConfig


class NeuralMarionetteConfig(MarioNetConfig):
    """Every MarioNet field (the network and its training) plus the inference-only schemes."""

    shadow_start: Literal["never", "always", "on_revision"] = "on_revision"
    action_revision: bool = True
    ss_l2_normalize: bool = True       # NEURAL MARIONETTE* (Table 5) = False
    ss_neighbours: int = 16            # N of Eq. 6; the paper leaves it open (a method setting)
    # L2 step: radius 1 (the literal reading), the mean norm of the N retrieved training
    # embeddings F̃ ("neighbours": the embedding-norm reading) or ‖f0‖ ("match")
    ss_norm: Literal["unit", "neighbours", "match"] = "unit"
    # F_c of Action Revision (§4.3.2): the scoring network or an independent classifier, built
    # by the ss_ar protocol (None: the protocol's ``revision_classifier``); AR rows only
    revision_classifier: Literal["evaluator", "independent"] | None = None

    @model_validator(mode="after")
    def _check_schemes(self):
        if self.action_revision and self.shadow_start != "on_revision":
            raise ValueError(f"action_revision=True needs shadow_start='on_revision' (got "
                             f"shadow_start={self.shadow_start!r}); use action_revision=False "
                             "for 'never' or 'always'")
        if self.shadow_start == "on_revision" and not self.action_revision:
            raise ValueError("shadow_start='on_revision' needs action_revision=True (Shadow "
                             "Start is only triggered by a revision)")
        if self.ss_neighbours < 1:
            raise ValueError(f"ss_neighbours must be >= 1, got {self.ss_neighbours}")
        if self.revision_classifier is not None and not self.action_revision:
            raise ValueError(f"revision_classifier={self.revision_classifier!r} needs "
                             "action_revision=True (F_c only decides revisions)")
        return self


#: The fields of :class:`NeuralMarionetteConfig` that only change sampling; the rest is the
#: MarioNet training config (:meth:`NeuralMarionette.training_config`).
INFERENCE_FIELDS: frozenset[str] = frozenset(NeuralMarionetteConfig.model_fields) - frozenset(
    MarioNetConfig.model_fields)
assert INFERENCE_FIELDS == {"shadow_start", "action_revision", "ss_l2_normalize",
                            "ss_neighbours", "ss_norm", "revision_classifier"}


NEURAL_MARIONETTE = register_card(MethodCard("neural_marionette", NeuralMarionetteConfig,
                                             trains_as="marionet",
                                             inference_fields=INFERENCE_FIELDS))
