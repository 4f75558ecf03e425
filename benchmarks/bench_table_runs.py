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
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(table: str, scale: str, jobs: int, home: Path) -> tuple[float, dict]:
    """Wall seconds of one ``repro run`` and its replicate values {(row, column, replicate): v}."""
    env = {**os.environ, "REPRO_HOME": str(home)}
    cmd = [sys.executable, "-m", "cli.main", "run", table, "--scale", scale, "--quiet",
           "--jobs", str(jobs)]
    t0 = time.perf_counter()
    out = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    if out.returncode != 0:
        sys.exit(f"bench_table_runs: {' '.join(cmd[2:])} exited {out.returncode}:\n{out.stderr}")
    return seconds, newest_values(home)


def newest_values(home: Path) -> dict:
    """The replicate values {(row, column, replicate): v} of the newest run in ``home``."""
    newest = max((home / "runs").iterdir(), key=lambda p: p.name)
    values = {}
    for line in (newest / "values.jsonl").read_text().splitlines():
        rec = json.loads(line)
        values[(rec["row"], rec["column"], rec["replicate"])] = rec["value"]
    return values


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--table", default="marionette/table1")
    ap.add_argument("--scale", default="quick")
    ap.add_argument("--jobs", type=int, default=2, help="jobs of the parallel cold run")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
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
