"""The convergence rule every training is measured by (issue 32, item 1): :func:`plateau_epoch`.

Why: a verdict that compares two models only says something about the *methods* when both were
trained until they stopped improving; a model cut off while its validation error still falls is
compared at an arbitrary point of its curve.  None of the three papers states a stopping rule
(Neural Marionette supp. Sec. 3 trains a fixed 1,000 epochs; MultiAct's released code 1,200;
ODMO's 100,000), so the rule is ours, and it is the same for every method.

The rule reads a per-epoch quantity measured on the held-out share of the *training* split
(:mod:`repro.train.validation`; never test data): ``val_loss`` by default, read only from the
first epoch at which it keeps one meaning, ``start_epoch`` (after ODMO's teacher-forcing decay;
after MarioNet's scheduled-sampling ramp, whose loss mixes two passes with moving weights until
then), and, with a ``gate``, only on epochs where the gate quantity is 1.

At epoch *e* (0-based), with each quantity smoothed by a trailing mean over ``smooth`` epochs
(``s``), and ``w = max(min_window, ceil(window_share · (e + 1)))`` epochs per window:

    converged at e  ⇔  the last two windows of ``w`` epochs lie wholly at or after
                        ``start_epoch`` + ``smooth`` − 1, and, with ``b`` and ``l`` the means
                        of s over the window before and over the last window,
                        b − l < tolerance · max(|b|, atol),
                        and the same holds with ``b`` and ``l`` the windows' medians

i.e. the smoothed quantity improved by less than ``tolerance`` (1 %) over the last ``w``
epochs (20 % of the run, at least 5), window against window (``atol``, 1e-6, only keeps a
quantity at zero from never firing).  Window summaries, not best values: a curve still falling
by a few per cent per window under epoch-to-epoch noise must not fire because one lucky early
epoch stands as the best; a window mean averages ``w`` epochs of noise away.

Medians too (``statistic = "both"``, the default; "mean" and "median" read one): a mean is
moved by a spike, so a curve still falling whose last few epochs jump (an unstable step, a bad
batch) reads as "no improvement" and fires in the middle of the jump: the first converged
records (2026-12-06, window means only) stopped MACVAE at epoch 63 while its ``val_kl`` went
243 → 528 and ODMO's paper reading in a bump; a median is not moved by a spike shorter than
half a window, but alone it is noisier than the mean under Gaussian noise and fires early on
a curve still falling.  Requiring both keeps each one's protection.  (The held-out
quantity is measured with the same random draws every epoch — :func:`repro.train.loop` seeds
validation once per training — so what noise remains is the model's own, not the draws'.)  A
rising curve (over-fitting) and a flat one fire; a curve still falling by more than 1 % per
window does not.  Every smoothed value in both windows must be finite (a window that holds a
NaN epoch never fires).

A rule may read further quantities (``also``), which must *stay* within the tolerance in both
directions: |b − l| < tolerance · max(|b|, atol); it fires only when every quantity does.
MACVAE and ACTOR weight their KL term by 1e-5, so ``val_loss`` is almost all reconstruction and
says nearly nothing about the posterior's distance from the prior the generator samples from;
their rules also read ``val_kl``, and a KL still rising (posteriors drifting from the prior)
holds the rule back as one still falling does.  A rule may name a ``gate``: an epoch counts
only where that quantity is 1 (MarioNet's ``val_ss_active``: its loss has one meaning only
while scheduled sampling is active on every held-out batch).  A method with no held-out
quantity that measures its generator (an adversarial one: Act-MoCoGAN) has ``metric = None``:
its rule never fires, and it trains to its cap.

:func:`plateau_epoch` returns the first epoch at which the rule fires, so a training that stops
there and a longer one that is read afterwards agree on when it first converged; a record's
``converged`` is whether the rule holds at its *last* epoch (a fixed-epoch training whose curve
flattened and then fell again has not converged), and ``converged_epoch`` is the first firing.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

#: what :func:`criterion_text` and the records call the rule
RULE_NAME = "plateau"
#: how a window of smoothed values is summarised (module docstring, "Medians"): each reading's
#: summaries, every one of which must find the improvement under the tolerance
_SUMMARIES = {"both": (np.mean, np.median), "mean": (np.mean,), "median": (np.median,)}
STATISTICS = tuple(_SUMMARIES)


@dataclass(frozen=True)
class PlateauRule:
    """The rule's settings (module docstring); defaults are the issue's: 1 % over the last
    max(5, 20 %) epochs, on a 3-epoch trailing mean of ``val_loss``."""

    metric: str | None = "val_loss"
    also: tuple[str, ...] = ()
    gate: str | None = None
    tolerance: float = 0.01
    atol: float = 1e-6
    window_share: float = 0.2
    min_window: int = 5
    smooth: int = 3
    start_epoch: int = 0
    statistic: str = "both"

    def __post_init__(self):
        if self.statistic not in STATISTICS:
            raise ValueError(f"plateau statistic must be one of {', '.join(STATISTICS)}, got "
                             f"{self.statistic!r}")
        if not (0.0 < self.tolerance < 1.0):
            raise ValueError(f"plateau tolerance must lie in (0, 1), got {self.tolerance!r}")
        if not (0.0 <= self.window_share < 1.0):
            raise ValueError(f"plateau window_share must lie in [0, 1), got {self.window_share!r}")
        if not self.atol > 0.0:
            raise ValueError(f"plateau atol must be > 0, got {self.atol!r}")
        if self.min_window < 1 or self.smooth < 1 or self.start_epoch < 0:
            raise ValueError("plateau min_window and smooth must be ≥ 1, start_epoch ≥ 0")

    def with_settings(self, settings: dict[str, Any] | None) -> "PlateauRule":
        """This rule with the profile's settings (``tolerance``, ``window_share``,
        ``min_window``, ``smooth``, ``statistic``) applied; the method's ``metric`` and
        ``start_epoch`` stay."""
        keys = ("tolerance", "window_share", "min_window", "smooth", "statistic")
        return replace(self, **{k: v for k, v in (settings or {}).items() if k in keys})

    @property
    def metrics(self) -> tuple[str, ...]:
        """Every quantity the rule reads (none for a method it cannot measure)."""
        return () if self.metric is None else (self.metric, *self.also)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["also"] = list(self.also)
        return d


def window(rule: PlateauRule, epochs_seen: int) -> int:
    """The number of epochs in the last window after ``epochs_seen`` epochs."""
    return max(rule.min_window, math.ceil(rule.window_share * epochs_seen - 1e-9))


def _series(history: list[dict], metric: str, gate: str | None = None) -> np.ndarray:
    """The metric per record (NaN where missing or not finite, or where the gate is not 1)."""
    out = np.full(len(history), np.nan)
    for i, h in enumerate(history):
        v = h.get(metric) if isinstance(h, dict) else None
        if gate is not None and (not isinstance(h, dict) or h.get(gate) != 1.0):
            continue
        if isinstance(v, (int, float)) and math.isfinite(float(v)):
            out[i] = float(v)
    return out


def _fires_on(history: list[dict], metric: str, rule: PlateauRule, epoch: int,
              two_sided: bool) -> bool:
    w = window(rule, epoch + 1)
    first = epoch - 2 * w + 1  # the window before's first epoch
    if first < rule.start_epoch + rule.smooth - 1:
        return False  # two whole comparable windows are not there yet
    # only the epochs the two windows' trailing means read: O(w) per call
    v = _series(history[first - rule.smooth + 1: epoch + 1], metric, rule.gate)
    s = sliding_window_view(v, rule.smooth).mean(axis=1)  # NaN where any epoch is NaN
    if not np.isfinite(s).all():
        return False  # a window with a missing or non-finite value never fires
    for agg in _SUMMARIES[rule.statistic]:
        b, last = float(agg(s[:w])), float(agg(s[w:]))
        change = abs(b - last) if two_sided else b - last
        if not change < rule.tolerance * max(abs(b), rule.atol):
            return False
    return True


def fires_at(history: list[dict], rule: PlateauRule, epoch: int) -> bool:
    """Whether the rule fires at ``epoch`` reading ``history[: epoch + 1]``: on every
    quantity it reads (never, for a rule that reads none)."""
    if not rule.metrics or epoch < 0 or epoch >= len(history):
        return False
    return (_fires_on(history, rule.metric, rule, epoch, two_sided=False)
            and all(_fires_on(history, m, rule, epoch, two_sided=True) for m in rule.also))


def plateau_epoch(history: list[dict], rule: PlateauRule) -> int | None:
    """The first epoch at which the rule fires on ``history`` (one record per epoch, in
    order), or None when it never does."""
    for e in range(len(history)):
        if fires_at(history, rule, e):
            return e
    return None


def criterion_text(rule: PlateauRule) -> str:
    """The rule in words, as records and verdicts name it."""
    if not rule.metrics:
        return ("none: no held-out quantity measures this method's generator (adversarial "
                "training); it trains to its cap and never counts as converged")
    start = (f", after the first {rule.start_epoch} epochs" if rule.start_epoch else "")
    gate = (f", on epochs with {rule.gate} = 1" if rule.gate else "")
    also = "".join(f"; {m} changed < {rule.tolerance:.0%} either way" for m in rule.also)
    stat = "mean and median" if rule.statistic == "both" else rule.statistic
    return (f"{rule.metric} ({rule.smooth}-epoch mean{start}{gate}): {stat} of the last max("
            f"{rule.min_window}, {rule.window_share:.0%}) epochs improved < "
            f"{rule.tolerance:.0%} on the window before{also}")


def convergence_record(history: list[dict], rule: PlateauRule, stopped_by: str | None = None
                       ) -> dict[str, Any]:
    """What ``training.json`` records of a training's convergence: ``converged`` (bool: the
    rule holds at the history's last epoch), ``converged_epoch`` (the first epoch the rule
    fired, 0-based; None when it never did), ``criterion`` (text),
    ``rule`` (the settings), ``stopped_by`` ("plateau", "epochs" for the cap or a fixed
    schedule, "time" for the time cap)."""
    e = plateau_epoch(history, rule)
    holds = e is not None and fires_at(history, rule, len(history) - 1)
    return {"converged": holds, "converged_epoch": e, "criterion": criterion_text(rule),
            "rule": rule.to_dict(), "stopped_by": stopped_by}


__all__ = ["PlateauRule", "RULE_NAME", "convergence_record", "criterion_text", "fires_at",
           "plateau_epoch", "window"]
