"""Items from composed sequences (repro.data.contexts): the leak tests.

An item's previous motion P^ini and its next tag come from its sequence — the previous
segment, the blended transition, the following segment — never from the clip being generated
or scored; test items use test clips only; and the real action is the recorded clip itself."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from repro.data.clipset import TEST, TRAIN
from repro.data.contexts import ActionSource
from repro.data.sequences import ROLE_ACTION


@pytest.fixture(scope="module")
def setup():
    from repro.data.registry import load_clipset

    torch.set_num_threads(1)
    clips = load_clipset("bandai2-mini")
    src = ActionSource()
    seqs = src.sequences(clips)
    return {"clips": clips, "src": src, "seqs": seqs,
            "train": src.items(clips, TRAIN), "test": src.items(clips, TEST)}


@pytest.mark.parametrize("which", ["train", "test"])
def test_context_never_comes_from_the_generated_clip(setup, which):
    seqs, items = setup["seqs"], setup[which]
    K = items.n_init
    split = TRAIN if which == "train" else TEST
    segs = items.segment_index.numpy()
    assert len(items) == seqs.segments(split=split, role=ROLE_ACTION).size
    for pos, a in enumerate(segs.tolist()):
        clip = int(seqs.seg_clip[a])
        assert int(items.clip_index[pos]) == clip
        s, start = int(seqs.seg_seq[a]), int(seqs.seg_start[a])
        # the K context frames lie before the segment in its sequence, and no frame of them
        # belongs to the segment itself
        ctx_rows = seqs.seq_starts[s] + np.arange(start - K, start)
        assert start - K >= 0
        own = seqs.seq_starts[s] + np.arange(start, start + int(seqs.seg_length[a]))
        assert not np.intersect1d(ctx_rows, own).size
        # the segment before it is another recording (its clip differs from the generated one)
        prev = a - 1
        assert int(seqs.seg_seq[prev]) == s
        assert int(seqs.seg_clip[prev]) != clip
        # the next tag is the following segment's label, and that segment is another clip
        nxt = a + 1
        assert int(seqs.seg_seq[nxt]) == s
        assert int(seqs.seg_clip[nxt]) != clip
        assert int(items.next_labels[pos]) == int(seqs.seg_label[nxt])
        # test items only see test clips (and train items train clips), context included
        assert setup["clips"] is not None
        sc = seqs.clips
        assert int(sc.split[clip]) == split
        assert int(sc.split[int(seqs.seg_clip[prev])]) == split
        assert int(sc.split[int(seqs.seg_clip[nxt])]) == split


def test_context_frames_differ_from_the_clips_own_start(setup):
    """The same-clip construction (the leak this replaces) took P^ini from the clip's own first
    frames; sequence items do not (structurally: previous test; numerically: here — an in-place
    action's context may be close to its own start, so the check is on the typical item)."""
    seqs, items = setup["seqs"], setup["test"]
    K = items.n_init
    sc = seqs.clips
    world = items.initial_world().joints()
    gaps = []
    for pos, a in enumerate(items.segment_index.tolist()):
        own = torch.from_numpy(sc.clip_joints(int(seqs.seg_clip[a]))[:K].astype(np.float32))
        gaps.append(float((world[pos] - own).norm(dim=-1).max()))
    gaps = np.array(gaps)
    assert (gaps > 1e-4).all()
    assert np.median(gaps) > 0.05  # metres


def test_real_action_is_the_recorded_clip(setup):
    seqs, items = setup["seqs"], setup["test"]
    sc = seqs.clips
    real = items.real()
    for pos, a in enumerate(items.segment_index.tolist()[:25]):
        clip, cut = int(seqs.seg_clip[a]), int(seqs.seg_clip_start[a])
        T = int(items.lengths[pos])
        want = torch.from_numpy(sc.clip_root(clip)[cut:cut + T].astype(np.float32))
        assert torch.allclose(real.motion.root[pos, :T], want, atol=1e-4)
        wj = torch.from_numpy(sc.clip_joints(clip)[cut:cut + T].astype(np.float32))
        assert torch.allclose(real.joints()[pos, :T], wj, atol=2e-3)


def test_context_joins_the_action_continuously(setup):
    """P^ini runs into the action: the step from P₋₁ to the first action frame is of the
    order of a frame-to-frame step, not a jump across recordings."""
    items = setup["test"]
    world_init = items.initial_world().joints()
    real = items.real().joints()
    step_in = (real[:, 0] - world_init[:, -1]).norm(dim=-1).mean(-1)
    inside = (real[:, 1:6] - real[:, :5]).norm(dim=-1).mean(-1).mean(-1)
    assert float(step_in.median()) < 5 * float(inside.median()) + 0.02


def test_same_clip_context_is_a_named_option(setup):
    clips = setup["clips"]
    leak = ActionSource(context="same_clip")
    assert leak.key() != ActionSource().key()
    items = leak.items(clips, TEST)
    assert items.segment_index is None
    assert "compose" not in leak.describe() and "compose" in ActionSource().describe()
