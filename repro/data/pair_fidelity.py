"""Two numbers that say whether MultiAct's ``[S_p, T, S_c]`` samples test what the paper tests
(issue 26, the card's ``pairs`` object; MultiAct AAAI'23, "Comparison with state-of-the-art
methods (Transition)" and supp. "Training data for MACVAE").

:func:`pair_fidelity` ``(seqs, source=None)`` returns exactly two keys:

- ``sp_heading_deg_median``: the median over the training pairs (``source.train_items``) of the
  absolute heading (degrees, 0..180) of ``S_p``'s last frame against ``S_c``'s canonical facing.
  ``S_c``'s canonical frame is the frame a label-only generator's output lives in before any
  placement (ACTOR's own frame: the previous pose at the origin facing +Z; MultiAct Table 3's
  "w. o. align" leaves ``Ŝ_c`` there).  Pairs are cut from their sequence's world frame
  (:mod:`repro.data.pairs_build`), so this is ``S_p``'s last-frame body heading
  (:func:`repro.motion.heading.motion_heading`, ``lateral`` axis, the face-front convention of
  MultiAct's reference ``face_front_align``) in that frame.  Near 0 means ``S_p`` already ends
  facing the way an unaligned ``Ŝ_c`` starts, so "w. align" and "w. o. align" cannot differ;
  in a recording (BABEL over AMASS) it is spread over (−180°, 180°] (median ≈ 90°).
- ``transition_linear_ratio``: ``median_T d(T) / median_W d(W)``.  ``d(x)`` of a run of ``n``
  frames is the mean over its interior frames ``1 .. n−2`` and over joints of the distance (cm)
  of the FK joint positions from the linear in-between of its first and last frame
  (``x_0 + (x_{n−1} − x_0)·k/(n−1)``); ``T`` ranges over the real transitions of the training
  pairs (``l_t ≥ 3``), ``W`` over windows inside clips: per transition, :data:`WINDOWS_PER_T`
  windows of the same length drawn (seeded, :data:`SEED`) from the training action segments
  long enough to hold them, each window wholly inside one segment (so inside one source clip,
  no transition frame).  Near 1 means the real transitions move like recorded motion; a blended
  junction (a straight, constant-speed path) pulls ``d(T)`` toward 0 and a visible jump pushes
  it up.

Both are computed at the pairs' ``fps`` (20) on the resampled sequences the pairs are cut from
(:func:`repro.data.pairs_build.resampled_sequences`).  Deterministic: the same sequences and
source give the same floats.  This module imports :mod:`repro.data.sequences` only inside
functions (the lead's card module calls it; ``sequences`` imports nothing from here).
"""

from __future__ import annotations

import numpy as np
import torch

#: windows inside clips drawn per real transition (the denominator's sample size is
#: ``WINDOWS_PER_T`` × the number of transitions with ``l_t ≥ 3``)
WINDOWS_PER_T = 4
#: seed of the window draw
SEED = 0

__all__ = ["pair_fidelity", "WINDOWS_PER_T", "SEED", "linear_deviation_cm"]


def linear_deviation_cm(joints: torch.Tensor) -> float:
    """``d(x)`` of the module docstring for one run of joint positions (n, J, 3) in metres,
    ``n ≥ 3``: mean over interior frames and joints of the distance (cm) from the straight
    in-between of the first and last frame."""
    n = joints.shape[0]
    if n < 3:
        raise ValueError("a run needs at least 3 frames")
    w = torch.arange(n, dtype=joints.dtype)[:, None, None] / (n - 1)
    lin = joints[0] + (joints[-1] - joints[0]) * w
    return float((joints[1:-1] - lin[1:-1]).norm(dim=-1).mean()) * 100.0


def pair_fidelity(seqs, source=None) -> dict[str, float]:
    """``{"sp_heading_deg_median", "transition_linear_ratio"}`` of the pairs ``source``
    (default :class:`~repro.data.pairs_build.PairSource` ``()``) cuts from the composed
    sequences ``seqs`` (a :class:`~repro.data.sequences.SequenceSet`, used as it is)."""
    from repro.data.clipset import TRAIN
    from repro.data.pairs_build import PairSource, resampled_sequences
    from repro.data.sequences import ROLE_ACTION
    from repro.motion.heading import motion_heading
    from repro.motion.motion import Motion
    from repro.models.baseline_io import pack_poses, pose_joints
    from repro.seeding import numpy_rng

    source = PairSource() if source is None else source
    items = source.train_items(seqs)
    N = len(items)
    last = items.motion.replace(
        root=items.motion.root[torch.arange(N), items.l_p - 1][:, None],
        rot6d=items.motion.rot6d[torch.arange(N), items.l_p - 1][:, None])
    head = motion_heading(last.to(dtype=torch.float64), axis="lateral")[:, 0]
    sp_heading = float(np.median(np.degrees(np.abs(head.numpy()))))

    # real transitions T (frames l_p .. l_p + l_t - 1 of each training pair)
    def joints_of(m: Motion) -> torch.Tensor:
        return pose_joints(seqs.skeleton, pack_poses(m.to(dtype=torch.float64)))

    with torch.no_grad():
        trans, l_t = items.transition()
        tj = joints_of(trans)
        keep = [i for i in range(N) if int(l_t[i]) >= 3]
        if not keep:
            raise ValueError("no training pair has a transition of 3 frames or more")
        d_t = [linear_deviation_cm(tj[i, :int(l_t[i])]) for i in keep]

        # same-length windows inside the training action segments, at the pairs' fps
        res = resampled_sequences(seqs, source.fps)
        segs = seqs.segments(split=TRAIN, role=ROLE_ACTION)
        s = seqs.seg_seq[segs].astype(np.int64)
        ratio = float(source.fps) / float(seqs.fps)
        a0 = np.floor(seqs.seg_start[segs] * ratio + 0.5 + 1e-9).astype(np.int64)
        a1 = np.floor((seqs.seg_start[segs] + seqs.seg_length[segs]) * ratio + 0.5
                      + 1e-9).astype(np.int64)
        a1 = np.minimum(a1, res["lengths"][s])
        first = res["starts"][s] + a0           # packed row of each segment's first frame
        seg_len = a1 - a0
        rng = numpy_rng(SEED, "pair_fidelity", "windows")
        d_w = []
        for i in keep:
            n = int(l_t[i])
            ok = np.flatnonzero(seg_len >= n)
            if ok.size == 0:
                continue
            for k in rng.choice(ok, size=WINDOWS_PER_T, replace=True):
                off = int(rng.integers(0, int(seg_len[k]) - n + 1))
                r0 = int(first[k]) + off
                m = Motion(res["root"][r0:r0 + n][None].to(torch.float64),
                           res["rot6d"][r0:r0 + n][None].to(torch.float64), seqs.skeleton,
                           float(source.fps))
                d_w.append(linear_deviation_cm(joints_of(m)[0]))
    if not d_w:
        raise ValueError("no training action segment is as long as a transition")
    return {"sp_heading_deg_median": sp_heading,
            "transition_linear_ratio": float(np.median(d_t) / np.median(d_w))}
