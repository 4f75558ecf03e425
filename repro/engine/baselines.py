"""Committed regression baselines (``tables/baselines/<scale>/<paper>/<table>.json``).

A baseline holds, per reproduced cell, the mean and our bootstrap interval of a reference run,
and each claim's verdict.  ``repro verify`` fails (exit 1) when

- a cell's mean leaves its tolerance band: ``|now − base| > max(k·halfwidth, rel·|base|,
  abs_floor)`` with ``halfwidth`` half the baseline's bootstrap interval (``k = 1``,
  ``rel = 0.02``, ``abs_floor = 1e-9``: same code, data and machine give identical bytes, so
  any real drift shows);
- a claim's verdict flips;
- a cell appears or disappears;
- the baseline file was edited by hand: it carries the content key of its own cells and
  claims, and a mismatch is reported as such.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from repro.errors import DataError, MissingDataError
from repro.keys import content_key

SCHEMA = 1
K_HALFWIDTH = 1.0
REL_FLOOR = 0.02
ABS_FLOOR = 1e-9


def baseline_path(root: Path, table: str) -> Path:
    paper, name = table.split("/", 1)
    return Path(root) / paper / f"{name}.json"


def make_baseline(summary: dict, *, scale: str, dataset: str, run_id: str) -> dict:
    cells = {}
    for row, cols in sorted(summary.get("cells", {}).items()):
        for col, s in sorted(cols.items()):
            lo, hi = (s.get("bootstrap_percentile") or [None, None])
            cells.setdefault(row, {})[col] = {"mean": s["mean"], "lo": lo, "hi": hi, "n": s["n"]}
    claims = {c["id"]: c["verdict"] for c in summary.get("claims", [])}
    body = {"cells": cells, "claims": claims}
    return {"schema": SCHEMA, "table": summary["table"], "scale": scale, "dataset": dataset,
            "run": run_id, "checksum": content_key(body), **body}


def write_baseline(root: Path, summary: dict, **meta) -> Path:
    base = make_baseline(summary, **meta)
    path = baseline_path(root, base["table"])
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(base, indent=2, sort_keys=True) + "\n")
    tmp.replace(path)
    return path


def load_baseline(root: Path, table: str) -> dict:
    path = baseline_path(root, table)
    if not path.is_file():
        raise MissingDataError(f"no baseline for {table} (write one with `repro verify {table} "
                               f"--baseline {root} --update`)", path)
    try:
        base = json.loads(path.read_text())
        if base.get("schema") != SCHEMA:
            raise DataError(f"unsupported baseline schema {base.get('schema')!r}", path)
        base["_path"] = str(path)
        return base
    except json.JSONDecodeError as e:
        raise DataError(f"malformed baseline JSON ({e.msg})", path, e.lineno) from None


def compare(base: dict, summary: dict) -> list[str]:
    """Problems of ``summary`` against ``base`` (empty when the run matches)."""
    problems = []
    body = {"cells": base.get("cells", {}), "claims": base.get("claims", {})}
    if content_key(body) != base.get("checksum"):
        problems.append(f"{base.get('_path', 'baseline')}: checksum mismatch — the baseline was "
                        "edited by hand; regenerate it with --update from a reviewed run")
    now = summary.get("cells", {})
    for row, cols in body["cells"].items():
        for col, b in cols.items():
            got = now.get(row, {}).get(col)
            if got is None:
                problems.append(f"{row}/{col}: in the baseline but not reproduced now")
                continue
            half = 0.0
            if b.get("lo") is not None and b.get("hi") is not None:
                half = (b["hi"] - b["lo"]) / 2
            tol = max(K_HALFWIDTH * half, REL_FLOOR * abs(b["mean"]), ABS_FLOOR)
            m = got["mean"]
            if m is None or not math.isfinite(m) or abs(m - b["mean"]) > tol:
                problems.append(f"{row}/{col}: {m!r} is outside {b['mean']!r} ± {tol:.4g}")
    for row, cols in now.items():
        for col in cols:
            if col not in body["cells"].get(row, {}):
                problems.append(f"{row}/{col}: reproduced now but not in the baseline")
    for cid, v in body["claims"].items():
        got = next((c["verdict"] for c in summary.get("claims", []) if c["id"] == cid), None)
        if got != v:
            problems.append(f"claim {cid}: verdict {v!r} in the baseline, {got!r} now")
    return problems
