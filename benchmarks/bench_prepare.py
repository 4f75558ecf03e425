"""Benchmark of `repro data prepare bandai2` (not a timed test; figures go to docs/data.md).

Measures, on this machine and in one run:

1. cold prepare of all 2,902 clips from the archive into a fresh REPRO_HOME (wall time, and
   peak resident memory of the whole process tree: main process + parser workers, sampled);
2. warm load of the prepared cache (open memory-mapped; and reading every array into RAM);
3. parse speed of :func:`repro.data.bvh.read_bvh` against ``bvhio`` (an independent PyPI BVH
   library) on the same files: parse only (``bvhio.readAsBvh``), and parse + world positions of
   every joint in every frame (``bvhio.readAsHierarchy`` + ``loadPose``).

Usage:  .venv/bin/python benchmarks/bench_prepare.py [--source ARCHIVE] [--workers 2]
        [--parse-files 100] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tarfile
import tempfile
import threading
import time
from pathlib import Path


def _tree_rss_bytes(pid: int) -> int:
    """Resident memory of ``pid`` and all its descendants (Linux /proc)."""
    total = 0
    todo = [pid]
    seen = set()
    while todo:
        p = todo.pop()
        if p in seen:
            continue
        seen.add(p)
        try:
            with open(f"/proc/{p}/status") as fh:
                for ln in fh:
                    if ln.startswith("VmRSS:"):
                        total += int(ln.split()[1]) * 1024
                        break
            with open(f"/proc/{p}/task/{p}/children") as fh:
                todo += [int(c) for c in fh.read().split()]
        except (OSError, ValueError):
            continue
    return total


class PeakSampler:
    def __init__(self, interval: float = 0.05):
        self.interval = interval
        self.peak = 0
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.peak = max(self.peak, _tree_rss_bytes(os.getpid()))
            self._stop.wait(self.interval)

    def __enter__(self):
        self._t.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._t.join()
        self.peak = max(self.peak, _tree_rss_bytes(os.getpid()))


def machine() -> dict:
    cpu = platform.processor()
    try:
        for ln in Path("/proc/cpuinfo").read_text().splitlines():
            if ln.startswith("model name"):
                cpu = ln.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import numpy
    import torch

    mem = ""
    try:
        for ln in Path("/proc/meminfo").read_text().splitlines():
            if ln.startswith("MemTotal:"):
                mem = f"{int(ln.split()[1]) / 2**20:.1f} GiB"
                break
    except (OSError, ValueError, IndexError):
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "platform": platform.platform(),
            "python": platform.python_version(), "numpy": numpy.__version__,
            "torch": torch.__version__, "memory": mem,
            "load_avg_at_start": os.getloadavg()}


def bench_prepare(source: Path, workers: int) -> dict:
    from repro.data.bandai import load_bandai2, prepare_bandai2

    home = Path(tempfile.mkdtemp(prefix="bench-repro-home-"))
    os.environ["REPRO_HOME"] = str(home)
    with PeakSampler() as ps:
        t0 = time.perf_counter()
        res = prepare_bandai2(source, workers=workers)
        cold = time.perf_counter() - t0
    t0 = time.perf_counter()
    cs = load_bandai2()
    warm_open = time.perf_counter() - t0
    t0 = time.perf_counter()
    cs = load_bandai2(mmap=False)
    warm_read = time.perf_counter() - t0
    cache_bytes = sum(p.stat().st_size for p in res.path.iterdir())
    out = {"cold_prepare_s": round(cold, 2), "timings": {k: round(v, 2) for k, v in res.timings.items()},
           "peak_rss_tree_mib": round(ps.peak / 2**20, 1), "warm_load_mmap_s": round(warm_open, 4),
           "warm_load_in_ram_s": round(warm_read, 3), "clips": len(cs), "frames": cs.n_frames,
           "cache_mib": round(cache_bytes / 2**20, 1), "workers": workers}
    import shutil

    shutil.rmtree(home, ignore_errors=True)
    return out


def bench_parse(source: Path, n_files: int, rounds: int = 3) -> dict:
    import bvhio
    import numpy as np
    import torch

    from repro.data.bvh import read_bvh

    torch.set_num_threads(1)
    tmp = Path(tempfile.mkdtemp(prefix="bench-bvh-"))
    paths = []
    with tarfile.open(source, "r|xz") as tf:
        for m in tf:
            if m.name.endswith(".bvh"):
                p = tmp / m.name.rsplit("/", 1)[-1]
                p.write_bytes(tf.extractfile(m).read())
                paths.append(p)
                if len(paths) == n_files:
                    break
    frames = sum(read_bvh(p).n_frames for p in paths)
    read_bvh(paths[0]).world_positions()  # warm-up (imports, torch init)

    def ours_parse():
        for p in paths:
            read_bvh(p)

    def ours_local():  # the same content bvhio.readAsBvh builds: local positions + quaternions
        for p in paths:
            b = read_bvh(p)
            b.local_translations()
            b.local_rotations(as_quaternions=True)

    def ours_fk():
        for p in paths:
            read_bvh(p).world_positions()

    def theirs_parse():
        for p in paths:
            bvhio.readAsBvh(str(p))

    def theirs_fk():
        for p in paths:
            root = bvhio.readAsHierarchy(str(p))
            layout = [j for j, _, _ in root.layout()]
            n = len(root.Keyframes)
            pos = np.empty((n, len(layout), 3))
            for f in range(n):
                root.loadPose(f)
                for k, j in enumerate(layout):
                    pos[f, k] = tuple(j.PositionWorld)

    # Interleaved rounds, best of each: the machine is shared, so single timings are noisy.
    best = {k: float("inf") for k in ("ours_parse", "ours_local", "ours_fk", "theirs_parse",
                                      "theirs_fk")}
    fns = {"ours_parse": ours_parse, "ours_local": ours_local, "ours_fk": ours_fk,
           "theirs_parse": theirs_parse, "theirs_fk": theirs_fk}
    for r in range(rounds):
        for k, fn in fns.items():
            if k == "theirs_fk" and r > 0:
                continue  # minutes per round; one round is enough for a >10x gap
            t0 = time.perf_counter()
            fn()
            best[k] = min(best[k], time.perf_counter() - t0)
    ours_parse_s, ours_local_s, ours_fk_s = best["ours_parse"], best["ours_local"], best["ours_fk"]
    theirs_parse_s, theirs_fk_s = best["theirs_parse"], best["theirs_fk"]
    import shutil

    shutil.rmtree(tmp, ignore_errors=True)
    return {"files": len(paths), "frames": frames,
            "rounds": rounds,
            "ours_parse_s": round(ours_parse_s, 3),
            "ours_parse_local_transforms_s": round(ours_local_s, 3),
            "bvhio_readAsBvh_s": round(theirs_parse_s, 3),
            "parse_speedup": round(theirs_parse_s / ours_parse_s, 1),
            "parse_local_transforms_speedup": round(theirs_parse_s / ours_local_s, 1),
            "ours_parse_fk_s": round(ours_fk_s, 3),
            "bvhio_readAsHierarchy_fk_s": round(theirs_fk_s, 3),
            "parse_fk_speedup": round(theirs_fk_s / ours_fk_s, 1)}


def main(argv: list[str] | None = None) -> int:
    from repro.paths import find_bandai_archive

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--source", type=Path, default=None)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--parse-files", type=int, default=100)
    ap.add_argument("--rounds", type=int, default=3, help="parse timing rounds (best is kept)")
    ap.add_argument("--skip-prepare", action="store_true")
    ap.add_argument("--json", type=Path, default=None, help="also write the results here")
    args = ap.parse_args(argv)
    source = args.source or find_bandai_archive()
    if source is None:
        print("bench_prepare: the Bandai-Namco-2 archive was not found; pass --source", file=sys.stderr)
        return 2
    result = {"machine": machine(), "source": str(source)}
    if not args.skip_prepare:
        result["prepare"] = bench_prepare(Path(source), args.workers)
    result["parse_vs_bvhio"] = bench_parse(Path(source), args.parse_files, args.rounds)
    result["machine"]["load_avg_at_end"] = os.getloadavg()
    text = json.dumps(result, indent=1)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
