"""Memorisation and fidelity/diversity columns: nearest-training distance and PRDC.

**These are harness columns.  None of the reproduced papers (Neural Marionette, MultiAct,
ODMO) reports them**; they sit next to the papers' metrics so that a reviewer can tell a
generator that models the data from one that replays it.

Why they are needed.  FID compares only the mean and covariance of recogniser features, and
Diversity/Multimodality only spreads of features.  A "generator" that returns training clips
verbatim reproduces the training distribution exactly, so it gets the best possible FID_train
(and a good FID_test), real-data Diversity and the recogniser's real-data accuracy: every
paper metric rewards copying.  The numbers here make copying visible.

Nearest-training distance (:func:`nearest_distances`, :func:`masked_nearest_rms`).  For each
generated sample, the distance to its closest training sample: in feature units for feature
vectors, in metres (root-mean-square per-joint distance over the valid frames) for joint-space
motion windows.  A copier scores ~0 for every sample.  The scale of "close" is set by real
data: read the generated distribution against the same statistic for held-out real samples
(test split → training split).  Clearly smaller than that baseline means near-copies.

PRDC (:func:`prdc`): precision and recall with k-NN balls (Kynkäänniemi, Karras, Laine,
Lehtinen, Aila, "Improved Precision and Recall Metric for Assessing Generative Models",
NeurIPS 2019, §2), density and coverage (Naeem, Oh, Uh, Choi, Yoo, "Reliable Fidelity and
Diversity Metrics for Generative Models", ICML 2020, §3).  With r_k(x) the distance from x to
its k-th nearest neighbour in its own set (itself excluded) and B(x, r) the closed ball:

- precision = fraction of fake samples inside at least one real ball B(x, r_k(x)):
  **fidelity**, how much of the output looks like real data.  In [0, 1].
- recall = fraction of real samples inside at least one fake ball B(y, r_k(y)):
  **diversity**, how much of the real data the output reaches.  In [0, 1].  Inflated by fake
  outliers (their balls are large), which is what coverage fixes.
- density = (1 / (k·M)) · Σ_fake Σ_real 1[y ∈ B(x, r_k(x))]: fidelity that counts *how many*
  real balls hold each fake sample.  Not capped at 1: > 1 means fakes crowd into dense regions
  of the real data (e.g. one mode rendered over and over); expectation 1 when fake and real are
  drawn from the same distribution (Naeem et al., Lemma 1).
- coverage = fraction of real samples whose nearest fake sample lies inside their own ball:
  **mode coverage**, robust to fake outliers.  In [0, 1]; for identical distributions and
  M = N it is ≈ 1 − 2^−k, not 1 (Naeem et al., Lemma 2).

A mode-dropping generator scores high precision and low recall/coverage.  A copier scores
precision = recall = coverage = 1 and density (k+1)/k (each real ball holds its own copy and
the copies of its k neighbours, all on or inside the boundary): PRDC does *not* flag
memorisation; the nearest-training distance does.

"Inside" is ``<=`` throughout, as in Kynkäänniemi et al.'s definition and reference code.
Naeem et al.'s reference code (``prdc`` package) uses strict ``<`` for all four numbers; the two
differ only on exact ties (probability zero for continuous features), i.e. for copied or
duplicated samples: with ``<`` an exact copy gets density 1, and duplicates inside the real set
(r_k = 0) are outside every ball.  To make ties exact rather than round-off dependent, PRDC
distances are computed by differences (``scipy.spatial.distance.cdist``), which gives exact
zeros for identical vectors and the same value for the same pair wherever it is computed.

All inputs may be numpy arrays or torch tensors; everything is float64; bad input raises
:class:`~repro.errors.DataError`.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.distance import cdist
from sklearn.neighbors import NearestNeighbors

from repro.errors import DataError
from repro.metrics.arrays import float_array, to_numpy

QUERY_CHUNK = 256  # queries per matrix product in masked_nearest_rms
_PAIR_BUDGET = 4_000_000  # distance-matrix entries per chunk in prdc (32 MB of float64)


def _feature_pair(a, b, name_a: str, name_b: str, what: str) -> tuple[np.ndarray, np.ndarray]:
    x = float_array(a, name_a, ndim=2, min_len=1)
    y = float_array(b, name_b, ndim=2, min_len=1)
    if x.shape[1] < 1:
        raise DataError(f"{what}: {name_a} has no feature columns (shape {x.shape})")
    if x.shape[1] != y.shape[1]:
        raise DataError(f"{what}: feature dimensions differ ({name_a} {x.shape[1]}, "
                        f"{name_b} {y.shape[1]})")
    return x, y


def nearest_distances(queries: np.ndarray, bank: np.ndarray) -> np.ndarray:
    """Euclidean distance from each row of ``queries`` (N, D) to its nearest row of ``bank``
    (M, D): float64 (N,), in the features' units.

    Exact brute-force search (scikit-learn ``NearestNeighbors``, ``algorithm="brute"``); the
    distance to the neighbour found is then recomputed from the difference vector, so an exact
    copy reads 0 rather than the square root of round-off.
    """
    q, b = _feature_pair(queries, bank, "queries", "bank", "nearest_distances")
    nn = NearestNeighbors(n_neighbors=1, algorithm="brute").fit(b)
    idx = nn.kneighbors(q, return_distance=False)[:, 0]
    return np.linalg.norm(q - b[idx], axis=1)


def _lengths(query_lengths, n: int, w: int) -> np.ndarray:
    a = to_numpy(query_lengths)
    if a.ndim != 1 or a.shape[0] != n:
        raise DataError(f"masked_nearest_rms: query_lengths must have shape ({n},), "
                        f"got {a.shape}")
    integer = np.issubdtype(a.dtype, np.integer)
    if not (integer or np.issubdtype(a.dtype, np.floating)):
        raise DataError(f"masked_nearest_rms: query_lengths must be integers, got dtype {a.dtype}")
    if not integer and not (np.all(np.isfinite(a)) and np.all(np.equal(np.mod(a, 1), 0))):
        raise DataError("masked_nearest_rms: query_lengths must be whole numbers of frames")
    a = a.astype(np.int64)
    if a.min() < 1 or a.max() > w:
        raise DataError(f"masked_nearest_rms: query_lengths must lie in 1..{w} (the window "
                        f"length), got {a.min()}..{a.max()}")
    return a


def masked_nearest_rms(queries: np.ndarray, query_lengths: np.ndarray,
                       bank: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest bank window of each query motion window, in joint space.

    ``queries`` (N, W, J, 3) joint positions in metres, of which the first ``query_lengths[n]``
    frames (1..W) are valid; frames at or beyond that length are ignored and may hold anything,
    NaN included.  ``bank`` (M, W, J, 3), every frame valid (the caller pads).  The distance
    between query n (valid length L) and bank window m is the root-mean-square per-joint
    distance over the query's valid frames, in metres::

        d(n, m) = sqrt( sum_{t < L} ||q_{n,t} - b_{m,t}||^2 / (L · J) )

    Returns ``(distances, indices)``: float64 (N,) and int64 (N,), the nearest window's
    distance and its row in ``bank`` (the first one on a tie).

    The search expands d^2 = sum_t m_t|q_t|^2 - 2 sum_t m_t q_t·b_t + sum_t m_t|b_t|^2 into
    matrix products, ``QUERY_CHUNK`` queries at a time (memory O(chunk · M)), clamping
    round-off negatives to 0; the reported distance of the window found is then recomputed
    from the frame differences, so a truncated copy reads 0, not sqrt(round-off).
    """
    q = float_array(queries, "queries", ndim=4, min_len=1, check_finite=False)
    b = float_array(bank, "bank", ndim=4, min_len=1)
    if q.shape[1:] != b.shape[1:]:
        raise DataError(f"masked_nearest_rms: queries are (N, W, J, C) = {q.shape} but the bank "
                        f"is {b.shape}; window length, joints and coordinates must agree")
    n, w, j = q.shape[0], q.shape[1], q.shape[2]
    if w < 1 or j < 1 or q.shape[3] < 1:
        raise DataError(f"masked_nearest_rms: empty windows (queries shape {q.shape})")
    lengths = _lengths(query_lengths, n, w)
    mask = np.arange(w)[None, :] < lengths[:, None]  # (N, W)
    q = np.where(mask[:, :, None, None], q, 0.0)  # invalid frames -> 0 (drops NaN garbage)
    if not np.all(np.isfinite(q)):
        raise DataError("masked_nearest_rms: queries contain NaN or infinite values in their "
                        "valid frames")

    m = b.shape[0]
    b_flat = b.reshape(m, -1)  # (M, W·J·C)
    b_frame_sq = (b * b).reshape(m, w, -1).sum(axis=2)  # (M, W): |b_{m,t}|^2
    q_flat = q.reshape(n, -1)
    denom = (lengths * j).astype(np.float64)

    indices = np.empty(n, dtype=np.int64)
    for start in range(0, n, QUERY_CHUNK):
        stop = min(start + QUERY_CHUNK, n)
        qc = q_flat[start:stop]
        d2 = (qc * qc).sum(axis=1)[:, None] - 2.0 * (qc @ b_flat.T) \
            + mask[start:stop].astype(np.float64) @ b_frame_sq.T
        np.maximum(d2, 0.0, out=d2)  # the 1/(L·J) scale is per row, so it cannot move the argmin
        indices[start:stop] = np.argmin(d2, axis=1)

    diff = q - np.where(mask[:, :, None, None], b[indices], 0.0)
    distances = np.sqrt((diff * diff).reshape(n, -1).sum(axis=1) / denom)
    return distances, indices


def _pairwise_chunks(x: np.ndarray, y: np.ndarray):
    """Yield ``(start, stop, cdist(x[start:stop], y))`` with bounded matrix size."""
    rows = max(1, _PAIR_BUDGET // max(1, y.shape[0]))
    for start in range(0, x.shape[0], rows):
        stop = min(start + rows, x.shape[0])
        yield start, stop, cdist(x[start:stop], y, metric="euclidean")


def _kth_neighbour_radii(x: np.ndarray, k: int) -> np.ndarray:
    """r_k(x_i): distance to the k-th nearest other sample (row i's own 0 is the smallest)."""
    radii = np.empty(x.shape[0])
    for start, stop, d in _pairwise_chunks(x, x):
        radii[start:stop] = np.partition(d, k, axis=1)[:, k]
    return radii


def prdc(real: np.ndarray, fake: np.ndarray, k: int = 5) -> dict[str, float]:
    """Precision, recall, density and coverage of ``fake`` (M, D) against ``real`` (N, D).

    Definitions in the module docstring (Kynkäänniemi et al. 2019; Naeem et al. 2020), with
    closed balls (``<=``).  Both sets need more than ``k`` samples.  Returns
    ``{"precision", "recall", "density", "coverage"}`` as Python floats.  Memory is bounded by
    computing the (N, M) distance matrix in row chunks.
    """
    x, y = _feature_pair(real, fake, "real", "fake", "prdc")
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise DataError(f"prdc: k must be a positive integer, got {k!r}")
    k = int(k)
    if x.shape[0] <= k or y.shape[0] <= k:
        raise DataError(f"prdc: both sets need more than k = {k} samples, got {x.shape[0]} real "
                        f"and {y.shape[0]} fake")
    r_real = _kth_neighbour_radii(x, k)  # (N,)
    r_fake = _kth_neighbour_radii(y, k)  # (M,)

    fake_in_real_balls = np.zeros(y.shape[0], dtype=np.int64)  # per fake: real balls holding it
    real_in_fake_ball = np.zeros(x.shape[0], dtype=bool)
    nearest_fake = np.empty(x.shape[0])
    for start, stop, d in _pairwise_chunks(x, y):  # d: (real chunk, M)
        fake_in_real_balls += (d <= r_real[start:stop, None]).sum(axis=0)
        real_in_fake_ball[start:stop] = (d <= r_fake[None, :]).any(axis=1)
        nearest_fake[start:stop] = d.min(axis=1)

    return {
        "precision": float(np.mean(fake_in_real_balls > 0)),
        "recall": float(np.mean(real_in_fake_ball)),
        "density": float(fake_in_real_balls.sum() / (k * y.shape[0])),
        "coverage": float(np.mean(nearest_fake <= r_real)),
    }
