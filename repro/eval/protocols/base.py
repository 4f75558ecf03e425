"""The interface every evaluation protocol implements: :class:`Protocol`.

A protocol turns a trained generator and a data set into the measured columns of a table
(DESIGN.md "Data flow": ``Sample(protocol, seed) -> Evaluate``).  It fixes

- which items a method is trained on (:meth:`Protocol.train_items`) and conditioned on at
  test time (:meth:`Protocol.test_items`);
- how one replicate of generated samples is drawn (:meth:`Protocol.generate`): a replicate is
  an independent sampling pass of the same trained model over all test items, seeded by
  :meth:`Protocol.replicate_seed` ``(seed, replicate)``;
- how one replicate is scored (:meth:`Protocol.measure`) and what the "Real" row of the table
  is (:meth:`Protocol.real_replicate`);
- how samples are kept (:meth:`Protocol.save_generated` / :meth:`Protocol.load_generated`, npz,
  so ``repro rescore`` can re-measure without regenerating).

Each protocol has a ``Params`` model (pydantic, ``extra="forbid"``, frozen): the table spec's
``protocol_params`` overlaid by the scale profile's ``[<scale>.protocols.<id>]`` table.  Every
choice a paper leaves open is a field with a default, recorded by :meth:`ProtocolParams.describe`
and so part of every content key downstream.

Every table protocol trains on items of the data layer (:mod:`repro.data.item_sources`): its
``Params`` derive from :class:`ItemParams`, which names the item source and which of its fields
say how the items are made (Neural Marionette §5.1.1, supp. §3; MultiAct §4.1; ODMO §3.1), and
the protocol from :class:`ItemProtocol`, whose :meth:`~ItemProtocol.item_source`,
:meth:`~ItemProtocol.split_clipset` and :meth:`~ItemProtocol.train_items` are that source's.
Two protocols with equal item fields train on the same items, so they share trained models.
"""

from __future__ import annotations

import abc
from pathlib import Path
from typing import Any, ClassVar, Mapping

from pydantic import BaseModel, ConfigDict, Field

from repro.config_errors import resolve_config
from repro.keys import content_key
from repro.seeding import derive_seed


class ProtocolParams(BaseModel):
    """Base of every protocol's ``Params``: unknown keys are errors; values are immutable."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    #: fields that do not change any one replicate's result (the engine's replicate count),
    #: left out of :meth:`describe` so that changing them keeps cached samples valid
    UNKEYED: ClassVar[frozenset[str]] = frozenset({"replicates"})

    def describe(self) -> dict:
        """Every field except :attr:`UNKEYED`, defaults resolved, as plain JSON (what enters
        content keys)."""
        return self.model_dump(mode="json", exclude=set(self.UNKEYED))

    @classmethod
    def resolve(cls, params: "ProtocolParams | Mapping[str, Any] | None", *, where: str):
        """``params`` validated over the defaults; a ConfigError names the first bad field."""
        return resolve_config(cls, params, f"{where}: parameter")


class ItemParams(ProtocolParams):
    """Base of the ``Params`` of a protocol whose items come from an item source (module
    docstring): :attr:`ITEM_FIELDS` maps the fields that say how the items are made onto the
    fields of :attr:`ITEM_SOURCE`; :attr:`MORE_ITEM_FIELDS` names a dict field passed through
    to the source (its other fields, validated there)."""

    #: the :class:`repro.data.item_sources.ItemSource` class these fields describe
    ITEM_SOURCE: ClassVar[type]
    #: {field of these params: field of the item source}
    ITEM_FIELDS: ClassVar[Mapping[str, str]] = {}
    #: a dict field holding further item-source fields, or None
    MORE_ITEM_FIELDS: ClassVar[str | None] = None

    def item_fields(self) -> dict:
        """The item source's fields: :attr:`MORE_ITEM_FIELDS`' entries, then the mapped ones
        (which win)."""
        more = dict(getattr(self, self.MORE_ITEM_FIELDS)) if self.MORE_ITEM_FIELDS else {}
        return {**more, **{src: getattr(self, name) for name, src in self.ITEM_FIELDS.items()}}

    def item_source(self, where: str):
        """The item source these fields describe (a ConfigError naming ``where`` and the field
        when one is not valid)."""
        return self.ITEM_SOURCE.make(where, **self.item_fields())


class SequenceItemParams(ItemParams):
    """:class:`ItemParams` of the families whose items are cut from composed multi-action
    sequences (Neural Marionette's actions, MultiAct's pairs; :mod:`repro.data.sequences`)."""

    compose: dict = Field(default_factory=dict,
                          description="repro.data.sequences.ComposeConfig overrides")


class Protocol(abc.ABC):
    """One evaluation protocol with validated parameters (module docstring)."""

    #: the protocol id used by table specs (``repro.specs.names.PROTOCOLS``)
    id: ClassVar[str]
    #: the pydantic model of the parameters
    Params: ClassVar[type[ProtocolParams]]
    #: metric ids (``repro.specs.names.METRICS``) :meth:`measure` can produce
    metrics: ClassVar[tuple[str, ...]]
    #: metric ids :meth:`real_replicate` produces (the rest are "/" in the Real row)
    real_metrics: ClassVar[tuple[str, ...]]
    #: the evaluator kind (:func:`repro.eval.get_evaluator`) the protocol scores with
    evaluator_kind: ClassVar[str]
    #: bumped when the protocol's procedure changes (enters :meth:`describe`)
    version: ClassVar[int] = 1

    def __init__(self, params: ProtocolParams | Mapping[str, Any] | None = None):
        self.params = self.Params.resolve(params, where=f"protocol {self.id!r}")

    def describe(self) -> dict:
        """What defines this protocol's results (enters content keys)."""
        return {"protocol": self.id, "version": self.version, "params": self.params.describe(),
                "evaluator_kind": self.evaluator_kind}

    def key(self) -> str:
        return content_key(self.describe())

    def replicate_seed(self, seed: int, replicate: int) -> int:
        """The sampling seed of replicate ``replicate`` of a run seeded ``seed``."""
        return derive_seed(seed, "protocol", self.id, "replicate", int(replicate))

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.params!r})"

    # -- what a protocol provides ----------------------------------------------------------
    @abc.abstractmethod
    def train_items(self, clipset):
        """The items a generator is trained on."""

    @abc.abstractmethod
    def test_items(self, clipset):
        """The items generation is conditioned on and scored against."""

    @abc.abstractmethod
    def generate(self, generator, items, *, seed: int, replicate: int):
        """One replicate of generated samples (a GeneratedItems) for ``items``."""

    @abc.abstractmethod
    def measure(self, generated, items, evaluator, *, seed: int) -> dict[str, float]:
        """One replicate's metric values ``{metric_id: value}``."""

    @abc.abstractmethod
    def real_replicate(self, clipset, items, evaluator, *, seed: int,
                       replicate: int) -> dict[str, float]:
        """One replicate of the "Real" row ``{metric_id: value}``."""

    @abc.abstractmethod
    def save_generated(self, generated, path: str | Path) -> Path:
        """Write generated samples to an npz file (atomically)."""

    @abc.abstractmethod
    def load_generated(self, path: str | Path):
        """Read samples written by :meth:`save_generated`."""


class ItemProtocol(Protocol):
    """A protocol whose items come from the item source its :class:`ItemParams` describe."""

    params: ItemParams

    def item_source(self):
        """How the items are made (shared with every protocol of equal item fields and with
        the engine's training step): an :class:`repro.data.item_sources.ItemSource`."""
        return self.params.item_source(f"protocol {self.id!r}")

    def split_clipset(self, clipset):
        """``clipset`` with the items' split (and frame rate): what the evaluator trains on,
        so that no scored test clip was seen by the recogniser."""
        return self.item_source().split_clipset(clipset)

    def split_view(self, clipset):
        """What a plan reads of :meth:`split_clipset` (fingerprint, labels, split, label names),
        without building its clips where that costs work (the item source's ``split_view``; a
        source without one gives its ``split_clipset``, which has the same fields)."""
        src = self.item_source()
        return getattr(src, "split_view", src.split_clipset)(clipset)

    def train_items(self, clipset):
        """The items a generator is trained on (the item source's training split)."""
        return self.item_source().train_items(clipset)
