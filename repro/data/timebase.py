"""The one place where seconds become frames (and where a frame rate becomes a subsampling step).

Annotations such as BABEL's segments are given in seconds (``start_t``, ``end_t``); motions are
arrays of frames at a source rate (AMASS ``mocap_framerate``: 60, 100, 120, 150 or 250 Hz).
Every conversion in ``repro`` goes through :func:`seconds_to_frame`, so one rule holds
everywhere and is tested once.

Rounding rule (the default, ``"trunc"``): ``frame = int(t * fps)``, i.e. truncation toward zero,
which for the non-negative times of annotations is the floor.  This is exactly what MultiAct's
reference loader does for BABEL (``int(start_t * mocap_framerate)`` and the same for ``end_t``,
``[MA] data/datasets/BABEL.py``), and so it is what produced MultiAct's printed numbers.
Applying the *same* rule to both ends of a segment keeps abutting segments abutting: the end
frame of one segment is the start frame of the next whenever their shared boundary is the same
number of seconds.  Segments are half-open frame ranges ``[start, stop)``.

Other rules, selectable where a caller needs them:

- ``"floor"``: like ``"trunc"`` but tolerant of binary floating-point artefacts: a product that
  lies within ``1e-6`` frames *below* an integer (``0.29 * 100 = 28.999999999999996``) counts
  as that integer.  ``"trunc"`` gives 28 there, as the reference code does.
- ``"round"``: nearest frame, halves away from zero (not Python's banker's rounding).
- ``"ceil"``: the first frame at or after ``t`` (same 1e-6 tolerance, upward).

Units: ``t`` in seconds, ``fps`` in frames per second (Hz), frames are 0-based indices.
"""

from __future__ import annotations

import math
from typing import Literal

Rounding = Literal["trunc", "floor", "round", "ceil"]
ROUNDINGS: tuple[str, ...] = ("trunc", "floor", "round", "ceil")

#: Tolerance (in frames) of the ``"floor"`` and ``"ceil"`` rules for float artefacts.
FRAME_TOLERANCE = 1e-6


def _check_rate(fps: float) -> float:
    fps = float(fps)
    if not math.isfinite(fps) or fps <= 0:
        raise ValueError(f"frame rate must be a positive number of frames per second, got {fps!r}")
    return fps


def seconds_to_frame(t: float, fps: float, rounding: Rounding = "trunc") -> int:
    """The frame index (0-based) at time ``t`` seconds of a motion sampled at ``fps`` Hz.

    See the module docstring for the rounding rules; the default ``"trunc"`` is MultiAct's
    ``int(t * fps)``.  Negative or non-finite ``t`` is refused (annotations start at 0 s).
    """
    fps = _check_rate(fps)
    t = float(t)
    if not math.isfinite(t) or t < 0:
        raise ValueError(f"time must be a finite number of seconds >= 0, got {t!r}")
    x = t * fps
    if rounding == "trunc":
        return int(x)
    if rounding == "floor":
        return int(math.floor(x + FRAME_TOLERANCE))
    if rounding == "ceil":
        return int(math.ceil(x - FRAME_TOLERANCE))
    if rounding == "round":
        return int(math.floor(x + 0.5))
    raise ValueError(f"unknown rounding {rounding!r}; choose one of {', '.join(ROUNDINGS)}")


def segment_frames(start_t: float, end_t: float, fps: float, n_frames: int | None = None,
                   rounding: Rounding = "trunc") -> tuple[int, int]:
    """Half-open frame range ``(start, stop)`` of the segment ``[start_t, end_t]`` seconds.

    Both ends use the same ``rounding`` (see module docstring).  When ``n_frames`` (the clip's
    length in frames) is given, both ends are clamped to ``[0, n_frames]``: annotations often
    end a few milliseconds past the last frame (BABEL: ``end_t = 3.834`` on a 3.83 s clip).
    The result may be empty (``start == stop``) for a segment shorter than one frame; callers
    decide whether to drop it (MultiAct drops such segments).
    """
    if float(end_t) < float(start_t):
        raise ValueError(f"segment ends before it starts: start_t={start_t!r}, end_t={end_t!r}")
    start = seconds_to_frame(start_t, fps, rounding)
    stop = seconds_to_frame(end_t, fps, rounding)
    if n_frames is not None:
        if n_frames < 0:
            raise ValueError(f"n_frames must be >= 0, got {n_frames}")
        start = min(start, n_frames)
        stop = min(stop, n_frames)
    return start, stop


def frames_to_seconds(frame: int, fps: float) -> float:
    """Time in seconds of frame index ``frame`` at ``fps`` Hz (the inverse mapping, exact)."""
    return float(frame) / _check_rate(fps)


def resampled_frames(n_frames: int, src_fps: float, dst_fps: float) -> int:
    """How many frames a clip of ``n_frames`` at ``src_fps`` has once resampled to ``dst_fps``
    (:func:`repro.motion.resample.frame_positions`' count, ``floor((T − 1)·dst/src) + 1``: no
    extrapolation past the last frame), computed without allocating anything, so that a cap on
    the result can be checked before a clip is converted (issue 29)."""
    src_fps, dst_fps = _check_rate(src_fps), _check_rate(dst_fps)
    if n_frames < 1:
        raise ValueError(f"n_frames must be >= 1, got {n_frames}")
    return int(math.floor((n_frames - 1) / (src_fps / dst_fps) + 1e-9)) + 1


def subsample_step(source_fps: float, target_fps: float = 20.0) -> int:
    """MultiAct's subsampling step: ``int(round(source_fps) / target_fps)``, at least 1.

    MultiAct (``[MA] data/datasets/BABEL.py``) rounds ``mocap_framerate`` to an integer and keeps
    every ``step``-th frame, so 120 Hz -> 6, 60 -> 3, 100 -> 5, but 150 -> 7 and 250 -> 12: the
    effective rate (:func:`effective_fps`) is then not exactly 20 fps (21.43 and 20.83).
    """
    source_fps = _check_rate(source_fps)
    target_fps = _check_rate(target_fps)
    return max(1, int(round(source_fps) / target_fps))


def effective_fps(source_fps: float, target_fps: float = 20.0) -> float:
    """The frame rate actually obtained by :func:`subsample_step` (source rate / step)."""
    return _check_rate(source_fps) / subsample_step(source_fps, target_fps)
