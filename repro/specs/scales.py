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
(:mod:`repro.train.validation`), the ``device`` its jobs train and sample on (``"cpu"``,
``"cuda"`` or ``"cuda:N"``; ``--device`` overrides it for one command through
:func:`device_override`; a CUDA device enters every job key with the CUDA determinism settings,
:func:`repro.seeding.device_key`), evaluator settings (validated by
:mod:`repro.eval.settings`) and one free table per method (``[quick.methods.marionet]``) whose
keys the method modules validate themselves.

:func:`resolve_scale` returns a frozen :class:`ResolvedScale`; its :attr:`~ResolvedScale.scale_hash`
is the content key of everything it holds.
"""

from __future__ import annotations

import json
import re
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictFloat, StrictInt, StrictStr, \
    ValidationError, field_validator

from repro.errors import ConfigError
from repro.keys import canonical_json, content_key
from repro.paths import tables_root
from repro.specs import names
from repro.specs.schema import MAX_SPEC_VERSION, DatasetName, fps_problem

SCALE_NAMES = ("quick", "medium", "paper", "converged")

#: the devices a profile (or ``--device``) may name: the CPU, or a CUDA card (``cuda:N`` picks
#: the card; the key holds the device type only, as placement does not change a result)
DEVICE_PATTERN = re.compile(r"cpu|cuda(:[0-9]+)?")
DEVICE_CHOICES = "cpu, cuda or cuda:N"


def device_problem(device: object) -> str | None:
    """Why ``device`` is not a device name this harness computes on (None when it is one)."""
    if isinstance(device, str) and DEVICE_PATTERN.fullmatch(device):
        return None
    return f"unknown device {device!r} (choose from {DEVICE_CHOICES})"

class PlateauSettings(BaseModel):
    """A profile's convergence rule settings (:mod:`repro.train.plateau`; issue 32): the rule
    reads each method's own quantity (:meth:`repro.models.base.Generator.plateau_rule`)."""

    model_config = ConfigDict(extra="forbid")

    tolerance: float = Field(0.01, gt=0.0, lt=1.0, description="relative improvement of the "
                             "best smoothed value under which the window counts as flat")
    window_share: float = Field(0.2, ge=0.0, lt=1.0, description="the window's share of the "
                                "epochs run so far")
    min_window: int = Field(5, ge=1, description="the window's least length in epochs")
    smooth: int = Field(3, ge=1, description="epochs of the trailing mean")
    statistic: Literal["both", "mean", "median"] = Field("both", description=(
        "how each window of smoothed values is summarised: 'both' fires only when the means "
        "and the medians of the two windows agree (a median is not moved by a spike of less "
        "than half a window; a mean averages noise best): repro/train/plateau.py"))
    max_minutes: float | None = Field(None, gt=0.0, description="time cap of one training "
                                      "(cumulative over resumes); None: the epoch cap only")
    method_max_minutes: dict[str, float] = Field(default_factory=dict, description=(
        "a method's own time cap in place of max_minutes (a method whose epoch costs minutes "
        "needs hours to reach its plateau where the others need minutes)"))

    @field_validator("method_max_minutes")
    @classmethod
    def _known_methods(cls, v: dict[str, float]) -> dict[str, float]:
        for m, minutes in v.items():
            if m not in names.METHODS:
                raise ValueError(names.unknown_name_message("method", m))
            if not minutes > 0:
                raise ValueError(f"{m} must be > 0, got {minutes!r}")
        return v


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
    device: str = Field("cpu", description=(
        "where the profile's train and generate jobs compute: cpu, cuda or cuda:N (--device "
        "overrides it); a CUDA device enters every job key with its determinism settings"))
    until: Literal["epochs", "plateau"] = Field("epochs", description=(
        "'epochs': every training runs its method's epochs; 'plateau': a method's epochs are a "
        "cap and training stops when the convergence rule fires (repro/train/plateau.py)"))
    plateau: PlateauSettings = Field(default_factory=PlateauSettings)
    protocols: dict[str, dict[str, Value]] = Field(default_factory=dict)
    evaluator: dict[str, Value] = Field(default_factory=dict)
    methods: dict[str, dict[str, Value]] = Field(default_factory=dict)

    @field_validator("device")
    @classmethod
    def _known_device(cls, v: str):
        problem = device_problem(v)
        if problem is not None:
            raise ValueError(problem)
        return v

    @field_validator("protocols")
    @classmethod
    def _known_protocols(cls, v: dict):
        for p, table in v.items():
            names.require_known("protocol", p)
            r = table.get("replicates")
            if r is not None and (not isinstance(r, int) or isinstance(r, bool) or r < 1):
                raise ValueError(f"protocols.{p}.replicates must be an integer ≥ 1 (got {r!r})")
            if "fps" in table and fps_problem(table["fps"]) is not None:
                raise ValueError(f"protocols.{p}.{fps_problem(table['fps'])}")
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
    version: int = Field(ge=1, le=MAX_SPEC_VERSION, description="bump when any profile "
                         "changes; stamped into runs")
    quick: ScaleProfile
    medium: ScaleProfile
    paper: ScaleProfile
    #: issue 32; optional, so a scales file written before it still loads
    converged: ScaleProfile | None = None


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
    #: where train and generate jobs compute ("cpu", "cuda", "cuda:N")
    device: str = "cpu"
    #: canonical JSON of the trainings' schedule (``until`` + plateau settings) when the
    #: profile trains until a plateau; "" for a fixed number of epochs
    _schedule: str = ""

    @property
    def schedule(self) -> dict[str, Any] | None:
        """What a train job's ``schedule`` holds (``until = "plateau"`` and the rule's
        settings, :func:`repro.engine.steps.stopping_of`), or None for fixed epochs."""
        return json.loads(self._schedule) if self._schedule else None

    def schedule_for(self, method: str) -> dict[str, Any] | None:
        """The ``schedule`` of one training of ``method`` (a train job's key holds it): the
        profile's, with the method's own time cap (``method_max_minutes``) in ``max_minutes``
        and the table of caps left out, so a method's key changes only with its own cap."""
        sched = self.schedule
        if sched is None:
            return None
        caps = sched.pop("method_max_minutes", None) or {}
        if method in caps:
            sched["max_minutes"] = caps[method]
        return sched

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
        """Everything the profile holds; ``device`` only when it is not the CPU (so a CPU
        profile's hash is what it was before profiles named a device)."""
        out = {
            "name": self.name, "version": self.version, "dataset": self.dataset,
            "replicates": self.replicates, "seed_base": self.seed_base,
            "bootstrap_resamples": self.bootstrap_resamples, "threads": self.threads,
            "validation_fraction": self.validation_fraction,
            **json.loads(self._payload),
        }
        if self.device != "cpu":
            out["device"] = self.device
        if self._schedule:  # only then: a fixed-epoch profile's hash is what it was
            out["schedule"] = self.schedule
        return out

    @property
    def scale_hash(self) -> str:
        return content_key(self.to_dict())


def scales_path(root: str | Path | None = None) -> Path:
    return (Path(root) if root is not None else tables_root()) / "scales.toml"


def load_scales(path: str | Path | None = None) -> ScaleFile:
    """Load and validate ``tables/scales.toml``; errors name the file, profile and field."""
    from repro.specs.load import (SpecValidationError, display_path, problems_from_validation,
                                  read_toml)

    path = Path(path) if path is not None else scales_path()
    data = read_toml(path)
    shown = display_path(path)
    try:
        return ScaleFile.model_validate(data)
    except ValidationError as e:
        raise SpecValidationError(problems_from_validation(e, data, ScaleFile, shown), shown) from None


#: the last :func:`load_scales` of :func:`resolve_scale`, by file: (path, inode, size, mtime) ->
#: the validated file.  A command resolves its profile several times (plan, jobs, footer);
#: parsing and validating the TOML each time was ~40 ms of ``repro plan`` (issue 31).  An
#: edited file (another size or mtime) is read again.
_SCALES_MEMO: dict[tuple, ScaleFile] = {}


def _scales_of(path: Path) -> ScaleFile:
    """:func:`load_scales` of ``path``, memoised per process while the file is unchanged
    (resolve_scale only reads the result)."""
    try:
        st = path.stat()
        sig = (str(path.resolve()), st.st_ino, st.st_size, st.st_mtime_ns)
    except OSError:
        return load_scales(path)  # its own error names the file
    sf = _SCALES_MEMO.get(sig)
    if sf is None:
        sf = load_scales(path)
        _SCALES_MEMO.clear()
        _SCALES_MEMO[sig] = sf
    return sf


#: ``--device`` of the running command (None: each profile's own device)
_DEVICE_OVERRIDE: ContextVar[str | None] = ContextVar("repro_device_override", default=None)


@contextmanager
def device_override(device: str | None):
    """Within the block, :func:`resolve_scale` gives every profile ``device`` instead of its
    own (``--device``; None leaves the profiles' devices).  A bad name is a ConfigError naming
    the option."""
    if device is not None and device_problem(device) is not None:
        raise ConfigError(f"--device: {device_problem(device)}")
    token = _DEVICE_OVERRIDE.set(device)
    try:
        yield
    finally:
        _DEVICE_OVERRIDE.reset(token)


#: ``until`` of the running computation (None: each profile's own), e.g. a sweep's plateau point
_UNTIL_OVERRIDE: ContextVar[str | None] = ContextVar("repro_until_override", default=None)


@contextmanager
def until_override(until: str | None):
    """Within the block, :func:`resolve_scale` gives every profile ``until`` ("epochs" or
    "plateau", with the profile's own ``[plateau]`` settings) instead of its own: the budget
    sweep's plateau point (:mod:`repro.engine.sweep`)."""
    if until not in (None, "epochs", "plateau"):
        raise ConfigError(f"until must be 'epochs' or 'plateau', got {until!r}")
    token = _UNTIL_OVERRIDE.set(until)
    try:
        yield
    finally:
        _UNTIL_OVERRIDE.reset(token)


def require_device(scale: ResolvedScale) -> str:
    """``scale.device`` when this machine can compute on it; else a ConfigError (exit 2) that
    says which profile asked for it and how to run on the CPU instead.  Called before a command
    computes anything (planning never needs the device)."""
    if scale.device == "cpu":
        return "cpu"
    import torch

    src = Path(scale.source)
    origin = ("--device" if _DEVICE_OVERRIDE.get() is not None
              else f"{src.parent.name}/{src.name} [{scale.name}] device")
    if not torch.cuda.is_available():
        raise ConfigError(f"scale {scale.name!r} computes on {scale.device!r} ({origin}) but "
                          "torch.cuda.is_available() is false on this machine (a CPU build of "
                          "torch, or no GPU); pass --device cpu to compute on the CPU")
    index = torch.device(scale.device).index
    if index is not None and index >= torch.cuda.device_count():
        raise ConfigError(f"scale {scale.name!r} computes on {scale.device!r} ({origin}) but "
                          f"this machine has {torch.cuda.device_count()} CUDA device(s)")
    return scale.device


def gpus_per_job(scale: ResolvedScale) -> int:
    """How many GPUs one of the profile's jobs asks a scheduler for (Ray's ``num_gpus``): one
    on a CUDA device (a job trains one model on one card), none on the CPU."""
    return 0 if scale.device == "cpu" else 1


def resolve_scale(name: str, dataset: str | None = None, *, path: str | Path | None = None,
                  device: str | None = None) -> ResolvedScale:
    """The frozen profile ``name`` (quick | medium | paper | converged), with ``dataset`` (``--dataset``)
    overriding the profile's default data set and ``device`` (else the running command's
    :func:`device_override`, else the profile's own) its device.  Resolving never checks that
    the device exists here (:func:`require_device` does, before work)."""
    if device is not None and device_problem(device) is not None:
        raise ConfigError(f"device: {device_problem(device)}")
    if name not in SCALE_NAMES:
        raise ConfigError(f"unknown scale {name!r}{names.suggest(name, SCALE_NAMES)} "
                          f"(choose from {', '.join(SCALE_NAMES)})")
    if dataset is not None and dataset not in names.DATASETS:
        from repro.data.registry import DATASETS as REGISTERED  # + declared data sets
        from repro.data.registry import unknown_dataset_message

        if dataset not in REGISTERED:
            raise ConfigError(unknown_dataset_message(dataset))
    path = Path(path) if path is not None else scales_path()
    sf = _scales_of(path)
    prof: ScaleProfile | None = getattr(sf, name)
    if prof is None:
        from repro.specs.load import display_path

        raise ConfigError(f"{display_path(path)}: no [{name}] profile (tables/scales.toml of "
                          "the repository has one to copy)")
    payload = canonical_json({"protocols": prof.protocols, "evaluator": prof.evaluator,
                              "methods": prof.methods})
    return ResolvedScale(
        name=name, version=sf.version, description=prof.description,
        dataset=dataset or prof.dataset, replicates=prof.replicates, seed_base=prof.seed_base,
        bootstrap_resamples=prof.bootstrap_resamples, threads=prof.threads, source=str(path),
        _payload=payload, validation_fraction=float(prof.validation_fraction),
        device=device or _DEVICE_OVERRIDE.get() or prof.device,
        _schedule=_schedule_of(prof),
    )


def _schedule_of(prof: ScaleProfile) -> str:
    """:attr:`ResolvedScale._schedule` of a profile (under :func:`until_override`)."""
    until = _UNTIL_OVERRIDE.get() or prof.until
    if until == "epochs":
        return ""
    return canonical_json({"until": until, **prof.plateau.model_dump()}).decode()


__all__ = ["SCALE_NAMES", "PlateauSettings", "ScaleProfile", "ScaleFile", "ResolvedScale",
           "device_override", "device_problem", "gpus_per_job", "load_scales", "require_device",
           "resolve_scale", "scales_path", "until_override"]
