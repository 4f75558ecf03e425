"""A table's job graph, its run, the aggregation of raw replicate values and the report view.

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
- ``trend`` along rows is the conjunction of consecutive pairs; trends along a figure's x axis
  are evaluated by the figure protocols (not yet built: "not evaluated").
- ``closer_to_real`` columns compare |value − mean(real)| with "lower" as better.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from repro.engine.job import Job
from repro.report.view import (DATA_UNAVAILABLE, NOT_IMPLEMENTED, NOT_RUN, OK,
                               CellView, ClaimView, ColumnView, RowView, TableView)

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
                "retrain": self.retrain,
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
    try:
        cfg = cls.Config.resolve({**scale.method_config(method), **overrides}, where=method)
    except ConfigError as e:  # a variant the spec names but the method does not offer (yet)
        return None, f"variant not implemented: {e}"
    return cfg.model_dump(mode="json"), None


def parse_seeds(text: str) -> tuple[int, ...]:
    """``"0-4"`` → (0, 1, 2, 3, 4); ``"0,3,7"`` → (0, 3, 7) (``--seeds``)."""
    from repro.errors import ConfigError

    try:
        out: list[int] = []
        for part in text.split(","):
            a, sep, b = part.strip().partition("-")
            out.extend(range(int(a), int(b) + 1) if sep else [int(a)])
    except ValueError:
        raise ConfigError(f"--seeds {text!r}: give seeds as '0-4' or '0,3,7'") from None
    if not out or len(set(out)) != len(out) or min(out) < 0:
        raise ConfigError(f"--seeds {text!r}: seeds must be distinct non-negative integers")
    return tuple(out)


def build_plan(spec, scale, dataset: str | None = None, seeds: tuple[int, ...] | None = None,
               retrain: bool = False) -> TablePlan:
    """Everything a run of ``spec`` at ``scale`` would do (no training; the data set is only
    opened, memory-mapped, for the fingerprint of the evaluator's training split).

    A replicate is a sampling pass of one trained model per row; with ``retrain`` each
    replicate also trains its own model (training seed = the replicate's seed), so the
    intervals include training-seed variance, at R times the training cost."""
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
    for b in bands:
        if not is_implemented(b.protocol):
            b.reason = f"protocol {b.protocol!r} is not implemented yet"
            continue
        proto = get_protocol(b.protocol, b.params)
        b.implemented = True
        b.params = proto.params.describe()  # resolved defaults, as the steps get them back
        b.version = proto.version
        b.module = type(proto).__module__
        b.evaluator = {"dataset": dataset, "kind": proto.evaluator_kind, "scale": scale.name,
                       "seed": 0}
        if fp is not None:
            from repro.engine.steps import clipset, evaluator_clipset

            clips = clips or clipset(dataset)
            b.evaluator_key = evaluator_key(proto.evaluator_kind, settings,
                                            evaluator_clipset(proto, clips).fingerprint, 0)
    plan = TablePlan(spec, scale, dataset, fp, missing, seeds, bands, [], retrain=bool(retrain))
    job = partial(Job, threads=scale.threads)  # every table job computes with the profile's count
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
            method_module = generator_class(row.method).__module__
        for bi, b in enumerate(bands):
            if not b.implemented:
                continue
            base = b.step_config(dataset)
            fps = {"dataset": fp}
            if row.method == "real":
                rp.measures[bi] = [
                    job("measure_real", f"{STEPS}:measure_real",
                        {**base, "replicate": r, "evaluator": b.evaluator},
                        seed=s, fingerprints={**fps, "evaluator": b.evaluator_key},
                        label=f"{row.id}/real/r{r}", plugins=(b.module,))
                    for r, s in enumerate(seeds)]
                continue
            def train_job(seed):
                return job("train", f"{STEPS}:train_method",
                           {**base, "method": row.method, "method_config": mcfg},
                           seed=seed, fingerprints=fps,
                           label=f"{row.method}/train"
                           + ("" if seed == seeds[0] else f"/s{seed}"),
                           plugins=(method_module, b.module))

            # one model per row (its seed = the first replicate seed), or with ``retrain`` one
            # per replicate (seed = the replicate's): the first is the same job either way
            trains = [train_job(s) for s in (seeds if retrain else seeds[:1])]
            rp.train[bi] = trains
            ms = []
            for r, s in enumerate(seeds):
                gen = job("generate", f"{STEPS}:generate",
                          {**base, "replicate": r, "need": sorted(set(b.metrics.values()))},
                          inputs=(trains[r if retrain else 0],), seed=s, fingerprints=fps,
                          label=f"{row.method}/generate/r{r}",
                          plugins=(method_module, b.module))
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
    ``reports`` maps row id -> that row's execution report."""
    from repro.engine.steps import read_values

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
                    v = vals.get(band.metrics[col])
                    if v is None and band.metrics[col] not in vals:
                        continue  # the protocol does not measure this column for this row
                    out.append({"row": rp.row_id, "column": col, "replicate": r,
                                "seed": job.seed, "value": v, "metric": band.metrics[col],
                                "job": job.key()})
    return out


def _values_by_cell(values: list[dict]) -> dict[tuple[str, str], list[float]]:
    cells: dict[tuple[str, str], list[float]] = {}
    for v in sorted(values, key=lambda d: (d["row"], d["column"], d["replicate"])):
        if v["value"] is not None and math.isfinite(v["value"]):
            cells.setdefault((v["row"], v["column"]), []).append(float(v["value"]))
    return cells


def summarise(plan: TablePlan, values: list[dict]) -> dict:
    """summary.json: per-cell statistics and per-claim verdicts, from raw values only."""
    from repro.seeding import derive_seed
    from repro.stats.summary import summarize

    spec = plan.spec
    cells = _values_by_cell(values)
    out_cells: dict[str, dict[str, dict]] = {}
    for (row_id, col), vals in cells.items():
        s = summarize(vals, spec.interval_for(row_id), n_boot=plan.scale.bootstrap_resamples,
                      seed=derive_seed(0, spec.id, row_id, col))
        out_cells.setdefault(row_id, {})[col] = s.to_dict()
    claims = [_claim(spec, cl, cells) for cl in spec.claims]
    return {"schema": SUMMARY_SCHEMA, "table": spec.id, "cells": out_cells, "claims": claims,
            "rows": {rp.row_id: {"status": rp.status, "reason": rp.reason} for rp in plan.rows},
            "unbuilt_columns": unbuilt_columns(plan)}


def unbuilt_columns(plan: TablePlan) -> dict[str, str]:
    """Columns whose protocol is not built yet, with the reason."""
    return {c: b.reason or NOT_IMPLEMENTED for b in plan.bands if not b.implemented for c in b.columns}


def _claim(spec, cl, cells) -> dict:
    from repro.stats.claims import claim_probability

    base = {"id": cl.id, "kind": cl.kind, "source": cl.source}
    involved = cl.involved_rows()
    for col in cl.column:
        for r in involved:
            if (r, col) not in cells:
                return {**base, "verdict": "not evaluated", "probability": None,
                        "reason": f"no reproduced values for row {r!r} in column {col!r}"}
    if cl.kind == "trend" and cl.along != "rows":
        return {**base, "verdict": "not evaluated", "probability": None,
                "reason": "trends along a figure's x axis are not evaluated yet"}
    seed = 0
    pairs = []  # (probability, verdict, reason)
    for col in cl.column:
        column = spec.column(col)
        direction = cl.direction or column.direction

        def vals(row_id, col=col, column=column, direction=direction):
            v = cells[(row_id, col)]
            if direction == "closer_to_real":
                ref = spec.reference_row(col)
                if ref is None or (ref, col) not in cells:
                    return None
                m = sum(cells[(ref, col)]) / len(cells[(ref, col)])
                return [abs(x - m) for x in v]
            return v

        d = "lower" if direction in ("lower", "closer_to_real", "decreasing") else "higher"
        if cl.kind == "order":
            comps = [(cl.better, other) for other in cl.than]
        elif cl.kind == "gap":
            comps = [(cl.a, cl.b)]
        else:  # trend along rows: consecutive rows follow the direction
            comps = list(zip(cl.rows[1:], cl.rows[:-1]))
        for a, b in comps:
            va, vb = vals(a), vals(b)
            if va is None or vb is None:
                return {**base, "verdict": "not evaluated", "probability": None,
                        "reason": f"no reference row for closer-to-real column {col!r}"}
            delta = float(cl.delta or 0.0)
            if cl.kind == "gap" and cl.bound == "within":
                hi = claim_probability(va, vb, "higher", delta, seed=seed)
                lo = claim_probability(va, vb, "lower", delta, seed=seed)
                p = 1.0 - hi.probability - lo.probability
                from repro.stats.claims import verdict as vd

                pairs.append((p, vd(p), hi.reason or lo.reason))
            else:
                res = claim_probability(va, vb, d, delta if cl.kind == "gap" else 0.0, seed=seed)
                pairs.append((res.probability, res.verdict, res.reason))
    ps = [p for p, _, _ in pairs]
    verdicts = [v for _, v, _ in pairs]
    if "contradicted" in verdicts:
        verdict = "contradicted"
    elif all(v == "supported" for v in verdicts):
        verdict = "supported"
    else:
        verdict = "inconclusive"
    finite = [p for p in ps if p is not None and math.isfinite(p)]
    reasons = sorted({r for _, _, r in pairs if r})
    return {**base, "verdict": verdict, "probability": min(finite) if finite else None,
            "pairwise": ps, "reason": "; ".join(reasons) or None}


# ---------------------------------------------------------------------------------------------
# the view


def _claim_text(spec, cl) -> str:
    cols = ", ".join(cl.column)
    if cl.kind == "order":
        return f"{cl.better} better than {', '.join(cl.than)} on {cols}"
    if cl.kind == "gap":
        rel = "within" if cl.bound == "within" else "ahead by at least"
        return f"{cl.a} vs {cl.b} on {cols}: {rel} {cl.delta}"
    return f"{', '.join(cl.rows)}: {cl.direction} on {cols}"


def make_view(spec, plan_rows: dict[str, dict], summary: dict | None, footer: list[str],
              dataset: str | None, unbuilt: dict[str, str] | None = None) -> TableView:
    """The reported-vs-reproduced view from a spec and (optionally) a run's summary;
    ``unbuilt`` names the columns whose protocol is not built (they read "not implemented")."""
    from repro.specs import names

    cells = (summary or {}).get("cells", {})
    unbuilt = (summary or {}).get("unbuilt_columns", {}) if unbuilt is None else unbuilt
    cols = []
    for c in spec.columns:
        g = spec.group_of(c.id)
        label = f"{g.label}: {c.label}" if g is not None else c.label
        cols.append(ColumnView(c.id, label, c.direction or "", c.unit or ""))
    rows = []
    for row in spec.rows:
        st = plan_rows.get(row.id, {}).get("status", NOT_RUN)
        reason = plan_rows.get(row.id, {}).get("reason")
        rv = RowView(row.id, row.label, row.method, st, note=reason)
        for c in spec.columns:
            rep = row.reported.get(c.id)
            printed = rep.printed if rep is not None else None
            got = cells.get(row.id, {}).get(c.id)
            if got is not None:
                ci = got.get("bootstrap_percentile")
                rv.cells[c.id] = CellView(printed, got["mean"], got.get("paper_halfwidth"),
                                          tuple(ci) if ci and None not in ci else None,
                                          got["n"], OK)
            else:
                if st != OK and st != NOT_RUN:
                    cst = st
                elif c.id in unbuilt:
                    cst = NOT_IMPLEMENTED
                else:
                    cst = "not measured" if summary else NOT_RUN
                rv.cells[c.id] = CellView(printed, status=cst)
        rows.append(rv)
    claims = []
    by_id = {c["id"]: c for c in (summary or {}).get("claims", [])}
    for cl in spec.claims:
        got = by_id.get(cl.id)
        claims.append(ClaimView(cl.id, _claim_text(spec, cl), cl.source,
                                None if got is None else got.get("probability"),
                                "not evaluated" if got is None else got["verdict"],
                                None if got is None else got.get("reason")))
    standin = None
    if dataset is not None and names.DATASETS[dataset].standin:
        standin = dataset
    return TableView(spec.id, spec.title, names.PAPERS[spec.paper.key].title if hasattr(
        names, "PAPERS") and spec.paper.key in names.PAPERS else spec.paper.title,
        cols, rows, claims, footer, standin, spec.interval)
