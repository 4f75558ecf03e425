"""``repro sweep``: one table rerun along one axis, every cell and claim read against it
(issue 11, items 2 and 4).

Two axes:

- ``budget``: every method's epoch counts × a factor (:func:`repro.engine.evidence.scale_epochs`;
  scheduled-sampling epochs and warm-restart periods scale with them).  The evaluators and the
  test items do not change, so a cell's movement is the models'.  Each claim's posterior
  verdicts (the sampler's, before the budget qualifies them) along the factors are classed
  **stable** (one verdict throughout), **converging** (the verdict changes once and keeps its
  last value at the largest budgets, e.g. inconclusive → supported) or **flipping** (it
  changes more than once).  A ``plateau`` point (``--budget 1,2,4,plateau``; issue 32) trains
  every method until its convergence rule fires (:mod:`repro.train.plateau`, the profile's
  ``[plateau]`` settings) with the largest factor's epochs as the cap, so it costs at most that
  point's training; it comes last on the axis, and its verdicts read "at convergence" where
  every training involved reached its plateau.
- ``evaluator_seed``: the same trained models, scored by evaluators trained with other seeds
  (the protocol's evaluator architecture and data; only its seed differs).  On the
  single-action tables the samples are the same too; on the multi-action ones the evaluator
  also picks the test set (candidate confidence) and drives Action Revision, so there a
  cell's spread mixes the evaluator with the test set.  Each cell gets its spread across
  evaluators (range and sd of the per-evaluator means); each claim either **holds under all**
  evaluators (one verdict) or **depends on the evaluator**.

Each point is an ordinary run (its own run record; cached jobs are reused: the ×1 point and the
seed-0 point are the plain run), and the sweep writes ``sweep.json`` (schema 1) with the run
ids, per point the cell means and intervals, claim verdicts, probabilities and budgets.
"""

from __future__ import annotations

import json
import math
import statistics
from pathlib import Path
from typing import Any

SWEEP_SCHEMA = 1
AXES = ("budget", "evaluator_seed")
#: the budget axis's point that trains until the plateau (after every factor)
PLATEAU = "plateau"


def parse_factors(text: str) -> tuple:
    """``"0.5,1,2,4"`` → (0.5, 1.0, 2.0, 4.0): distinct, positive, at most 12; the word
    ``plateau`` adds the plateau point (module docstring), last."""
    from repro.errors import ConfigError

    shown = text if len(text) <= 40 else text[:37] + "..."
    words = [x.strip() for x in text.split(",") if x.strip()]
    plateau = words.count(PLATEAU)
    try:
        out = tuple(float(x) for x in words if x != PLATEAU)
    except ValueError:
        raise ConfigError(f"--budget {shown!r}: give factors as '0.5,1,2,4' (and 'plateau' "
                          "for a point trained until the plateau)") from None
    if plateau > 1 or not (out or plateau) or len(out) + plateau > 12 or \
            len(set(out)) != len(out) or not all(math.isfinite(x) and x > 0 for x in out):
        raise ConfigError(f"--budget {shown!r}: 1 to 12 distinct positive factors "
                          "(or 'plateau' once)")
    return out + ((PLATEAU,) if plateau else ())


def _ordered(points: list) -> list:
    """The axis in order: numbers ascending, the plateau point last."""
    return sorted(p for p in points if p != PLATEAU) + [p for p in points if p == PLATEAU]


def classify_budget(verdicts: list[str]) -> str:
    """stable / converging / flipping (module docstring)."""
    changes = sum(1 for a, b in zip(verdicts, verdicts[1:]) if a != b)
    if changes == 0:
        return "stable"
    return "converging" if changes == 1 else "flipping"


def sweep_table(name: str, *, axis: str, points: list, scale: str = "quick",
                dataset: str | None = None, jobs: int = 1, progress: bool = True,
                seeds: tuple[int, ...] | None = None, retrain: bool = False,
                lines: bool = False, gate_margin: float | None = None,
                no_gate: bool = False) -> dict:
    """Run ``name`` once per point of ``axis`` and return the sweep record (also written to
    ``REPRO_HOME/sweeps/<id>/sweep.json``); ``lines``, ``gate_margin``, ``no_gate``: as
    :func:`repro.engine.runner.run_tables` (each point's run records its gate)."""
    from repro.engine.runner import run_table
    from repro.errors import ConfigError
    from repro.specs.scales import until_override

    if axis not in AXES:
        raise ConfigError(f"sweep axis must be one of {', '.join(AXES)}, got {axis!r}")
    points = _ordered(points)
    cap = max([float(p) for p in points if p != PLATEAU] or [1.0])
    runs = []
    for pt in points:
        if axis != "budget":
            kw = {"evaluator_seed": int(pt)}
        else:
            kw = {"budget": cap if pt == PLATEAU else float(pt)}
        with until_override(PLATEAU if pt == PLATEAU else None):
            plan, summary, run_id = run_table(name, scale=scale, dataset=dataset, jobs=jobs,
                                              progress=progress, seeds=seeds, retrain=retrain,
                                              lines=lines, gate_margin=gate_margin,
                                              no_gate=no_gate, **kw)
        runs.append((pt, plan, summary, run_id))
    record = build_record(axis, runs)
    write_record(record)
    return record


def build_record(axis: str, runs: list[tuple[Any, Any, dict, str]]) -> dict:
    """The sweep record from (point, plan, summary, run id) per point (module docstring)."""
    plan0 = runs[0][1]
    spec = plan0.spec
    cells: dict[str, dict[str, list]] = {}
    claims: dict[str, dict[str, list]] = {}
    for i, (_, _, summary, _) in enumerate(runs):
        for row, cols in summary.get("cells", {}).items():
            for col, c in cols.items():
                slot = cells.setdefault(row, {}).setdefault(col, [None] * len(runs))
                slot[i] = {"mean": c.get("mean"), "ci": c.get("bootstrap_percentile"),
                           "n": c.get("n")}
        for cl in summary.get("claims", []):
            slot = claims.setdefault(cl["id"], {"verdict": [None] * len(runs),
                                                "probability": [None] * len(runs),
                                                "posterior_verdict": [None] * len(runs)})
            slot["verdict"][i] = cl.get("verdict")
            slot["probability"][i] = cl.get("probability")
            slot["posterior_verdict"][i] = cl.get("posterior_verdict", cl.get("verdict"))
    for cid, c in claims.items():
        # classed on the sampler's verdicts: the printed ones are qualified by the budget
        # itself ("not reproduced at this budget" turns into another wording at ×1 of the
        # paper's), which would look like movement where the evidence did not move
        vs = [v or "not evaluated" for v in c["posterior_verdict"]]
        if axis == "budget":
            c["along_budget"] = classify_budget(vs)
        else:
            c["under_evaluators"] = ("holds under all" if len(set(vs)) == 1
                                     else "depends on the evaluator")
    if axis == "evaluator_seed":
        for row, cols in cells.items():
            for col, pts in cols.items():
                means = [p["mean"] for p in pts if p and p.get("mean") is not None]
                if len(means) >= 2:
                    cols[col] = {"points": pts, "range": max(means) - min(means),
                                 "sd": statistics.stdev(means)}
                else:
                    cols[col] = {"points": pts, "range": None, "sd": None}
    budgets = [s.get("budgets", {}) for _, _, s, _ in runs]
    return {"schema": SWEEP_SCHEMA, "table": spec.id, "spec_version": spec.version,
            "scale": plan0.scale.name, "dataset": plan0.dataset, "axis": axis,
            "points": [p for p, *_ in runs], "runs": [r for *_, r in runs],
            "retrain": plan0.retrain, "replicates": len(plan0.seeds),
            "cells": cells, "claims": claims, "budgets": budgets,
            "claim_text": {cl.id: _text(spec, cl) for cl in spec.claims},
            "row_labels": {r.id: r.label for r in spec.rows}}


def _text(spec, cl) -> str:
    from repro.engine.table_view import claim_text

    return claim_text(spec, cl)


def write_record(record: dict) -> Path:
    """``REPRO_HOME/sweeps/<first run id>-<axis>/sweep.json`` (atomic)."""
    from repro.paths import repro_home
    from repro.store.atomic import atomic_write_bytes

    d = repro_home() / "sweeps" / f"{record['runs'][0]}-{record['axis']}"
    d.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(d / "sweep.json", json.dumps(record, indent=1, sort_keys=True).encode())
    record["path"] = str(d)
    return d


def _fmt(x) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{x:.2e}" if x != 0 and (abs(x) >= 1e4 or abs(x) < 1e-3) else f"{x:.3f}"


def _point_label(axis: str, p, cap: float | None = None) -> str:
    if p == PLATEAU:
        return "plateau" + ("" if cap is None else f" (cap ×{cap:g})")
    return f"×{p:g}" if axis == "budget" else f"seed {p}"


def render_sweep(record: dict, fmt: str = "md") -> str:
    """The sweep as Markdown (``md``) or plain text (``term``): cells against the axis, then
    each claim's verdict per point with its class (module docstring), then the budgets."""
    axis = record["axis"]
    nums = [p for p in record["points"] if p != PLATEAU]
    cap = max(nums) if nums else 1.0
    heads = [_point_label(axis, p, cap) for p in record["points"]]
    extra = ["range", "sd"] if axis == "evaluator_seed" else []
    lines = [f"{record['table']}: sweep over "
             f"{'training budget (epochs × factor)' if axis == 'budget' else 'evaluator seed'} "
             f"at scale {record['scale']} on {record['dataset']} "
             f"({record['replicates']} replicates per point; runs {', '.join(record['runs'])})", ""]
    lines.append("| row | column | " + " | ".join(heads + extra) + " |")
    lines.append("|" + "---|" * (2 + len(heads) + len(extra)))
    for row, cols in record["cells"].items():
        for col, val in sorted(cols.items()):
            pts = val["points"] if isinstance(val, dict) and "points" in val else val
            cellv = []
            for p in pts:
                if not p or p.get("mean") is None:
                    cellv.append("-")
                    continue
                ci = p.get("ci")
                cellv.append(_fmt(p["mean"]) + (f" [{_fmt(ci[0])}, {_fmt(ci[1])}]"
                                                if ci and None not in ci else ""))
            if extra:
                cellv += [_fmt(val.get("range")), _fmt(val.get("sd"))]
            lines.append(f"| {row} | {col} | " + " | ".join(cellv) + " |")
    lines += ["", "| claim | " + " | ".join(heads) + " | " +
              ("along budget" if axis == "budget" else "under evaluators") + " |",
              "|" + "---|" * (2 + len(heads))]
    for cid, c in record["claims"].items():
        vs = []
        for v, pv, p in zip(c["verdict"], c["posterior_verdict"], c["probability"]):
            shown = v or "not evaluated"
            if pv and pv != shown:
                shown += f" (posterior: {pv})"
            vs.append(shown + ("" if p is None else f", P = {p:.3f}"))
        cls = c.get("along_budget") or c.get("under_evaluators")
        lines.append(f"| {cid}: {record['claim_text'].get(cid, '')} | " + " | ".join(vs)
                     + f" | {cls} |")
    if axis == "budget":
        lines += ["", "Budget against the paper's schedule on this data, per point:"]
        from repro.engine.evidence import budgets_text

        for p, b in zip(record["points"], record["budgets"]):
            lines.append(f"- {_point_label(axis, p, cap)}: "
                         + (budgets_text((b or {}).values()) or "-"))
    return "\n".join(lines) + "\n"
