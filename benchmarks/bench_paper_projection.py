"""Project the device time of every table at the ``paper`` scale from two measurements.

On whatever device it finds (CUDA when torch sees one, else the CPU) it times

1. Neural Marionette (MarioNet) training at paper width (supp. Table 2; batch 30) on Table 1's
   training items: ``--batches`` optimiser steps of the first pass alone (epochs before
   scheduled sampling) and as many with scheduled sampling's second pass (epochs 250-1000),
   each after one warm-up step, through the one training loop's step; the epoch is the
   measured per-batch time times the epoch's batch count (extrapolated, and printed as such);
2. Table 1's paper-scale sampling: ``--items`` MarioNet samples (paper width, Table 1's test
   items, their own lengths), per item, extrapolated to the paper's samples per replicate.

Then, for all 18 specs, the planner (:func:`repro.engine.table_plan.build_plan`, as ``repro plan``)
counts each table's jobs at ``paper`` and the projection prices them (the rule is printed with
the table): a ``train`` job costs its method's epochs (the profile's, with their batch counts)
× MarioNet's measured time per training item × (the method's parameter count / MarioNet's); a
``generate`` job costs the samples its protocol draws per replicate × MarioNet's measured time
per sampled item × the same parameter ratio; ``measure`` jobs score on the CPU with the
evaluator and are counted, not priced.  Jobs shared between tables (the full MarioNet serves
Tables 1, 2 and 4) count in each table and once in the total.  A generate job is priced with
the model of its first input (a composite row's first component).

Usage: ``.venv/bin/python benchmarks/bench_paper_projection.py [--batches 2] [--items 4]``.
The data set is the paper profile's stand-in (``bandai2``) when prepared, else the bundled
``bandai2-mini`` (job counts do not depend on it; item counts, hence epochs' batch counts, do:
the printout says which).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import repro  # noqa: F401,E402  (pins the kernel paths before torch / numpy load: repro/kernels.py)
import torch  # noqa: E402

#: per protocol: how many actions one ``generate`` job samples, from its resolved parameters
SAMPLES = {
    "single_action": lambda p, c: p["samples_per_class"] * c,
    "multi_action": lambda p, c: p["sequences"] * p["actions_per_sequence"],
    "ss_ar": lambda p, c: p["sequences"] * p["actions_per_sequence"],
    "multiact_conditioned": lambda p, c: p["per_label"] * c,
    "transition": lambda p, c: p["per_label"] * c,
    "long_term": lambda p, c: p["sequences"] * p["steps"],
    "odmo_generation": lambda p, c: p["per_class"] * c,
    "latent_modes": lambda p, c: p["codes_per_class"] * c,
    "trajectory_customisation": lambda p, c: p["codes_per_class"] * p["end_points_per_code"] * c,
}


def device_name(dev: torch.device) -> str:
    if dev.type == "cuda":
        return f"cuda ({torch.cuda.get_device_name(dev)})"
    from repro.store.runs import cpu_info

    cpu = cpu_info()
    return f"cpu ({cpu['model']}, {torch.get_num_threads()} torch thread(s), {cpu['cpus']} cores)"


def _sync(dev):
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


def n_params(method: str, config: dict, clips) -> int:
    from repro.models.base import generator_class

    cls = generator_class(method)
    gen = cls(config, clips.skeleton, clips.n_classes, clips.fps)
    return sum(p.numel() for p in gen.network.parameters())


def time_training(gen, items, dev, n_batches: int) -> tuple[float, float, int]:
    """Seconds per optimiser step without and with scheduled sampling's second pass, and the
    epoch's batch count on ``items``."""
    from repro.models.base import epoch_batches
    from repro.seeding import torch_generator
    from repro.train.loop import to_device

    cfg = gen.config
    data = gen._tensors(items, with_targets=True)
    net = gen.network.to(dev)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    idx = epoch_batches(len(items), cfg.batch_size, torch_generator(0, "bench"))
    per = []
    for epoch in (0, cfg.ss_accomplish_epoch):  # one pass; two passes (SS active, xi = 1)
        times = []
        for b in idx[:n_batches + 1]:
            batch = to_device(gen._crop(data, b), dev)
            _sync(dev)
            t0 = time.perf_counter()
            out = gen.training_step(net, batch, epoch)
            opt.zero_grad(set_to_none=True)
            out["loss"].backward()
            opt.step()
            _sync(dev)
            times.append(time.perf_counter() - t0)
        per.append(sum(times[1:]) / max(len(times) - 1, 1))  # the first is a warm-up
    return per[0], per[1], len(idx)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batches", type=int, default=2, help="timed training steps per kind")
    ap.add_argument("--items", type=int, default=4, help="timed MarioNet samples")
    a = ap.parse_args(argv)

    from repro.data.registry import load_clipset
    from repro.train.epochs import config_epochs
    from repro.engine.job import topo_order
    from repro.engine.table_plan import build_plan
    from repro.errors import ReproError
    from repro.eval.protocols import get_protocol
    from repro.models.marionet import MarioNet
    from repro.paths import tables_root
    from repro.specs.load import find_spec
    from repro.specs.scales import resolve_scale
    from repro.seeding import prepare_device

    torch.manual_seed(0)
    dev = prepare_device("cuda" if torch.cuda.is_available() else "cpu")
    paper = resolve_scale("paper", device=str(dev))
    t1 = find_spec("marionette/table1")
    dataset = paper.dataset_for(t1)
    try:
        clips = load_clipset(dataset)
    except ReproError:  # not prepared here: the bundled subset (job counts do not change)
        dataset = "bandai2-mini"
        clips = load_clipset(dataset)
    print(f"device: {device_name(dev)}")
    print(f"data: {dataset} ({clips.n_classes} classes); paper profile, device {dev}")

    # 1. MarioNet paper-width training steps on Table 1's training items
    proto = get_protocol("single_action", paper.protocol_settings(t1, t1.columns[0].id))
    train_items, test_items = proto.train_items(clips), proto.test_items(clips)
    mcfg = paper.method_config("marionet")
    gen = MarioNet(mcfg, clips.skeleton, clips.n_classes, clips.fps)
    p_mn = sum(p.numel() for p in gen.network.parameters())
    s1, s2, n_batches = time_training(gen, train_items, dev, a.batches)
    cfg = gen.config
    ss_epochs = cfg.epochs - cfg.ss_activate_epoch
    epoch_first = s1 * n_batches
    epoch_ss = s2 * n_batches
    train_total = cfg.ss_activate_epoch * epoch_first + ss_epochs * epoch_ss
    per_item_epoch = train_total / cfg.epochs / len(train_items)
    print(f"MarioNet paper width: {p_mn / 1e6:.2f} M parameters; {len(train_items)} training "
          f"items, {n_batches} batches of {cfg.batch_size} per epoch")
    print(f"  measured {a.batches} step(s) each (after a warm-up): {s1:.3f} s/step (first pass), "
          f"{s2:.3f} s/step (with scheduled sampling)")
    print(f"  one epoch, EXTRAPOLATED from those steps x {n_batches} batches: {epoch_first:.1f} s "
          f"(epochs < {cfg.ss_activate_epoch}), {epoch_ss:.1f} s (scheduled sampling)")
    print(f"  {cfg.epochs} epochs: {train_total / 3600:.2f} device-hours")

    # 2. Table 1's paper-scale sampling
    k = min(a.items, len(test_items))
    sub = test_items.subset(torch.arange(k))
    gen.network.eval()
    gen.sample(sub, seed=0)  # warm-up
    _sync(dev)
    t0 = time.perf_counter()
    gen.sample(sub, seed=1)
    _sync(dev)
    per_sample = (time.perf_counter() - t0) / k
    n_t1 = SAMPLES["single_action"](paper.protocol_settings(t1, t1.columns[0].id), clips.n_classes)
    reps = len(paper.seeds_for("single_action"))
    print(f"Table 1 sampling: measured {k} MarioNet samples: {per_sample:.2f} s/sample; "
          f"paper scale = {n_t1} samples x {reps} replicates per row = "
          f"{n_t1 * reps * per_sample / 3600:.2f} device-hours per row (EXTRAPOLATED)")

    # 3. every table at paper scale
    specs = sorted(p.relative_to(tables_root()).with_suffix("").as_posix()
                   for p in tables_root().glob("*/*.toml"))
    params: dict[str, int] = {"marionet": p_mn, "neural_marionette": p_mn}
    rows, seen, total_h, total_jobs = [], set(), 0.0, 0
    for sid in specs:
        spec = find_spec(sid)
        plan = build_plan(spec, paper, dataset)
        jobs = topo_order([j for r in plan.rows for js in list(r.train.values())
                           + list(r.measures.values()) for j in js])
        hours, kinds = 0.0, {}
        for j in jobs:
            kinds[j.kind] = kinds.get(j.kind, 0) + 1
            h = _job_hours(j, clips, params, per_item_epoch, per_sample, len(train_items), p_mn,
                           config_epochs)
            hours += h
            if j.key() not in seen:
                seen.add(j.key())
                total_h += h
                total_jobs += 1
        rows.append((sid, len(jobs), kinds, hours))
    print()
    print("Projection rule: train job = epochs x items per epoch x MarioNet's measured s per "
          "training item x (parameters / MarioNet's); generate job = samples per replicate x "
          "MarioNet's measured s per sample x (parameters / MarioNet's); measure jobs (CPU "
          "evaluator) not priced.  Items per epoch: windows_per_epoch where the method has it, "
          f"else Table 1's {len(train_items)} training items.")
    print()
    print(f"| table | jobs | train | generate | measure | projected device-hours ({dev.type}) |")
    print("| --- | ---: | ---: | ---: | ---: | ---: |")
    for sid, n, kinds, h in rows:
        print(f"| {sid} | {n} | {kinds.get('train', 0)} | {kinds.get('generate', 0)} | "
              f"{kinds.get('measure', 0) + kinds.get('measure_real', 0)} | {h:,.1f} |")
    print(f"| all 18 (shared jobs once) | {total_jobs} | | | | {total_h:,.1f} |")
    return 0


def _job_hours(job, clips, params, per_item_epoch, per_sample, n_items, p_mn, config_epochs):
    """The projected device-hours of one job (see the module docstring)."""
    cfg = job.config
    if job.kind not in ("train", "generate"):
        return 0.0
    # a generate job's model is its first input's (a train job: method and its config)
    trained = job.config if job.kind == "train" else (job.inputs[0].config if job.inputs else {})
    method, mcfg = trained.get("method"), trained.get("method_config") or {}
    if not method or method == "nearest_clip":
        return 0.0
    key = (method, tuple(sorted((k, str(v)) for k, v in mcfg.items())))
    if key not in params:
        try:
            params[key] = n_params(method, mcfg, clips)
        except Exception:  # a composite (ACTOR + SSMCT): its components are priced as theirs
            params[key] = 0
    ratio = params[key] / p_mn
    if job.kind == "train":
        epochs = config_epochs(mcfg) or 0
        per_epoch = int(mcfg.get("windows_per_epoch") or n_items)
        return epochs * per_epoch * per_item_epoch * ratio / 3600
    fn = SAMPLES.get(cfg.get("protocol"))
    if fn is None:
        return 0.0
    try:
        n = fn(cfg.get("protocol_params") or {}, clips.n_classes)
    except KeyError:
        return 0.0
    return n * per_sample * ratio / 3600


if __name__ == "__main__":
    raise SystemExit(main())
