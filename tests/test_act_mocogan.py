"""Act-MoCoGAN (repro/models/act_mocogan.py): shapes, seeds, save/load, the single-loss GAN step
(disjoint gradients, D toward discriminating, G toward fooling), the loss switches and a short
training on the bundled bandai2-mini windows."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from repro.data.odmo_items import WindowSource
from repro.errors import ConfigError
from repro.models.act_mocogan import D_TERMS, G_TERMS, ActMoCoGAN
from repro.models.base import Generator, generator_class
from repro.seeding import numpy_rng
from repro.train.validation import holdout
from model_fixtures import mini_clips, one_torch_thread  # noqa: F401 (fixtures)

WINDOW = 20
SMALL = {"dim_z_content": 8, "dim_z_motion": 4, "g_hidden": 64, "di_hidden": 64, "dv_hidden": 32,
         "dv_layers": 1, "batch_size": 32, "windows_per_epoch": 64, "epochs": 10,
         "val_windows": 32}


@pytest.fixture(scope="module")
def clips(mini_clips):
    return mini_clips


@pytest.fixture(scope="module")
def items(clips):
    return WindowSource(window=WINDOW).train_items(clips)


def make(clips, **over):
    return ActMoCoGAN({**SMALL, **over}, clips.skeleton, clips.n_classes, float(clips.fps))


@pytest.fixture(scope="module")
def trained(clips, items):
    gen = make(clips, lr=1e-3)
    result = gen.fit(items, seed=0)
    return gen, result


def real_batch(items, n, seed=0):
    wb = items.draw(n, numpy_rng(seed, "test_act_mocogan"))
    return {"joints": torch.from_numpy(wb.joints),
            "labels": torch.from_numpy(wb.labels.astype(np.int64))}


def test_defaults_registry_and_bad_configs(clips):
    gen = ActMoCoGAN(None, clips.skeleton, clips.n_classes, float(clips.fps))
    cfg = gen.config
    assert (cfg.dim_z_content, cfg.dim_z_motion) == (50, 10)          # MoCoGAN train.py
    assert (cfg.lr, cfg.beta1, cfg.beta2, cfg.weight_decay) == (2e-4, 0.5, 0.999, 1e-5)
    assert (cfg.batch_size, cfg.windows_per_epoch) == (512, 2048)       # ODMO's loader
    assert ActMoCoGAN.item_kind == "windows"
    assert generator_class("act_mocogan") is ActMoCoGAN
    net = gen.network
    J, C = clips.skeleton.n_joints, clips.n_classes
    assert net.motion.input_size == net.motion.hidden_size == 10
    assert net.pose.main[0].in_features == 50 + C + 10
    assert net.pose.main[-1].out_features == 3 * J
    assert net.d_image.main[0].in_features == 3 * J
    assert net.d_video.fc2.out_features == 1 + C
    assert make(clips, di_class=True).network.d_image.main[0].in_features == 3 * J + C
    for bad in ({"dim_z_motion": 0}, {"lr": 0.0}, {"beta1": 1.0}, {"nope": 1}):
        with pytest.raises(ConfigError):
            make(clips, **bad)


def test_sample_windows_shapes_frame_and_errors(clips):
    gen = make(clips)
    x = gen.sample_windows([0, 3, 9, 3], 37, seed=1)
    assert x.shape == (4, 37, clips.skeleton.n_joints, 3) and x.dtype == torch.float32
    assert torch.isfinite(x).all()
    assert torch.equal(x[:, 0, 0], torch.zeros(4, 3))            # first-frame root at origin
    assert x[:, 1:].abs().sum() > 0
    assert gen.sample_windows([], 5, seed=0).shape == (0, 5, clips.skeleton.n_joints, 3)
    with pytest.raises(ConfigError, match="sample_windows"):
        gen.sample(None, seed=0)
    with pytest.raises(ConfigError):
        gen.sample_windows([clips.n_classes], 5, seed=0)
    with pytest.raises(ConfigError):
        gen.sample_windows([0], 0, seed=0)
    with pytest.raises(TypeError):
        gen.fit(object(), seed=0)


def test_sampling_determinism_and_conditioning(clips):
    gen = make(clips)
    labels = [1, 2, 2, 5, 7]
    a = gen.sample_windows(labels, WINDOW, seed=3)
    assert torch.equal(a, gen.sample_windows(labels, WINDOW, seed=3))
    assert not torch.equal(a, gen.sample_windows(labels, WINDOW, seed=4))
    assert not torch.equal(a[1], a[2])                     # same label, own noise per item
    b = gen.sample_windows([0] * 5, WINDOW, seed=3)
    assert not torch.allclose(a, b)                        # the label enters the generator
    # per-item noise: the sampling batch size does not change a sample (up to matmul rounding)
    small_batches = ActMoCoGAN({**SMALL, "sample_batch_size": 2}, clips.skeleton,
                               clips.n_classes, float(clips.fps))
    small_batches.network.load_state_dict(gen.network.state_dict())
    assert torch.allclose(a, small_batches.sample_windows(labels, WINDOW, seed=3), atol=1e-6)


def test_save_load_round_trip(trained, tmp_path):
    gen, _ = trained
    gen.save(tmp_path / "g")
    back = Generator.load(tmp_path / "g")
    assert isinstance(back, ActMoCoGAN) and back.config == gen.config
    assert torch.equal(gen.sample_windows([0, 4, 8], 25, seed=7),
                       back.sample_windows([0, 4, 8], 25, seed=7))


def _split(state, part):
    is_d = lambda k: k.startswith(("d_image.", "d_video."))
    return {k: v for k, v in state.items() if is_d(k) == (part == "D")}


def test_one_step_moves_d_to_discriminate_and_g_to_fool(clips, items):
    gen = make(clips)
    net = gen.network
    net.train()
    batch = real_batch(items, 64)
    Dp, Gp = net.discriminator_parameters(), net.generator_parameters()
    assert {id(p) for p in Dp} | {id(p) for p in Gp} == {id(p) for p in net.parameters()}

    torch.manual_seed(11)
    terms = gen.losses(net, batch)
    assert set(D_TERMS) | set(G_TERMS) <= set(terms)
    d = sum(terms[k] for k in D_TERMS)
    g = sum(terms[k] for k in G_TERMS)
    # the discriminator terms see detached fakes, the generator terms frozen discriminators
    assert all(x is None for x in torch.autograd.grad(d, Gp, retain_graph=True, allow_unused=True))
    assert all(x is None for x in torch.autograd.grad(g, Dp, retain_graph=True, allow_unused=True))
    gd = torch.autograd.grad(d, Dp, retain_graph=True)
    gg = torch.autograd.grad(g, Gp)
    assert all(p.requires_grad for p in net.parameters())          # flags restored

    # the loop's single backward of "loss" gives each side exactly its own gradient
    opt = gen.make_optimizer()
    torch.manual_seed(11)
    out = gen.training_step(net, batch, 0)
    assert torch.allclose(out["loss"], d + g)
    opt.zero_grad(set_to_none=True)
    out["loss"].backward()
    for p, ref in zip(Dp, gd):
        assert torch.allclose(p.grad, ref, atol=1e-7)
    for p, ref in zip(Gp, gg):
        assert torch.allclose(p.grad, ref, atol=1e-7)
    assert sum(float(x.abs().sum()) for x in gd) > 0 and sum(float(x.abs().sum()) for x in gg) > 0
    before = copy.deepcopy(net.state_dict())
    opt.step()
    after = copy.deepcopy(net.state_dict())

    def terms_with(d_state, g_state):
        mixed = copy.deepcopy(net)
        mixed.load_state_dict({**d_state, **g_state})
        torch.manual_seed(11)                       # same noise and frames as the step saw
        with torch.no_grad():
            return gen.losses(mixed, batch)

    new_d = terms_with(_split(after, "D"), _split(before, "G"))
    new_g = terms_with(_split(before, "D"), _split(after, "G"))
    # D toward discriminating (same fakes), each discriminator on its own parameters
    assert new_d["d_image"] < terms["d_image"]
    assert new_d["d_video"] + new_d["d_category"] < terms["d_video"] + terms["d_category"]
    # G toward fooling the discriminators it was stepped against
    assert sum(new_g[k] for k in G_TERMS) < g


def test_loss_switches_remove_their_terms(clips, items):
    batch = real_batch(items, 32, seed=1)
    ref = make(clips)
    state = ref.network.state_dict()
    torch.manual_seed(5)
    full = ref.training_step(ref.network, batch, 0)
    for switch, term in (("use_categories", "d_category"), ("use_infogan", "g_category")):
        off = make(clips, **{switch: False})
        off.network.load_state_dict(state)
        torch.manual_seed(5)
        out = off.training_step(off.network, batch, 0)
        assert term not in out and term in full
        assert torch.allclose(full["loss"] - out["loss"], full[term], atol=1e-5)
    # the class-conditioned image discriminator sees the one-hot
    cond = make(clips, di_class=True)
    net = cond.network
    x = net.image_input(batch["joints"][:, 3], batch["labels"])
    assert torch.equal(x[:, -clips.n_classes:],
                       torch.nn.functional.one_hot(batch["labels"], clips.n_classes).float())
    # root-relative poses by default; absolute window-frame poses when switched off
    assert torch.equal(make(clips).network.image_input(batch["joints"][:, 3], batch["labels"])[:, :3],
                       torch.zeros(32, 3))
    absolute = make(clips, di_root_relative=False).network
    assert torch.equal(absolute.image_input(batch["joints"][:, 3], batch["labels"]),
                       batch["joints"][:, 3].reshape(32, -1))


def test_short_training_is_finite_and_d_discriminates(trained, items):
    gen, result = trained
    hist = result.history
    assert len(hist) == SMALL["epochs"] and all(h["batches"] == 2 for h in hist)
    for h in hist:
        assert all(np.isfinite(v) for v in h.values())
    # the discriminators tell fresh real windows from fresh samples (pairwise accuracy: the
    # share of (real, fake) pairs where the real one gets the higher logit; chance = 0.5)
    batch = real_batch(items, 128, seed=2)
    real, labels = batch["joints"], batch["labels"]
    fake = gen.sample_windows(labels, WINDOW, seed=9)
    net = gen.network
    with torch.no_grad():
        rv, _ = net.d_video(real.reshape(128, WINDOW, -1))
        fv, _ = net.d_video(fake.reshape(128, WINDOW, -1))
        ri = net.d_image(net.image_input(real[:, 10], labels))
        fi = net.d_image(net.image_input(fake[:, 10], labels))
    pairwise = lambda r, f: float((r[:, None] > f[None, :]).float().mean())
    assert pairwise(ri, fi) > 0.9
    assert pairwise(rv, fv) > 0.7
    # the generator still produces windows in the window frame
    assert torch.equal(fake[:, 0, 0], torch.zeros(128, 3))


def test_training_is_deterministic_and_validation_changes_nothing(clips, items, trained):
    gen, result = trained
    again = make(clips, lr=1e-3)
    train_items, val_items = holdout(items, 0.1, 0)
    assert val_items is not None
    with_val = make(clips, lr=1e-3, epochs=3)
    without = make(clips, lr=1e-3, epochs=3)
    r_val = with_val.fit(train_items, seed=2, val_items=val_items)
    without.fit(train_items, seed=2)
    for a, b in zip(with_val.network.state_dict().values(), without.network.state_dict().values()):
        assert torch.equal(a, b)
    assert {"val_loss", "val_d_video", "val_g_video", "val_acc_video"} <= set(r_val.history[-1])
    # same seed, same weights; another seed, other weights
    r2 = again.fit(items, seed=0)
    assert [h["loss"] for h in r2.history] == [h["loss"] for h in result.history]
    for a, b in zip(gen.network.state_dict().values(), again.network.state_dict().values()):
        assert torch.equal(a, b)
    other = make(clips, lr=1e-3, epochs=1)
    other.fit(items, seed=1)
    assert not torch.equal(other.network.pose.main[0].weight, gen.network.pose.main[0].weight)


def test_resume_is_exact(clips, items, tmp_path):
    full = make(clips, epochs=4)
    full.fit(items, seed=3)
    first = make(clips, epochs=4)

    def stop_at_epoch_one(epoch, rec):
        if epoch == 1:           # the loop checkpoints after on_epoch: epoch 0 is saved
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        first.fit(items, seed=3, ckpt_dir=tmp_path, on_epoch=stop_at_epoch_one)
    resumed = make(clips, epochs=4)
    res = resumed.fit(items, seed=3, ckpt_dir=tmp_path)
    assert res.resumed_from == 1
    for a, b in zip(full.network.state_dict().values(), resumed.network.state_dict().values()):
        assert torch.equal(a, b)
