"""How long the strips of a table take to draw (issue 12: Table 1 at quick under 10 s).

Uses the newest finished run of the table in ``REPRO_HOME`` (run ``repro run TABLE --scale
quick`` first, or pass ``--run-first``).  Measured, in this one process:

1. ``setup``: the run's plan rebuilt, the test items (and, multi-action, the test set) made,
   every shown row's samples read from the store;
2. ``draw``: every strip rendered and written as PNG and EXR (the default ``repro strips``);
3. ``draw again``: the same with everything in memory (drawing and encoding only).

Printed: the three times, the strip count and their ratio to the 10 s target.

Usage: .venv/bin/python benchmarks/bench_strips.py [--table marionette/table1] [--scale quick]
       [--items 2] [--run-first] [--json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 10.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--table", default="marionette/table1")
    ap.add_argument("--scale", default="quick")
    ap.add_argument("--items", type=int, default=2)
    ap.add_argument("--run-first", action="store_true")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    sys.path.insert(0, str(ROOT))
    if a.run_first:
        subprocess.run([sys.executable, "-m", "cli.main", "run", a.table, "--scale", a.scale,
                        "--quiet"], cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
    from repro.engine.run_samples import run_samples
    from repro.report.strip_sets import table_strips, write_strips

    t0 = time.perf_counter()
    rs = run_samples(a.table, scale=a.scale)
    strips, _ = table_strips(rs, items=a.items)  # builds items, reads every row's samples
    t1 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        rec = write_strips(rs, Path(d) / "one", items=a.items)
        t2 = time.perf_counter()
        write_strips(rs, Path(d) / "two", items=a.items)
        t3 = time.perf_counter()
    out = {"table": a.table, "run": rs.run_id, "strips": len(rec["strips"]),
           "rows": sorted({r for s in rec["strips"] for r in s["rows"]}),
           "setup_s": round(t1 - t0, 3), "draw_s": round(t2 - t1, 3),
           "draw_again_s": round(t3 - t2, 3), "total_s": round(t2 - t0, 3),
           "share_of_target": round((t2 - t0) / TARGET_S, 3)}
    if a.json:
        print(json.dumps(out, indent=1))
    else:
        print(f"{a.table} run {rs.run_id}: {out['strips']} strips (PNG + EXR) of "
              f"{len(out['rows'])} generated rows + the real motion")
        print(f"  setup (plan, items, samples read)  {out['setup_s']:.2f} s")
        print(f"  draw + write                       {out['draw_s']:.2f} s")
        print(f"  draw + write again (warm)          {out['draw_again_s']:.2f} s")
        print(f"  total {out['total_s']:.2f} s = {out['share_of_target']:.0%} of the "
              f"{TARGET_S:.0f} s target")
    return 0


if __name__ == "__main__":
    sys.exit(main())
