"""The conditions of MultiAct's protocols: what a generator is given and where a previous
motion comes from (``multiact_conditioned``, ``transition``, ``long_term``; MultiAct AAAI'23 §5
and supplement; protocols.md §4).  The protocol base, the scoring frame and the metric block
are :mod:`repro.eval.protocols.multiact_common`.

**Blinding** (no leak by construction).  A generator may be conditioned on ``S_p``, the labels
and the lengths ``l_t``, ``l_c`` only.  :func:`blind` makes the copy every generator gets: the
frames of ``T`` and ``S_c`` are replaced by ``S_p``'s last frame (and ``segment_index`` /
``clip_index`` dropped), so no method can read a target, whatever it does.

**ACTOR in these protocols** (a label-only :class:`~repro.data.action_items.ActionItems` generator):
its ``S_c`` comes from ``blind(items).as_action_items()`` (labels ``a_c``, lengths ``l_c``,
placed at the end of ``S_p``).  A generated previous motion (``prev_motion_source = "actor"``)
is ACTOR's action for ``a_p`` of length ``l_p``: a composite method's own ``actor_motion``
(ACTOR + SSMCT, ACTOR + interpolation always take their previous motion from their ACTOR), else
the extra model ``"actor"``
(:meth:`repro.eval.protocols.multiact_common.MultiActProtocol.extra_models`), **placed where
the real ``S_p`` starts** (:func:`place_at` its first frame: root position and heading; its
poses are not read; our reading: the paper does not say where ACTOR's previous motion
sits, and the alternative is origin placement, ACTOR's own frame, as before issue 26).  So a
generated ``S_p`` keeps the real one's placement in its sequence's world frame, whose origin
facing +Z is ``S_c``'s canonical frame (where "w. o. align" leaves ACTOR's ``Ŝ_c``): as in a
recording, the previous motion may end anywhere, facing any way (MultiAct, "Comparison with
state-of-the-art methods (Transition)": "seeing the opposite direction"; docs/multiact.md).

Units: metres, frames at the pairs' frame rate.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from repro.data.pairs import GeneratedPairs, PairItems, gather_frames, last_frames
from repro.errors import ConfigError, DataError
from repro.motion.motion import Motion

#: method ids of MultiAct's composite baselines (ACTOR + SSMCT, ACTOR + interpolation), used
#: when their classes are not importable (they are recognised by ``components`` otherwise)
COMPOSITES = frozenset({"actor_ssmct", "interpolation"})


def blind(items: PairItems) -> PairItems:
    """``items`` as a generator may see them: ``S_p``, labels and lengths kept; every frame of
    ``T`` and ``S_c`` replaced by ``S_p``'s last frame; ``segment_index`` and ``clip_index``
    dropped (module docstring)."""
    import torch

    motion = gather_frames(items.motion, torch.zeros_like(items.l_p), items.l_p,
                           items.motion.n_frames)
    return PairItems(motion, items.l_p.clone(), items.l_t.clone(), items.l_c.clone(),
                     items.prev_labels.clone(), items.labels.clone(), items.label_names,
                     None, items.source)


def with_prev(items: PairItems, prev: Motion) -> PairItems:
    """Blinded ``items`` whose ``S_p`` is ``prev`` (N, ≥ max l_p; ``l_p`` valid frames each),
    e.g. a generated previous motion."""
    import torch

    width = max(items.motion.n_frames, int((items.l_p + items.l_t + items.l_c).max()))
    motion = gather_frames(prev.to(dtype=items.motion.dtype), torch.zeros_like(items.l_p),
                           items.l_p, width)
    return PairItems(motion, items.l_p.clone(), items.l_t.clone(), items.l_c.clone(),
                     items.prev_labels.clone(), items.labels.clone(), items.label_names,
                     None, items.source)


def anchor_frames(motion: Motion, lengths: torch.Tensor) -> Motion:
    """(N, 1): the last valid frame of each row (``lengths`` valid frames)."""
    import torch

    return last_frames(motion, torch.as_tensor(lengths, dtype=torch.long), 1)


def first_frames(motion: Motion) -> Motion:
    return motion.slice_time(0, 1)


def at_origin(frame: Motion) -> Motion:
    """``frame`` (N, 1) face-front canonicalised at itself: root at the origin, heading 0."""
    from repro.motion.canon import face_front

    return face_front(frame, anchor=0)[0]


def is_pair_generator(generator) -> bool:
    return getattr(generator, "item_kind", None) == "pairs"


def is_composite(generator) -> bool:
    return callable(getattr(generator, "actor_motion", None))


def method_is_composite(method_id: str) -> bool:
    """Whether ``method_id`` is a composite (ACTOR + X) method: its card has ``components``
    (read without the method's network, so a plan imports no torch)."""
    try:
        from repro.models.base import method_card

        return bool(method_card(method_id).components)
    except Exception:  # noqa: BLE001 - not registered yet: fall back to the known ids
        return method_id in COMPOSITES


def actor_action_items(actor, labels, lengths, anchor: Motion, label_names, *, n_init: int):
    """ActionItems for a label-only generator: ``labels``, ``lengths``; placed at ``anchor``
    (N, 1) (its pose repeated ``n_init`` times as the initial motion; placement only)."""
    import torch

    from repro.data.action_items import condition_items

    N = anchor.batch_size
    init = anchor.replace(root=anchor.root.expand(N, n_init, 3).clone(),
                          rot6d=anchor.rot6d.expand(N, n_init, *anchor.rot6d.shape[2:]).clone())
    labels = torch.as_tensor(labels, dtype=torch.long).reshape(N)
    return condition_items(init, labels, labels, torch.as_tensor(lengths, dtype=torch.long),
                           label_names)


def actor_sample(actor, cond, *, seed: int):
    """ACTOR's actions for ``cond`` (ActionItems): (Motion world (N, max len), lengths)."""
    out = actor.sample(cond, seed=seed)
    m = getattr(out, "motion", out)
    if m.batch_size != len(cond):
        raise DataError(f"{generator_name(actor)} returned {m.batch_size} motions for "
                        f"{len(cond)} items")
    if m.n_frames < int(cond.lengths.max()):
        raise DataError(f"{generator_name(actor)} returned motions shorter than asked")
    return m, cond.lengths.clone()


def place_at(motion: Motion, frame: Motion) -> Motion:
    """``motion`` (N, T), given in ACTOR's own frame (the previous pose at the origin facing
    +Z), placed at ``frame`` (N, 1): the exact inverse of the normalisation
    :func:`repro.data.action_items.condition_items` applies to an initial pose (Marionette
    normalisation with :class:`~repro.data.action_items.ItemsConfig`'s heading axis and
    translation), so the result is what ACTOR returns when conditioned on ``frame``.
    :func:`actor_motion` places a generated ``S_p`` at the real ``S_p``'s first frame (our
    reading; see there)."""
    from repro.data.action_items import ItemsConfig
    from repro.motion.canon import marionette_normalize, uncanonicalize

    cfg = ItemsConfig()
    _, params = marionette_normalize(frame.to(dtype=motion.dtype), anchor=0,
                                     heading_axis=cfg.heading_axis, translation=cfg.translation)
    return uncanonicalize(motion, params)


def actor_motion(generator, models: Mapping[str, Any] | None, labels, lengths, template: Motion,
                 label_names, *, seed: int, n_init: int) -> Motion:
    """A generated previous motion: ACTOR's action for ``labels`` / ``lengths`` placed at
    ``template`` (N, 1), the real ``S_p``'s first frame (module docstring; only its root
    position and heading are used: ACTOR never reads poses).  This placement is our reading:
    MultiAct ("Comparison with state-of-the-art methods", Tab. 3) does not say where ACTOR's
    previous motion sits; the alternative, origin placement (ACTOR's own frame, the origin
    facing +Z, as before issue 26), would leave "w.o. align" only ``S_p``'s own travel."""
    import torch

    labels = torch.as_tensor(labels, dtype=torch.long)
    lengths = torch.as_tensor(lengths, dtype=torch.long)
    if is_composite(generator):
        # the composite's ACTOR motion is in ACTOR's own frame (origin, +Z)
        m = place_at(generator.actor_motion(labels, lengths, seed=seed), template)
    else:
        actor = (models or {}).get("actor")
        if actor is None and not is_pair_generator(generator):
            actor = generator
        if actor is None:
            raise ConfigError(f"{generator_name(generator)}: a previous motion from ACTOR needs "
                              "the extra model 'actor' (protocol.extra_models)")
        cond = actor_action_items(actor, labels, lengths, template, label_names,
                                  n_init=n_init)
        m, _ = actor_sample(actor, cond, seed=seed)
    if m.batch_size != len(labels) or m.n_frames < int(lengths.max()):
        raise DataError(f"{generator_name(generator)}: ACTOR motions do not fit the asked lengths")
    return m


def generator_name(generator) -> str:
    """How messages name ``generator``: its method id, else its class name (quoted)."""
    return repr(getattr(generator, "method_id", type(generator).__name__))


def check_generated_pairs(out, l_t, l_c, n: int, who: str) -> GeneratedPairs:
    import torch

    if not isinstance(out, GeneratedPairs):
        raise DataError(f"{who}: expected GeneratedPairs, got {type(out).__name__}")
    if len(out) != n:
        raise DataError(f"{who}: {len(out)} samples for {n} conditions")
    if not (torch.equal(out.l_t.long(), torch.as_tensor(l_t).long())
            and torch.equal(out.l_c.long(), torch.as_tensor(l_c).long())):
        raise DataError(f"{who}: generated lengths differ from the asked l_t, l_c")
    return out


__all__ = [
    "COMPOSITES",
    "actor_action_items",
    "actor_motion",
    "actor_sample",
    "anchor_frames",
    "at_origin",
    "blind",
    "check_generated_pairs",
    "first_frames",
    "generator_name",
    "is_composite",
    "is_pair_generator",
    "method_is_composite",
    "place_at",
    "with_prev",
]
