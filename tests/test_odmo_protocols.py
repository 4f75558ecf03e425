"""ODMO's data layer and protocols (odmo_generation, latent_modes, trajectory_customisation)
with stand-in generators and a stand-in recogniser, so the protocol logic is tested alone."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from repro.data.clipset import TEST, TRAIN
from repro.data.odmo_items import WindowSource, label_condition_items
from repro.data.registry import load_clipset
from repro.errors import DataError
from repro.eval.protocols import get_protocol
from repro.eval.protocols.odmo_common import real_set


@pytest.fixture(scope="module")
def clips():
    return load_clipset("bandai2-mini")


class FakeEvaluator:
    """Features = 30 fixed random projections of the flattened window; logits = the label a
    nearest class mean (of the training windows) gives: deterministic, cheap."""

    def __init__(self, clips, window=20):
        self.label_names = tuple(clips.label_names)
        self.joint_names = tuple(clips.skeleton.names)
        self.meta = {"store_key": f"fake-{window}"}
        pool = WindowSource(window=window).train_items(clips)
        j, y = real_set(pool, 10, 0, "fake-evaluator")
        self.proj = np.random.default_rng(0).normal(size=(j[0].size, 30)) / np.sqrt(j[0].size)
        f = self._feats(j)
        self.means = np.stack([f[y == c].mean(0) for c in range(len(self.label_names))])

    def _feats(self, joints):
        x = np.asarray(joints, np.float64)
        x = x - x[:, :1, :1, :]
        return x.reshape(len(x), -1) @ self.proj

    def encode(self, joints, lengths=None, seed=None):
        f = self._feats(joints)
        return f.astype(np.float32), -((f[:, None] - self.means[None]) ** 2).sum(-1)


class Copier:
    """Returns real training windows of the asked labels (a memoriser)."""

    method_id = "copier"

    def sample_windows(self, labels, n_frames, *, seed, pool):
        rng = np.random.default_rng(seed)
        lab = pool.clipset.labels[pool.indices]
        clips_ = [pool.indices[lab == int(c)][rng.integers(0, (lab == int(c)).sum())]
                  for c in labels.tolist()]
        return torch.from_numpy(pool.random_cut(np.asarray(clips_), rng).joints)


# -- the data layer ---------------------------------------------------------------------------

def test_window_pool_is_the_train_split_and_pairs_follow_the_rule(clips):
    src = WindowSource(window=20)
    pool = src.train_items(clips)
    assert set(np.unique(clips.split[pool.indices])) == {TRAIN}
    assert len(pool) == int((clips.split == TRAIN).sum())
    rng = np.random.default_rng(0)
    a, p = pool.draw_pairs(2000, rng)
    same = (a.labels == p.labels).mean()
    assert 0.45 < same < 0.55
    assert np.allclose(a.joints[:, 0, 0], 0.0)
    # class-balanced anchors: every class about 1/10
    counts = np.bincount(a.labels, minlength=clips.n_classes) / len(a)
    assert counts.min() > 0.06 and counts.max() < 0.14
    # the same seed draws the same windows
    b, _ = pool.draw_pairs(2000, np.random.default_rng(0))
    assert np.array_equal(a.joints, b.joints)
    assert set(np.unique(clips.split[a.indices])) == {TRAIN}
    assert src.pool(clips, TEST).indices.size == int((clips.split == TEST).sum())
    assert WindowSource.from_description(src.describe()) == src


def test_fixed_windows_as_action_items_match_the_xyz_windows(clips):
    pool = WindowSource(window=20, action_windows_per_clip=2).train_items(clips)
    items = pool.as_action_items()
    xyz = pool.fixed_windows().joints
    assert len(items) == 2 * len(pool)
    assert float((items.action.joints() - torch.from_numpy(xyz)).abs().max()) < 1e-4
    assert torch.allclose(items.canon.rotation, torch.eye(3).expand(len(items), 3, 3))
    # label-only condition items: identity placement, no data of any scored clip
    cond = label_condition_items(pool.label_names, [0, 3], 20, clips.skeleton, clips.fps,
                                 items.initial.select(torch.tensor([0])))
    assert cond.lengths.tolist() == [20, 20] and float(cond.canon.origin.abs().max()) == 0.0
    assert float(cond.initial.root.abs().max()) == 0.0


# -- odmo_generation --------------------------------------------------------------------------

def test_generation_scores_a_copier_like_real_data(clips):
    proto = get_protocol("odmo_generation", {"window": 20, "per_class": 12,
                                             "fid_references": ["train", "test"]})
    ev = FakeEvaluator(clips, 20)
    ctx = proto.test_items(clips)
    assert ctx.test is not None and len(ctx) == 12 * clips.n_classes
    out = proto.generate(Copier(), ctx, seed=0, replicate=0)
    vals = proto.measure(out, ctx, ev, seed=0)
    real = proto.real_replicate(clips, ctx, ev, seed=0, replicate=0)
    assert real["n_apd"] == pytest.approx(100.0, abs=1e-9)  # paired with itself
    assert set(vals) == {"acc", "fid", "fid_train", "fid_test", "div", "multimod", "n_apd"}
    assert vals["fid"] == vals["fid_train"]
    assert 50 < vals["n_apd"] < 200 and vals["acc"] > 20  # a copier of real windows
    # a generator that returns one frozen pose per class has no diversity: n-APD 0
    class Frozen(Copier):
        def sample_windows(self, labels, n_frames, *, seed, pool):
            w = super().sample_windows(labels, n_frames, seed=0, pool=pool)
            first = {int(c): w[i] for i, c in reversed(list(enumerate(labels.tolist())))}
            return torch.stack([first[int(c)] for c in labels.tolist()])
    frozen = proto.measure(proto.generate(Frozen(), ctx, seed=0, replicate=0), ctx, ev, seed=0)
    assert frozen["n_apd"] == pytest.approx(0.0, abs=1e-6)


def test_generation_samples_round_trip_and_bad_shapes(clips, tmp_path):
    proto = get_protocol("odmo_generation", {"window": 20, "per_class": 4})
    ctx = proto.test_items(clips)
    out = proto.generate(Copier(), ctx, seed=1, replicate=2)
    back = proto.load_generated(proto.save_generated(out, tmp_path / "g.npz"))
    assert np.array_equal(back.joints, out.joints) and np.array_equal(back.labels, out.labels)

    class Short(Copier):
        def sample_windows(self, labels, n_frames, *, seed, pool):
            return super().sample_windows(labels, n_frames, seed=seed, pool=pool)[:, :5]
    with pytest.raises(DataError, match="expected"):
        proto.generate(Short(), ctx, seed=0, replicate=0)
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(DataError):
        proto.load_generated(tmp_path / "bad.npz")


def test_rotation_generators_get_label_only_items(clips):
    """ACTOR / A2M get tags and durations only: the items hold no scored clip's frames."""
    seen = {}

    class Spy:
        method_id = "spy"

        def sample_joints(self, cond, *, seed):
            seen["cond"] = cond
            return cond.action.joints()

    proto = get_protocol("odmo_generation", {"window": 20, "per_class": 3})
    ctx = proto.test_items(clips)
    out = proto.generate(Spy(), ctx, seed=0, replicate=0)
    cond = seen["cond"]
    assert out.joints.shape == (30, 20, clips.skeleton.n_joints, 3)
    assert cond.labels.tolist() == ctx.labels.tolist()
    assert cond.clip_index is None and cond.styles is None
    # every item's pose is the same training-pool placeholder frame, moved to the origin
    assert torch.equal(cond.initial.rot6d, cond.initial.rot6d[:1].expand_as(cond.initial.rot6d))


# -- trajectory_customisation ---------------------------------------------------------------

class Bank:
    def __init__(self, codes, ends, labels):
        self.codes, self.ends, self.labels = codes, ends, labels


class FakeODMO:
    """decode() puts the root's last frame at target + (0.3, 0, 0.4): dist_e = 0.25 exactly."""

    method_id = "odmo"

    def __init__(self, pool):
        self.pool = pool

    def bank(self, pool, *, n_iter, seed):
        b = pool.draw(n_iter * 50, np.random.default_rng(seed))
        codes = np.concatenate([b.labels[:, None].astype(float), np.arange(len(b))[:, None]], 1)
        return Bank(codes, b.joints[:, -1, 0, :].astype(np.float64), b.labels)

    def decode(self, codes, labels, ends, n_frames):
        x = torch.zeros(len(codes), n_frames, self.pool.n_joints, 3)
        x[:, -1, :, :] = ends[:, None, :] + torch.tensor([0.3, 0.0, 0.4])
        return x


def test_trajectory_pairs_and_dist_e(clips):
    proto = get_protocol("trajectory_customisation", {"window": 20, "codes_per_class": 3,
                                                      "end_points_per_code": 5})
    ctx = proto.test_items(clips)
    gen = FakeODMO(ctx.train)
    bank = gen.bank(ctx.train, n_iter=2, seed=5)
    codes, labels, targets = proto.pairs(bank, clips.n_classes, 5)
    assert len(codes) == 3 * 5 * clips.n_classes
    # per code: 5 targets from the code's own end (first) to another window's end (last),
    # evenly spaced, all of the code's class
    for k in range(0, len(codes), 5):
        src = int(codes[k, 1])
        assert np.allclose(targets[k], bank.ends[src], atol=1e-6)
        assert bank.labels[src] == labels[k] and (labels[k:k + 5] == labels[k]).all()
        other = targets[k + 4]
        assert any(np.allclose(other, bank.ends[j], atol=1e-6)
                   for j in np.flatnonzero(bank.labels == labels[k]))
        assert np.allclose(targets[k + 2], (targets[k] + targets[k + 4]) / 2, atol=1e-5)
    out = proto.generate(gen, ctx, seed=0, replicate=0)
    vals = proto.measure(out, ctx, FakeEvaluator(clips, 20), seed=0)
    assert vals["dist_e"] == pytest.approx(0.25, abs=1e-5)  # squared, summed over xyz
    with pytest.raises(DataError, match="code bank"):
        proto.generate(Copier(), ctx, seed=0, replicate=0)


# -- latent_modes -----------------------------------------------------------------------------

class StyleEncoder:
    """latent_codes = a point per style (planted modes = styles) + small noise."""

    method_id = "style"

    def __init__(self, clips):
        self.clips = clips

    def latent_codes(self, joints):
        raise AssertionError("replaced per call below")


def test_latent_modes_recover_planted_styles(clips, monkeypatch):
    proto = get_protocol("latent_modes", {"window": 20, "codes_per_class": 150,
                                          "k_rule": "code"})
    ctx = proto.test_items(clips)
    gen = StyleEncoder(clips)
    centres = np.random.default_rng(0).normal(scale=20.0, size=(7, 4))
    b = proto.windows(ctx, proto.replicate_seed(0, 0))
    styles = clips.styles[b.indices]
    gen.latent_codes = lambda joints: centres[styles] + np.random.default_rng(1).normal(
        scale=0.1, size=(len(styles), 4))
    out = proto.generate(gen, ctx, seed=0, replicate=0)
    assert np.array_equal(out.styles, styles)
    assert np.array_equal(out.padded, 20 - b.valid)
    vals = proto.measure(out, ctx, None, seed=0)
    assert set(vals) == {"mode_homogeneity", "style_ami", "style_ari"}
    assert vals["style_ami"] > 0.8 and vals["style_ari"] > 0.6
    assert proto.real_replicate(clips, ctx, None, seed=0, replicate=0) == {"mode_homogeneity": 0.0}
    # codes that carry no style information: AMI and ARI near 0 (chance-corrected)
    gen.latent_codes = lambda joints: np.random.default_rng(2).normal(size=(len(styles), 4))
    noise = proto.measure(proto.generate(gen, ctx, seed=0, replicate=0), ctx, None, seed=0)
    assert abs(noise["style_ami"]) < 0.05 and abs(noise["style_ari"]) < 0.05


def test_no_same_class_partner_is_its_own_clip(clips):
    pool = WindowSource(window=20, same_class_p=1.0).train_items(clips)
    rng = np.random.default_rng(0)
    anchors = pool.balanced_clips(3000, rng)
    partners = pool.partner_clips(anchors, rng)
    assert np.array_equal(clips.labels[anchors], clips.labels[partners])
    assert not np.any(anchors == partners)
    a, p = pool.draw_pairs(2000, np.random.default_rng(1))
    same = a.labels == p.labels
    assert same.any() and not np.any(a.indices[same] == p.indices[same])
    # a class with one clip in the pool (a small hold-out): its only clip, another window
    lab = clips.labels[pool.indices]
    one = pool.subset(np.concatenate([np.flatnonzero(lab == 0)[:1], np.flatnonzero(lab == 1)]))
    alone = np.repeat(one.indices[:1], 5)
    assert np.array_equal(one.partner_clips(alone, np.random.default_rng(0)), alone)
    other = one.partner_clips(np.repeat(one.indices[1:2], 50), np.random.default_rng(0))
    assert np.all(clips.labels[other] == 1) and not np.any(other == one.indices[1])


def test_window_strips_show_the_same_sample_of_every_row(clips):
    """ODMO's strips: per picked sample, a real training window of its tag on top, then every
    row's sample at that position (grounded for display)."""
    from types import SimpleNamespace

    from repro.report.strip_sets import _window_strips

    proto = get_protocol("odmo_generation", {"window": 20, "per_class": 3})
    ctx = proto.test_items(clips)
    a = proto.generate(Copier(), ctx, seed=0, replicate=0)
    b = proto.generate(Copier(), ctx, seed=1, replicate=0)
    band = SimpleNamespace(items=ctx, index=0, label="odmo_generation", protocol_id="odmo_generation")
    rows = [(SimpleNamespace(label="A", row_id="a"), a), (SimpleNamespace(label="B", row_id="b"), b)]
    strips = _window_strips(band, rows, 2, 0, 4, 0)
    assert len(strips) == 2
    for st in strips:
        i = st.meta["item"]
        assert [p.label for p in st.panels] == ["Real (a training window)", "A", "B"]
        assert np.allclose(st.panels[1].joints[..., [0, 2]], a.joints[i][..., [0, 2]])
        assert min(float(p.joints[..., 1].min()) for p in st.panels) == pytest.approx(0.0, abs=1e-6)
        assert st.meta["tag"] == clips.label_names[int(a.labels[i])]
