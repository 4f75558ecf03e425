"""One page of claims (issue 32, item 6): every claim of every spec, one line each, with what
its newest run says about it — ``repro claims`` and the top of the report's index page.

Each entry carries exactly :data:`KEYS`:

- ``paper``: the paper's key (``marionette``, ``multiact``, ``odmo``);
- ``table``: the spec id (``marionette/table1``);
- ``claim``: the claim in the spec's words (:func:`repro.engine.table_view.claim_text`, as a
  table's page and ``repro show`` word it: rows, columns and what they assert; several claims
  can share the paper's sentence, never this), its id when that is empty;
- ``verdict``: the run's verdict ("supported", "not reproduced at this budget", ...);
  :data:`NOT_RUN` when the table has no finished run to read, "not evaluated" when the run
  holds no verdict of that claim (a run older than the claim);
- ``p``: the posterior probability that the claim holds (None when none was computed);
- ``converged``: True when every trained row the claim involves trained to a measured
  plateau, False when some did not, None when it involves no trained row, the table has no
  run or the run predates the record (``evidence["converged"]``);
- ``variance``: what the intervals hold: ``"sampling"`` (one trained model per row) or
  ``"training seeds"`` (``--retrain``), None without a run or evidence;
- ``budget``: the trained rows' budgets against the paper's schedules, short
  (``"marionet 1%, actor 0.5%*"``; :func:`repro.engine.evidence.budgets_text`), ``"no trained
  row"``, or None without a run or evidence.

Which run: with a scale, the run ``repro show TABLE --scale S`` and the report's table page
show (the newest finished plain run on the profile's data set, or ``dataset``); without one
(``repro claims`` by default), the newest finished plain run of the table at any scale on any
data set.  A table with no such run still lists every claim, as "not run", so the page always
holds every claim of the specs.
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

#: the keys of an entry, in order (the JSON objects', the CSV header's, the table columns')
KEYS = ("paper", "table", "claim", "verdict", "p", "converged", "variance", "budget")
#: the column headings of a printed list (term, Markdown, HTML): the keys, P capitalised
HEADINGS = tuple("P" if k == "p" else k for k in KEYS)
#: the verdict of a claim whose table has no finished run
NOT_RUN = "not run"
#: the verdict of a claim the table's run holds no verdict for (as the table's view says it)
NOT_EVALUATED = "not evaluated"
#: the words of an evidence's ``variance``
VARIANCE_WORDS = {"sampling": "sampling", "training": "training seeds"}
#: the formats :func:`render_claims` writes (``term`` is the CLI's rich table)
FORMATS = ("md", "json", "csv")


def claim_specs(tables: list[str] | None = None) -> list:
    """The specs whose claims are listed: ``tables`` (ids, aliases or spec files; an unknown
    name is the registry's did-you-mean :class:`~repro.errors.ConfigError`), each once, or
    every registered spec in the registry's order when None."""
    from repro.engine.runner import table_spec
    from repro.specs.load import load_all

    if tables is None:
        return list(load_all().values())
    specs: dict[str, object] = {}
    for name in tables:
        spec = table_spec(name)
        specs.setdefault(spec.id, spec)
    return list(specs.values())


def claims_run(spec, scale: str | None = None, dataset: str | None = None) -> Path | None:
    """The run folder whose verdicts are listed for ``spec`` (module docstring, "Which run"),
    None when there is none."""
    from repro.engine.runner import latest_run, table_run

    if scale is None:
        return latest_run(spec.id, dataset=dataset)
    return table_run(spec, scale, dataset)


def _budget(ev: dict, rows: list[str]) -> str | None:
    """The short budget text of the evidence's trained rows, in the claim's row order (as its
    evidence line words it); "no trained row" when it has none, None when a budget cannot be
    read."""
    from repro.engine.evidence import budgets_text

    budgets = ev.get("budgets") if isinstance(ev.get("budgets"), dict) else {}
    order = [r for r in rows if r in budgets] + sorted(set(budgets) - set(rows))
    trained = [budgets[r] for r in order if isinstance(budgets[r], dict)]
    try:
        return budgets_text(trained, short=True) or "no trained row"
    except (KeyError, TypeError, ValueError):  # a record edited by hand: no budget to say
        return None


def _probability(p) -> float | None:
    if isinstance(p, bool) or not isinstance(p, (int, float)) or not math.isfinite(p):
        return None
    return float(p)


def table_claims(spec, path: Path | None) -> list[dict]:
    """One entry (:data:`KEYS`) per claim of ``spec``, in the spec's order, read from the
    ``summary.json`` of the run folder ``path`` (None: every claim :data:`NOT_RUN`)."""
    from repro.engine.table_view import claim_text
    from repro.store.runs import read_summary

    recorded = {}
    if path is not None:
        summary = read_summary(path, required=True)
        recorded = {c.get("id"): c for c in summary.get("claims") or [] if isinstance(c, dict)}
    out = []
    for cl in spec.claims:
        entry = {"paper": spec.paper.key, "table": spec.id,
                 "claim": claim_text(spec, cl) or cl.id, "verdict": NOT_RUN, "p": None,
                 "converged": None, "variance": None, "budget": None}
        if path is not None:
            got = recorded.get(cl.id) or {}
            ev = got.get("evidence") if isinstance(got.get("evidence"), dict) else None
            entry["verdict"] = str(got.get("verdict") or NOT_EVALUATED)
            entry["p"] = _probability(got.get("probability"))
            if ev is not None:
                conv = ev.get("converged")  # absent in records made before it was kept
                entry["converged"] = conv if isinstance(conv, bool) else None
                entry["variance"] = VARIANCE_WORDS.get(ev.get("variance"))
                entry["budget"] = _budget(ev, cl.involved_rows())
        out.append(entry)
    return out


def list_claims(tables: list[str] | None = None, *, scale: str | None = None,
                dataset: str | None = None, runs: dict[str, Path | None] | None = None
                ) -> list[dict]:
    """Every claim of ``tables`` (default: every spec), one entry each (module docstring);
    ``runs`` (spec id -> run folder or None) overrides the run read for those tables (the
    report's ``--run``)."""
    runs = runs or {}
    out: list[dict] = []
    for spec in claim_specs(tables):
        path = runs[spec.id] if spec.id in runs else claims_run(spec, scale, dataset)
        out.extend(table_claims(spec, path))
    return out


def verdict_kind(verdict: str) -> str:
    """What a verdict says, for its colour: ``supported`` or ``contradicted`` (also "...
    at convergence on the stand-in"), ``none`` (:data:`NOT_RUN`, :data:`NOT_EVALUATED`: no
    verdict), else ``other`` (inconclusive, not reproduced ...)."""
    v = str(verdict).lower()
    for kind in ("supported", "contradicted"):
        if v.startswith(kind):
            return kind
    return "none" if v in (NOT_RUN, NOT_EVALUATED) else "other"


def claim_cells(entry: dict) -> list[str]:
    """An entry's values as printed in a table (term, Markdown, HTML), in :data:`KEYS`
    order: P to three decimals, converged yes / no / —, anything missing —."""
    conv = entry.get("converged")
    cells = []
    for k in KEYS:
        v = entry.get(k)
        if k == "converged":
            cells.append("—" if conv is None else "yes" if conv else "no")
        elif k == "p" and v is not None:
            cells.append(f"{v:.3f}")
        else:
            cells.append("—" if v is None else str(v))
    return cells


def render_claims(entries: list[dict], fmt: str) -> str:
    """``entries`` as ``md`` (a Markdown table), ``json`` (a list of objects with exactly
    :data:`KEYS`) or ``csv`` (a header of :data:`KEYS`, then one row per claim: P in full,
    converged yes / no / —, nothing for a missing value)."""
    if fmt == "json":
        return json.dumps([{k: e.get(k) for k in KEYS} for e in entries], indent=2) + "\n"
    if fmt == "md":
        from repro.report.render import md_row

        lines = [md_row(HEADINGS), "|" + "---|" * len(HEADINGS)]
        return "\n".join(lines + [md_row(claim_cells(e)) for e in entries]) + "\n"
    if fmt == "csv":
        buf = io.StringIO()
        w = csv.writer(buf)
        w.writerow(KEYS)
        for e in entries:
            cells = claim_cells(e)
            w.writerow(["" if e.get(k) is None and k != "converged" else
                        repr(e[k]) if k == "p" else cells[i] for i, k in enumerate(KEYS)])
        return buf.getvalue()
    from repro.errors import ConfigError

    raise ConfigError(f"unknown format {fmt!r}; choose one of term, {', '.join(FORMATS)}")
