"""Diversity and Multimodality of recogniser features (Action2Motion protocol).

Neural Marionette §5.1.2 (Div, Multi-mod), MultiAct §5, ODMO §4.2.1; drawing rules as the
reference code has them (protocols.md §1.3, §1.4, §4.6).  Units: feature units (Euclidean
distance between 30-d recogniser features).

Diversity (D pairs, default 200): two independent vectors of D indices drawn uniformly *with
replacement* from all N samples; Div = mean ||f_a - f_b||.  Pairs may mix classes and may
repeat an index (distance 0).

Multimodality (M pairs per class, default 20): each class has a quota of M; repeatedly draw a
first index uniformly from all samples (redrawn while its class quota is spent), then second
indices uniformly until one carries the same label (it may be the same sample); add the
distance and decrement the quota.  Result = sum / (M·C) with C the *full* class count.
Conditioned on the class, both indices of that loop are uniform over the class's samples and
independent, so this module draws them per class directly: the same distribution as the quota
loop, without the rejection loop.  A class absent from the set makes the reference loop run
forever; here it is an error, unless ``early_break=True`` (MultiAct's variant: stop when only
absent classes have quota left, still divide by M·C, so absent labels lower the score).

Seeds: an ``int`` seed is turned into an independent stream with
:func:`repro.seeding.numpy_rng` (labelled "diversity" / "multimodality"); a
``numpy.random.Generator`` is used as is.
"""

from __future__ import annotations

import numpy as np

from repro.errors import DataError
from repro.metrics.arrays import check_classes, float_array, int_array
from repro.seeding import numpy_rng

DIVERSITY_PAIRS = 200  # protocols §1.3 (ACTOR, ODMO, MultiAct)
MULTIMODALITY_PAIRS_PER_CLASS = 20  # protocols §1.4


def _rng(seed, label: str) -> np.random.Generator:
    if isinstance(seed, np.random.Generator):
        return seed
    return numpy_rng(int(seed), label)


def diversity(feats, n_pairs: int = DIVERSITY_PAIRS, seed=0) -> float:
    """Mean Euclidean distance over ``n_pairs`` uniformly drawn index pairs (with replacement)."""
    f = float_array(feats, "features", ndim=2, min_len=1)
    if n_pairs < 1:
        raise DataError(f"diversity: n_pairs must be at least 1, got {n_pairs}")
    rng = _rng(seed, "diversity")
    n = f.shape[0]
    first = rng.integers(0, n, size=n_pairs)
    second = rng.integers(0, n, size=n_pairs)
    return float(np.linalg.norm(f[first] - f[second], axis=1).mean())


def multimodality(feats, labels, n_classes: int, per_class: int = MULTIMODALITY_PAIRS_PER_CLASS,
                  seed=0, early_break: bool = False) -> float:
    """Within-class distance: ``per_class`` same-label pairs per class, sum / (per_class·C).

    Pairs are drawn with replacement, as the released code draws them (ACTOR, Action2Motion).
    A class with a single sample has no within-class pair: the released code's quota loop
    then pairs the sample with itself and the class adds exactly 0.  The harness departs from
    that on purpose (a guard, not a reading: it changes no number where every class has two
    samples): when any class that has samples has only one (own data with one test clip per
    class) the value is NaN, which a table shows as "not measured", rather than a mean pulled
    towards 0 that claims would be decided on (docs/metrics.md, "Multimodality")."""
    f = float_array(feats, "features", ndim=2, min_len=1)
    y = int_array(labels, "labels", n=f.shape[0])
    check_classes(y, n_classes, "labels")
    if per_class < 1:
        raise DataError(f"multimodality: per_class must be at least 1, got {per_class}")
    counts = np.bincount(y, minlength=n_classes)
    absent = np.flatnonzero(counts == 0)
    if absent.size and not early_break:
        raise DataError(f"multimodality: classes {absent.tolist()} have no samples (the reference "
                        "quota loop never ends); pass early_break=True for MultiAct's variant")
    if (counts == 1).any():
        return float("nan")
    rng = _rng(seed, "multimodality")
    order = np.argsort(y, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    total = 0.0
    for c in np.flatnonzero(counts):
        members = order[starts[c]: starts[c] + counts[c]]
        a = members[rng.integers(0, counts[c], size=per_class)]
        b = members[rng.integers(0, counts[c], size=per_class)]
        total += float(np.linalg.norm(f[a] - f[b], axis=1).sum())
    return total / (per_class * n_classes)
