"""What the comparison strips of both kinds share: the :class:`Strip` record, a one-item
motion's joints (:func:`strip_joints`) and the seeded choice of items (:func:`pick_items`).

The Neural Marionette and ODMO bands are drawn by :mod:`repro.report.strip_sets`, MultiAct's
by :mod:`repro.report.pair_strips`; drawing itself is :mod:`repro.render.strips`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from repro.seeding import numpy_rng


@dataclass
class Strip:
    """One strip: what it shows (``meta``) and its panels (top: real)."""

    name: str                 # file stem, e.g. "band0-item3"
    title: str
    panels: list              # repro.render.strips.Panel
    frames: list[int]
    meta: dict = field(default_factory=dict)


def strip_joints(motion) -> np.ndarray:
    """(T, J, 3) float32 world joints of a one-item Motion."""
    return motion.joints()[0].detach().cpu().numpy().astype(np.float32)


def pick_items(labels: np.ndarray, n: int, seed: int) -> list[int]:
    """``n`` item positions, one per tag as far as tags go: a seeded order of the tags, the
    first (seeded) item of each."""
    rng = numpy_rng(seed, "strips", "items")
    tags = rng.permutation(np.unique(labels))
    out: list[int] = []
    round_ = 0
    while len(out) < min(n, len(labels)):
        for t in tags:
            pos = np.flatnonzero(labels == t)
            order = numpy_rng(seed, "strips", "tag", int(t)).permutation(pos)
            if round_ < len(order) and len(out) < n:
                out.append(int(order[round_]))
        round_ += 1
    return out
