"""A claim's pairwise comparisons and their conjunction: what a table's claims
(:mod:`repro.engine.tables`) and a figure's (:mod:`repro.engine.figures`) are both decided by.

:func:`pairs_on` reads the comparisons of an ``order`` / ``gap`` / ``trend``-along-rows claim on
one column from the summary cells, each with its posterior probability
(:func:`repro.stats.claims.claim_probability`); :func:`conjunction` joins them into the claim's
verdict (supported when every one is, contradicted when any is, P = the smallest P).
"""

from __future__ import annotations

import math


def pairs_on(spec, cl, col: str, key: str, cells, seed: int = 0):
    """The pairwise comparisons of an order / gap / trend-along-rows claim on column ``col``,
    read from the cells ``(row, key)`` (``key`` = ``col`` on a table, ``"col@x"`` on a figure):
    a list of (probability, verdict, reason), or a str saying why it cannot be evaluated."""
    from repro.stats.claims import claim_probability
    from repro.stats.claims import verdict as vd

    column = spec.column(col)
    direction = cl.direction or column.direction

    def vals(row_id):
        v = cells[(row_id, key)]
        if direction == "closer_to_real":
            ref = spec.reference_row(col)
            if ref is None or (ref, key) not in cells:
                return None
            m = sum(cells[(ref, key)]) / len(cells[(ref, key)])
            return [abs(x - m) for x in v]
        return v

    d = "lower" if direction in ("lower", "closer_to_real", "decreasing") else "higher"
    if cl.kind == "order":
        comps = [(cl.better, other) for other in cl.than]
    elif cl.kind == "gap":
        comps = [(cl.a, cl.b)]
    else:  # trend along rows: consecutive rows follow the direction
        comps = list(zip(cl.rows[1:], cl.rows[:-1]))
    within = (cl.kind == "gap" and cl.bound == "within") or \
        (cl.kind == "trend" and direction == "stable")  # stable: consecutive rows within δ
    pairs = []
    for a, b in comps:
        va, vb = vals(a), vals(b)
        if va is None or vb is None:
            return f"no reference row for closer-to-real column {col!r}"
        delta = float(cl.delta or 0.0)
        tag = (lambda r: None if r is None else f"{key}: {r}")  # say which column it is about
        if within:
            hi = claim_probability(va, vb, "higher", delta, seed=seed)
            lo = claim_probability(va, vb, "lower", delta, seed=seed)
            if hi.decided_by == "values":  # no spread: within iff neither side is ahead by δ
                holds = hi.verdict != "supported" and lo.verdict != "supported"
                pairs.append((math.nan, "supported" if holds else "contradicted",
                              tag(hi.reason)))
                continue
            if hi.reason or lo.reason:  # a chain that did not mix (or no spread to learn)
                pairs.append((math.nan, "inconclusive", tag(hi.reason or lo.reason)))
                continue
            p = 1.0 - hi.probability - lo.probability
            pairs.append((p, vd(p), None))
        else:
            res = claim_probability(va, vb, d, delta if cl.kind == "gap" else 0.0, seed=seed)
            # a chain that did not mix shows no P (its P is not evidence)
            p = math.nan if res.verdict == "inconclusive" and res.reason else res.probability
            pairs.append((p, res.verdict, tag(res.reason)))
    return pairs


def conjunction(base: dict, pairs: list, lead: str | None = None, notes=()) -> dict:
    """The verdict of a conjunction of comparisons (probability, verdict, reason): supported
    when every one is, contradicted when any is, else inconclusive; P = the smallest P (an
    upper bound on the joint probability).  ``lead`` (what decided it: the x present, the
    replicates) opens the reason, then ``notes`` and the comparisons' own reasons."""
    ps = [p for p, _, _ in pairs]
    verdicts = [v for _, v, _ in pairs]
    if "contradicted" in verdicts:
        verdict = "contradicted"
    elif all(v == "supported" for v in verdicts):
        verdict = "supported"
    else:
        verdict = "inconclusive"
    finite = [p for p in ps if p is not None and math.isfinite(p)]
    # a comparison that could not be evaluated (a chain that did not mix, a single replicate)
    # leaves the joint probability unknown: no P for the conjunction
    unknown = any(v == "inconclusive" and (p is None or not math.isfinite(p)) for p, v, _ in pairs)
    reasons = sorted({r for _, _, r in pairs if r} | set(notes))
    reason = "; ".join(([lead] if lead else []) + reasons) or None
    return {**base, "verdict": verdict,
            "probability": min(finite) if finite and not unknown else None,
            "pairwise": ps, "reason": reason}
