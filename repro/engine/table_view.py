"""A table's report view: the reported-vs-reproduced cells of a spec beside a run's summary
(:func:`make_view`; a figure's per-x view is :mod:`repro.engine.figures`'), and each claim in
words (:func:`claim_text`) with its verdict and the evidence that decided it.  The job graph
and the summary the view reads are :mod:`repro.engine.tables`'."""

from __future__ import annotations

from repro.report.view import NOT_IMPLEMENTED, NOT_RUN, OK, CellView, ClaimView, RowView, TableView


def claim_text(spec, cl) -> str:
    """A claim in words (the view's claim list, the sweep record's ``claim_text``): its rows,
    columns (and x range on a figure) and what it asserts."""
    cols = ", ".join(cl.column)
    if cl.x_range is not None:  # figures only
        cols += f" at x {cl.x_range[0]}..{cl.x_range[1]}"
    elif cl.along == "x" and getattr(spec, "x", None) is not None:
        cols += f" along x {spec.x.start}..{spec.x.stop}"
    elif getattr(spec, "kind", "table") == "figure" and getattr(spec, "x", None) is not None:
        cols += " at every x"
    if cl.kind == "order":
        return f"{cl.better} better than {', '.join(cl.than)} on {cols}"
    if cl.kind == "gap":
        rel = "within" if cl.bound == "within" else "ahead by at least"
        return f"{cl.a} vs {cl.b} on {cols}: {rel} {cl.delta}"
    if cl.direction == "stable" and cl.delta is not None:
        return f"{', '.join(cl.rows)}: stable within {cl.delta} on {cols}"
    return f"{', '.join(cl.rows)}: {cl.direction} on {cols}"


def make_view(spec, plan_rows: dict[str, dict], summary: dict | None, footer: list[str],
              dataset: str | None, unbuilt: dict[str, str] | None = None) -> TableView:
    """The reported-vs-reproduced view from a spec and (optionally) a run's summary;
    ``unbuilt`` names the columns whose protocol is not built (they read "not implemented").
    A figure's view has its per-x cells (:func:`repro.engine.figures.figure_view`)."""
    from repro.engine.figures import column_views, figure_view, is_figure

    cells = (summary or {}).get("cells", {})
    unbuilt = (summary or {}).get("unbuilt_columns", {}) if unbuilt is None else unbuilt
    test_sets = (summary or {}).get("test_sets")  # recorded by the run (table_facts.test_sets_stored)
    if is_figure(spec):
        fig = figure_view(spec, plan_rows, summary, footer, _standin(dataset),
                          _paper_title(spec), unbuilt, _claim_views(spec, summary))
        fig.test_sets = test_sets
        return fig
    cols = column_views(spec)
    rows = []
    for row in spec.rows:
        st = plan_rows.get(row.id, {}).get("status", NOT_RUN)
        reason = plan_rows.get(row.id, {}).get("reason")
        rv = RowView(row.id, row.label, row.method, st, note=reason)
        for c in spec.columns:
            rep = row.reported.get(c.id)
            printed = rep.printed if rep is not None else None
            if getattr(c, "harness", False):
                printed = "not in paper"
            elif rep is not None and getattr(rep, "certain", True) is False:
                printed = f"{printed}?"  # the spec marks the extraction uncertain (its note says why)
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
    uncertain = [f"{row.id}/{cid}" for row in spec.rows for cid, rep in row.reported.items()
                 if getattr(rep, "certain", True) is False]
    if uncertain:
        footer = list(footer) + [f"Paper cells marked '?' ({', '.join(uncertain)}) are uncertain "
                                 "in the PDF extraction (the spec's note says why); never used."]
    return TableView(spec.id, spec.title, _paper_title(spec), cols, rows,
                     _claim_views(spec, summary), footer, _standin(dataset), spec.interval,
                     test_sets=test_sets)


def _claim_views(spec, summary: dict | None) -> list[ClaimView]:
    claims = []
    by_id = {c["id"]: c for c in (summary or {}).get("claims", [])}
    for cl in spec.claims:
        got = by_id.get(cl.id)
        claims.append(ClaimView(cl.id, claim_text(spec, cl), cl.source,
                                None if got is None else got.get("probability"),
                                "not evaluated" if got is None else got["verdict"],
                                None if got is None else got.get("reason"),
                                None if got is None else _evidence_text(got)))
    return claims


#: what a claim of a run recorded before verdicts carried their evidence says instead
NO_EVIDENCE = ("not recorded: a run made before verdicts carried their evidence (budget far "
               "below the paper's unless its footer says otherwise); rerun to get it")


def _evidence_text(claim: dict) -> str | None:
    if claim.get("verdict") == "not evaluated":
        return None
    ev = claim.get("evidence")
    return ev.get("text") if ev else NO_EVIDENCE


def _standin(dataset: str | None) -> str | None:
    from repro.specs import names

    if dataset is None:
        return None
    # a declared data set (repro.data.dataset_spec) is never a paper's: a stand-in too
    return None if names.dataset_kind(dataset) == names.PAPER else dataset


def _paper_title(spec) -> str:
    from repro.specs import names

    return names.PAPERS[spec.paper.key].title if hasattr(
        names, "PAPERS") and spec.paper.key in names.PAPERS else spec.paper.title
