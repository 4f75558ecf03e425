"""ODMO (repro.models.odmo, odmo_nets): the code's shapes and readings by default, the window
length the network is built for, determinism, save/load, every loss switch
removing its term, the contrastive and KL forms against their formulas, the teacher-forcing
schedule, the 1-NN end point, mode-preserving and conventional sampling on planted banks, and
a short training lowering the loss.  Windows of the bundled bandai2-mini set (21 joints)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from repro.data.odmo_items import WindowSource
from repro.data.registry import load_clipset
from repro.errors import ConfigError
from repro.models.base import Generator, generator_class
from repro.models.odmo import (ODMO, Bank, ODMOConfig, contrastive_loss, kl_term,
                               mode_preserving_codes)
from repro.seeding import numpy_rng
from model_fixtures import one_torch_thread  # noqa: F401 (autouse fixture)

# the code's shapes (no separate "embed": the embedding widths are "hidden"), built for 20-frame
# windows; the fitted fixture leaves "window" unset so that fit adopts the items'
TINY = {"enc_hidden": 16, "enc_feature": 16, "hidden": 32, "window": 20, "epochs": 2,
        "windows_per_epoch": 32, "batch_size": 16, "val_pairs": 16}


@pytest.fixture(scope="module")
def items():
    return WindowSource(window=20).train_items(load_clipset("bandai2-mini"))


def make(items, **over) -> ODMO:
    return ODMO({**TINY, **over}, items.skeleton, items.n_classes, items.fps)


@pytest.fixture(scope="module")
def fitted(items):
    g = make(items, window=None)
    g.fit(items, seed=3)
    assert g.config.window == items.window == 20  # adopted from the items, saved with the config
    return g


def one_batch(items, n=8, seed=0) -> dict:
    a, p = items.draw_pairs(n, numpy_rng(seed, "test-batch"))
    return make(items)._pair_batches(a, p, items.y_weight)[0]


def step(g: ODMO, batch, epoch=0) -> dict:
    torch.manual_seed(11)
    g.net.train()
    return {k: float(v.detach()) for k, v in g.training_step(g.net, batch, epoch).items()}


def test_registered_shapes_and_paper_defaults(items, fitted):
    assert generator_class("odmo") is ODMO and ODMO.item_kind == "windows"
    assert ODMO.inference_fields == ("sampling", "k_rule", "conventional_form", "bank_iters")
    c = ODMOConfig()
    assert (c.latent_dim, c.enc_hidden, c.hidden, c.margin, c.sigma2, c.lr, c.batch_size,
            c.windows_per_epoch, c.epochs, c.tf_decay_epochs) == (20, 64, 128, 5.0, 0.05, 1e-3,
                                                                 512, 2048, 100_000, 4000)
    net, J, C = fitted.net, items.n_joints, items.n_classes
    assert net.encoder.lstm.hidden_size == 16 and net.trajectory.lstm.num_layers == 2
    x = torch.from_numpy(items.draw(5, numpy_rng(0, "x")).joints)
    mu, lv = net.encode(x)
    assert mu.shape == lv.shape == (5, 20)
    vel, traj, poses = net.generate(mu, torch.arange(5), x[:, -1, 0], 20)
    assert vel.shape == (5, 19, 3) and traj.shape == (5, 20, 3) and poses.shape == (5, 20, J, 3)
    assert torch.all(traj[:, 0] == 0)
    torch.testing.assert_close(traj[:, 1:], torch.cumsum(vel, 1))
    assert net.trajectory.expand.in_features == C * 20 + 3
    assert net.trajectory.expand.out_features == (C * 20 + 3) * 19   # one input per step
    assert net.motion.dec_embed.in_features == 3 * J + C * 20 + 1    # no trajectory term
    c = ODMOConfig()
    assert (c.traj_target, c.reduction, c.classic_mu_prior, c.encoder_head, c.trajectory_input,
            c.embed, c.enc_feature, c.window) == ("position", "code", False, "code", "code",
                                                  None, 256, None)
    untrained = make(items, window=None)
    with pytest.raises(ConfigError, match="window"):
        untrained.network
    codes = fitted.latent_codes(x.numpy())
    assert codes.shape == (5, 20) and codes.dtype == np.float64
    np.testing.assert_allclose(codes, mu.detach().double().numpy(), atol=1e-6)
    # the LMP: a translated window has the same code
    np.testing.assert_allclose(fitted.latent_codes(x.numpy() + 1.5), codes, atol=1e-5)
    with pytest.raises(ConfigError, match="sample_windows"):
        fitted.sample(None, seed=0)
    with pytest.raises(ConfigError):
        ODMO({"sampling": "nope"}, items.skeleton, items.n_classes, items.fps)


def test_sample_windows_order_determinism_and_save_load(tmp_path, items, fitted):
    kw = {"seed": 5, "pool": items, "n_iter": 2}
    a = fitted.sample_windows([3, 0, 3, 7], 20, **kw)
    assert a.shape == (4, 20, items.n_joints, 3) and a.dtype == torch.float32
    assert torch.equal(a, fitted.sample_windows([3, 0, 3, 7], 20, **kw))
    assert not torch.equal(a, fitted.sample_windows([3, 0, 3, 7], 20, **{**kw, "seed": 6}))
    b = fitted.sample_windows([0, 3, 3, 7], 20, **kw)  # same codes per class, scattered back
    assert torch.equal(a[[1, 0, 2, 3]], b)
    with pytest.raises(ConfigError, match="built for windows of 20 frames"):
        fitted.sample_windows([3, 0, 3, 7], 25, **kw)   # the code's per-frame input expansion
    rep = make(items, trajectory_input="repeat", window=None)  # harness variant: any length
    assert rep.sample_windows([3, 0], 25, seed=5, pool=items, n_iter=1).shape[1] == 25
    conv = fitted.sample_windows([3, 0, 3, 7], 20, **kw, sampling="conventional")
    assert conv.shape == a.shape and not torch.equal(conv, a)
    # the config's names of the inference fields, as a protocol passes them
    assert ODMO.uses_code_bank and torch.equal(conv, fitted.sample_windows(
        torch.tensor([3, 0, 3, 7]), 20, seed=5, pool=items, bank_iters=2,
        sampling="conventional", k_rule="paper", conventional_form="code"))
    with pytest.raises(ConfigError, match="pool"):
        fitted.sample_windows([0], 20, seed=0)
    fitted.save(tmp_path / "m")
    back = Generator.load(tmp_path / "m")
    assert isinstance(back, ODMO) and back.config == fitted.config
    assert torch.equal(back.sample_windows([3, 0, 3, 7], 20, **kw), a)


def test_training_is_seeded_and_inference_fields_do_not_change_it(items, fitted):
    same = make(items, sampling="conventional", k_rule="paper", bank_iters=3)
    same.fit(items, seed=3)
    for (k, v), w in zip(fitted.net.state_dict().items(), same.net.state_dict().values()):
        assert torch.equal(v, w), k
    assert same.key() == fitted.key()
    other = make(items)
    other.fit(items, seed=4)
    assert not torch.equal(other.net.state_dict()["motion.out.weight"],
                           fitted.net.state_dict()["motion.out.weight"])
    assert make(items, use_end=False).key() != fitted.key()


def test_validation_adds_a_curve_without_changing_the_weights(items, fitted):
    val = items.subset(np.arange(0, len(items), 5))
    g = make(items)
    hist = g.fit(items, seed=3, val_items=val).history
    assert {"val_loss", "val_mre", "val_kl", "val_contrastive"} <= set(hist[-1])
    assert torch.equal(g.net.state_dict()["encoder.feature.6.weight"],
                       fitted.net.state_dict()["encoder.feature.6.weight"])


def test_each_switch_removes_its_term(items):
    batch = one_batch(items)
    full = step(make(items), batch)
    assert {"loss", "mre", "traj", "cons", "contrastive", "kl"} == set(full)
    assert full["loss"] == pytest.approx(sum(v for k, v in full.items() if k != "loss"), rel=1e-5)
    for switch, term in (("contrastive", "contrastive"), ("cons_loss", "cons"),
                         ("traj_loss", "traj")):
        out = step(make(items, **{switch: False}), batch)
        assert term not in out and set(full) - set(out) == {term}
        assert out["loss"] == pytest.approx(sum(v for k, v in out.items() if k != "loss"),
                                            rel=1e-5)
        assert out["loss"] == pytest.approx(full["loss"] - full[term], rel=1e-5)
    # −L_es as the paper's "classic VAE" (supp. §3.1): the standard prior's μᵀμ per window,
    # per pair (the code's reading, the default, adds nothing: the set difference above)
    g = make(items, contrastive=False, classic_mu_prior=True)
    vae = step(g, batch)
    assert "contrastive" not in vae and "mu_prior" in vae
    with torch.no_grad():  # train mode as in the step: anchors and partners encoded as two
        # batches (the code's two model calls; BatchNorm statistics per side)
        mu = torch.cat([g.net.encode(batch["anchor"])[0], g.net.encode(batch["partner"])[0]])
    assert vae["mu_prior"] == pytest.approx(float(2 * (mu ** 2).sum(1).mean()), rel=1e-4)
    both = step(make(items, traj_loss=False, cons_loss=False), batch)
    assert "traj" not in both and "cons" not in both
    # weights scale their term; the reductions of the motion term: code = Σ_t mean over J·3,
    # "sum" = J·3 times it, "mean" = 1/T of it
    w = step(make(items, lambda_mre=2.0), batch)
    assert w["loss"] == pytest.approx(full["loss"] + full["mre"], rel=1e-5)
    m = step(make(items, reduction="mean"), batch)
    assert m["mre"] == pytest.approx(full["mre"] / 20, rel=1e-4)
    s = step(make(items, reduction="sum"), batch)
    assert s["mre"] == pytest.approx(full["mre"] * items.n_joints * 3, rel=1e-4)


def test_use_end_false_ignores_the_end_point(items):
    codes = np.random.default_rng(0).normal(size=(3, 20))
    labels, e1, e2 = np.array([0, 1, 2]), np.zeros((3, 3)), np.full((3, 3), 2.0)
    on, off = make(items), make(items, use_end=False)
    assert not torch.equal(on.decode(codes, labels, e1, 20), on.decode(codes, labels, e2, 20))
    assert torch.equal(off.decode(codes, labels, e1, 20), off.decode(codes, labels, e2, 20))
    assert torch.equal(on.decode(codes, labels, e1, 20),
                       on.decode(codes, labels, e2, 20, use_end=False))
    # in training too: the trajectory generator gets zeros (use_end False) or the real end
    batch = one_batch(items)
    for g, want in ((off, torch.zeros(16, 3)),
                    (on, torch.cat([batch["anchor"], batch["partner"]])[:, -1, 0])):
        seen: list[torch.Tensor] = []
        g.net.trajectory.register_forward_pre_hook(lambda mod, args, log=seen: log.append(args[1]))
        step(g, batch)
        assert len(seen) == 1 and torch.equal(seen[0], want)


def test_contrastive_forms_match_their_formulas():
    mu1 = torch.zeros(4, 20)
    mu2 = torch.zeros(4, 20)
    mu2[0, 0], mu2[1, 0], mu2[2, :2], mu2[3, 0] = 1.0, 0.4, torch.tensor([3.0, 4.0]), 1.0
    same = torch.tensor([True, True, False, False])          # d = 1, 0.4, 5, 1
    code = contrastive_loss(mu1, mu2, same, margin=5.0, form="code")
    paper = contrastive_loss(mu1, mu2, same, margin=5.0, form="paper")
    torch.testing.assert_close(code, torch.tensor([0.5 * 0.75, 0.0, 0.0, 0.5 * 16.0]))
    torch.testing.assert_close(paper, torch.tensor([1.0, 0.16, 0.0, 16.0]))


@pytest.mark.parametrize("form,reading", [("code", "std"), ("code", "variance"),
                                          ("paper", "std"), ("paper", "variance")])
def test_kl_forms_match_the_closed_forms(form, reading):
    s2 = torch.tensor([0.01, 0.0025, 0.05, 1.0]).repeat(5)   # posterior variances, D = 20
    got = kl_term(s2.log()[None], form=form, sigma2=0.05, reading=reading)[0]
    v = 0.0025 if reading == "std" else 0.05                 # prior variance
    if form == "code":
        ref = torch.distributions.kl_divergence(torch.distributions.Normal(0.0, s2.sqrt()),
                                                torch.distributions.Normal(0.0, math.sqrt(v)))
    else:
        ref = -s2.log() + s2 / v
    assert float(got) == pytest.approx(float(ref.sum()), rel=1e-5)
    lv = torch.full((1, 20), math.log(v), requires_grad=True)  # minimal at the prior variance
    kl_term(lv, form=form, sigma2=0.05, reading=reading).sum().backward()
    assert float(lv.grad.abs().max()) < 1e-4


def test_teacher_forcing_schedule(items):
    g = make(items, tf_decay_epochs=400)
    assert [g.teacher_forcing(e) for e in (0, 200, 400, 5000)] == pytest.approx(
        [1.0, 0.65, 0.3, 0.3])
    assert ODMO(None, items.skeleton, items.n_classes, items.fps).teacher_forcing(2000) == \
        pytest.approx(0.65)


def _bank(codes, labels, ends=None) -> Bank:
    n = len(labels)
    ends = np.arange(n * 3, dtype=float).reshape(n, 3) if ends is None else ends
    z = np.zeros(n, np.int64)
    return Bank(np.asarray(codes, float), ends, np.asarray(labels, np.int64), z, z, z)


def test_end_point_is_the_nearest_same_class_bank_code():
    codes = np.zeros((5, 20))
    codes[:, 0] = [0.0, 1.0, 2.0, 0.1, 5.0]
    bank = _bank(codes, [0, 0, 0, 1, 1])
    q = np.zeros((3, 20))
    q[:, 0] = [0.2, 1.8, 0.2]
    got = ODMO.end_points(q, np.array([0, 0, 1]), bank)
    np.testing.assert_array_equal(got, bank.ends[[0, 2, 3]])


def _planted(rng, sizes, centers, scale=0.05):
    return np.concatenate([c + scale * rng.normal(size=(n, 20)) for n, c in zip(sizes, centers)])


def test_mode_preserving_draws_from_the_planted_modes_in_proportion(items):
    rng = np.random.default_rng(0)
    centers = 4.0 * np.eye(20)[:3]
    codes = _planted(rng, (60, 30, 15), centers)
    out = mode_preserving_codes(codes, 70, rule="code", seed=1, rng=np.random.default_rng(2))
    dist = np.linalg.norm(out[:, None] - centers[None], axis=-1)
    assert out.shape == (70, 20) and dist.min(1).max() < 1.5
    assert sorted(np.bincount(dist.argmin(1), minlength=3)) == [10, 20, 40]
    # through the model: per-class counts, grouped by class
    g = make(items)
    bank = _bank(np.concatenate([codes, codes[:45] - 8.0]), [0] * 105 + [1] * 45)
    z, lab = g.sample_codes(bank, {1: 4, 0: 70}, seed=0)
    assert z.shape == (74, 20) and list(lab) == [0] * 70 + [1] * 4
    z2, _ = g.sample_codes(bank, {1: 4, 0: 70}, seed=0)
    assert np.array_equal(z, z2)


@pytest.mark.parametrize("form", ["code", "paper"])
def test_conventional_sampling_draws_each_class_from_its_own_gaussian(items, form):
    rng = np.random.default_rng(1)
    centers = 6.0 * np.eye(20)[:3]
    # class 0: 30 codes at A and 10 at B (class 1's cluster); class 2 at C
    codes = _planted(rng, (30, 10, 40, 40), centers[[0, 1, 1, 2]], scale=0.1)
    bank = _bank(codes, np.repeat([0, 0, 1, 2], [30, 10, 40, 40]))
    g = make(items, sampling="conventional", conventional_form=form)
    z, lab = g.sample_codes(bank, 200, seed=3)
    assert z.shape == (600, 20) and np.array_equal(lab, np.repeat([0, 1, 2], 200))
    near = np.linalg.norm(z[:, None] - centers[None], axis=-1).argmin(1)
    np.testing.assert_array_equal(near[200:], lab[200:])
    mean0 = z[:200].mean(0)
    if form == "code":   # the majority component of class 0 only (its B codes are filtered)
        assert np.linalg.norm(mean0 - centers[0]) < 0.3
    else:                # one Gaussian over all of class 0's codes: mean 0.75 A + 0.25 B
        assert np.linalg.norm(mean0 - (0.75 * centers[0] + 0.25 * centers[1])) < 0.5


def test_short_training_lowers_the_loss(items):
    g = ODMO({"epochs": 3, "windows_per_epoch": 64, "batch_size": 32}, items.skeleton,
             items.n_classes, items.fps)
    hist = g.fit(items, seed=0).history
    assert len(hist) == 3 and all(h["batches"] == 2 for h in hist)
    assert hist[-1]["loss"] < hist[0]["loss"] and hist[-1]["mre"] < hist[0]["mre"]
