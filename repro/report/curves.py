"""Learning curves as plain text: :func:`format_learning_curve`.

A train job's ``training.json`` (:func:`repro.engine.steps.read_training`, schema 2) holds one
history record per epoch: the means over the epoch's batches of the loss terms the method
logs, ``batches`` (optimiser steps), the same terms on the held-out validation clips with a
``val_`` prefix (:mod:`repro.train.validation`) and, for MarioNet, whether scheduled sampling
was active (``ss_active``: the share of the epoch's batches where it was) and its mixing share
``xi`` (the mean over the epoch's batches, 0 on a batch without scheduled sampling; shown as
``xi|active`` = ξ on the active batches).  ``repro runs show`` prints these lines; docs may
reuse them.
"""

from __future__ import annotations

import math
from typing import Any

#: columns shown when a record has them, in order: (history key, header, format)
COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("loss", "loss", ".4g"),
    ("val_loss", "val_loss", ".4g"),
    # MarioNet: ``loss`` changes meaning when scheduled sampling switches on (λ1·first pass +
    # λ2·second pass); the first pass's reconstruction and the joint error are comparable
    # across epochs, on training and held-out clips
    ("rec1", "rec1", ".4g"),
    ("val_rec1", "val_rec1", ".4g"),
    ("mpjpe", "mpjpe", ".4g"),
    ("val_mpjpe", "val_mpjpe", ".4g"),
    ("ss_active", "ss_active", ".2f"),
    ("xi_active", "xi|active", ".3f"),
)


def _derived(h: dict) -> dict:
    """``xi_active``: the mixing share ξ on the batches where scheduled sampling was on (the
    logged ``xi`` averages ξ with 0 over the batches where it was off)."""
    out = dict(h)
    a = h.get("ss_active")
    if a is not None and "xi" in h:
        out["xi_active"] = float(h["xi"]) / float(a) if float(a) > 0 else None
    return out


def _num(v: Any, fmt: str) -> str:
    if v is None:
        return "—"
    try:
        x = float(v)
    except (TypeError, ValueError):
        return str(v)
    if not math.isfinite(x):
        return str(x)
    return format(x, fmt)


def curve_epochs(n: int, max_rows: int = 25) -> list[int]:
    """Positions of the history records shown: all when ``n <= max_rows``, else every k-th
    one (k the smallest step that fits) plus the last, at most ``max_rows`` in all."""
    if n <= max_rows:
        return list(range(n))
    k = math.ceil((n - 1) / max(max_rows - 1, 1))
    rows = list(range(0, n - 1, k))
    return rows + [n - 1]


def summary_line(training: dict) -> str:
    """One line: epochs, optimiser steps, batch size, train / validation items, seconds."""
    history = training.get("history") or []
    epochs = training.get("epochs")
    if epochs is None and history:
        epochs = len(history)
    steps = training.get("steps")
    if steps is None and history and all("batches" in h for h in history):
        steps = sum(int(h["batches"]) for h in history)
    ran = (f"epochs {len(history)} of a cap of {epochs}"
           if training.get("until") == "plateau" and epochs is not None
           else f"epochs {'—' if epochs is None else epochs}")
    parts = [ran, f"steps {'—' if steps is None else steps}"]
    if training.get("batch_size") is not None:
        parts.append(f"batch {training['batch_size']}")
    n_train, n_val = training.get("n_train"), training.get("n_validation")
    if n_train is not None or n_val is not None:
        frac = training.get("validation_fraction")
        parts.append(f"items {'—' if n_train is None else n_train} train / "
                     f"{'—' if n_val is None else n_val} validation"
                     + ("" if frac is None else f" (fraction {float(frac):g})"))
    secs = training.get("seconds")
    parts.append(f"{_num(secs, '.1f')} s")
    if training.get("resumed_from") is not None:
        parts.append(f"resumed at epoch {training['resumed_from']}")
    return ", ".join(parts)


def convergence_line(training: dict) -> str | None:
    """One line on the convergence rule (issue 32; ``training.json`` schema 3): whether and
    when it fired, what it reads, and why the training stopped; None for an older record."""
    conv = training.get("convergence")
    if not isinstance(conv, dict):
        return None
    crit = conv.get("criterion") or "the plateau rule"
    if conv.get("converged"):
        e = conv.get("converged_epoch")
        head = ("converged" if e is None else f"converged at epoch {e}") + f" ({crit})"
    elif conv.get("converged_epoch") is not None:
        head = (f"not converged at its last epoch ({crit} first held at epoch "
                f"{conv['converged_epoch']}, then no longer)")
    else:
        head = f"not converged ({crit} never held)"
    stop = {"plateau": "stopped by the rule", "epochs": "ran to its last epoch",
            "time": "stopped by the time cap"}.get(conv.get("stopped_by"), None)
    mode = ("trained until the plateau" if training.get("until") == "plateau"
            else "a fixed number of epochs")
    return f"{head}; {mode}" + ("" if stop is None else f", {stop}")


def format_learning_curve(training: dict, *, max_rows: int = 25) -> list[str]:
    """Text lines of one training's learning curve: a table of epoch, ``loss``, ``val_loss``
    and, when logged (MarioNet), ``rec1``, ``mpjpe`` (each also on the held-out clips),
    ``ss_active`` and ξ where active — every epoch, or every k-th plus the
    last when there are more than ``max_rows`` — then :func:`summary_line`.  A training without
    epochs (a method that only indexes its items) gives one line saying so, then the summary."""
    history = [_derived(h) for h in (training.get("history") or []) if isinstance(h, dict)]
    if not history:
        return ["no epochs (nothing trained)", summary_line(training)]
    cols = [(k, head, fmt) for k, head, fmt in COLUMNS if any(k in h for h in history)]
    header = ["epoch"] + [head for _, head, _ in cols]
    rows = []
    for i in curve_epochs(len(history), max_rows):
        h = history[i]
        rows.append([str(h.get("epoch", i))] + [_num(h.get(k), fmt) for k, _, fmt in cols])
    widths = [max(len(r[j]) for r in [header] + rows) for j in range(len(header))]
    fmt_row = lambda r: "  ".join(c.rjust(w) for c, w in zip(r, widths))  # noqa: E731
    conv = convergence_line(training)
    return ([fmt_row(header)] + [fmt_row(r) for r in rows] + [summary_line(training)]
            + ([] if conv is None else [conv]))


__all__ = ["format_learning_curve", "convergence_line", "summary_line", "curve_epochs",
           "COLUMNS"]
