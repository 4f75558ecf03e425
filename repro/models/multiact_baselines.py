"""MultiAct's composite baselines (Table 3, Fig. 6; protocols.md §4.7-4.8): "ACTOR + SSMCT
(w. align)", "ACTOR + SSMCT (w. o. align)" and "ACTOR + Interpolation".

MultiAct (Sec. "Comparison with state-of-the-art methods") joins "individually generated action
motion from ACTOR" with SSMCT in-betweening, or with linear interpolation; no code for these
rows was released (protocols.md §8), so what follows is our reading, each choice named.

Both classes train nothing: they are built from trained components
(:meth:`from_components`; the engine trains ``components`` as those methods' own rows) and
:meth:`fit` refuses.  One step, given a world-frame previous motion ``S_p``, the label ``a_c``
and the lengths ``l_t``, ``l_c`` (:meth:`step`, :meth:`sample` on PairItems):

1. ``Ŝ_c = actor_action(a_c, l_c, after=S_p)``: ACTOR's action (:class:`repro.models.actor.ACTOR`,
   which never reads the previous motion).
   - ``align=True`` ("w. align": "manually aligning ACTOR's action motions before performing
     in-betweening"): the action is placed at the last valid frame of ``S_p``, its position and
     heading, through the same inverse normalisation ACTOR uses for any item
     (:func:`repro.data.action_items.condition_items` on the last ``n_init`` = 6 frames of ``S_p``,
     Marionette normalisation: forward heading axis, full 3-D translation).  ACTOR's canonical
     frame is the frame of the pose just before the action, so the action starts where ``S_p``
     ended, facing its way.
   - ``align=False`` ("w. o. align", our reading): ACTOR's canonical output left in its own
     frame, i.e. placed as if the previous pose stood at the **world origin facing +Z**,
     whatever ``S_p`` is.  MultiAct's point is that ACTOR's motions "start anywhere", e.g.
     "seeing the opposite direction"; the origin/+Z placement is the deterministic version of
     that (``S_p``'s own heading and position play no part).
2. ``T̂``: ``l_t`` frames strictly between ``S_p``'s last valid frame and ``Ŝ_c``'s first:
   - ACTOR + SSMCT: :meth:`repro.models.ssmct.SSMCT.inbetween` (context: ``S_p``'s last frames;
     keyframes: ``Ŝ_c``'s first frames);
   - ACTOR + Interpolation: frame ``k = 1..l_t`` at weight ``k / (l_t + 1)``: slerp of every
     local joint rotation (the root's global one included) and linear root translation
     (:func:`repro.models.ssmct.interpolate_frames`).  The paper does not say whether ACTOR's
     action is aligned first; ``align=True`` by default (our choice: interpolating across an
     unaligned jump would measure the jump, not the interpolation).
3. ``[T̂, Ŝ_c]`` as :class:`~repro.data.pairs.GeneratedPairs` in the world frame, continuing
   ``S_p``.

Seeds: the ACTOR noise of a step is drawn from ``derive_seed(seed, "multiact_baselines",
"action")``, the same for both composites, so ACTOR + SSMCT and ACTOR + Interpolation in-between
to the very same action for one seed; :meth:`actor_action` and :meth:`actor_motion` called
directly pass ``seed`` to ACTOR unchanged.  :meth:`actor_motion` (origin-placed ACTOR motion) is
what protocols use to make a previous motion ``S_p`` from ``a_p`` (Table 3's baselines in-between
two ACTOR actions; Fig. 6 step 1).

:meth:`sample` reads only ``S_p``, ``a_c``, ``l_t`` and ``l_c`` of its PairItems, never ``T`` or
``S_c``.  Saving writes each component beside the composite's ``config.json``;
:meth:`load` on the composite's class restores them (``Generator.load`` alone gives a composite
without components, which refuses to sample).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path

import torch
from torch import nn

from repro.data.action_items import ItemsConfig, condition_items, pad_last
from repro.data.pairs import GeneratedPairs, PairItems, last_frames
from repro.errors import ConfigError, DataError, MissingDataError
from repro.keys import canonical_json
from repro.models.base import (
    CONFIG_FILE,
    SAVE_FORMAT,
    WEIGHTS_FILE,
    Generator,
    register,
)
from repro.models.baseline_io import unpack_poses
from repro.models.multiact_baselines_config import (  # noqa: F401 (AlignConfig re-exported)
    ACTOR_SSMCT, INTERPOLATION, AlignConfig)
from repro.models.ssmct import interpolate_frames, join_pairs
from repro.motion.motion import Motion
from repro.motion.rotations import matrix_to_6d, sixd_to_matrix
from repro.seeding import derive_seed

#: frames of ``after`` handed to :func:`condition_items` to place an aligned ACTOR action
N_INIT = ItemsConfig().n_init


class _Composite(Generator):
    """What both composites share: components, ACTOR placement, one step, save/load."""

    item_kind = "pairs"
    uses = frozenset({"label", "length", "initial_motion"})

    def __init__(self, config, skeleton, n_classes: int, fps: float):
        super().__init__(config, skeleton, n_classes, fps)
        self.models: dict[str, Generator] = {}

    # -- construction --------------------------------------------------------------------------
    @classmethod
    def from_components(cls, models: Mapping[str, Generator], config=None) -> _Composite:
        """The composite over trained ``models`` (one per name of ``components``, each of the
        named method), with ``config`` (``align``)."""
        missing = sorted(set(cls.components) - set(models))
        if missing:
            raise ConfigError(f"{cls.method_id}: missing component(s) {', '.join(missing)}")
        for name, method in cls.components.items():
            m = models[name]
            if not isinstance(m, Generator) or m.method_id != method:
                got = getattr(m, "method_id", type(m).__name__)
                raise ConfigError(f"{cls.method_id}: component {name!r} must be a {method!r} "
                                  f"generator, got {got!r}")
        actor = models["actor"]
        for name in cls.components:
            m = models[name]
            if m.skeleton != actor.skeleton or abs(m.fps - actor.fps) > 1e-6:
                raise DataError(f"{cls.method_id}: component {name!r} was trained on another "
                                "skeleton or frame rate than ACTOR")
        gen = cls(config, actor.skeleton, actor.n_classes, actor.fps)
        gen.models = {name: models[name] for name in cls.components}
        return gen

    def _model(self, name: str) -> Generator:
        try:
            return self.models[name]
        except KeyError:
            raise ConfigError(f"{self.method_id}: component {name!r} is not attached (build with "
                              f"{type(self).__name__}.from_components or "
                              f"{type(self).__name__}.load)") from None

    @property
    def network(self) -> nn.ModuleDict:
        return nn.ModuleDict({name: m.network for name, m in self.models.items()})

    def fit(self, train_items, *, seed: int, ckpt_dir=None, on_epoch=None, val_items=None):
        raise ConfigError(f"{self.method_id} trains nothing itself: its components "
                          f"({', '.join(f'{k} = {v}' for k, v in self.components.items())}) are "
                          "trained separately, as their own methods; build it with "
                          f"{type(self).__name__}.from_components")

    # -- ACTOR placement -----------------------------------------------------------------------
    def _label_names(self) -> tuple[str, ...]:
        return tuple(f"class{i}" for i in range(self.n_classes))

    def actor_action(self, labels, l_c, *, seed: int, after: Motion | None = None,
                     after_lengths=None, use_mean: bool = False) -> Motion:
        """ACTOR's action (N, max l_c) for ``labels`` in the world frame, padded by repeating
        each item's last frame.  With ``after`` (N, ·) world frame, ``after_lengths`` valid
        frames each, and ``align=True``: placed at ``after``'s last valid pose (position and
        heading); otherwise in ACTOR's own frame (previous pose at the origin facing +Z)."""
        actor = self._model("actor")
        labels = torch.as_tensor(labels, dtype=torch.long).reshape(-1)
        N = labels.numel()
        l_c = torch.as_tensor(l_c, dtype=torch.long).reshape(N)
        if after is not None and self.config.align:
            if after.batch_size != N:
                raise ValueError("after and labels differ in batch size")
            lens = (torch.full((N,), after.n_frames, dtype=torch.long) if after_lengths is None
                    else torch.as_tensor(after_lengths, dtype=torch.long).reshape(N))
            init = last_frames(after, lens, N_INIT).to(dtype=torch.float32)
            cond = condition_items(init, labels, labels, l_c, self._label_names())
            return actor.sample(cond, seed=seed, use_mean=use_mean).motion
        return self.actor_motion(labels, l_c, seed=seed, use_mean=use_mean)

    def actor_motion(self, labels, lengths, *, seed: int, use_mean: bool = False) -> Motion:
        """An origin-placed ACTOR motion (N, max lengths) for ``labels`` (previous pose at the
        origin facing +Z, whatever ``align``): the ``S_p`` of Table 3's baselines and Fig. 6's
        first step."""
        actor = self._model("actor")
        labels = torch.as_tensor(labels, dtype=torch.long).reshape(-1)
        N, J = labels.numel(), self.skeleton.n_joints
        lengths = torch.as_tensor(lengths, dtype=torch.long).reshape(N)
        # ACTOR reads only labels and lengths: the condition's initial pose (any pose) is never
        # used, since its canonical output is taken as it is, unplaced
        rest = Motion(torch.zeros(N, 1, 3), matrix_to_6d(torch.eye(3).expand(N, 1, J, 3, 3)),
                      self.skeleton, self.fps)
        cond = condition_items(rest, labels, labels, lengths, self._label_names())
        poses = actor.generate_poses(cond, seed=seed, use_mean=use_mean)
        rot6d, root = unpack_poses(poses.float(), J)
        rot6d, root = pad_last(rot6d, lengths), pad_last(root, lengths)
        return Motion(root, matrix_to_6d(sixd_to_matrix(rot6d)), self.skeleton, self.fps)

    # -- one step ------------------------------------------------------------------------------
    def _transition(self, prev: Motion, prev_lengths: torch.Tensor, action: Motion,
                    l_t: torch.Tensor) -> Motion:
        raise NotImplementedError

    def step(self, prev: Motion, prev_lengths, labels, l_t, l_c, *, seed: int,
             use_mean: bool = False) -> GeneratedPairs:
        """``[T̂, Ŝ_c]`` continuing the world-frame ``prev`` (N, ·) with ``prev_lengths`` valid
        frames, for labels ``a_c`` and lengths ``l_t``, ``l_c`` (module docstring)."""
        if prev.skeleton != self.skeleton:
            raise DataError(f"{self.method_id}: the previous motion uses another skeleton")
        N = prev.batch_size
        prev_lengths = torch.as_tensor(prev_lengths, dtype=torch.long).reshape(N)
        l_t = torch.as_tensor(l_t, dtype=torch.long).reshape(N)
        l_c = torch.as_tensor(l_c, dtype=torch.long).reshape(N)
        if N and (int(l_t.min()) < 0 or int(l_c.min()) < 1 or int(prev_lengths.min()) < 1):
            raise ValueError("need l_t >= 0, l_c >= 1 and prev_lengths >= 1")
        action = self.actor_action(labels, l_c, seed=derive_seed(seed, "multiact_baselines",
                                                                  "action"),
                                   after=prev, after_lengths=prev_lengths, use_mean=use_mean)
        T = self._transition(prev, prev_lengths, action, l_t)
        return join_pairs(T.to(dtype=action.dtype), l_t, action, l_c)

    def sample(self, cond_items: PairItems, *, seed: int, use_mean: bool = False) -> GeneratedPairs:
        """:meth:`step` on each pair's ``S_p``, ``a_c``, ``l_t``, ``l_c`` (never its ``T`` or
        ``S_c``)."""
        if not isinstance(cond_items, PairItems):
            raise TypeError(f"{self.method_id} samples from repro.data.pairs.PairItems, got "
                            f"{type(cond_items).__name__}")
        prev, l_p = cond_items.prev()
        return self.step(prev, l_p, cond_items.labels, cond_items.l_t, cond_items.l_c,
                         seed=seed, use_mean=use_mean)

    # -- save / load ---------------------------------------------------------------------------
    def save(self, directory: str | Path) -> Path:
        """``config.json`` (an empty ``weights.pt``: nothing of its own) and each component
        saved in a sub-folder named after it."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        for name, m in self.models.items():
            m.save(d / name)
        tmp = d / f".{WEIGHTS_FILE}.{os.getpid()}.tmp"
        with open(tmp, "wb") as fh:  # a handle: same bytes in every process
            torch.save({}, fh)
        os.replace(tmp, d / WEIGHTS_FILE)
        meta = {"format": SAVE_FORMAT, "method_id": self.method_id,
                "config": self.config.model_dump(mode="json"), "skeleton": self.skeleton.to_dict(),
                "n_classes": self.n_classes, "fps": self.fps,
                "components": sorted(self.models)}
        tmp = d / f".{CONFIG_FILE}.{os.getpid()}.tmp"
        tmp.write_bytes(canonical_json(meta))
        os.replace(tmp, d / CONFIG_FILE)
        return d

    @classmethod
    def load(cls, directory: str | Path) -> Generator:
        """The composite saved in ``directory`` with its components (on ``Generator`` itself:
        the bare composite, see the module docstring)."""
        gen = Generator.load.__func__(cls, directory)
        d = Path(directory)
        if isinstance(gen, _Composite):
            try:
                names = json.loads((d / CONFIG_FILE).read_text()).get("components", [])
            except ValueError:
                names = []
            if names:
                for name in names:
                    if not (d / name / CONFIG_FILE).is_file():
                        raise MissingDataError(f"component {name!r} is missing", d / name)
                gen.models = {name: Generator.load(d / name) for name in names}
        return gen


@register
class ActorSSMCT(_Composite):
    """ACTOR + SSMCT (w. align / w. o. align): ACTOR's action, SSMCT's transition."""

    card = ACTOR_SSMCT

    def _transition(self, prev, prev_lengths, action, l_t) -> Motion:
        return self._model("ssmct").inbetween(prev, prev_lengths, action, l_t)


@register
class Interpolation(_Composite):
    """ACTOR + Interpolation: ACTOR's action, slerp/linear transition."""

    card = INTERPOLATION

    def _transition(self, prev, prev_lengths, action, l_t) -> Motion:
        a = last_frames(prev, prev_lengths, 1).to(dtype=action.dtype)
        return interpolate_frames(a, action.slice_time(0, 1), l_t)
