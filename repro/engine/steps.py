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
    ``evaluator`` {dataset, kind, scale, seed[, heading]}.  Trained once, then loaded from the
    store."""
    from repro.eval.provider import get_evaluator

    ev = cfg["evaluator"]
    clips = evaluator_clipset(_protocol(cfg), clipset(cfg["dataset"]))
    return get_evaluator(ev["dataset"], ev["kind"], ev["scale"], ev["seed"], clipset=clips,
                         heading=ev.get("heading"))


def training_items(cfg: dict, clips):
    """The items a method trains on: described by ``cfg["items"]`` (a
    :class:`repro.data.contexts.ItemSource`), so every protocol that makes items the same way
    shares the trained model."""
    from repro.data.contexts import ItemSource

    return ItemSource.from_description(cfg["items"]).train_items(clips)


def _write_values(ctx, values: dict) -> None:
    clean = {k: (None if v is None else float(v)) for k, v in values.items()}
    (ctx.out / VALUES).write_text(json.dumps({"schema": 1, "values": clean}, sort_keys=True))


def train_method(ctx) -> None:
    from repro.models.base import generator_class

    cfg = ctx.config
    ctx.seed_globals()
    clips = clipset(cfg["dataset"])
    items = training_items(cfg, clips)
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


def load_generator(cfg: dict, path):
    """The trained generator of a row: as saved, or, for a method that trains as another
    (``trains_as``: NEURAL MARIONETTE runs MarioNet's weights with inference-time schemes), the
    saved model wrapped with the row's inference options."""
    from repro.models.base import Generator, generator_class

    gen = Generator.load(path)
    method = cfg.get("method")
    if method is not None and method != gen.method_id:
        cls = generator_class(method)
        if getattr(cls, "trains_as", None) != gen.method_id:
            from repro.errors import DataError

            raise DataError(f"stored model is {gen.method_id!r}, the row's method {method!r}")
        opts = {k: v for k, v in cfg["method_config"].items() if k in cls.inference_fields}
        gen = cls.from_marionet(gen, opts)
    return gen


def _protocol_extras(cfg, proto, clips) -> dict:
    """What protocols that generate or measure with the evaluator and the data set get."""
    if not getattr(proto, "generation_uses_evaluator", False):
        return {}

    def factory(kind: str, seed: int):  # another classifier on the same split and heading
        return evaluator_for({**cfg, "evaluator": {**cfg["evaluator"], "kind": kind,
                                                   "seed": int(seed)}})

    return {"evaluator": evaluator_for(cfg), "clipset": clips, "evaluator_factory": factory}


def generate(ctx) -> None:
    cfg, proto, clips, items = _replicate_inputs(ctx)
    gen = load_generator(cfg, ctx.inputs[0].path)
    out = proto.generate(gen, items, seed=ctx.seed, replicate=cfg["replicate"], need=cfg["need"],
                         **_protocol_extras(cfg, proto, clips))
    proto.save_generated(out, ctx.out / GENERATED)


def measure(ctx) -> None:
    cfg, proto, clips, items = _replicate_inputs(ctx)
    generated = proto.load_generated(ctx.inputs[0].path / GENERATED)
    extra = {"clipset": clips} if getattr(proto, "generation_uses_evaluator", False) else {}
    values = proto.measure(generated, items, evaluator_for(cfg), seed=ctx.seed, **extra)
    _write_values(ctx, values)


def measure_real(ctx) -> None:
    cfg, proto, clips, items = _replicate_inputs(ctx)
    values = proto.real_replicate(clips, items, evaluator_for(cfg), seed=ctx.seed,
                                  replicate=cfg["replicate"])
    _write_values(ctx, values)


def read_values(obj) -> dict[str, float | None]:
    """The metric values a measure/measure_real object holds."""
    return json.loads(obj.read_text(VALUES))["values"]
