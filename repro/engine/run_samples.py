"""The stored samples behind a run's rows: which generate job made each row's motions, and the
test items (and, for multi-action protocols, the test sequences) they were made for.

A run record (``run.json``) names its table, scale, data set, seeds and plan options
(``config``: retrain, budget, evaluator seed).  :func:`run_samples` rebuilds that plan, takes
each row's generate job per band and replicate, and keeps it only when its content key is one
the run itself recorded: the pictures shown beside a run's numbers are the samples those
numbers were measured on, never a later run's.  A row whose key the run does not hold (the
code changed since, so a rerun would make new samples) says so instead of showing others.

Every row of a band generated for the *same* test items with the same replicate seed
(:meth:`repro.eval.protocols.base.Protocol.replicate_seed` depends on the replicate, not on
the method), so item ``i`` of replicate ``r`` compares like with like across rows.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from repro.errors import ConfigError, DataError


@dataclass
class RowSamples:
    """One row's generate job in one band and replicate."""

    row_id: str
    label: str
    method: str
    band: int
    replicate: int
    seed: int
    key: str | None
    reason: str | None = None  # why there are no samples (None: key recorded by the run)

    @property
    def available(self) -> bool:
        return self.key is not None and self.reason is None


@dataclass
class BandSamples:
    """A band (one protocol with its parameters) of the run: its rows' generate jobs."""

    index: int
    protocol_id: str
    group: str | None
    config: dict | None            # a generate job's config (protocol params, data set, ...)
    evaluator_key: str | None = None  # the store key of the band's evaluator (run.json)
    rows: list[RowSamples] = field(default_factory=list)
    real_row: str | None = None    # the table's Real row id, when it has one
    _cache: dict = field(default_factory=dict, repr=False)

    # -- the protocol's side ------------------------------------------------------------------
    def _get(self, name: str, make):
        if name not in self._cache:
            self._cache[name] = make()
        return self._cache[name]

    @property
    def protocol(self):
        from repro.engine.steps import protocol_of

        return self._get("protocol", lambda: protocol_of(self.config))

    @property
    def clipset(self):
        from repro.engine.steps import clipset

        return self._get("clipset", lambda: clipset(self.config["dataset"]))

    @property
    def items(self):
        """The protocol's scored test items (as the generate job built them)."""
        return self._get("items", lambda: self.protocol.test_items(self.clipset))

    @property
    def is_sequence(self) -> bool:
        """Multi-action: samples are S test sequences of L actions."""
        return hasattr(self.protocol, "test_set")

    @property
    def label(self) -> str:
        """What the band is, in words: ``multi_action, overall`` (protocol, spec group)."""
        return self.protocol_id + (f", {self.group}" if self.group else "")

    @property
    def test_set(self):
        """The multi-action protocol's test sequences.  They depend on the run's evaluator,
        which is read from the store, never trained here: DataError when it is gone."""
        from repro.engine.steps import evaluator_for
        from repro.store.objects import Store

        def make():
            if not self.is_sequence:
                raise ConfigError(f"protocol {self.protocol_id!r} has no test sequences")
            if not self.evaluator_key or not Store().has(self.evaluator_key):
                raise DataError(f"the run's evaluator ({(self.evaluator_key or '?')[:12]}) is no "
                                "longer in the store, so its test sequences cannot be rebuilt; "
                                "rerun the table")
            return self.protocol.test_set(self.clipset, self.items, evaluator_for(self.config))

        return self._get("test_set", make)

    def load(self, row: RowSamples):
        """The stored samples of ``row`` (DataError naming the store object when they are gone)."""
        from repro.engine.steps import GENERATED
        from repro.store.objects import Store

        if not row.available:
            raise DataError(row.reason or "no samples")
        ck = ("samples", row.key)
        if ck not in self._cache:
            obj = Store().get(row.key)
            if obj is None:
                raise DataError(f"samples {row.key[:12]} are no longer in the store (garbage-"
                                "collected or corrupt); rerun the table")
            self._cache[ck] = self.protocol.load_generated(obj.file(GENERATED))
        return self._cache[ck]


@dataclass
class RunSamples:
    spec: Any
    run_path: Path
    run: dict
    bands: list[BandSamples]

    @property
    def run_id(self) -> str:
        return self.run_path.name


def _recorded_keys(rj: dict) -> set[str]:
    """Keys of the generate jobs the run read or wrote (a failed or cancelled job is in
    ``jobs`` with its key but made nothing)."""
    done = set((rj.get("keys") or {}).get("read", [])) | set((rj.get("keys") or {}).get(
        "written", []))
    return {j["key"] for j in rj.get("jobs", [])
            if j.get("kind") == "generate" and j.get("key") in done}


def _group_of(columns: list[str]) -> str | None:
    """The spec group a band's columns share (``overall`` of ``overall.acc``), if any."""
    heads = {c.split(".", 1)[0] for c in columns if "." in c}
    return heads.pop() if len(heads) == 1 and all("." in c for c in columns) else None


def run_samples(table: str, *, scale: str = "quick", dataset: str | None = None,
                run: str | Path | None = None) -> RunSamples:
    """The samples behind a run of ``table`` (the newest finished plain run at ``scale`` by
    default; ``run``: an id, a prefix or a folder).  ConfigError when there is no run."""
    from repro.engine.runner import table_run, table_scale, table_spec
    from repro.engine.table_plan import build_plan
    from repro.store.runs import read_run_json

    spec = table_spec(table)
    path = table_run(spec, scale, dataset, run)
    if path is None:
        from repro.engine.footer import no_run_message
        from repro.engine.runner import newest_failure

        sc = table_scale(scale, dataset)
        failed = newest_failure(spec.id, sc.name, dataset or sc.dataset_for(spec))
        raise ConfigError(no_run_message(spec.id, sc.name, dataset, failed))
    rj = read_run_json(path)
    if rj.get("table") != spec.id:
        raise ConfigError(f"run {path.name} is of {rj.get('table')!r}, not {spec.id!r}")
    cfg = rj.get("config") or {}
    sc = table_scale(rj.get("scale") or scale, rj.get("dataset"))
    plan = build_plan(spec, sc, rj.get("dataset"), tuple(cfg.get("seeds") or ()) or None,
                      bool(cfg.get("retrain")), float(cfg.get("budget", 1.0)),
                      int(cfg.get("evaluator_seed", 0)))
    recorded = _recorded_keys(rj)
    recorded_bands = cfg.get("bands") or []
    bands = [BandSamples(i, b.protocol, _group_of(b.columns) if len(plan.bands) > 1 else None,
                         None, (recorded_bands[i] if i < len(recorded_bands) else {}).get(
                             "evaluator_key") or b.evaluator_key)
             for i, b in enumerate(plan.bands)]
    labels = {r.id: r.label for r in spec.rows}
    for rp in plan.rows:
        for bi, measures in sorted(rp.measures.items()):
            band = bands[bi]
            if rp.method == "real":
                band.real_row = rp.row_id
                continue
            for r, m in enumerate(measures):
                gen = m.inputs[0]
                if band.config is None:
                    band.config = dict(gen.config)
                key = gen.key()
                reason = None if key in recorded else (
                    "the run did not record these samples (the row failed, or they were made "
                    "by other code or options; rerun the table to draw them)")
                band.rows.append(RowSamples(rp.row_id, labels.get(rp.row_id, rp.row_id),
                                            rp.method, bi, r, int(gen.seed), key, reason))
    return RunSamples(spec, Path(path), rj, bands)


def describe(rs: RunSamples) -> str:
    """One line per band and row: what is stored (for ``repro export --list``)."""
    lines = [f"{rs.spec.id}: run {rs.run_id}"]
    for b in rs.bands:
        head = f"band {b.index} ({b.protocol_id}{', ' + b.group if b.group else ''})"
        lines.append(head + ("" if b.rows else ": no generated rows"))
        for r in b.rows:
            state = r.key[:12] if r.available else f"unavailable: {r.reason}"
            lines.append(f"  {r.row_id:28} r{r.replicate} seed {r.seed}  {state}")
    return "\n".join(lines)


def as_json(rs: RunSamples) -> str:
    return json.dumps({"table": rs.spec.id, "run": rs.run_id, "bands": [
        {"index": b.index, "protocol": b.protocol_id, "group": b.group,
         "rows": [{"row": r.row_id, "replicate": r.replicate, "seed": r.seed, "key": r.key,
                   "available": r.available, "reason": r.reason} for r in b.rows]}
        for b in rs.bands]}, indent=1)
