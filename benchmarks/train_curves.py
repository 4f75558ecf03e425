"""Learning curves before and after issue 31's number-changing speed-ups (issue 31, "a statement
of equivalence"): each method trained at ``medium`` on its own ``train`` job's items, from
training seeds 0, 1, 2 (``--seeds``), through the training paths of commit
``bench_train_throughput.BEFORE`` (swapped in as that benchmark does) and through today's,
recording the validation loss of every epoch on the job's held-out share of the training clips
(``validation_fraction``; never test clips).

The statement per method: at every epoch, the difference of the two paths' mean validation
losses against the seed-to-seed spread (the pooled standard deviation of the seeds, both paths);
"within the spread" when the difference is at most that standard deviation at every epoch.
Beside it, for curves whose epoch-to-epoch noise is large (:func:`exceedance`): the share of
epochs outside the spread against the share expected when the two paths are equivalent (their
seeds independent draws of one distribution), and how many epochs each path was the lower.
Printed as a table, written with every raw value by ``--json FILE``.

    .venv/bin/python benchmarks/train_curves.py --methods marionet --json out.json [--seeds 0,1,2]
        [--before-from earlier.json]   # reuse an earlier run's "before" curves
    .venv/bin/python benchmarks/train_curves.py --methods macvae --combine a.json,b.json --json c.json

A full ``medium`` training per seed and path: minutes to tens of minutes per method on a 2-core
machine (MarioNet ~3 minutes after, ~6 before, per seed).  Needs the git history holding the
"before" commit (exit 2 without it) and the profile's data set prepared.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import repro  # noqa: F401,E402  (pins the kernel paths before torch / numpy load)
import torch  # noqa: E402
from bench_train_throughput import (BEFORE, METHOD_SPECS, head_commit, before_available,  # noqa: E402
                                    before_paths, path_generator, train_job_configs)

#: the history key each method's curve is read from (the validation loss of its own objective)
CURVE = "val_loss"


def curve(method: str, cfg: dict, clips, train_items, val_items, seed: int, path: str):
    """(validation losses per epoch, seconds) of one full training of ``method``."""
    gen = path_generator(path, method, cfg, clips, train_items.fps)
    ctx = before_paths() if path == "before" else contextlib.nullcontext()
    t0 = time.perf_counter()
    with ctx:
        res = gen.fit(train_items, seed=seed, val_items=val_items)
    return [float(h[CURVE]) for h in res.history if CURVE in h], time.perf_counter() - t0


def summarise(before: list[list[float]], after: list[list[float]]) -> list[dict]:
    """Per epoch: the two paths' means and standard deviations over seeds, the difference,
    the pooled seed standard deviation and whether the difference is within it."""
    rows = []
    for e in range(min(min(map(len, before)), min(map(len, after)))):
        b, a = [c[e] for c in before], [c[e] for c in after]
        sb, sa = statistics.stdev(b), statistics.stdev(a)
        pooled = math.sqrt((sb * sb + sa * sa) / 2)
        diff = statistics.fmean(a) - statistics.fmean(b)
        rows.append({"epoch": e, "before_mean": statistics.fmean(b), "before_sd": sb,
                     "after_mean": statistics.fmean(a), "after_sd": sa, "diff": diff,
                     "pooled_sd": pooled, "within": abs(diff) <= pooled})
    return rows


def exceedance(rows: list[dict], n_seeds: int) -> dict:
    """Epochs outside the seed spread, against chance: with ``n`` seeds per path drawn from one
    normal distribution, the difference of the two means over the pooled sample sd (2(n − 1)
    degrees of freedom) times √(n/2) is Student-t with 2(n − 1) degrees of freedom, so the
    difference exceeds the pooled sd with probability 2·P(T > √(n/2)) (0.29 for 3 seeds per
    path, 0.11 for 6; 200,000 simulated draws give 0.288 for 3).  Also the epochs where each
    path's mean is the lower (a systematic shift shows as one-sided)."""
    from scipy.stats import t as student_t

    expected = float(2 * student_t.sf(math.sqrt(n_seeds / 2), 2 * (n_seeds - 1)))
    out = [r for r in rows if not r["within"]]
    return {"epochs": len(rows), "outside": len(out),
            "outside_share": len(out) / len(rows) if rows else float("nan"),
            "expected_share_if_equivalent": expected,
            "after_lower": sum(r["diff"] < 0 for r in rows),
            "before_lower": sum(r["diff"] > 0 for r in rows)}


def statement(m: str, raw: dict, secs: dict, seeds: list[int]) -> dict:
    """The per-method record (raw curves, seconds, per-epoch rows, ``equivalent``,
    :func:`exceedance`), printed as a table."""
    rows = summarise(raw["before"], raw["after"])
    ok = all(r["within"] for r in rows)
    ex = exceedance(rows, len(seeds))
    print(f"\n{m}: {CURVE} per epoch over seeds {seeds} (mean ± sd)")
    print("| epoch | before | after | after − before | seed sd (pooled) | within |")
    print("| ---: | ---: | ---: | ---: | ---: | --- |")
    for r in rows:
        print(f"| {r['epoch']} | {r['before_mean']:.4f} ± {r['before_sd']:.4f} | "
              f"{r['after_mean']:.4f} ± {r['after_sd']:.4f} | {r['diff']:+.4f} | "
              f"{r['pooled_sd']:.4f} | {'yes' if r['within'] else 'no'} |")
    print(f"{m}: outside the spread at {ex['outside']} of {ex['epochs']} epochs "
          f"({ex['outside_share']:.0%}; {ex['expected_share_if_equivalent']:.0%} expected "
          f"for equivalent paths); after lower at {ex['after_lower']}, before lower at "
          f"{ex['before_lower']}")
    print(f"{m}: {'within the seed spread at every epoch' if ok else 'NOT within'}; "
          f"training time before {statistics.fmean(secs['before']):.0f} s, after "
          f"{statistics.fmean(secs['after']):.0f} s per seed\n", flush=True)
    return {"raw": raw, "seconds": secs, "epochs": rows, "equivalent": ok, "exceedance": ex}


def combine(files: list[str], methods: list[str]) -> dict:
    """One statement per method over the seeds of several earlier ``--json`` runs (same before
    commit, scale and curve; no seed twice): their raw curves concatenated."""
    runs = [json.loads(Path(f).read_text()) for f in files]
    key = {(r["before"], r["scale"], r["curve"]) for r in runs}
    seeds = [s for r in runs for s in r["seeds"]]
    if len(key) != 1 or len(set(seeds)) != len(seeds):
        raise ValueError("the runs differ in before commit, scale or curve, or repeat a seed")
    before, scale, curve_key = key.pop()
    out = {"schema": 1, "benchmark": "train_curves", "before": before,
           "after": [r["after"] for r in runs], "scale": scale, "curve": curve_key,
           "seeds": seeds, "combined_from": files, "methods": {}}
    for m in methods:
        raw = {p: [c for r in runs for c in r["methods"][m]["raw"][p]] for p in ("before", "after")}
        secs = {p: [t for r in runs for t in r["methods"][m]["seconds"][p]]
                for p in ("before", "after")}
        out["methods"][m] = statement(m, raw, secs, seeds)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", required=True, help="comma-separated trained methods")
    ap.add_argument("--seeds", default="0,1,2", help="training seeds (at least two)")
    ap.add_argument("--scale", default="medium")
    ap.add_argument("--json", default=None, metavar="FILE")
    ap.add_argument("--before-from", default=None, metavar="FILE",
                    help="take the 'before' curves from an earlier --json FILE (same before "
                         "commit, scale and seeds) instead of training them again: the "
                         "before paths do not change, only today's do")
    ap.add_argument("--combine", default=None, metavar="FILE,FILE",
                    help="no training: one statement over the seeds of earlier --json FILEs")
    a = ap.parse_args(argv)
    methods = [m.strip() for m in a.methods.split(",") if m.strip()]
    seeds = [int(s) for s in a.seeds.split(",") if s.strip()]
    if a.combine:
        try:
            out = combine([f for f in a.combine.split(",") if f], methods)
        except (OSError, ValueError, KeyError) as e:
            print(f"curves: --combine: {e}", file=sys.stderr)
            return 2
        if a.json:
            Path(a.json).write_text(json.dumps(out, indent=1) + "\n")
        return 0
    if any(m not in METHOD_SPECS for m in methods) or len(seeds) < 2:
        print(f"curves: --methods from {', '.join(METHOD_SPECS)}; --seeds at least two",
              file=sys.stderr)
        return 2
    from repro.engine import steps as job_steps
    from repro.errors import ReproError
    from repro.models.base import generator_class
    from repro.specs.scales import resolve_scale
    from repro.train.validation import holdout

    if not before_available("curves"):
        return 2
    earlier = {}
    if a.before_from:
        try:
            prev = json.loads(Path(a.before_from).read_text())
            if (prev.get("before"), prev.get("scale"), prev.get("seeds")) != (BEFORE, a.scale, seeds):
                raise ValueError(f"made for before {prev.get('before')}, scale "
                                 f"{prev.get('scale')}, seeds {prev.get('seeds')}")
            earlier = {m: prev["methods"][m] for m in methods}
        except (OSError, ValueError, KeyError) as e:
            print(f"curves: {a.before_from}: cannot take its before curves ({e})", file=sys.stderr)
            return 2
    try:
        scale = resolve_scale(a.scale)
        configs = train_job_configs(methods, scale, None)
        clips = job_steps.clipset(next(iter(configs.values()))["dataset"])
    except ReproError as e:
        print(f"curves: {e}", file=sys.stderr)
        return 2
    torch.set_num_threads(int(getattr(scale, "threads", 1) or 1))
    out = {"schema": 1, "benchmark": "train_curves", "before": BEFORE, "after": head_commit(),
           "scale": a.scale, "curve": CURVE, "seeds": seeds, "methods": {}}
    for m in methods:
        cfg = configs[m]
        items = job_steps.training_items(cfg, clips, getattr(generator_class(m), "item_kind",
                                                             "actions"))
        fraction, val_seed = job_steps.validation_settings(cfg, 0)
        train_items, val_items = holdout(items, fraction, val_seed)
        raw = {"before": [], "after": []}
        secs = {"before": [], "after": []}
        paths = ("before", "after")
        if m in earlier:
            raw["before"] = earlier[m]["raw"]["before"]
            secs["before"] = earlier[m]["seconds"]["before"]
            paths = ("after",)
            out.setdefault("before_from", {})[m] = a.before_from
        for s in seeds:
            for path in paths:
                c, t = curve(m, cfg, clips, train_items, val_items, s, path)
                raw[path].append(c)
                secs[path].append(t)
                print(f"{m} seed {s} {path}: {len(c)} epochs, {t:.0f} s, last {c[-1]:.5g}",
                      flush=True)
        out["methods"][m] = statement(m, raw, secs, seeds)
        if a.json:
            Path(a.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
