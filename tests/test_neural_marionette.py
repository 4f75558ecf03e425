"""NEURAL MARIONETTE (repro.models.neural_marionette): Shadow Start (Eq. 6 + the L2 step) and
Action Revision on a tiny MarioNet trained for one epoch; "never" is bitwise MarioNet; config
validation; save/load; training as MarioNet."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from repro.data.action_items import GeneratedItems
from repro.errors import ConfigError, DataError
from repro.models.base import Generator, generator_class
from repro.models.marionet import MarioNet, MarioNetConfig, pack_poses
from repro.models.neural_marionette import (INFERENCE_FIELDS, NeuralMarionette,
                                            NeuralMarionetteConfig, RevisedItems)
from model_fixtures import clips, items, one_torch_thread, test_items  # noqa: F401 (fixtures)

TINY = dict(d_model=16, traj_dim=4, cond_heads=2, cond_ff=32, cond_layers=1, traj_heads=1,
            traj_ff=8, unroll_heads=2, unroll_ff=32, unroll_layers=1, dec_heads=2, dec_ff=32,
            dec_layers=2, batch_size=8, lr=1e-3, epochs=1, ss_activate_epoch=1,
            ss_accomplish_epoch=3, sample_batch_size=4)
NEVER = {"shadow_start": "never", "action_revision": False}
ALWAYS = {"shadow_start": "always", "action_revision": False}
NM = {"shadow_start": "on_revision", "action_revision": True}


@pytest.fixture(scope="module")
def marionet(clips, items):
    m = MarioNet(TINY, clips.skeleton, clips.n_classes, clips.fps)
    m.fit(items, seed=0)
    return m


def nm(marionet, items=None, **options):
    g = NeuralMarionette.from_marionet(marionet, options)
    if items is not None:
        g.set_shadow_bank(items)
    return g


def same(a: GeneratedItems, b: GeneratedItems) -> bool:
    return torch.equal(a.root, b.root) and torch.equal(a.rot6d, b.rot6d)


def spy_generate(g):
    """Record every first_feature the decoder receives (None: the real BOP embedding)."""
    seen = []
    orig = g.network.generate

    def gen(*a, **k):
        ff = k.get("first_feature")
        seen.append(None if ff is None else ff.clone())
        return orig(*a, **k)

    g.network.generate = gen
    return seen


# -- configuration -----------------------------------------------------------------------------


def test_config_fields_and_validation(clips):
    assert INFERENCE_FIELDS == {"shadow_start", "action_revision", "ss_l2_normalize",
                                "ss_neighbours", "ss_norm", "revision_classifier"}
    cfg = NeuralMarionetteConfig()
    assert (cfg.shadow_start, cfg.action_revision, cfg.ss_l2_normalize, cfg.ss_norm) == \
        ("on_revision", True, True, "unit")
    assert cfg.revision_classifier is None             # the ss_ar protocol's choice
    assert cfg.ss_neighbours == 16 and cfg.d_model == MarioNetConfig().d_model
    assert generator_class("neural_marionette") is NeuralMarionette
    assert NeuralMarionette.trains_as == "marionet"
    assert NeuralMarionette.inference_fields == INFERENCE_FIELDS
    sk, n, fps = clips.skeleton, clips.n_classes, clips.fps
    g = NeuralMarionette({**TINY, **ALWAYS, "ss_neighbours": 4}, sk, n, fps)
    assert not g.needs_classifier and g.needs_shadow_bank
    assert NeuralMarionette({**TINY, **NM}, sk, n, fps).needs_classifier
    assert not NeuralMarionette({**TINY, **NEVER}, sk, n, fps).needs_shadow_bank
    # the training config is MarioNet's: inference fields stripped, the rest kept
    assert g.training_config() == MarioNetConfig(**TINY)
    train, infer = NeuralMarionette.split_config(g.config)
    assert set(infer) == INFERENCE_FIELDS and not set(train) & INFERENCE_FIELDS
    bad = [({"shadow_start": "always"}, "action_revision"),              # AR needs on_revision
           ({"shadow_start": "never"}, "action_revision"),
           ({"action_revision": False}, "shadow_start"),                # on_revision needs AR
           ({"ss_neighbours": 0}, "ss_neighbours"),
           ({"ss_norm": "l1"}, "ss_norm"),
           ({"revision_classifier": "oracle"}, "revision_classifier"),
           ({**ALWAYS, "revision_classifier": "evaluator"}, "revision_classifier"),
           ({"shadow_start": "sometimes"}, "shadow_start"),
           ({"ss_neighbourz": 3}, "ss_neighbourz")]
    for over, field in bad:
        with pytest.raises(ConfigError, match=field):
            NeuralMarionette({**TINY, **over}, sk, n, fps)


def test_from_marionet_shares_weights_and_rejects_training_changes(marionet, items):
    g = nm(marionet, **ALWAYS)
    assert g.config.shadow_start == "always" and g.config.d_model == TINY["d_model"]
    for (k, a), b in zip(marionet.network.state_dict().items(), g.network.state_dict().values()):
        assert torch.equal(a, b), k
    assert g.shadow_bank_key is None  # the bank is never carried over
    with pytest.raises(ConfigError, match="d_model"):
        NeuralMarionette.from_marionet(marionet, {"d_model": 32, **NEVER})
    with pytest.raises(ConfigError, match="action_revision"):
        NeuralMarionette.from_marionet(marionet, {"shadow_start": "always"})
    # repeating a training value is fine
    assert NeuralMarionette.from_marionet(marionet, {"d_model": 16, **NEVER}).config.d_model == 16


# -- "never" is MarioNet -----------------------------------------------------------------------


def test_never_is_bitwise_marionet(marionet, items, test_items):
    g = nm(marionet, **NEVER)           # no bank needed
    seen = spy_generate(g)
    for cond, kw in ((items, {}), (test_items, {}), (items, {"use_mean": True}),
                     (items, {"use_cache": False})):
        out = g.sample(cond, seed=3, **kw)
        ref = marionet.sample(cond, seed=3, **kw)
        assert isinstance(out, RevisedItems) and same(out, ref)
        assert torch.equal(out.lengths, ref.lengths) and torch.equal(out.labels, ref.labels)
        assert not out.revised.any() and not out.shadow_start.any()
    assert seen and all(ff is None for ff in seen)   # the BOP embedding is left alone
    assert not same(g.sample(items, seed=4), marionet.sample(items, seed=3))


# -- Shadow Start (Eq. 6) ----------------------------------------------------------------------


def _np_embed(g, poses: torch.Tensor) -> np.ndarray:
    """FC(P) recomputed in numpy from the weights (standardise, Linear, ReLU)."""
    net = g.network
    x = poses.double().numpy()
    x = (x - net.pose_mean.double().numpy()) / net.pose_std.double().numpy()
    lin = net.pose_encode[0]
    y = x @ lin.weight.detach().double().numpy().T + lin.bias.detach().double().numpy()
    return np.maximum(y, 0.0)


def _np_shadow(g, bank_items, cond, k, l2=None, radii=None):
    f0 = _np_embed(g, pack_poses(cond.initial)[:, -1])
    bank = _np_embed(g, pack_poses(bank_items.initial)[:, -1])
    bl = bank_items.labels.numpy()
    out = []
    radii = [] if radii is None else radii
    for i in range(len(cond)):
        cand = bank[bl == int(cond.labels[i])]
        near = np.argsort(((cand - f0[i]) ** 2).sum(-1), kind="stable")[:k]
        F = cand[near]
        radii.append(np.linalg.norm(F, axis=1).mean())
        phi = np.linalg.lstsq(F.T, f0[i], rcond=None)[0]
        p = phi @ F
        if l2 == "unit":
            p = p / np.linalg.norm(p)
        elif l2 == "neighbours":  # the embedding-norm reading: radius = mean ||f~^i|| of F~
            p = p / np.linalg.norm(p) * np.linalg.norm(F, axis=1).mean()
        elif l2 == "match":
            p = p / np.linalg.norm(p) * np.linalg.norm(f0[i])
        out.append(p)
    return f0, np.stack(out)


def test_shadow_start_is_the_projection_onto_nearest_same_tag_bops(marionet, items, test_items):
    # bank = half of the training items, so the test BOPs and the other half lie off the span
    keep = [i for i in range(len(items)) if i % 2 == 0]
    bank = items.subset(keep)
    cond = items.subset([i for i in range(len(items)) if i % 2 == 1])
    n_per_tag = np.bincount(bank.labels.numpy())
    assert n_per_tag.min() >= 2
    for c in (test_items, cond):
        for k in (2, 16):               # 16 > bank items per tag: all of them are used
            g = nm(marionet, bank, **ALWAYS, ss_neighbours=k, ss_l2_normalize=False)
            f = g.shadow_start_features(c)
            f0, ref = _np_shadow(g, bank, c, k)
            assert f.shape == (len(c), TINY["d_model"]) and f.dtype == torch.float32
            assert np.allclose(f.numpy(), ref, atol=1e-5)
            assert np.allclose(g.bop_embeddings(c).numpy(), f0, atol=1e-5)
            assert not np.allclose(f.numpy(), f0, atol=1e-3)      # a real projection
            assert not np.allclose(f.norm(dim=1).numpy(), 1.0)     # no L2 step
            # the L2 step: unit norm ("unit", the literal reading), the mean norm of the
            # retrieved training embeddings ("neighbours", the embedding-norm reading) or
            # ||f0|| ("match"); the direction is the projection's under every reading
            radii: list = []
            _np_shadow(g, bank, c, k, radii=radii)
            direction = ref / np.linalg.norm(ref, axis=1, keepdims=True)
            for norm in ("unit", "neighbours", "match"):
                gn = nm(marionet, bank, **ALWAYS, ss_neighbours=k, ss_norm=norm)
                fn = gn.shadow_start_features(c)
                assert np.allclose(fn.numpy(), _np_shadow(gn, bank, c, k, norm)[1], atol=1e-5)
                want = {"unit": np.ones(len(c)), "neighbours": np.asarray(radii),
                        "match": np.linalg.norm(f0, axis=1)}[norm]
                assert np.allclose(fn.norm(dim=1).numpy(), want, rtol=1e-5, atol=1e-5)
                assert np.allclose(fn.numpy() / want[:, None], direction, atol=1e-4)
            # the embedding norm is not the unit sphere, nor ||f0||, here
            assert not np.allclose(radii, 1.0, atol=1e-2)
            assert not np.allclose(radii, np.linalg.norm(f0, axis=1), atol=1e-3)


def test_shadow_start_leaves_a_bop_in_the_span_unchanged(marionet, items):
    # every training item's own BOP is in the bank (distance 0: its own nearest neighbour)
    for k in (1, 3):
        g = nm(marionet, items, **ALWAYS, ss_neighbours=k, ss_l2_normalize=False)
        f0 = g.bop_embeddings(items)
        assert torch.allclose(g.shadow_start_features(items), f0, atol=1e-5)
    gl = nm(marionet, items, **ALWAYS, ss_neighbours=3)
    fl = gl.shadow_start_features(items)
    assert torch.allclose(fl, f0 / f0.norm(dim=1, keepdim=True), atol=1e-5)


def test_shadow_start_needs_a_bank_with_the_tag(marionet, items, test_items):
    g = nm(marionet, **ALWAYS)
    with pytest.raises(ConfigError, match="set_shadow_bank"):
        g.shadow_start_features(test_items)
    with pytest.raises(ConfigError, match="set_shadow_bank"):
        g.sample(test_items, seed=0)
    g.set_shadow_bank(items.subset(torch.nonzero(items.labels != 2).reshape(-1)))
    with pytest.raises(DataError, match="tag 2"):
        g.shadow_start_features(test_items)


def test_always_feeds_the_projection_to_the_decoder_only(marionet, items, test_items):
    g = nm(marionet, items.subset(list(range(0, len(items), 2))), **ALWAYS, ss_neighbours=2)
    seen = spy_generate(g)
    encoded = []
    orig_encode = g.network.encode
    g.network.encode = lambda init, *a: (encoded.append(init.clone()), orig_encode(init, *a))[1]
    out = g.sample(items, seed=3)
    # batched like MarioNet (sample_batch_size 4), the decoder got f0* at step 0 of every item
    assert len(seen) == -(-len(items) // TINY["sample_batch_size"])
    assert torch.equal(torch.cat(seen), g.shadow_start_features(items))
    # the condition encoder still sees the real initial motion
    assert torch.equal(torch.cat(encoded), pack_poses(items.initial).float())
    assert out.shadow_start.all() and not out.revised.any()
    plain = marionet.sample(items, seed=3)
    assert not same(out, plain)
    # same noise as the plain pass: a projection that changes nothing gives MarioNet's output
    own = nm(marionet, items, **ALWAYS, ss_neighbours=3, ss_l2_normalize=False)
    assert torch.allclose(own.sample(items, seed=3).root, plain.root, atol=1e-4)


# -- Action Revision ---------------------------------------------------------------------------


class FakeClassifier:
    """Marks the items ``wrong`` as misrecognised; counts calls and keeps what it saw."""

    def __init__(self, wrong, kind="torch"):
        self.wrong, self.kind, self.calls, self.seen = list(wrong), kind, 0, []

    def __call__(self, generated):
        self.calls += 1
        self.seen.append(generated)
        ok = np.ones(len(generated), dtype=bool)
        ok[self.wrong] = False
        as_kind = {"torch": torch.from_numpy, "numpy": np.asarray,
                   "list": lambda a: a.astype(int).tolist()}
        return as_kind[self.kind](ok)


def test_action_revision_regenerates_exactly_the_misclassified_once(marionet, items):
    bank = items.subset(list(range(0, len(items), 2)))
    g = nm(marionet, bank, **NM, ss_neighbours=2)
    seen = spy_generate(g)
    wrong = [1, 6, 7, 13]                           # across the batches of 4
    clf = FakeClassifier(wrong)
    out = g.sample(items, seed=5, classify=clf)
    plain = marionet.sample(items, seed=5)
    assert clf.calls == 1 and same(clf.seen[0], plain)   # classified the plain pass, once
    mask = torch.zeros(len(items), dtype=torch.bool)
    mask[wrong] = True
    assert torch.equal(out.revised, mask) and torch.equal(out.shadow_start, mask)
    keep = ~mask
    assert torch.equal(out.root[keep], plain.root[keep])
    assert torch.equal(out.rot6d[keep], plain.rot6d[keep])
    for i in wrong:
        assert not torch.equal(out.root[i], plain.root[i])
    # the decoder ran the plain pass (4 batches) and one SS pass over the 4 revised items
    assert len(seen) == 4 + 1 and all(ff is None for ff in seen[:4])
    assert seen[4].shape == (len(wrong), TINY["d_model"])
    # the revised items = a direct Shadow Start generation of that subset with the revision seed
    sub = items.subset(wrong)
    direct = nm(marionet, bank, **ALWAYS, ss_neighbours=2).sample(
        sub, seed=NeuralMarionette.revision_seed(5))
    T = direct.root.shape[1]
    assert torch.equal(out.root[mask][:, :T], direct.root)
    assert torch.equal(out.rot6d[mask][:, :T], direct.rot6d)
    # past each item's length the last valid frame repeats (as in every GeneratedItems)
    for j, i in enumerate(wrong):
        L = int(items.lengths[i])
        assert torch.equal(out.root[i, L:], out.root[i, L - 1:L].expand_as(out.root[i, L:]))
    assert torch.equal(out.lengths, items.lengths) and torch.equal(out.labels, items.labels)
    # deterministic; the result does not depend on the classifier's return type
    for kind in ("numpy", "list"):
        again = g.sample(items, seed=5, classify=FakeClassifier(wrong, kind))
        assert same(again, out) and torch.equal(again.revised, out.revised)


def test_action_revision_all_recognised_and_errors(marionet, items, test_items):
    g = nm(marionet, items, **NM)
    seen = spy_generate(g)
    clf = FakeClassifier([])
    out = g.sample(test_items, seed=2, classify=clf)
    assert clf.calls == 1 and len(seen) == 1 and not out.revised.any()
    assert same(out, marionet.sample(test_items, seed=2))
    with pytest.raises(ConfigError, match="classif"):
        g.sample(test_items, seed=2)
    with pytest.raises(DataError, match="shape"):
        g.sample(test_items, seed=2, classify=lambda gen: torch.ones(len(gen) + 1) > 0)
    with pytest.raises(DataError, match="boolean"):
        g.sample(test_items, seed=2, classify=lambda gen: torch.full((len(gen),), 0.5))
    # no bank: refused before any generation
    fresh = nm(marionet, **NM)
    with pytest.raises(ConfigError, match="set_shadow_bank"):
        fresh.sample(test_items, seed=2, classify=FakeClassifier([0]))


# -- persistence and training ------------------------------------------------------------------


def test_save_load_roundtrip(marionet, items, test_items, tmp_path):
    g = nm(marionet, items, **NM, ss_neighbours=3, ss_norm="match")
    d = g.save(tmp_path / "nm")
    meta = json.loads((d / "config.json").read_text())
    assert meta["method_id"] == "neural_marionette"
    assert meta["config"]["shadow_start"] == "on_revision" and meta["config"]["ss_neighbours"] == 3
    ref = g.sample(test_items, seed=4, classify=FakeClassifier([1]))
    for loaded in (NeuralMarionette.load(d), Generator.load(d)):
        assert type(loaded) is NeuralMarionette and loaded.config == g.config
        assert loaded.shadow_bank_key is None          # the bank is not saved
        with pytest.raises(ConfigError, match="set_shadow_bank"):
            loaded.sample(test_items, seed=4, classify=FakeClassifier([1]))
        loaded.set_shadow_bank(items)
        assert loaded.shadow_bank_key == items.key()
        got = loaded.sample(test_items, seed=4, classify=FakeClassifier([1]))
        assert same(got, ref) and torch.equal(got.revised, ref.revised)
    # a saved MarioNet is not a saved NeuralMarionette: go through from_marionet
    md = marionet.save(tmp_path / "mn")
    with pytest.raises(DataError, match="marionet"):
        NeuralMarionette.load(md)
    assert isinstance(NeuralMarionette.from_marionet(MarioNet.load(md), NEVER), NeuralMarionette)


def test_fit_trains_the_marionet_weights(clips, items, marionet):
    g = NeuralMarionette({**TINY, **NM}, clips.skeleton, clips.n_classes, clips.fps)
    g.fit(items, seed=0)
    for (k, a), b in zip(marionet.network.state_dict().items(), g.network.state_dict().values()):
        assert torch.equal(a, b), k
    assert g.shadow_bank_key == items.key()           # fit sets the bank from its items
