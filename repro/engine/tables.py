"""A table's job graph, its run and the aggregation of raw replicate values (the plan is built
by :mod:`repro.engine.table_plan`, the report view is :mod:`repro.engine.table_view`).

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

from repro.engine.table_plan import TablePlan
from repro.report.view import NOT_IMPLEMENTED

SUMMARY_SCHEMA = 1


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


def row_convergence(trainings: list[dict] | None) -> dict[str, dict]:
    """Per trained row, whether its trainings reached their plateau (issue 32): ``trainings``
    (its training jobs), ``plateau_runs`` (how many were trained with ``until = "plateau"``),
    ``converged`` (how many of those the convergence rule stopped), ``epochs`` (the epochs each ran),
    ``stopped_by`` and ``criterion``.  A fixed-epoch training records whether the rule fired
    in its own ``training.json`` but does not count here: the verdicts of fixed budgets keep
    their meaning (:func:`repro.engine.evidence.qualified_verdict`)."""
    out: dict[str, dict] = {}
    for t in trainings or []:
        rec = t.get("training") or {}
        if rec.get("epochs") is None and not rec.get("history"):
            continue  # nothing trained (a retrieval reference)
        conv = rec.get("convergence") or {}
        r = out.setdefault(t["row"], {"trainings": 0, "converged": 0, "plateau_runs": 0,
                                      "epochs": [], "stopped_by": [],
                                      "criterion": conv.get("criterion")})
        until_plateau = rec.get("until") == "plateau"
        r["trainings"] += 1
        r["plateau_runs"] += int(until_plateau)
        r["converged"] += int(until_plateau and bool(conv.get("converged")))
        r["epochs"].append(len(rec.get("history") or []))
        r["stopped_by"].append(conv.get("stopped_by"))
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
    convergence = row_convergence(trainings)
    claims = [with_evidence(plan, cl, _claim(spec, cl, cells, values), budgets, convergence)
              for cl in spec.claims]
    out = {"schema": SUMMARY_SCHEMA, "table": spec.id, "cells": out_cells, "claims": claims,
           "budgets": budgets, "budget_factor": plan.budget,
           "rows": {rp.row_id: {"status": rp.status, "reason": rp.reason} for rp in plan.rows},
           "unbuilt_columns": unbuilt_columns(plan)}
    from repro.engine.figures import axis_summary, is_figure

    if is_figure(spec):  # cells are per x ("overall.acc@3"); say which x the run has
        out["x"] = axis_summary(spec, cells)
    return out


def with_evidence(plan: TablePlan, cl, claim: dict, budgets: dict,
                  convergence: dict | None = None) -> dict:
    """``claim`` with its evidence (variance, budgets and convergence of the rows involved,
    evaluators of its columns) and the verdict that evidence allows; the sampler's own verdict
    is kept as ``posterior_verdict``."""
    from repro.engine.evidence import claim_evidence, evaluator_text, qualified_verdict

    evs = []
    for b in plan.bands:
        if b.implemented and set(b.columns) & set(cl.column):
            t = evaluator_text(b.evaluator, plan.dataset)
            if t and t not in evs:
                evs.append(t)
    ev = claim_evidence(rows=list(cl.involved_rows()), budgets=budgets, retrain=plan.retrain,
                        replicates=len(plan.seeds), evaluators=evs,
                        scale=getattr(plan.scale, "name", None), convergence=convergence,
                        dataset=plan.dataset)
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
