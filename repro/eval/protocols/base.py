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
"""

from __future__ import annotations

import abc
from pathlib import Path
from typing import Any, ClassVar, Literal, Mapping

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from repro.errors import ConfigError
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
        if params is None:
            return cls()
        if isinstance(params, cls):
            return params
        if isinstance(params, BaseModel):
            params = params.model_dump()
        try:
            return cls(**dict(params))
        except ValidationError as e:
            err = e.errors()[0]
            field = ".".join(str(p) for p in err.get("loc", ())) or "?"
            raise ConfigError(f"{where}: parameter {field!r}: {err['msg']}") from None


class ItemSourceParams(ProtocolParams):
    """The fields that say how a protocol's items are made, shared by every protocol that
    builds them with :class:`repro.data.contexts.ItemSource` (single-action, multi-action,
    SS/AR): two protocols with equal values train on the same items, so they share models."""

    # fixed by Neural Marionette (§5.1.1, supp. §3)
    initial_frames: int = Field(6, ge=1, description="frames of initial motion (supp. §3)")
    fps: float = Field(30.0, gt=0, description="frame rate the data must have (supp. §3)")
    test_fraction: float = Field(0.2, gt=0, lt=1, description="test share per class (§5.1.1)")
    test_cap_per_class: int = Field(100, ge=1, description="test clips per class at most (§5.1.1)")
    # open choices (docs/protocols.md, docs/multi_action.md)
    split: Literal["marionette", "dataset"] = Field(
        "marionette", description="Marionette's per-class split, or the data set's stored one")
    split_seed: int = Field(0, description="seed of the Marionette split")
    context: Literal["sequence", "same_clip"] = Field(
        "sequence", description="where P^ini and the next tag come from: the action's composed "
        "sequence (repro.data.contexts), or the clip itself (the earlier, leaking construction)")
    compose: dict = Field(default_factory=dict,
                          description="repro.data.sequences.ComposeConfig overrides")
    max_frames: int = Field(120, ge=1, description="cap on an action's duration (frames)")

    def item_source(self, where: str):
        """The :class:`repro.data.contexts.ItemSource` these fields describe."""
        from repro.data.contexts import ItemSource

        return ItemSource.make(where, context=self.context, fps=self.fps, split=self.split,
                               split_seed=self.split_seed, test_fraction=self.test_fraction,
                               test_cap_per_class=self.test_cap_per_class,
                               n_init=self.initial_frames, max_frames=self.max_frames,
                               compose=self.compose)


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
