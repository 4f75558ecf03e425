"""Evidence for the kernel pin (issue 25, item 2; results in docs/engine.md, "Kernel pinning").

Part 1 (``--ops``, a minute; ~15 minutes more with qemu): the op battery
(``benchmarks/kernel_ops.py``) in fresh processes, pinned and unpinned, under every kernel path
this CPU offers through the environment (ATen ``default`` / ``avx2`` / ``avx512`` where the CPU
has it; MKL ``AUTO`` / ``COMPATIBLE`` / ``AVX2``) and, when ``qemu-x86_64`` is installed
(Debian's ``qemu-user``), under an emulated Intel CPU (``-cpu Haswell``: vendor GenuineIntel,
qemu's own cache model), which is how the ops the environment cannot pin were found.  Pinned,
every variant must give the native pinned bytes; unpinned, the variants show which ops the
paths change (the control).

Part 3 (``--steps ROUNDS``, a minute a round): the training-step cost of each layer family the
harness trains (``benchmarks/kernel_step_cost.py``), pinned and unpinned, alternating.

Part 2 (``--tables``, tens of minutes): the given table specs at ``quick``, each in an empty
``REPRO_HOME``, side by side: pinned with ambient settings that name other paths
(``ATEN_CPU_CAPABILITY=default``, ``MKL_CBWR=AUTO``) and unpinned (``--fast-kernels``); the
pinned run's raw replicate values (``values.jsonl``) must equal, bit for bit, those of a pinned
run with nothing set (``--reference HOME``, or a third run), and the two wall times give the
pin's cost.

    .venv/bin/python benchmarks/bench_kernel_paths.py --ops [--no-qemu] [--json out.json]
    .venv/bin/python benchmarks/bench_kernel_paths.py --tables marionette/table1 [--reference HOME]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BATTERY = ROOT / "benchmarks" / "kernel_ops.py"
GOLDEN = ROOT / "tests" / "golden" / "kernel_ops.json"
AMBIENT = ("ATEN_CPU_CAPABILITY", "MKL_CBWR", "ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA",
           "OPENBLAS_CORETYPE", "OPENBLAS_NUM_THREADS", "NPY_DISABLE_CPU_FEATURES",
           "MKL_DYNAMIC", "OMP_DYNAMIC",
           "REPRO_FAST_KERNELS")


def _env(**extra) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in AMBIENT}
    env.update({k: v for k, v in extra.items() if v is not None})
    return env


def _cpu_flags() -> set[str]:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def battery(prefix: list[str], **env) -> dict | None:
    """The battery's hashes; None when it crashed under emulation (said in the result)."""
    r = subprocess.run(prefix + [sys.executable, str(BATTERY)], env=_env(**env), text=True,
                       capture_output=True, timeout=3600, cwd=ROOT)
    if r.returncode != 0:
        if prefix:
            return None
        raise SystemExit(f"battery failed ({env}): {r.stderr[-800:]}")
    return json.loads(r.stdout)


def ops(use_qemu: bool) -> dict:
    atens = ["default", "avx2"] + (["avx512"] if "avx512f" in _cpu_flags() else [])
    variants = [(f"ATEN={a} MKL={m}", {"ATEN_CPU_CAPABILITY": a, "MKL_CBWR": m})
                for a in atens for m in ("AUTO", "COMPATIBLE", "AVX2")]
    variants.append(("ambient (nothing set)", {}))
    qemu = shutil.which("qemu-x86_64") if use_qemu else None
    out: dict = {"host_flags": sorted(_cpu_flags() & {"avx2", "avx512f", "amx_tile"}),
                 "qemu": qemu, "pinned": {}, "unpinned": {}}
    ref = battery([])
    ref_ops = {k: v for k, v in ref.items() if not k.startswith("_")}
    out["reference_state"] = ref["_state"]
    for mode in ("pinned", "unpinned"):
        fast = None if mode == "pinned" else "1"
        got = {}
        for name, env in variants:
            b = battery([], REPRO_FAST_KERNELS=fast, **env)
            got[name] = {k: v for k, v in b.items() if not k.startswith("_")}
            out[mode][name] = {"state": b["_state"]}
        # pinned: against the pinned reference; unpinned: against this host's own default paths
        base = ref_ops if mode == "pinned" else got["ambient (nothing set)"]
        for name in got:
            out[mode][name]["differ"] = sorted(k for k in base if got[name].get(k) != base[k])
        if qemu:
            t0 = time.perf_counter()
            b = battery([qemu, "-cpu", "Haswell"], REPRO_FAST_KERNELS=fast)
            if b is None:  # unpinned: oneDNN's JIT code crashes qemu's emulation
                out[mode]["qemu -cpu Haswell (GenuineIntel)"] = {
                    "crashed": True, "seconds": round(time.perf_counter() - t0, 1),
                    "differ": ["(crashed under emulation)"] if mode == "pinned" else []}
                continue
            b_ops = {k: v for k, v in b.items() if not k.startswith("_")}
            native_unused = ref["_unused"] if mode == "pinned" else None
            out[mode]["qemu -cpu Haswell (GenuineIntel)"] = {
                "state": b["_state"], "seconds": round(time.perf_counter() - t0, 1),
                "differ": sorted(k for k in base if b_ops.get(k) != base[k]),
                **({"unused_ops_differ": sorted(k for k in native_unused
                                                if b["_unused"].get(k) != native_unused[k])}
                   if native_unused else {})}
    ok = all(not v["differ"] for v in out["pinned"].values())
    out["pinned_all_equal"] = ok
    # the pinned bytes against the hashes committed from the golden host (another CPU)
    golden = json.loads(GOLDEN.read_text())
    out["golden"] = {"host": golden["note"],
                     "ops": len(golden["ops"]),
                     "differ": sorted(k for k in golden["ops"] if ref_ops.get(k) != golden["ops"][k])}
    out["hashes"] = ref_ops
    return out


def _values(home: Path, table: str) -> list[str]:
    runs = sorted((home / "runs").iterdir())
    for d in reversed(runs):
        rj = json.loads((d / "run.json").read_text())
        if rj.get("table") == table and rj.get("status") == "FINISHED":
            rows = [json.loads(x) for x in (d / "values.jsonl").read_text().splitlines()]
            # the job key names the code and the kernel mode, not the value: left out
            return sorted(json.dumps({k: v for k, v in r.items() if k != "job"}, sort_keys=True)
                          for r in rows)
    raise SystemExit(f"no finished run of {table} in {home}")


def tables(names: list[str], jobs: int, reference: Path | None) -> dict:
    """Part 2: the tables pinned with ambient settings that name other paths, and unpinned
    (``--fast-kernels``), side by side from empty stores (so both share the machine alike:
    their wall-time ratio is the pin's cost); the pinned run's raw values against the
    reference store's (a pinned run with nothing set), or against a second pinned run."""
    repro = str(Path(sys.executable).with_name("repro"))
    variants = [("pinned, ATEN=default MKL=AUTO", {"ATEN_CPU_CAPABILITY": "default",
                                                   "MKL_CBWR": "AUTO"}, []),
                ("unpinned (--fast-kernels)", {}, ["--fast-kernels"])]
    if reference is None:
        variants.append(("pinned, nothing set", {}, []))
    procs, homes = {}, {}
    for label, env, extra in variants:
        home = Path(tempfile.mkdtemp(prefix="repro-paths-"))
        homes[label] = home
        with (home / "stderr.txt").open("w") as err:  # the child keeps its own descriptor
            procs[label] = (time.perf_counter(), subprocess.Popen(
                [repro, "run", *names, "--scale", "quick", "--quiet", "--jobs", str(jobs),
                 *extra],
                env=_env(REPRO_HOME=str(home), **env), cwd=ROOT, stdout=subprocess.DEVNULL,
                stderr=err))
    out: dict = {"tables": names, "jobs_per_run": jobs, "runs": {}}
    # each run's own end time: polled, so a run that ends first is not timed as the last one
    # (reading them in turn timed every run as the slowest)
    ended: dict[str, float] = {}
    deadline = time.perf_counter() + 4 * 3600  # a hung run ends the benchmark, not the machine

    def stop_all() -> None:
        for _, q in procs.values():
            if q.poll() is None:
                q.terminate()

    while len(ended) < len(procs):
        for label, (_, p) in procs.items():
            if label not in ended and p.poll() is not None:
                ended[label] = time.perf_counter()
                if p.returncode != 0:  # one failed: stop the others now, report it below
                    stop_all()
        if time.perf_counter() > deadline:
            stop_all()
            raise SystemExit("part 2: a table run took over 4 hours; stopped")
        time.sleep(0.5)
    for label, (t0, p) in sorted(procs.items(), key=lambda kv: ended[kv[0]]):  # first end first
        if p.returncode != 0:
            err = (homes[label] / "stderr.txt").read_text(errors="replace")
            raise SystemExit(f"{label}: repro run failed: {err[-800:]}")
        out["runs"][label] = {"seconds": round(ended[label] - t0, 1),
                              "home": str(homes[label])}
    pinned = homes[variants[0][0]]
    ref = reference if reference is not None else homes["pinned, nothing set"]
    out["reference"] = str(ref)
    out["equal"] = {t: _values(pinned, t) == _values(ref, t) for t in names}
    out["values"] = {t: len(_values(ref, t)) for t in names}
    out["unpinned_equal"] = {t: _values(homes["unpinned (--fast-kernels)"], t) == _values(ref, t)
                             for t in names}
    a = out["runs"][variants[0][0]]["seconds"]
    b = out["runs"]["unpinned (--fast-kernels)"]["seconds"]
    out["cost_ratio_pinned_over_unpinned"] = round(a / b, 2)
    return out


def steps(rounds: int) -> dict:
    """Part 3 (``--steps``): the training-step cost of each layer family pinned and unpinned,
    alternating the two modes ``rounds`` times in fresh processes so that both see the same
    machine load; the median of each."""
    import statistics

    script = ROOT / "benchmarks" / "kernel_step_cost.py"
    got: dict[str, list[dict]] = {"pinned": [], "unpinned": []}
    for _ in range(rounds):
        for mode, fast in (("pinned", None), ("unpinned", "1")):
            r = subprocess.run([sys.executable, str(script)], env=_env(REPRO_FAST_KERNELS=fast),
                               text=True, capture_output=True, timeout=1800, cwd=ROOT)
            if r.returncode != 0:
                raise SystemExit(f"step cost ({mode}) failed: {r.stderr[-800:]}")
            got[mode].append(json.loads(r.stdout))
    out: dict = {"rounds": rounds, "ms_per_step": {}, "ratio_pinned_over_unpinned": {}}
    for fam in got["pinned"][0]:
        p = statistics.median(g[fam] for g in got["pinned"])
        u = statistics.median(g[fam] for g in got["unpinned"])
        out["ms_per_step"][fam] = {"pinned": p, "unpinned": u}
        out["ratio_pinned_over_unpinned"][fam] = round(p / u, 2)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ops", action="store_true", help="part 1: the op battery")
    ap.add_argument("--no-qemu", action="store_true", help="part 1 without the emulated Intel CPU")
    ap.add_argument("--tables", nargs="*", default=None, metavar="TABLE", help="part 2")
    ap.add_argument("--steps", type=int, default=0, metavar="ROUNDS",
                    help="part 3: training-step cost per layer family, pinned vs unpinned")
    ap.add_argument("--jobs", type=int, default=1, help="--jobs of each part-2 run (they run "
                    "side by side)")
    ap.add_argument("--reference", default=None, help="part 2: a REPRO_HOME holding a pinned "
                    "run of the tables to compare with")
    ap.add_argument("--json", default=None, help="write the result here")
    args = ap.parse_args()
    result: dict = {}
    if args.ops:
        result["ops"] = ops(not args.no_qemu)
    if args.tables:
        result["tables"] = tables(args.tables, args.jobs,
                                  Path(args.reference) if args.reference else None)
    if args.steps:
        result["steps"] = steps(args.steps)
    if not result:
        ap.error("say --ops, --tables TABLE... and/or --steps ROUNDS")
    text = json.dumps(result, indent=1, sort_keys=True)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n")
    bad = (("ops" in result and not result["ops"]["pinned_all_equal"])
           or ("tables" in result and not all(result["tables"]["equal"].values())))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
