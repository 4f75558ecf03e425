"""The one training loop: seeded epochs, atomic checkpoints, exact resume.

Every method and evaluator trains through :func:`train`.  The caller supplies

- ``model`` (a ``torch.nn.Module``) and an ``optimizer`` over its parameters;
- ``batches(epoch, generator)``: an iterable of batches for one epoch, drawn only from the
  given ``torch.Generator`` (so the data order of epoch *e* depends on ``(seed, e)`` alone);
- ``step(model, batch, epoch)``: returns a dict of scalar tensors with a ``"loss"`` entry
  (the loop back-propagates ``"loss"`` and logs the detached others).

Determinism and resume: at the start of epoch *e* the global torch RNG (dropout, sampling
inside the model) is re-seeded from ``(seed, e)`` and the batch generator is built from
``(seed, "batches", e)``.  A checkpoint after epoch *e* holds the model, the optimizer and the
history, so a run killed after any checkpoint and started again with the same arguments ends
with byte-identical weights to an uninterrupted run.  Checkpoints are written atomically
(temp file + ``os.replace``) beside a ``config.json`` describing what is being trained
(MDM/ACTOR style); a checkpoint whose config differs is ignored, never resumed from.

History: one record per epoch, the means over its batches of the scalars ``step`` returned,
plus ``epoch`` and ``batches`` (optimiser steps in the epoch).  With ``validate(model, epoch)``
the loop also calls it after each epoch's optimisation, in eval mode, under ``no_grad`` and
with the global torch RNG forked and seeded from ``(seed, "validation")`` (the same draws every
epoch, so the curve moves with the model only), and stores
what it returns with a ``val_`` prefix: validation never moves the training's random stream,
so the weights (and exact resume) are the same with or without it.  The history is in the
checkpoint, so a resumed run's curve is the uninterrupted run's.

Training until a plateau (issue 32, item 2): within :func:`use_stopping` (a job sets it from its
scale profile's ``until = "plateau"``) the loop treats ``epochs`` as a cap and stops after the
first epoch at which the convergence rule (:mod:`repro.train.plateau`) fires on the history, or
after the first epoch that ends past the time cap (cumulative over resumes; a time stop depends
on the machine's speed and is recorded as such, ``stopped_by = "time"``).  The last epoch run is
always checkpointed, and a run resumed from a checkpoint whose history already fired stops
without another epoch, so stopping and resuming give the uninterrupted run's bytes.
"""

from __future__ import annotations

import json
import math
import time
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from repro.keys import canonical_json, content_key
from repro.seeding import derive_seed, torch_generator
from repro.store.atomic import atomic_write_bytes

CHECKPOINT = "checkpoint.pt"
CONFIG = "config.json"


#: the device :func:`train` computes on when its caller names none (set by :func:`use_device`)
_DEVICE: ContextVar[str | None] = ContextVar("repro_train_device", default=None)


@dataclass(frozen=True)
class Stopping:
    """Train until ``rule`` (a :class:`repro.train.plateau.PlateauRule`) fires, the caller's
    ``epochs`` being the cap, or until ``max_seconds`` of training (None: no time cap)."""

    rule: Any
    max_seconds: float | None = None


#: how :func:`train` decides to stop early (set by :func:`use_stopping`; None: run all epochs)
_STOPPING: ContextVar[Stopping | None] = ContextVar("repro_train_stopping", default=None)


@contextmanager
def use_stopping(stopping: Stopping | None):
    """Within the block, every :func:`train` call stops early as ``stopping`` says (module
    docstring); None keeps the fixed number of epochs."""
    token = _STOPPING.set(stopping)
    try:
        yield
    finally:
        _STOPPING.reset(token)


@contextmanager
def use_device(device):
    """Within the block, :func:`train` computes on ``device`` (a name or ``torch.device``; None
    = the CPU) unless its caller passes one.  A job sets it around a generator's ``fit`` so
    that every model, whichever way it calls the loop, trains on the job's device."""
    token = _DEVICE.set(None if device is None else str(device))
    try:
        yield
    finally:
        _DEVICE.reset(token)


def current_device() -> str:
    """The device :func:`train` uses by default here: :func:`use_device`'s, else ``"cpu"``."""
    return _DEVICE.get() or "cpu"


def to_device(obj: Any, device) -> Any:
    """``obj`` with every tensor inside it (dicts, lists, tuples, nested) on ``device``;
    other values as they are.  A tensor already there is returned itself (no copy)."""
    if hasattr(obj, "to") and hasattr(obj, "device") and hasattr(obj, "dtype"):
        return obj.to(device)
    if isinstance(obj, dict):
        out = type(obj)((k, to_device(v, device)) for k, v in obj.items())
        if hasattr(obj, "_metadata"):  # a state_dict's module versions
            out._metadata = obj._metadata
        return out
    if isinstance(obj, (list, tuple)) and not hasattr(obj, "_fields"):
        return type(obj)(to_device(v, device) for v in obj)
    return obj


def module_device(module):
    """The device of ``module``'s first parameter or buffer (the CPU for an empty module):
    where sampling code puts the tensors it makes."""
    import torch

    for t in module.parameters():
        return t.device
    for t in module.buffers():
        return t.device
    return torch.device("cpu")


@dataclass
class TrainResult:
    epochs: int
    resumed_from: int | None
    history: list[dict[str, float]] = field(default_factory=list)
    seconds: float = 0.0
    #: why the loop ended: "epochs" (ran every epoch), "plateau" (the rule fired), "time"
    stopped_by: str = "epochs"


def _atomic_torch_save(obj: Any, path: Path) -> None:
    import io

    import torch

    buf = io.BytesIO()
    torch.save(obj, buf)
    atomic_write_bytes(path, buf.getvalue())


def train(
    model,
    optimizer,
    *,
    batches: Callable[[int, Any], Iterable[Any]],
    step: Callable[[Any, Any, int], dict],
    epochs: int,
    seed: int,
    config: dict,
    ckpt_dir: str | Path | None = None,
    checkpoint_every: int = 1,
    grad_clip: float | None = None,
    on_epoch: Callable[[int, dict[str, float]], None] | None = None,
    scheduler=None,
    validate: Callable[[Any, int], dict[str, float]] | None = None,
    device=None,
) -> TrainResult:
    """Train ``model`` for ``epochs`` epochs (see module docstring); returns the loss history.

    ``config`` is the resolved configuration of what is being trained; it is saved beside the
    checkpoint and guards resumption.  ``checkpoint_every`` is in epochs (the last epoch is
    always checkpointed).  ``grad_clip`` clips the global gradient norm.  ``validate(model,
    epoch)`` returns scalars measured on held-out data after each epoch (stored as ``val_*``;
    it must not change the model); ``on_epoch`` sees the record with them.  ``device``: where
    to compute (default :func:`current_device`); the model is left there.
    """
    import torch

    from repro.kernels import check as check_kernels

    check_kernels()  # every training computes under the pin it is keyed with (repro/kernels.py)
    dev = torch.device(current_device() if device is None else str(device))
    on_cpu = dev.type == "cpu"
    if not on_cpu:  # before resuming: the optimiser's state is then loaded onto the device
        model.to(dev)
    t0 = time.perf_counter()
    cfg_key = content_key(config)
    start_epoch, resumed_from, history, spent = 0, None, [], 0.0
    ckpt_path = None
    if ckpt_dir is not None:
        ckpt_dir = Path(ckpt_dir)
        ckpt_path = ckpt_dir / CHECKPOINT
        start_epoch, resumed_from, history, spent = _resume(ckpt_dir, config, cfg_key, model,
                                                            optimizer, scheduler)
    stopping = _STOPPING.get()
    stopped_by = _stop_reason(stopping, history, spent) if history else None
    epoch = start_epoch
    while stopped_by is None and epoch < epochs:
        rec = _train_epoch(model, optimizer, batches, step, seed, epoch, dev, grad_clip,
                           scheduler)
        if validate is not None:
            rec.update(_validation(model, validate, seed, epoch))
        history.append(rec)
        if on_epoch is not None:
            on_epoch(epoch, rec)
        stopped_by = _stop_reason(stopping, history, spent + time.perf_counter() - t0)
        last = epoch == epochs - 1 or stopped_by is not None
        if ckpt_path is not None and (last or (epoch + 1) % max(checkpoint_every, 1) == 0):
            _save_checkpoint(ckpt_path, model, optimizer, scheduler, epoch, history, on_cpu,
                             spent + time.perf_counter() - t0)
        epoch += 1
    model.eval()
    return TrainResult(epochs=epochs, resumed_from=resumed_from, history=history,
                       seconds=time.perf_counter() - t0, stopped_by=stopped_by or "epochs")


def _stop_reason(stopping: Stopping | None, history: list, seconds: float) -> str | None:
    """"plateau" when the rule fires at the history's last epoch, "time" past the time cap,
    else None (go on)."""
    if stopping is None:
        return None
    from repro.train.plateau import fires_at

    if fires_at(history, stopping.rule, len(history) - 1):
        return "plateau"
    if stopping.max_seconds is not None and seconds >= stopping.max_seconds:
        return "time"
    return None


def _resume(ckpt_dir: Path, config: dict, cfg_key: str, model, optimizer, scheduler
            ) -> tuple[int, int | None, list, float]:
    """Load the checkpoint in ``ckpt_dir`` into the model, optimiser and scheduler when its
    ``config.json`` holds ``cfg_key`` (a torn or foreign one is ignored), then write the
    config files beside it; returns ``(start epoch, resumed_from, history, seconds trained
    before)``."""
    import torch

    ckpt_dir.mkdir(parents=True, exist_ok=True)
    ckpt_path = ckpt_dir / CHECKPOINT
    cfg_path = ckpt_dir / CONFIG
    start_epoch, resumed_from, history, spent = 0, None, [], 0.0
    if ckpt_path.exists() and cfg_path.exists():
        try:
            saved_cfg = json.loads(cfg_path.read_text())
            state = torch.load(ckpt_path, map_location="cpu", weights_only=True)
        except Exception:  # a torn or foreign checkpoint: start afresh
            state, saved_cfg = None, None
        if state is not None and saved_cfg == {"key": cfg_key}:
            model.load_state_dict(state["model"])
            optimizer.load_state_dict(state["optimizer"])
            if scheduler is not None and state.get("scheduler") is not None:
                scheduler.load_state_dict(state["scheduler"])
            start_epoch = int(state["epoch"]) + 1
            resumed_from = start_epoch
            history = json.loads(state["history"])
            spent = float(state.get("seconds") or 0.0)
    atomic_write_bytes(cfg_path, canonical_json({"key": cfg_key}))
    atomic_write_bytes(ckpt_dir / "config.full.json", canonical_json(config))
    return start_epoch, resumed_from, history, spent


def _train_epoch(model, optimizer, batches, step, seed: int, epoch: int, dev, grad_clip,
                 scheduler) -> dict:
    """One epoch's optimisation: the global torch RNG seeded from ``(seed, epoch)``, the batches
    drawn from ``(seed, "batches", epoch)`` (moved to the device ``dev`` off the CPU), one
    optimiser step per batch, then the scheduler's step; returns the epoch's record (the means
    of the scalars ``step`` returned, ``epoch`` and ``batches``)."""
    import torch

    torch.manual_seed(derive_seed(seed, "epoch", epoch))
    gen = torch_generator(seed, "batches", epoch)
    model.train()
    logged: dict[str, list] = {}   # each scalar's per-step values, converted at the end
    n = 0
    on_cpu = dev.type == "cpu"
    for batch in batches(epoch, gen):
        if not on_cpu:
            batch = to_device(batch, dev)
        out = step(model, batch, epoch)
        loss = out["loss"]
        if not torch.isfinite(loss):
            raise FloatingPointError(f"non-finite loss at epoch {epoch}: {float(loss)}")
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if grad_clip is not None:
            torch.nn.utils.clip_grad_norm_(model.parameters(), grad_clip)
        optimizer.step()
        for k, v in out.items():  # a copy: the step's tensor may alias a parameter
            logged.setdefault(k, []).append(v.detach().clone() if hasattr(v, "detach") else v)
        n += 1
    if scheduler is not None:
        scheduler.step()
    rec = {k: _float_sum(vs) / max(n, 1) for k, vs in logged.items()}
    rec["epoch"] = epoch
    rec["batches"] = n
    return rec


def _save_checkpoint(ckpt_path: Path, model, optimizer, scheduler, epoch: int, history: list,
                     on_cpu: bool, seconds: float = 0.0) -> None:
    """Write the checkpoint after ``epoch`` atomically: model, optimiser and scheduler states
    (on the CPU), the epoch, the history so far and the seconds trained (for the time cap)."""
    state = {
        "model": model.state_dict(),
        "optimizer": optimizer.state_dict(),
        "scheduler": None if scheduler is None else scheduler.state_dict(),
        "epoch": epoch,
        "history": json.dumps(history),
        "seconds": float(seconds),
    }
    _atomic_torch_save(state if on_cpu else to_device(state, "cpu"), ckpt_path)


def _float_sum(values: list) -> float:
    """The Python-float sum, in step order, of one logged scalar's values over an epoch (0-d
    tensors or numbers): what adding ``float(v)`` after every step gives, bitwise, with one
    host transfer for all the tensors instead of one per value and step (on an accelerator
    each ``float`` waits for the device)."""
    import torch

    tensors = [v for v in values if isinstance(v, torch.Tensor)]
    if len({(t.dtype, t.device) for t in tensors}) == 1:  # one transfer, no type promotion
        floats = iter(torch.stack([t.reshape(()) for t in tensors]).tolist())
    else:
        floats = iter([float(t) for t in tensors])
    total = 0.0
    for v in values:
        total += next(floats) if isinstance(v, torch.Tensor) else float(v)
    return total


def _validation(model, validate, seed: int, epoch: int) -> dict[str, float]:
    """``validate(model, epoch)`` in eval mode, without gradients, on a forked global RNG seeded
    from ``(seed, "validation")`` — the same draws every epoch (reparameterisation noise,
    teacher-forcing masks, A2M's self-feeding coin), so the curve moves only with the model and
    the convergence rule (:mod:`repro.train.plateau`) does not read draw-to-draw noise as a
    plateau; the training's own RNG is untouched (forked).  Its scalars with a ``val_``
    prefix.  The caller puts the model back in train mode at the next epoch."""
    import torch

    devices = (list(range(torch.cuda.device_count()))
               if torch.cuda.is_available() and torch.cuda.is_initialized() else [])
    with torch.random.fork_rng(devices=devices):
        torch.manual_seed(derive_seed(seed, "validation"))
        model.eval()
        with torch.no_grad():
            out = validate(model, epoch) or {}
    return {f"val_{k}": float(v.detach() if hasattr(v, "detach") else v) for k, v in out.items()}


def finite_or_none(x: float) -> float | None:
    return x if math.isfinite(x) else None
