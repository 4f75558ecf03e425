"""Hashes of every array of every item set the table protocols build (issue 30's proof).

For each spec of ``tables/`` at scale ``quick`` on the bundled ``bandai2-mini``, every
implemented band's protocol builds its training items (every item kind the engine's training
step can ask for: actions, pairs, windows), its test items, its evaluator's clip set and the
derived sets the protocols draw (MultiAct's reference draws, ODMO's fixed windows, epoch draws,
pair draws and label-only conditions, Neural Marionette's chained condition items); also the
``same_clip`` items of ``single_action`` (in no table) and the evaluators' training windows.  Every
tensor / array reached from them is hashed (sha256 of bytes, dtype and shape); strings, numbers
and pydantic configs are recorded as they are; the item sources' ``describe()`` and the
protocols' ``describe()`` are recorded too.

Run it once with one tree on ``PYTHONPATH`` and once with another, then compare::

    PYTHONPATH=/work/main python benchmarks/items_equality.py dump /tmp/main.json
    PYTHONPATH=. python benchmarks/items_equality.py dump /tmp/mine.json
    python benchmarks/items_equality.py compare /tmp/main.json /tmp/mine.json

It uses only interfaces both trees have (the protocols, ``repro.engine.steps.training_items``)
and looks the moved item functions up under either module.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import json
import sys

import numpy as np


def _sha(a: np.ndarray) -> str:
    a = np.ascontiguousarray(a)
    return hashlib.sha256(a.tobytes() + str(a.dtype).encode() + str(a.shape).encode()).hexdigest()


def flatten(obj, path: str, out: dict, seen: set) -> None:
    """``out[path] = ("array", sha)`` for arrays, ``("value", json)`` for the rest."""
    import torch
    from pydantic import BaseModel

    if isinstance(obj, torch.Tensor):
        out[path] = ["array", _sha(obj.detach().cpu().numpy())]
    elif isinstance(obj, np.ndarray):
        out[path] = ["array", _sha(obj)]
    elif isinstance(obj, BaseModel):
        out[path] = ["value", json.dumps(obj.model_dump(mode="json"), sort_keys=True)]
    elif type(obj).__name__ == "ClipSet":
        out[path] = ["value", str(obj.fingerprint)]
        for f in ("split", "labels", "styles", "starts", "lengths", "rotations", "root",
                  "joints"):
            flatten(getattr(obj, f), f"{path}.{f}", out, seen)
    elif type(obj).__name__ == "Skeleton":
        out[path] = ["value", obj.fingerprint()]
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        if id(obj) in seen:
            return
        seen.add(id(obj))
        for f in dataclasses.fields(obj):
            if f.name.startswith("_"):
                continue
            flatten(getattr(obj, f.name), f"{path}.{f.name}", out, seen)
    elif isinstance(obj, dict):
        for k in sorted(obj, key=str):
            flatten(obj[k], f"{path}[{k}]", out, seen)
    elif isinstance(obj, (list, tuple)) and obj and any(
            hasattr(x, "shape") or dataclasses.is_dataclass(x) for x in obj):
        for i, x in enumerate(obj):
            flatten(x, f"{path}[{i}]", out, seen)
    else:
        try:
            out[path] = ["value", json.dumps(obj, sort_keys=True, default=str)]
        except TypeError:
            out[path] = ["value", repr(obj)]


def _first(names: list[tuple[str, str]]):
    for mod, name in names:
        try:
            return getattr(importlib.import_module(mod), name)
        except (ImportError, AttributeError):
            continue
    raise ImportError(f"none of {names}")


def band_sets(proto, clips) -> dict:
    """Every item set of one protocol (module docstring)."""
    import torch

    from repro.data.clipset import TEST, TRAIN
    from repro.engine.steps import evaluator_clipset, training_items

    src = proto.item_source()
    desc = src.describe()
    sets: dict = {"describe.protocol": proto.describe(), "describe.items": desc,
                  "evaluator_clipset": evaluator_clipset(proto, clips)}
    builder = desc.get("builder")
    kinds = {"multiact_pairs": ("pairs", "actions"), "odmo_windows": ("windows", "actions")}.get(
        builder, ("actions",))
    for kind in kinds:
        sets[f"train.{kind}"] = training_items({"items": desc}, clips, kind)
    test = proto.test_items(clips)
    sets["test"] = test
    if builder == "multiact_pairs":
        per = proto.params.per_label
        sets["pairs.all.train"] = src.pairs(clips, TRAIN)
        sets["pairs.all.test"] = src.pairs(clips, TEST)
        sets["reference.train"] = src.reference(clips, TRAIN, per, 7)
        sets["reference.test"] = src.reference(clips, TEST, per, 7)
        sets["label_pairs.test"] = np.asarray(src.label_pairs(clips, TEST), np.int64)
        sets["length_stats"] = src.length_stats(clips)
        tab = src.pair_table(clips, TRAIN)
        sets["pair_table.train"] = tab
        sets["test.as_action_items"] = (test.pairs if hasattr(test, "pairs") else test
                                        ).as_action_items(proto.params.actor_initial_frames)
    elif builder == "odmo_windows":
        pool = sets["train.windows"]
        rng = np.random.default_rng(11)
        sets["fixed_windows"] = pool.fixed_windows()
        sets["draw"] = pool.draw(64, rng)
        sets["draw_pairs"] = pool.draw_pairs(64, rng)
        sets["balanced_clips"] = pool.balanced_clips(500, np.random.default_rng(3))
        from repro.eval.protocols.odmo_common import real_batch

        sets["real_batch.train"] = real_batch(test.train, 5, 1, "train", 0)
        if test.test is not None:
            sets["real_batch.test"] = real_batch(test.test, 5, 1, "test", 0)
        label_condition_items = _first([("repro.data.odmo_items", "label_condition_items")])
        from repro.motion.motion import Motion

        place = Motion.from_clipset(pool.clipset, pool.indices[:1], 0, 1)
        sets["label_conditions"] = label_condition_items(
            pool.label_names, test.labels[:50], pool.window, pool.skeleton, pool.fps, place)
    else:
        sets["items.test"] = src.items(clips, TEST)
        sets["items.train"] = src.items(clips, TRAIN)
        condition_items = _first([("repro.data.action_items", "condition_items"),
                                  ("repro.models.items", "condition_items")])
        it = sets["items.test"]
        n = min(len(it), 40)
        sets["condition_items"] = condition_items(
            it.initial_world().select(torch.arange(n)), it.labels[:n], it.next_labels[:n],
            it.lengths[:n], it.label_names, trajectory=it.trajectory[:n, :int(it.lengths[:n].max())],
            in_place=it.in_place[:n], config=it.config)
        sets["real"] = it.real()
        sets["subset"] = it.subset(np.arange(0, len(it), 3))
        sets["key.test"] = it.key()
    return sets


def dump(path: str) -> None:
    import torch

    try:  # the names since issue 30's cycle clean-up; a tree before it has the private ones
        from repro.engine.runner import table_scale as _scale, table_spec as _spec
    except ImportError:
        from repro.engine.runner import _scale, _spec
    from repro.engine.steps import clipset
    from repro.engine.table_plan import build_plan
    from repro.eval.protocols import get_protocol
    from repro.paths import tables_root

    torch.set_num_threads(1)
    import repro

    print("repro from", repro.__file__, flush=True)
    specs = sorted(str(p.relative_to(tables_root()).with_suffix(""))
                   for p in tables_root().glob("*/*.toml"))
    out: dict = {}
    clips = clipset("bandai2-mini")
    for name in specs:
        spec = _spec(name)
        scale = _scale("quick", "bandai2-mini")
        plan = build_plan(spec, scale, dataset="bandai2-mini")
        for bi, b in enumerate(plan.bands):
            if not b.implemented:
                continue
            proto = get_protocol(b.protocol, b.params)
            flat: dict = {}
            for what, obj in band_sets(proto, clips).items():
                flatten(obj, what, flat, set())
            out[f"{name}#{bi}:{b.protocol}"] = flat
            n = sum(1 for v in flat.values() if v[0] == "array")
            print(f"{name} band {bi} ({b.protocol}): {n} arrays, {len(flat) - n} values",
                  flush=True)
    # not in a table: the earlier, same-clip context of Neural Marionette's items (a named
    # option; its description gains the context version, the one expected difference)
    proto = get_protocol("single_action", {"context": "same_clip"})
    flat = {}
    for what, obj in band_sets(proto, clips).items():
        flatten(obj, what, flat, set())
    out["extra/same_clip#0:single_action"] = flat
    # the evaluators' training draws (repro.eval.sampling), which share ODMO's clip draws
    from repro.data.clipset import TRAIN
    from repro.eval.sampling import per_class_windows, random_windows

    pool = clips.indices(split=TRAIN)
    flat = {}
    for balanced in (True, False):
        flatten(random_windows(clips, pool, 200, 30, np.random.default_rng(5),
                               class_balanced=balanced), f"random_windows.{balanced}", flat, set())
    flatten(per_class_windows(clips, pool, 6, 30, np.random.default_rng(6)), "per_class_windows",
            flat, set())
    out["evaluator_windows"] = flat
    with open(path, "w") as f:
        json.dump(out, f, sort_keys=True, indent=0)


#: differences explained by a recorded change: (band, entry) -> why
EXPECTED = {
    ("extra/same_clip#0:single_action", "describe.items[context_version]"):
        "issue 30: the one ItemSource.describe() records the version for the same_clip context "
        "too (before: only for sequence items)",
}


def compare(a_path: str, b_path: str) -> int:
    a, b = json.load(open(a_path)), json.load(open(b_path))
    bad = 0
    explained = 0
    n_arrays = n_values = 0
    if set(a) != set(b):
        print("bands differ:", sorted(set(a) ^ set(b)))
        bad += 1
    for band in sorted(set(a) & set(b)):
        fa, fb = a[band], b[band]
        for k in sorted(set(fa) | set(fb)):
            va, vb = fa.get(k), fb.get(k)
            if va is not None and va[0] == "array":
                n_arrays += 1
            else:
                n_values += 1
            if va != vb:
                why = EXPECTED.get((band, k))
                explained += why is not None
                bad += why is None
                print(f"{'expected' if why else 'DIFF'} {band} {k}:\n  a: {str(va)[:300]}\n"
                      f"  b: {str(vb)[:300]}" + (f"\n  ({why})" if why else ""))
    print(f"{len(a)} bands, {n_arrays} arrays and {n_values} other values compared; "
          f"{bad} differences, {explained} expected")
    return 1 if bad else 0


if __name__ == "__main__":
    if sys.argv[1] == "dump":
        dump(sys.argv[2])
    else:
        sys.exit(compare(sys.argv[2], sys.argv[3]))
