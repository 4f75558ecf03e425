"""Benchmark of `repro data prepare bandai2` (not a timed test; figures go to docs/data.md).

Measures, on this machine and in one run, this working tree ("after") against the code of a
pinned earlier commit ("before", :data:`BEFORE`, unpacked from git history into a temporary
folder by ``benchmarks/_before.py``; the library itself keeps one parser):

1. cold prepare of all 2,902 clips from the archive into a fresh REPRO_HOME, before and after,
   each in its own process with ``--workers`` parser workers (wall time of the
   ``prepare_bandai2`` call, CPU seconds of that process and its workers, peak resident memory
   of that process tree, sampled every 50 ms), and whether the two caches are byte-identical
   (sha256 of every file);
2. warm load of the prepared cache (open memory-mapped; and reading every array into RAM);
3. parse speed of :func:`repro.data.bvh.read_bvh`, before and after, against ``bvhio`` (an
   independent PyPI BVH library) on the same files: parse only (``bvhio.readAsBvh``), and parse
   + world positions of every joint in every frame (``bvhio.readAsHierarchy`` + ``loadPose``).
   Times are CPU seconds of the benchmark process (best of ``--rounds`` interleaved rounds).
   The parser's memo of HIERARCHY blocks is emptied before every round, so a round reads its
   files as a cold prepare does.

Usage:  .venv/bin/python benchmarks/bench_prepare.py [--source ARCHIVE] [--workers 2]
        [--parse-files 100] [--before COMMIT] [--skip-prepare] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import shutil
import subprocess
import sys
import tarfile
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _before import BeforeUnavailable, load_module, tree_at  # after the path entry

#: The "before" code: the last commit before the BVH reader's issue-17 speed-ups.
BEFORE = "4b3830acd23621ac745fb0b587599a3a5f9acb15"
REPO = Path(__file__).resolve().parents[1]


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
    """Peak resident memory of the process tree under ``pid`` (default: this process)."""

    def __init__(self, interval: float = 0.05, pid: int | None = None):
        self.interval = interval
        self.pid = os.getpid() if pid is None else pid
        self.peak = 0
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.peak = max(self.peak, _tree_rss_bytes(self.pid))
            self._stop.wait(self.interval)

    def __enter__(self):
        self._t.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._t.join()
        self.peak = max(self.peak, _tree_rss_bytes(self.pid))


def unpack_before(commit: str) -> Path | None:
    """A temporary folder holding ``repro/`` as it was at ``commit`` (:func:`_before.tree_at`;
    None without git or the commit: the "before" figures are then left out)."""
    try:
        return tree_at(commit)
    except BeforeUnavailable as e:
        print(f"bench_prepare: no 'before' code ({commit[:12]}: {e}); after figures only",
              file=sys.stderr)
        return None


# Run in a child process whose ``repro`` is the code under test (PYTHONPATH), so that the
# prepare's workers (the "before" code's spawned processes; threads since issue 31) run the
# same code; prints one JSON line.
_PREPARE_CHILD = """
import json, os, resource, sys, time
import repro
from repro.data.bandai import load_bandai2, prepare_bandai2
t0 = time.perf_counter()
res = prepare_bandai2(sys.argv[1], workers=int(sys.argv[2]))
cold = time.perf_counter() - t0
me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
t0 = time.perf_counter(); cs = load_bandai2(); warm_open = time.perf_counter() - t0
t0 = time.perf_counter(); cs = load_bandai2(mmap=False); warm_read = time.perf_counter() - t0
print(json.dumps({"cold_prepare_s": cold, "timings": res.timings, "path": str(res.path),
                  "code": repro.__file__,
                  "cpu_s": me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime,
                  "warm_load_mmap_s": warm_open, "warm_load_in_ram_s": warm_read,
                  "clips": len(cs), "frames": cs.n_frames}))
"""


def _tree_sha256(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.iterdir()) if p.is_file()}


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


def prepare_once(source: Path, workers: int, code_root: Path) -> tuple[dict, Path]:
    """Cold prepare in a child process running the ``repro`` under ``code_root``; returns its
    figures and the REPRO_HOME it prepared into (the caller removes it)."""
    home = Path(tempfile.mkdtemp(prefix="bench-repro-home-"))
    env = {**os.environ, "REPRO_HOME": str(home),
           "PYTHONPATH": os.pathsep.join([str(code_root), os.environ.get("PYTHONPATH", "")])}
    t0 = time.perf_counter()
    # -P: ``-c`` would otherwise put the working directory first on sys.path, ahead of
    # PYTHONPATH, and run from the repository root the "before" child would import today's repro
    proc = subprocess.Popen([sys.executable, "-P", "-c", _PREPARE_CHILD, str(source),
                             str(workers)],
                            env=env, stdout=subprocess.PIPE, text=True)
    with PeakSampler(pid=proc.pid) as ps:
        out, _ = proc.communicate()
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"bench_prepare: the prepare under {code_root} failed "
                         f"(exit {proc.returncode})")
    r = json.loads(out.strip().splitlines()[-1])
    path = Path(r.pop("path"))
    if not Path(r.pop("code")).resolve().is_relative_to(code_root.resolve()):
        shutil.rmtree(path.parents[2], ignore_errors=True)
        raise SystemExit(f"bench_prepare: the child meant to run the repro under {code_root} "
                         "imported another one")
    res = {"cold_prepare_s": round(r["cold_prepare_s"], 2),
           "process_wall_s": round(wall, 2),
           "cpu_s": round(r["cpu_s"], 1),
           "timings": {k: round(v, 2) for k, v in r["timings"].items()},
           "peak_rss_tree_mib": round(ps.peak / 2**20, 1),
           "warm_load_mmap_s": round(r["warm_load_mmap_s"], 4),
           "warm_load_in_ram_s": round(r["warm_load_in_ram_s"], 3),
           "clips": r["clips"], "frames": r["frames"],
           "cache_mib": round(sum(p.stat().st_size for p in path.iterdir()) / 2**20, 1),
           "workers": workers}
    return res, path


def bench_prepare(source: Path, workers: int, before_root: Path | None) -> dict:
    """Cold prepare before and after (one after the other), and whether the caches agree."""
    out: dict = {}
    homes = []
    try:
        after, after_path = prepare_once(source, workers, REPO)
        homes.append(after_path)
        out["after"] = after
        if before_root is not None:
            before, before_path = prepare_once(source, workers, before_root)
            homes.append(before_path)
            out["before"] = before
            a, b = _tree_sha256(after_path), _tree_sha256(before_path)
            out["cache_files_identical"] = a == b
            out["cache_files_compared"] = len(a)
            out["cold_speedup"] = round(before["cold_prepare_s"] / after["cold_prepare_s"], 2)
    finally:
        for p in homes:  # <home>/datasets/bandai2/<fingerprint>
            shutil.rmtree(p.parents[2], ignore_errors=True)
    return out


def bench_parse(source: Path, n_files: int, rounds: int = 3, before_root: Path | None = None
                ) -> dict:
    import bvhio
    import numpy as np
    import torch

    import repro.data.bvh as bvh_now
    from repro.data.bvh import read_bvh

    before = (load_module(before_root / "repro" / "data" / "bvh.py", "bench_bvh_before")
              if before_root is not None else None)

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
    blobs = [(str(p), p.read_bytes()) for p in paths]
    if before is not None:  # the same values, bit for bit
        for p in paths:
            x, y = read_bvh(p), before.read_bvh(p)
            assert x.motion.tobytes() == y.motion.tobytes(), p
            assert (x.names, x.parents, x.channels, x.frame_time) == \
                (y.names, y.parents, y.channels, y.frame_time), p
            assert x.offsets.tobytes() == y.offsets.tobytes(), p
    read_bvh(paths[0]).world_positions()  # warm-up (imports, torch init)

    def ours_parse():
        bvh_now._HIERARCHIES.clear()  # each round reads its files cold (module docstring)
        for p in paths:
            read_bvh(p)

    def before_parse():
        for p in paths:
            before.read_bvh(p)

    def ours_parse_bytes():  # what prepare's workers do: parse bytes already in memory
        bvh_now._HIERARCHIES.clear()
        for label, data in blobs:
            bvh_now.parse_bvh(data, label)

    def before_parse_bytes():
        for label, data in blobs:
            before.parse_bvh(data, label)

    def ours_local():  # the same content bvhio.readAsBvh builds: local positions + quaternions
        bvh_now._HIERARCHIES.clear()
        for p in paths:
            b = read_bvh(p)
            b.local_translations()
            b.local_rotations(as_quaternions=True)

    def ours_fk():
        bvh_now._HIERARCHIES.clear()
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

    # Interleaved rounds, best of each, in CPU seconds of this (single-threaded) process: the
    # machine is shared, and wall time also counts the time other jobs hold the cores.
    fns = {"ours_parse": ours_parse, "ours_parse_bytes": ours_parse_bytes,
           "ours_local": ours_local, "ours_fk": ours_fk, "theirs_parse": theirs_parse,
           "theirs_fk": theirs_fk}
    if before is not None:
        fns.update(before_parse=before_parse, before_parse_bytes=before_parse_bytes)
    best = {k: float("inf") for k in fns}
    for r in range(rounds):
        for k, fn in fns.items():
            if k == "theirs_fk" and r > 0:
                continue  # minutes per round; one round is enough for a >10x gap
            t0 = time.process_time()
            fn()
            best[k] = min(best[k], time.process_time() - t0)
    ours_parse_s, ours_local_s, ours_fk_s = best["ours_parse"], best["ours_local"], best["ours_fk"]
    theirs_parse_s, theirs_fk_s = best["theirs_parse"], best["theirs_fk"]
    shutil.rmtree(tmp, ignore_errors=True)
    out = {"files": len(paths), "frames": frames, "rounds": rounds}
    if before is not None:
        out.update({
            "before_parse_s": round(best["before_parse"], 3),
            "before_parse_speedup": round(theirs_parse_s / best["before_parse"], 1),
            "before_parse_bytes_s": round(best["before_parse_bytes"], 3),
            "parse_after_vs_before": round(best["before_parse"] / ours_parse_s, 2)})
    return {**out,
            "ours_parse_s": round(ours_parse_s, 3),
            "ours_parse_bytes_s": round(best["ours_parse_bytes"], 3),
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
    ap.add_argument("--before", default=BEFORE, help="commit whose code is timed as 'before' "
                    "(default: %(default).12s); '' to time only this tree")
    ap.add_argument("--json", type=Path, default=None, help="also write the results here")
    args = ap.parse_args(argv)
    source = args.source or find_bandai_archive()
    if source is None:
        print("bench_prepare: the Bandai-Namco-2 archive was not found; pass --source", file=sys.stderr)
        return 2
    result = {"machine": machine(), "source": str(source), "before_commit": args.before or None}
    before_root = unpack_before(args.before) if args.before else None  # removed at exit
    if not args.skip_prepare:
        result["prepare"] = bench_prepare(Path(source), args.workers, before_root)
    result["parse_vs_bvhio"] = bench_parse(Path(source), args.parse_files, args.rounds,
                                           before_root)
    result["machine"]["load_avg_at_end"] = os.getloadavg()
    text = json.dumps(result, indent=1)
    print(text)
    if args.json:
        args.json.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
