"""The compiled reader of a BVH MOTION block (issue 31): one pass over its bytes.

:func:`read_rows` fills a ``(rows, cols)`` float64 array from whitespace-separated decimal
numbers, or answers ``None`` and leaves the decision to the general parser
(:func:`repro.data.bvh.parse_bvh`: ``np.loadtxt`` and, on failure, a line-by-line diagnosis
naming the culprit).  It takes only what it can read *exactly*: an optional sign, at most 18
digits with at most one decimal point, no exponent, and a significand below 2^53.  Each such
number is ``m / 10**k`` with ``m`` and ``10**k`` both exact doubles, so one IEEE division
rounds it correctly (Clinger's fast path, "How to read floating point numbers accurately",
PLDI 1990): the same double as Python's ``float`` and ``np.loadtxt``, bit for bit
(``-0.000000`` included).  Anything else (an exponent, ``nan``, more digits, a stray
character, a row of the wrong length, too few or too many rows) makes it answer ``None``.

Motion capture writes fixed-point values (the stand-in: six decimals), so in practice every
file takes this path; it reads the MOTION block about 10x faster than ``np.loadtxt`` (numbers
in ``docs/data.md``, "Issue 31").  The kernel is compiled by numba once per process, from
numba's on-disk cache where it can write one (beside this module, else the user's cache
folder); ``numba`` is imported only when a MOTION block is read.  Where numba is missing or
cannot compile (no writable cache folder, ``NUMBA_DISABLE_JIT``), every block goes to the
general parser: slower, the same values.
"""

from __future__ import annotations

import threading
import warnings

import numpy as np

#: Exact powers of ten: every 10**k with k <= 22 is a double (5**22 < 2**53).
_POW10 = np.array([10.0 ** k for k in range(23)])
_KERNEL = None  # None: not built yet; False: unavailable in this process
_KERNEL_LOCK = threading.Lock()


def _compile():
    from numba import config, njit

    if config.DISABLE_JIT:  # the plain Python function would be far slower than np.loadtxt
        return False

    @njit(cache=True, nogil=True)
    def kernel(buf, out, pow10):  # pragma: no cover - compiled; exercised through read_rows
        n_rows, n_cols = out.shape
        n = buf.shape[0]
        i = 0
        row = 0
        col = 0
        while i < n:
            c = np.int64(buf[i])
            if c == 10:  # line end: a row is complete, or the line was blank
                if col != 0:
                    if col != n_cols:
                        return False
                    row += 1
                    col = 0
                i += 1
                continue
            if c == 32 or c == 9:
                i += 1
                continue
            if row >= n_rows:
                return False
            if col >= n_cols:
                return False
            neg = c == 45
            if c == 45 or c == 43:
                i += 1
            m = 0
            digits = 0
            frac = 0
            point = False
            while i < n:
                c = np.int64(buf[i])
                if 48 <= c <= 57:
                    digits += 1
                    if digits > 18:  # m stays below 10**18, inside int64
                        return False
                    m = m * 10 + (c - 48)
                    if point:
                        frac += 1
                elif c == 46 and not point:
                    point = True
                else:
                    break
                i += 1
            if digits == 0:
                return False
            if i < n and not (buf[i] == 32 or buf[i] == 9 or buf[i] == 10):
                return False  # an exponent, a letter, a second point: not ours to read
            if m >= 9007199254740992:  # 2**53: m would not be an exact double
                return False
            v = np.float64(m) / pow10[frac]
            out[row, col] = -v if neg else v
            col += 1
        if col != 0:
            if col != n_cols:
                return False
            row += 1
        return row == n_rows

    probe = np.empty((1, 2))  # compile (or load from the cache) now, inside the caller's try
    if not (kernel(np.frombuffer(b"-1.5 2\n", dtype=np.uint8), probe, _POW10)
            and probe.tolist() == [[-1.5, 2.0]]):
        raise RuntimeError("the compiled reader failed its self-check")
    return kernel


def _kernel():
    global _KERNEL
    if _KERNEL is None:
        with _KERNEL_LOCK:
            if _KERNEL is None:
                try:
                    _KERNEL = _compile()
                except ImportError:  # a declared dependency; without it the general parser reads
                    _KERNEL = False
                except Exception as e:  # noqa: BLE001 - e.g. no writable cache folder
                    warnings.warn(f"repro: the compiled BVH reader is unavailable ({e}); MOTION "
                                  f"blocks are read by np.loadtxt (same values, slower)",
                                  RuntimeWarning, stacklevel=3)
                    _KERNEL = False
    return _KERNEL


def read_rows(body, n_rows: int, n_cols: int) -> np.ndarray | None:
    """The ``(n_rows, n_cols)`` values of ``body`` (bytes-like, LF line ends), or ``None`` when
    the block is not in the exactly readable subset (module docstring) or the compiled kernel
    is unavailable."""
    kernel = _kernel()
    if kernel is False or n_rows <= 0 or n_cols <= 0:
        return None
    buf = np.frombuffer(body, dtype=np.uint8)
    out = np.empty((n_rows, n_cols), dtype=np.float64)
    if not kernel(buf, out, _POW10):
        return None
    return out
