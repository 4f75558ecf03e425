"""The configuration of MultiAct's composite baselines (Table 3, Fig. 6; protocols.md §4.7-4.8),
torch-free so that a table's plan reads it without importing the network (issue 31); the method
and the sources of its defaults: :mod:`repro.models.multiact_baselines`."""

from __future__ import annotations

from repro.models.base import GeneratorConfig, MethodCard, register_card


class AlignConfig(GeneratorConfig):
    """``align``: place ACTOR's action at the previous motion's last pose
    (:mod:`repro.models.multiact_baselines`)."""

    align: bool = True


#: ACTOR + SSMCT (w. align / w. o. align): ACTOR's action, SSMCT's transition
ACTOR_SSMCT = register_card(MethodCard("actor_ssmct", AlignConfig, inference_fields=("align",),
                                       components={"actor": "actor", "ssmct": "ssmct"}))
#: ACTOR + Interpolation: ACTOR's action, slerp/linear transition
INTERPOLATION = register_card(MethodCard("interpolation", AlignConfig, inference_fields=("align",),
                                         components={"actor": "actor"}))
