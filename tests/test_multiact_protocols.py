"""MultiAct's protocols (repro.eval.protocols.multiact_conditioned, transition, long_term)
and the ``multiact_gru`` recogniser kind, on small synthetic pairs with fake generators and a
fake recogniser (deterministic, fast); one test runs the real (untrained) 4 × 256 GRU."""

from __future__ import annotations

import dataclasses
import itertools
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from model_fixtures import one_torch_thread  # noqa: F401 (autouse fixture)
from test_items import synthetic_clipset

from repro.data.action_items import ActionItems, GeneratedItems
from repro.data.clipset import TEST, TRAIN
from repro.data.pairs import GeneratedPairs, PairItems, gather_frames
from repro.errors import ConfigError, DataError
from repro.eval.features import facing_joint_indices, to_model_input
from repro.eval.protocols.long_term import (
    LongTerm,
    draw_label_sequences,
    prune_walk_graph,
)
from repro.eval.protocols.multiact_common import MultiActSamples, load_samples
from repro.eval.protocols.multiact_conditions import anchor_frames, blind
from repro.eval.protocols.multiact_conditioned import MultiActConditioned
from repro.eval.protocols.transition import Transition
from repro.motion.motion import Motion
from repro.seeding import numpy_rng, torch_generator

L_P, L_T = 6, 4


# ---------------------------------------------------------------------------------------------
# fakes


class FakePairSource:
    """PairSource's interface over a synthetic clip set: each clip is one pair (S_p = its
    first 6 frames, T the next 4, S_c the rest); clips i % 3 == 0 are test pairs."""

    def __init__(self, clips):
        self.clips = clips
        n = len(clips.lengths)
        T = int(clips.lengths.max())
        motion = Motion.from_clipset(clips, np.arange(n), 0, T, pad=True)
        C = len(clips.label_names)
        labels = torch.as_tensor(clips.labels, dtype=torch.long)
        prev = (labels + torch.arange(n) % 2 + 1) % C       # two predecessors per label
        self.all = PairItems(motion, torch.full((n,), L_P), torch.full((n,), L_T),
                             torch.as_tensor(clips.lengths - L_P - L_T), prev, labels,
                             clips.label_names, source="fake")
        self.split = np.where(np.arange(n) % 3 == 0, TEST, TRAIN)

    def describe(self):
        return {"fake": 1}

    def split_clipset(self, clipset):
        return clipset

    def pairs(self, clipset, split):
        return self.all.subset(np.flatnonzero(self.split == split))

    def train_items(self, clipset):
        return self.pairs(clipset, TRAIN)

    def _per_label(self, pool, k, rng=None):
        y = pool.labels.numpy()
        rows = []
        for c in np.unique(y):
            idx = np.flatnonzero(y == c)
            rows.append(np.resize(idx, k) if rng is None else
                        rng.choice(idx, size=k, replace=idx.size < k))
        return pool.subset(np.concatenate(rows))

    def test_items(self, clipset, per_label=None):
        return self._per_label(self.pairs(clipset, TEST), per_label or 4)

    def reference(self, clipset, split, per_label, seed):
        pool = self.train_items(clipset) if split == TRAIN else self.pairs(clipset, TEST)
        sub = self._per_label(pool, per_label, numpy_rng(seed, "fake-ref"))
        return dataclasses.replace(sub, source=f"ref:{split}:{per_label}:{seed}")

    def label_pairs(self, clipset, split):
        p = self.pairs(clipset, split)
        return sorted({(int(a), int(b)) for a, b in zip(p.prev_labels, p.labels)})

    def length_stats(self, clipset):
        tr = self.train_items(clipset)
        out = {}
        for c in np.unique(tr.labels.numpy()):
            m = tr.labels == int(c)
            out[tr.label_names[int(c)]] = {"l_T": float(tr.l_t[m].float().mean()),
                                           "l_S": float(tr.l_c[m].float().mean()) + 2.0}
        return out


class FakeEvaluator:
    """The recogniser interface: the real input convention (heading removed), then a fixed
    random map to 4-d tanh features (+ seeded noise when ``noise``) and 3 logits."""

    def __init__(self, clips, *, noise: float = 0.0, label_names=None, dim: int = 4):
        self.label_names = tuple(label_names or clips.label_names)
        self.joint_names = tuple(clips.skeleton.names)
        self.facing = facing_joint_indices(clips.skeleton)
        self.settings = SimpleNamespace(window=16, heading="remove", feature_dim=dim)
        self.fingerprint = f"fake-{noise}-{dim}-{len(self.label_names)}"
        self.noise = noise
        g = torch_generator(0, "fake-evaluator")
        D = 3 * len(self.joint_names)
        self.A = torch.randn(2 * D, dim, generator=g, dtype=torch.float64) / np.sqrt(D)
        self.centroids = torch.randn(len(self.label_names), dim, generator=g,
                                     dtype=torch.float64)

    def fit(self, items: PairItems) -> FakeEvaluator:
        """Logits = −squared distance to the class centroids of ``items``' real S_c."""
        seg, lens = items.action()
        f = self._features(seg.joints().numpy(), lens.numpy(), None, noise=False)
        y = items.labels
        self.centroids = torch.stack([f[y == c].mean(0) for c in range(len(self.label_names))])
        return self

    def _features(self, joints, lengths, seed, noise=True):
        x = torch.from_numpy(to_model_input(np.asarray(joints), lengths, heading="remove",
                                            facing=self.facing)).double()
        h = torch.cat([x.mean(1), x.std(1)], 1) @ self.A
        if noise and self.noise:
            h = h + self.noise * torch.randn(h.shape, generator=torch_generator(int(seed or 0),
                                                                                "noise"),
                                             dtype=h.dtype)
        return torch.tanh(h)

    def encode(self, joints, lengths=None, seed=None):
        f = self._features(joints, lengths, seed)
        logits = -torch.cdist(f, self.centroids) ** 2
        return f.float().numpy(), logits.float().numpy()


def _drift(anchor: Motion, n: int, seed: int, speed: float = 0.02) -> Motion:
    """(N, n) frames: the anchor pose moving forward with seeded jitter."""
    N = anchor.batch_size
    g = torch_generator(seed, "drift")
    t = torch.arange(n, dtype=anchor.dtype)[None, :, None]
    step = torch.tensor([0.0, 0.0, speed], dtype=anchor.dtype)
    jitter = 0.01 * torch.randn(N, n, 3, generator=g, dtype=anchor.dtype)
    root = anchor.root + t * step + jitter
    rot = anchor.rot6d.expand(N, n, *anchor.rot6d.shape[2:]).clone()
    return anchor.replace(root=root, rot6d=rot)


class FakeMACVAE:
    """A pair generator that reads only S_p, labels and lengths (like MACVAE)."""

    item_kind = "pairs"
    method_id = "macvae"

    def __init__(self):
        self.seen: list[PairItems] = []

    def _out(self, prev, l_p, l_t, l_c, seed):
        anchor = anchor_frames(prev, l_p)
        n = int((l_t + l_c).max())
        return GeneratedPairs(_drift(anchor, n, seed), l_t.clone(), l_c.clone())

    def sample(self, cond: PairItems, *, seed, use_mean=False):
        self.seen.append(cond)
        prev, l_p = cond.prev()
        return self._out(prev, l_p, cond.l_t, cond.l_c, seed)

    def step(self, prev, prev_lengths, labels, l_t, l_c, *, seed, use_mean=False):
        return self._out(prev, torch.as_tensor(prev_lengths), torch.as_tensor(l_t),
                         torch.as_tensor(l_c), seed)


class LeakyGenerator(FakeMACVAE):
    """Returns the conditions' [T, S_c] frames: it would copy the targets if it could see them."""

    def sample(self, cond: PairItems, *, seed, use_mean=False):
        m, _ = cond.target()
        return GeneratedPairs(m, cond.l_t.clone(), cond.l_c.clone())


class FakeACTOR:
    """A label-only ActionItems generator placed at the items' canonical frames."""

    method_id = "actor"

    def sample(self, cond: ActionItems, *, seed, use_mean=False):
        assert isinstance(cond, ActionItems)
        m = cond.to_world(cond.action)
        m = _drift(m.slice_time(0, 1), m.n_frames, seed, speed=0.03)
        return GeneratedItems(m, cond.lengths.clone(), cond.labels.clone())


class FakeComposite(FakeMACVAE):
    """ACTOR + X: its own ACTOR for previous motions."""

    method_id = "actor_ssmct"

    def __init__(self, template: Motion):
        super().__init__()
        self.template = template

    def actor_motion(self, labels, lengths, *, seed):
        n = len(labels)
        a = self.template.select(torch.zeros(n, dtype=torch.long))
        return _drift(a, int(max(lengths)), seed, speed=0.03)


# ---------------------------------------------------------------------------------------------
# fixtures


@pytest.fixture(scope="module")
def clips():
    return synthetic_clipset(n_per_class=24, min_len=24, max_len=40, fps=20.0)


@pytest.fixture(scope="module")
def source(clips):
    return FakePairSource(clips)


@pytest.fixture(scope="module")
def evaluator(clips, source):
    return FakeEvaluator(clips).fit(source.train_items(clips))


def _proto(cls, source, **params):
    p = cls(params)
    p.item_source = lambda: source
    return p


def _real_samples(items: PairItems, *, junk_action=False, junk_transition=False):
    """The items' own [T, S_c] as samples (a perfect generator), optionally with junk parts."""
    m, _ = items.target()
    anchor = anchor_frames(items.motion, items.l_p)
    if junk_action or junk_transition:
        junk = _drift(anchor, m.n_frames, 7, speed=0.2)
        t = torch.arange(m.n_frames)[None, :]
        use = torch.zeros_like(t, dtype=torch.bool).expand(len(items), -1).clone()
        if junk_transition:
            use |= t < items.l_t[:, None]
        if junk_action:
            use |= t >= items.l_t[:, None]
        m = m.replace(root=torch.where(use[..., None], junk.root, m.root),
                      rot6d=torch.where(use[..., None, None], junk.rot6d, m.rot6d))
    return MultiActSamples(m, items.l_t, items.l_c, items.labels, anchor, items_key=items.key())


# ---------------------------------------------------------------------------------------------
# the recogniser kind


def test_multiact_gru_kind():
    from repro.eval.classifiers import GRURecogniser, build_module
    from repro.eval.settings import GRU_SHAPES, KINDS, architecture, resolve_settings

    assert "multiact_gru" in KINDS and GRU_SHAPES["multiact_gru"] == {"layers": 4, "hidden": 256}
    s = resolve_settings("quick")
    net = build_module("multiact_gru", 21, 3, s)
    assert isinstance(net, GRURecogniser) and net.gru.num_layers == 4 and net.gru.hidden_size == 256
    assert net.feature.out_features == 30
    arch = architecture("multiact_gru", s)
    assert arch["layers"] == 4 and arch["hidden"] == 256 and arch["feature_act"] == "tanh"
    f, lg = net(torch.zeros(2, 10, 21))
    assert f.shape == (2, 30) and lg.shape == (2, 3)


def test_real_recogniser_plumbing(clips, source):
    """measure() through a real (untrained) multiact_gru Evaluator with heading removed."""
    from repro.eval.classifiers import build_module
    from repro.eval.evaluator import Evaluator, weights_sha256
    from repro.eval.settings import architecture, resolve_settings

    s = resolve_settings("quick", {"heading": "remove", "window": 16})
    torch.manual_seed(0)
    net = build_module("multiact_gru", 3 * len(clips.skeleton.names), 3, s).eval()
    ev = Evaluator(kind="multiact_gru", settings=s, module=net,
                   joint_names=tuple(clips.skeleton.names), label_names=clips.label_names,
                   dataset="synthetic", data_fingerprint="x",
                   weights_sha256=weights_sha256(net.state_dict()), fingerprint="real-gru",
                   facing=facing_joint_indices(clips.skeleton),
                   meta={"architecture": architecture("multiact_gru", s)})
    proto = _proto(MultiActConditioned, source, per_label=4, train_per_label=16)
    items = proto.test_items(clips)
    out = proto.generate(FakeMACVAE(), items, seed=0, replicate=0)
    vals = proto.measure(out, items, ev, seed=0, clipset=clips)
    assert set(vals) == {"fid_train", "fid_test", "acc", "acc_top5", "div", "multimod"}
    assert all(np.isfinite(v) for v in vals.values())
    bad = _proto(MultiActConditioned, source, per_label=4, evaluator_heading="yaw_augment")
    with pytest.raises(ConfigError, match="heading"):
        bad.measure(out, items, ev, seed=0, clipset=clips)


# ---------------------------------------------------------------------------------------------
# multiact_conditioned


def test_generate_is_blind_no_leak(clips, source):
    proto = _proto(MultiActConditioned, source, per_label=4)
    items = proto.test_items(clips)
    # the same items with every T / S_c frame zeroed: S_p, labels, lengths unchanged
    t = torch.arange(items.motion.n_frames)[None, :]
    keep = (t < items.l_p[:, None])
    zeroed = dataclasses.replace(items, motion=items.motion.replace(
        root=torch.where(keep[..., None], items.motion.root, torch.zeros(())),
        rot6d=torch.where(keep[..., None, None], items.motion.rot6d, torch.zeros(()))))
    for gen in (FakeMACVAE(), LeakyGenerator(), FakeACTOR()):
        a = proto.generate(gen, items, seed=3, replicate=1)
        b = proto.generate(gen, zeroed, seed=3, replicate=1)
        assert torch.equal(a.motion.root, b.motion.root) and torch.equal(a.motion.rot6d,
                                                                         b.motion.rot6d)
    # what generators are given holds S_p's last frame in place of T and S_c
    gen = FakeMACVAE()
    proto.generate(gen, items, seed=0, replicate=0)
    cond = gen.seen[0]
    last = anchor_frames(items.motion, items.l_p)
    tgt, _ = cond.target()
    assert torch.allclose(tgt.root, last.root.expand_as(tgt.root))
    assert (cond.segment_index == -1).all() and cond.clip_index is None
    # a leaky generator can only "copy" S_p's last frame
    leak = proto.generate(LeakyGenerator(), items, seed=0, replicate=0)
    act, _ = leak.action()
    assert torch.allclose(act.root, last.root.expand_as(act.root))


def test_real_train_fid_train_is_noise_only(clips, source):
    proto = _proto(MultiActConditioned, source, per_label=16, train_per_label=16)
    items = proto.test_items(clips)
    exact = proto.real_replicate(clips, items, FakeEvaluator(clips), seed=0, replicate=0,
                                 split="train")
    assert abs(exact["fid_train"]) < 1e-6
    noisy = proto.real_replicate(clips, items, FakeEvaluator(clips, noise=0.05), seed=0,
                                 replicate=0, split="train")
    assert 0 < noisy["fid_train"] < 0.05
    test = proto.real_replicate(clips, items, FakeEvaluator(clips), seed=0, replicate=0,
                                split="test")
    assert test["fid_train"] > 1e-3 and set(test) == set(proto.real_metrics)
    with pytest.raises(ConfigError, match="split"):
        proto.real_replicate(clips, items, FakeEvaluator(clips), seed=0, replicate=0,
                             split="val")


def test_fid_test_reference_redrawn_per_replicate(clips, source, evaluator):
    proto = _proto(MultiActConditioned, source, per_label=4)
    items = proto.test_items(clips)
    out = proto.generate(FakeMACVAE(), items, seed=0, replicate=0)
    r0 = proto.test_reference(clips, evaluator, seed=0)
    r1 = proto.test_reference(clips, evaluator, seed=1)
    assert not np.allclose(r0.mu, r1.mu)
    v0 = proto.measure(out, items, evaluator, seed=0, clipset=clips)
    v1 = proto.measure(out, items, evaluator, seed=1, clipset=clips)
    assert v0["fid_train"] == v1["fid_train"]   # fixed training reference
    assert v0["fid_test"] != v1["fid_test"]     # fresh test reference per replicate
    assert v0["acc"] == v1["acc"]


def test_perfect_generator_scores_like_real_test(clips, source, evaluator):
    proto = _proto(MultiActConditioned, source, per_label=4)
    items = proto.test_items(clips)
    seeds = range(6)
    perfect = [proto.measure(_real_samples(items), items, evaluator, seed=s, clipset=clips)
               for s in seeds]
    real = [proto.real_replicate(clips, items, evaluator, seed=s, replicate=0, split="test")
            for s in seeds]
    junk = [proto.measure(_real_samples(items, junk_action=True), items, evaluator, seed=s,
                          clipset=clips) for s in seeds]
    mean = lambda rows, k: float(np.mean([r[k] for r in rows]))
    for k in ("fid_train", "fid_test"):
        assert mean(perfect, k) < 0.5 * mean(junk, k)
        assert abs(mean(perfect, k) - mean(real, k)) < 0.5 * mean(junk, k)
    assert mean(real, "acc") > 0.6 and mean(junk, "acc") < mean(real, "acc") - 0.2
    assert abs(mean(perfect, "acc") - mean(real, "acc")) < 0.2


def test_label_merge_only_with_babel_names(clips, source):
    proto = _proto(MultiActConditioned, source)
    assert proto.label_merge(clips.label_names) is None
    babel = ("walk", "walk forward", "stand")
    assert proto.label_merge(babel)                     # BABEL's table applies
    logits = np.array([[5.0, 0.0, 0.0], [0.0, 5.0, 0.0]])  # predicts walk, walk forward
    gt = np.array([1, 0])                                # GT walk forward, walk
    assert proto.accuracy(logits, gt, babel) == 1.0      # merged both ways
    none = _proto(MultiActConditioned, source, label_merge="none")
    assert none.accuracy(logits, gt, babel) == 0.0
    assert proto.accuracy(logits, gt, clips.label_names) == 0.0  # stand-in names: exact match
    forced = _proto(MultiActConditioned, source, label_merge="multiact_babel")
    assert forced.accuracy(logits, gt, clips.label_names) == 0.0


def test_actor_row_and_prev_from_actor(clips, source, evaluator):
    proto = _proto(MultiActConditioned, source, per_label=4)
    items = proto.test_items(clips)
    out = proto.generate(FakeACTOR(), items, seed=0, replicate=0)
    assert not out.transitions and int(out.l_t.max()) == 0
    assert torch.equal(out.l_c, items.l_c)
    vals = proto.measure(out, items, evaluator, seed=0, clipset=clips)
    assert set(vals) == set(proto.metrics)
    with pytest.raises(ConfigError, match="actor"):
        proto.generate(FakeMACVAE(), items, seed=0, replicate=0,
                       row_config={"prev_motion_source": "actor"})
    a = proto.generate(FakeMACVAE(), items, seed=0, replicate=0, models={"actor": FakeACTOR()},
                       row_config={"prev_motion_source": "actor"})
    b = proto.generate(FakeMACVAE(), items, seed=0, replicate=0)
    assert not torch.allclose(a.anchor.root, b.anchor.root)   # S_p was ACTOR's
    assert proto.extra_models("macvae", {"prev_motion_source": "actor"}) == {"actor": "actor"}
    assert proto.extra_models("macvae", {"prev_motion_source": "test"}) == {}
    assert proto.extra_models("actor", {"prev_motion_source": "actor"}) == {}
    assert proto.extra_models("interpolation", {"prev_motion_source": "actor"}) == {}


def test_determinism_and_save_load(clips, source, evaluator, tmp_path):
    proto = _proto(MultiActConditioned, source, per_label=4)
    items = proto.test_items(clips)
    a = proto.generate(FakeMACVAE(), items, seed=5, replicate=2)
    b = proto.generate(FakeMACVAE(), items, seed=5, replicate=2)
    c = proto.generate(FakeMACVAE(), items, seed=5, replicate=3)
    assert torch.equal(a.motion.root, b.motion.root)
    assert not torch.equal(a.motion.root, c.motion.root)
    va = proto.measure(a, items, evaluator, seed=5, clipset=clips)
    assert va == proto.measure(b, items, evaluator, seed=5, clipset=clips)
    path = proto.save_generated(a, tmp_path / "g.npz")
    back = proto.load_generated(path)
    assert torch.equal(back.motion.root, a.motion.root) and torch.equal(back.l_t, a.l_t)
    assert back.items_key == items.key() and back.transitions
    assert proto.measure(back, items, evaluator, seed=5, clipset=clips) == va
    with pytest.raises(DataError):
        load_samples("transition", path)   # another protocol's file


# ---------------------------------------------------------------------------------------------
# transition


def test_transition_scores_transitions_not_actions(clips, source, evaluator):
    proto = _proto(Transition, source, per_label=4)
    items = proto.test_items(clips)
    base = proto.measure(_real_samples(items), items, evaluator, seed=0, clipset=clips)
    assert set(base) == {"fid_train", "fid_test"}
    assert abs(base["fid_test"]) < 1e-6      # the same pairs' transitions
    other_action = proto.measure(_real_samples(items, junk_action=True), items, evaluator,
                                 seed=0, clipset=clips)
    assert other_action == base
    other_t = proto.measure(_real_samples(items, junk_transition=True), items, evaluator,
                            seed=0, clipset=clips)
    assert other_t["fid_test"] > base["fid_test"] + 1e-3
    with pytest.raises(ConfigError, match="transition"):
        proto.generate(FakeACTOR(), items, seed=0, replicate=0)
    assert "segment" not in proto.params.describe()


def test_transition_rows(clips, source, evaluator):
    proto = _proto(Transition, source, per_label=4)
    items = proto.test_items(clips)
    test = proto.generate(FakeMACVAE(), items, seed=0, replicate=0,
                          row_config={"prev_motion_source": "test"})
    assert torch.allclose(test.anchor.root, anchor_frames(items.motion, items.l_p).root)
    act = proto.generate(FakeMACVAE(), items, seed=0, replicate=0, models={"actor": FakeACTOR()},
                         row_config={"prev_motion_source": "actor"})
    comp = FakeComposite(anchor_frames(items.motion, items.l_p).select([0]))
    c = proto.generate(comp, items, seed=0, replicate=0)
    for out in (test, act, c):
        vals = proto.measure(out, items, evaluator, seed=0, clipset=clips)
        assert np.isfinite(vals["fid_train"]) and np.isfinite(vals["fid_test"])


# ---------------------------------------------------------------------------------------------
# long_term


def test_label_walks_use_test_pairs_only():
    pairs = [(0, 1), (1, 0), (1, 2), (3, 0)]          # 2 is a sink
    succ = prune_walk_graph(pairs, 4)
    assert succ == {0: [1], 1: [0], 3: [0]}
    seqs = draw_label_sequences(pairs, 4, 20, 6, seed=0)
    ok = {(a, b) for a, b in pairs}
    assert all((int(a), int(b)) in ok for s in seqs for a, b in itertools.pairwise(s))
    assert np.array_equal(seqs, draw_label_sequences(pairs, 4, 20, 6, seed=0))
    with pytest.raises(DataError, match="dead end"):
        draw_label_sequences([(0, 1)], 2, 2, 3, seed=0)


def test_walk_successors_test_pairs_or_training_counts(clips, source):
    """successors: the test pairs' own (a_p, a_c) (default, the paper's rule) or every pair
    the training sequences join, read through SequenceSet.tag_pair_counts(TRAIN)."""
    proto = _proto(LongTerm, source, steps=4, sequences=8)
    assert proto.walk_pairs(clips) == source.label_pairs(clips, TEST)
    counts = np.zeros((4, 4), np.int64)
    counts[0, 1], counts[1, 2], counts[2, 0], counts[3, 3] = 9, 1, 2, 1
    seen = []

    class WithSequences(FakePairSource):
        def sequences(self, clipset):
            def tag_pair_counts(split=TRAIN):
                seen.append(split)
                return counts
            return SimpleNamespace(tag_pair_counts=tag_pair_counts)

    src = WithSequences(clips)
    tr = _proto(LongTerm, src, steps=4, sequences=8, successors="train_counts")
    assert tr.walk_pairs(clips) == [(0, 1), (1, 2), (2, 0), (3, 3)] and seen == [TRAIN]
    walks = draw_label_sequences(tr.walk_pairs(clips), 4, 10, 5, seed=0)
    ok = {(0, 1), (1, 2), (2, 0), (3, 3)}
    assert all((int(a), int(b)) in ok for w in walks for a, b in itertools.pairwise(w))


def test_long_term_keys_and_rows(clips, source, evaluator):
    proto = _proto(LongTerm, source, steps=4, sequences=8)
    items = proto.test_items(clips)
    assert items.shape == (8, 4)
    ok = set(source.label_pairs(clips, TEST))
    y = items.labels.numpy()
    assert all((int(a), int(b)) in ok for s in y for a, b in itertools.pairwise(s))
    assert int((items.prev_len[:, 1:] + items.l_t[:, 1:] + items.l_c[:, 1:]).max()) <= 115
    assert proto.extra_models("macvae") == {"actor": "actor"}
    assert proto.extra_models("actor_ssmct") == {} and proto.extra_models("actor") == {}
    with pytest.raises(ConfigError, match="actor"):
        proto.generate(FakeMACVAE(), items, seed=0, replicate=0)
    out = proto.generate(FakeMACVAE(), items, seed=0, replicate=0, models={"actor": FakeACTOR()})
    vals = proto.measure(out, items, evaluator, seed=0, clipset=clips)
    assert {f"acc@{x}" for x in range(1, 5)} <= set(vals)
    assert {k for k in vals if k.startswith("fid_test@")} == {f"fid_test@{x}" for x in range(2, 5)}
    assert all(np.isfinite(vals[f"fid_test@{x}"]) for x in range(2, 5))
    # ACTOR alone: accuracy only
    a = proto.generate(FakeACTOR(), items, seed=0, replicate=0)
    va = proto.measure(a, items, evaluator, seed=0, clipset=clips)
    assert not any(k.startswith("fid_test") for k in va) and "acc@4" in va
    # a composite uses its own ACTOR
    comp = FakeComposite(anchor_frames(items.pairs.motion, items.pairs.l_p).select([0]))
    vc = proto.measure(proto.generate(comp, items, seed=0, replicate=0), items, evaluator,
                       seed=0, clipset=clips)
    assert "fid_test@4" in vc
    # determinism; the samples continue the previous action (anchor = its trimmed end)
    again = proto.generate(FakeMACVAE(), items, seed=0, replicate=0,
                           models={"actor": FakeACTOR()})
    assert torch.equal(again.motion.root, out.motion.root)
    assert proto.measure(again, items, evaluator, seed=0, clipset=clips) == vals
    assert "segment" not in proto.params.describe()


def test_long_term_initial_macvae(clips, source, evaluator, tmp_path):
    proto = _proto(LongTerm, source, steps=3, sequences=5, initial_generator="macvae")
    items = proto.test_items(clips)
    assert (items.init_rows >= 0).all()
    assert torch.equal(items.pairs.labels[items.init_rows], items.labels[:, 0])
    assert proto.extra_models("macvae") == {}
    out = proto.generate(FakeMACVAE(), items, seed=1, replicate=0)
    back = proto.load_generated(proto.save_generated(out, tmp_path / "lt.npz"))
    assert (back.n_sequences, back.n_steps) == (5, 3)
    vals = proto.measure(back, items, evaluator, seed=1, clipset=clips)
    assert {"acc@1", "acc@3", "fid_test@2", "fid_test@3"} <= set(vals)


def test_blind_keeps_allowed_fields(clips, source):
    items = source.test_items(clips, 2)
    b = blind(items)
    assert torch.equal(b.l_p, items.l_p) and torch.equal(b.l_t, items.l_t)
    assert torch.equal(b.l_c, items.l_c) and torch.equal(b.labels, items.labels)
    assert torch.equal(b.prev_labels, items.prev_labels)
    p0, _ = b.prev()
    p1, _ = items.prev()
    assert torch.equal(p0.root, p1.root)
    m = gather_frames(items.motion, items.l_p - 1, torch.ones_like(items.l_p))
    a, _ = b.action()
    assert torch.allclose(a.root, m.root.expand_as(a.root))


# ---------------------------------------------------------------------------------------------
# placement of a generated S_p (issue 26, "S_p placed in the world")


def _placed_in_world(items: PairItems, seed: int) -> PairItems:
    """``items`` rigidly moved per item by a seeded yaw (uniform) and ground offset (±5 m), as
    the composer places each sequence in its world."""
    from repro.motion.canon import CanonParams, canonicalize_with
    from repro.motion.heading import yaw_matrix

    N = len(items)
    rng = numpy_rng(seed, "test-world-placement")
    yaw = torch.as_tensor(rng.uniform(-np.pi, np.pi, N))
    off = torch.as_tensor(np.stack([rng.uniform(-5, 5, N), np.zeros(N), rng.uniform(-5, 5, N)], 1))
    G = yaw_matrix(yaw).to(items.motion.dtype)
    params = CanonParams("test", G, -(G.transpose(-1, -2) @ off[..., None].to(G.dtype))[..., 0],
                         torch.zeros(N, dtype=torch.long))
    return dataclasses.replace(items, motion=canonicalize_with(items.motion, params))


def test_generated_prev_starts_where_the_real_prev_starts(clips, source):
    """A generated S_p (ACTOR's, for a_p) is placed at the real S_p's first frame, so its end
    lies near the real S_p's start and faces every way when the pairs do; ACTOR's own frame
    (origin, +Z: where "w. o. align" leaves Ŝ_c) is not where it ends."""
    from repro.eval.protocols.multiact_conditions import at_origin, first_frames, place_at
    from repro.motion.heading import motion_heading

    proto = _proto(Transition, source, per_label=4)
    items = _placed_in_world(proto.test_items(clips), 3)
    start = first_frames(items.motion)
    h_start = motion_heading(start, axis="forward")[:, 0]
    assert np.median(np.degrees(np.abs(h_start.numpy()))) > 30      # the pairs face every way
    origin_pose = at_origin(anchor_frames(items.motion, items.l_p).select([0]))
    for gen, models in ((FakeComposite(origin_pose), None),
                        (FakeMACVAE(), {"actor": FakeACTOR()})):
        rows = None if models is None else {"prev_motion_source": "actor"}
        out = proto.generate(gen, items, seed=0, replicate=0, models=models, row_config=rows)
        end = out.anchor                                 # the generated S_p's last frame
        travel = 0.03 * items.l_p.to(end.root.dtype) + 0.2
        gap = (end.root[:, 0, [0, 2]] - start.root[:, 0, [0, 2]]).norm(dim=-1)
        assert torch.all(gap <= travel)                  # it starts where the real S_p starts
        h_end = motion_heading(end, axis="forward")[:, 0]
        assert np.median(np.degrees(np.abs(h_end.numpy()))) > 30    # and faces every way
        d = torch.remainder(h_end - h_start + np.pi, 2 * np.pi) - np.pi
        assert float(d.std()) < 1e-3                     # with one fixed offset: the placement
    # place_at is the inverse of ACTOR's normalisation: the origin pose lands on the frame
    placed = place_at(origin_pose.select(torch.zeros(len(items), dtype=torch.long)), start)
    assert torch.allclose(placed.root, start.root, atol=1e-5)


@pytest.mark.parametrize("successors", ["test_pairs", "train_counts"])
def test_long_term_walks_keep_their_class_mix_on_the_mini_view(successors, tmp_path_factory):
    """Issue 26: on the composed bandai2-mini, the label walks of Fig. 6 do not drift into a
    few classes with the step (the previous composer's walks held no locomotion from step 12)."""
    from repro.data.registry import load_clipset

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("REPRO_HOME", str(tmp_path_factory.mktemp("lt-home")))
        mini = load_clipset("bandai2-mini")
    proto = LongTerm({"successors": successors})
    C = mini.n_classes
    walks = draw_label_sequences(proto.walk_pairs(mini), C, 500, 20, seed=0)
    share = np.stack([np.bincount(walks[:, x], minlength=C) / 500 for x in range(20)])
    if successors == "train_counts":    # the dense training matrix: near-uniform at every step
        assert share[1:].min() >= 0.3 / C and share[1:].max() <= 3 / C
    else:
        # the paper's rule walks the test pairs (sparse on the mini view, so not uniform), but
        # the mix does not drift with the step: every class at every step, and each class's
        # share over steps 11-20 within half of its share over steps 2-10, either way
        assert share[1:].min() > 0
        early, late = share[1:10].mean(0), share[10:].mean(0)
        assert (late >= 0.5 * early).all() and (late <= 1.5 * early).all()
