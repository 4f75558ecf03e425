"""Figures: per-x cells, claims along a figure's x axis, and the figure's view.

Convention (the figure protocols emit it): besides its plain metric ids (``"acc"``, an
average), a measure job's values hold the curve of each metric under ``f"{metric}@{x}"`` with
an integer x on the figure's axis (``"acc@1"``, ``"acc@2"``, … the 1-based action index).  A
run may cover fewer x than the spec's ``[x]`` (the quick scale generates 6 actions of the
paper's 20): the x present within ``[x.start, x.stop]`` are used, and every claim says which.

Aggregation (:func:`repro.engine.tables.collect_values`): one raw value per (row, column,
replicate, x), with the column id ``f"{column}@{x}"`` (:func:`repro.report.view.x_cell_id`), so
a summary cell is ``cells[row]["overall.acc@3"]``, each x point with its own interval; the plain
averages are not recorded for a figure.

Claims (docs/specs.md, "Claims on figures"):

- ``order`` / ``gap`` / ``trend`` along rows: the table's pairwise comparisons at every x of
  ``x_range`` (the whole axis when absent) that the run reproduced for every row involved, and
  on every column; the conjunction of all of them (supported only when every comparison is,
  contradicted when any is), P = the smallest pairwise P.
- ``trend`` along x: per row, column and replicate the least-squares slope of the value against
  x over the x in range; per row and column P(mean slope < 0) ("decreasing"), P(> 0)
  ("increasing") or P(|mean slope| · (x_hi − x_lo) <= δ) ("stable": the fitted line's change
  across the x present stays within δ), from the Student-t posterior of the mean of the
  replicate slopes (:func:`repro.stats.claims.mean_probability`); the conjunction over rows and
  columns, P = the smallest.
- A range that holds no reproduced x is "not evaluated", saying where the run's axis stops.
"""

from __future__ import annotations

import math
import re
from typing import Any

from repro.report.view import (NOT_IMPLEMENTED, NOT_RUN, OK, AxisView,
                               CellView, ColumnView, FigureView, RowView, X_SEP, format_xs,
                               x_cell_id)

NOT_EVALUATED = "not evaluated"
_INT = re.compile(r"-?\d+")
_TREND = {"decreasing": "lower", "increasing": "higher", "stable": "within"}

__all__ = ["is_figure", "per_x_values", "split_cell_id", "axis_summary", "figure_claim",
           "figure_view", "x_cell_id"]


def is_figure(spec) -> bool:
    return getattr(spec, "kind", "table") == "figure" and getattr(spec, "x", None) is not None


def per_x_values(values: dict[str, Any], metric: str, start: int,
                 stop: int) -> list[tuple[int, Any]]:
    """``[(x, value), ...]`` of ``metric``'s ``metric@x`` entries with start <= x <= stop,
    in x order (keys whose tail is not an integer are ignored)."""
    prefix = metric + X_SEP
    out = []
    for k, v in values.items():
        if not k.startswith(prefix):
            continue
        tail = k[len(prefix):]
        if not _INT.fullmatch(tail):
            continue
        x = int(tail)
        if start <= x <= stop:
            out.append((x, v))
    return sorted(out, key=lambda t: t[0])


def split_cell_id(cell: str) -> tuple[str, int | None]:
    """``"overall.acc@3"`` → ``("overall.acc", 3)``; a table's ``"acc"`` → ``("acc", None)``."""
    col, sep, tail = cell.rpartition(X_SEP)
    if sep and _INT.fullmatch(tail):
        return col, int(tail)
    return cell, None


def _xs_of(cells, row: str, col: str) -> set[int]:
    out = set()
    for (r, cid) in cells:
        if r != row:
            continue
        c, x = split_cell_id(cid)
        if c == col and x is not None:
            out.add(x)
    return out


def axis_summary(spec, cells) -> dict:
    """summary.json's ``x`` of a figure: the spec's axis and the x reproduced in any cell."""
    present = sorted({x for (_, cid) in cells for x in [split_cell_id(cid)[1]]
                      if x is not None and spec.x.start <= x <= spec.x.stop})
    return {"id": spec.x.id, "label": spec.x.label, "start": spec.x.start, "stop": spec.x.stop,
            "present": present}


# ---------------------------------------------------------------------------------------------
# claims


def claim_range(spec, cl) -> tuple[int, int]:
    return (int(cl.x_range[0]), int(cl.x_range[1])) if cl.x_range else (spec.x.start, spec.x.stop)


def _out_of_range(lo: int, hi: int, xs: list[int]) -> str:
    if not xs:
        return "no x is reproduced for every row the claim involves"
    if max(xs) < lo:
        return (f"x_range {lo}..{hi} holds no reproduced x: the run's axis stops at {max(xs)} "
                f"(x {format_xs(xs)} reproduced)")
    return f"x_range {lo}..{hi} holds no reproduced x (x {format_xs(xs)} reproduced)"


def _coverage(lo: int, hi: int, xs_by_col: dict[str, list[int]], counts: set[int],
              whole_axis: bool = False) -> str:
    """"x 1..6 present of x_range 1..8 (the run's axis stops at 6); 3 replicates each"."""
    distinct = {tuple(v) for v in xs_by_col.values()}
    if len(distinct) == 1:
        xs = next(iter(distinct))
        what = f"x {format_xs(xs)} present"
    else:
        xs = tuple(sorted({x for v in xs_by_col.values() for x in v}))
        what = "; ".join(f"{c}: x {format_xs(v)} present" for c, v in xs_by_col.items())
    if list(xs) != list(range(lo, hi + 1)):
        what += f" of the axis {lo}..{hi}" if whole_axis else f" of x_range {lo}..{hi}"
        if max(xs) < hi:
            what += f" (the run's axis stops at {max(xs)})"
    if counts:
        n = (f"{min(counts)} replicates each" if len(counts) == 1
             else f"{min(counts)}-{max(counts)} replicates per cell")
        what += f"; {n}"
    return what


def _rows_needed(spec, cl, col: str) -> list[str]:
    rows = list(dict.fromkeys(cl.involved_rows()))
    if not (cl.kind == "trend" and cl.along == "x"):
        direction = cl.direction or spec.column(col).direction
        ref = spec.reference_row(col) if direction == "closer_to_real" else None
        if ref is not None and ref not in rows:
            rows.append(ref)
    return rows


def figure_claim(spec, cl, cells: dict[tuple[str, str], list[float]],
                 values: list[dict] | None = None) -> dict:
    """A claim's verdict on a figure's per-x cells (module docstring); ``values`` (the raw
    records) pair each replicate's points for the slopes of a trend along x."""
    from repro.engine.comparisons import conjunction, pairs_on

    base = {"id": cl.id, "kind": cl.kind, "source": cl.source}

    def not_evaluated(reason: str) -> dict:
        return {**base, "verdict": NOT_EVALUATED, "probability": None, "reason": reason}

    lo, hi = claim_range(spec, cl)
    along_x = cl.kind == "trend" and cl.along == "x"
    xs_by_col: dict[str, list[int]] = {}
    for col in cl.column:
        common: set[int] | None = None
        for r in _rows_needed(spec, cl, col):
            xs = _xs_of(cells, r, col)
            if not xs:
                return not_evaluated(f"no reproduced values for row {r!r} in column {col!r}")
            common = xs if common is None else common & xs
        everywhere = sorted(common or ())
        in_range = [x for x in everywhere if lo <= x <= hi]
        if not in_range:
            return not_evaluated(f"{col}: {_out_of_range(lo, hi, everywhere)}")
        if along_x and len(in_range) < 2:
            return not_evaluated(f"{col}: only x {in_range[0]} of x_range {lo}..{hi} reproduced; "
                                 "a slope needs two")
        xs_by_col[col] = in_range
    if along_x:
        return _trend_along_x(spec, cl, cells, values, xs_by_col, lo, hi, base)
    pairs = []
    counts = set()
    for col, xs in xs_by_col.items():
        for x in xs:
            key = x_cell_id(col, x)
            counts |= {len(cells[(r, key)]) for r in _rows_needed(spec, cl, col)}
            got = pairs_on(spec, cl, col, key, cells)
            if isinstance(got, str):
                return not_evaluated(f"x {x}: {got}")
            pairs.extend(got)
    out = conjunction(base, pairs, lead=_coverage(lo, hi, xs_by_col, counts, cl.x_range is None))
    out["x"] = sorted({x for v in xs_by_col.values() for x in v})
    return out


def _by_replicate(values: list[dict]) -> dict[tuple[str, str], dict[int, float]]:
    out: dict[tuple[str, str], dict[int, float]] = {}
    for v in values:
        val = v.get("value")
        if val is None or not math.isfinite(val):
            continue
        out.setdefault((v["row"], v["column"]), {})[int(v["replicate"])] = float(val)
    return out


def _curves(row: str, col: str, xs: list[int], cells, by_rep) -> tuple[list[list[float]], int]:
    """Each replicate's values at ``xs`` (only replicates with a value at every x), and how
    many replicates were left out for a missing point."""
    keys = [x_cell_id(col, x) for x in xs]
    if by_rep is None:  # no raw records: the cells' lists, in replicate order
        lists = [cells[(row, k)] for k in keys]
        n = min(len(v) for v in lists)
        return [[v[i] for v in lists] for i in range(n)], max(len(v) for v in lists) - n
    per_x = [by_rep.get((row, k), {}) for k in keys]
    reps = set(per_x[0]).intersection(*per_x[1:])
    seen = set().union(*per_x)
    return [[p[r] for p in per_x] for r in sorted(reps)], len(seen - reps)


def slope(xs: list[int], ys: list[float]) -> float:
    """Least-squares slope of ys against xs (at least two distinct xs)."""
    mx = sum(xs) / len(xs)
    my = sum(ys) / len(ys)
    sxx = sum((x - mx) ** 2 for x in xs)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sxx


def _trend_along_x(spec, cl, cells, values, xs_by_col, lo, hi, base) -> dict:
    from repro.engine.comparisons import conjunction
    from repro.stats.claims import mean_probability

    direction = _TREND[cl.direction]
    by_rep = _by_replicate(values) if values is not None else None
    results = []  # (probability, verdict, reason)
    slopes: dict[str, float] = {}
    counts: set[int] = set()
    notes = set()
    for col, xs in xs_by_col.items():
        span = xs[-1] - xs[0]
        delta = float(cl.delta) / span if direction == "within" else 0.0
        for row in cl.rows:
            curves, dropped = _curves(row, col, xs, cells, by_rep)
            if not curves:
                return {**base, "verdict": NOT_EVALUATED, "probability": None,
                        "reason": f"{row}/{col}: no replicate has a value at every x of "
                                  f"{format_xs(xs)}"}
            s = [slope(xs, c) for c in curves]
            counts.add(len(s))
            if dropped:
                notes.add(f"{row}/{col}: {dropped} replicate(s) left out for a missing x")
            res = mean_probability(s, direction, delta)
            slopes[f"{row}/{col}"] = sum(s) / len(s)
            results.append((res.probability, res.verdict,
                            f"{row}/{col}: {res.reason}" if res.reason else None))
    how = {"lower": "P(mean slope < 0)", "higher": "P(mean slope > 0)",
           "within": f"P(|mean slope|·(x_hi − x_lo) <= {cl.delta})"}[direction]
    lead = (f"{_coverage(lo, hi, xs_by_col, counts, cl.x_range is None)}; "
            "least-squares slope per replicate, "
            f"{how} from its Student-t posterior")
    out = conjunction(base, results, lead=lead, notes=notes)
    out["pairwise"] = [p for p, _, _ in results]
    out["slopes"] = slopes
    out["x"] = sorted({x for v in xs_by_col.values() for x in v})
    return out


# ---------------------------------------------------------------------------------------------
# the view


def column_views(spec) -> list:
    """One ColumnView per spec column, labelled "group: column" inside a column group."""
    cols = []
    for c in spec.columns:
        g = spec.group_of(c.id)
        label = f"{g.label}: {c.label}" if g is not None else c.label
        if getattr(c, "harness", False):  # not in the paper: say so in every format
            label += " (harness)"
        cols.append(ColumnView(c.id, label, c.direction or "", c.unit or ""))
    return cols


def figure_view(spec, plan_rows: dict[str, dict], summary: dict | None, footer: list[str],
                standin: str | None, paper_title: str, unbuilt: dict[str, str],
                claims: list) -> FigureView:
    """A figure's view: per column, each row's cell at every x the run reproduced (within the
    spec's axis); before a run one status cell per row and column."""
    cells = (summary or {}).get("cells", {})
    xs = sorted({x for cols in cells.values() for cid in cols
                 for x in [split_cell_id(cid)[1]]
                 if x is not None and spec.x.start <= x <= spec.x.stop})
    cols = column_views(spec)
    rows = []
    for row in spec.rows:
        st = plan_rows.get(row.id, {}).get("status", NOT_RUN)
        rv = RowView(row.id, row.label, row.method, st,
                     note=plan_rows.get(row.id, {}).get("reason"))
        for c in spec.columns:
            if st not in (OK, NOT_RUN):
                missing = st
            elif c.id in unbuilt:
                missing = NOT_IMPLEMENTED
            else:
                missing = "not measured" if summary else NOT_RUN
            if not xs:
                rv.cells[c.id] = CellView(None, status=missing)
                continue
            for x in xs:
                got = cells.get(row.id, {}).get(x_cell_id(c.id, x))
                if got is None:
                    rv.cells[x_cell_id(c.id, x)] = CellView(None, status=missing)
                    continue
                ci = got.get("bootstrap_percentile")
                rv.cells[x_cell_id(c.id, x)] = CellView(
                    None, got["mean"], got.get("paper_halfwidth"),
                    tuple(ci) if ci and None not in ci else None, got["n"], OK)
        rows.append(rv)
    axis = AxisView(spec.x.id, spec.x.label, spec.x.start, spec.x.stop, xs)
    return FigureView(spec.id, spec.title, paper_title, cols, rows, claims, footer, standin,
                      spec.interval, x=axis)

