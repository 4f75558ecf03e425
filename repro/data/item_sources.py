"""The one family of item sources: how a protocol's items and their context are made (data layer).

Every method in a table is trained and tested on *items* made from a prepared data set (DESIGN.md
"Datasets": an item's context comes from its sequence, never from the clip being generated or
scored).  Three papers make them three ways, each a specialisation of :class:`ItemSource`:

- :class:`repro.data.contexts.ActionSource`: Neural Marionette's single-/multi-action items, an
  action with its previous motion ``P^ini``, next tag and trajectory (Neural Marionette §3,
  Fig. 2; §4.2; supp. §3), as :class:`repro.data.action_items.ActionItems`;
- :class:`repro.data.pairs_build.PairSource`: MultiAct's ``[S_p, T, S_c]`` samples (MultiAct
  supp. "Training data for MACVAE"; protocols.md §4.1), as
  :class:`repro.data.pairs.PairItems`;
- :class:`repro.data.odmo_items.WindowSource`: ODMO's pools of fixed-length windows (ODMO §3.1,
  §4.1; protocols.md §3.1), as :class:`repro.data.odmo_items.WindowItems`.

What they share lives here, once:

- a source is a frozen pydantic model whose every field can change the items (``extra =
  "forbid"``); :meth:`ItemSource.make` validates fields with one ConfigError line naming where
  they came from;
- :meth:`ItemSource.describe` is the content description that keys every training on those
  items (:func:`repro.engine.steps.training_items`; the engine's ``items`` entry): the fields,
  as each specialisation resolves them (:meth:`ItemSource.describe_fields`), plus the family's
  construction version under its own name (:attr:`ItemSource.VERSION_FIELD`);
  :meth:`ItemSource.from_description` reads it back (refusing another version);
- :meth:`ItemSource.split_clipset` (the split the evaluator also trains on, so no scored test
  clip was seen by the recogniser; :meth:`ItemSource.split_view`: what a plan reads of it,
  without its frames), :meth:`ItemSource.train_items` and
  :meth:`ItemSource.training_items` (the items a method of a given ``item_kind`` trains on);
- :meth:`ItemSource.cached_build`: one in-process LRU (:func:`cached`), keyed by the source's
  description, the data set's fingerprint and what is built;
- :class:`ItemSet`: what every family's item container answers (classes, skeleton, fps).

:func:`source_from_description` (in :mod:`repro.data.item_families`, which imports every
family) picks the specialisation a description names.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict

from repro.errors import ConfigError, DataError
from repro.keys import content_key

__all__ = ["ItemSource", "ItemSet", "SplitView", "cached", "clear_cache"]

# Items are immutable in use and cost seconds to build: keep the last few per process.
_CACHE: "OrderedDict[str, object]" = OrderedDict()
_CACHE_SIZE = 24


def cached(key: str, build):
    """``build()`` through a small in-process LRU (24 entries) keyed by the content key
    ``key``: every family's items, pair tables and resampled sequences, and the test sets the
    protocols build from them.  Deterministic builds only (a hit returns the same object)."""
    hit = _CACHE.get(key)
    if hit is not None:
        _CACHE.move_to_end(key)
        return hit
    out = build()
    _CACHE[key] = out
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return out


def clear_cache() -> None:
    """Forget every build :func:`cached` holds (tests: the next build is made afresh)."""
    _CACHE.clear()


@dataclass(frozen=True)
class SplitView:
    """The clip set an evaluator trains on as a plan reads it (its key, the split check), without
    its frames: :meth:`ItemSource.split_view`."""

    fingerprint: str
    labels: Any  # (n_clips,) int
    split: Any   # (n_clips,) int8: TRAIN / TEST
    label_names: tuple[str, ...]

    @property
    def n_classes(self) -> int:
        return len(self.label_names)


class ItemSource(BaseModel):
    """How a protocol's items are made from a data set (module docstring).  Every field enters
    :meth:`describe` and so the content keys of the models trained on the items."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    #: the key :meth:`describe` records the construction version under
    VERSION_FIELD: ClassVar[str] = "version"
    #: bumped by a specialisation when its items are built differently
    VERSION: ClassVar[int] = 1
    #: a description without the version field is of the current version (descriptions
    #: written before the field existed); False: it is refused like another version
    VERSION_MAY_BE_ABSENT: ClassVar[bool] = True
    #: the ``item_kind`` of the methods that train on :meth:`train_items` as they are
    ITEM_KIND: ClassVar[str] = "actions"

    # -- description ------------------------------------------------------------------------
    def describe_fields(self) -> dict:
        """The fields as they enter :meth:`describe` (a specialisation resolves defaults here,
        e.g. a composition's overrides into the full composition)."""
        return self.model_dump(mode="json")

    def describe(self) -> dict:
        """What keys a training on these items: :meth:`describe_fields` plus the version."""
        return {**self.describe_fields(), self.VERSION_FIELD: self.VERSION}

    def key(self) -> str:
        return content_key(self.describe())

    @classmethod
    def make(cls, where: str, **fields) -> "ItemSource":
        """``cls(**fields)``; a bad value is a ConfigError naming ``where`` and the field."""
        from repro.config_errors import resolve_config

        return resolve_config(cls, fields, f"{where}:", unnamed="parameters", quote=False)

    @classmethod
    def from_description(cls, d: dict) -> "ItemSource":
        """The source :meth:`describe` wrote (a training job's config); a description of
        another construction version is a DataError."""
        d = dict(d)
        version = d.pop(cls.VERSION_FIELD, cls.VERSION if cls.VERSION_MAY_BE_ABSENT else None)
        if version != cls.VERSION:
            raise DataError(f"{cls.__name__}: items were described by {cls.VERSION_FIELD} "
                            f"{version!r}, this code builds {cls.VERSION_FIELD} {cls.VERSION}")
        return cls.make("items", **d)

    # -- building ---------------------------------------------------------------------------
    def cached_build(self, what: str, clipset, build, **more):
        """``build()`` through :func:`cached`, keyed by this source's description, the data
        set's fingerprint, ``what`` and ``more`` (JSON values)."""
        key = content_key({"what": what, "source": self.describe(),
                           "data": str(clipset.fingerprint), **more})
        return cached(key, build)

    def split_clipset(self, clipset):
        """``clipset`` with the split (and frame rate) the items use; the evaluator trains on
        this one too, so that no scored test clip was seen by the recogniser."""
        raise NotImplementedError

    def split_view(self, clipset):
        """What a plan reads of :meth:`split_clipset` (``fingerprint``, ``labels``, ``split``,
        ``label_names``, ``n_classes``): here the clip set itself; a source whose split clip set
        costs work to build (MultiAct's resampling) answers a :class:`SplitView` instead."""
        return self.split_clipset(clipset)

    def train_items(self, clipset):
        """The items of the training split (never a test clip)."""
        raise NotImplementedError

    def training_items(self, clipset, item_kind: str = "actions"):
        """What a method of ``item_kind`` (the generator class's) trains on:
        :meth:`train_items` when it is this family's :attr:`ITEM_KIND`, those items as single
        actions (``as_action_items()``) for an ``"actions"`` method (ACTOR, Action2Motion on
        MultiAct's pairs or ODMO's windows); any other pairing is a ConfigError."""
        items = self.train_items(clipset)
        if item_kind == self.ITEM_KIND:
            return items
        if item_kind == "actions":
            return items.as_action_items()
        raise ConfigError(f"a method that trains on {item_kind} cannot train on the "
                          f"{self.ITEM_KIND} of {type(self).__name__}")


class ItemSet:
    """What every family's item container answers (mixed into the frozen dataclasses
    :class:`~repro.data.action_items.ActionItems`, :class:`~repro.data.pairs.PairItems`,
    :class:`~repro.data.odmo_items.WindowItems`): ``label_names`` is theirs; the skeleton and
    the frame rate are those of :meth:`frames_basis` (a Motion or the ClipSet they cut)."""

    label_names: tuple[str, ...]

    def frames_basis(self):
        """The Motion (or ClipSet) whose skeleton and fps the items have."""
        raise NotImplementedError

    @property
    def skeleton(self):
        return self.frames_basis().skeleton

    @property
    def fps(self) -> float:
        return float(self.frames_basis().fps)

    @property
    def n_classes(self) -> int:
        return len(self.label_names)
