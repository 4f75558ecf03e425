"""Key/value-cache benchmark of MarioNet's frame-by-frame sampler (issue 5 item 1, issue 17
item 2).

Generates ``--batch`` (64) sequences of ``--frames`` (120) frames with MarioNet at the paper's
width (supp. Table 2: d = 256, 8 heads, 6 motion-decoder layers, feed-forward 1024), in one
run, on the same weights and conditions, with

- the key/value-cached sampler before issue 17 (``before``: taken from git history at
  :data:`BEFORE` by ``benchmarks/_before.py`` and swapped in by :func:`old_cached_sampler`;
  caches grown by ``torch.cat`` at every step, separate q/k/v projections, per-step masks and
  positional encodings),
- the library's cached sampler (``after``: preallocated key/value caches written in place,
  the cross-attention memory's keys/values projected once per pass (issue 31), fused and
  pre-transposed step weights, everything reusable made once per call),
- the uncached sampler, recomputing the full causal pass at every step.

Targets (issue 17): ``after`` >= 25x the uncached sampler, and its output equal to both the
uncached and the ``before`` output to 1e-5.  The check is on the sampler's output, the
decoder's poses (raw 6D rotations and root translations); the world-frame motions derived from
them (Gram-Schmidt, forward kinematics) are reported too, with the smallest raw 6D column norm:
untrained weights emit short 6D columns, and Gram-Schmidt magnifies float32 rounding by about
the inverse of that norm.  The cached samplers are timed ``--repeats`` times each, alternately
(so load changes hit both alike), the uncached one once.

It also times the multi-action pipeline's unit of work, one 20-action sequence
(``--chain-actions``; ``--chain-sequences`` of them side by side), chained as the
``multi_action`` protocol chains them (supp. Alg. 1: every action starts from the last 6
generated frames of the previous one), with each cached sampler, as generated frames per
second.

Conditions are real: the first 6 frames of ``--batch`` clips of the bundled ``bandai2-mini``
set (their labels, motion-graph next labels and, for moving classes, their trajectories
padded with the last point), each asked for ``--frames`` frames; the chain draws its actions
(tag, duration, trajectory) uniformly from the same clips (seed ``--seed``).  Weights are
MarioNet's seeded initialisation (the cost of sampling does not depend on training).

Usage: .venv/bin/python benchmarks/bench_kv_cache.py [--batch 64] [--frames 120]
       [--threads N] [--repeats 3] [--chain-actions 20] [--chain-sequences 1] [--json]

A checkout without the git history holding :data:`BEFORE` (a source tarball, a shallow clone)
has no "before" sampler: the benchmark then says so and ends with exit 2.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _before import BeforeUnavailable, import_before, swapped  # after the path entry

#: the code before issue 17's sampler work (the cached sampler of :func:`old_cached_sampler`)
BEFORE = "4b3830acd23621ac745fb0b587599a3a5f9acb15"
#: issue 17's target: the cached sampler against the uncached one
TARGET_SPEEDUP = 25.0
#: largest accepted difference between two samplers' poses
TOLERANCE = 1e-5


def _cpu_name() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def old_cached_sampler(commit: str = BEFORE):
    """A context manager within which MarioNet samples with the key/value-cached sampler as it
    was at ``commit`` (imported from git history, ``benchmarks/_before.py``):
    ``MarioNetNet.generate`` and the decoder's cache (``TransformerDecoder.init_cache`` /
    ``step``, ``DecoderLayer.step``, with the old ``DecoderCache`` they make) are the old
    commit's, on today's model object and weights (the layers' parameters are the same).
    BeforeUnavailable without that history."""
    from repro.models.layers import DecoderLayer, TransformerDecoder
    from repro.models.marionet import MarioNetNet

    old_layers = import_before(commit, "repro/models/layers.py")
    old_net = vars(import_before(commit, "repro/models/marionet.py").MarioNetNet)
    old_dec, old_layer = vars(old_layers.TransformerDecoder), vars(old_layers.DecoderLayer)
    return swapped((MarioNetNet, "generate", old_net["generate"]),
                   (TransformerDecoder, "init_cache", old_dec["init_cache"]),
                   (TransformerDecoder, "step", old_dec["step"]),
                   (DecoderLayer, "step", old_layer["step"]))


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def _chain_fps(model, src, *, actions: int, sequences: int, seed: int) -> dict:
    """Generated frames per second of ``sequences`` chains of ``actions`` actions, built and
    run by the ``multi_action`` protocol's chaining (its ``_chain``) with ``model.sample``."""
    import numpy as np
    import torch

    from repro.eval.protocols import get_protocol
    from repro.eval.protocols.multi_action import TestSet
    from repro.seeding import numpy_rng

    proto = get_protocol("multi_action", {"actions_per_sequence": actions,
                                          "sequences": sequences})
    rng = numpy_rng(seed, "bench_kv_cache", "chain")
    pos = rng.integers(0, len(src), size=(sequences, actions))
    labels = src.labels.numpy()[pos]
    nxt = np.concatenate([labels[:, 1:], labels[:, -1:]], axis=1)   # last: its own tag
    ts = TestSet(pos, nxt, np.unique(pos), np.ones(len(src)))
    frames = int(src.lengths[torch.from_numpy(pos.reshape(-1))].sum())

    def sampler(cond, s):
        return model.sample(cond, seed=s), torch.zeros(len(cond), dtype=torch.bool)

    out, secs = _timed(lambda: proto._chain(sampler, src, ts, seed=seed))
    return {"frames": frames, "s": secs, "fps": frames / secs, "samples": out}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--threads", type=int, default=1,
                    help="torch threads (default 1: steadier timings on a shared machine)")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs of each cached sampler")
    ap.add_argument("--chain-actions", type=int, default=20,
                    help="actions per chained sequence (0: skip the chain figure)")
    ap.add_argument("--chain-sequences", type=int, default=1,
                    help="chained sequences generated side by side")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    if min(args.batch, args.frames, args.repeats, args.chain_sequences) < 1 or args.chain_actions < 0:
        ap.error("--batch, --frames, --repeats and --chain-sequences must be >= 1, "
                 "--chain-actions >= 0")

    import torch

    try:
        old_cached_sampler()  # the old code imported up front: no history, no "before" (exit 2)
    except BeforeUnavailable as e:
        print(f"bench_kv_cache: no 'before' sampler: {e}", file=sys.stderr)
        return 2
    from repro.data.registry import load_clipset
    from repro.data.action_items import condition_items
    from repro.data.contexts import build_items
    from repro.models.marionet import MarioNet

    torch.set_num_threads(max(1, args.threads))
    clips = load_clipset("bandai2-mini")
    all_items = build_items(clips, None)
    pick = torch.arange(args.batch) % len(all_items)
    src = all_items.subset(pick)
    T = args.frames
    traj = src.trajectory[:, :T]
    if traj.shape[1] < T:
        traj = torch.cat([traj, traj[:, -1:].expand(-1, T - traj.shape[1], -1)], 1)
    items = condition_items(src.initial_world(), src.labels, src.next_labels,
                            torch.full((args.batch,), T), src.label_names, trajectory=traj)

    model = MarioNet(None, clips.skeleton, clips.n_classes, clips.fps)  # paper widths
    cfg = model.config
    n_params = sum(p.numel() for p in model.network.parameters())

    def before():
        with old_cached_sampler():
            return model.generate_poses(items, seed=args.seed, use_cache=True)

    def after():
        return model.generate_poses(items, seed=args.seed, use_cache=True)

    warm = items.subset(torch.arange(min(4, args.batch)))
    model.generate_poses(warm, seed=args.seed)                      # warm-up, both paths
    with old_cached_sampler():
        model.generate_poses(warm, seed=args.seed)

    before_s, after_s = [], []
    for _ in range(args.repeats):
        raw_before, s = _timed(before)
        before_s.append(s)
        raw_cached, s = _timed(after)
        after_s.append(s)
    raw_full, uncached_s = _timed(lambda: model.generate_poses(items, seed=args.seed,
                                                               use_cache=False))

    # the sampler's output (decoder poses: 6D rotations and root, item frame) ...
    diff_raw = float((raw_cached - raw_full).abs().max())
    diff_before = float((raw_cached - raw_before).abs().max())
    diff_before_full = float((raw_before - raw_full).abs().max())
    # ... and the world-frame motions built from it (Gram-Schmidt, FK)
    cached, full = model.finish(items, raw_cached), model.finish(items, raw_full)
    diff_root = float((cached.root - full.root).abs().max())
    diff_rot = float((cached.rot6d - full.rot6d).abs().max())
    diff_joints = float((cached.joints() - full.joints()).abs().max())
    # conditioning of Gram-Schmidt: its sensitivity grows like 1 / |first 6D column|
    J = clips.skeleton.n_joints
    col1 = raw_cached[..., :-3].reshape(*raw_cached.shape[:-1], J, 3, 2)[..., 0].norm(dim=-1)
    t_before, t_after = statistics.median(before_s), statistics.median(after_s)

    chain = {}
    if args.chain_actions:
        kw = {"actions": args.chain_actions, "sequences": args.chain_sequences, "seed": args.seed}
        with old_cached_sampler():
            chain_before = _chain_fps(model, all_items, **kw)
        chain_after = _chain_fps(model, all_items, **kw)
        chain_diff = float((chain_after["samples"].motion.root
                            - chain_before["samples"].motion.root).abs().max())
        chain = {"chain_actions": args.chain_actions, "chain_sequences": args.chain_sequences,
                 "chain_frames": chain_after["frames"],
                 "chain_before_s": round(chain_before["s"], 3),
                 "chain_after_s": round(chain_after["s"], 3),
                 "chain_before_fps": round(chain_before["fps"], 1),
                 "chain_after_fps": round(chain_after["fps"], 1),
                 "chain_max_abs_diff_root_m": chain_diff}

    speedup = uncached_s / t_after
    res = {
        "batch": args.batch, "frames": T, "d_model": cfg.d_model, "decoder_layers": cfg.dec_layers,
        "heads": cfg.dec_heads, "ff": cfg.dec_ff, "parameters": n_params,
        "before_s": round(t_before, 3), "before_runs_s": [round(x, 3) for x in before_s],
        "cached_s": round(t_after, 3), "cached_runs_s": [round(x, 3) for x in after_s],
        "uncached_s": round(uncached_s, 3), "speedup": round(speedup, 1),
        "speedup_before": round(uncached_s / t_before, 1),
        "after_vs_before": round(t_before / t_after, 2),
        "max_abs_diff_poses": diff_raw, "max_abs_diff_poses_vs_before": diff_before,
        "max_abs_diff_poses_before_vs_uncached": diff_before_full,
        "max_abs_diff_root_m": diff_root, "max_abs_diff_rot6d": diff_rot,
        "max_abs_diff_joints_m": diff_joints, "min_6d_column_norm": float(col1.min()),
        **chain,
        "pass": bool(speedup >= TARGET_SPEEDUP and diff_raw <= TOLERANCE
                     and diff_before <= TOLERANCE),
        "torch": torch.__version__, "threads": torch.get_num_threads(), "cpu": _cpu_name(),
        "cpus": os.cpu_count(), "python": platform.python_version(),
        "load_average_1min": round(os.getloadavg()[0], 2),
    }
    if args.json:
        print(json.dumps(res))
    else:
        def runs(xs):
            return ", ".join(f"{x:.2f}" for x in xs)

        print(f"MarioNet sampling, {args.batch} x {T} frames, d={cfg.d_model}, "
              f"{cfg.dec_layers} decoder layers ({n_params:,} parameters)")
        print(f"  cached, before : {t_before:8.2f} s  (median of {len(before_s)}: "
              f"{runs(before_s)})  {uncached_s / t_before:6.1f}x the uncached")
        print(f"  cached, after  : {t_after:8.2f} s  (median of {len(after_s)}: "
              f"{runs(after_s)})  {speedup:6.1f}x the uncached   (target >= {TARGET_SPEEDUP:g}x)"
              f";  {t_before / t_after:.2f}x before")
        print(f"  uncached       : {uncached_s:8.2f} s")
        print(f"  max |after - uncached| of the sampler's poses: {diff_raw:.2e}   "
              f"(target <= {TOLERANCE:g})")
        print(f"  max |after - before|   of the sampler's poses: {diff_before:.2e}   "
              f"(target <= {TOLERANCE:g}; before vs uncached {diff_before_full:.2e})")
        print(f"    derived, world frame: root {diff_root:.2e} m, joints {diff_joints:.2e} m, "
              f"orthonormalised 6D {diff_rot:.2e}")
        print(f"    (smallest raw 6D first-column norm {float(col1.min()):.3f}: Gram-Schmidt "
              "magnifies differences by about its inverse)")
        if chain:
            print(f"  {chain['chain_sequences']} x {chain['chain_actions']}-action sequence "
                  f"({chain['chain_frames']} frames each pass, multi_action chaining): "
                  f"before {chain['chain_before_fps']:.0f} frames/s ({chain['chain_before_s']:.2f} s), "
                  f"after {chain['chain_after_fps']:.0f} frames/s ({chain['chain_after_s']:.2f} s); "
                  f"max root diff {chain['chain_max_abs_diff_root_m']:.1e} m")
        print(f"  {res['cpu']} ({res['cpus']} CPUs, 1-min load {res['load_average_1min']}), "
              f"{res['threads']} torch threads, torch {res['torch']}")
        print("  PASS" if res["pass"] else "  FAIL")
    return 0 if res["pass"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
