"""MultiAct timings (issue 13): MACVAE's quick training and Fig. 6's recurrence.

Measured in this one process, on one torch thread (the profiles' ``threads``), on the bundled
``bandai2-mini`` stand-in (or ``--dataset``):

1. ``train``: MACVAE at the scale's settings (``tables/scales.toml``, default quick: d 64,
   2 + 2 layers, ff 256, batch 16, 20 epochs) on the MultiAct training pairs (20 per label),
   and ACTOR at the same scale on the same pairs' actions, for the ratio;
2. ``recurrence``: Fig. 6's long-term generation (``long_term`` protocol, the paper's 20 steps,
   ``--sequences`` label sequences, step 1 by ACTOR) with the trained models, one replicate;
   printed as seconds per recurrent step and as a ratio to one single-step pass of MACVAE over
   the same number of conditions (what each step adds on top of sampling).

Usage: .venv/bin/python benchmarks/bench_multiact.py [--scale quick] [--epochs N]
       [--sequences 100] [--steps 20] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scale", default="quick")
    ap.add_argument("--dataset", default="bandai2-mini")
    ap.add_argument("--epochs", type=int, default=None, help="override the scale's epochs")
    ap.add_argument("--sequences", type=int, default=100)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    sys.path.insert(0, str(ROOT))
    import torch

    from repro.data.registry import load_clipset
    from repro.eval.protocols import get_protocol
    from repro.models.base import generator_class
    from repro.specs.scales import resolve_scale

    torch.set_num_threads(1)
    scale = resolve_scale(a.scale)
    clips = load_clipset(a.dataset)
    proto = get_protocol("long_term", {"steps": a.steps, "sequences": a.sequences})
    pairs = proto.item_source().train_items(clips)

    def config(method):
        cfg = dict(scale.method_config(method))
        if a.epochs is not None:
            cfg["epochs"] = a.epochs
        return cfg

    out = {"scale": a.scale, "dataset": a.dataset, "n_pairs": len(pairs)}
    t0 = time.perf_counter()
    macvae = generator_class("macvae")(config("macvae"), clips.skeleton, clips.n_classes, pairs.fps)
    macvae.fit(pairs, seed=0)
    t1 = time.perf_counter()
    actor = generator_class("actor")(config("actor"), clips.skeleton, clips.n_classes, pairs.fps)
    actor.fit(pairs.as_action_items(), seed=0)
    t2 = time.perf_counter()
    epochs = macvae.config.epochs
    out.update(macvae_epochs=epochs, macvae_train_s=round(t1 - t0, 2),
               macvae_s_per_epoch=round((t1 - t0) / epochs, 3),
               actor_train_s=round(t2 - t1, 2),
               macvae_over_actor=round((t1 - t0) / max(t2 - t1, 1e-9), 2))

    items = proto.test_items(clips)
    t3 = time.perf_counter()
    proto.generate(macvae, items, seed=0, replicate=0, models={"actor": actor},
                   row_config=macvae.config.model_dump(mode="json"))
    t4 = time.perf_counter()
    n = min(a.sequences, len(pairs))
    cond = pairs.subset(list(range(n)))
    t5 = time.perf_counter()
    macvae.sample(cond, seed=0)
    t6 = time.perf_counter()
    step_s = (t4 - t3) / a.steps
    out.update(sequences=a.sequences, steps=a.steps, recurrence_s=round(t4 - t3, 2),
               recurrence_s_per_step=round(step_s, 3), single_step_sample_s=round(t6 - t5, 3),
               step_over_single_sample=round(step_s / max(t6 - t5, 1e-9), 2))
    if a.json:
        print(json.dumps(out, indent=1))
        return 0
    print(f"MultiAct at {a.scale} on {a.dataset} ({len(pairs)} training pairs, 1 thread)")
    print(f"  MACVAE training   {out['macvae_train_s']:.1f} s ({epochs} epochs, "
          f"{out['macvae_s_per_epoch']:.2f} s/epoch) = {out['macvae_over_actor']:.2f} × ACTOR's "
          f"{out['actor_train_s']:.1f} s on the same pairs")
    print(f"  Fig. 6 recurrence {out['recurrence_s']:.1f} s for {a.steps} steps × {a.sequences} "
          f"sequences ({out['recurrence_s_per_step']:.3f} s/step) = "
          f"{out['step_over_single_sample']:.2f} × one single-step MACVAE pass over {n} pairs "
          f"({out['single_step_sample_s']:.3f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
