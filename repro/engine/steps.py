"""Job implementations of a table's graph (called by the executor as ``fn(ctx)``).

Each step reads only its job's config, seed and input objects, and writes its payload into
``ctx.out``; everything it depends on is in its key (see :mod:`repro.engine.tables`):

- ``train_method``: train one row's method on the protocol's training items (checkpoints in the
  key's scratch folder, so a killed training resumes), minus the clips held out for its
  validation curve (``config["validation"]``), and save it (config beside weights) with its
  learning curve (``training.json``, :data:`TRAINING_SCHEMA`);
- ``generate``: one replicate's samples for the protocol's test items (kept, so a rescore
  re-measures without regenerating);
- ``measure``: one replicate's metric values for a generated set (evaluator features kept);
- ``measure_real``: one replicate of the "Real" row.

Device: ``train_method`` and ``generate`` compute on the job's device (``Job.device``, from the
scale profile or ``--device``; :func:`job_device` applies the CUDA determinism settings first);
saved models and samples are CPU tensors, so every later step reads them anywhere.  ``measure``
jobs score with the evaluator on the CPU.
"""

from __future__ import annotations

import json
import math
from functools import lru_cache

GENERATED = "generated.npz"
VALUES = "values.json"
TRAINING = "training.json"
#: ``training.json`` format: 2 added ``epochs``, ``batch_size``, ``n_train``, ``n_validation``,
#: ``validation_fraction``, ``steps`` and per-epoch ``batches`` / ``val_*`` in ``history``;
#: 3 added ``until`` ("epochs" or "plateau") and ``convergence`` (:func:`convergence_of`)
TRAINING_SCHEMA = 3


@lru_cache(maxsize=4)
def clipset(dataset: str):
    """The data set's ClipSet, loaded once per process (memory-mapped where it can be)."""
    from repro.data.registry import load_clipset

    return load_clipset(dataset)


def protocol_of(cfg):
    """The protocol a step's config names (``protocol`` with its ``protocol_params``)."""
    from repro.eval.protocols import get_protocol

    return get_protocol(cfg["protocol"], cfg["protocol_params"])


def evaluator_clipset(protocol, clipset):
    """The clips an evaluator for ``protocol`` trains on: the protocol's own split when it has
    one (so no scored test clip was seen by the recogniser), else the data set's."""
    split = getattr(protocol, "split_clipset", None)
    return clipset if split is None else split(clipset)


def evaluator_split(protocol, clipset):
    """What a plan reads of :func:`evaluator_clipset` (``fingerprint``, ``labels``, ``split``,
    ``label_names``, ``n_classes``), without building clips where that costs work (MultiAct's
    resampling, which also needs torch): the protocol's ``split_view`` where it has one."""
    view = getattr(protocol, "split_view", None)
    return evaluator_clipset(protocol, clipset) if view is None else view(clipset)


def evaluator_for(cfg: dict, weights: bool = True):
    """The evaluator of a band: ``cfg`` holds ``dataset``, ``protocol``, ``protocol_params`` and
    ``evaluator`` {dataset, kind, scale, seed[, heading][, settings]} (``settings``: the
    protocol's overrides of the scale's evaluator settings, e.g. ODMO's window).  Trained once,
    then loaded from the store (``weights=False``: only its stored record when there is one,
    :func:`repro.eval.provider.get_evaluator`)."""
    from repro.eval.provider import get_evaluator

    ev = cfg["evaluator"]
    clips = evaluator_clipset(protocol_of(cfg), clipset(cfg["dataset"]))
    return get_evaluator(ev["dataset"], ev["kind"], ev["scale"], ev["seed"], clipset=clips,
                         heading=ev.get("heading"), overrides=ev.get("settings"),
                         weights=weights)


def training_items(cfg: dict, clips, item_kind: str = "actions"):
    """The items a method trains on: described by ``cfg["items"]`` (an item source's
    ``describe()``, :mod:`repro.data.item_sources`), so every protocol that makes items the
    same way shares the trained model; a method reads them as its ``item_kind`` asks
    (:meth:`repro.data.item_sources.ItemSource.training_items`: e.g. ACTOR the current actions
    of MultiAct's pairs, Action2Motion the fixed windows of ODMO's pool as actions)."""
    from repro.data.item_families import source_from_description

    return source_from_description(cfg["items"]).training_items(clips, item_kind)


def write_values(ctx, values: dict) -> None:
    # a non-finite value (e.g. multimodality with no within-class pair) is "not measured"
    clean = {k: (None if v is None or not math.isfinite(float(v)) else float(v))
             for k, v in values.items()}
    (ctx.out / VALUES).write_text(json.dumps({"schema": 1, "values": clean}, sort_keys=True))


def validation_settings(cfg: dict, seed: int) -> tuple[float, int]:
    """(fraction, seed) of a train job's validation hold-out: ``cfg["validation"]``
    ``{"fraction": f, "seed": s}`` (absent: no hold-out; no seed: the job's)."""
    v = cfg.get("validation") or {}
    return float(v.get("fraction", 0.0) or 0.0), int(v.get("seed", seed))


def job_device(ctx):
    """The ``torch.device`` the job computes on (its ``device``; the CPU when it names none),
    prepared by :func:`repro.seeding.prepare_device` (CUDA determinism, in one place)."""
    from repro.seeding import prepare_device

    return prepare_device(getattr(getattr(ctx, "job", None), "device", None))


def train_method(ctx) -> None:
    from repro.models.base import generator_class
    from repro.train.loop import use_device, use_stopping
    from repro.train.validation import holdout

    cfg = ctx.config
    ctx.seed_globals()
    clips = clipset(cfg["dataset"])
    cls = generator_class(cfg["method"])
    items = training_items(cfg, clips, getattr(cls, "item_kind", "actions"))
    gen = cls(cfg["method_config"], clips.skeleton, clips.n_classes, items.fps)
    from repro.train.epochs import config_epochs

    epochs = config_epochs(cfg["method_config"])
    fraction, val_seed = validation_settings(cfg, ctx.seed)
    if epochs is None:  # nothing is trained (nearest_clip indexes): no curve, every item
        fraction = 0.0
    train_items, val_items = holdout(items, fraction, val_seed)

    def on_epoch(epoch, rec):
        loss, val = rec.get("loss"), rec.get("val_loss")
        msg = None if loss is None else f"loss {loss:.4g}" + (
            "" if val is None else f", val {val:.4g}")
        ctx.progress(epoch + 1, epochs, msg)

    kw = {} if val_items is None else {"val_items": val_items}
    rule = gen.plateau_rule().with_settings(cfg.get("schedule"))
    with use_device(job_device(ctx)), use_stopping(stopping_of(cfg.get("schedule"), rule)):
        result = gen.fit(train_items, seed=ctx.seed, ckpt_dir=ctx.scratch, on_epoch=on_epoch,
                         **kw)
    gen.save(ctx.out)
    history = getattr(result, "history", None) or []
    (ctx.out / TRAINING).write_text(json.dumps(
        {"schema": TRAINING_SCHEMA, "history": history,
         "resumed_from": getattr(result, "resumed_from", None),
         "seconds": getattr(result, "seconds", None),
         "epochs": None if epochs is None else int(epochs),
         "batch_size": cfg["method_config"].get("batch_size"),
         "n_train": len(train_items), "n_validation": 0 if val_items is None else len(val_items),
         "validation_fraction": fraction,
         "steps": int(sum(int(h.get("batches", 0)) for h in history)),
         "until": (cfg.get("schedule") or {}).get("until", "epochs"),
         "convergence": None if epochs is None else convergence_of(
             history, rule, getattr(result, "stopped_by", None))}, sort_keys=True))


def stopping_of(schedule: dict | None, rule):
    """The loop's :class:`~repro.train.loop.Stopping` for a train job's ``schedule`` (the
    profile's ``until`` and ``plateau`` settings): None for a fixed number of epochs."""
    from repro.train.loop import Stopping

    if not schedule or schedule.get("until", "epochs") != "plateau":
        return None
    minutes = schedule.get("max_minutes")
    return Stopping(rule=rule, max_seconds=None if minutes is None else 60.0 * float(minutes))


def convergence_of(history: list[dict], rule, stopped_by: str | None) -> dict:
    """``training.json``'s ``convergence`` (:func:`repro.train.plateau.convergence_record`);
    a training in stages (DLow-Gen: the VAE, then DLow; records carry ``stage``) converged
    when every stage did, each read on its own epochs (``stage_epoch``)."""
    from repro.train.plateau import convergence_record

    stages = list(dict.fromkeys(h.get("stage") for h in history if isinstance(h, dict)))
    if len(stages) <= 1 or None in stages:
        return convergence_record(history, rule, stopped_by)
    per = {st: convergence_record([h for h in history if h.get("stage") == st], rule)
           for st in stages}
    out = convergence_record([], rule, stopped_by)
    out.update(converged=all(r["converged"] for r in per.values()),
               converged_epoch=None, stages=per)
    return out


def _replicate_inputs(ctx):
    """What every per-replicate step starts from: the job's config, the global generators
    seeded from the job's seed, the protocol, the data set's clips and the protocol's test
    items."""
    cfg = ctx.config
    ctx.seed_globals()
    proto = protocol_of(cfg)
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


def _generators(cfg: dict, inputs) -> tuple:
    """(the row's generator, {name: extra generator}) from a generate job's inputs.

    ``cfg["models"]`` names the inputs after the first: a composite method (``components``:
    ACTOR + SSMCT, ACTOR + interpolation) is built from all of them and has none of its own;
    otherwise the first input is the row's own model and the named ones are the extra models
    its protocol asked for (:meth:`extra_models`, e.g. ACTOR for MultiAct's first step)."""
    from repro.models.base import Generator, generator_class

    names = list(cfg.get("models") or [])
    method = cfg.get("method")
    cls = generator_class(method) if method else None
    if cls is not None and getattr(cls, "components", None):
        parts = {n: Generator.load(i.path) for n, i in zip(names, inputs)}
        return cls.from_components(parts, cfg["method_config"]), {}
    gen = load_generator(cfg, inputs[0].path)
    return gen, {n: Generator.load(i.path) for n, i in zip(names, inputs[1:])}


def generate(ctx) -> None:
    cfg, proto, clips, items = _replicate_inputs(ctx)
    gen, models = _generators(cfg, ctx.inputs)
    dev = job_device(ctx)
    for g in (gen, *models.values()):  # sampling follows the network's device
        g.to(dev)
    extra = _protocol_extras(cfg, proto, clips)
    if getattr(proto, "takes_models", False):  # MultiAct: extra models and the row's options
        extra.update(models=models, row_config=cfg.get("method_config") or {})
    out = proto.generate(gen, items, seed=ctx.seed, replicate=cfg["replicate"], need=cfg["need"],
                         **extra)
    proto.save_generated(out, ctx.out / GENERATED)


def measure(ctx) -> None:
    cfg, proto, clips, items = _replicate_inputs(ctx)
    generated = proto.load_generated(ctx.inputs[0].path / GENERATED)
    uses = getattr(proto, "generation_uses_evaluator", False) or \
        getattr(proto, "measure_uses_clipset", False)  # e.g. the harness columns' training bank
    extra = {"clipset": clips} if uses else {}
    values = proto.measure(generated, items, evaluator_for(cfg), seed=ctx.seed, **extra)
    write_values(ctx, values)


def measure_real(ctx) -> None:
    cfg, proto, clips, items = _replicate_inputs(ctx)
    values = proto.real_replicate(clips, items, evaluator_for(cfg), seed=ctx.seed,
                                  replicate=cfg["replicate"], **(cfg.get("real") or {}))
    write_values(ctx, values)


def read_values(obj) -> dict[str, float | None]:
    """The metric values a measure/measure_real object holds."""
    return json.loads(obj.read_text(VALUES))["values"]


def read_training(obj) -> dict | None:
    """The parsed ``training.json`` of a train job's store object (its learning curve and
    sizes, schema :data:`TRAINING_SCHEMA`; an older object may hold schema 1: ``history``,
    ``resumed_from``, ``seconds`` only), or None when the object has none."""
    try:
        text = obj.read_text(TRAINING)
    except (FileNotFoundError, KeyError, OSError):
        return None
    return json.loads(text)
