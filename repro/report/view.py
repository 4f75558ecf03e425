"""The neutral view of a reported-vs-reproduced table, built by the engine, drawn by renderers.

Keeping the view separate from specs and run records lets every output format (terminal,
Markdown, LaTeX, HTML, JSON, CSV) show exactly the same cells, statuses and footers.
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

    def to_dict(self) -> dict:
        return asdict(self)
