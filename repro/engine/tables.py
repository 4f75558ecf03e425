"""A table's job graph, its run and the aggregation of raw replicate values (the report view is
:mod:`repro.engine.table_view`).

Data flow (DESIGN.md): spec + scale profile + data set → bands of columns that share a
protocol → per row: ``train`` (one model per row, training seed = the profile's first seed) →
per replicate: ``generate`` → ``measure``; the "Real" row: per replicate ``measure_real``.
Every job's key covers its kind, the source of its implementation, its resolved config, its
inputs, the data-set fingerprint, the evaluator's store key, its seed, its CPU thread count
(the profile's ``threads``: float reductions depend on it) and, as plug-ins, the source of the
row's method module and of the band's protocol module (both loaded by name, so no import
statement leads the source hash to them), so jobs shared by
two tables (the full MarioNet serves Tables 1, 2 and 4) run once.

Replicates (a choice the papers' reference code also makes): a replicate is an independent
sampling pass of one trained model, with seed ``seed_base + i``; training-seed variance is not
inside the interval, and every report says so.  ``retrain`` (``repro run --retrain``) gives each
replicate its own training (seed ``seed_base + i``), so the interval does include it.

Aggregation keeps every raw replicate value (``values.jsonl``) and summarises each cell with
the paper-style ± of the spec's interval convention beside our bootstrap interval
(:func:`repro.stats.summary.summarize`).  Claims get a posterior probability from
:func:`repro.stats.claims.claim_probability`:

- ``order`` (A better than B, C, …) is the conjunction of its pairwise comparisons: its verdict
  is "supported" only when every pair is, "contradicted" when any pair is; the P shown is the
  smallest pairwise P (an upper bound on the joint probability);
- ``gap`` with ``bound = "at_least"`` is P(A beats B by ≥ δ); ``bound = "within"`` is
  1 − P(A − B ≥ δ) − P(B − A ≥ δ);
- ``trend`` along rows is the conjunction of consecutive pairs (``stable``: each pair within δ);
- on a figure, cells are per x point (``"overall.acc@3"``) and claims are evaluated along the
  x axis by :mod:`repro.engine.figures` (conjunctions over ``x_range``; trends along x from
  the replicates' least-squares slopes).
- ``closer_to_real`` columns compare |value − mean(real)| with "lower" as better.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from repro.engine.job import Job
from repro.report.view import DATA_UNAVAILABLE, NOT_IMPLEMENTED, OK

STEPS = "repro.engine.steps"
SUMMARY_SCHEMA = 1


# ---------------------------------------------------------------------------------------------
# planning


@dataclass
class Band:
    """Columns of one table that share a protocol and its parameters."""

    protocol: str
    params: dict[str, Any]
    columns: list[str]
    metrics: dict[str, str]  # column id -> metric id
    implemented: bool = False
    reason: str | None = None
    evaluator: dict[str, Any] | None = None  # {dataset, kind, scale, seed}
    evaluator_key: str | None = None
    version: int | None = None  # the protocol implementation's version
    module: str | None = None   # the protocol implementation's module (a plug-in of its jobs)
    item_source: dict | None = None  # how training items are made (ItemSource.describe())
    generation_uses_evaluator: bool = False  # generate jobs read the evaluator (multi-action)

    def step_config(self, dataset: str, *, with_evaluator: bool = False) -> dict[str, Any]:
        """What every step of this band reads: data set and protocol (+ the evaluator for the
        steps that measure; train/generate keys must not depend on the evaluator)."""
        cfg = {"dataset": dataset, "protocol": self.protocol, "protocol_params": self.params,
               "protocol_version": self.version}
        if with_evaluator:
            cfg["evaluator"] = self.evaluator
        return cfg


@dataclass
class RowPlan:
    row_id: str
    method: str
    status: str = OK
    reason: str | None = None
    train: dict[int, list[Job]] = field(default_factory=dict)    # band index -> train job(s)
    measures: dict[int, list[Job]] = field(default_factory=dict)  # band index -> per replicate


@dataclass
class TablePlan:
    spec: Any
    scale: Any
    dataset: str
    data_fingerprint: str | None
    data_missing: str | None
    seeds: tuple[int, ...]
    bands: list[Band]
    rows: list[RowPlan]
    retrain: bool = False  # one training per replicate (build_plan)
    budget: float = 1.0    # epochs × this factor (repro sweep --budget; 1 = the profile's)
    evaluator_seed: int = 0  # the evaluators' training seed (repro sweep --evaluator-seeds)

    def jobs(self) -> list[Job]:
        out: list[Job] = []
        for r in self.rows:
            for js in r.measures.values():
                out.extend(js)
        return out

    @property
    def config(self) -> dict:
        """The resolved configuration recorded in run.json."""
        return {"scale": self.scale.to_dict(), "dataset": self.dataset, "seeds": list(self.seeds),
                "retrain": self.retrain, "budget": self.budget,
                "evaluator_seed": self.evaluator_seed,
                "data_fingerprint": self.data_fingerprint,
                "bands": [{"protocol": b.protocol, "params": b.params, "columns": b.columns,
                           "implemented": b.implemented, "evaluator": b.evaluator,
                           "evaluator_key": b.evaluator_key} for b in self.bands]}


def _bands(spec, scale) -> list[Band]:
    bands: list[Band] = []
    for col in spec.columns:
        pid = spec.protocol_for(col.id)
        params = {**spec.protocol_params_for(col.id),
                  **{k: v for k, v in scale.protocol_config(pid).items() if k != "replicates"}}
        for b in bands:
            if b.protocol == pid and b.params == params:
                b.columns.append(col.id)
                b.metrics[col.id] = col.metric
                break
        else:
            bands.append(Band(pid, params, [col.id], {col.id: col.metric}))
    return bands


def _data_status(dataset: str) -> tuple[str | None, str | None]:
    from repro.data.registry import get_entry

    st = get_entry(dataset).status()
    if not st.prepared:
        return None, st.missing or f"data set {dataset!r} is not prepared"
    return st.fingerprint, None


def _method_config(method: str, scale, overrides: dict) -> tuple[dict | None, str | None]:
    """The fully resolved config of ``method`` (paper defaults < scale < row overrides), or
    (None, reason) when the method is not built."""
    from repro.errors import ConfigError
    from repro.models.base import GENERATOR_MODULES, generator_class

    if method not in GENERATOR_MODULES:
        return None, f"method {method!r} is not implemented yet"
    try:
        cls = generator_class(method)
    except ConfigError as e:
        return None, str(e)
    base = getattr(cls, "trains_as", None)  # its training method's scale settings come first
    scaled = {**(scale.method_config(base) if base else {}), **scale.method_config(method)}
    try:
        cfg = cls.Config.resolve({**scaled, **overrides}, where=method)
    except ConfigError as e:  # a variant the spec names but the method does not offer (yet)
        return None, f"variant not implemented: {e}"
    return cfg.model_dump(mode="json"), None


#: at most this many replicate seeds in one ``--seeds`` (a typo must not allocate billions)
MAX_SEEDS = 10_000


def parse_seeds(text: str) -> tuple[int, ...]:
    """``"0-4"`` → (0, 1, 2, 3, 4); ``"0,3,7"`` → (0, 3, 7) (``--seeds``; at most
    :data:`MAX_SEEDS` of them)."""
    from repro.errors import ConfigError

    shown = text if len(text) <= 40 else text[:37] + "..."
    try:
        out: list[int] = []
        for part in text.split(","):
            a, sep, b = part.strip().partition("-")
            lo, hi = (int(a), int(b)) if sep else (int(a), int(a))
            if hi - lo + 1 + len(out) > MAX_SEEDS:
                raise ConfigError(f"--seeds {shown!r}: more than {MAX_SEEDS} seeds")
            out.extend(range(lo, hi + 1))
    except ValueError:
        raise ConfigError(f"--seeds {shown!r}: give seeds as '0-4' or '0,3,7'") from None
    if not out or len(set(out)) != len(out) or min(out) < 0:
        raise ConfigError(f"--seeds {shown!r}: seeds must be distinct non-negative integers")
    return tuple(out)


def build_plan(spec, scale, dataset: str | None = None, seeds: tuple[int, ...] | None = None,
               retrain: bool = False, budget: float = 1.0, evaluator_seed: int = 0) -> TablePlan:
    """Everything a run of ``spec`` at ``scale`` would do (no training; the data set is only
    opened, memory-mapped, for the fingerprint of the evaluator's training split).

    A replicate is a sampling pass of one trained model per row; with ``retrain`` each
    replicate also trains its own model (training seed = the replicate's seed), so the
    intervals include training-seed variance, at R times the training cost.  ``budget``
    multiplies every method's epoch counts (:func:`repro.engine.evidence.scale_epochs`; 1 keeps
    the profile's, so its jobs are the plain run's); ``evaluator_seed`` trains the evaluators
    with another seed (evaluator sensitivity, :mod:`repro.engine.sweep`)."""
    from repro.engine.evidence import scale_epochs
    from repro.eval.protocols import get_protocol, is_implemented
    from repro.eval.provider import evaluator_key
    from repro.eval.settings import resolve_settings
    from repro.models.base import generator_class

    dataset = dataset or scale.dataset_for(spec)
    fp, missing = _data_status(dataset)
    seeds = tuple(seeds) if seeds else scale.seeds_for(spec.protocol)
    bands = _bands(spec, scale)
    settings = resolve_settings(scale.name)
    clips = None
    protos: dict[int, Any] = {}
    for bi, b in enumerate(bands):
        if not is_implemented(b.protocol):
            b.reason = f"protocol {b.protocol!r} is not implemented yet"
            continue
        proto = protos[bi] = get_protocol(b.protocol, b.params)
        b.implemented = True
        b.params = proto.params.describe()  # resolved defaults, as the steps get them back
        b.version = proto.version
        b.module = type(proto).__module__
        b.evaluator = {"dataset": dataset, "kind": proto.evaluator_kind, "scale": scale.name,
                       "seed": int(evaluator_seed)}
        heading = getattr(proto, "evaluator_heading", None)
        if heading is not None:  # a protocol that changes headings asks for a heading-free one
            b.evaluator["heading"] = heading
        over = dict(proto.evaluator_overrides()) if hasattr(proto, "evaluator_overrides") else {}
        if over:  # e.g. ODMO's window per paper data set
            b.evaluator["settings"] = over
        b.item_source = proto.item_source().describe() if hasattr(proto, "item_source") else None
        b.generation_uses_evaluator = bool(getattr(proto, "generation_uses_evaluator", False))
        if fp is not None:
            from repro.engine.steps import clipset, evaluator_clipset

            clips = clips or clipset(dataset)
            ev_over = {**over, **({} if heading is None else {"heading": heading})}
            ev_settings = resolve_settings(scale.name, ev_over) if ev_over else settings
            b.evaluator_key = evaluator_key(proto.evaluator_kind, ev_settings,
                                            evaluator_clipset(proto, clips).fingerprint,
                                            int(evaluator_seed))
    plan = TablePlan(spec, scale, dataset, fp, missing, seeds, bands, [], retrain=bool(retrain),
                     budget=float(budget), evaluator_seed=int(evaluator_seed))
    # held-out share of the training actions for the learning curve (repro.train.validation)
    validation = {"fraction": float(getattr(scale, "validation_fraction", 0.0) or 0.0), "seed": 0}
    # every table job computes with the profile's thread count; only the jobs that compute
    # with a network (train and generate of a method that ``uses_device``) on the profile's
    # device (--device): measuring runs on the CPU, so its keys never name a device and Ray
    # gives it no GPU
    job = partial(Job, threads=scale.threads)
    device = getattr(scale, "device", "cpu")

    def device_of(method: str) -> str | None:
        return device if getattr(generator_class(method), "uses_device", True) else None
    for row in spec.rows:
        rp = RowPlan(row.id, row.method)
        plan.rows.append(rp)
        if missing is not None:
            rp.status, rp.reason = DATA_UNAVAILABLE, missing
            continue
        if not any(b.implemented for b in bands):
            rp.status = NOT_IMPLEMENTED
            rp.reason = "; ".join(sorted({b.reason for b in bands if b.reason}))
            continue
        if row.method != "real":
            mcfg, why = _method_config(row.method, scale, dict(row.overrides))
            if mcfg is None:
                rp.status, rp.reason = NOT_IMPLEMENTED, why
                continue
            mcfg = scale_epochs(mcfg, budget)
            cls = generator_class(row.method)
            method_module = cls.__module__
            # a method that trains as another (NEURAL MARIONETTE = MarioNet's weights plus
            # inference-time schemes) shares that method's training job
            train_method = getattr(cls, "trains_as", None) or row.method
            inference = tuple(getattr(cls, "inference_fields", ()))
            train_cfg = {k: v for k, v in mcfg.items() if k not in inference}
            train_module = generator_class(train_method).__module__
            # a composite (ACTOR + SSMCT, ACTOR + interpolation) trains nothing of its own: its
            # components are trained as those methods are for any other row (shared jobs)
            components = dict(getattr(cls, "components", None) or {})
            if components:
                comp_cfgs = {}
                for name, m in components.items():
                    c, why = _method_config(m, scale, {})
                    if c is None:
                        break
                    comp_cfgs[name] = (m, scale_epochs(c, budget))
                if c is None:
                    rp.status, rp.reason = NOT_IMPLEMENTED, f"component {name!r}: {why}"
                    continue
        for bi, b in enumerate(bands):
            if not b.implemented:
                continue
            base = b.step_config(dataset)
            fps = {"dataset": fp}
            if row.method == "real":
                # a protocol whose Real rows differ by an option (MultiAct's Real-train /
                # Real-test: ``split``) names the overrides it reads; others ignore them
                opts = {k: v for k, v in row.overrides.items()
                        if k in getattr(protos[bi], "real_row_options", ())}
                real = {"real": opts} if opts else {}
                rp.measures[bi] = [
                    job("measure_real", f"{STEPS}:measure_real",
                        {**base, "replicate": r, "evaluator": b.evaluator, **real},
                        seed=s, fingerprints={**fps, "evaluator": b.evaluator_key},
                        label=f"{row.id}/real/r{r}", plugins=(b.module,))
                    for r, s in enumerate(seeds)]
                continue
            def train_job(seed, method=train_method, method_cfg=train_cfg, module=train_module):
                # keyed by how the training items are made, not by the protocol, so a model
                # serves every table whose protocols make items the same way
                return job("train", f"{STEPS}:train_method",
                           {"dataset": dataset, "items": b.item_source, "method": method,
                            "method_config": method_cfg, "validation": validation},
                           seed=seed, fingerprints=fps, device=device_of(method),
                           label=f"{method}/train"
                           + ("" if seed == seeds[0] else f"/s{seed}"),
                           plugins=(module,))

            proto = protos[bi]
            takes_models = bool(getattr(proto, "takes_models", False))
            # extra trained models the protocol needs for this row (MultiAct: ACTOR's previous
            # motions and first step), then a composite's components; name -> (method, config)
            needed: dict[str, tuple[str, dict]] = {}
            if takes_models and hasattr(proto, "extra_models"):
                for name, m in sorted(proto.extra_models(row.method, mcfg).items()):
                    c, why = _method_config(m, scale, {})
                    if c is None:
                        rp.status, rp.reason = NOT_IMPLEMENTED, f"model {name!r}: {why}"
                        break
                    needed[name] = (m, scale_epochs(c, budget))
            if rp.status != OK:
                break
            if components:
                needed.update(comp_cfgs)

            def jobs_for(seed):
                own = [] if components else [train_job(seed)]
                return own + [train_job(seed, m, c, generator_class(m).__module__)
                              for _, (m, c) in needed.items()]

            # one model per row (its seed = the first replicate seed), or with ``retrain`` one
            # per replicate (seed = the replicate's): the first is the same job either way
            per_seed = [jobs_for(s) for s in (seeds if retrain else seeds[:1])]
            rp.train[bi] = [j for js in per_seed for j in js]
            ms = []
            for r, s in enumerate(seeds):
                gcfg = {**base, "replicate": r, "need": sorted(set(b.metrics.values()))}
                gfps = fps
                if train_method != row.method or components or (takes_models and inference):
                    gcfg.update(method=row.method, method_config=mcfg)
                if needed:
                    gcfg["models"] = list(needed)
                if b.generation_uses_evaluator:  # test set (and AR) depend on the evaluator
                    gcfg["evaluator"] = b.evaluator
                    gfps = {**fps, "evaluator": b.evaluator_key}
                gen = job("generate", f"{STEPS}:generate", gcfg,
                          inputs=tuple(per_seed[r if retrain else 0]), seed=s, fingerprints=gfps,
                          device=device_of(row.method),
                          label=f"{row.id if train_method != row.method else row.method}"
                                f"/generate/r{r}",
                          plugins=tuple(dict.fromkeys((method_module, train_module, b.module))))
                ms.append(job("measure", f"{STEPS}:measure", {**base, "evaluator": b.evaluator},
                              inputs=(gen,), seed=s,
                              fingerprints={**fps, "evaluator": b.evaluator_key},
                              label=f"{row.id}/measure/r{r}", plugins=(b.module,)))
            rp.measures[bi] = ms
        if not rp.measures and rp.status == OK:
            rp.status = NOT_IMPLEMENTED
            rp.reason = "; ".join(sorted({b.reason for b in bands if b.reason}))
    return plan


# ---------------------------------------------------------------------------------------------
# aggregation


def collect_values(plan: TablePlan, reports: dict) -> list[dict]:
    """Every raw replicate value of the run: one dict per (row, column, replicate);
    ``reports`` maps row id -> that row's execution report.  On a figure, one dict per (row,
    column, replicate, x present), column id ``f"{column}@{x}"`` (:mod:`repro.engine.figures`)."""
    from repro.engine.figures import is_figure, per_x_values, x_cell_id
    from repro.engine.steps import read_values

    axis = plan.spec.x if is_figure(plan.spec) else None
    out = []
    for rp in plan.rows:
        report = reports.get(rp.row_id)
        if report is None:
            continue
        for bi, jobs in rp.measures.items():
            band = plan.bands[bi]
            for r, job in enumerate(jobs):
                vals = read_values(report.object(job))
                for col in band.columns:
                    if axis is not None:
                        for x, v in per_x_values(vals, band.metrics[col], axis.start, axis.stop):
                            out.append({"row": rp.row_id, "column": x_cell_id(col, x),
                                        "replicate": r, "seed": job.seed, "value": v,
                                        "metric": band.metrics[col], "job": job.key(), "x": x})
                        continue
                    v = vals.get(band.metrics[col])
                    if v is None and band.metrics[col] not in vals:
                        continue  # the protocol does not measure this column for this row
                    out.append({"row": rp.row_id, "column": col, "replicate": r,
                                "seed": job.seed, "value": v, "metric": band.metrics[col],
                                "job": job.key()})
    return out


def collect_trainings(plan: TablePlan, reports: dict) -> list[dict]:
    """Every training of the run, once per (row, training job): the row, the method trained,
    its seed, job key, the resolved method config and the training record the job wrote
    (``training.json``: per-epoch loss terms, validation error, steps; None if absent)."""
    from repro.engine.steps import read_training
    from repro.store.objects import Store

    out = []
    for rp in plan.rows:
        report = reports.get(rp.row_id)
        if report is None:
            continue
        seen = set()
        for jobs in rp.train.values():
            for job in jobs:
                if job.key() in seen:
                    continue
                seen.add(job.key())
                try:  # the graph's object, or (a run whose measures were all cached never
                    # loads its trainings) the store's
                    obj = report.object(job)
                except KeyError:
                    obj = Store().get(job.key())
                rec = read_training(obj) if obj is not None else None
                out.append({"row": rp.row_id, "method": job.config["method"], "seed": job.seed,
                            "job": job.key(), "method_config": job.config["method_config"],
                            "training": rec})
    return out


def row_budgets(plan: TablePlan, trainings: list[dict] | None) -> dict[str, dict | None]:
    """Each trained row's budget against the paper's (:func:`repro.engine.evidence.training_budget`),
    from its first training's record, or from the planned config when there is no record."""
    from repro.engine.evidence import training_budget

    recs = {}
    for t in trainings or []:
        recs.setdefault(t["row"], t)
    out: dict[str, dict | None] = {}
    for rp in plan.rows:
        jobs = [j for js in rp.train.values() for j in js]
        if not jobs:
            continue
        t = recs.get(rp.row_id)
        cfg = jobs[0].config
        out[rp.row_id] = training_budget(cfg["method"], cfg["method_config"],
                                         None if t is None else t.get("training"))
    return out


def _values_by_cell(values: list[dict]) -> dict[tuple[str, str], list[float]]:
    cells: dict[tuple[str, str], list[float]] = {}
    for v in sorted(values, key=lambda d: (d["row"], d["column"], d["replicate"])):
        if v["value"] is not None and math.isfinite(v["value"]):
            cells.setdefault((v["row"], v["column"]), []).append(float(v["value"]))
    return cells


def summarise(plan: TablePlan, values: list[dict], trainings: list[dict] | None = None) -> dict:
    """summary.json: per-cell statistics and per-claim verdicts from the raw values, each
    verdict with the evidence that decided it (:mod:`repro.engine.evidence`; ``trainings``
    from :func:`collect_trainings` give the budgets)."""
    from repro.seeding import derive_seed
    from repro.stats.summary import summarize

    spec = plan.spec
    cells = _values_by_cell(values)
    out_cells: dict[str, dict[str, dict]] = {}
    for (row_id, col), vals in cells.items():
        s = summarize(vals, spec.interval_for(row_id), n_boot=plan.scale.bootstrap_resamples,
                      seed=derive_seed(0, spec.id, row_id, col))
        out_cells.setdefault(row_id, {})[col] = s.to_dict()
    budgets = row_budgets(plan, trainings)
    claims = [with_evidence(plan, cl, _claim(spec, cl, cells, values), budgets)
              for cl in spec.claims]
    out = {"schema": SUMMARY_SCHEMA, "table": spec.id, "cells": out_cells, "claims": claims,
           "budgets": budgets, "budget_factor": plan.budget,
           "rows": {rp.row_id: {"status": rp.status, "reason": rp.reason} for rp in plan.rows},
           "unbuilt_columns": unbuilt_columns(plan)}
    from repro.engine.figures import axis_summary, is_figure

    if is_figure(spec):  # cells are per x ("overall.acc@3"); say which x the run has
        out["x"] = axis_summary(spec, cells)
    return out


def with_evidence(plan: TablePlan, cl, claim: dict, budgets: dict) -> dict:
    """``claim`` with its evidence (variance, budgets of the rows involved, evaluators of its
    columns) and the verdict that evidence allows; the sampler's own verdict is kept as
    ``posterior_verdict``."""
    from repro.engine.evidence import claim_evidence, evaluator_text, qualified_verdict

    evs = []
    for b in plan.bands:
        if b.implemented and set(b.columns) & set(cl.column):
            t = evaluator_text(b.evaluator, getattr(plan, "dataset", None))
            if t and t not in evs:
                evs.append(t)
    ev = claim_evidence(rows=list(cl.involved_rows()), budgets=budgets, retrain=plan.retrain,
                        replicates=len(plan.seeds), evaluators=evs,
                        scale=getattr(plan.scale, "name", None))
    out = {**claim, "evidence": ev, "posterior_verdict": claim["verdict"]}
    out["verdict"] = qualified_verdict(claim["verdict"], ev)
    return out


def unbuilt_columns(plan: TablePlan) -> dict[str, str]:
    """Columns whose protocol is not built yet, with the reason."""
    return {c: b.reason or NOT_IMPLEMENTED for b in plan.bands if not b.implemented for c in b.columns}


def _claim(spec, cl, cells, values: list[dict] | None = None) -> dict:
    """One claim's verdict from the cells (``(row, column) -> replicate values``); a figure's
    claims read its per-x cells (:func:`repro.engine.figures.figure_claim`), with the raw
    ``values`` pairing replicates for the slopes of a trend along x."""
    from repro.engine.comparisons import conjunction, pairs_on
    from repro.engine.figures import figure_claim, is_figure

    if is_figure(spec):
        return figure_claim(spec, cl, cells, values)
    base = {"id": cl.id, "kind": cl.kind, "source": cl.source}
    involved = cl.involved_rows()
    for col in cl.column:
        for r in involved:
            if (r, col) not in cells:
                return {**base, "verdict": "not evaluated", "probability": None,
                        "reason": f"no reproduced values for row {r!r} in column {col!r}"}
    if cl.kind == "trend" and cl.along != "rows":
        return {**base, "verdict": "not evaluated", "probability": None,
                "reason": "a trend along x needs a figure (a table has no x axis)"}
    pairs = []  # (probability, verdict, reason)
    for col in cl.column:
        got = pairs_on(spec, cl, col, col, cells)
        if isinstance(got, str):
            return {**base, "verdict": "not evaluated", "probability": None, "reason": got}
        pairs.extend(got)
    return conjunction(base, pairs)
