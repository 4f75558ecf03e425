"""ODMO / Action2Motion fixed-length windows (ODMO, MM'22, Sec. 4.1 data; protocols.md §3.1).

Each epoch, every selected clip gives one window of ``T`` consecutive frames:

- ``len ≥ T``: ``start`` is drawn uniformly from ``0 .. len − T − 1``.  The reference code calls
  ``np.random.randint(0, len − T)`` (exclusive upper bound) and uses ``start = 0`` when
  ``len == T``, so the very last window is never used.  That is ``include_last=False``
  (default); ``include_last=True`` draws from ``0 .. len − T`` inclusive.
- ``len < T``: the whole clip, padded by repeating its last frame (``start = 0``).
- The window is re-centred: its first frame's root position is subtracted from every joint
  (positions only; no rotation anywhere: "rotate2xz" is a misnomer, protocols.md §3.1).  For a
  short clip this equals ODMO's "already at the origin" (the clip was centred on frame 0).

``valid`` = ``min(len, T)`` (the reference loader's returned length).  Randomness comes from an
explicit :class:`numpy.random.Generator`; :func:`epoch_windows` derives one per (seed, epoch).
Units: metres (whatever the ClipSet holds).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from repro.data.clipset import ClipSet
from repro.seeding import numpy_rng

__all__ = ["WindowBatch", "window_starts", "cut_windows", "odmo_windows", "epoch_windows",
           "motion_windows"]


@dataclass(frozen=True, eq=False)
class WindowBatch:
    """One window per selected clip.

    ``joints`` (N, T, J, 3) float32 re-centred positions; ``origin`` (N, 3) the subtracted root
    position (world); ``indices`` (N,) clip indices; ``starts`` (N,) first frame in the clip;
    ``valid`` (N,) real (unpadded) frames; ``labels`` (N,) action ids.
    """

    joints: np.ndarray
    origin: np.ndarray
    indices: np.ndarray
    starts: np.ndarray
    valid: np.ndarray
    labels: np.ndarray

    def __len__(self) -> int:
        return int(self.indices.shape[0])

    def flat(self) -> np.ndarray:
        """(N, T, J·3): ODMO / Action2Motion's flattened per-frame input."""
        n, t = self.joints.shape[:2]
        return self.joints.reshape(n, t, -1)


def window_starts(lengths: Sequence[int], window: int, rng: np.random.Generator, *,
                  include_last: bool = False) -> np.ndarray:
    """One start frame per clip (int64); 0 for clips no longer than the window (see module)."""
    if window < 1:
        raise ValueError(f"window must be at least 1 frame, got {window}")
    lens = np.asarray(lengths, dtype=np.int64).reshape(-1)
    if np.any(lens < 1):
        raise ValueError("every clip needs at least one frame")
    gap = np.maximum(lens - window, 0)
    high = gap + 1 if include_last else gap
    starts = np.zeros(lens.shape, dtype=np.int64)
    draw = high > 0
    if draw.any():
        starts[draw] = rng.integers(0, high[draw])
    return starts


def _rows(clipset: ClipSet, idx: np.ndarray, starts: np.ndarray, window: int) -> np.ndarray:
    lens = clipset.lengths[idx].astype(np.int64)
    local = starts[:, None] + np.arange(window, dtype=np.int64)[None, :]
    local = np.minimum(local, lens[:, None] - 1)
    return clipset.starts[idx].astype(np.int64)[:, None] + local


def cut_windows(clipset: ClipSet, indices: Sequence[int], starts: Sequence[int] | int, window: int,
                *, root_joint: int = 0, recenter: bool = True) -> WindowBatch:
    """Windows of ``window`` frames from given starts (padding short clips with their last
    frame), re-centred on the first frame's ``root_joint`` position."""
    idx = np.asarray(indices, dtype=np.int64).reshape(-1)
    st = np.broadcast_to(np.asarray(starts, dtype=np.int64), idx.shape).copy()
    lens = clipset.lengths[idx].astype(np.int64)
    if np.any(st < 0) or np.any(st >= lens):
        bad = int(np.flatnonzero((st < 0) | (st >= lens))[0])
        raise ValueError(f"clip {clipset.clip_names[idx[bad]]!r}: start {st[bad]} outside its "
                         f"{lens[bad]} frames")
    joints = np.asarray(clipset.joints[_rows(clipset, idx, st, window)], dtype=np.float32)
    origin = joints[:, 0, root_joint, :].copy() if recenter else np.zeros((len(idx), 3), np.float32)
    joints = joints - origin[:, None, None, :]
    return WindowBatch(joints=np.ascontiguousarray(joints), origin=origin, indices=idx, starts=st,
                       valid=np.minimum(lens - st, window), labels=clipset.labels[idx].copy())


def odmo_windows(clipset: ClipSet, indices: Sequence[int], window: int, rng: np.random.Generator,
                 *, include_last: bool = False, root_joint: int = 0) -> WindowBatch:
    """One random window per clip in ``indices`` (ODMO's ``__getitem__``, module docstring)."""
    idx = np.asarray(indices, dtype=np.int64).reshape(-1)
    starts = window_starts(clipset.lengths[idx], window, rng, include_last=include_last)
    return cut_windows(clipset, idx, starts, window, root_joint=root_joint)


def epoch_windows(clipset: ClipSet, indices: Sequence[int], window: int, seed: int, epoch: int,
                  *, include_last: bool = False, root_joint: int = 0) -> WindowBatch:
    """:func:`odmo_windows` with a generator derived from ``(seed, "windows", epoch)``, so
    every epoch draws fresh windows and the same (seed, epoch) gives the same bytes."""
    rng = numpy_rng(seed, "windows", int(epoch))
    return odmo_windows(clipset, indices, window, rng, include_last=include_last,
                        root_joint=root_joint)


def motion_windows(clipset: ClipSet, indices: Sequence[int], starts: Sequence[int] | int,
                   window: int):
    """The same windows as rotation-based :class:`~repro.motion.motion.Motion` (padded with
    the last frame, root translation re-centred on the window's first frame, rotations kept),
    with the :class:`~repro.motion.canon.CanonParams` that undo the re-centring."""
    from repro.motion.canon import root_to_origin
    from repro.motion.motion import Motion

    m = Motion.from_clipset(clipset, indices, starts, window, pad=True)
    return root_to_origin(m, 0)
