"""Schedules used by several methods.

- :func:`linear_ramp`: a value rising linearly from ``start`` to ``end`` between two epochs
  (Neural Marionette supp. Sec. 3: the scheduled-sampling share ξ from 0 to 1 between the
  "activate" and "accomplish" epochs; ODMO Sec. 4: teacher forcing decays 1 → 0.3).
"""

from __future__ import annotations


def linear_ramp(epoch: float, begin: float, finish: float, start: float = 0.0, end: float = 1.0) -> float:
    """``start`` before ``begin``, ``end`` after ``finish``, linear in between."""
    if finish <= begin:
        return end if epoch >= begin else start
    if epoch <= begin:
        return start
    if epoch >= finish:
        return end
    return start + (end - start) * (epoch - begin) / (finish - begin)
