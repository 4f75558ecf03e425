"""Plots of figures, tables and learning curves (repro.render.plots): PNGs that decode, byte-
identical re-renders, the data files beside them, the "not reproduced yet" / "no learning
curves recorded" placeholders, and golden images compared by SSIM.

Golden images: ``tests/golden/fig_plot.png`` and ``tests/golden/curves_plot.png`` are compared
with the fresh render by SSIM (grayscale, ``data_range=255``) against :data:`SSIM_MIN`; a
render of a different view must fall below it, so the comparison can fail.  After an intended
change of the drawing, look at the new PNGs and rewrite the goldens with

    REPRO_UPDATE_GOLDEN=1 .venv/bin/python -m pytest tests/test_render_plots.py
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from skimage.metrics import structural_similarity

from repro.render.plots import (figure_plot, learning_curve_plot, paper_number, table_plot,
                                view_from_dict)
from repro.report.view import (AxisView, CellView, ColumnView, FigureView, RowView, TableView,
                               x_cell_id)

GOLDEN = Path(__file__).parent / "golden"
SSIM_MIN = 0.97
DPI = 72  # small PNGs: quick to draw and compare
XS = [1, 2, 3, 4]


def _fig8_view(*, trend: float = 1.0, standin: str | None = "bandai2-mini",
               xs=XS) -> FigureView:
    """A trimmed Fig. 8 view: two rows, two metrics (acc, fid), two groups (-O, -S), four x;
    one gap (mann's FID-S at x = 3 not measured).  ``trend`` scales how the curves move."""
    cols = [ColumnView(f"{g}.{m}", f"{gl}: {ml}-{s}", d, u)
            for g, gl, s in (("overall", "Overall (-O)", "O"),
                             ("sufficient", "Sufficient (-S)", "S"))
            for m, ml, d, u in (("acc", "Acc", "higher", "fraction"), ("fid", "FID", "lower", ""))]
    rows = []
    for r, (rid, label) in enumerate((("mann", "MANN"), ("marionet", "MARIONET"))):
        row = RowView(rid, label, rid, "ok")
        for c in cols:
            for x in xs:
                if c.id.endswith("acc"):
                    v = 0.6 + 0.15 * r - trend * 0.05 * x * (1 + (c.id[0] == "s"))
                else:
                    v = 20 - 8 * r + 4 * (c.id[0] == "s") + trend * 2.0 * x * (1 + r)
                hw = 0.04 if c.id.endswith("acc") else 2.5
                row.cells[x_cell_id(c.id, x)] = CellView(None, v, None, (v - hw, v + hw), 3, "ok")
        if r == 0 and 3 in xs:
            row.cells[x_cell_id("sufficient.fid", 3)] = CellView(None, status="not measured")
        rows.append(row)
    return FigureView("marionette/fig8", "Quantitative results per action index",
                      "Neural Marionette", cols, rows, standin=standin,
                      x=AxisView("action_index", "Action index", 1, 20, list(xs)))


def _trainings(*, validation: bool = True) -> list[dict]:
    def hist(n, scale, extra):
        out = []
        for e in range(n):
            h = {"epoch": e, "loss": scale / (1 + e), "batches": 7}
            if validation:
                h["val_loss"] = 1.1 * scale / (1 + e)
            if extra:
                h.update(rec1=3.0 / (1 + 0.5 * e), mpjpe=0.5 / (1 + 0.2 * e),
                         ss_active=min(1.0, max(0.0, (e - 2) / 3)))
                if validation:
                    h.update(val_rec1=2.8 / (1 + 0.5 * e), val_mpjpe=0.45 / (1 + 0.2 * e))
            out.append(h)
        return out
    return [{"row": "mann", "method": "mann", "seed": 0,
             "training": {"history": hist(8, 0.5, False)}},
            {"row": "marionet", "method": "marionet", "seed": 0,
             "training": {"history": hist(8, 6.0, True)}},
            {"row": "nearest_clip", "method": "nearest_clip", "seed": 0,
             "training": {"history": []}}]


def _gray(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("L"), dtype=np.float64)


def _ssim(a: Path, b: Path) -> float:
    x, y = _gray(a), _gray(b)
    assert x.shape == y.shape, f"image sizes differ: {x.shape} vs {y.shape}"
    return float(structural_similarity(x, y, data_range=255))


def _check_golden(png: Path, name: str) -> None:
    golden = GOLDEN / name
    if os.environ.get("REPRO_UPDATE_GOLDEN") == "1":
        golden.parent.mkdir(exist_ok=True)
        golden.write_bytes(png.read_bytes())
    assert golden.is_file(), f"{golden} missing: rerun with REPRO_UPDATE_GOLDEN=1"
    s = _ssim(png, golden)
    assert s >= SSIM_MIN, f"{name}: SSIM {s:.4f} < {SSIM_MIN} (look at {png})"


def _decodes(path: Path) -> tuple[int, int]:
    with Image.open(path) as im:
        im.load()
        assert im.format == "PNG"
        return im.size


# -- figures ----------------------------------------------------------------------------------


def test_figure_plot_png_data_and_determinism(tmp_path):
    view = _fig8_view()
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    got = figure_plot(view, a, data_path=tmp_path / "a.csv", dpi=DPI)
    figure_plot(view, b, data_path=tmp_path / "b.json", dpi=DPI)
    w, h = _decodes(a)
    assert w > 300 and h > 300
    assert a.read_bytes() == b.read_bytes()
    # two panels (acc, fid), each 2 groups x 2 rows; one gap
    assert got == {"panels": 2, "series": 8, "points": 8 * 4 - 1, "paper_points": 0,
                   "reproduced": True}
    with open(tmp_path / "a.csv", newline="", encoding="utf-8") as fh:
        recs = list(csv.DictReader(fh))
    assert len(recs) == 2 * 4 * 4  # rows x columns x x
    def rec(row, col, x):
        return next(r for r in recs if (r["row"], r["column"], r["x"]) == (row, col, x))

    one = rec("marionet", "overall.acc", "2")
    cell = view.rows[1].cells["overall.acc@2"]
    assert float(one["value"]) == pytest.approx(cell.value)
    assert (float(one["ci_lo"]), float(one["ci_hi"])) == pytest.approx(cell.ci)
    assert one["n"] == "3" and one["status"] == "ok"
    gap = rec("mann", "sufficient.fid", "3")
    assert gap["value"] == "" and gap["status"] == "not measured"
    data = json.loads((tmp_path / "b.json").read_text())
    assert data["view"] == "marionette/fig8" and len(data["records"]) == 32
    assert sum(r["value"] is not None for r in data["records"]) == 31


def test_figure_plot_overlays_parseable_paper_values(tmp_path):
    view = _fig8_view(standin=None)
    view.rows[0].cells["overall.acc@1"].reported = "0.92±0.01"
    view.rows[1].cells["overall.acc@2"].reported = "-"
    got = figure_plot(view, tmp_path / "p.png", data_path=tmp_path / "p.json", dpi=DPI)
    assert got["paper_points"] == 1
    recs = json.loads((tmp_path / "p.json").read_text())["records"]
    assert [r["paper"] for r in recs if r["paper"] is not None] == [0.92]


def test_figure_not_reproduced_yet(tmp_path):
    view = _fig8_view(xs=[])
    for row in view.rows:
        row.status, row.cells = "not run", {c.id: CellView(None, status="not run")
                                            for c in view.columns}
    got = figure_plot(view, tmp_path / "n.png", data_path=tmp_path / "n.csv", dpi=DPI)
    assert got["reproduced"] is False and got["message"] == "not reproduced yet"
    _decodes(tmp_path / "n.png")
    assert (tmp_path / "n.csv").read_text().splitlines()[1:] == []
    # a figure whose protocol is not implemented has no axis values either
    view.x = None
    assert figure_plot(view, tmp_path / "m.png", dpi=DPI)["reproduced"] is False


def test_figure_golden_and_a_different_view_fails_it(tmp_path):
    png = tmp_path / "fig.png"
    figure_plot(_fig8_view(), png, dpi=DPI)
    _check_golden(png, "fig_plot.png")
    other = tmp_path / "other.png"
    figure_plot(_fig8_view(trend=-1.0), other, dpi=DPI)
    assert _ssim(other, GOLDEN / "fig_plot.png") < SSIM_MIN


def test_view_from_dict_round_trip(tmp_path):
    view = _fig8_view()
    back = view_from_dict(json.loads(json.dumps(view.to_dict())))
    assert isinstance(back, FigureView) and back.to_dict() == view.to_dict()
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    figure_plot(view, a, dpi=DPI)
    figure_plot(back, b, dpi=DPI)
    assert a.read_bytes() == b.read_bytes()


# -- learning curves --------------------------------------------------------------------------


def test_learning_curves_with_validation(tmp_path):
    png = tmp_path / "c.png"
    got = learning_curve_plot(_trainings(), png, data_path=tmp_path / "c.json", dpi=DPI)
    _decodes(png)
    # loss (2 trainings x train/val), rec1 and mpjpe (marionet x train/val), ss_active (1)
    assert got == {"panels": 4, "series": 4 + 2 + 2 + 1, "points": 9 * 8, "validation": True}
    recs = json.loads((tmp_path / "c.json").read_text())["records"]
    assert len(recs) == 72
    assert {r["quantity"] for r in recs} == {"loss", "val_loss", "rec1", "val_rec1", "mpjpe",
                                             "val_mpjpe", "ss_active"}
    first = next(r for r in recs
                 if r["training"] == "marionet (seed 0)" and r["quantity"] == "loss")
    assert (first["epoch"], first["value"]) == (0, 6.0)
    again = tmp_path / "c2.png"
    learning_curve_plot(_trainings(), again, dpi=DPI)
    assert again.read_bytes() == png.read_bytes()
    _check_golden(png, "curves_plot.png")


def test_learning_curves_without_validation_and_without_history(tmp_path):
    got = learning_curve_plot(_trainings(validation=False), tmp_path / "c.png",
                              data_path=tmp_path / "c.csv", dpi=DPI)
    assert got == {"panels": 4, "series": 5, "points": 40, "validation": False}
    assert len((tmp_path / "c.csv").read_text().splitlines()) == 1 + 40
    ssim = _ssim(tmp_path / "c.png", GOLDEN / "curves_plot.png")
    assert ssim < SSIM_MIN  # without the dashed validation curves the golden does not match
    none = learning_curve_plot([_trainings()[2]], tmp_path / "none.png", dpi=DPI)
    assert none["message"] == "no learning curves recorded" and none["panels"] == 0
    _decodes(tmp_path / "none.png")
    assert learning_curve_plot([], tmp_path / "empty.png", dpi=DPI)["series"] == 0


# -- tables -----------------------------------------------------------------------------------


def test_paper_number():
    assert paper_number("0.92±0.01") == 0.92
    assert paper_number("1.58") == 1.58
    assert paper_number("−3.5e-2") == -0.035
    for s in ("-", "/", "not in paper", "1?", None, ""):
        assert paper_number(s) is None


def test_table_plot(tmp_path):
    cols = [ColumnView("fid", "FID↓", "lower"), ColumnView("acc", "Acc", "higher", "fraction")]
    rows = [RowView("real", "Real", "real", "ok", {
                "fid": CellView("0.1", 0.2, None, (0.1, 0.3), 3, "ok"),
                "acc": CellView("0.89±0.01", None, status="not measured")}),
            RowView("ours", "Ours", "marionet", "ok", {
                "fid": CellView("1?", 4.0, None, None, 3, "ok"),
                "acc": CellView("-", 0.5, None, (0.45, 0.55), 3, "ok")})]
    view = TableView("marionette/table1", "Single-action", "Neural Marionette", cols, rows,
                     standin="bandai2-mini")
    got = table_plot(view, tmp_path / "t.png", data_path=tmp_path / "t.json", dpi=DPI)
    _decodes(tmp_path / "t.png")
    assert got == {"panels": 2, "series": 2, "points": 3, "paper_points": 2}
    recs = json.loads((tmp_path / "t.json").read_text())["records"]
    assert [(r["row"], r["column"], r["paper"]) for r in recs] == [
        ("real", "fid", 0.1), ("ours", "fid", None), ("real", "acc", 0.89), ("ours", "acc", None)]
    table_plot(view, tmp_path / "t2.png", dpi=DPI)
    assert (tmp_path / "t2.png").read_bytes() == (tmp_path / "t.png").read_bytes()
