"""The neutral view of a reported-vs-reproduced table, built by the engine, drawn by renderers.

Keeping the view separate from specs and run records lets every output format (terminal,
Markdown, LaTeX, HTML, JSON, CSV) show exactly the same cells, statuses and footers.

A figure (:class:`FigureView`) is a table whose cells are per x point: row ``r``'s cell of
column ``c`` at x is ``rows[r].cells[f"{c}@{x}"]`` (:func:`x_cell_id`), for every x of
``x.values`` (the x the run reproduced); before a run (no x) a row's cell of ``c`` is keyed by
``c`` alone and only carries a status.  A figure prints no numbers, so ``reported`` is None.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

# Cell / row statuses, said in words in every format (never a number where there is none).
OK = "ok"
NOT_IMPLEMENTED = "not implemented"
DATA_UNAVAILABLE = "data unavailable"
NOT_RUN = "not run"
FAILED = "failed"
NOT_REPORTED = "not reported"


@dataclass
class CellView:
    """One cell: the paper's printed value beside ours.

    ``value`` is the mean over replicates; ``paper_pm`` the half-width in the paper's own
    convention (``interval``); ``ci`` our bootstrap interval; ``n`` the replicate count.
    """

    reported: str | None = None
    value: float | None = None
    paper_pm: float | None = None
    ci: tuple[float, float] | None = None
    n: int = 0
    status: str = NOT_RUN
    note: str | None = None


@dataclass
class ColumnView:
    id: str
    label: str
    direction: str = ""  # lower | higher | closer_to_real
    unit: str = ""


@dataclass
class RowView:
    id: str
    label: str
    method: str
    status: str
    cells: dict[str, CellView] = field(default_factory=dict)
    note: str | None = None


@dataclass
class ClaimView:
    id: str
    text: str
    source: str = ""
    probability: float | None = None
    verdict: str = "not evaluated"
    reason: str | None = None
    evidence: str | None = None  # what decided the verdict (repro.engine.evidence)


@dataclass
class TableView:
    id: str
    title: str
    paper: str
    columns: list[ColumnView]
    rows: list[RowView]
    claims: list[ClaimView] = field(default_factory=list)
    footer: list[str] = field(default_factory=list)
    standin: str | None = None  # the stand-in data set's name when it is not the paper's
    interval: str = "none"
    # what each multi-action test set holds (issue 26; None: the table draws none, or has not
    # run): {set: {unseen_share, median_support, class_share_by_position, ...}}
    test_sets: dict | None = None
    # short marks every format shows beside the title (issue 28): a run under a non-standard
    # real-data gate, a newest run that failed; the footer says the rest
    marks: list[str] = field(default_factory=list)
    # the newest run of the table when it did not finish (FAILED / INTERRUPTED), newer than
    # the run shown: {run_id, status, ended, error}
    failed_run: dict | None = None

    def to_dict(self) -> dict:
        return asdict(self)


def data_mark(name: str) -> str:
    """The title's mark of a data set that is not the paper's: ``STAND-IN DATA: bandai2`` for
    a built-in stand-in, ``OWN DATA: mylab`` for one a data-set spec declares (issue 28: it
    is not a stand-in the harness ships, and never called one)."""
    from repro.specs import names

    return (f"STAND-IN DATA: {name}" if names.dataset_kind(name) == names.STANDIN
            else f"OWN DATA: {name}")


#: Separator of a figure's per-x cell ids: ``"overall.acc@3"`` is column overall.acc at x = 3.
X_SEP = "@"


def x_cell_id(column_id: str, x: int) -> str:
    return f"{column_id}{X_SEP}{x}"


def format_xs(xs) -> str:
    """``[1, 2, 3, 5, 7, 8]`` → ``"1..3, 5, 7..8"``."""
    xs = sorted(set(xs))
    runs: list[list[int]] = []
    for x in xs:
        if runs and x == runs[-1][1] + 1:
            runs[-1][1] = x
        else:
            runs.append([x, x])
    return ", ".join(str(a) if a == b else f"{a}..{b}" for a, b in runs)


@dataclass
class AxisView:
    """A figure's x axis: the paper's range and the x the run reproduced."""

    id: str
    label: str
    start: int
    stop: int
    values: list[int] = field(default_factory=list)


@dataclass
class FigureView(TableView):
    x: AxisView | None = None

    def cell_keys(self, column_id: str) -> list[tuple[str, str]]:
        """(x as text, cell key) of one column, in x order; one ("–", column id) before a run."""
        if self.x is None or not self.x.values:
            return [("–", column_id)]
        return [(str(x), x_cell_id(column_id, x)) for x in self.x.values]

    def axis_line(self) -> str:
        a = self.x
        if a is None:
            return "figure: no printed values"
        got = f"x {format_xs(a.values)}" if a.values else "nothing yet"
        return f"figure: no printed values; x: {a.label} {a.start}..{a.stop}; reproduced: {got}"
