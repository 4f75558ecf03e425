"""Statistics over replicates: the papers' ± conventions, Wilson and bootstrap intervals,
claim probabilities with emcee (see docs/metrics.md)."""

from repro.stats.bootstrap import bootstrap_ci
from repro.stats.claims import ClaimResult, claim_probability, verdict
from repro.stats.intervals import INTERVAL_DESCRIPTIONS, INTERVAL_METHODS, paper_halfwidth, wilson
from repro.stats.summary import ReplicateSummary, summarize

__all__ = ["bootstrap_ci", "ClaimResult", "claim_probability", "verdict", "INTERVAL_METHODS",
           "INTERVAL_DESCRIPTIONS", "paper_halfwidth", "wilson", "ReplicateSummary", "summarize"]
