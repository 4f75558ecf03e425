"""MultiAct's BABEL label set and its confusion-tolerant label merging, as data.

MultiAct scores generated motions with 53 BABEL labels (the labels with more than twenty
training pairs, in the classifier's output order) and counts a prediction as correct when the
ground-truth label is a key of a "confusion" table and the prediction is one of that key's
accepted labels; otherwise only an exact match counts (protocols.md §4.5, MultiAct
``get_correct_pred_conf``; top-5 uses the same rule on any of the five predictions).

The table is reproduced as the reference code has it, asymmetries included:

- ``'pickup'`` is a key and an accepted value but not one of the 53 labels (the real label is
  ``'pick up'``, which is neither a key nor accepted anywhere);
- ground truth ``'sit'``, ``'turn'``, ``'stand in place'``, ``'pick up'``, ``'take'``, ``'tpose'``
  etc. need an exact match (they are not keys);
- ``'turn right'`` accepts ``'turn'``, ``'turn around'``, ``'turn back'`` but not ``'turn left'``,
  while the turn-left family does not accept ``'turn right'``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

#: The 53 BABEL labels of MultiAct's recogniser, in output-index order.
MULTIACT_LABELS: tuple[str, ...] = (
    "place", "turn", "walk", "take", "stand with arms down", "stand", "turn left", "bend down",
    "tpose", "step forward", "step backward", "sit down", "walk forward", "step backwards",
    "turn around", "look down", "stand still", "walk backwards", "stand in place", "turn right",
    "apose", "stand up", "pick up object", "walk back", "stumble", "put down object", "bend over",
    "sit", "knock", "step back", "turn back", "step up", "step down", "squat", "jump", "run",
    "walk backward", "kick", "pick up", "turn around to the left", "crouch", "jog",
    "pick something up with right hand", "set down", "throw", "catch", "place object",
    "catch the ball", "catch ball", "stop", "turn around left", "throw the ball",
    "right foot forward",
)

_TURN_LEFT = ("turn", "turn left", "turn around left", "turn around to the left", "turn around",
              "turn back")
_WALK_BACK = ("walk", "walk back", "walk backward", "walk backwards")
_CATCH = ("catch", "catch ball", "catch the ball")
_PICK = ("pickup", "pick up object", "pick something up with right hand")
_STAND = ("stand", "stand still", "stand with arms down", "stop", "look down")
_PLACE = ("place", "put down object", "set down")
_STEP_BACK = ("step back", "step backward", "step backwards")
_STEP_FWD = ("step forward", "right foot forward")


def _group(keys, accepted) -> dict[str, tuple[str, ...]]:
    return {k: tuple(accepted) for k in keys}


_ACCEPTS: dict[str, tuple[str, ...]] = {
    **_group(("turn around to the left", "turn around left", "turn left", "turn around",
              "turn back"), _TURN_LEFT),
    "turn right": ("turn", "turn around", "turn back", "turn right"),
    "walk": ("walk", "walk back", "walk backward", "walk backwards", "walk forward"),
    "walk forward": ("walk", "walk forward"),
    **_group(("walk back", "walk backward", "walk backwards"), _WALK_BACK),
    **_group(("throw", "throw the ball"), ("throw", "throw the ball")),
    **_group(_CATCH, _CATCH),
    **_group(("pick something up with right hand", "pickup", "pick up object"), _PICK),
    **_group(_STAND, _STAND),
    "sit down": ("sit", "sit down"),
    **_group(("bend down", "bend over"), ("bend down", "bend over")),
    **_group(_PLACE, _PLACE),
    **_group(("jog", "run"), ("jog", "run")),
    **_group(("right foot forward", "step forward"), _STEP_FWD),
    **_group(_STEP_BACK, _STEP_BACK),
}


@dataclass(frozen=True)
class LabelMerge:
    """A ground-truth-label -> accepted-predictions table over a named label list.

    ``accepts`` is keyed by label *name*; :meth:`index_map` turns it into class indices for
    :func:`repro.metrics.accuracy.accuracy`, silently skipping names that are not labels
    (MultiAct's dead ``'pickup'`` entry), exactly as the reference code's name lookup does.
    A ground-truth label that is not a key needs an exact match.
    """

    labels: tuple[str, ...]
    accepts: Mapping[str, tuple[str, ...]] = field(repr=False)

    def index_map(self, labels: tuple[str, ...] | None = None) -> dict[int, frozenset[int]]:
        names = self.labels if labels is None else tuple(labels)
        index = {name: i for i, name in enumerate(names)}
        out: dict[int, frozenset[int]] = {}
        for key, accepted in self.accepts.items():
            if key in index:
                out[index[key]] = frozenset(index[a] for a in accepted if a in index)
        return out


#: MultiAct's merge table (protocols.md §4.5) over :data:`MULTIACT_LABELS`.
MULTIACT_LABEL_MERGE = LabelMerge(labels=MULTIACT_LABELS, accepts=MappingProxyType(_ACCEPTS))
