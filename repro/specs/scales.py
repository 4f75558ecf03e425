"""Scale profiles (``tables/scales.toml``): how much work a table run does.

Three profiles, each a table of the TOML file:

- ``quick``: the bundled ``bandai2-mini`` stand-in, tiny models, minutes on a 2-core CPU (CI);
- ``medium``: the full ``bandai2`` stand-in, small models, under an hour per table on the CPU;
- ``paper``: the papers' hyper-parameters and sample counts (GPU).

A profile holds a default data set (the spec's ``standin_dataset`` when absent; ``--dataset``
overrides both), the replicate count and seed base, bootstrap resamples, per-protocol settings
(sample counts; a protocol table may override ``replicates``), the CPU ``threads`` every job
computes with (fixed, so that a job's bytes do not depend on ``--jobs`` or on the machine's core
count: the count changes float reductions, hence trained weights), the ``validation_fraction``
of the training clips held out to draw each trained model's validation curve
(:mod:`repro.train.validation`), evaluator settings (validated by
:mod:`repro.eval.settings`) and one free table per method (``[quick.methods.marionet]``) whose
keys the method modules validate themselves.

:func:`resolve_scale` returns a frozen :class:`ResolvedScale`; its :attr:`~ResolvedScale.scale_hash`
is the content key of everything it holds.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Union

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictFloat, StrictInt, StrictStr, \
    ValidationError, field_validator

from repro.errors import ConfigError
from repro.keys import canonical_json, content_key
from repro.paths import tables_root
from repro.specs import names
from repro.specs.schema import DatasetName

SCALE_NAMES = ("quick", "medium", "paper")

Scalar = Union[StrictBool, StrictInt, StrictFloat, StrictStr]
# Evaluator and method tables may nest one or two levels ([paper.evaluator.train]).
Value = Union[Scalar, list[Scalar], dict[str, Union[Scalar, list[Scalar], dict[str, Union[Scalar, list[Scalar]]]]]]


class ScaleProfile(BaseModel):
    """One profile of ``tables/scales.toml``."""

    model_config = ConfigDict(extra="forbid")

    description: str = Field(min_length=3)
    dataset: DatasetName | None = Field(None, description="default data set; None = the spec's "
                                       "stand-in")
    replicates: int = Field(ge=1, description="independent replicates (seeds) per cell")
    seed_base: int = Field(0, ge=0, description="replicate i uses seed seed_base + i")
    bootstrap_resamples: int = Field(ge=100, description="resamples of our bootstrap intervals")
    threads: int = Field(1, ge=1, le=256, description=(
        "torch/BLAS CPU threads each job of a table computes with; part of every job key, "
        "because float reductions (hence trained weights) depend on the count"))
    validation_fraction: float = Field(0.0, ge=0.0, lt=0.5, description=(
        "share of each class's training clips held out (by clip, seeded) to draw every trained "
        "model's validation curve; never used to select anything; 0 = train on every training "
        "clip, as the papers do (repro/train/validation.py)"))
    protocols: dict[str, dict[str, Value]] = Field(default_factory=dict)
    evaluator: dict[str, Value] = Field(default_factory=dict)
    methods: dict[str, dict[str, Value]] = Field(default_factory=dict)

    @field_validator("protocols")
    @classmethod
    def _known_protocols(cls, v: dict):
        for p, table in v.items():
            names.require_known("protocol", p)
            r = table.get("replicates")
            if r is not None and (not isinstance(r, int) or isinstance(r, bool) or r < 1):
                raise ValueError(f"protocols.{p}.replicates must be an integer ≥ 1 (got {r!r})")
        return v

    @field_validator("methods")
    @classmethod
    def _known_methods(cls, v: dict):
        for m in v:
            names.require_known("method", m)
        return v


class ScaleFile(BaseModel):
    """The whole ``tables/scales.toml``."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)

    schema_version: int = Field(1, alias="schema", ge=1, le=1)
    version: int = Field(ge=1, description="bump when any profile changes; stamped into runs")
    quick: ScaleProfile
    medium: ScaleProfile
    paper: ScaleProfile


@dataclass(frozen=True)
class ResolvedScale:
    """A profile with the data set decided; immutable (mappings are handed out as fresh copies).

    ``dataset`` is None only when neither ``--dataset`` nor the profile names one: the caller
    then uses the spec's ``standin_dataset`` (:meth:`dataset_for`).
    """

    name: str
    version: int
    description: str
    dataset: str | None
    replicates: int
    seed_base: int
    bootstrap_resamples: int
    threads: int
    source: str
    _payload: bytes  # canonical JSON of protocols / evaluator / methods
    #: share of each class's training clips held out for the validation curve (0: none)
    validation_fraction: float = 0.0

    # -- the free tables, as fresh plain dicts ---------------------------------------------

    def _part(self, key: str) -> dict[str, Any]:
        return json.loads(self._payload)[key]

    @property
    def protocols(self) -> dict[str, dict[str, Any]]:
        return self._part("protocols")

    @property
    def evaluator(self) -> dict[str, Any]:
        return self._part("evaluator")

    @property
    def methods(self) -> dict[str, dict[str, Any]]:
        return self._part("methods")

    def protocol_config(self, protocol: str) -> dict[str, Any]:
        if protocol not in names.PROTOCOLS:
            raise ConfigError(names.unknown_name_message("protocol", protocol))
        return self.protocols.get(protocol, {})

    def method_config(self, method: str) -> dict[str, Any]:
        if method not in names.METHODS:
            raise ConfigError(names.unknown_name_message("method", method))
        return self.methods.get(method, {})

    def replicates_for(self, protocol: str) -> int:
        return int(self.protocol_config(protocol).get("replicates", self.replicates))

    def seeds_for(self, protocol: str) -> tuple[int, ...]:
        return tuple(range(self.seed_base, self.seed_base + self.replicates_for(protocol)))

    @property
    def seeds(self) -> tuple[int, ...]:
        return tuple(range(self.seed_base, self.seed_base + self.replicates))

    def protocol_settings(self, spec, column_id: str) -> dict[str, Any]:
        """Everything a protocol module needs for one column of ``spec``: the spec's
        ``protocol_params`` (what the paper fixed), then its column group's, then this
        profile's table for the column's protocol (sample counts, ``replicates``), each later
        one overriding the earlier."""
        return {**spec.protocol_params_for(column_id),
                **self.protocol_config(spec.protocol_for(column_id))}

    def dataset_for(self, spec) -> str:
        """``--dataset`` / the profile's data set, else the spec's stand-in."""
        return self.dataset or spec.standin_dataset

    # -- identity ----------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name, "version": self.version, "dataset": self.dataset,
            "replicates": self.replicates, "seed_base": self.seed_base,
            "bootstrap_resamples": self.bootstrap_resamples, "threads": self.threads,
            "validation_fraction": self.validation_fraction,
            **json.loads(self._payload),
        }

    @property
    def scale_hash(self) -> str:
        return content_key(self.to_dict())


def scales_path(root: str | Path | None = None) -> Path:
    return (Path(root) if root is not None else tables_root()) / "scales.toml"


def load_scales(path: str | Path | None = None) -> ScaleFile:
    """Load and validate ``tables/scales.toml``; errors name the file, profile and field."""
    from repro.specs.load import SpecValidationError, _display_path, _problems_from_validation, read_toml

    path = Path(path) if path is not None else scales_path()
    data = read_toml(path)
    shown = _display_path(path)
    try:
        return ScaleFile.model_validate(data)
    except ValidationError as e:
        raise SpecValidationError(_problems_from_validation(e, data, ScaleFile, shown), shown) from None


def resolve_scale(name: str, dataset: str | None = None, *, path: str | Path | None = None) -> ResolvedScale:
    """The frozen profile ``name`` (quick | medium | paper), with ``dataset`` (``--dataset``)
    overriding the profile's default data set."""
    if name not in SCALE_NAMES:
        raise ConfigError(f"unknown scale {name!r}{names.suggest(name, SCALE_NAMES)} "
                          f"(choose from {', '.join(SCALE_NAMES)})")
    if dataset is not None and dataset not in names.DATASETS:
        from repro.data.registry import DATASETS as REGISTERED  # + declared data sets

        if dataset not in REGISTERED:
            raise ConfigError(names.unknown_name_message("dataset", dataset,
                                                         list(REGISTERED)))
    path = Path(path) if path is not None else scales_path()
    sf = load_scales(path)
    prof: ScaleProfile = getattr(sf, name)
    payload = canonical_json({"protocols": prof.protocols, "evaluator": prof.evaluator,
                              "methods": prof.methods})
    return ResolvedScale(
        name=name, version=sf.version, description=prof.description,
        dataset=dataset or prof.dataset, replicates=prof.replicates, seed_base=prof.seed_base,
        bootstrap_resamples=prof.bootstrap_resamples, threads=prof.threads, source=str(path),
        _payload=payload, validation_fraction=float(prof.validation_fraction),
    )


__all__ = ["SCALE_NAMES", "ScaleProfile", "ScaleFile", "ResolvedScale", "load_scales",
           "resolve_scale", "scales_path"]
