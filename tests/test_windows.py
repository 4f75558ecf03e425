"""ODMO / Action2Motion fixed-length windows (repro.data.windows)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from repro.data.clipset import ClipSet
from repro.data.windows import (cut_windows, epoch_windows, motion_windows, odmo_windows,
                                window_starts)
from repro.motion.canon import uncanonicalize
from repro.motion.motion import Motion
from repro.motion.rotations import matrix_to_quat, random_rotmats
from repro.motion.skeleton import Skeleton, forward_kinematics
from repro.seeding import numpy_rng, torch_generator

LENGTHS = (12, 10, 4, 30, 11)
T = 10


@pytest.fixture(scope="module")
def clipset() -> ClipSet:
    sk = Skeleton(("root", "a", "b"), (-1, 0, 1), np.array([[0, 0, 0], [0, 0.2, 0], [0.1, 0.2, 0]]))
    g = torch_generator(0, "windows")
    F = sum(LENGTHS)
    R = random_rotmats((F, 3), g, dtype=torch.float64)
    root = np.cumsum(torch.randn(F, 3, generator=g, dtype=torch.float64).numpy(), 0) + [0, 0.9, 0]
    joints = forward_kinematics(sk, R.numpy(), root)
    n = len(LENGTHS)
    return ClipSet(name="w", skeleton=sk, fps=30.0,
                   rotations=matrix_to_quat(R).numpy().astype(np.float32),
                   root=root.astype(np.float32), joints=joints.astype(np.float32),
                   starts=np.concatenate([[0], np.cumsum(LENGTHS)[:-1]]).astype(np.int64),
                   lengths=np.array(LENGTHS, np.int64), labels=np.arange(n, dtype=np.int64),
                   label_names=tuple("abcde"), styles=np.full(n, -1, np.int64), style_names=(),
                   clip_names=tuple(f"c{i}" for i in range(n)), split=np.zeros(n, np.int8),
                   fingerprint="w")


def test_starts_exclude_the_last_window_by_default():
    lens = np.array([12, 10, 4, 30, 11] * 400)
    s = window_starts(lens, T, numpy_rng(0, "s"))
    gap = np.maximum(lens - T, 0)
    assert np.all(s[gap == 0] == 0)                     # len == T and short clips: start 0
    assert np.all(s[gap > 0] < gap[gap > 0])            # start = randint(0, len - T), exclusive
    assert set(s[lens == 11]) == {0}                    # gap 1: only start 0 is ever drawn
    assert set(s[lens == 12]) == {0, 1}
    assert set(s[lens == 30]) == set(range(20))
    s2 = window_starts(lens, T, numpy_rng(0, "s"), include_last=True)
    assert np.all(s2 <= gap) and set(s2[lens == 11]) == {0, 1} and set(s2[lens == 30]) == set(range(21))
    with pytest.raises(ValueError):
        window_starts([5], 0, numpy_rng(0))


def test_windows_are_recentred_slices(clipset):
    w = cut_windows(clipset, [0, 3], [2, 17], T)
    for k, (i, s) in enumerate([(0, 2), (3, 17)]):
        clip = clipset.clip_joints(i)[s:s + T]
        assert np.allclose(w.joints[k], clip - clip[0, 0], atol=1e-6)
        assert np.allclose(w.origin[k], clip[0, 0])
    assert np.allclose(w.joints[:, 0, 0], 0.0)
    assert w.valid.tolist() == [T, T] and w.labels.tolist() == [0, 3]
    assert w.flat().shape == (2, T, 9) and w.joints.dtype == np.float32


def test_short_clip_is_padded_with_its_last_frame(clipset):
    w = cut_windows(clipset, [2], 0, T)
    clip = clipset.clip_joints(2)
    assert w.valid.tolist() == [4]
    assert np.allclose(w.joints[0, :4], clip - clip[0, 0], atol=1e-6)
    assert np.allclose(w.joints[0, 4:], (clip[-1] - clip[0, 0])[None], atol=1e-6)


def test_padded_frame_count_per_drawn_window(clipset):
    from repro.data.odmo_items import padded_frames

    # clips of 12, 10, 4, 30, 11 frames, windows of 10: only the 4-frame clip is padded (6)
    w = cut_windows(clipset, [0, 1, 2, 3, 4, 2], [2, 0, 0, 17, 1, 0], T)
    assert padded_frames(w).tolist() == [0, 0, 6, 0, 0, 6]
    # each padded frame repeats the clip's last real frame
    n_pad = padded_frames(w)[2]
    assert np.allclose(w.joints[2, T - n_pad:], w.joints[2, T - n_pad - 1][None], atol=1e-6)


def test_epoch_windows_deterministic_and_fresh_each_epoch(clipset):
    idx = np.arange(len(clipset)).repeat(20)
    a = epoch_windows(clipset, idx, T, seed=3, epoch=0)
    b = epoch_windows(clipset, idx, T, seed=3, epoch=0)
    c = epoch_windows(clipset, idx, T, seed=3, epoch=1)
    assert a.joints.tobytes() == b.joints.tobytes() and np.array_equal(a.starts, b.starts)
    assert not np.array_equal(a.starts, c.starts)
    assert a.joints.shape == (len(idx), T, 3, 3)
    d = odmo_windows(clipset, idx, T, numpy_rng(3, "windows", 0))
    assert np.array_equal(d.starts, a.starts)


def test_motion_windows_match_position_windows(clipset):
    m, params = motion_windows(clipset, [2, 3], [0, 5], T)
    w = cut_windows(clipset, [2, 3], [0, 5], T)
    assert isinstance(m, Motion) and m.n_frames == T
    assert np.allclose(m.joints().numpy(), w.joints, atol=1e-5)
    back = uncanonicalize(m, params)
    assert np.allclose(back.joints()[1].numpy(), clipset.clip_joints(3)[5:15], atol=1e-5)


def test_bad_start(clipset):
    with pytest.raises(ValueError, match="outside"):
        cut_windows(clipset, [2], 4, T)
