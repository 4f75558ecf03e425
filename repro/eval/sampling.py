"""Fixed-length windows cut from a ClipSet for training and testing the evaluators.

Action2Motion / ODMO convention (protocols.md §3.1): a window of ``T`` frames starts at a
uniformly drawn frame of a clip; a clip shorter than ``T`` is padded by repeating its last
frame; the window is re-centred on its first frame's root (:mod:`repro.data.windows`).
Choices recorded here:

- the start is drawn by :func:`repro.data.windows.odmo_windows`; ``include_last`` (setting,
  default False as in the reference) also allows the clip's very last window;
- class-balanced training draws (ODMO's WeightedRandomSampler, class weight ∝ 1/count) pick a
  class uniformly, then a clip of that class uniformly: the same distribution over clips;
- test windows are deterministic: per clip, evenly spaced starts ``stride`` frames apart
  (ends included), so every test frame is seen.

Windows come back as joints (N, T, J, 3) in metres, re-centred, plus their valid lengths (N,);
:func:`repro.eval.features.to_model_input` applies the evaluators' input convention.
"""

from __future__ import annotations

import numpy as np

from repro.data.clip_draws import balanced_clips, per_class_clips
from repro.data.clipset import ClipSet
from repro.data.windows import cut_windows, odmo_windows


def _out(batch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return batch.joints, batch.valid.astype(np.int64), batch.labels.astype(np.int64)


def random_windows(clipset: ClipSet, pool: np.ndarray, n: int, window: int, rng: np.random.Generator,
                   *, class_balanced: bool = True, include_last: bool = False
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` random windows (joints (n, T, J, 3) re-centred, valid lengths, labels)."""
    clips = balanced_clips(clipset, pool, n, rng,
                           recipe="weights" if class_balanced else "uniform")
    return _out(odmo_windows(clipset, clips, window, rng, include_last=include_last))


def per_class_windows(clipset: ClipSet, pool: np.ndarray, per_class: int, window: int,
                      rng: np.random.Generator, *, include_last: bool = False
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exactly ``per_class`` windows of every class present in ``pool`` (clips drawn uniformly
    with replacement within the class, random starts), classes in index order (ODMO's real
    reference sets, protocols.md §3.2)."""
    clips = per_class_clips(clipset, pool, per_class, rng)
    return _out(odmo_windows(clipset, clips, window, rng, include_last=include_last))


def tiling_windows(clipset: ClipSet, pool: np.ndarray, window: int, stride: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Deterministic windows covering every clip of ``pool``: starts evenly spaced at most
    ``stride`` apart from 0 to ``len − T`` (one window at 0 for short clips).
    Returns (joints, lengths, labels, clip index per window)."""
    pool = np.asarray(pool, dtype=np.int64)
    clips, starts = [], []
    for i in pool:
        span = max(int(clipset.lengths[i]) - window, 0)
        k = 1 + -(-span // stride)
        s = np.unique(np.round(np.linspace(0, span, k)).astype(np.int64))
        clips.append(np.full(s.size, i, dtype=np.int64))
        starts.append(s)
    clips = np.concatenate(clips) if clips else np.zeros(0, np.int64)
    starts = np.concatenate(starts) if starts else np.zeros(0, np.int64)
    joints, lengths, labels = _out(cut_windows(clipset, clips, starts, window))
    return joints, lengths, labels, clips
