"""``get_evaluator``: train an evaluation classifier once, then load it from the store.

The store key (:func:`evaluator_key`) is the content key of the job kind, the evaluator kind
and architecture, the resolved settings (except the real-row settings, which do not change
the weights), the training data fingerprint, the training seed and the hash of the source
that trains it (:func:`repro.engine.source_hash.source_hash`).  The stored object holds
``weights.pt`` and ``evaluator.json`` (fingerprint, training record, test accuracy and
confusion matrix on the real test split); training checkpoints live in the key's scratch
folder, so an interrupted training resumes exactly.
"""

from __future__ import annotations

from typing import Callable

from repro.eval.evaluator import Evaluator
from repro.eval.settings import KINDS, EvaluatorSettings, resolve_settings
from repro.errors import ConfigError
from repro.keys import content_key

STORE_KIND = "evaluator"
TRAINING_MODULE = "repro.eval.training"

# Evaluators loaded in this process, by store key (they are immutable once trained).
_LOADED: dict[str, Evaluator] = {}


def check_kind(kind: str) -> str:
    if kind not in KINDS:
        raise ConfigError(f"unknown evaluator kind {kind!r} (choose from {', '.join(KINDS)})")
    return kind


def load_dataset(dataset: str):
    """The ClipSet of ``dataset`` through the data-set registry."""
    from repro.data.registry import load_clipset

    return load_clipset(dataset)


def dataset_fingerprint(dataset: str) -> str | None:
    """The prepared data set's fingerprint without loading it (None when unknown)."""
    from repro.data.registry import get_entry

    return get_entry(dataset).status().fingerprint


def evaluator_key(kind: str, settings: EvaluatorSettings, data_fingerprint: str, seed: int) -> str:
    from repro.engine.source_hash import source_hash

    from repro.eval.settings import architecture
    from repro.kernels import key as kernel_key

    return content_key({
        "job": "train_evaluator",
        "kind": kind,
        "architecture": architecture(kind, settings),
        "settings": settings.model_dump(mode="json", exclude={"real"}),
        "data": data_fingerprint,
        "seed": int(seed),
        "kernels": kernel_key(),  # the paths it trains with (repro/kernels.py)
        "source": source_hash(TRAINING_MODULE),
    })


def get_evaluator(dataset: str, kind: str = "a2m_gru", scale: str = "medium", seed: int = 0, *,
                  heading: str | None = None, overrides: dict | None = None,
                  clipset=None, settings: EvaluatorSettings | None = None,
                  on_epoch: Callable[[int, dict], None] | None = None,
                  force: bool = False, weights: bool = True) -> Evaluator:
    """The evaluator of ``kind`` for ``dataset`` at ``scale`` (trained on the real train split
    with training seed ``seed``), from the store or trained now.

    ``heading`` (``"raw" | "yaw_augment" | "remove"``) overrides the scale's heading mode:
    protocols that can change an action's heading (chained multi-action sequences, facing
    normalisation) ask for ``"remove"`` or ``"yaw_augment"``.  ``overrides`` is merged over the
    scale's evaluator settings (e.g. ``{"hidden_init": "random"}`` for reference fidelity).
    ``on_epoch(epoch, record)`` reports training progress; ``force`` retrains even when stored.
    ``weights=False``: when the evaluator is stored, only its record
    (:meth:`Evaluator.load` without weights: describe, fingerprint, test statistics), for a
    run that scores nothing; one not stored yet is trained and loaded as usual."""
    from repro.store.objects import Store

    check_kind(kind)
    if settings is None:
        over = dict(overrides or {})
        if heading is not None:
            over["heading"] = heading
        settings = resolve_settings(scale, over)
    elif heading is not None or overrides:
        settings = settings.model_validate({**settings.model_dump(), **(overrides or {}),
                                            **({"heading": heading} if heading else {})})
    store = Store()
    # Check the store before loading any data (DESIGN.md "Keys").
    fp = clipset.fingerprint if clipset is not None else dataset_fingerprint(dataset)
    if fp is not None and not force:
        key = evaluator_key(kind, settings, fp, seed)
        if key in _LOADED:
            return _LOADED[key]
        obj = store.get(key)
        if obj is not None and not weights:  # a record only: not kept as the loaded one
            return _finish(Evaluator.load(obj.path, weights=False), settings, key, hit=True,
                           keep=False)
        if obj is not None:
            return _finish(Evaluator.load(obj.path), settings, key, hit=True)
    if clipset is None:
        clipset = load_dataset(dataset)
    key = evaluator_key(kind, settings, clipset.fingerprint, seed)

    def build(out_dir) -> None:
        from repro.eval.training import test_accuracy, train_evaluator

        ev = train_evaluator(clipset, kind, settings, seed, ckpt_dir=store.scratch(key),
                             on_epoch=on_epoch)
        ev.meta["test"] = test_accuracy(ev, clipset).to_dict()
        ev.meta["scale"] = scale
        ev.save(out_dir)

    obj = store.compute(key, STORE_KIND, build,
                        meta={"dataset": dataset, "kind": kind, "scale": scale, "seed": int(seed),
                              "data": clipset.fingerprint},
                        force=force)
    return _finish(Evaluator.load(obj.path), settings, key, hit=bool(obj.hit))


def _finish(ev: Evaluator, settings: EvaluatorSettings, key: str, *, hit: bool,
            keep: bool = True) -> Evaluator:
    ev.settings = settings  # identical except for the real-row settings, which are not keyed
    ev.meta["store_key"] = key
    ev.meta["store_hit"] = hit
    if keep:
        _LOADED[key] = ev
    return ev


def evaluator_stats(evaluator: Evaluator) -> dict:
    """The recorded test-split statistics of ``evaluator`` (``top1``, ``top5``, ``n_windows`` ...)."""
    return dict(evaluator.meta.get("test", {}))
