"""Job implementations of a table's graph (called by the executor as ``fn(ctx)``).

Each step reads only its job's config, seed and input objects, and writes its payload into
``ctx.out``; everything it depends on is in its key (see :mod:`repro.engine.tables`):

- ``train_method``: train one row's method on the protocol's training items (checkpoints in the
  key's scratch folder, so a killed training resumes) and save it (config beside weights);
- ``generate``: one replicate's samples for the protocol's test items (kept, so a rescore
  re-measures without regenerating);
- ``measure``: one replicate's metric values for a generated set (evaluator features kept);
- ``measure_real``: one replicate of the "Real" row.
"""

from __future__ import annotations

import json
from functools import lru_cache

GENERATED = "generated.npz"
VALUES = "values.json"


@lru_cache(maxsize=4)
def clipset(dataset: str):
    """The data set's ClipSet, loaded once per process (memory-mapped where it can be)."""
    from repro.data.registry import load_clipset

    return load_clipset(dataset)


def _protocol(cfg):
    from repro.eval.protocols import get_protocol

    return get_protocol(cfg["protocol"], cfg["protocol_params"])


def evaluator_clipset(protocol, clipset):
    """The clips an evaluator for ``protocol`` trains on: the protocol's own split when it has
    one (so no scored test clip was seen by the recogniser), else the data set's."""
    split = getattr(protocol, "split_clipset", None)
    return clipset if split is None else split(clipset)


def evaluator_for(cfg: dict):
    """The evaluator of a band: ``cfg`` holds ``dataset``, ``protocol``, ``protocol_params`` and
    ``evaluator`` {dataset, kind, scale, seed}.  Trained once, then loaded from the store."""
    from repro.eval.provider import get_evaluator

    ev = cfg["evaluator"]
    clips = evaluator_clipset(_protocol(cfg), clipset(cfg["dataset"]))
    return get_evaluator(ev["dataset"], ev["kind"], ev["scale"], ev["seed"], clipset=clips)


def _write_values(ctx, values: dict) -> None:
    clean = {k: (None if v is None else float(v)) for k, v in values.items()}
    (ctx.out / VALUES).write_text(json.dumps({"schema": 1, "values": clean}, sort_keys=True))


def train_method(ctx) -> None:
    from repro.models.base import generator_class

    cfg = ctx.config
    ctx.seed_globals()
    clips = clipset(cfg["dataset"])
    items = _protocol(cfg).train_items(clips)
    cls = generator_class(cfg["method"])
    gen = cls(cfg["method_config"], clips.skeleton, clips.n_classes, clips.fps)
    epochs = cfg["method_config"].get("epochs")

    def on_epoch(epoch, rec):
        loss = rec.get("loss")
        ctx.progress(epoch + 1, epochs, None if loss is None else f"loss {loss:.4g}")

    result = gen.fit(items, seed=ctx.seed, ckpt_dir=ctx.scratch, on_epoch=on_epoch)
    gen.save(ctx.out)
    history = getattr(result, "history", None) or []
    (ctx.out / "training.json").write_text(json.dumps(
        {"schema": 1, "history": history, "resumed_from": getattr(result, "resumed_from", None),
         "seconds": getattr(result, "seconds", None)}, sort_keys=True))


def _replicate_inputs(ctx):
    """What every per-replicate step starts from: the job's config, the global generators
    seeded from the job's seed, the protocol, the data set's clips and the protocol's test
    items."""
    cfg = ctx.config
    ctx.seed_globals()
    proto = _protocol(cfg)
    clips = clipset(cfg["dataset"])
    return cfg, proto, clips, proto.test_items(clips)


def generate(ctx) -> None:
    from repro.models.base import Generator

    cfg, proto, _, items = _replicate_inputs(ctx)
    gen = Generator.load(ctx.inputs[0].path)
    out = proto.generate(gen, items, seed=ctx.seed, replicate=cfg["replicate"], need=cfg["need"])
    proto.save_generated(out, ctx.out / GENERATED)


def measure(ctx) -> None:
    cfg, proto, _, items = _replicate_inputs(ctx)
    generated = proto.load_generated(ctx.inputs[0].path / GENERATED)
    values = proto.measure(generated, items, evaluator_for(cfg), seed=ctx.seed)
    _write_values(ctx, values)


def measure_real(ctx) -> None:
    cfg, proto, clips, items = _replicate_inputs(ctx)
    values = proto.real_replicate(clips, items, evaluator_for(cfg), seed=ctx.seed,
                                  replicate=cfg["replicate"])
    _write_values(ctx, values)


def read_values(obj) -> dict[str, float | None]:
    """The metric values a measure/measure_real object holds."""
    return json.loads(obj.read_text(VALUES))["values"]
