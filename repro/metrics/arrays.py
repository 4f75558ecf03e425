"""Input checking shared by the metric functions: arrays or tensors in, float64 numpy out.

Every metric accepts numpy arrays or torch tensors (detached, moved to CPU).  A wrong shape,
an empty set or a non-finite value is bad input: it raises :class:`~repro.errors.DataError`
with one sentence naming the argument and the problem, never a numpy traceback.
"""

from __future__ import annotations

import numpy as np

from repro.errors import DataError


def to_numpy(x) -> np.ndarray:
    """A numpy view/copy of ``x`` (numpy array, torch tensor, list or scalar)."""
    if hasattr(x, "detach") and hasattr(x, "cpu"):  # torch.Tensor without importing torch
        x = x.detach().cpu().numpy()
    return np.asarray(x)


def float_array(x, name: str, ndim: int | tuple[int, ...] | None = None,
                min_len: int = 1, check_finite: bool = True) -> np.ndarray:
    """``x`` as a finite float64 array with ``ndim`` dimensions and at least ``min_len`` rows.

    ``check_finite=False`` leaves the NaN/inf check to the caller (who can do it more cheaply
    on a reduction, e.g. a row's sum of squares, which is non-finite iff the row is).
    """
    a = to_numpy(x)
    if a.dtype == object or not (np.issubdtype(a.dtype, np.number) or a.dtype == bool):
        raise DataError(f"{name}: expected numbers, got dtype {a.dtype}")
    a = a.astype(np.float64, copy=False)
    if ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        if a.ndim not in allowed:
            want = " or ".join(str(d) for d in allowed)
            raise DataError(f"{name}: expected a {want}-D array, got shape {a.shape}")
    if a.ndim >= 1 and a.shape[0] < min_len:
        raise DataError(f"{name}: needs at least {min_len} rows, got {a.shape[0]}")
    if check_finite and not np.all(np.isfinite(a)):
        raise DataError(f"{name}: contains NaN or infinite values")
    return a


def int_array(x, name: str, n: int | None = None) -> np.ndarray:
    """``x`` as a 1-D int64 array (of length ``n`` when given)."""
    a = to_numpy(x)
    if a.ndim != 1:
        raise DataError(f"{name}: expected a 1-D array of class indices, got shape {a.shape}")
    if a.size and not np.issubdtype(a.dtype, np.integer):
        if not np.all(np.equal(np.mod(a, 1), 0)):
            raise DataError(f"{name}: class indices must be integers")
    a = a.astype(np.int64, copy=False)
    if n is not None and a.shape[0] != n:
        raise DataError(f"{name}: expected {n} entries, got {a.shape[0]}")
    return a


def check_classes(labels: np.ndarray, n_classes: int, name: str) -> None:
    """Every label must lie in ``0 .. n_classes-1``."""
    if n_classes < 1:
        raise DataError(f"n_classes must be at least 1, got {n_classes}")
    if labels.size and (labels.min() < 0 or labels.max() >= n_classes):
        raise DataError(f"{name}: class indices must lie in 0..{n_classes - 1}, "
                        f"got {labels.min()}..{labels.max()}")


def flatten_sequences(motions, name: str, check_finite: bool = True) -> np.ndarray:
    """(N, T, J, 3), (N, T, D) or (N, D) -> (N, T·J·3) float64: one vector per sequence."""
    a = float_array(motions, name, ndim=(2, 3, 4), check_finite=check_finite)
    return a.reshape(a.shape[0], -1)
