"""Do the paper's own printed numbers support its claims?

``repro spec check`` evaluates every order / gap / trend-along-rows claim on the spec's
*certain* reported cells and compares the result with the claim's ``holds_on_reported``.  This
catches transcription slips (a digit typed wrong flips an ordering) and documents where a paper
contradicts its own table.  Figure trends (``along = "x"``) have no printed numbers and are not
evaluable here.  Comparisons are strict: a tie does not count as "better".

This is a plain check on printed numbers; the verdicts on reproduced numbers (with their
uncertainty) live in ``repro.stats``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from repro.specs.schema import Claim, TableSpec


@dataclass(frozen=True)
class ReportedCheck:
    """``result``: True / False, or None when no column could be evaluated (missing or
    uncertain cells, figure curves).  ``per_column`` gives the same per column id."""

    claim_id: str
    result: bool | None
    per_column: dict[str, bool | None] = field(default_factory=dict)


def _value(spec: TableSpec, row_id: str, column_id: str) -> float | None:
    cell = spec.reported(row_id, column_id)
    if cell is None or not cell.certain:
        return None
    return cell.value


def _score(spec: TableSpec, claim: Claim, row_id: str, column_id: str) -> float | None:
    """A number where larger is better, in the claim's (or column's) direction."""
    v = _value(spec, row_id, column_id)
    if v is None:
        return None
    direction = claim.direction or spec.column(column_id).direction
    if direction == "higher":
        return v
    if direction == "lower":
        return -v
    ref_row = spec.reference_row(column_id)
    ref = _value(spec, ref_row, column_id) if ref_row else None
    return None if ref is None else -abs(v - ref)


def _order(spec: TableSpec, claim: Claim, col: str) -> bool | None:
    best = _score(spec, claim, claim.better, col)
    others = [_score(spec, claim, r, col) for r in claim.than]
    if best is None or any(o is None for o in others):
        return None
    return all(best > o for o in others)


def _gap(spec: TableSpec, claim: Claim, col: str) -> bool | None:
    if claim.bound == "within":
        a, b = _value(spec, claim.a, col), _value(spec, claim.b, col)
        if a is None or b is None:
            return None
        return abs(a - b) <= claim.delta + 1e-12
    sa, sb = _score(spec, claim, claim.a, col), _score(spec, claim, claim.b, col)
    if sa is None or sb is None:
        return None
    return sa - sb >= claim.delta - 1e-12


def _trend_rows(spec: TableSpec, claim: Claim, col: str) -> bool | None:
    vals = [v for v in (_value(spec, r, col) for r in claim.rows) if v is not None]
    if len(vals) < 2:
        return None
    if claim.direction == "decreasing":
        return all(b < a for a, b in zip(vals, vals[1:]))
    if claim.direction == "increasing":
        return all(b > a for a, b in zip(vals, vals[1:]))
    return max(vals) - min(vals) <= claim.delta + 1e-12


def check_claim_on_reported(spec: TableSpec, claim: Claim) -> ReportedCheck:
    """Evaluate ``claim`` on the spec's certain printed numbers."""
    per: dict[str, bool | None] = {}
    for col in claim.column:
        if claim.kind == "order":
            per[col] = _order(spec, claim, col)
        elif claim.kind == "gap":
            per[col] = _gap(spec, claim, col)
        elif claim.along == "rows":
            per[col] = _trend_rows(spec, claim, col)
        else:
            per[col] = None
    known = [v for v in per.values() if v is not None]
    result = None if not known else all(known)
    return ReportedCheck(claim.id, result, per)


def reported_problems(spec: TableSpec) -> list[tuple[str, str]]:
    """Claims whose evaluation on the printed numbers disagrees with ``holds_on_reported``."""
    out = []
    for i, claim in enumerate(spec.claims):
        chk = check_claim_on_reported(spec, claim)
        if chk.result is None or chk.result == claim.holds_on_reported:
            continue
        failing = [c for c, v in chk.per_column.items() if v is not None and v != claim.holds_on_reported]
        if claim.holds_on_reported:
            msg = (f"the paper's own numbers do not support this claim on {', '.join(failing)}; "
                   "fix the transcription, or set holds_on_reported = false with a note")
        else:
            msg = ("marked holds_on_reported = false, but the paper's numbers support it on "
                   f"every evaluable column ({', '.join(failing)})")
        out.append((f"claims[{i}] (id {claim.id!r})", msg))
    return out
