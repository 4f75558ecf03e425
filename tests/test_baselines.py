"""The adapted baselines (repro.models.mann, a2m, actor): paper widths, training, sampling,
which conditions each reads, save/load, determinism, exact resume.  Tiny widths everywhere
except the width checks; the quick-scale run on bandai2-mini is marked slow."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from repro.data.clipset import TEST, TRAIN
from repro.data.contexts import build_items
from repro.errors import ConfigError
from repro.models.a2m import A2M, A2MConfig, kl_gaussians
from repro.models.macvae_nets import kl_gaussians as macvae_kl_gaussians
from repro.models.actor import ACTOR, ACTORConfig
from repro.models.base import Generator, generator_class
from repro.models.baseline_io import pack_poses, pose_joints
from repro.models.mann import MANN, MANNConfig, ExpertLinear, sgdr_factor
from repro.motion.rotations import sixd_to_matrix
from model_fixtures import clips, items, one_torch_thread, test_items  # noqa: F401 (fixtures)
from model_fixtures import assert_resume_is_exact

TINY = {
    "mann": dict(n_experts=3, hidden=24, gating_hidden=8, batch_size=32, epochs=3, lr=3e-3,
                 restart_period=2, sample_batch_size=4),
    "a2m": dict(dim_z=4, hidden=16, batch_size=8, epochs=3, lr=3e-3, sample_batch_size=4),
    "actor": dict(latent_dim=16, ff_size=32, num_layers=1, num_heads=2, batch_size=8, epochs=3,
                  lr=1e-3, sample_batch_size=4),
}
METHODS = sorted(TINY)


def model(method, clips, **over):
    return generator_class(method)({**TINY[method], **over}, clips.skeleton, clips.n_classes,
                                    clips.fps)


@pytest.fixture(scope="module")
def trained(clips, items):
    out = {}
    for method in METHODS:
        m = model(method, clips)
        out[method] = (m, m.fit(items, seed=3))
    return out


def same(a, b) -> bool:
    return torch.equal(a.motion.root, b.motion.root) and torch.equal(a.motion.rot6d, b.motion.rot6d)


# -- paper defaults and widths ----------------------------------------------------------------


def test_mann_defaults_and_widths(clips):
    cfg = MANNConfig()
    assert (cfg.n_experts, cfg.hidden, cfg.gating_hidden, cfg.dropout) == (8, 512, 32, 0.3)
    assert (cfg.batch_size, cfg.epochs, cfg.lr, cfg.weight_decay) == (32, 150, 1e-4, 2.5e-3)
    assert (cfg.restart_period, cfg.restart_mult) == (10, 2)
    assert len(cfg.offsets()) == 12 and 0 in cfg.offsets()
    m = MANN(None, clips.skeleton, 4, 30.0)
    net, f = m.network, m.features
    J = clips.skeleton.n_joints
    assert net.layer0.alpha.shape == (8, 512, f.n_in) and net.layer1.alpha.shape == (8, 512, 512)
    assert net.layer2.alpha.shape == (8, 6 * J + 3, 512)
    assert net.gate0.out_features == 32 and net.gate2.out_features == 8
    # input: rot 6J, positions 3J, velocities 3J, root height, 12 × (2 + 2) window, tag
    assert f.n_in == 12 * J + 1 + 48 + 4
    leaves = [j for j in range(J) if not clips.skeleton.children(j)]
    assert net.gating_index.numel() == 3 * len(leaves) + 2 + 4


def test_a2m_defaults_and_widths(clips):
    cfg = A2MConfig()
    assert (cfg.representation, cfg.initial_pose, cfg.time_counter) == ("6d", True, True)
    assert (cfg.dim_z, cfg.hidden, cfg.prior_layers, cfg.posterior_layers, cfg.decoder_layers) == \
        (30, 128, 1, 1, 2)
    assert (cfg.lambda_kld, cfg.self_feed_ratio, cfg.batch_size, cfg.lr) == (1e-3, 0.6, 128, 2e-4)
    net = A2M(None, clips.skeleton, 4, 30.0).network
    P = 6 * clips.skeleton.n_joints + 3
    assert net.posterior.embed.in_features == P + 4 + 1 and net.prior.embed.in_features == P + 5
    assert net.decoder.embed.in_features == P + 5 + 30 and net.decoder.out.out_features == P
    assert len(net.decoder.cells) == 2 and len(net.prior.cells) == 1
    assert net.prior.mu.out_features == 30 and net.prior.cells[0].hidden_size == 128
    # the table specs' row overrides (NM's adaptation) are Config fields
    A2M({"representation": "6d", "initial_pose": True}, clips.skeleton, 4, 30.0)
    lie = A2M({"representation": "lie"}, clips.skeleton, 4, 30.0)
    assert lie.network.decoder.out.out_features == 3 * clips.skeleton.n_joints + 3


def test_actor_defaults_and_widths(clips):
    cfg = ACTORConfig()
    assert (cfg.latent_dim, cfg.ff_size, cfg.num_layers, cfg.num_heads) == (256, 1024, 8, 4)
    assert (cfg.dropout, cfg.activation, cfg.lambda_kl, cfg.lambda_rc, cfg.lambda_rcxyz) == \
        (0.1, "gelu", 1e-5, 1.0, 1.0)
    assert (cfg.batch_size, cfg.lr) == (20, 1e-4)
    net = ACTOR(None, clips.skeleton, 4, 30.0).network
    assert net.mu_query.shape == (4, 256) and net.action_bias.shape == (4, 256)
    assert len(net.encoder.layers) == 8 and len(net.decoder.layers) == 8
    assert net.encoder.layers[0].ff.lin1.out_features == 1024
    assert net.final.out_features == 6 * clips.skeleton.n_joints + 3


def test_registry_and_bad_configs(clips):
    assert generator_class("mann") is MANN and generator_class("a2m") is A2M
    assert generator_class("actor") is ACTOR
    with pytest.raises(ConfigError, match="n_expertz"):
        MANN({"n_expertz": 4}, clips.skeleton, 3, 30.0)
    with pytest.raises(ConfigError, match="representation"):
        A2M({"representation": "quat"}, clips.skeleton, 3, 30.0)
    with pytest.raises(ConfigError, match="divisible"):
        ACTOR({"latent_dim": 30, "num_heads": 4}, clips.skeleton, 3, 30.0)


@pytest.mark.parametrize("scale", ["quick", "medium", "paper"])
def test_scale_profiles_are_valid_configs(scale):
    """tables/scales.toml: every profile's [<scale>.methods.<method>] is a valid Config, and the
    paper profile is exactly the defaults."""
    from repro.specs import resolve_scale

    prof = resolve_scale(scale)
    for method in METHODS:
        cls = generator_class(method)
        over = prof.method_config(method)
        assert over, f"no [{scale}.methods.{method}]"
        cfg = cls.Config.resolve(over)
        if scale == "paper":
            assert cfg == cls.Config()


# -- pieces -------------------------------------------------------------------------------------


def test_expert_layer_blends_weights():
    """Eq. 3: the layer equals a layer whose weights are Σ_k ω_k α_k, Σ_k ω_k β_k."""
    torch.manual_seed(0)
    layer = ExpertLinear(3, 5, 4)
    with torch.no_grad():
        layer.beta.normal_()
    x, omega = torch.randn(6, 5), torch.softmax(torch.randn(6, 3), -1)
    W = torch.einsum("bk,koi->boi", omega, layer.alpha)
    b = omega @ layer.beta
    assert torch.allclose(layer(x, omega), (W @ x[..., None])[..., 0] + b, atol=1e-6)


def test_sgdr_schedule():
    assert sgdr_factor(0, 0, 100, 10, 2) == 1.0
    assert sgdr_factor(5, 0, 100, 10, 2) == pytest.approx(0.5)        # half of the first cycle
    assert sgdr_factor(10, 0, 100, 10, 2) == 1.0                      # restart after 10
    assert sgdr_factor(20, 0, 100, 10, 2) == pytest.approx(0.5)       # cycle 2 has 20 epochs
    assert sgdr_factor(30, 0, 100, 10, 2) == 1.0 and sgdr_factor(70, 0, 100, 10, 2) == 1.0
    cap = 0.5 * (1 + math.cos(0.9 * math.pi))
    assert sgdr_factor(9, 99, 100, 10, 2) == pytest.approx(cap)       # phase capped at 0.9


@pytest.mark.parametrize("kl", [kl_gaussians, macvae_kl_gaussians], ids=["a2m", "macvae"])
def test_gaussian_kl_matches_torch(kl):
    mu1, lv1, mu2, lv2 = (torch.randn(4, 6) for _ in range(4))
    ref = torch.distributions.kl_divergence(
        torch.distributions.Normal(mu1, (0.5 * lv1).exp()),
        torch.distributions.Normal(mu2, (0.5 * lv2).exp())).sum(-1)
    assert torch.allclose(kl(mu1, lv1, mu2, lv2), ref, atol=1e-5)


def test_mann_training_pairs(clips, items):
    m = model("mann", clips)
    X, Y = m.features.training_pairs(items)
    f = m.features
    assert X.shape == (int(items.lengths.sum()), f.n_in) and Y.shape[1] == f.n_out
    first = pack_poses(items.initial)[0, -1]                          # P_0 of item 0
    target = pack_poses(items.action)[0, 0]                           # P_1 of item 0
    assert torch.allclose(X[0, :f.c_rot[1]], first[:-3])
    assert torch.allclose(Y[0, :-3], target[:-3]) and torch.allclose(Y[0, -3:], target[-3:] - first[-3:])
    tag = X[:, f.c_tag[0]:f.c_tag[1]]
    assert torch.equal(tag.argmax(1), torch.repeat_interleave(items.labels, items.lengths))


def test_a2m_representations_round_trip(clips, items):
    poses = pack_poses(items.action)[:2, :5]
    lie = model("a2m", clips, representation="lie")
    back = lie.to_poses(lie.to_params(poses))
    assert torch.allclose(pose_joints(clips.skeleton, back), pose_joints(clips.skeleton, poses),
                          atol=1e-4)
    rest = model("a2m", clips, initial_pose=False).start_params(items)
    assert torch.allclose(sixd_to_matrix(rest[:, :-3].reshape(len(items), -1, 6)),
                          torch.eye(3).expand(len(items), clips.skeleton.n_joints, 3, 3))


# -- training and sampling ------------------------------------------------------------------------


@pytest.mark.parametrize("method", METHODS)
def test_fit_decreases_loss_and_samples_durations(method, trained, test_items):
    m, result = trained[method]
    losses = [h["loss"] for h in result.history]
    assert len(losses) == 3 and all(math.isfinite(v) for v in losses)
    assert losses[-1] < losses[0]
    out = m.sample(test_items, seed=0)
    assert torch.equal(out.lengths, test_items.lengths) and torch.equal(out.labels, test_items.labels)
    assert out.motion.n_frames >= int(test_items.lengths.max())
    assert torch.isfinite(out.motion.root).all() and torch.isfinite(out.motion.rot6d).all()
    R = sixd_to_matrix(out.motion.rot6d)
    assert torch.allclose(R @ R.transpose(-1, -2), torch.eye(3).expand_as(R), atol=1e-4)
    i = int(test_items.lengths.argmin())
    n = int(test_items.lengths[i])
    assert torch.equal(out.motion.root[i, n:], out.motion.root[i, n - 1:n].expand_as(out.motion.root[i, n:]))


def _perturbed(items, field):
    g = torch.Generator().manual_seed(11)
    if field == "initial_motion":
        init = items.initial
        noise = 0.3 * torch.randn(init.rot6d.shape, generator=g)
        return dataclasses.replace(items, initial=init.replace(rot6d=init.rot6d + noise))
    if field == "trajectory":
        return dataclasses.replace(items, trajectory=items.trajectory + 0.5)
    if field == "next_label":
        return dataclasses.replace(items, next_labels=(items.next_labels + 1) % items.n_classes)
    raise AssertionError(field)


@pytest.mark.parametrize("method", METHODS)
def test_respects_uses(method, trained, test_items):
    """A condition a method does not declare leaves its samples unchanged; a declared one
    changes them (ACTOR: the initial motion is not read, only the item's frame places it)."""
    m, _ = trained[method]
    base = m.sample(test_items, seed=5)
    for field in ("initial_motion", "trajectory", "next_label"):
        other = m.sample(_perturbed(test_items, field), seed=5)
        assert same(base, other) == (field not in m.uses), (method, field)
    expected = {"mann": {"label", "length", "initial_motion", "trajectory"},
                "a2m": {"label", "length", "initial_motion"}, "actor": {"label", "length"}}
    assert set(m.uses) == expected[method]


def test_a2m_without_initial_pose_ignores_initial_motion(clips, items, test_items):
    m = model("a2m", clips, initial_pose=False, epochs=1)
    m.fit(items, seed=0)
    assert "initial_motion" not in m.uses
    assert same(m.sample(test_items, seed=1),
                m.sample(_perturbed(test_items, "initial_motion"), seed=1))


def test_actor_is_placed_at_the_item_frame(trained, test_items):
    """ACTOR's world output is its canonical-frame output mapped by each item's inverse
    normalisation (the documented start)."""
    m, _ = trained["actor"]
    poses = m.generate_poses(test_items, seed=2)
    out = m.sample(test_items, seed=2)
    i = 0
    canon_root = poses[i, 0, -3:]
    world = test_items.canon.select(i).invert_points(canon_root[None, None])[0, 0]
    assert torch.allclose(out.motion.root[i, 0], world, atol=1e-5)


@pytest.mark.parametrize("method", METHODS)
def test_save_load_and_seeds(method, trained, test_items, tmp_path):
    m, _ = trained[method]
    a = m.sample(test_items, seed=7)
    m.save(tmp_path / method)
    back = Generator.load(tmp_path / method)
    assert type(back) is type(m) and back.config == m.config
    assert same(back.sample(test_items, seed=7), a)
    b = m.sample(test_items, seed=8)
    assert same(a, b) == (method == "mann")                   # MANN has no latent variable
    assert same(m.sample(test_items, seed=7, use_mean=True), m.sample(test_items, seed=8, use_mean=True))


@pytest.mark.parametrize("method", ["a2m", "actor"])
def test_samples_do_not_depend_on_sample_batch_size(method, clips, trained, test_items):
    m, _ = trained[method]
    one = model(method, clips, sample_batch_size=1)
    one.network.load_state_dict(m.network.state_dict())
    a, b = m.generate_poses(test_items, seed=4), one.generate_poses(test_items, seed=4)
    valid = test_items.valid_mask()
    assert torch.allclose(a[valid], b[valid], atol=1e-5)


@pytest.mark.parametrize("method", METHODS)
def test_training_is_deterministic(method, clips, items, trained):
    m, result = trained[method]
    again = model(method, clips)
    r2 = again.fit(items, seed=3)
    assert [h["loss"] for h in r2.history] == [h["loss"] for h in result.history]
    for (k, v), (k2, v2) in zip(m.network.state_dict().items(), again.network.state_dict().items()):
        assert k == k2 and torch.equal(v, v2), k


def test_mann_resume_is_exact(clips, items, tmp_path):
    """The per-batch AdamWR learning rate is a function of (epoch, batch), so a killed run
    resumes to the same bytes."""
    full = model("mann", clips)
    full.fit(items, seed=1)
    assert_resume_is_exact(full, lambda: model("mann", clips), items, tmp_path, seed=1)


# -- quick scale on the bundled stand-in (slow) ------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
def test_quick_scale_on_bandai2_mini(method):
    from repro.data.registry import load_clipset
    from repro.specs import resolve_scale

    cs = load_clipset("bandai2-mini")
    train_items, test = build_items(cs, TRAIN), build_items(cs, TEST)
    cfg = resolve_scale("quick").method_config(method)
    assert cfg, f"tables/scales.toml has no [quick.methods.{method}]"
    m = generator_class(method)(cfg, cs.skeleton, cs.n_classes, cs.fps)
    result = m.fit(train_items, seed=0)
    assert result.history[-1]["loss"] < result.history[0]["loss"]
    out = m.sample(test, seed=0)
    assert torch.isfinite(out.joints()).all()


def _a2m_step_frame_by_frame(m, net, batch):
    """A2M's loss as Guo et al. Eq. 5 reads, every network run one frame at a time (the
    library's step before issue 31): the reference for its sequence-level step."""
    cfg = m.config
    x, lengths = batch["params"], batch["lengths"]
    B, T = x.shape[:2]
    mask = (torch.arange(T)[None] < lengths[:, None]).to(x.dtype)
    onehot = torch.nn.functional.one_hot(batch["labels"], m.n_classes).to(x.dtype)
    h_post, h_prior, h_dec = (n.init_hidden(B, x) for n in (net.posterior, net.prior,
                                                            net.decoder))
    self_feed = bool(torch.rand(()) < cfg.self_feed_ratio)
    prev, preds, kls = batch["start"], [], []
    for t in range(T):
        c = net.condition(onehot, t, lengths)
        mu, logvar, h_post = net.posterior(torch.cat([x[:, t], c], -1), h_post)
        mu_p, logvar_p, h_prior = net.prior(torch.cat([prev, c], -1), h_prior)
        z = mu + torch.exp(0.5 * logvar) * torch.randn_like(mu)
        x_hat, h_dec = net.decoder(torch.cat([prev, c, z], -1), h_dec)
        preds.append(x_hat)
        kls.append(kl_gaussians(mu, logvar, mu_p, logvar_p))
        prev = x_hat if self_feed else x[:, t]
    joints = pose_joints(m.skeleton, m.to_poses(torch.stack(preds, 1)))
    rec = ((((joints - batch["joints"]) ** 2).mean((-1, -2))) * mask).sum(1).mean()
    return rec + cfg.lambda_kld * (torch.stack(kls, 1) * mask).sum(1).mean()


@pytest.mark.parametrize("self_feed", [0.0, 1.0], ids=["teacher-forced", "self-fed"])
def test_a2m_sequence_step_equals_frame_by_frame(clips, items, self_feed):
    """The posterior over the whole sequence (and, teacher-forced, the prior and decoder too):
    the same loss and gradients as running every network frame by frame, up to the order in
    which the frames' gradient terms are summed; the same noise (drawn frame-major: equal to one
    draw per frame because B·dim_z = 64 is a multiple of torch's normal block of 16)."""
    m = model("a2m", clips, self_feed_ratio=self_feed, hidden=32, dim_z=8)
    net = m.network.train()
    batch = m._crop(m._tensors(items), torch.arange(8))       # 8 * 8 latent numbers: x16
    assert int(batch["lengths"].min()) < int(batch["lengths"].max())     # padded frames too
    grads = []
    for step in (lambda: m.training_step(net, batch, 0)["loss"],
                 lambda: _a2m_step_frame_by_frame(m, net, batch)):
        torch.manual_seed(7)
        net.zero_grad()
        loss = step()
        loss.backward()
        grads.append((loss.detach(), [p.grad.clone() for p in net.parameters()]))
    (loss_seq, g_seq), (loss_ref, g_ref) = grads
    torch.testing.assert_close(loss_seq, loss_ref, rtol=1e-6, atol=0)
    for a, b in zip(g_seq, g_ref):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)
