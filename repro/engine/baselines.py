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

Hosts (issue 25): a baseline names the CPU and the kernel paths it was made with (``kernels``,
:func:`repro.kernels.record`; outside the checksum, like ``run``).  Under the pin every x86-64
CPU with AVX2 computes the same bytes, so the bands above stay tight.  :func:`host_lines` says
which hosts and kernel paths a comparison puts side by side; :func:`refusal` refuses to compare
a run made with ``--fast-kernels`` (or before pinning) with a pinned baseline; when cells drift
and the hosts differ, :func:`compare`'s caller says so (:func:`host_note`).

``tolerance`` (``repro verify --tolerance K``, off by default) is for comparing across hosts or
kernel paths that are *not* bitwise equal (an unpinned run, another architecture): a cell then
passes when ``|now − base| ≤ K · s``, with ``s`` the half-width of the *current* run's interval
when that run was made with ``--retrain`` (its interval then holds the spread of training
seeds), else the larger of the two runs' half-widths (sampling spread only: weaker, and said so);
a verdict that moves by one step (supported ↔ inconclusive) is then a note, not a failure.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from repro.errors import DataError, MissingDataError
from repro.keys import content_key

SCHEMA = 1  # 1: cells, claims, checksum; ``kernels`` (issue 25) is optional metadata
K_HALFWIDTH = 1.0
REL_FLOOR = 0.02
ABS_FLOOR = 1e-9


def baseline_path(root: Path, table: str) -> Path:
    paper, name = table.split("/", 1)
    return Path(root) / paper / f"{name}.json"


def make_baseline(summary: dict, *, scale: str, dataset: str, run_id: str,
                  kernels: dict | None = None) -> dict:
    """The baseline of a run's summary; its real-data gate (``gate``) is metadata outside
    the checksum, like ``kernels``."""
    cells = {}
    for row, cols in sorted(summary.get("cells", {}).items()):
        for col, s in sorted(cols.items()):
            lo, hi = (s.get("bootstrap_percentile") or [None, None])
            cells.setdefault(row, {})[col] = {"mean": s["mean"], "lo": lo, "hi": hi, "n": s["n"]}
    claims = {c["id"]: c["verdict"] for c in summary.get("claims", [])}
    body = {"cells": cells, "claims": claims}
    gate = summary.get("gate")
    extra = {} if not gate else {"gate": {k: gate.get(k) for k in (
        "enabled", "margin", "standard_margin", "standard", "relaxed")}}
    return {"schema": SCHEMA, "table": summary["table"], "scale": scale, "dataset": dataset,
            "run": run_id, "kernels": kernels, "checksum": content_key(body), **extra, **body}


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


def host_lines(base: dict, run_kernels: dict | None) -> list[str]:
    """Two lines naming the baseline's and this run's CPU and kernel paths."""
    from repro.kernels import describe

    return [f"baseline: {describe(base.get('kernels'))}",
            f"this run: {describe(run_kernels)}"]


def refusal(base: dict, run_kernels: dict | None) -> str | None:
    """Why a run cannot be compared with ``base`` at all (None when it can): a pinned baseline
    and a run made unpinned (``--fast-kernels``) or before pinning existed."""
    bk, rk = base.get("kernels") or {}, run_kernels or {}
    if bk.get("mode") == "pinned" and rk.get("mode") != "pinned":
        why = "with --fast-kernels" if rk.get("mode") == "fast" else "before kernel pinning"
        return (f"the run was made {why} and the baseline {base.get('_path', '')} under the "
                f"pinned kernel paths: their numbers are not comparable; rerun without "
                f"--fast-kernels (or compare by the spread of training seeds: --tolerance)")
    if bk.get("mode") == "pinned" and (bk.get("pin"), bk.get("version")) != (rk.get("pin"),
                                                                          rk.get("version")):
        return (f"the run was made under kernel pin {rk.get('pin')} v{rk.get('version')} and "
                f"the baseline {base.get('_path', '')} under {bk.get('pin')} "
                f"v{bk.get('version')}: remake the baselines with this code (make baselines)")
    return None


def host_note(base: dict, run_kernels: dict | None, *, drift: bool = True) -> str | None:
    """A line saying that the host differs (None when the CPUs match or are unknown); with
    ``drift`` (cells or verdicts moved) it says what that means."""
    bk, rk = base.get("kernels") or {}, run_kernels or {}
    bh, rh = bk.get("host") or {}, rk.get("host") or {}
    keys = ("vendor", "model", "isa")
    if not bh or not rh or all(bh.get(k) == rh.get(k) for k in keys):
        return None
    head = (f"the host differs (baseline: {bh.get('model')}, {bh.get('vendor')}, "
            f"{bh.get('isa')}; now: {rh.get('model')}, {rh.get('vendor')}, {rh.get('isa')})")
    if not drift:
        return head + "; every cell and verdict matches"
    same_pin = (bk.get("mode") == rk.get("mode") == "pinned"
                and bk.get("version") == rk.get("version"))
    tail = ("both pinned to the same kernel paths, so a drift is a code or data change or a "
            "kernel path the pin does not cover (docs/engine.md)" if same_pin else
            "the kernel paths differ, so last-bit differences grow through training: compare "
            "with --tolerance, or make both runs pinned")
    return f"{head}: {tail}"


def gate_check(base: dict, run_gate: dict | None) -> tuple[str | None, str | None]:
    """(note, problem) of comparing a run's real-data gate (``summary["gate"]``,
    :func:`repro.eval.gate.gate_summary`) with the baseline's (``gate``, outside the checksum
    like ``kernels``; a baseline made before runs recorded their gate was made under the
    standard one, as every committed baseline must be).  The gate changes no number, so a run
    under a relaxed gate is compared all the same, with a one-line note; it fails only when
    the standard gate would have failed on that run's real rows: the standard harness would
    then have scored nothing, so the baseline does not describe such a run (docs/engine.md)."""
    from repro.eval.gate import gate_line

    if not run_gate or run_gate.get("standard", True):
        return None, None
    base_gate = base.get("gate") or {"standard": True}
    if not base_gate.get("standard", True):
        return ("both this run and the baseline were made under a non-standard real-data "
                f"gate; this run's: {gate_line(run_gate)}"), None
    note = (f"this run was made under a NON-STANDARD real-data gate, the baseline under the "
            f"standard one: {gate_line(run_gate)}")
    failed = [r for c in run_gate.get("checks") or [] for r in c.get("standard_reasons") or []]
    if failed:
        return note, ("real-data gate: the standard gate fails on this run's real rows ("
                      + "; ".join(failed) + "), so the baseline's standard run does not "
                      "describe it")
    return note, None


def _step(verdict: str | None) -> int | None:
    """A verdict's place on supported (2) > inconclusive (1) > contradicted / not reproduced
    (0); None for anything else (not run, failed)."""
    v = str(verdict or "")
    if v.startswith("supported"):
        return 2
    if v.startswith("inconclusive"):
        return 1
    if v.startswith(("contradicted", "not reproduced")):
        return 0
    return None


def compare(base: dict, summary: dict, *, tolerance: float | None = None,
            retrain: bool = False, notes: list[str] | None = None) -> list[str]:
    """Problems of ``summary`` against ``base`` (empty when the run matches); with
    ``tolerance`` the looser comparison of the module docstring (``retrain``: the current
    run's intervals hold training-seed variance); what passes only by the tolerance is
    appended to ``notes``."""
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
            if tolerance is not None:
                lo, hi = (got.get("bootstrap_percentile") or [None, None])
                now_half = (hi - lo) / 2 if lo is not None and hi is not None else 0.0
                spread = now_half if retrain else max(now_half, half)
                tol = max(tol, float(tolerance) * spread)
            m = got["mean"]
            if m is None or not math.isfinite(m) or abs(m - b["mean"]) > tol:
                problems.append(f"{row}/{col}: {m!r} is outside {b['mean']!r} ± {tol:.4g}")
            elif tolerance is not None and notes is not None and m != b["mean"]:
                strict = max(K_HALFWIDTH * half, REL_FLOOR * abs(b["mean"]), ABS_FLOOR)
                if abs(m - b["mean"]) > strict:
                    notes.append(f"{row}/{col}: {m!r} vs {b['mean']!r}: within the tolerance "
                                 f"± {tol:.4g}, outside the strict band ± {strict:.4g}")
    for row, cols in now.items():
        for col in cols:
            if col not in body["cells"].get(row, {}):
                problems.append(f"{row}/{col}: reproduced now but not in the baseline")
    for cid, v in body["claims"].items():
        got = next((c["verdict"] for c in summary.get("claims", []) if c["id"] == cid), None)
        if got != v:
            if (tolerance is not None and None not in (_step(got), _step(v))
                    and abs(_step(got) - _step(v)) <= 1):
                if notes is not None:  # one step apart: passes under tolerance, said
                    notes.append(f"claim {cid}: verdict {v!r} in the baseline, {got!r} now "
                                 "(one step: within the tolerance)")
                continue
            problems.append(f"claim {cid}: verdict {v!r} in the baseline, {got!r} now")
    return problems
