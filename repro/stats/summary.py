"""One cell's replicate summary: raw values, mean, the paper-style ± and bootstrap intervals.

DESIGN.md "Keys, runs, intervals": reports show the paper's own ± (its convention, named in
the table spec) beside our bootstrap interval, and the raw replicate values are always kept
so that any convention can be recomputed later.  :func:`summarize` builds that record;
``to_dict`` is JSON-safe (NaN -> None) for ``values.jsonl`` / ``summary.json``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from repro.stats.bootstrap import bootstrap_ci
from repro.stats.intervals import INTERVAL_DESCRIPTIONS, paper_halfwidth


@dataclass(frozen=True)
class ReplicateSummary:
    values: tuple[float, ...]  # raw per-replicate values (never dropped)
    n: int
    mean: float
    sd: float | None  # ddof 1; None for a single replicate
    paper_method: str
    paper_halfwidth: float | None
    percentile: tuple[float, float]
    bca: tuple[float, float]
    conf: float
    n_boot: int
    seed: int

    def to_dict(self) -> dict:
        def num(x):
            return None if x is None or not math.isfinite(x) else float(x)

        return {
            "values": [float(v) for v in self.values], "n": self.n, "mean": num(self.mean),
            "sd": num(self.sd), "paper_method": self.paper_method,
            "paper_method_description": INTERVAL_DESCRIPTIONS[self.paper_method],
            "paper_halfwidth": num(self.paper_halfwidth),
            "bootstrap_percentile": [num(x) for x in self.percentile],
            "bootstrap_bca": [num(x) for x in self.bca],
            "conf": self.conf, "n_boot": self.n_boot, "seed": self.seed,
        }


def summarize(values, paper_method: str, conf: float = 0.95, n_boot: int = 1000, seed: int = 0,
              scale: float = 1.0) -> ReplicateSummary:
    """Summary of one cell's replicate values (``scale`` multiplies them first, e.g. 100 for
    a fraction shown in %; it matters for ACTOR's variance-based ±)."""
    v = np.asarray(values, dtype=np.float64).ravel() * scale
    return ReplicateSummary(
        values=tuple(float(x) for x in v), n=int(v.size), mean=float(v.mean()),
        sd=float(np.std(v, ddof=1)) if v.size > 1 else None, paper_method=paper_method,
        paper_halfwidth=paper_halfwidth(v, paper_method, conf=conf),
        percentile=bootstrap_ci(v, np.mean, "percentile", n_boot=n_boot, conf=conf, seed=seed),
        bca=bootstrap_ci(v, np.mean, "bca", n_boot=n_boot, conf=conf, seed=seed),
        conf=conf, n_boot=n_boot, seed=seed,
    )
