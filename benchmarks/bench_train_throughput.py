"""Training-throughput benchmark of every trained method at the ``medium`` scale (issues 17
and 31): samples per CPU-second before and after the throughput work, in one run.

For each method (``--methods``, default all nine trained ones) the benchmark takes the
``medium`` profile's ``train`` job for it from the planner (the method's resolved config and
its training-item description, as ``repro run`` would train it), builds those items as the job
does (``repro.engine.steps.training_items``, then the validation hold-out) and calls the
method's own ``fit`` with the one training loop capped at ``--steps`` optimiser steps of epoch 0
(validation and checkpoints off: they are per epoch, not per step).  Two code paths train from
the same seed, alternately (the order swapped at every repeat, so warm-up costs fall on both
alike), ``--repeats`` times each:

- ``before``: the training paths of commit :data:`BEFORE` (main before issue 31), swapped in
  by :func:`before_paths`: torch's own matrix-product kernels (MKL's COMPATIBLE branch) instead
  of :mod:`repro.gemm`'s, ``nn.Dropout``'s ``bernoulli_`` masks instead of
  :func:`repro.models.layers.dropout`'s, ``nn.Conv1d``'s own kernel (im2col on MKL) instead of
  :class:`repro.models.layers.Conv1d`'s unfolded product, the attention of that commit
  (SDPA with its own weight dropout; ``MultiHeadAttention.attend`` imported from git history
  by ``benchmarks/_before.py``), Action2Motion's frame-by-frame step (``A2M.training_step``,
  from git history) and MarioNet's padded frames (``packed_frames = False``,
  :data:`BEFORE_CONFIG`).  Everything else is today's code in both paths: forward kinematics' and
  ODMO's decoder's per-joint / per-step views (bitwise the same numbers as at that commit, a
  little faster, so the ratios slightly understate the change) and one setting of the
  process: numpy's OpenBLAS runs one thread under pin v2 in both paths (at a681c37 it ran as
  many as the machine has; no method's step called numpy's BLAS then);
- ``after``: the library as it is.

Printed per method: the batch unit (items; MANN: frame pairs; ODMO: window pairs; DLow-Gen:
both stages' steps), samples per CPU-second of the training steps (the process's CPU time,
robust to other work on a shared machine; the best of the repeats) and per wall-second, the
after/before ratio, the issue's goal (MarioNet and MACVAE 2x, the others 1.5x) and whether the
two paths computed equal per-step losses (issue 31's changes change numbers: "no" is expected;
their equivalence is shown by learning curves, docs/training-profile.md).  ``--json FILE``
writes the same per method (``samples_per_cpu_s_before``, ``samples_per_cpu_s_after``,
``ratio``, ...) with the commit, host and settings.

Usage: ``.venv/bin/python benchmarks/bench_train_throughput.py [--steps 6] [--repeats 2]
[--methods marionet,a2m] [--scale medium] [--dataset bandai2] [--json out.json]``.  The data
set is the profile's (``bandai2`` at medium: ``repro data prepare bandai2 --source ...``); a
data set that is not prepared ends with the command that prepares it (exit 2), and so does a
checkout without the git history holding :data:`BEFORE` (a source tarball, a shallow clone).
Building the training items is the slow part of a first run (MultiAct's pairs, Neural
Marionette's composed contexts: about a minute each on a 2-core machine); items shared by
several methods are built once.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import itertools
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import repro  # noqa: F401,E402  (pins the kernel paths before torch / numpy load: repro/kernels.py)
import torch
from _before import BeforeUnavailable, import_before, swapped  # after the path entry

#: main before issue 31's training work (the training paths of :func:`before_paths`)
BEFORE = "a681c37"
#: the code before issue 17's bitwise throughput work (:func:`issue17_paths`; its tests)
ISSUE17 = "4b3830acd23621ac745fb0b587599a3a5f9acb15"

#: the trained methods and one spec whose ``medium`` plan trains each (the first found is used)
METHOD_SPECS = {
    "marionet": "marionette/table1", "mann": "marionette/fig8", "a2m": "marionette/table1",
    "actor": "marionette/table1", "macvae": "multiact/fig6", "ssmct": "multiact/fig6",
    "odmo": "odmo/table1", "dlow_gen": "odmo/table1", "act_mocogan": "odmo/table1",
}
#: the issue's goals: after / before samples per second
GOALS = {"marionet": 2.0, "macvae": 2.0}
DEFAULT_GOAL = 1.5
#: config switches that turn a method's issue-31 path off in the "before" path (its config
#: field; the library's default is the new path)
BEFORE_CONFIG = {"marionet": {"packed_frames": False}}
#: what one batch row is, where it is not a training item
UNITS = {"mann": "frame pairs", "odmo": "window pairs", "dlow_gen": "windows",
         "act_mocogan": "windows"}


def train_job_configs(methods, scale, dataset):
    """method -> the resolved config of the first ``train`` job of it in its spec's plan."""
    from repro.engine.table_plan import build_plan
    from repro.specs.load import find_spec

    out, plans = {}, {}
    for m in methods:
        sid = METHOD_SPECS[m]
        if sid not in plans:
            plans[sid] = build_plan(find_spec(sid), scale, dataset)
        for row in plans[sid].rows:
            for jobs in row.train.values():
                for job in (jobs if isinstance(jobs, (list, tuple)) else [jobs]):
                    if job.kind == "train" and job.config.get("method") == m and m not in out:
                        out[m] = job.config
        if m not in out:
            raise SystemExit(f"bench: no {m} training in {sid}'s plan")
    return out


def leading_rows(batch) -> int:
    """The leading dimension of the first tensor in a batch (dicts, tuples, nested)."""
    if isinstance(batch, torch.Tensor):
        return int(batch.shape[0]) if batch.dim() else 0
    values = batch.values() if isinstance(batch, dict) else (
        batch if isinstance(batch, (list, tuple)) else ())
    for v in values:
        n = leading_rows(v)
        if n:
            return n
    return 0


class Capped:
    """A stand-in for ``repro.train.loop.train`` that runs the given loop (``inner``) on the
    first ``steps`` batches of epoch 0 only, without validation or checkpoints, and records the
    steps' losses, the samples seen and the time spent inside the loop."""

    def __init__(self, inner, steps: int):
        self.inner, self.steps = inner, steps
        self.losses, self.samples, self.cpu, self.wall = [], 0, 0.0, 0.0

    def __call__(self, model, optimizer, *, batches, step, epochs, **kw):
        kw.pop("validate", None)
        kw["ckpt_dir"] = None

        def capped(epoch, gen):
            for b in itertools.islice(batches(epoch, gen), self.steps):
                self.samples += leading_rows(b)
                yield b

        def recorded(m, b, e):
            out = step(m, b, e)
            self.losses.append(out["loss"].detach().clone())
            return out

        c0, w0 = time.process_time(), time.perf_counter()
        try:
            return self.inner(model, optimizer, batches=capped, step=recorded, epochs=1, **kw)
        finally:
            self.cpu += time.process_time() - c0
            self.wall += time.perf_counter() - w0


def issue17_paths(commit: str = ISSUE17):
    """A context manager within which every training runs the paths that issue 17 changed, as
    they were at ``commit`` (imported from git history, ``benchmarks/_before.py``): the loop
    (``repro.train.loop.train``, which every ``fit`` looks up when it runs) and Action2Motion's
    step (``A2M.training_step``).  Everything else is today's library (its bitwise tests:
    ``tests/test_train_throughput.py``).  BeforeUnavailable without that history."""
    from repro.models.a2m import A2M
    from repro.train import loop

    old_loop = import_before(commit, "repro/train/loop.py")
    old_a2m = import_before(commit, "repro/models/a2m.py")
    return swapped((loop, "train", old_loop.train),
                   (A2M, "training_step", vars(old_a2m.A2M)["training_step"]))


def _check_as_before():
    """``repro.kernels.check`` as at :data:`BEFORE`: the pin's torch settings without
    :mod:`repro.gemm` (torch's own matrix products); the state it returns is not checked."""
    from repro import gemm, kernels

    gemm.uninstall()
    import torch

    torch.backends.mkldnn.enabled = False
    torch.backends.nnpack.set_flags(False)
    torch.use_deterministic_algorithms(True)
    return kernels.state()


def _torch_dropout(self, x):
    """``nn.Dropout.forward`` (``bernoulli_`` masks), as every method's dropout was before."""
    return torch.nn.functional.dropout(x, self.p, self.training)


def _unpacked(attend):
    """An ``attend`` of before issue 31 as today's layers call it (``packing=None``: the before
    path never packs, :data:`BEFORE_CONFIG`)."""
    @functools.wraps(attend)
    def call(self, q_in, k, v, *, packing=None, **kw):
        if packing is not None:
            raise RuntimeError("the before path's attention takes no packed tokens")
        return attend(self, q_in, k, v, **kw)
    return call


@contextlib.contextmanager
def before_paths(commit: str = BEFORE):
    """Within the block every training runs the paths issue 31 changed as they were at
    ``commit`` (module docstring): torch's matrix products, ``nn.Dropout``'s masks,
    ``nn.Conv1d``'s kernel, the old attention (``MultiHeadAttention.attend`` from git
    history) and Action2Motion's frame-by-frame step (``A2M.training_step``, from git history);
    on exit the library's are back (``repro.gemm`` installed again).  BeforeUnavailable
    without that history."""
    from repro import gemm, kernels
    from repro.models import layers
    from repro.models.a2m import A2M

    old_layers = import_before(commit, "repro/models/layers.py")
    old_a2m = import_before(commit, "repro/models/a2m.py")
    try:
        with swapped((kernels, "check", _check_as_before),
                     (A2M, "training_step", vars(old_a2m.A2M)["training_step"]),
                     (layers.Dropout, "forward", _torch_dropout),
                     (layers.Conv1d, "forward", torch.nn.Conv1d.forward),
                     (layers.MultiHeadAttention, "attend",
                      _unpacked(vars(old_layers.MultiHeadAttention)["attend"]))):
            gemm.uninstall()
            yield
    finally:
        gemm.install()


def before_available(who: str) -> bool:
    """Whether ``BEFORE``'s code can be read from the git history (imported up front, so that a
    missing history ends before any training); says why not on stderr as ``who``."""
    try:
        import_before(BEFORE, "repro/models/layers.py")
    except BeforeUnavailable as e:
        print(f"{who}: no 'before' code: {e}", file=sys.stderr)
        return False
    return True


def path_generator(path: str, method: str, cfg: dict, clips, fps: float):
    """A fresh generator of ``method`` from a train job's ``cfg``, with the ``before`` path's
    config switches (:data:`BEFORE_CONFIG`) when ``path`` is "before"."""
    from repro.models.base import generator_class

    config = dict(cfg["method_config"])
    if path == "before":
        config.update(BEFORE_CONFIG.get(method, {}))
    return generator_class(method)(config, clips.skeleton, clips.n_classes, fps)


def run_path(path: str, method: str, cfg: dict, clips, train_items, steps: int):
    """One capped ``fit`` of ``method`` on ``path`` ("before" / "after"): (Capped, weights)."""
    from repro.train import loop

    gen = path_generator(path, method, cfg, clips, train_items.fps)
    ctx = before_paths() if path == "before" else contextlib.nullcontext()
    with ctx:
        cap = Capped(loop.train, steps)
        saved, loop.train = loop.train, cap
        try:
            gen.fit(train_items, seed=0)
        finally:
            loop.train = saved
    weights = [t.detach().clone() for t in gen.network.state_dict().values()]
    return cap, weights


def head_commit() -> str:
    """The checked-out commit (``+dirty`` when the working tree differs), or "unknown"."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    try:
        sha = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], check=True,
                             capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--", "repro"],
                               check=True, capture_output=True, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return sha + ("+dirty" if dirty else "")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", default=",".join(METHOD_SPECS),
                    help="comma-separated (default: all nine trained methods)")
    ap.add_argument("--steps", type=int, default=6, help="optimiser steps per timed fit")
    ap.add_argument("--repeats", type=int, default=2, help="timed fits per path (alternating)")
    ap.add_argument("--scale", default="medium")
    ap.add_argument("--dataset", default=None, help="default: the profile's")
    ap.add_argument("--json", default=None, metavar="FILE",
                    help="also write the results, per method, to FILE")
    a = ap.parse_args(argv)
    methods = [m.strip() for m in a.methods.split(",") if m.strip()]
    unknown = [m for m in methods if m not in METHOD_SPECS]
    if unknown or a.steps < 1 or a.repeats < 1:
        print(f"bench: --methods: unknown {unknown} (known: {', '.join(METHOD_SPECS)}); "
              "--steps and --repeats must be >= 1", file=sys.stderr)
        return 2

    from repro import kernels
    from repro.engine import steps as job_steps
    from repro.errors import ReproError
    from repro.keys import content_key
    from repro.models.base import generator_class
    from repro.specs.scales import resolve_scale
    from repro.train.validation import holdout

    if not before_available("bench"):  # no history, no "before" (exit 2)
        return 2
    try:
        scale = resolve_scale(a.scale)
        configs = train_job_configs(methods, scale, a.dataset)
        dataset = next(iter(configs.values()))["dataset"]
        clips = job_steps.clipset(dataset)
    except ReproError as e:
        print(f"bench: {e}", file=sys.stderr)
        return 2
    torch.set_num_threads(int(getattr(scale, "threads", 1) or 1))
    print(f"scale {a.scale}, data set {dataset}; {a.steps} steps of epoch 0 per fit, best of "
          f"{a.repeats} alternating fits per path; torch {torch.__version__}, "
          f"{torch.get_num_threads()} thread(s); before = {BEFORE}")
    print("| method | unit | batch | before /cpu-s | after /cpu-s | after/before | goal | "
          "before /wall-s | after /wall-s | same numbers |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |")
    item_cache, results = {}, {}
    for m in methods:
        cfg = configs[m]
        key = content_key({"items": cfg["items"], "kind": getattr(
            generator_class(m), "item_kind", "actions"), "validation": cfg.get("validation")})
        if key not in item_cache:
            items = job_steps.training_items(cfg, clips, getattr(generator_class(m), "item_kind",
                                                                 "actions"))
            fraction, val_seed = job_steps.validation_settings(cfg, 0)
            item_cache[key] = holdout(items, fraction, val_seed)[0]
        train_items = item_cache[key]
        best = {"before": None, "after": None}
        ref = {}
        for r in range(a.repeats):  # alternating, the order swapped every repeat
            for path in (("before", "after") if r % 2 == 0 else ("after", "before")):
                cap, weights = run_path(path, m, cfg, clips, train_items, a.steps)
                if path not in ref:
                    ref[path] = (cap.losses, weights)
                if best[path] is None or cap.cpu < best[path].cpu:
                    best[path] = cap
        same = (len(ref["before"][0]) == len(ref["after"][0])
                and all(torch.equal(x, y) for x, y in zip(ref["before"][0], ref["after"][0]))
                and all(torch.equal(x, y) for x, y in zip(ref["before"][1], ref["after"][1])))
        b, f = best["before"], best["after"]
        rate = lambda cap, t: cap.samples / t if t > 0 else float("nan")  # noqa: E731
        ratio = rate(f, f.cpu) / rate(b, b.cpu)
        goal = GOALS.get(m, DEFAULT_GOAL)
        per_step = b.samples / max(len(b.losses), 1)
        results[m] = {
            "unit": UNITS.get(m, "items"), "batch": round(per_step),
            "samples_per_cpu_s_before": rate(b, b.cpu), "samples_per_cpu_s_after": rate(f, f.cpu),
            "ratio": ratio, "goal": goal, "met": bool(ratio >= goal),
            "samples_per_wall_s_before": rate(b, b.wall),
            "samples_per_wall_s_after": rate(f, f.wall), "same_numbers": bool(same)}
        print(f"| {m} | {UNITS.get(m, 'items')} | {per_step:.0f} | {rate(b, b.cpu):.1f} | "
              f"{rate(f, f.cpu):.1f} | {ratio:.2f}x | {goal:.1f}x "
              f"({'met' if ratio >= goal else 'missed'}) | {rate(b, b.wall):.1f} | "
              f"{rate(f, f.wall):.1f} | {'yes' if same else 'no'} |", flush=True)
    if a.json:
        import json

        out = {"schema": 1, "benchmark": "bench_train_throughput", "before": BEFORE,
               "after": head_commit(), "scale": a.scale, "dataset": dataset, "steps": a.steps,
               "repeats": a.repeats, "threads": torch.get_num_threads(),
               "torch": torch.__version__, "host": kernels.host_paths(), "methods": results}
        Path(a.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
