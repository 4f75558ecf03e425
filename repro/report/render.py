"""Renderers of a :class:`~repro.report.view.TableView`: term, md, latex, html, json, csv.

Every format shows, per cell, the paper's printed value and ours (mean, the paper-style ± in
the table's own interval convention, and our bootstrap interval), says "not implemented",
"data unavailable" or "not run" in words, marks a stand-in data set visibly, lists each claim
with its verdict and probability, and ends with the footer (evaluator fingerprint, interval
method, scale, run, spec version).

A figure (:class:`~repro.report.view.FigureView`) prints no paper values: each format says so
and shows one block per column, x down the side and the rows across (20 x points fit a
terminal that way; 20 columns would not), each cell our mean with its intervals; json and csv
carry every x cell.
"""

from __future__ import annotations

import csv
import html
import io
import json
import math

from repro.report.view import OK, CellView, FigureView, TableView, data_mark

FORMATS = ("term", "md", "latex", "html", "json", "csv")


def _num(x: float | None, digits: int = 3) -> str:
    if x is None or not math.isfinite(x):
        return "-"
    a = abs(x)
    if a != 0 and (a >= 1e4 or a < 1e-3):
        return f"{x:.2e}"
    return f"{x:.{digits}f}"


def ours_text(c: CellView) -> str:
    """Our value as text: ``mean ±pm [lo, hi]`` or the status in words."""
    if c.status != OK:
        return c.status
    s = _num(c.value)
    if c.paper_pm is not None:
        s += f" ±{_num(c.paper_pm)}"
    if c.ci is not None:
        s += f" [{_num(c.ci[0])}, {_num(c.ci[1])}]"
    return s


def paper_text(c: CellView) -> str:
    return c.reported if c.reported is not None else "-"


def _arrow(direction: str, label: str = "") -> str:
    """The direction mark, unless the paper's own header already carries one."""
    if any(a in label for a in "↓↑→"):
        return ""
    return {"lower": "↓", "higher": "↑", "closer_to_real": "→real"}.get(direction, "")


def _title(view: TableView) -> str:
    t = f"{view.id}: {view.title}"
    if view.standin:
        t += f"  [{data_mark(view.standin)}]"
    for m in getattr(view, "marks", None) or []:
        t += f"  [{m}]"
    return t


def _claim_line(cl) -> str:
    """A claim's verdict line; a claim that was evaluated carries its evidence (variance,
    budget against the paper's, evaluator: :mod:`repro.engine.evidence`) after "decided by"."""
    p = "" if cl.probability is None else f" (P = {cl.probability:.3f})"
    r = f" — {cl.reason}" if cl.reason else ""
    ev = f" [decided by: {cl.evidence}]" if getattr(cl, "evidence", None) else ""
    return f"{cl.verdict.upper()}{p}: {cl.text}{r}{ev}"


def _term_tail(console, view) -> None:
    """Claims and footer under a terminal table or figure."""
    if view.claims:
        console.print("Claims:")
        for cl in view.claims:
            console.print(f"  {_claim_line(cl)}", highlight=False, markup=False)
    for line in view.footer:
        console.print(line, highlight=False, markup=False)


def md_text(s: str) -> str:
    """Text for Markdown: HTML's ``& < >`` as entities (a spec label never becomes markup
    where the Markdown is rendered), ``|`` escaped (it would end a table cell) and line
    breaks as spaces (they would end the table, the heading or the list item)."""
    s = html.escape(str(s), quote=False).replace("|", "\\|")
    return s.replace("\r\n", " ").replace("\r", " ").replace("\n", " ")


def _md_tail(view) -> list[str]:
    """Claims and footer lines under a Markdown table or figure."""
    lines: list[str] = []
    if view.claims:
        lines += ["", "**Claims**", ""] + [f"- {md_text(_claim_line(cl))}" for cl in view.claims]
    if view.footer:
        lines += [""] + [f"{md_text(x)}  " for x in view.footer]
    return lines


def _html_tail(view) -> list[str]:
    """Claims and footer elements under an HTML table or figure."""
    e = html.escape
    out = []
    if view.claims:
        out.append("<ul>" + "".join(f"<li>{e(_claim_line(cl))}</li>" for cl in view.claims)
                   + "</ul>")
    return out + [f"<p>{e(x)}</p>" for x in view.footer]


def render(view: TableView, fmt: str = "term") -> str:
    if fmt not in FORMATS:
        from repro.errors import ConfigError

        raise ConfigError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
    if isinstance(view, FigureView) and fmt not in ("json",):
        return globals()[f"_figure_{fmt}"](view)
    return globals()[f"_render_{fmt}"](view)


def _render_term(view: TableView) -> str:
    from rich.console import Console
    from rich.table import Table
    from rich.text import Text

    table = Table(title=Text(_title(view)), show_lines=False, title_justify="left")
    table.add_column("row")
    table.add_column("")
    for col in view.columns:
        unit = f" ({col.unit})" if col.unit else ""
        table.add_column(f"{col.label}{_arrow(col.direction, col.label)}{unit}", overflow="fold")
    for row in view.rows:  # Text(): cell contents are never read as rich markup
        table.add_row(Text(row.label), "paper",
                      *[Text(paper_text(row.cells.get(c.id, CellView()))) for c in view.columns])
        ours = [Text(ours_text(row.cells.get(c.id, CellView(status=row.status)))) for c in view.columns]
        table.add_row("", "ours", *ours, end_section=True)
    buf = io.StringIO()
    console = Console(file=buf, width=max(100, 26 * (len(view.columns) + 1)), force_terminal=False,
                      color_system=None)
    console.print(table)
    _term_tail(console, view)
    return buf.getvalue()


def md_row(cells) -> str:
    """One Markdown table line of ``cells``, each escaped by :func:`md_text`."""
    return "| " + " | ".join(md_text(c) for c in cells) + " |"


def _render_md(view: TableView) -> str:
    head = ["row", ""] + [f"{c.label}{_arrow(c.direction, c.label)}" for c in view.columns]
    lines = [f"### {md_text(_title(view))}", "", md_row(head), "|" + "---|" * len(head)]
    for row in view.rows:
        lines.append(md_row([row.label, "paper"] + [paper_text(row.cells.get(c.id, CellView()))
                                                     for c in view.columns]))
        lines.append(md_row(["", "ours"] + [ours_text(row.cells.get(c.id, CellView(status=row.status)))
                                             for c in view.columns]))
    return "\n".join(lines + _md_tail(view)) + "\n"


#: LaTeX of each character that is not itself in LaTeX: every special (``\\ & % $ # _ { } ~
#: ^``) and the arrows and ± the tables print
_TEX = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
        "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}",
        "±": r"$\pm$", "↓": r"$\downarrow$", "↑": r"$\uparrow$", "→": r"$\rightarrow$",
        "\r": " ", "\n": " "}


def _tex(s: str) -> str:
    """``s`` as LaTeX text: one character at a time (so an escape is never escaped again)."""
    return "".join(_TEX.get(ch, ch) for ch in str(s))


def _tex_comment(s: str) -> str:
    """A ``%`` comment line: a line break in ``s`` would end the comment and run the rest."""
    return "% " + " ".join(str(s).splitlines())


def _render_latex(view: TableView) -> str:
    n = len(view.columns)
    out = [r"\begin{table}[t]", r"\centering", r"\caption{" + _tex(_title(view)) + "}",
           r"\begin{tabular}{ll" + "c" * n + "}", r"\toprule",
           " & & " + " & ".join(_tex(c.label + _arrow(c.direction, c.label)) for c in view.columns) + r" \\",
           r"\midrule"]
    for row in view.rows:
        out.append(_tex(row.label) + " & paper & " + " & ".join(
            _tex(paper_text(row.cells.get(c.id, CellView()))) for c in view.columns) + r" \\")
        out.append(" & ours & " + " & ".join(
            _tex(ours_text(row.cells.get(c.id, CellView(status=row.status)))) for c in view.columns) + r" \\")
    out += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    out += [_tex_comment(_claim_line(cl)) for cl in view.claims]
    out += [_tex_comment(x) for x in view.footer]
    return "\n".join(out) + "\n"


def html_table(view: TableView) -> str:
    """The HTML table (a figure: its per-column tables) without claims and footer, for pages
    that lay those out themselves (:mod:`repro.report.html_report`)."""
    if isinstance(view, FigureView):
        return _figure_html(view, tail=False)
    return _render_html(view, tail=False)


def _render_html(view: TableView, tail: bool = True) -> str:
    e = html.escape
    out = [f"<h3>{e(_title(view))}</h3>", "<table>", "<tr><th>row</th><th></th>" +
           "".join(f"<th>{e(c.label + _arrow(c.direction, c.label))}</th>" for c in view.columns) + "</tr>"]
    for row in view.rows:
        out.append(f"<tr><td>{e(row.label)}</td><td>paper</td>" + "".join(
            f"<td>{e(paper_text(row.cells.get(c.id, CellView())))}</td>" for c in view.columns) + "</tr>")
        out.append("<tr><td></td><td>ours</td>" + "".join(
            f"<td>{e(ours_text(row.cells.get(c.id, CellView(status=row.status))))}</td>" for c in view.columns) + "</tr>")
    out.append("</table>")
    return "\n".join(out + (_html_tail(view) if tail else [])) + "\n"


def _render_json(view: TableView) -> str:
    return json.dumps(view.to_dict(), indent=2, sort_keys=True) + "\n"


def _csv_marks(view: TableView) -> str:
    """The CSV's ``marks`` column (the same on every line): a CSV has no title or footer, so
    the marks a title carries (a non-standard gate, a newest run that failed) go here."""
    return " | ".join(getattr(view, "marks", None) or [])


def _render_csv(view: TableView) -> str:
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["table", "row", "method", "column", "status", "paper", "value", "paper_pm",
                "ci_lo", "ci_hi", "n", "marks"])
    marks = _csv_marks(view)
    for row in view.rows:
        for c in view.columns:
            cell = row.cells.get(c.id, CellView(status=row.status))
            w.writerow([view.id, row.id, row.method, c.id, cell.status, cell.reported or "",
                        "" if cell.value is None else repr(cell.value),
                        "" if cell.paper_pm is None else repr(cell.paper_pm),
                        "" if cell.ci is None else repr(cell.ci[0]),
                        "" if cell.ci is None else repr(cell.ci[1]), cell.n, marks])
    return buf.getvalue()


# ---------------------------------------------------------------------------------------------
# figures: one block per column, x down the side, rows across


def _figure_cell(row, key: str) -> str:
    return ours_text(row.cells.get(key, CellView(status=row.status)))


def _column_title(col) -> str:
    unit = f" ({col.unit})" if col.unit else ""
    return f"{col.label}{_arrow(col.direction, col.label)}{unit}"


def _figure_term(view: FigureView) -> str:
    from rich.console import Console
    from rich.table import Table
    from rich.text import Text

    buf = io.StringIO()
    console = Console(file=buf, width=max(100, 12 + 30 * len(view.rows)), force_terminal=False,
                      color_system=None)
    console.print(_title(view), highlight=False, markup=False)
    console.print(view.axis_line(), highlight=False, markup=False)
    xlabel = view.x.label if view.x is not None else "x"
    for col in view.columns:
        table = Table(title=Text(_column_title(col)), show_lines=False, title_justify="left")
        table.add_column(xlabel)
        for row in view.rows:
            table.add_column(row.label, overflow="fold")
        for xs, key in view.cell_keys(col.id):
            table.add_row(Text(xs), *[Text(_figure_cell(row, key)) for row in view.rows])
        console.print(table)
    _term_tail(console, view)
    return buf.getvalue()


def _figure_md(view: FigureView) -> str:
    xlabel = view.x.label if view.x is not None else "x"
    lines = [f"### {md_text(_title(view))}", "", md_text(view.axis_line())]
    for col in view.columns:
        head = [xlabel] + [r.label for r in view.rows]
        lines += ["", f"#### {md_text(_column_title(col))}", "", md_row(head),
                  "|" + "---|" * len(head)]
        for xs, key in view.cell_keys(col.id):
            lines.append(md_row([xs] + [_figure_cell(r, key) for r in view.rows]))
    return "\n".join(lines + _md_tail(view)) + "\n"


def _figure_latex(view: FigureView) -> str:
    xlabel = view.x.label if view.x is not None else "x"
    n = len(view.rows)
    out = [r"\begin{table}[t]", r"\centering", r"\caption{" + _tex(_title(view)) + "}",
           _tex_comment(view.axis_line())]
    for i, col in enumerate(view.columns):
        if i:
            out.append(r"\medskip")
        out += [r"\begin{tabular}{l" + "c" * n + "}", r"\toprule",
                r"\multicolumn{" + str(n + 1) + "}{l}{" + _tex(_column_title(col)) + r"} \\",
                r"\midrule",
                _tex(xlabel) + " & " + " & ".join(_tex(r.label) for r in view.rows) + r" \\",
                r"\midrule"]
        for xs, key in view.cell_keys(col.id):
            out.append(_tex(xs) + " & " + " & ".join(_tex(_figure_cell(r, key))
                                                    for r in view.rows) + r" \\")
        out += [r"\bottomrule", r"\end{tabular}"]
    out.append(r"\end{table}")
    out += [_tex_comment(_claim_line(cl)) for cl in view.claims]
    out += [_tex_comment(x) for x in view.footer]
    return "\n".join(out) + "\n"


def _figure_html(view: FigureView, tail: bool = True) -> str:
    e = html.escape
    xlabel = view.x.label if view.x is not None else "x"
    out = [f"<h3>{e(_title(view))}</h3>", f"<p>{e(view.axis_line())}</p>"]
    for col in view.columns:
        out += [f"<h4>{e(_column_title(col))}</h4>", "<table>",
                f"<tr><th>{e(xlabel)}</th>" + "".join(f"<th>{e(r.label)}</th>" for r in view.rows)
                + "</tr>"]
        for xs, key in view.cell_keys(col.id):
            out.append(f"<tr><td>{e(xs)}</td>" + "".join(
                f"<td>{e(_figure_cell(r, key))}</td>" for r in view.rows) + "</tr>")
        out.append("</table>")
    return "\n".join(out + (_html_tail(view) if tail else [])) + "\n"


def _figure_csv(view: FigureView) -> str:
    """The table's columns plus ``x``; ``column`` is the cell id (``overall.acc@3``), the
    paper column is empty (a figure prints no numbers); before a run one status line per row
    and column with an empty x."""
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["table", "row", "method", "column", "status", "paper", "value", "paper_pm",
                "ci_lo", "ci_hi", "n", "x", "marks"])
    marks = _csv_marks(view)
    for row in view.rows:
        for c in view.columns:
            for xs, key in view.cell_keys(c.id):
                cell = row.cells.get(key, CellView(status=row.status))
                w.writerow([view.id, row.id, row.method, key, cell.status, "",
                            "" if cell.value is None else repr(cell.value),
                            "" if cell.paper_pm is None else repr(cell.paper_pm),
                            "" if cell.ci is None else repr(cell.ci[0]),
                            "" if cell.ci is None else repr(cell.ci[1]), cell.n,
                            "" if key == c.id else xs, marks])
    return buf.getvalue()
