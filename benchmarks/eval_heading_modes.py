"""Which evaluator heading mode holds accuracy on real *chained* motion (docs/evaluators.md).

The multi-action protocols chain actions, so an action ends up facing wherever the chain took
it, while the stand-in's classes have fixed absolute headings (bandai2 SOURCE.md).  This script
trains the Neural Marionette recogniser (the transformer, at the profile's settings, through the
store: a trained one is reused) with each heading mode — ``raw``, ``remove``, ``yaw_augment`` —
on the protocol's training split and scores the real test actions twice:

- *as recorded* (each clip in its own world frame, what the single-action tables see);
- *in their composed test sequences* (the frames of the ``bandai2-seq`` view, headings as the
  motion graph placed them: what the chained protocols see).

Printed, per mode: top-1 accuracy on both, and the drop from the first to the second.

Usage: .venv/bin/python benchmarks/eval_heading_modes.py [--scale quick] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys

import repro  # noqa: F401,E402  (pins the kernel paths before torch / numpy load: repro/kernels.py)
import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", default="quick")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)

    import torch

    from repro.data.clipset import TEST
    from repro.data.sequences import ROLE_ACTION
    from repro.eval.protocols import get_protocol
    from repro.eval.protocols.single_action import evaluation_clips
    from repro.eval.provider import get_evaluator
    from repro.specs.scales import resolve_scale

    torch.set_num_threads(1)
    scale = resolve_scale(args.scale)
    dataset = scale.dataset or "bandai2"
    from repro.data.registry import load_clipset

    clips = load_clipset(dataset)
    proto = get_protocol("multi_action", scale.protocol_config("multi_action"))
    source = proto.item_source()
    sc = source.split_clipset(clips)
    seqs = source.sequences(clips)
    segs = seqs.segments(split=TEST, role=ROLE_ACTION)
    labels = seqs.seg_label[segs]
    T = min(int(seqs.seg_length[segs].max()), source.max_frames)
    lens = np.minimum(seqs.seg_length[segs], T)
    J = clips.skeleton.n_joints

    def windows(rows_of) -> np.ndarray:
        out = np.empty((segs.size, T, J, 3), np.float32)
        for i, a in enumerate(segs.tolist()):
            rows = rows_of(a)[np.minimum(np.arange(T), lens[i] - 1)]
            out[i] = rows
        return out

    def recorded(a):
        c, cut = int(seqs.seg_clip[a]), int(seqs.seg_clip_start[a])
        return sc.clip_joints(c)[cut:cut + int(seqs.seg_length[a])]

    def composed(a):
        return seqs.joints[seqs.segment_rows(a)]

    sets = {"recorded": windows(recorded), "in sequences": windows(composed)}
    result = {"scale": args.scale, "dataset": dataset, "test_actions": int(segs.size), "modes": {}}
    for mode in ("raw", "remove", "yaw_augment"):
        ev = get_evaluator(dataset, "transformer", args.scale, 0, heading=mode, clipset=sc)
        row = {}
        for name, j in sets.items():
            x, ln = evaluation_clips(j, lens, ev.settings.window, "centre")
            logits = ev.logits(x, ln, seed=0)
            row[name] = round(float((np.asarray(logits).argmax(1) == labels).mean()), 4)
        row["drop"] = round(row["recorded"] - row["in sequences"], 4)
        result["modes"][mode] = row
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(f"{args.scale}: {result['test_actions']} real test actions of {dataset}")
        for mode, row in result["modes"].items():
            print(f"  heading={mode:12s} recorded {row['recorded']:.3f}   in sequences "
                  f"{row['in sequences']:.3f}   drop {row['drop']:+.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
