"""Every number in the specs is the paper's: each printed cell is found in the paper's text.

For each spec the caption (``paper.caption``) must occur in the paper's text extraction; the
table is taken to be the lines around it.  Each reported cell must then occur in that region:
its verbatim ``printed`` string (after stripping the extraction's markup: ``<sup>``, ``$``,
``^{\\pm ...}``, spaces around ``±``), with number boundaries on both sides, or, for a garbled
cell, its ``extracted`` fragment exactly as the extraction has it.  Every claim's ``source``
sentence (fragments joined by " … ") must occur in the text too.

The paper texts live outside the repository (``../shared/papers/`` or ``$REPRO_PAPERS``); the
module is skipped when they are absent.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from repro.paths import repo_root
from repro.specs import load_all
from repro.specs.schema import parse_printed


def _papers_dir() -> Path:
    env = os.environ.get("REPRO_PAPERS")
    return Path(env) if env else repo_root().parent / "shared" / "papers"


PAPERS = _papers_dir()
pytestmark = pytest.mark.skipif(not PAPERS.is_dir(), reason=f"paper texts not found at {PAPERS}")

# lines before / after the caption line that belong to the table (captions sit above the table
# in two papers and below it in MultiAct; Table S1 runs 24 lines below its caption)
BEFORE, AFTER = 12, 26

_MARKUP = [("<sup>", ""), ("</sup>", ""), ("<b>", ""), ("</b>", ""), ("<u>", ""), ("</u>", ""),
           ("\\pm", "±"), ("\\%", "%"), ("$", ""), ("^{", ""), ("{", ""), ("}", ""), ("^", "")]


def normalise(text: str) -> str:
    for a, b in _MARKUP:
        text = text.replace(a, b)
    return re.sub(r"[ \t]*±[ \t]*", "±", text)


def _squash(text: str) -> str:
    return re.sub(r"\s+", " ", text)


_TEXTS: dict[str, str] = {}


def paper_text(file: str) -> str:
    if file not in _TEXTS:
        _TEXTS[file] = (PAPERS / file).read_text(encoding="utf-8")
    return _TEXTS[file]


def region(spec) -> str:
    """The raw lines around the spec's caption."""
    lines = paper_text(spec.paper.file).splitlines()
    hits = [i for i, line in enumerate(lines) if spec.paper.caption in line]
    assert hits, f"{spec.id}: caption {spec.paper.caption!r} not found in {spec.paper.file}"
    assert len(hits) == 1, f"{spec.id}: caption occurs on lines {hits}; make it unique"
    i = hits[0]
    return "\n".join(lines[max(0, i - BEFORE): i + AFTER + 1])


def printed_occurs(printed: str, text: str) -> bool:
    pattern = r"(?<![\d.])" + re.escape(printed) + r"(?!\d)"
    return re.search(pattern, text) is not None


SPECS = load_all() if PAPERS.is_dir() else {}
CELLS = [(sid, row.id, cid, cell) for sid, spec in SPECS.items() for row in spec.rows
         for cid, cell in row.reported.items()]


@pytest.mark.parametrize("sid", sorted(SPECS))
def test_caption_locates_the_table(sid):
    region(SPECS[sid])


def test_every_printed_cell_occurs_in_the_paper():
    """All reported cells of all 18 specs (several hundred), each found in its table's text."""
    missing, checked = [], 0
    for sid, row_id, cid, cell in CELLS:
        spec = SPECS[sid]
        raw = region(spec)
        if cell.extracted is not None:
            ok = cell.extracted in raw
            what = f"extracted {cell.extracted!r}"
        else:
            ok = printed_occurs(cell.printed, normalise(raw))
            what = f"printed {cell.printed!r}"
        checked += 1
        if not ok:
            missing.append(f"{sid} row {row_id} column {cid}: {what}")
    assert not missing, "not found in the paper text:\n" + "\n".join(missing)
    assert checked >= 450, checked


def test_extracted_fragments_carry_the_printed_digits():
    """A garbled cell's reconstruction invents nothing the fragment does not show: the
    half-width digits occur in the fragment, and so does the value's last digit (the
    extraction splits a number as '0.1 | 2±.01', doubles the last digit as in '0.12 | 2±.01',
    or reads it as 'l' / ')' for 1 / 9)."""
    for sid, row_id, cid, cell in CELLS:
        if cell.extracted is None:
            continue
        frag = cell.extracted.replace("l", "1").replace(")", "9")
        value, _, half = cell.printed.partition("±")
        assert value[-1] in frag, (sid, row_id, cid, cell.printed, cell.extracted)
        if half:
            assert half in frag, (sid, row_id, cid, cell.printed, cell.extracted)


@pytest.mark.parametrize("sid", sorted(SPECS))
def test_claim_sources_are_sentences_of_the_paper(sid):
    spec = SPECS[sid]
    text = _squash(paper_text(spec.paper.file))
    for claim in spec.claims:
        for frag in claim.source.split(" … "):
            assert _squash(frag.strip()) in text, f"{sid} claim {claim.id}: {frag!r} not in paper"


def test_a_sample_of_cells_by_hand():
    """Spot checks against numbers read off the papers by eye (guards the loader itself)."""
    s = SPECS
    assert s["marionette/table1"].reported("marionet", "fid").value == 1.115
    assert s["marionette/table3"].reported("marionet", "sufficient.fid").value == 4.624
    c = s["marionette/table5"].reported("neural_marionette", "pose_gap")
    assert c.printed == "0.265" and not c.certain
    c = s["multiact/table1"].reported("macvae", "fid_train")
    assert (c.printed, c.value, c.paper_halfwidth) == ("0.74±0.019", 0.74, 0.019)
    c = s["multiact/table2"].reported("actor", "div")
    assert (c.value, c.paper_halfwidth) == (6.52, 0.64)
    c = s["odmo/table1"].reported("dlow_gen", "uestc.n_apd")
    assert (c.value, c.paper_halfwidth) == (197.1, 1.1)
    c = s["odmo/table3"].reported("odmo", "humanact12.mode_homogeneity")
    assert (c.value, c.paper_halfwidth, c.percent) == (15.22, 0.92, True)
    assert s["odmo/tableS1"].reported("sigma2_1_25", "humanact12.fid").value == 0.31
    assert s["odmo/table2"].reported("odmo", "acc").printed == "93.51±.04"
    assert s["odmo/tableS1"].reported("sigma2_0_05", "mocap.acc").printed == "93.51±.39"


def test_ablation_rows_agree_with_the_main_rows_where_the_paper_repeats_them():
    """Numbers printed twice by a paper are transcribed identically."""
    ma1, ma2, maA = SPECS["multiact/table1"], SPECS["multiact/table2"], SPECS["multiact/tableA"]
    maB = SPECS["multiact/tableB"]
    for col in ("fid_train", "fid_test", "acc", "acc_top5", "div", "multimod"):
        for row in ("real_train", "real_test", "macvae"):
            other = "frames_4" if row == "macvae" else row
            assert ma1.reported(row, col).printed == ma2.reported(row, col).printed
            assert ma1.reported(row, col).printed == maA.reported(other, col).printed
    for col in ("fid_train", "fid_test", "acc", "acc_top5"):
        assert ma1.reported("macvae", col).printed == maB.reported("transformer", col).printed
    nm1, nm2 = SPECS["marionette/table1"], SPECS["marionette/table2"]
    for col in ("fid", "acc", "div", "multimod"):
        assert nm1.reported("marionet", col).printed == nm2.reported("marionet", col).printed
    nm3, nm4, nm5 = SPECS["marionette/table3"], SPECS["marionette/table4"], SPECS["marionette/table5"]
    assert nm3.reported("marionet", "overall.acc").printed == nm4.reported("with_next_tag", "overall.acc").printed
    assert nm3.reported("marionet", "overall.acc").printed == nm5.reported("marionet", "acc").printed
    od1, od2, s1 = SPECS["odmo/table1"], SPECS["odmo/table2"], SPECS["odmo/tableS1"]
    for col in ("acc", "fid", "multimod"):
        assert od1.reported("odmo", f"humanact12.{col}").printed == s1.reported("sigma2_0_05", f"humanact12.{col}").printed
        assert parse_printed(od2.reported("odmo", col).printed)[0] == s1.reported("sigma2_0_05", f"mocap.{col}").value


def test_each_row_reads_off_one_line_in_column_order():
    """A row's cells (those not reconstructed from garbled text) sit on one line of the table,
    in the spec's column order (per column group: Table S1 prints one block per data set).  This catches swapped rows or columns, which a plain search
    for each number cannot.  Merged lines pass too: the extraction keeps column order and
    lists the merged rows' values cell by cell."""
    bad = []
    for sid, spec in SPECS.items():
        lines = [normalise(line) for line in region(spec).splitlines()]
        bands = {}
        for c in spec.columns:
            bands.setdefault(c.group, []).append(c.id)
        for row, band in ((r, b) for r in spec.rows for b in bands.values()):
            cells = [row.reported[c].printed for c in band
                     if c in row.reported and row.reported[c].extracted is None
                     and row.reported[c].reported]
            if len(cells) < 2:
                continue

            def in_order(line: str) -> bool:
                pos = 0
                for printed in cells:
                    m = re.compile(r"(?<![\d.])" + re.escape(printed) + r"(?!\d)").search(line, pos)
                    if m is None:
                        return False
                    pos = m.end()
                return True

            if not any(in_order(line) for line in lines):
                bad.append(f"{sid} row {row.id}: {cells}")
    assert not bad, "rows not found on one line in column order:\n" + "\n".join(bad)
