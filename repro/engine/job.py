"""Jobs and their content keys (issue 4, item 3).

A :class:`Job` is one step of a table's graph (prepare data, train a classifier, train a method
for one seed, sample, evaluate, ...).  Its key is :func:`repro.keys.content_key` of
:meth:`Job.key_parts`::

    {"schema": 1, "kind": ..., "impl": "pkg.module:function",
     "source": source_hash(pkg.module, *plugins), # the code, transitively (source_hash.py)
     "plugins": [module names loaded by name at run time],
     "config": {...resolved...}, "inputs": [input keys, in order],
     "fingerprints": {"dataset": ..., "evaluator": ...}, "seed": int | None,
     "threads": int | None, "kernels": {...}[, "device": {...}]}

Canonical JSON makes the key independent of dict order; the order of ``inputs`` is kept
because the implementation receives them positionally.  ``label`` (display, ``plan --why``
bookkeeping) is not part of the key, so identical jobs built by two tables are one job.

``plugins`` names the modules the implementation loads by name through a registry (the row's
method, the band's protocol): no import statement leads the source hash to them, so the job
lists them and their code (transitively) is hashed with its own.

``threads`` is the torch/BLAS CPU thread count the job computes with (the executor applies it
for the job's duration, whatever ``--jobs`` says): float reductions, hence trained weights,
depend on it, so it is part of the key (a table's jobs take it from the scale profile).  A job
without one runs with the executor's default and must not depend on the count.

``device`` is where the job computes (``"cpu"``, ``"cuda"``, ``"cuda:N"``; None = the CPU; a
table's jobs take it from the scale profile or ``--device``).  A CUDA job's key holds
``"device"``: the device type with the CUDA determinism settings it computes under
(:func:`repro.seeding.device_key`); a CPU job's key has no such entry, so it is what it was
before jobs named a device.  The job implementation applies it (:func:`repro.seeding.prepare_device`).

``kernels`` is the kernel paths the job computes with (:func:`repro.kernels.key`): the portable
pin (any x86-64 CPU with AVX2 computes the same bytes), or under ``--fast-kernels`` the host's
vendor and widest ISA, so a shared store never hands one kind's results to the other.

A job with ``seed=None`` is cached only when it declares ``deterministic=True``; otherwise it
(and everything downstream of it) is re-run every time and never published (unseeded work is
never cached).

The implementation is called as ``fn(ctx)`` with a :class:`JobContext`.
"""

from __future__ import annotations

import importlib
import json
import logging
import random
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

from repro.keys import canonical_json, content_key

KEY_SCHEMA = 3  # 2: ``threads`` and ``plugins`` in the key; 3: ``kernels``


def _plain(obj: Any, what: str) -> Any:
    """A private deep copy of ``obj`` in canonical plain-JSON types (refuses paths, NaN, ...)."""
    try:
        return json.loads(canonical_json(obj))
    except (TypeError, ValueError) as e:
        raise ValueError(f"job {what} must be canonical JSON ({e})") from None


@dataclass(frozen=True, eq=False)
class Job:
    """One step of a job graph; equal jobs are jobs with equal keys.

    ``config`` and ``fingerprints`` are copied at construction (treat them as immutable);
    ``inputs`` are the jobs whose outputs this one reads, in the order the implementation
    receives them.
    """

    kind: str
    impl: str
    config: Mapping[str, Any] = field(default_factory=dict)
    inputs: tuple[Job, ...] = ()
    seed: int | None = None
    fingerprints: Mapping[str, Any] = field(default_factory=dict)
    label: str = ""
    deterministic: bool = False
    threads: int | None = None
    plugins: tuple[str, ...] = ()
    device: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.kind, str) or not self.kind.strip():
            raise ValueError("a job needs a non-empty kind")
        mod, sep, fn = str(self.impl).partition(":")
        if not sep or not mod or not fn or not all(p.isidentifier() for p in mod.split(".")) \
                or not fn.isidentifier():
            raise ValueError(f"job impl must be 'package.module:function', got {self.impl!r}")
        if self.seed is not None and (isinstance(self.seed, bool) or not isinstance(self.seed, int)):
            raise ValueError(f"job seed must be an int or None, got {self.seed!r}")
        if self.threads is not None and (isinstance(self.threads, bool)
                                         or not isinstance(self.threads, int) or self.threads < 1):
            raise ValueError(f"job threads must be an int >= 1 or None, got {self.threads!r}")
        if self.device is not None:
            from repro.specs.scales import device_problem

            if device_problem(self.device) is not None:
                raise ValueError(f"job device: {device_problem(self.device)}")
        if not isinstance(self.config, Mapping) or not isinstance(self.fingerprints, Mapping):
            raise ValueError("job config and fingerprints must be mappings")

        def module_name(m) -> bool:
            return isinstance(m, str) and all(p.isidentifier() for p in m.split("."))

        if isinstance(self.plugins, str) or not all(map(module_name, self.plugins)):
            raise ValueError(f"job plugins must be module names, got {self.plugins!r}")
        object.__setattr__(self, "plugins", tuple(sorted(set(self.plugins))))
        object.__setattr__(self, "config", _plain(dict(self.config), "config"))
        object.__setattr__(self, "fingerprints", _plain(dict(self.fingerprints), "fingerprints"))
        inputs = tuple(self.inputs)
        for j in inputs:
            if not isinstance(j, Job):
                raise ValueError(f"job inputs must be Jobs, got {type(j).__name__}")
        object.__setattr__(self, "inputs", inputs)

    # ------------------------------------------------------------------ identity
    @property
    def module(self) -> str:
        return self.impl.partition(":")[0]

    @property
    def function(self) -> str:
        return self.impl.partition(":")[2]

    @property
    def identity(self) -> str:
        """``kind`` plus ``label``: what ``plan --why`` compares across runs."""
        return f"{self.kind}:{self.label}" if self.label else self.kind

    @property
    def name(self) -> str:
        """A short display name: the label, else the kind."""
        return self.label or self.kind

    @cached_property
    def cacheable(self) -> bool:
        """Seeded (or declared deterministic) and every input cacheable."""
        own = self.seed is not None or self.deterministic
        return own and all(j.cacheable for j in self.inputs)

    def key_parts(self) -> dict[str, Any]:
        """What the key hashes (see the module docstring)."""
        from repro.engine.source_hash import source_hash
        from repro.kernels import key as kernel_key
        from repro.seeding import device_key

        device = device_key(self.device)
        return {
            **({} if device is None else {"device": device}),
            "kernels": kernel_key(),
            "schema": KEY_SCHEMA,
            "kind": self.kind,
            "impl": self.impl,
            "source": source_hash(self.module, *self.plugins),
            "plugins": list(self.plugins),
            "config": self.config,
            "inputs": [j.key() for j in self.inputs],
            "fingerprints": self.fingerprints,
            "seed": self.seed,
            "threads": self.threads,
        }

    @cached_property
    def _key(self) -> str:
        return content_key(self.key_parts())

    def key(self) -> str:
        """sha256 of the canonical JSON of :meth:`key_parts` (cached on the instance)."""
        return self._key

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Job) and other.key() == self.key()

    def __hash__(self) -> int:
        return hash(self.key())

    def resolve(self) -> Callable[[JobContext], Any]:
        """Import and return the implementing function."""
        try:
            mod = importlib.import_module(self.module)
        except ModuleNotFoundError as e:
            from repro.errors import ConfigError

            raise ConfigError(f"job {self.name}: cannot import {self.module} ({e})") from None
        fn = getattr(mod, self.function, None)
        if not callable(fn):
            from repro.errors import ConfigError

            raise ConfigError(f"job {self.name}: {self.module} has no function {self.function}")
        return fn


def topo_order(targets: Iterable[Job]) -> list[Job]:
    """Every job reachable from ``targets``, inputs before consumers, one per key.

    Jobs with equal keys are merged (the first one met keeps its label): a job shared by two
    tables runs once.  Deterministic: depth-first in the given input order.
    """
    order: list[Job] = []
    state: dict[str, int] = {}  # 1 visiting, 2 done

    def visit(job: Job) -> None:
        k = job.key()
        s = state.get(k)
        if s == 2:
            return
        if s == 1:  # impossible with immutable jobs, kept as a guard
            raise ValueError(f"job graph has a cycle through {job.name}")
        state[k] = 1
        for j in job.inputs:
            visit(j)
        state[k] = 2
        order.append(job)

    for t in targets:
        if not isinstance(t, Job):
            raise ValueError(f"graph targets must be Jobs, got {type(t).__name__}")
        visit(t)
    return order


@dataclass
class JobContext:
    """What an implementation ``fn(ctx)`` gets.

    - ``out``: the folder to write the payload into (published atomically afterwards);
    - ``scratch``: a persistent folder for this key (checkpoints), kept after a kill and given
      to the next attempt with the same key, removed once the object is published;
    - ``inputs``: the input objects (:class:`~repro.store.object_files.StoredObject`), in order;
    - ``seed``: the job's seed (``None`` for deterministic jobs);
    - ``progress(done, total=None, message=None)``: report progress;
    - ``logger``: a logger whose records also go to the key's log file in the store.
    """

    job: Job
    key: str
    inputs: tuple
    out: Path
    scratch: Path
    logger: logging.Logger
    threads: int | None = None
    progress_fn: Callable[[float, float | None, str | None], None] | None = None

    @property
    def seed(self) -> int | None:
        return self.job.seed

    @property
    def config(self) -> Mapping[str, Any]:
        return self.job.config

    def progress(self, done: float, total: float | None = None, message: str | None = None) -> None:
        if self.progress_fn is not None:
            self.progress_fn(done, total, message)

    def input(self, name: str):
        """The input object whose job label (or, if unique, kind) is ``name``."""
        by_label = [o for j, o in zip(self.job.inputs, self.inputs) if j.label == name]
        if len(by_label) == 1:
            return by_label[0]
        by_kind = [o for j, o in zip(self.job.inputs, self.inputs) if j.kind == name]
        if len(by_kind) == 1:
            return by_kind[0]
        names = [j.name for j in self.job.inputs]
        raise KeyError(f"job {self.job.name}: no unique input {name!r} among {names}")

    def seed_globals(self) -> int:
        """Seed Python's, numpy's legacy and torch's global generators from the job's seed.

        Implementations should pass explicit generators (:mod:`repro.seeding`); this covers
        library code that draws from the global state (e.g. ``torch.nn`` default parameter
        initialisation), so a worker that runs several jobs gives each the same stream
        whatever ran before it.  Returns the derived seed.
        """
        from repro.seeding import derive_seed

        s = derive_seed(0 if self.seed is None else self.seed, "globals", self.job.kind)
        random.seed(s)
        import numpy as np

        np.random.seed(s % (2**32))
        try:
            import torch
        except ImportError:  # pragma: no cover
            return s
        torch.manual_seed(s)
        return s
