"""The pydantic schema of a table spec (``tables/<paper>/<table>.toml``).

A :class:`TableSpec` names the paper and its table or figure, the paper's data set and the
default stand-in, the protocol, the columns (metric + direction), the rows (a method + variant
overrides), every number the paper printed (verbatim, beside its parsed value and ±), the
paper's interval convention, and the paper's claims as structured records.  Unknown keys are
errors (``extra="forbid"``); names of methods, metrics, data sets, protocols and interval
conventions come from :mod:`repro.specs.names` and are refused with a did-you-mean.

Structural validation lives here; cross-references (a claim naming a row that exists, a
reported cell naming a column that exists, ...) are checked by :func:`cross_check`, which the
loader runs after the model validates.  The format is described in ``docs/specs.md``.
"""

from __future__ import annotations

import re
from functools import partial
from typing import Annotated, Any, Literal, Union

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    StrictFloat,
    StrictInt,
    StrictStr,
    computed_field,
    field_validator,
    model_validator,
)

from repro.keys import content_key
from repro.specs import names

SCHEMA_VERSION = 1

# Names checked against the vocabularies of repro.specs.names ("unknown method 'marionett' (did
# you mean 'marionet'?)"); one validator per kind, used by every model here and in scales.py.
PaperName = Annotated[str, AfterValidator(partial(names.require_known, "paper"))]
DatasetName = Annotated[str, AfterValidator(partial(names.require_known, "dataset"))]
StandinName = Annotated[str, AfterValidator(names.require_standin)]
MethodName = Annotated[str, AfterValidator(partial(names.require_known, "method"))]
MetricName = Annotated[str, AfterValidator(partial(names.require_known, "metric"))]
ProtocolName = Annotated[str, AfterValidator(partial(names.require_known, "protocol"))]
IntervalName = Annotated[str, AfterValidator(partial(names.require_known, "interval"))]

Scalar = Union[StrictBool, StrictInt, StrictFloat, StrictStr]
ParamValue = Union[Scalar, list[Scalar]]
Params = dict[str, ParamValue]

#: a spec's hand-bumped ``version``: an integer 1 .. 1,000,000 (issue 29: 10^23 was accepted)
MAX_SPEC_VERSION = 1_000_000
#: a protocol's ``fps`` (frames per second of the data it reads): in (0, 1000]
MAX_PROTOCOL_FPS = 1000.0


def fps_problem(value: object) -> str | None:
    """Why ``value`` is not a protocol frame rate (a number in (0, :data:`MAX_PROTOCOL_FPS`]),
    or None; shared with the scale profiles' protocol tables."""
    if isinstance(value, (int, float)) and not isinstance(value, bool) and \
            0 < value <= MAX_PROTOCOL_FPS:
        return None
    return (f"fps must be a number of frames per second above 0 and at most "
            f"{MAX_PROTOCOL_FPS:g} (got {value!r:.40})")


def _bounded_params(v: dict) -> dict:
    problem = fps_problem(v["fps"]) if "fps" in v else None
    if problem is not None:
        raise ValueError(problem)
    return v


#: ``protocol_params`` tables: :data:`Params` whose ``fps``, when set, is a sane frame rate
ProtocolParams = Annotated[Params, AfterValidator(_bounded_params)]

ROW_ID = r"^[a-z0-9][a-z0-9_\-]*$"
COLUMN_ID = r"^[a-z0-9][a-z0-9_]*(\.[a-z0-9][a-z0-9_]*)?$"
SPEC_ID = r"^[a-z0-9]+/[A-Za-z0-9_]+$"

#: Printed strings that mean "the paper reports nothing here".
NOT_REPORTED = frozenset({"", "/", "-", "–", "—", "n/a", "N/A"})

_NUM = r"[-+]?(?:\d+(?:\.\d*)?|\.\d+)"
_PRINTED = re.compile(rf"^(?P<v>{_NUM})\s*(?P<pct>%)?\s*(?:±\s*(?P<h>{_NUM}))?$")


def parse_printed(printed: str) -> tuple[float | None, float | None, bool]:
    """Parse a printed cell: ``"0.74±0.019"`` → ``(0.74, 0.019, False)``;
    ``"15.22%±.92"`` → ``(15.22, 0.92, True)``; ``"/"`` → ``(None, None, False)``.

    The value stays in the column's printed unit (a percentage stays 15.22).  Raises
    ``ValueError`` for anything else, so a mistyped cell never passes silently.
    """
    s = printed.strip()
    if s in NOT_REPORTED:
        return None, None, False
    m = _PRINTED.match(s)
    if not m:
        raise ValueError(f"cannot parse printed value {printed!r}: expected a number, "
                         "optionally with '%' and '±half-width' (e.g. '0.74±0.019', '99.70±.06'), "
                         "or '/' for not reported")
    h = m.group("h")
    return float(m.group("v")), (float(h) if h is not None else None), m.group("pct") is not None


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_default=True)


# ----------------------------------------------------------------------------------------------
# parts


class PaperRef(_Strict):
    """Which paper and which of its tables or figures the spec reproduces."""

    key: PaperName = Field(description="paper key: marionette | multiact | odmo")
    title: str = Field(min_length=3)
    file: str = Field(description="text extraction in ../shared/papers/ the numbers come from")
    table_label: str = Field(min_length=3, description="as the paper labels it: 'Table 3', 'Fig. 8'")
    caption: str = Field(min_length=8, description="a verbatim fragment of the caption as extracted "
                         "(locates the table in the text file)")
    section: str | None = Field(None, description="the section that discusses the table")


class Axis(_Strict):
    """The x axis of a figure (e.g. the action index 1..20 of a multi-action sequence)."""

    id: str = Field(pattern=r"^[a-z][a-z0-9_]*$")
    label: str
    start: int
    stop: int = Field(description="inclusive")

    @model_validator(mode="after")
    def _ordered(self):
        if self.stop < self.start:
            raise ValueError(f"x.stop ({self.stop}) is below x.start ({self.start})")
        return self


class ColumnGroup(_Strict):
    """A band of columns sharing a protocol setting, data set or test set ("Overall",
    "HumanAct12").  Columns join a group by the prefix of their id (``overall.acc``)."""

    id: str = Field(pattern=r"^[a-z0-9][a-z0-9_]*$")
    label: str
    protocol: ProtocolName | None = Field(None, description="overrides the table's protocol for "
                                          "this band")
    paper_dataset: DatasetName | None = Field(None, description="overrides the table's paper "
                                              "data set")
    protocol_params: ProtocolParams = Field(default_factory=dict)
    note: str | None = None


class Column(_Strict):
    """One measured column: a metric, its direction and unit (defaults from the metric)."""

    id: str = Field(pattern=COLUMN_ID, description="'<group>.<name>' inside a group, else '<name>'")
    metric: MetricName
    label: str = Field(description="the column header as the paper prints it")
    direction: Literal["lower", "higher", "closer_to_real"] | None = Field(
        None, description="default: the metric's direction")
    unit: str | None = Field(None, description="default: the metric's unit")
    reference: str | None = Field(None, description="closer_to_real columns: the row that is 'real'"
                                  " (default: the only row whose method is 'real')")
    harness: bool = Field(False, description="a column the harness adds, not in the paper "
                          "(no reported values; shown marked 'harness')")
    note: str | None = None

    @model_validator(mode="after")
    def _defaults(self):
        info = names.METRICS[self.metric]
        if self.direction is None:
            self.direction = info.direction
        if self.unit is None:
            self.unit = info.unit
        return self

    @property
    def group(self) -> str | None:
        return self.id.split(".", 1)[0] if "." in self.id else None


class ReportedCell(_Strict):
    """A number as the paper printed it.  ``printed`` is verbatim (its precision is
    information); ``value`` and ``paper_halfwidth`` are parsed from it.

    ``certain = false`` marks a cell whose attribution the PDF extraction leaves open (a merged
    or shifted cell); such a cell is shown but never used to check a claim.  ``extracted`` is
    the text exactly as the extraction has it when it differs from ``printed`` (garbled cells).
    """

    printed: str
    certain: bool = True
    extracted: str | None = None
    note: str | None = None

    @field_validator("printed")
    @classmethod
    def _parses(cls, v: str) -> str:
        parse_printed(v)
        return v

    @model_validator(mode="after")
    def _uncertain_needs_note(self):
        if not self.certain and not self.note:
            raise ValueError("a cell with certain = false needs a note saying what is uncertain")
        return self

    @computed_field  # type: ignore[prop-decorator]
    @property
    def value(self) -> float | None:
        return parse_printed(self.printed)[0]

    @computed_field  # type: ignore[prop-decorator]
    @property
    def paper_halfwidth(self) -> float | None:
        return parse_printed(self.printed)[1]

    @property
    def percent(self) -> bool:
        return parse_printed(self.printed)[2]

    @property
    def reported(self) -> bool:
        """False for '/', '-' and friends: the paper prints no number here."""
        return self.value is not None


_CELL_KEYS = frozenset(ReportedCell.model_fields)


def _flatten_reported(raw: Any) -> Any:
    """Accept ``{"overall.acc": "0.786"}``, nested TOML ``overall.acc = "0.786"`` (a dict of
    dicts) and bare strings; return ``{column_id: {"printed": ...}}``."""
    if not isinstance(raw, dict):
        return raw
    out: dict[str, Any] = {}

    def walk(prefix: str, obj: dict):
        for k, v in obj.items():
            key = f"{prefix}.{k}" if prefix else str(k)
            if isinstance(v, str):
                out[key] = {"printed": v}
            elif isinstance(v, dict) and not (_CELL_KEYS & set(v)):
                walk(key, v)
            else:
                out[key] = v

    walk("", raw)
    return out


class Row(_Strict):
    """One row: a method plus variant overrides, and what the paper printed for it."""

    id: str = Field(pattern=ROW_ID)
    label: str = Field(description="the row label as the paper prints it")
    method: MethodName
    overrides: Params = Field(default_factory=dict, description="variant settings, e.g. "
                              "time_unrolling = false; keys are validated by the method")
    interval: IntervalName | None = Field(None, description="this row's ± convention when it "
                                          "differs from the table's (a row copied from another "
                                          "paper)")
    reported: dict[str, ReportedCell] = Field(default_factory=dict)
    note: str | None = None

    @field_validator("reported", mode="before")
    @classmethod
    def _flatten(cls, v):
        return _flatten_reported(v)


def _as_list(v):
    return [v] if isinstance(v, str) else v


class Claim(_Strict):
    """A claim of the paper as a structured record, with the sentence it comes from.

    - ``order``: row ``better`` beats every row in ``than`` on each column (on a figure, at
      every x of ``x_range``, the whole axis when absent).
    - ``gap``: on each column, ``a`` beats ``b`` by at least ``delta`` (``bound = "at_least"``,
      measured in the column's direction: a − b for higher, b − a for lower, the reduction of
      the distance to the reference row for closer_to_real), or ``|a − b| ≤ delta``
      (``bound = "within"``).
    - ``trend``: along the figure's x axis (``along = "x"``) each row in ``rows`` follows
      ``direction`` (decreasing | increasing | stable within ``delta``); with ``along = "rows"``
      the values of ``rows``, in the listed order, do.

    ``direction`` of an order/gap claim defaults to the column's.  ``holds_on_reported``
    records whether the paper's own certain numbers support the claim (checked by
    ``repro spec check``; mark it ``false`` with a note where the paper contradicts itself).
    """

    id: str = Field(pattern=ROW_ID)
    kind: Literal["order", "gap", "trend"]
    column: list[str] = Field(min_length=1, description="one column id or a list")
    better: str | None = None
    than: list[str] = Field(default_factory=list)
    a: str | None = None
    b: str | None = None
    delta: float | None = Field(None, ge=0)
    bound: Literal["at_least", "within"] = "at_least"
    rows: list[str] = Field(default_factory=list)
    along: Literal["x", "rows"] | None = None
    x_range: tuple[int, int] | None = Field(None, description="inclusive x range (figures)")
    direction: str | None = None
    holds_on_reported: bool = True
    source: str = Field(min_length=10, description="the paper's sentence(s); fragments joined "
                        "by ' … ' must each occur in the paper text")
    note: str | None = None

    @field_validator("column", "than", "rows", mode="before")
    @classmethod
    def _listify(cls, v):
        return _as_list(v)

    @model_validator(mode="after")
    def _fields_match_kind(self):
        k = self.kind
        problems = []

        def forbid(*fields):
            for f in fields:
                v = getattr(self, f)
                if v not in (None, [], "at_least"):
                    problems.append(f"'{f}' is not used by a {k} claim")

        if k == "order":
            if not self.better or not self.than:
                problems.append("an order claim needs 'better' and 'than'")
            if self.better in self.than:
                problems.append(f"row {self.better!r} is both 'better' and in 'than'")
            forbid("a", "b", "delta", "rows", "along")
            forbid("bound")
        elif k == "gap":
            if not self.a or not self.b or self.delta is None:
                problems.append("a gap claim needs 'a', 'b' and 'delta'")
            if self.a and self.a == self.b:
                problems.append("'a' and 'b' must differ")
            forbid("better", "than", "rows", "along")
        else:
            if not self.rows or self.along is None:
                problems.append("a trend claim needs 'rows' and 'along' ('x' or 'rows')")
            if self.direction not in names.TREND_DIRECTIONS:
                problems.append(f"a trend claim's direction must be one of "
                                f"{', '.join(names.TREND_DIRECTIONS)}{names.suggest(self.direction or '', names.TREND_DIRECTIONS)}")
            if self.direction == "stable" and self.delta is None:
                problems.append("a 'stable' trend needs 'delta' (the largest allowed spread)")
            if self.along == "rows" and len(self.rows) < 2:
                problems.append("a trend along rows needs at least two rows")
            forbid("better", "than", "a", "b")
            forbid("bound")
        if k in ("order", "gap") and self.direction is not None \
                and self.direction not in names.DIRECTIONS:
            problems.append(f"direction {self.direction!r} is not one of "
                            f"{', '.join(names.DIRECTIONS)}{names.suggest(self.direction, names.DIRECTIONS)}")
        if self.x_range is not None and self.x_range[1] < self.x_range[0]:
            problems.append("x_range must be [low, high]")
        if problems:
            raise ValueError("; ".join(problems))
        return self

    def involved_rows(self) -> list[str]:
        rows = [self.better, *self.than, self.a, self.b, *self.rows]
        return [r for r in rows if r]


# ----------------------------------------------------------------------------------------------
# the spec


class TableSpec(_Strict):
    """One paper table or figure, complete enough that a reader of the paper recognises every
    row and column.  ``version`` is bumped whenever the spec changes and is stamped into every
    run made from it, beside :attr:`spec_hash`."""

    model_config = ConfigDict(extra="forbid", validate_default=True, populate_by_name=True)

    schema_version: Literal[1] = Field(alias="schema", description="spec format version (1)")
    id: str = Field(pattern=SPEC_ID, description="'<paper>/<table>', e.g. 'marionette/table3'")
    version: int = Field(ge=1, le=MAX_SPEC_VERSION)
    kind: Literal["table", "figure"] = "table"
    paper: PaperRef
    title: str = Field(min_length=3)
    protocol: ProtocolName
    paper_dataset: DatasetName
    standin_dataset: StandinName
    interval: IntervalName = Field(description="the paper's ± convention for this table")
    x: Axis | None = Field(None, description="figures: the x axis of the curves")
    groups: list[ColumnGroup] = Field(default_factory=list)
    columns: Annotated[list[Column], Field(min_length=1)]
    rows: Annotated[list[Row], Field(min_length=1)]
    claims: list[Claim] = Field(default_factory=list)
    protocol_params: ProtocolParams = Field(default_factory=dict, description="what the paper fixes for "
                                    "this table (test set, windows, its sample counts); the scale "
                                    "profile's protocol table overrides keys it also sets")
    note: str | None = None

    # -- identity --------------------------------------------------------------------------

    @property
    def spec_hash(self) -> str:
        """sha256 of the canonical JSON of the validated spec (comments and layout of the TOML
        file do not count; every value does)."""
        return content_key(self.model_dump(mode="json", by_alias=True))

    # -- lookups ---------------------------------------------------------------------------

    def row(self, row_id: str) -> Row:
        for r in self.rows:
            if r.id == row_id:
                return r
        raise KeyError(row_id)

    def column(self, column_id: str) -> Column:
        for c in self.columns:
            if c.id == column_id:
                return c
        raise KeyError(column_id)

    def group(self, group_id: str) -> ColumnGroup:
        for g in self.groups:
            if g.id == group_id:
                return g
        raise KeyError(group_id)

    def group_of(self, column_id: str) -> ColumnGroup | None:
        gid = self.column(column_id).group
        return None if gid is None else self.group(gid)

    def protocol_for(self, column_id: str) -> str:
        g = self.group_of(column_id)
        return g.protocol if g is not None and g.protocol else self.protocol

    def paper_dataset_for(self, column_id: str) -> str:
        g = self.group_of(column_id)
        return g.paper_dataset if g is not None and g.paper_dataset else self.paper_dataset

    def protocol_params_for(self, column_id: str) -> dict[str, Any]:
        """The table's protocol_params overlaid by the column group's."""
        g = self.group_of(column_id)
        return {**self.protocol_params, **(g.protocol_params if g is not None else {})}

    def interval_for(self, row_id: str) -> str:
        return self.row(row_id).interval or self.interval

    def reference_row(self, column_id: str) -> str | None:
        """The row a closer_to_real column is compared with (None for other directions)."""
        col = self.column(column_id)
        if col.direction != "closer_to_real":
            return None
        if col.reference:
            return col.reference
        reals = [r.id for r in self.rows if r.method == "real"]
        return reals[0] if len(reals) == 1 else None

    def reported(self, row_id: str, column_id: str) -> ReportedCell | None:
        return self.row(row_id).reported.get(column_id)

    def n_reported(self) -> int:
        return sum(1 for r in self.rows for c in r.reported.values() if c.reported)


# ----------------------------------------------------------------------------------------------
# cross-references


def _dups(ids: list[str]) -> list[str]:
    seen, dup = set(), []
    for i in ids:
        if i in seen and i not in dup:
            dup.append(i)
        seen.add(i)
    return dup


def cross_check(spec: TableSpec) -> list[tuple[str, str]]:
    """Problems between the parts of a validated spec, as ``(location, problem)`` pairs."""
    return [*_check_header(spec), *_check_columns(spec), *_check_rows(spec),
            *_check_claims(spec)]


def _check_header(spec: TableSpec) -> list[tuple[str, str]]:
    """:func:`cross_check` of the spec's id, paper and kind, then of duplicate ids."""
    out: list[tuple[str, str]] = []
    paper, _, _ = spec.id.partition("/")
    if paper != spec.paper.key:
        out.append(("id", f"spec id {spec.id!r} starts with {paper!r} but paper.key is "
                          f"{spec.paper.key!r}"))
    expected_file = names.PAPERS[spec.paper.key].file
    if spec.paper.file != expected_file:
        out.append(("paper.file", f"{spec.paper.file!r} is not the text of paper "
                                  f"{spec.paper.key!r} ({expected_file!r})"))
    if spec.kind == "figure" and spec.x is None:
        out.append(("x", "a figure needs an x axis"))
    if spec.kind == "table" and spec.x is not None:
        out.append(("x", "only a figure has an x axis (set kind = \"figure\")"))

    for what, ids in (("group", [g.id for g in spec.groups]), ("column", [c.id for c in spec.columns]),
                      ("row", [r.id for r in spec.rows]), ("claim", [c.id for c in spec.claims])):
        for d in _dups(ids):
            out.append((f"{what}s", f"duplicate {what} id {d!r}"))
    return out


def _check_columns(spec: TableSpec) -> list[tuple[str, str]]:
    """:func:`cross_check` of the columns (their groups and reference rows), then of the groups
    (each needs a column)."""
    out: list[tuple[str, str]] = []
    group_ids = [g.id for g in spec.groups]
    row_ids = [r.id for r in spec.rows]
    real_rows = [r.id for r in spec.rows if r.method == "real"]

    for i, c in enumerate(spec.columns):
        loc = f"columns[{i}] (id {c.id!r})"
        if c.group is not None and c.group not in group_ids:
            out.append((loc, f"group {c.group!r} is not declared in [[groups]]"
                             f"{names.suggest(c.group, group_ids)}"))
        if c.reference is not None:
            if c.direction != "closer_to_real":
                out.append((f"{loc}.reference", "only a closer_to_real column has a reference row"))
            elif c.reference not in row_ids:
                out.append((f"{loc}.reference", f"unknown row {c.reference!r}"
                                                f"{names.suggest(c.reference, row_ids)}"))
        elif c.direction == "closer_to_real" and len(real_rows) != 1 and not c.harness:
            # (a harness column carries no claim, so it needs no reference row)
            out.append((loc, "a closer_to_real column needs a reference row: set 'reference' "
                             f"(rows with method 'real': {', '.join(real_rows) or 'none'})"))
    for i, g in enumerate(spec.groups):
        if not any(c.group == g.id for c in spec.columns):
            out.append((f"groups[{i}] (id {g.id!r})", "no column belongs to this group"))
    return out


def _check_rows(spec: TableSpec) -> list[tuple[str, str]]:
    """:func:`cross_check` of the rows' reported values against the columns."""
    out: list[tuple[str, str]] = []
    col_ids = [c.id for c in spec.columns]
    for i, r in enumerate(spec.rows):
        loc = f"rows[{i}] (id {r.id!r})"
        for cid, cell in r.reported.items():
            if cid not in col_ids:
                out.append((f"{loc}.reported", f"unknown column {cid!r}{names.suggest(cid, col_ids)}"))
                continue
            col = spec.column(cid)
            if col.harness:
                out.append((f"{loc}.reported.{cid}", "a harness column is not in the paper: "
                                                     "it has no reported values"))
                continue
            if cell.percent and col.unit != "%":
                out.append((f"{loc}.reported.{cid}", f"printed {cell.printed!r} has '%' but the "
                                                     f"column's unit is {col.unit!r}"))
        if spec.kind == "figure" and r.reported:
            out.append((f"{loc}.reported", "a figure prints no numbers; leave 'reported' empty"))
    return out


def _check_claims(spec: TableSpec) -> list[tuple[str, str]]:
    """:func:`cross_check` of the claims: their columns, rows, ``along`` and ``x_range``."""
    out: list[tuple[str, str]] = []
    col_ids = [c.id for c in spec.columns]
    row_ids = [r.id for r in spec.rows]
    for i, cl in enumerate(spec.claims):
        loc = f"claims[{i}] (id {cl.id!r})"
        for cid in cl.column:
            if cid not in col_ids:
                out.append((f"{loc}.column", f"unknown column {cid!r}{names.suggest(cid, col_ids)}"))
            elif spec.column(cid).harness:
                out.append((f"{loc}.column", f"column {cid!r} is a harness column: the paper "
                                             "claims nothing about it"))
        for field in ("better", "than", "a", "b", "rows"):
            val = getattr(cl, field)
            for rid in ([val] if isinstance(val, str) else (val or [])):
                if rid not in row_ids:
                    out.append((f"{loc}.{field}", f"unknown row {rid!r}{names.suggest(rid, row_ids)}"))
        if cl.along == "x" and spec.kind != "figure":
            out.append((f"{loc}.along", "'along = \"x\"' needs a figure (a table has no x axis)"))
        if cl.x_range is not None:
            if spec.x is None:
                out.append((f"{loc}.x_range", "x_range needs a figure with an x axis"))
            elif cl.x_range[0] < spec.x.start or cl.x_range[1] > spec.x.stop:
                out.append((f"{loc}.x_range", f"{list(cl.x_range)} lies outside the axis "
                                              f"[{spec.x.start}, {spec.x.stop}]"))
    return out
