"""MultiAct's [S_p, T, S_c] samples (repro.data.pairs, PairSource) on the bundled bandai2-mini.

protocols.md §4.1: 20 fps, transition extension, filters, per-label caps (repetition in the
test sets); and the leak rules: S_p and S_c come from different recordings, test pairs from
test clips only."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from repro.data.clipset import TEST, TRAIN
from repro.data.pairs import PairItems
from repro.data.pairs_build import PairSource
from repro.data.sequences import ROLE_ACTION, ROLE_LEAD_IN
from repro.errors import ConfigError, DataError
from repro.motion.motion import Motion
from repro.motion.resample import resample_fps
from repro.motion.rotations import quat_to_6d


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    from repro.data.registry import load_clipset

    with pytest.MonkeyPatch.context() as mp:  # decode the bundle into a private REPRO_HOME
        mp.setenv("REPRO_HOME", str(tmp_path_factory.mktemp("pairs-home")))
        clips = load_clipset("bandai2-mini")
    src = PairSource()
    return {"clips": clips, "src": src, "seqs": src.sequences(clips),
            "tables": {sp: src.pair_table(clips, sp) for sp in (TRAIN, TEST)},
            "pairs": {sp: src.pairs(clips, sp) for sp in (TRAIN, TEST)},
            "train": src.train_items(clips), "test": src.test_items(clips)}


def _arrays(p: PairItems):
    return [p.motion.root, p.motion.rot6d, p.l_p, p.l_t, p.l_c, p.prev_labels, p.labels,
            p.segment_index, p.clip_index]


def test_same_bytes_twice(setup):
    from repro.data.item_sources import clear_cache

    clips, src = setup["clips"], setup["src"]
    first = [src.train_items(clips), src.test_items(clips)]
    clear_cache()
    second = [PairSource().train_items(clips), PairSource().test_items(clips)]
    for a, b in zip(first, second):
        assert a is not b and a.key() == b.key() and a.source == b.source
        for x, y in zip(_arrays(a), _arrays(b)):
            assert x.dtype == y.dtype and x.shape == y.shape
            assert x.numpy().tobytes() == y.numpy().tobytes()


@pytest.mark.parametrize("split", [TRAIN, TEST])
def test_filters_and_parts(setup, split):
    src, p = setup["src"], setup["pairs"][split]
    assert p.fps == 20.0 and len(p) > 0
    assert int(p.l_p.min()) >= max(src.min_part, src.s1_end_len + 1)
    assert int(p.l_t.min()) >= src.min_part and int(p.l_c.min()) >= src.min_part
    assert int(p.l_p.max()) <= src.max_prev_frames
    assert int(p.l_c.max()) <= src.max_curr_frames + src.extra_curr_frames
    seqs = src.sequences(setup["clips"])               # T = the composed transition + extensions
    blend = int(np.ceil(int(np.max(seqs.trans_length, initial=0)) * p.fps / seqs.fps))
    assert int(p.l_t.max()) <= 2 * src.trans_ext_cap + blend + 1
    total = p.total
    assert int(total.max()) < src.max_len - 1 and int(total.min()) > src.min_len
    assert p.motion.n_frames == int(total.max())
    counts = np.bincount(p.labels.numpy(), minlength=p.n_classes)
    assert counts.max() <= src.all_cap_per_label


def test_filters_and_cap_bite(setup):
    clips = setup["clips"]
    base = PairSource().pair_table(clips, TRAIN)
    thr = int(np.median(base["l_p"] + base["l_t"] + base["l_c"]))   # whatever the composer
    tight = PairSource(min_len=thr, all_cap_per_label=3)
    tab = tight.pair_table(clips, TRAIN)
    assert tab["dropped"]["min_len"] > 0
    total = tab["l_p"] + tab["l_t"] + tab["l_c"]
    assert (total > thr).all()
    p = tight.pairs(clips, TRAIN)
    assert np.bincount(p.labels.numpy()).max() == 3
    assert (p.total > thr).all()
    # a short S_p crop below s1_end_len + 1 is filtered out
    short = PairSource(max_prev_frames=4)
    with pytest.raises(DataError, match="no valid MultiAct pair"):
        short.pairs(clips, TEST)
    assert short.pair_table(clips, TEST)["dropped"]["prev_part"] > 0


def test_per_label_counts(setup):
    src, train, test = setup["src"], setup["train"], setup["test"]
    avail = {sp: np.bincount(setup["tables"][sp]["label"], minlength=train.n_classes)
             for sp in (TRAIN, TEST)}
    tr = np.bincount(train.labels.numpy(), minlength=train.n_classes)
    assert (tr <= src.train_per_label).all()
    assert (tr == np.minimum(avail[TRAIN], src.train_per_label)).all()
    # training pairs are distinct; test pairs are exactly per_label per label, repeated when
    # a label has fewer (bandai2-mini has 7 test pairs per label)
    assert np.unique(train.segment_index.numpy()).size == len(train)
    te = np.bincount(test.labels.numpy(), minlength=test.n_classes)
    assert (te[avail[TEST] > 0] == src.test_per_label).all()
    assert (avail[TEST][avail[TEST] > 0] < src.test_per_label).any()   # repetition exercised
    for lab in range(test.n_classes):
        segs = test.segment_index[test.labels == lab].numpy()
        n = int(avail[TEST][lab])
        assert np.unique(segs).size == n
        assert np.array_equal(segs, np.resize(segs[:n], segs.size))     # cyclic repetition
    five = src.test_items(setup["clips"], per_label=5)
    assert (np.bincount(five.labels.numpy()) == 5).all()
    assert np.unique(five.segment_index.numpy()).size == len(five)
    # label-major order
    assert (np.diff(test.labels.numpy()) >= 0).all()


def test_reference_is_redrawn_per_seed(setup):
    clips, src = setup["clips"], setup["src"]
    a = src.reference(clips, TEST, 5, seed=1)
    b = src.reference(clips, TEST, 5, seed=2)
    assert (np.bincount(a.labels.numpy()) == 5).all()
    assert not np.array_equal(a.segment_index.numpy(), b.segment_index.numpy())
    assert a.key() != b.key()
    same = src.reference(clips, TEST, 5, seed=1)
    assert a.key() == same.key()
    tr = src.reference(clips, TRAIN, 20, seed=3)   # the training set is the train pool
    assert set(tr.segment_index.tolist()) <= set(setup["train"].segment_index.tolist())
    assert (np.bincount(tr.labels.numpy()) == 20).all()


def _resampled_sequence(seqs, s):
    a, n = int(seqs.seq_starts[s]), int(seqs.seq_lengths[s])
    q = torch.from_numpy(np.asarray(seqs.rotations[a:a + n], np.float64))
    r = torch.from_numpy(np.asarray(seqs.root[a:a + n], np.float64))
    return resample_fps(Motion(r[None], quat_to_6d(q)[None], seqs.skeleton, seqs.fps), 20.0)


@pytest.mark.parametrize("which", ["train", "test"])
def test_parts_are_continuous_rows_of_the_resampled_sequence(setup, which):
    seqs = setup["seqs"]
    split = TRAIN if which == "train" else TEST
    items, tab = setup[which], setup["tables"][split]
    row_of = {int(g): i for i, g in enumerate(tab["segment"])}
    prev_m, _ = items.prev()
    tr_m, _ = items.transition()
    act_m, _ = items.action()
    ratio = seqs.fps / 20.0
    for pos in range(0, len(items), 7):
        r = row_of[int(items.segment_index[pos])]
        s, start = int(tab["seq"][r]), int(tab["start"][r])
        lp, lt, lc = int(items.l_p[pos]), int(items.l_t[pos]), int(items.l_c[pos])
        ref = _resampled_sequence(seqs, s)
        rows = slice(start, start + lp + lt + lc)
        assert torch.allclose(items.motion.root[pos, :lp + lt + lc],
                              ref.root[0, rows].float(), atol=1e-6)
        assert torch.allclose(items.motion.rot6d[pos, :lp + lt + lc],
                              ref.rot6d[0, rows].float(), atol=1e-6)
        # the parts are the consecutive runs S_p | T | S_c of that window
        assert torch.equal(prev_m.root[pos, :lp], items.motion.root[pos, :lp])
        assert torch.equal(tr_m.root[pos, :lt], items.motion.root[pos, lp:lp + lt])
        assert torch.equal(act_m.root[pos, :lc], items.motion.root[pos, lp + lt:lp + lt + lc])
        # T covers the composed blend frames (boundaries mapped by time)
        a, g = int(tab["prev_segment"][r]), int(tab["segment"][r])
        blend0 = int(seqs.seg_start[a] + seqs.seg_length[a])
        blend1 = int(seqs.seg_start[g])
        assert (start + lp) * ratio <= blend0 + 1e-9
        assert blend1 - 1 <= (start + lp + lt) * ratio
        # S_p lies in the previous segment, S_c starts in the current one
        assert int(seqs.seg_start[a]) <= start * ratio + 0.75
        assert (start + lp + lt) * ratio < blend1 + int(seqs.seg_length[g])
        assert (seqs.frame_label[int(seqs.seq_starts[s]) + round((start + lp + lt) * ratio)]
                == int(items.labels[pos]))


@pytest.mark.parametrize("split", [TRAIN, TEST])
def test_no_leak(setup, split):
    seqs, tab, p = setup["seqs"], setup["tables"][split], setup["pairs"][split]
    clips = seqs.clips
    assert (seqs.seq_split[tab["seq"]] == split).all()
    assert (tab["prev_clip"] != tab["clip"]).all()
    assert (clips.split[tab["prev_clip"]] == split).all()
    assert (clips.split[tab["clip"]] == split).all()
    assert (seqs.seg_clip[tab["prev_segment"]] == tab["prev_clip"]).all()
    assert (seqs.seg_role[tab["segment"]] == ROLE_ACTION).all()
    assert np.isin(seqs.seg_role[tab["prev_segment"]], (ROLE_ACTION, ROLE_LEAD_IN)).all()
    assert (tab["prev_segment"] == tab["segment"] - 1).all()
    # every clip is S_c at most once; PairItems carry S_c's clip and segment
    assert np.unique(tab["clip"]).size == tab["clip"].size
    assert (seqs.seg_clip[p.segment_index.numpy()] == p.clip_index.numpy()).all()
    assert (clips.split[p.clip_index.numpy()] == split).all()
    assert (seqs.seg_label[p.segment_index.numpy()] == p.labels.numpy()).all()
    assert (seqs.seg_label[p.segment_index.numpy() - 1] == p.prev_labels.numpy()).all()


def test_train_and_test_sets_use_their_split(setup):
    clips = setup["seqs"].clips
    assert (clips.split[setup["train"].clip_index.numpy()] == TRAIN).all()
    assert (clips.split[setup["test"].clip_index.numpy()] == TEST).all()


def test_lead_in_pairs_is_a_recorded_option(setup):
    clips, seqs = setup["clips"], setup["seqs"]
    only = PairSource(lead_in_pairs=False)
    assert only.key() != PairSource().key()
    tab = only.pair_table(clips, TRAIN)
    assert (seqs.seg_role[tab["prev_segment"]] == ROLE_ACTION).all()
    assert tab["dropped"]["prev_lead_in"] == int((seqs.seg_role[seqs.segments(
        split=TRAIN, role=ROLE_ACTION) - 1] == ROLE_LEAD_IN).sum())


def test_as_action_items_round_trip(setup):
    items = setup["test"]
    acts = items.as_action_items()
    assert len(acts) == len(items) and acts.n_init == 4
    assert torch.equal(acts.lengths, items.l_c) and torch.equal(acts.labels, items.labels)
    world = acts.to_world(acts.action)
    sc, _ = items.action()
    assert torch.allclose(world.root, sc.root, atol=1e-5)
    assert torch.allclose(world.rot6d, sc.rot6d, atol=1e-5)
    init = acts.initial_world()
    for pos in range(len(items)):
        lp = int(items.l_p[pos])
        assert torch.allclose(init.root[pos], items.motion.root[pos, lp - 4:lp], atol=1e-5)
    # the canonical frame is the last S_p frame's: its root sits at the origin
    assert torch.allclose(acts.initial.root[:, -1], torch.zeros(len(items), 3), atol=1e-5)
    assert acts.key() != items.subset(range(len(items) - 1)).as_action_items().key()


def test_label_pairs_and_length_stats(setup):
    clips, src, seqs = setup["clips"], setup["src"], setup["seqs"]
    lp = src.label_pairs(clips, TEST)
    assert lp == sorted(lp) and len(lp) == len(set(lp))
    counts = seqs.tag_pair_counts(TEST)
    assert all(counts[a, b] > 0 for a, b in lp)
    stats = src.length_stats(clips)
    train = setup["train"]
    for name, st in stats.items():
        m = train.labels == train.label_names.index(name)
        assert st["n"] == int(m.sum())
        assert st["mean_l_t"] == pytest.approx(float(train.l_t[m].double().mean()))
        assert st["l_S"] == pytest.approx(st["mean_l_c"] + 2)


def test_split_clipset_is_resampled(setup):
    clips, src = setup["clips"], setup["src"]
    sc = src.split_clipset(clips)
    assert sc.fps == 20.0 and np.array_equal(sc.split, clips.split)
    assert np.array_equal(sc.labels, clips.labels) and sc.fingerprint != clips.fingerprint
    assert np.array_equal(sc.lengths, (clips.lengths - 1) * 2 // 3 + 1)
    assert src.split_clipset(clips) is sc
    assert PairSource(fps=30.0).split_clipset(clips) is clips


def test_make_names_the_bad_field():
    with pytest.raises(ConfigError, match="protocol x: max_prev_frames"):
        PairSource.make("protocol x", max_prev_frames=0)
    with pytest.raises(ConfigError, match="train_per_labl"):
        PairSource.make("protocol x", train_per_labl=3)
    with pytest.raises(ConfigError, match="compose"):
        PairSource.make("protocol x", compose={"blend_frame": 2})
    with pytest.raises(ConfigError, match="builder"):
        PairSource.make("protocol x", builder="other")


@pytest.mark.parametrize("field,value", [
    ("fps", 25.0), ("compose", {"seed": 1}), ("lead_in_pairs", False), ("seed", 1),
    ("train_per_label", 10), ("test_per_label", 10), ("all_cap_per_label", 50),
    ("max_prev_frames", 30), ("max_curr_frames", 50), ("trans_ext_fraction", 0.2),
    ("trans_ext_cap", 4), ("extra_curr_frames", 0), ("max_len", 100), ("min_len", 10),
    ("min_part", 4), ("s1_end_len", 2)])
def test_describe_changes_the_key(field, value):
    base = PairSource()
    other = PairSource(**{field: value})
    assert other.key() != base.key()
    assert PairSource.from_description(other.describe()).key() == other.key()
    assert PairSource.from_description(base.describe()) == base


def test_source_follows_description_and_sequences(setup):
    clips = setup["clips"]
    a = PairSource(train_per_label=10).train_items(clips)
    b = PairSource(train_per_label=10, compose={"seed": 1}).train_items(clips)
    assert a.source != setup["train"].source and b.source != a.source
    assert setup["train"].source.startswith("multiact_pairs:")
