"""``make table3`` (Neural Marionette Table 3 at ``quick`` on the bundled data) from an empty
store, then again with everything cached: the command the product is known by.

Both are the Makefile's own command (``make table3 [JOBS=N]``, i.e. ``repro run
marionette/table3 --scale quick --jobs N``) in a fresh ``REPRO_HOME``; the first trains the
heading-free evaluator and MANN, A2M and MarioNet, then chains 12 × 6 actions per set and
replicate; the second finds every job in the store.  Printed, measured in this one run: both
wall times, their ratio, and whether the two runs recorded identical values.

Usage: .venv/bin/python benchmarks/bench_make_table3.py [--jobs 1] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

from bench_table_runs import run_for_values  # benchmarks/ is the script's own folder


def make_table3(home: Path, jobs: int) -> tuple[float, dict]:
    cmd = ["make", "-s", "table3", f"JOBS={jobs}", f"REPRO={sys.executable} -m cli.main",
           "RUNFLAGS=--quiet"]
    return run_for_values(cmd, home, f"bench_make_table3: {' '.join(cmd)}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=1, help="JOBS= of make (default: make's 1)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bench-table3-") as tmp:
        cold, v1 = make_table3(Path(tmp), args.jobs)
        warm, v2 = make_table3(Path(tmp), args.jobs)
    result = {"command": f"make table3 JOBS={args.jobs}", "cpus": os.cpu_count(),
              "cold_s": round(cold, 1), "warm_s": round(warm, 1),
              "warm_over_cold": round(warm / cold, 3), "values": len(v1),
              "warm_values_identical": v1 == v2}
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        for k, v in result.items():
            print(f"{k:24s} {v}")
    return 0 if v1 == v2 else 1


if __name__ == "__main__":
    sys.exit(main())
