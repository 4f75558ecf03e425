"""Average pairwise distance (APD) and normalised APD (n-APD), vectorised.

ODMO §4.2.2 (APD formula after [43]; n-APD definition) and protocols.md §3.6:

    APD(A) = 1 / (N(N-1)) · sum_i sum_{j != i} ( sum_t ||m_t^(i) - m_t^(j)||^2 )^(1/2)

i.e. every sequence is flattened to one T·J·3 vector and APD is the mean Euclidean distance
over ordered pairs; the zero diagonal is included in the sum and N(N-1) divides, exactly as
ODMO's ``compute_APD`` (``sklearn.metrics.pairwise_distances``).  A set of one sequence has
APD 0 (the reference returns the bare sum).  Units: those of the input (metres for joints in
``repro``; ODMO's MoCap is in metres/20).

    n-APD(I) = 100 · (1/|C|) · sum_c APD(gen_c) / APD(real_c)      (in %)

Speed: distances come from one Gram matrix (BLAS ``syrk``) in float64,
d_ij^2 = |x_i|^2 + |x_j|^2 - 2 x_i·x_j, processed in row blocks to bound memory.  The rounding
error of d_ij^2 is about 1e-16·(|x_i|^2 + |x_j|^2); pairs where that could matter (d^2 below
1e-6 of |x_i|^2 + |x_j|^2, e.g. duplicated windows) are recomputed exactly from the differences,
so every distance carries a relative error below ~1e-10 and duplicates read as exactly 0.  The
data are not mean-centred first: in float64 that buys nothing measurable for motions within a
few hundred metres of the origin and costs a full copy.  See
``benchmarks/bench_apd.py`` and docs/metrics.md for timings.
"""

from __future__ import annotations

import numpy as np

from repro.errors import DataError
from repro.metrics.arrays import check_classes, flatten_sequences, int_array

_BLOCK_ROWS = 4096
_CANCEL_TOL = 1e-6


def pairwise_distance_sum(x: np.ndarray) -> float:
    """Sum of Euclidean distances over all ordered pairs (i, j) of rows of a 2-D float array."""
    n = x.shape[0]
    if n < 2:
        return 0.0
    xc = np.ascontiguousarray(x, dtype=np.float64)
    sq = np.einsum("ij,ij->i", xc, xc)
    if not np.all(np.isfinite(sq)):  # a row's sum of squares is finite iff the row is
        raise DataError("APD: motions contain NaN or infinite values (or values too large to square)")
    coarse = _CANCEL_TOL * 2.0 * float(sq.max())  # no cancelling pair can lie above this
    total = 0.0
    for s in range(0, n, _BLOCK_ROWS):
        e = min(n, s + _BLOCK_ROWS)
        d2 = xc[s:e] @ xc.T
        d2 *= -2.0
        d2 += sq[s:e, None]
        d2 += sq[None, :]
        rows, cols = np.nonzero(d2 <= coarse)
        keep = (rows + s != cols) & (d2[rows, cols] <= _CANCEL_TOL * (sq[rows + s] + sq[cols]))
        rows, cols = rows[keep], cols[keep]
        for c0 in range(0, rows.size, 4096):  # exact recomputation of cancelling pairs
            r, c = rows[c0:c0 + 4096], cols[c0:c0 + 4096]
            diff = xc[r + s] - xc[c]
            d2[r, c] = np.einsum("ij,ij->i", diff, diff)
        idx = np.arange(s, e)
        d2[idx - s, idx] = 0.0
        np.maximum(d2, 0.0, out=d2)
        np.sqrt(d2, out=d2)
        total += float(d2.sum())
    return total


def apd(motions) -> float:
    """APD of a set of sequences: (N, T, J, 3), (N, T, D) or (N, D); N >= 1 (see module)."""
    x = flatten_sequences(motions, "motions", check_finite=False)
    n = x.shape[0]
    if n < 2:
        if not np.all(np.isfinite(x)):
            raise DataError("APD: motions contain NaN or infinite values")
        return 0.0
    return pairwise_distance_sum(x) / (n * (n - 1))


def per_class_apd(motions, labels, n_classes: int) -> np.ndarray:
    """(C,) APD of each class's sequences; a class with no sequence is an error."""
    x = flatten_sequences(motions, "motions")
    y = int_array(labels, "labels", n=x.shape[0])
    check_classes(y, n_classes, "labels")
    counts = np.bincount(y, minlength=n_classes)
    if (counts == 0).any():
        raise DataError(f"APD: classes {np.flatnonzero(counts == 0).tolist()} have no sequences")
    out = np.empty(n_classes)
    for c in range(n_classes):
        members = x[y == c]
        n = members.shape[0]
        out[c] = pairwise_distance_sum(members) / (n * (n - 1)) if n > 1 else 0.0
    return out


def n_apd(gen, gen_labels, real, real_labels, n_classes: int) -> float:
    """n-APD in %: the mean over classes of APD(generated_c) / APD(real_c), times 100.

    ODMO §4.2.2; protocols §3.6 (one generated set against its paired real set).
    """
    g = per_class_apd(gen, gen_labels, n_classes)
    r = per_class_apd(real, real_labels, n_classes)
    zero = np.flatnonzero(r == 0.0)
    if zero.size:
        raise DataError(f"n-APD: real APD is 0 for classes {zero.tolist()} (fewer than two "
                        "distinct real sequences); the ratio is undefined")
    return float(100.0 * np.mean(g / r))
