"""Action-level and motion-level qualification ratios (Neural Marionette §5.2.2, Eq. 7).

Input: ``correct``, a bool (S, A) array — S generated multi-action sequences, A actions each,
True where the recogniser classified the action as its tag.

- Action QR: per sequence, the fraction of its actions classified correctly; averaged over
  sequences ("a motion including 3 accurate actions among total 5 actions … 60 %").
- Motion QR (Eq. 7): qualified animations / all animations, an animation being qualified
  only if all its actions are recognised correctly.

Both are fractions in [0, 1].  Whether the first action (whose initial motion comes from the
data set) counts is not stated; ``from_action`` is the 0-based index of the first action that
counts (default 0: all; NM's table averages run from the second action, ``from_action=1``).
:func:`qualification_curves` gives both ratios as functions of the number of actions, as in
Fig. 8/10.  :func:`qualification_counts` gives the success counts behind them (for Wilson
intervals).
"""

from __future__ import annotations

import numpy as np

from repro.errors import DataError
from repro.metrics.arrays import to_numpy


def _correct(correct, from_action: int) -> np.ndarray:
    c = to_numpy(correct)
    if c.ndim != 2:
        raise DataError(f"qualification: expected a (sequences, actions) array, got shape {c.shape}")
    if c.dtype != bool:
        if not np.isin(c, (0, 1)).all():
            raise DataError("qualification: 'correct' must be boolean (or 0/1)")
        c = c.astype(bool)
    if not 0 <= from_action < c.shape[1]:
        raise DataError(f"qualification: from_action must lie in 0..{c.shape[1] - 1}, got {from_action}")
    c = c[:, from_action:]
    if c.shape[0] == 0:
        raise DataError("qualification: no sequences")
    return c


def qualification_ratios(correct, from_action: int = 0) -> tuple[float, float]:
    """``(action_qr, motion_qr)`` as fractions (module docstring)."""
    c = _correct(correct, from_action)
    return float(c.mean(axis=1).mean()), float(c.all(axis=1).mean())


def qualification_counts(correct, from_action: int = 0) -> dict[str, int]:
    """Success counts: correct actions / actions counted, qualified sequences / sequences."""
    c = _correct(correct, from_action)
    return {"actions_correct": int(c.sum()), "actions": int(c.size),
            "motions_qualified": int(c.all(axis=1).sum()), "motions": int(c.shape[0])}


def qualification_curves(correct, from_action: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(A', ) arrays: Action QR and Motion QR over the first 1, 2, … counted actions."""
    c = _correct(correct, from_action)
    n_actions = np.arange(1, c.shape[1] + 1)
    action_qr = (np.cumsum(c, axis=1) / n_actions).mean(axis=0)
    motion_qr = np.logical_and.accumulate(c, axis=1).mean(axis=0)
    return action_qr, motion_qr
