"""Figures, tables and learning curves as PNG plots (matplotlib, Agg, no display).

:func:`figure_plot` draws a :class:`~repro.report.view.FigureView` the way the papers draw
their curves: Neural Marionette Fig. 8 plots each metric (Recognition Accuracy, FID, Action QR,
Motion QR) over the action index, the overall test set as solid lines ("-O") and the sufficient
set as dashed lines ("-S"); Fig. 10 plots Action QR and Motion QR of the variants side by side.
Here a column ``group.metric`` goes to the panel of ``metric``; the first group of a panel is
drawn solid with circles, the second dashed with squares (then dotted / dash-dot); a column id
without a group prefix gets its own panel.  Each row has one colour (fixed palette, row order),
our mean as the line and our interval (``ci``) as a translucent band.  Cells whose status is
not "ok" or whose value is None are gaps.  :func:`table_plot` shows a plain table as one
dot-and-whisker panel per column, :func:`learning_curve_plot` a run's training histories.

The paper's values: a figure prints none (``reported`` is None), but every cell whose
``reported`` text starts with a number (``"0.92±0.01"`` → 0.92; ``"-"``, ``"/"``, words and
values marked ``?`` are skipped) is overlaid as a black ``x`` labelled "paper".

Every function also writes the plotted data (``data_path``: ``.csv`` or ``.json``, one record
per drawn cell) and returns a small dict of what it drew (panels, series, points).

Determinism: the same input gives the same PNG bytes.  No pyplot (no global figure state): a
:class:`~matplotlib.figure.Figure` on a :class:`~matplotlib.backends.backend_agg.FigureCanvasAgg`;
rcParams are matplotlib's defaults plus :data:`RC` (bundled DejaVu Sans, fixed sizes) inside a
style context, so a user's matplotlibrc changes nothing; the layout is fixed in inches (no
"best" legend placement, no tight/constrained layout); the PNG carries no Software/time tag.
"""

from __future__ import annotations

import csv
import functools
import io
import json
import math
import os.path
import re
import textwrap
from pathlib import Path

import matplotlib.style
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator

from repro.report.view import (OK, AxisView, CellView, ClaimView, ColumnView, FigureView,
                               RowView, TableView, format_xs, x_cell_id)

#: one colour per row, in row order (Okabe-Ito first); black is kept for the paper's values
PALETTE = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#7F7F7F",
           "#8C564B", "#332288", "#999933")
#: (line style, marker) of the 1st, 2nd, ... group in a panel (Fig. 8: -O solid, -S dashed)
GROUP_STYLES = (("-", "o"), ("--", "s"), (":", "^"), ("-.", "D"))
RC = {"font.family": "DejaVu Sans", "font.size": 9, "axes.titlesize": 10,
      "axes.labelsize": 9, "legend.fontsize": 8, "xtick.labelsize": 8, "ytick.labelsize": 8,
      "axes.grid": True, "grid.alpha": 0.3, "grid.linewidth": 0.6, "svg.hashsalt": "repro",
      "path.simplify": False, "lines.linewidth": 1.5, "lines.markersize": 4}
STANDIN_COLOUR = "#B00020"
GREY = "#555555"
PANEL_W, PANEL_H = 4.0, 2.9  # inches per panel
DATA_FIELDS = ("row", "row_label", "column", "column_label", "x", "value", "ci_lo", "ci_hi",
               "n", "status", "reported", "paper")
CURVE_FIELDS = ("training", "row", "method", "seed", "quantity", "epoch", "value")
#: learning-curve panels: (history key, title); ``val_<key>`` is drawn dashed beside it
CURVE_PANELS = (("loss", "loss"), ("rec1", "rec1 (first-pass reconstruction)"),
                ("mpjpe", "MPJPE"), ("ss_active", "scheduled sampling active (share)"))
_NUM = re.compile(r"\s*([-+−]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][-+]?\d+)?)")


def paper_number(reported) -> float | None:
    """The leading number of a paper cell (``"0.92±0.01"`` → 0.92), None when there is none
    or the value is marked uncertain (``?``)."""
    m = None if reported is None or "?" in str(reported) else _NUM.match(str(reported))
    return float(m.group(1).replace("−", "-")) if m else None


def _finite(v) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def _nan(values) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], dtype=float)


def _short(label: str) -> str:
    """A column label without its "group: " prefix (``"Overall (-O): Acc-O"`` → ``"Acc-O"``)."""
    return label.split(": ", 1)[-1]


def _arrow(direction: str, label: str) -> str:
    return "" if any(a in label for a in "↓↑") else {"lower": " ↓", "higher": " ↑"}.get(
        direction, "")


def _styled(fn):
    """Run ``fn`` under matplotlib's default style plus :data:`RC` (restored afterwards)."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with matplotlib.style.context(["default", RC]):
            return fn(*args, **kwargs)
    return wrapper


def _header(lines: list[tuple[str, dict]], w: float, h_below: float, dpi: int):
    """A ``w`` inch wide figure: the header lines (wrapped, about 0.6 em a character) top-down
    at fixed inch offsets, ``h_below`` inches under them; returns (figure, header inches)."""
    lines = [(part, kw) for text, kw in lines
             for part in textwrap.wrap(text, max(20, int(w * 115 / kw.get("size", 9)))) or [""]]
    top = 0.22 + sum(kw.get("size", 9) * 1.45 / 72 for _, kw in lines)
    fig = Figure(figsize=(w, top + h_below), dpi=dpi)
    FigureCanvasAgg(fig)
    y = 0.12
    for text, kw in lines:
        fig.text(0.5, 1 - y / (top + h_below), text, ha="center", va="top", **kw)
        y += kw.get("size", 9) * 1.45 / 72
    return fig, top


def _header_lines(view: TableView, extra: str = "") -> list[tuple[str, dict]]:
    lines = [(f"{view.id}: {view.title}", {"size": 11, "weight": "bold"})]
    sub = " — ".join(t for t in (view.paper, extra) if t)
    if sub:
        lines.append((sub, {"size": 8, "color": "#444444"}))
    if view.standin:
        note = (f"STAND-IN DATA: {view.standin} (not the paper's data; compare orderings and "
                "gaps, not absolute values)")
        lines.append((note, {"size": 9, "weight": "bold", "color": STANDIN_COLOUR}))
    return lines


def _canvas(lines, n: int, dpi: int, *, ncol=None, panel=(PANEL_W, PANEL_H), left=0.75,
            right=0.25, gap=(0.8, 0.9), above=0.3, legend=1, sharey=False):
    """The header and a grid of ``n`` panels (unused cells hidden), every size in inches
    (``above``: room for the panel titles; ``legend``: rows of the figure legend below)."""
    ncol = ncol or (1 if n == 1 else 2 if n in (2, 4) else 3)
    nrow = math.ceil(n / ncol)
    bottom = 0.6 + 0.2 * legend
    w = left + ncol * panel[0] + (ncol - 1) * gap[0] + right
    below = above + nrow * panel[1] + (nrow - 1) * gap[1] + bottom
    fig, top = _header(lines, w, below, dpi)
    top, h = top + above, top + below
    axes = list(fig.subplots(nrow, ncol, squeeze=False, sharey=sharey).flat)
    fig.subplots_adjust(left=left / w, right=1 - right / w, top=1 - top / h, bottom=bottom / h,
                        wspace=gap[0] / panel[0], hspace=gap[1] / panel[1])
    for ax in axes[n:]:
        ax.set_visible(False)
    return fig, axes[:n]


def _finish(fig: Figure, handles: list, path, dpi: int) -> None:
    """The figure legend under the panels (4 entries a row), then the PNG without any
    Software / time tag."""
    if handles:
        fig.legend(handles=handles, loc="lower center", ncol=min(4, len(handles)),
                   bbox_to_anchor=(0.5, 0.02 / fig.get_figheight()), frameon=False)
    from repro.store.atomic import write_output

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()  # then written beside the name and renamed: never through a link
    fig.savefig(buf, dpi=dpi, format="png", metadata={"Software": None}, facecolor="white")
    write_output(path, buf.getvalue())


def _message(path, lines, message: str, dpi: int, detail: str = "") -> None:
    fig, top = _header(lines, 8.0, 2.2, dpi)
    fig.text(0.5, 1 - (top + 0.9) / (top + 2.2), message, ha="center", va="center", size=16,
             color=GREY, bbox=dict(boxstyle="round,pad=0.6", fc="#F2F2F2", ec="#BBBBBB"))
    if detail:
        fig.text(0.5, 0.06, "\n".join(textwrap.wrap(detail, 110)), ha="center", va="bottom",
                 size=8, color="#444444", linespacing=1.4)
    _finish(fig, [], path, dpi)


def write_data(path, records: list[dict], fields, meta: dict) -> None:
    """The plotted records: CSV (a header of ``fields``) or JSON (``meta`` + ``records``)."""
    p = Path(path)
    if p.suffix not in (".csv", ".json"):
        raise ValueError(f"data file must end in .csv or .json: {p}")
    from repro.store.atomic import write_output

    p.parent.mkdir(parents=True, exist_ok=True)
    if p.suffix == ".json":
        write_output(p, json.dumps({"schema": 1, **meta, "records": records}, indent=1,
                                   ensure_ascii=False) + "\n")
        return
    fh = io.StringIO(newline="")
    w = csv.DictWriter(fh, fieldnames=list(fields), extrasaction="ignore")
    w.writeheader()
    w.writerows({k: ("" if r.get(k) is None else r[k]) for k in fields} for r in records)
    write_output(p, fh.getvalue())


def _cell_record(row: RowView, col: ColumnView, x, c: CellView | None) -> dict:
    c = c or CellView()
    ok = c.status == OK and _finite(c.value) is not None
    lo, hi = c.ci if ok and c.ci is not None else (None, None)
    return {"row": row.id, "row_label": row.label, "column": col.id, "column_label": col.label,
            "x": x, "value": _finite(c.value) if ok else None, "ci_lo": _finite(lo),
            "ci_hi": _finite(hi), "n": c.n, "status": c.status, "reported": c.reported,
            "paper": paper_number(c.reported)}


def _panels(columns: list[ColumnView]) -> list[list[ColumnView]]:
    """Columns grouped into panels: ``group.metric`` by metric, others one panel each."""
    order: dict[tuple, list[ColumnView]] = {}
    for c in columns:
        order.setdefault(("m", c.id.split(".", 1)[1]) if "." in c.id else ("c", c.id),
                         []).append(c)
    return list(order.values())


def _panel_title(cols: list[ColumnView]) -> str:
    """One column: its label; several groups: their labels' common stem ("Acc-O", "Acc-S" →
    "Acc")."""
    if len(cols) == 1:
        return cols[0].label
    stem = os.path.commonprefix([_short(c.label) for c in cols]).rstrip(" -_(")
    return stem or cols[0].id.split(".", 1)[-1]


@_styled
def figure_plot(view: FigureView, path_png, *, data_path=None, dpi: int = 100) -> dict:
    """Draw a figure view: one panel per metric, x = the reproduced x (``view.x.values``),
    y = each row's mean with our interval (``ci``) as a band; groups of a metric share its
    panel, the first solid with circles, the second dashed with squares (Fig. 8's -O / -S).

    The paper's values: a figure prints none (``reported`` is None everywhere), but any cell
    whose ``reported`` parses as a number (:func:`paper_number`) is overlaid as a black ``x``
    and the legend gets a "paper" entry.  Without reproduced x (no run yet, or a protocol not
    implemented) the PNG says "not reproduced yet" under the spec's title.  Writes the plotted
    records to ``data_path`` (.csv / .json; one per row, column and x, gaps included) and
    returns ``{"panels", "series", "points", "paper_points", "reproduced"}``.
    """
    a, xs = view.x, list(view.x.values) if view.x is not None else []
    lines = _header_lines(view, f"{a.label}: reproduced {format_xs(xs)} of the paper's "
                                f"{a.start}..{a.stop}" if xs else "")
    if not xs:
        detail = "" if a is None else (
            f"x: {a.label} {a.start}..{a.stop}; columns: "
            + ", ".join(_short(c.label) for c in view.columns)
            + "; rows: " + ", ".join(f"{r.label} ({r.status})" for r in view.rows))
        _message(path_png, lines, "not reproduced yet", dpi, detail)
        if data_path is not None:
            write_data(data_path, [], DATA_FIELDS, {"view": view.id, "kind": "figure"})
        return {"panels": 0, "series": 0, "points": 0, "paper_points": 0, "reproduced": False,
                "message": "not reproduced yet"}
    panels = _panels(view.columns)
    extra = 0.22 if any(len(cols) > 1 for cols in panels) else 0.0  # group legend room
    fig, axes = _canvas(lines, len(panels), dpi, above=0.35 + extra, gap=(0.8, 0.85 + extra),
                        legend=math.ceil((len(view.rows) + 1) / 4))
    records, series, points, paper_pts, drawn = [], 0, 0, 0, set()
    xarr = np.asarray(xs, dtype=float)
    for ax, cols in zip(axes, panels):
        for (ls, mk), col in zip(GROUP_STYLES * len(cols), cols):
            for r, row in enumerate(view.rows):
                colour = PALETTE[r % len(PALETTE)]
                recs = [_cell_record(row, col, x, row.cells.get(x_cell_id(col.id, x)))
                        for x in xs]
                records.extend(recs)
                y, lo, hi = (_nan(q[k] for q in recs) for k in ("value", "ci_lo", "ci_hi"))
                if np.isfinite(lo).any():
                    ax.fill_between(xarr, lo, hi, color=colour, alpha=0.18, lw=0)
                if np.isfinite(y).any():
                    ax.plot(xarr, y, color=colour, ls=ls, marker=mk, ms=3.5, zorder=3)
                    series, points = series + 1, points + int(np.isfinite(y).sum())
                    drawn.add(row.id)
                pp = [(x, q["paper"]) for x, q in zip(xs, recs) if q["paper"] is not None]
                if pp:
                    ax.plot(*zip(*pp), ls="none", marker="x", color="black", ms=6, mew=1.5,
                            zorder=4)
                    paper_pts += len(pp)
        title = _panel_title(cols)
        ax.set_title(title + _arrow(cols[0].direction, title), pad=6 + 16 * (len(cols) > 1))
        ax.set_ylabel(_short(title) + (f" ({cols[0].unit})" if cols[0].unit else ""))
        ax.set_xlabel(a.label)
        ax.set_xlim(min(xs) - 0.5, max(xs) + 0.5)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True, nbins=10))
        if len(cols) > 1:  # the group styles, between the title and the panel
            ax.legend(handles=[Line2D([], [], color=GREY, ls=ls, marker=mk, label=_short(c.label))
                               for (ls, mk), c in zip(GROUP_STYLES * len(cols), cols)],
                      loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=len(cols),
                      frameon=False, handlelength=2.6, borderaxespad=0.15, fontsize=7.5)
    handles = [Line2D([], [], color=PALETTE[r % len(PALETTE)], lw=2.5 if row.id in drawn else 0,
                      label=row.label if row.id in drawn else
                      f"{row.label} ({row.status if row.status != OK else 'no data'})")
               for r, row in enumerate(view.rows)]
    if paper_pts:
        handles.append(Line2D([], [], ls="none", marker="x", color="black", mew=1.5,
                              label="paper"))
    _finish(fig, handles, path_png, dpi)
    if data_path is not None:
        write_data(data_path, records, DATA_FIELDS,
                   {"view": view.id, "kind": "figure", "x_label": a.label})
    return {"panels": len(panels), "series": series, "points": points,
            "paper_points": paper_pts, "reproduced": True}


def _training_label(t: dict) -> str:
    row, method = t.get("row", "?"), t.get("method", "?")
    who = row if row == method else f"{row}/{method}"
    return who if t.get("seed") is None else f"{who} (seed {t['seed']})"


@_styled
def learning_curve_plot(trainings: list[dict], path_png, *, data_path=None, dpi: int = 100,
                        title: str = "Learning curves") -> dict:
    """Draw a run's training records (``trainings.json``'s ``trainings``): one panel per
    quantity present (loss, rec1, MPJPE, ss_active), x = epoch, one colour per training,
    training solid and held-out validation (``val_*``) dashed; a positive curve set spanning
    more than two decades is drawn on a log axis.  Without any history the PNG says "no
    learning curves recorded".  Writes the records (one per training, quantity and epoch) to
    ``data_path`` and returns ``{"panels", "series", "points", "validation"}``."""
    ts = [t for t in trainings if isinstance(t, dict)]
    hist = [[h for h in ((t.get("training") or {}).get("history") or []) if isinstance(h, dict)]
            for t in ts]
    present = [(k, name) for k, name in CURVE_PANELS
               if any(k in h or f"val_{k}" in h for hs in hist for h in hs)]
    head = [(title, {"size": 11, "weight": "bold"})]
    if not present:
        _message(path_png, head, "no learning curves recorded", dpi)
        if data_path is not None:
            write_data(data_path, [], CURVE_FIELDS, {"kind": "learning_curves"})
        return {"panels": 0, "series": 0, "points": 0, "validation": False,
                "message": "no learning curves recorded"}
    used = [i for i, hs in enumerate(hist) if hs]
    has_val = any(f"val_{k}" in h for k, _ in present if k != "ss_active"
                  for hs in hist for h in hs)
    fig, axes = _canvas(head, len(present), dpi, legend=math.ceil((len(used) + 2) / 4))
    records, series, points = [], 0, 0
    for ax, (key, name) in zip(axes, present):
        seen = []
        keys = [(key, "-")] + ([(f"val_{key}", "--")] if key != "ss_active" else [])
        for j, i in enumerate(used):
            ep = [_finite(h.get("epoch", e)) for e, h in enumerate(hist[i])]
            for q, ls in keys:
                ys = [_finite(h.get(q)) for h in hist[i]]
                pts = [(e, y) for e, y in zip(ep, ys) if e is not None and y is not None]
                if not pts:
                    continue
                t = ts[i]
                records.extend({"training": _training_label(t), "row": t.get("row"),
                                "method": t.get("method"), "seed": t.get("seed"),
                                "quantity": q, "epoch": e, "value": y} for e, y in pts)
                ax.plot(_nan(ep), _nan(ys), color=PALETTE[j % len(PALETTE)], ls=ls, marker="o",
                        ms=2.2, lw=1.3)
                seen.extend(y for _, y in pts)
                series, points = series + 1, points + len(pts)
        if key != "ss_active" and seen and min(seen) > 0 and max(seen) > 100 * min(seen):
            ax.set_yscale("log")
        ax.set_title(name)
        ax.set_xlabel("epoch")
        ax.set_ylabel(key)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    handles = [Line2D([], [], color=PALETTE[j % len(PALETTE)], lw=2.5,
                      label=_training_label(ts[i])) for j, i in enumerate(used)]
    handles.append(Line2D([], [], color=GREY, ls="-", label="training"))
    if has_val:
        handles.append(Line2D([], [], color=GREY, ls="--", label="validation (held out)"))
    _finish(fig, handles, path_png, dpi)
    if data_path is not None:
        write_data(data_path, records, CURVE_FIELDS, {"kind": "learning_curves"})
    return {"panels": len(present), "series": series, "points": points, "validation": has_val}


@_styled
def table_plot(view: TableView, path_png, *, data_path=None, dpi: int = 100) -> dict:
    """A plain table at a glance: one panel per column (four a row), rows down, our mean as a
    dot with its interval as a whisker and the paper's value (:func:`paper_number` of
    ``reported``; "-", "/", words and "?" skipped) as a black ``x``; a cell with neither says
    its status in words.  Writes one record per row and column to ``data_path``."""
    cols = view.columns
    labels = ["\n".join(textwrap.wrap(r.label, 26)) or r.id for r in view.rows]
    left = 0.3 + 0.065 * max((len(s) for lab in labels for s in lab.split("\n")), default=4)
    fig, axes = _canvas(_header_lines(view), len(cols), dpi, ncol=min(4, len(cols)),
                        panel=(2.4, 0.36 * len(view.rows) + 0.4), left=left, gap=(0.2, 0.75),
                        sharey=True)
    records, points, paper_pts = [], 0, 0
    for ax, col in zip(axes, cols):
        for r, row in enumerate(view.rows):
            q = _cell_record(row, col, None, row.cells.get(col.id))
            del q["x"]
            records.append(q)
            v, lo, hi = q["value"], q["ci_lo"], q["ci_hi"]
            if v is not None:
                err = None if lo is None or hi is None else [[max(v - lo, 0)], [max(hi - v, 0)]]
                ax.errorbar([v], [r], xerr=err, fmt="o", color=PALETTE[r % len(PALETTE)],
                            ms=5, capsize=3, zorder=3)
                points += 1
            elif q["paper"] is None:
                ax.text(0.03, r, q["status"], transform=ax.get_yaxis_transform(),
                        va="center", size=7, color="#777777", style="italic")
            if q["paper"] is not None:
                ax.plot([q["paper"]], [r], ls="none", marker="x", color="black", ms=7,
                        mew=1.6, zorder=4)
                paper_pts += 1
        ax.set_title(col.label + _arrow(col.direction, col.label), size=9)
        ax.set_yticks(np.arange(len(view.rows)), labels)
        ax.set_ylim(len(view.rows) - 0.5, -0.5)
        ax.xaxis.set_major_locator(MaxNLocator(nbins=4))
        ax.margins(x=0.15)
    _finish(fig, [Line2D([], [], ls="none", marker="o", color=GREY,
                         label="ours: mean with interval"),
                  Line2D([], [], ls="none", marker="x", color="black", mew=1.6, label="paper")],
            path_png, dpi)
    if data_path is not None:
        write_data(data_path, records, [f for f in DATA_FIELDS if f != "x"],
                   {"view": view.id, "kind": "table"})
    return {"panels": len(cols), "series": len(view.rows), "points": points,
            "paper_points": paper_pts}


def view_from_dict(d: dict) -> TableView:
    """A view back from its JSON (``TableView.to_dict()``, ``repro show --format json``): a
    :class:`FigureView` when the dict has an ``x`` axis."""
    rows = [RowView(**{**r, "cells": {k: CellView(**{**c, "ci": tuple(c["ci"]) if c.get("ci")
                                                     else None})
                                      for k, c in (r.get("cells") or {}).items()}})
            for r in d.get("rows", [])]
    kw = dict(columns=[ColumnView(**c) for c in d.get("columns", [])], rows=rows,
              claims=[ClaimView(**c) for c in d.get("claims", [])],
              footer=list(d.get("footer", [])), standin=d.get("standin"),
              interval=d.get("interval", "none"))
    if d.get("x") is not None:
        return FigureView(d["id"], d.get("title", ""), d.get("paper", ""), **kw,
                          x=AxisView(**d["x"]))
    return TableView(d["id"], d.get("title", ""), d.get("paper", ""), **kw)


__all__ = ["figure_plot", "learning_curve_plot", "table_plot", "view_from_dict",
           "paper_number", "write_data", "PALETTE", "RC"]
