"""``repro claims [TABLE ...]``: every claim of every spec on one page, one line each (issue 32,
item 6): paper, table, claim, verdict, P, converged, variance, budget, from each table's newest
finished run (:mod:`repro.engine.claims_list`)."""

from __future__ import annotations

#: --format's choices: a rich table, or :func:`repro.engine.claims_list.render_claims`' formats
CLAIMS_FORMATS = ("term", "md", "json", "csv")


def register(sub) -> None:
    p = sub.add_parser("claims", help="every claim of every spec, one line each: verdict, P, "
                       "converged, variance, budget",
                       description="Each table's claims with what its newest finished run "
                       "says (any scale unless --scale is given); a table without a run lists "
                       "its claims as 'not run'.")
    p.add_argument("tables", nargs="*", metavar="TABLE",
                   help="only these tables (default: every spec)")
    p.add_argument("--scale", default=None,
                   help="quick | medium | paper | converged: read the run `repro show TABLE "
                   "--scale S` shows (default: the newest finished run at any scale, so "
                   "profiles may mix: name one to compare like with like)")
    p.add_argument("--format", default="term", choices=CLAIMS_FORMATS,
                   help="term | md | json | csv (default term)")
    p.set_defaults(func=cmd_claims)


def cmd_claims(args) -> int:
    from repro.engine.claims_list import NOT_RUN, list_claims, render_claims

    if args.scale is not None:  # an unknown scale: one line, before any run is read
        from repro.specs.scales import resolve_scale

        resolve_scale(args.scale)
    entries = list_claims(args.tables or None, scale=args.scale)
    if args.format != "term":
        print(render_claims(entries, args.format), end="")
        return 0
    tables = list(dict.fromkeys(e["table"] for e in entries))
    not_run = {e["table"] for e in entries if e["verdict"] == NOT_RUN}
    where = f"at scale {args.scale}" if args.scale else "at any scale"
    _print_term(entries, f"{len(entries)} claims of {len(tables)} tables, from the newest "
                         f"finished run of each {where}; tables not run: {len(not_run)}")
    return 0


#: the colour of each kind of verdict (:func:`repro.engine.claims_list.verdict_kind`)
VERDICT_STYLES = {"supported": "green", "contradicted": "red", "none": "dim", "other": "yellow"}


def _print_term(entries: list[dict], caption: str) -> None:
    """The claims as a rich table; every cell is a :class:`rich.text.Text` (never markup)."""
    from rich.console import Console
    from rich.table import Table
    from rich.text import Text

    from repro.engine.claims_list import HEADINGS, claim_cells, verdict_kind

    t = Table(show_lines=False)
    for col in HEADINGS:
        t.add_column(col, overflow="fold", justify="right" if col == "P" else "left",
                     no_wrap=col in ("paper", "table", "P", "converged"))
    for e in entries:
        cells = [Text(c) for c in claim_cells(e)]
        cells[3].stylize(VERDICT_STYLES[verdict_kind(e["verdict"])])
        t.add_row(*cells)
    con = Console()
    if not con.is_terminal:  # a pipe or a file: wide enough for one line per claim
        con = Console(width=160)
    con.print(t)
    con.print(caption, highlight=False, markup=False, soft_wrap=True)
