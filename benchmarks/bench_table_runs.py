"""What the cache and ``--jobs`` buy on one table run, and proof that ``--jobs`` changes no number.

Three runs of one table (default ``marionette/table1`` at ``quick`` on the bundled data), each a
``repro run`` process:

1. cold, ``--jobs 1``, in an empty ``REPRO_HOME`` (trains the evaluator and every row's model);
2. the same command again in that home: every job a cache hit;
3. cold, ``--jobs 2``, in a second empty home.

Printed, all measured in this one run: the wall time of each, the cached / cold ratio, the
``--jobs 2`` speed-up, and whether runs 1 and 3 recorded bitwise-identical replicate values
(they must: every job computes with the scale profile's fixed ``threads``, which is part of its
key, so the number of jobs side by side cannot change a float; docs/store.md, "Threads").

Usage: .venv/bin/python benchmarks/bench_table_runs.py [--table marionette/table1]
       [--scale quick] [--jobs 2] [--json]

``--fixed-costs HOME`` measures instead what a table costs once it is computed (issue 17,
"Fixed costs"): the wall time of a fully cached ``repro run`` and of ``repro show``, ``list``
and ``plan`` in ``HOME`` (the median of ``--repeat`` runs each), the cold time of the table in
that home (timed now when ``HOME`` holds no finished run of it, else read from its oldest run
record: ``ended - created``, process start-up not included), the cached / cold ratio, whether
every job of the rerun was a hit and whether the rerun recorded the cold run's cells,
evaluators and footer.  ``--before REV --before-home HOME2`` times the code of git revision
``REV`` (``git archive`` into a temporary folder) the same way in its own home (job keys
hash the source, so one code's store is a miss for the other's), so before and after print
in one run; ``--tree DIR`` times a copy of the code in ``DIR`` instead of this checkout.
A home that holds no run yet costs one cold run (minutes); prepared homes, a minute or two:

    .venv/bin/python benchmarks/bench_table_runs.py --fixed-costs /tmp/after-home \
        --before 4b3830a --before-home /tmp/before-home
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(table: str, scale: str, jobs: int, home: Path) -> tuple[float, dict]:
    """Wall seconds of one ``repro run`` and its replicate values {(row, column, replicate): v}."""
    cmd = [sys.executable, "-m", "cli.main", "run", table, "--scale", scale, "--quiet",
           "--jobs", str(jobs)]
    return run_for_values(cmd, home, f"bench_table_runs: {' '.join(cmd[2:])}")


def run_for_values(cmd: list[str], home: Path, shown: str) -> tuple[float, dict]:
    """Wall seconds of ``cmd`` run at the repository root with ``REPRO_HOME=home``, and the
    newest run's replicate values (:func:`newest_values`); a failure exits, naming ``shown``."""
    env = {**os.environ, "REPRO_HOME": str(home)}
    t0 = time.perf_counter()
    out = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    if out.returncode != 0:
        sys.exit(f"{shown} exited {out.returncode}:\n{out.stderr}")
    return seconds, newest_values(home)


def newest_values(home: Path) -> dict:
    """The replicate values {(row, column, replicate): v} of the newest run in ``home``."""
    newest = max((home / "runs").iterdir(), key=lambda p: p.name)
    values = {}
    for line in (newest / "values.jsonl").read_text().splitlines():
        rec = json.loads(line)
        values[(rec["row"], rec["column"], rec["replicate"])] = rec["value"]
    return values


def timed(code: Path, home: Path, *args: str) -> tuple[float, subprocess.CompletedProcess]:
    """Wall seconds of one ``python -m cli.main ARGS`` of the code in ``code`` (its own
    ``repro`` first on the path) in ``home``; exits with its stderr when it fails."""
    env = {**os.environ, "REPRO_HOME": str(home), "PYTHONPATH": str(code)}
    cmd = [sys.executable, "-m", "cli.main", *args]
    t0 = time.perf_counter()
    out = subprocess.run(cmd, cwd=code, env=env, capture_output=True, text=True, check=False)
    seconds = time.perf_counter() - t0
    if out.returncode != 0:
        sys.exit(f"bench_table_runs: {' '.join(args)} ({code}) exited {out.returncode}:\n"
                 f"{out.stderr[-2000:]}")
    return seconds, out


def finished_runs(home: Path, table: str) -> list[Path]:
    """The FINISHED run folders of ``table`` in ``home``, oldest first."""
    out = []
    for d in sorted((home / "runs").iterdir() if (home / "runs").is_dir() else []):
        rj = d / "run.json"
        if rj.is_file():
            data = json.loads(rj.read_text())
            if data.get("table") == table and data.get("status") == "FINISHED":
                out.append(d)
    return out


def recorded_seconds(run_dir: Path) -> float:
    """``ended - created`` of a run record (the run's own time, without process start-up)."""
    rj = json.loads((run_dir / "run.json").read_text())
    t = [datetime.fromisoformat(rj[k]) for k in ("created", "ended")]  # "...Z": 3.11+
    return (t[1] - t[0]).total_seconds()


def _record(run_dir: Path) -> dict:
    """What a cached rerun must record as its cold run did: cells, evaluators, the footer
    without its last line (which names the run id)."""
    s = json.loads((run_dir / "summary.json").read_text())
    return {"cells": s.get("cells"), "evaluators": s.get("evaluators"),
            "footer": (s.get("footer") or [])[:-1]}


def fixed_costs(code: Path, home: Path, table: str, scale: str, jobs: int, repeat: int) -> dict:
    """The fixed-cost figures of the code in ``code`` in ``home`` (module docstring)."""
    home.mkdir(parents=True, exist_ok=True)
    runs = finished_runs(home, table)
    if runs:
        cold, cold_source = recorded_seconds(runs[0]), "run record"
    else:
        cold, _ = timed(code, home, "run", table, "--scale", scale, "--jobs", str(jobs),
                        "--quiet")
        cold_source = "timed now"
        runs = finished_runs(home, table)
    first = runs[0]
    reruns, all_hits, same = [], True, True
    for _ in range(repeat):
        t, out = timed(code, home, "run", table, "--scale", scale, "--quiet")
        reruns.append(t)
        counts = out.stderr.rsplit("(", 1)[-1]  # "repro: TABLE: run ID (87 hit)"
        all_hits &= "computed" not in counts and "hit" in counts
        same &= _record(finished_runs(home, table)[-1]) == _record(first)
    result = {"cold_s": round(cold, 1), "cold_from": cold_source,
              "cached_rerun_s": round(statistics.median(reruns), 2)}
    result["cached_over_cold"] = round(result["cached_rerun_s"] / cold, 4)
    for name, args in (("show", ("show", table, "--scale", scale)), ("list", ("list",)),
                       ("plan", ("plan", table, "--scale", scale))):
        result[f"{name}_s"] = round(statistics.median(
            timed(code, home, *args)[0] for _ in range(repeat)), 2)
    result["rerun_all_hits"] = all_hits
    result["rerun_records_the_cold_run"] = same
    return result


def main_fixed_costs(args) -> int:
    """``--fixed-costs``: before (``--before``) and after figures in one run."""
    out: dict = {"table": args.table, "scale": args.scale, "cpus": os.cpu_count(),
                 "repeat": args.repeat}
    with tempfile.TemporaryDirectory(prefix="bench-fixed-") as tmp:
        if args.before:
            if not args.before_home:
                sys.exit("bench_table_runs: --before needs --before-home (its own store)")
            code = Path(tmp) / "before"
            code.mkdir()
            archive = subprocess.run(["git", "archive", args.before], cwd=ROOT,
                                     capture_output=True, check=False)
            if archive.returncode != 0:
                sys.exit(f"bench_table_runs: git archive {args.before}: "
                         f"{archive.stderr.decode().strip()}")
            subprocess.run(["tar", "xf", "-"], input=archive.stdout, cwd=code, check=True)
            out[f"before ({args.before})"] = fixed_costs(
                code, Path(args.before_home), args.table, args.scale, args.jobs, args.repeat)
        tree = Path(args.tree).resolve() if args.tree else ROOT
        out[f"after ({'this checkout' if tree == ROOT else tree})"] = fixed_costs(
            tree, Path(args.fixed_costs), args.table, args.scale, args.jobs, args.repeat)
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        for k, v in out.items():
            if isinstance(v, dict):
                print(k)
                for kk, vv in v.items():
                    print(f"  {kk:30s} {vv}")
            else:
                print(f"{k:32s} {v}")
    ok = all(v["rerun_all_hits"] and v["rerun_records_the_cold_run"]
             for v in out.values() if isinstance(v, dict))
    return 0 if ok else 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--table", default="marionette/table1")
    ap.add_argument("--scale", default="quick")
    ap.add_argument("--jobs", type=int, default=2, help="jobs of the parallel cold run")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--fixed-costs", metavar="HOME", default=None,
                    help="time a cached rerun and show/list/plan in HOME (module docstring)")
    ap.add_argument("--before", metavar="REV", default=None,
                    help="with --fixed-costs: also time git revision REV's code")
    ap.add_argument("--before-home", metavar="HOME", default=None,
                    help="REV's own store (prepared, or filled by one cold run)")
    ap.add_argument("--tree", metavar="DIR", default=None,
                    help="with --fixed-costs: time the code in DIR (default: this checkout)")
    ap.add_argument("--repeat", type=int, default=3, help="timings per figure (median)")
    args = ap.parse_args(argv)
    if args.fixed_costs:
        return main_fixed_costs(args)
    with tempfile.TemporaryDirectory(prefix="bench-table-") as tmp:
        serial, parallel = Path(tmp) / "serial", Path(tmp) / "parallel"
        cold, v1 = run(args.table, args.scale, 1, serial)
        warm, v2 = run(args.table, args.scale, 1, serial)
        cold_n, vn = run(args.table, args.scale, args.jobs, parallel)
    result = {
        "table": args.table, "scale": args.scale, "cpus": os.cpu_count(),
        "cold_jobs1_s": round(cold, 1), "cached_s": round(warm, 1),
        f"cold_jobs{args.jobs}_s": round(cold_n, 1),
        "cached_over_cold": round(warm / cold, 3),
        f"speedup_jobs{args.jobs}": round(cold / cold_n, 2),
        "values": len(v1),
        "cached_values_identical": v1 == v2,
        f"jobs1_vs_jobs{args.jobs}_values_identical": v1 == vn,
    }
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        for k, v in result.items():
            print(f"{k:32s} {v}")
    return 0 if v1 == v2 == vn else 1


if __name__ == "__main__":
    sys.exit(main())
