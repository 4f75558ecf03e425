"""Latent mode discovery (GMM + silhouette K selection) and ODMO's mode-homogeneity.

ODMO §3.3 / supplement §2.2 (mode discovery), §4.3.1 and Table 3 (mode-homogeneity);
protocols.md §3.5, §3.7 and §7 items 1-3.

For one action class, a Gaussian mixture (scikit-learn ``GaussianMixture``: full covariance,
k-means initialisation, ``n_init=5``, ``random_state=seed``) is fitted for each candidate K and
scored with ``silhouette_score`` (Euclidean) of its hard assignment.  Three K-selection rules:

``"code"`` (default; ODMO's sampler ``sample_code_multimodal``, which produced the numbers)
    k = 3..9; keep K = k while S_k >= 0.95·S_{k-1} (S_2 := -1, so k = 3 is always kept); stop
    at the first k with S_k < 0.95·S_{k-1}; K = 9 if it never stops.  Components holding
    <= 10 of the fitted codes are dropped.
``"paper"`` (supplement §2.2)
    k = 3..11; K = the first i with S_i > 0.95·S_{i+1}; K = 11 if there is none.  Components
    with < 10 codes are dropped.

**Small-component threshold and the number of codes.**  The "10" of both rules was set for
the reference's code bank (HumanAct12: 15 × 2,048 windows over 12 classes = 2,560 codes per
class; UESTC: 8 × 2,048 / 40 = 410).  With ``reference_codes`` given, the threshold is scaled
by ``n / reference_codes`` (n = the class's codes as drawn, duplicates included, as the
reference bank counts them; the component counts compared with it are of the distinct codes
fitted, as in the sampler): the code rule drops components of ``<= 10·n/reference_codes``
codes, the paper rule those of ``< 10·n/reference_codes``.  At the reference's count it is the
published 10; at 60 codes per class against 2,560 it drops only empty components (0.23), where
the unscaled 10 would merge every K >= 7 into one mode.  ``reference_codes=None`` keeps the
published 10; ODMO's sampler (:func:`repro.models.odmo.mode_preserving_codes`) passes its bank's
size against the reference's, so it is the published 10 at the paper scale only.
``"discovery"`` (ODMO's mode-discovery script ``cluster_multimodal``)
    the code rule's loop with K = k_break - 1, i.e. K = 8 when it never stops; no dropping.

A clustering with a single non-empty component has no silhouette; it scores -1 (the worst
value), so it is never preferred.  The fit uses the class's distinct codes
(``np.unique(axis=0)``, as the sampler does) unless ``unique=False``.

Mode-homogeneity (in %):  for each class c with real sequences G_c split into modes G(c, k)
by their codes,

    mode-APD(G_c) = sum_k |G(c,k)| · APD(G(c,k)) / |G_c|,
    homogeneity   = 100 · mean_c (APD(G_c) - mode-APD(G_c)) / APD(G_c).

Choices the paper leaves open (docs/metrics.md): every code of the class (duplicates
included) is assigned its most probable kept component; sequences whose component was dropped
are reassigned to their most probable *kept* component (``small_modes="reassign"``, default)
or left out of both APD terms (``"exclude"``); if every component is small, the largest is
kept.  APD is :func:`repro.metrics.apd.apd` (units of the motions; the ratio is unit-free).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from repro.errors import DataError
from repro.metrics.apd import pairwise_distance_sum
from repro.metrics.arrays import check_classes, flatten_sequences, float_array, int_array

Rule = Literal["code", "paper", "discovery"]


@dataclass(frozen=True)
class RuleSpec:
    k_min: int
    k_max: int
    small: float | None = None  # the published threshold ("<= 10" code, "< 10" paper; None:
    inclusive: bool = True      # only empty components go); True: count <= small is dropped

    def dropped(self, counts: np.ndarray, scale: float = 1.0) -> np.ndarray:
        """Mask of the components too small to keep, the threshold × ``scale``."""
        counts = np.asarray(counts)
        if self.small is None:
            return counts <= 0
        t = self.small * float(scale)
        return (counts <= t) if self.inclusive else (counts < t)


RULES: dict[str, RuleSpec] = {
    "code": RuleSpec(k_min=3, k_max=9, small=10.0, inclusive=True),
    "paper": RuleSpec(k_min=3, k_max=11, small=10.0, inclusive=False),  # "< 10"
    "discovery": RuleSpec(k_min=3, k_max=9),
}


def small_scale(n_codes: int, reference_codes: float | None) -> float:
    """Factor on the small-component threshold (module docstring): ``n / reference_codes``,
    1 when no reference count is given."""
    if reference_codes is None:
        return 1.0
    if reference_codes < 1:
        raise DataError(f"mode selection: reference_codes must be >= 1, got {reference_codes}")
    return float(n_codes) / float(reference_codes)


@dataclass(frozen=True)
class KSelection:
    """Chosen number of modes and the silhouette score of every K that was fitted."""

    k: int
    rule: str
    scores: tuple[tuple[int, float], ...]

    def __int__(self) -> int:
        return self.k

    def __index__(self) -> int:
        return self.k


def _rule(rule: str) -> RuleSpec:
    if rule not in RULES:
        raise DataError(f"mode selection: unknown rule {rule!r} (use one of {sorted(RULES)})")
    return RULES[rule]


def _fit_gmm(codes: np.ndarray, k: int, seed: int, n_init: int):
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.mixture import GaussianMixture
    from threadpoolctl import threadpool_limits

    gmm = GaussianMixture(n_components=k, covariance_type="full", init_params="kmeans",
                          n_init=n_init, random_state=seed)
    # one thread: these fits are tiny, and OpenMP k-means on a loaded 2-core machine spins
    # for seconds; it also keeps the result independent of the machine's thread count
    with threadpool_limits(limits=1), warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        labels = gmm.fit_predict(codes)
    return gmm, labels


def _silhouette(codes: np.ndarray, labels: np.ndarray) -> float:
    from sklearn.metrics import silhouette_score

    n_labels = np.unique(labels).size
    if n_labels < 2 or n_labels >= codes.shape[0]:
        return -1.0
    return float(silhouette_score(codes, labels, metric="euclidean"))


def _prepare_codes(codes, unique: bool) -> np.ndarray:
    c = float_array(codes, "codes", ndim=2, min_len=1)
    return np.unique(c, axis=0) if unique else c


def _select(codes: np.ndarray, rule: str, seed: int, n_init: int):
    spec = _rule(rule)
    k_max = min(spec.k_max, codes.shape[0] - 1)
    if k_max < spec.k_min:
        raise DataError(f"mode selection: {codes.shape[0]} distinct codes are too few for "
                        f"K >= {spec.k_min} (need at least {spec.k_min + 1})")
    scores: list[tuple[int, float]] = []
    models: dict[int, tuple] = {}
    chosen = None
    if rule == "paper":
        for k in range(spec.k_min, k_max + 1):
            models[k] = _fit_gmm(codes, k, seed, n_init)
            scores.append((k, _silhouette(codes, models[k][1])))
        for (ki, si), (_, sj) in zip(scores[:-1], scores[1:]):
            if si > 0.95 * sj:
                chosen = ki
                break
        if chosen is None:
            chosen = scores[-1][0]
    else:
        prev = -1.0
        chosen = None
        for k in range(spec.k_min, k_max + 1):
            models[k] = _fit_gmm(codes, k, seed, n_init)
            s = _silhouette(codes, models[k][1])
            scores.append((k, s))
            if s < 0.95 * prev:
                chosen = max(k - 1, spec.k_min)  # a degenerate k = 3 (S = -1) keeps K = 3
                break
            prev = s
        if chosen is None:
            chosen = k_max if rule == "code" else k_max - 1
            if chosen < spec.k_min:
                chosen = spec.k_min
            if chosen not in models:
                models[chosen] = _fit_gmm(codes, chosen, seed, n_init)
    return KSelection(k=int(chosen), rule=rule, scores=tuple(scores)), models[chosen]


def select_k(codes, rule: Rule = "code", seed: int = 0, unique: bool = True,
             n_init: int = 5) -> KSelection:
    """Number of modes of one class's latent codes (N, D) under ``rule`` (module docstring)."""
    c = _prepare_codes(codes, unique)
    return _select(c, rule, seed, n_init)[0]


@dataclass(frozen=True)
class ClassModes:
    """Modes of one class: K chosen, kept components and each code's mode index; ``mixture``
    (the fitted GaussianMixture of the K chosen) and ``counts`` (K,) (hard assignments of the
    fitted codes) let a sampler draw from the same fit (:func:`repro.models.odmo.mode_preserving_codes`)."""

    selection: KSelection
    kept: tuple[int, ...]
    assignment: np.ndarray  # (N,) component index per input code; -1 = excluded
    mixture: object = field(default=None, repr=False, compare=False)
    counts: np.ndarray | None = field(default=None, repr=False, compare=False)


def discover_modes(codes, rule: Rule = "code", seed: int = 0, unique: bool = True,
                   small_modes: Literal["reassign", "exclude"] = "reassign",
                   n_init: int = 5, reference_codes: float | None = None) -> ClassModes:
    """Select K, fit the GMM, drop small components (threshold scaled by ``n /
    reference_codes``, module docstring) and assign every code (duplicates too)."""
    all_codes = float_array(codes, "codes", ndim=2, min_len=1)
    fit_codes = np.unique(all_codes, axis=0) if unique else all_codes
    selection, (gmm, fit_labels) = _select(fit_codes, rule, seed, n_init)
    spec = _rule(rule)
    counts = np.bincount(fit_labels, minlength=selection.k)
    # reference_codes counts codes drawn (the reference bank, duplicates included): scale by n drawn
    kept = np.flatnonzero(~spec.dropped(counts, small_scale(all_codes.shape[0], reference_codes)))
    if kept.size == 0:
        kept = np.array([int(np.argmax(counts))])
    proba = gmm.predict_proba(all_codes)
    best = np.argmax(proba, axis=1)
    if small_modes == "reassign":
        assignment = kept[np.argmax(proba[:, kept], axis=1)]
    elif small_modes == "exclude":
        assignment = np.where(np.isin(best, kept), best, -1)
    else:
        raise DataError(f"small_modes must be 'reassign' or 'exclude', got {small_modes!r}")
    return ClassModes(selection=selection, kept=tuple(int(k) for k in kept), assignment=assignment,
                      mixture=gmm, counts=counts)


def _apd_of(x: np.ndarray) -> float:
    n = x.shape[0]
    return pairwise_distance_sum(x) / (n * (n - 1)) if n > 1 else 0.0


def mode_apd(motions, modes) -> tuple[float, float]:
    """``(APD(G_c), mode-APD(G_c))`` of one class's sequences given mode indices (-1 = left out)."""
    x = flatten_sequences(motions, "motions")
    m = int_array(modes, "modes", n=x.shape[0])
    inside = m >= 0
    x, m = x[inside], m[inside]
    if x.shape[0] == 0:
        raise DataError("mode-APD: no sequence is assigned to a mode")
    total = _apd_of(x)
    weighted = 0.0
    for k in np.unique(m):
        members = x[m == k]
        weighted += members.shape[0] * _apd_of(members)
    return total, weighted / x.shape[0]


@dataclass(frozen=True)
class ModeHomogeneityResult:
    """``value`` in %; per-class homogeneity (%), K and the APD terms behind it."""

    value: float
    per_class: tuple[float, ...]
    k_per_class: tuple[int, ...]
    apd: tuple[float, ...]
    mode_apd: tuple[float, ...]
    rule: str

    def __float__(self) -> float:
        return float(self.value)


def mode_homogeneity(motions, codes, labels, rule: Rule = "code", seed: int = 0,
                     n_classes: int | None = None, unique: bool = True,
                     small_modes: Literal["reassign", "exclude"] = "reassign",
                     n_init: int = 5, reference_codes: float | None = None) -> ModeHomogeneityResult:
    """ODMO Table 3 mode-homogeneity (%) of real sequences ``motions`` (N, T, J, 3) whose
    latent codes are ``codes`` (N, D) and classes ``labels`` (N,); see the module docstring."""
    x = flatten_sequences(motions, "motions")
    c = float_array(codes, "codes", ndim=2)
    if c.shape[0] != x.shape[0]:
        raise DataError(f"mode-homogeneity: {x.shape[0]} motions but {c.shape[0]} codes")
    y = int_array(labels, "labels", n=x.shape[0])
    if n_classes is None:
        n_classes = int(y.max()) + 1 if y.size else 0
    check_classes(y, n_classes, "labels")
    per_class, ks, apds, mapds = [], [], [], []
    for cls in range(n_classes):
        rows = np.flatnonzero(y == cls)
        if rows.size == 0:
            raise DataError(f"mode-homogeneity: class {cls} has no sequences")
        modes = discover_modes(c[rows], rule=rule, seed=seed, unique=unique,
                               small_modes=small_modes, n_init=n_init,
                               reference_codes=reference_codes)
        total, weighted = mode_apd(x[rows], modes.assignment)
        if total == 0.0:
            raise DataError(f"mode-homogeneity: class {cls} has APD 0 (identical sequences)")
        per_class.append(100.0 * (total - weighted) / total)
        ks.append(modes.selection.k)
        apds.append(total)
        mapds.append(weighted)
    return ModeHomogeneityResult(value=float(np.mean(per_class)), per_class=tuple(per_class),
                                 k_per_class=tuple(ks), apd=tuple(apds), mode_apd=tuple(mapds),
                                 rule=rule)
