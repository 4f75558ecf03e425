"""SSMCT (repro.models.ssmct) and MultiAct's composite baselines ACTOR + SSMCT and ACTOR +
Interpolation (repro.models.multiact_baselines): training, exact resume, the in-betweening
window and its canonical frame, interpolation, ACTOR placement with and without alignment,
no reading of the targets, determinism.  Tiny widths; synthetic pairs cut from the synthetic
clip set (S_p, T, S_c consecutive frames of one clip)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import roma
import torch
from model_fixtures import assert_resume_is_exact
from model_fixtures import one_torch_thread  # noqa: F401 (fixture)
from test_items import synthetic_clipset
from torch import nn

from repro.data.pairs import GeneratedPairs, PairItems, last_frames
from repro.errors import ConfigError
from repro.models.actor import ACTOR
from repro.models.base import Generator, generator_class
from repro.models.multiact_baselines import ActorSSMCT, Interpolation
from repro.models.ssmct import SSMCT, SSMCTConfig, interpolate_frames
from repro.motion.canon import CanonParams, marionette_normalize, uncanonicalize
from repro.motion.heading import motion_heading, yaw_matrix
from repro.motion.motion import Motion
from repro.motion.rotations import sixd_to_matrix, sixd_to_quat

TINY_SSMCT = dict(d_model=32, layers=1, heads=2, ff_size=64, batch_size=8, epochs=2, lr=1e-3,
                  sample_batch_size=5, max_window=48)
TINY_ACTOR = dict(latent_dim=16, ff_size=32, num_layers=1, num_heads=2, batch_size=8, epochs=1,
                  sample_batch_size=4)


@pytest.fixture(scope="module")
def clips():
    return synthetic_clipset(n_per_class=8, min_len=30, max_len=44)


def make_pairs(clips, seed: int = 0) -> PairItems:
    """One pair per clip: S_p, T, S_c are consecutive parts of it (l_t may be 0)."""
    rng = np.random.default_rng(seed)
    idx = np.arange(len(clips.lengths))
    lens = clips.lengths[idx]
    motion = Motion.from_clipset(clips, idx, 0, int(lens.max()), pad=True)
    l_p = rng.integers(6, 13, idx.size)
    l_t = rng.integers(0, 7, idx.size)
    l_t[:3] = (0, 1, 6)
    l_c = lens - l_p - l_t
    prev_labels = (clips.labels[idx] + 1) % clips.n_classes
    return PairItems(motion=motion, l_p=l_p, l_t=l_t, l_c=l_c, prev_labels=prev_labels,
                     labels=clips.labels[idx], label_names=clips.label_names,
                     source="synthetic-pairs")


@pytest.fixture(scope="module")
def pairs(clips):
    return make_pairs(clips)


def ssmct(clips, **over) -> SSMCT:
    return SSMCT({**TINY_SSMCT, **over}, clips.skeleton, clips.n_classes, clips.fps)


@pytest.fixture(scope="module")
def trained(clips, pairs):
    m = ssmct(clips)
    return m, m.fit(pairs, seed=3)


@pytest.fixture(scope="module")
def actor(clips):
    return ACTOR(TINY_ACTOR, clips.skeleton, clips.n_classes, clips.fps)  # untrained is enough


def composite(cls, actor, model, align=True):
    parts = {"actor": actor, "ssmct": model} if cls is ActorSSMCT else {"actor": actor}
    return cls.from_components(parts, {"align": align})


def same(a: Motion, b: Motion) -> bool:
    return torch.equal(a.root, b.root) and torch.equal(a.rot6d, b.rot6d)


def moved(m: Motion, angle: float, shift) -> Motion:
    """``m`` rotated about world +Y by ``angle`` and translated by ``shift``."""
    B = m.batch_size
    G = yaw_matrix(torch.full((B,), -angle, dtype=m.dtype))      # uncanonicalize applies Gᵀ
    o = torch.as_tensor(shift, dtype=m.dtype).expand(B, 3)
    return uncanonicalize(m, CanonParams("test", G, o, torch.zeros(B, dtype=torch.long)))


# -- configuration ----------------------------------------------------------------------------


def test_defaults_registry_and_bad_configs(clips):
    cfg = SSMCTConfig()
    assert (cfg.layers, cfg.heads, cfg.d_model, cfg.ff_size, cfg.dropout) == (8, 8, 256, 512, 0.1)
    assert (cfg.context_frames, cfg.target_frames, cfg.lambda_pose, cfg.lambda_pos) == (10, 2, 1, 1)
    assert (cfg.lr, cfg.weight_decay, cfg.batch_size) == (1e-4, 1e-5, 128)
    assert generator_class("ssmct") is SSMCT and SSMCT.item_kind == "pairs"
    assert generator_class("actor_ssmct") is ActorSSMCT
    assert generator_class("interpolation") is Interpolation
    assert ActorSSMCT.components == {"actor": "actor", "ssmct": "ssmct"}
    assert Interpolation.components == {"actor": "actor"}
    assert ActorSSMCT.inference_fields == ("align",) == Interpolation.inference_fields
    assert "epochs" not in ActorSSMCT.Config.model_fields and ActorSSMCT.Config().align
    with pytest.raises(ConfigError, match="heads"):
        ssmct(clips, d_model=30, heads=4)
    with pytest.raises(ConfigError, match="kernel_size"):
        ssmct(clips, kernel_size=2)
    with pytest.raises(ConfigError, match="epochs"):
        ActorSSMCT({"align": True, "epochs": 3}, clips.skeleton, 3, clips.fps)


def test_network_shapes(clips):
    net = ssmct(clips).network
    P = 6 * clips.skeleton.n_joints + 3
    assert net.conv_in.in_channels == P and net.conv_out.out_channels == P
    assert net.conv_in.out_channels == 32 and net.keyframe.num_embeddings == 3
    assert net.position.num_embeddings == 48 and len(net.encoder.layers) == 1


# -- SSMCT training ---------------------------------------------------------------------------


def test_training_window_and_targets(clips, pairs):
    data = ssmct(clips)._tensors(pairs)
    C, K = 10, 2
    assert torch.equal(data["lengths"], C + pairs.l_t + K)
    i = 2  # l_t = 6
    kind = data["kind"][i]
    assert kind[:C].eq(0).all() and kind[C:C + 6].eq(1).all() and kind[C + 6:C + 8].eq(0).all()
    assert kind[C + 8:].eq(2).all()
    # known frames of the input are the real ones; missing ones differ from the real transition
    known = kind == 0
    assert torch.equal(data["inp"][i][known], data["target"][i][known])
    assert not torch.allclose(data["inp"][i][kind == 1], data["target"][i][kind == 1])
    # the anchor (S_p's last frame) sits at the origin of the face-front frame
    assert torch.allclose(data["target"][i, C - 1, -3:], torch.zeros(3), atol=1e-5)
    assert data["kind"][0][C:C + K].eq(0).all()  # l_t = 0: keyframes follow the context


def test_fit_decreases_loss(trained, pairs):
    _, result = trained
    losses = [h["loss"] for h in result.history]
    assert len(losses) == 2 and all(math.isfinite(v) for v in losses)
    assert losses[-1] < losses[0]
    assert {"pose", "pos"} <= set(result.history[0])


def test_resume_is_exact(clips, pairs, trained, tmp_path):
    full, _ = trained
    assert_resume_is_exact(full, lambda: ssmct(clips), pairs, tmp_path, seed=3)


def test_validation_curve_leaves_weights_alone(clips, pairs):
    train, val = pairs.subset(range(18)), pairs.subset(range(18, 24))
    a, b = ssmct(clips), ssmct(clips)
    r = a.fit(train, seed=3, val_items=val)
    b.fit(train, seed=3)
    assert "val_loss" in r.history[-1] and math.isfinite(r.history[-1]["val_loss"])
    for (k, v), v2 in zip(a.network.state_dict().items(), b.network.state_dict().values()):
        assert torch.equal(v, v2), k


# -- SSMCT in-betweening ---------------------------------------------------------------------


def test_inbetween_shape_determinism_and_frame(trained, pairs):
    m, _ = trained
    prev, l_p = pairs.prev()
    act, _ = pairs.action()
    T = m.inbetween(prev, l_p, act, pairs.l_t)
    assert T.n_frames == int(pairs.l_t.max()) and T.batch_size == len(pairs)
    assert same(T, m.inbetween(prev, l_p, act, pairs.l_t, seed=99))   # deterministic
    R = sixd_to_matrix(T.rot6d)
    assert torch.allclose(R @ R.transpose(-1, -2), torch.eye(3).expand_as(R), atol=1e-5)
    # padding repeats the last frame; l_t = 0 holds S_c's first frame
    i = 1  # l_t = 1
    assert torch.equal(T.root[i, 1:], T.root[i, :1].expand_as(T.root[i, 1:]))
    assert torch.allclose(T.root[0], act.root[0, :1].expand_as(T.root[0]), atol=1e-5)
    # the same with the samples one at a time (padding of the batch changes nothing)
    one = m.inbetween(prev.select([2]), l_p[[2]], act.select([2]), pairs.l_t[[2]])
    assert torch.allclose(one.root[0], T.root[2, :6], atol=1e-5)
    # yaw + translation of both inputs moves the output the same way
    a, d = 1.1, (0.7, 0.2, -2.0)
    T2 = m.inbetween(moved(prev, a, d), l_p, moved(act, a, d), pairs.l_t)
    exp = moved(T, a, d)
    assert torch.allclose(T2.root, exp.root, atol=1e-4)
    assert torch.allclose(T2.rot6d, exp.rot6d, atol=1e-4)


def test_sample_keeps_the_real_action(trained, pairs):
    m, _ = trained
    out = m.sample(pairs, seed=0)
    assert isinstance(out, GeneratedPairs)
    assert torch.equal(out.l_t, pairs.l_t) and torch.equal(out.l_c, pairs.l_c)
    got, _ = out.action()
    real, _ = pairs.action()
    assert torch.allclose(got.root, real.root) and torch.allclose(got.rot6d, real.rot6d)


def test_window_longer_than_positions_is_refused(trained, pairs):
    m, _ = trained
    prev, l_p = pairs.prev()
    act, _ = pairs.action()
    with pytest.raises(ConfigError, match="max_window"):
        m.inbetween(prev, l_p, act, torch.full((len(pairs),), 40))


# -- interpolation --------------------------------------------------------------------------


def test_interpolate_frames_lies_strictly_between(pairs):
    prev, l_p = pairs.prev()
    act, _ = pairs.action()
    a, b = last_frames(prev, l_p, 1), act.slice_time(0, 1)
    mid = interpolate_frames(a, b, torch.ones(len(pairs), dtype=torch.long))
    assert mid.n_frames == 1
    qa, qb = sixd_to_quat(a.rot6d[:, 0].double()), sixd_to_quat(b.rot6d[:, 0].double())
    for i in range(3):
        half = roma.unitquat_slerp(qa[i], qb[i], torch.tensor([0.5], dtype=torch.float64),
                                   shortest_arc=True)[0]
        assert torch.allclose(sixd_to_matrix(mid.rot6d[i, 0]).double(),
                              roma.unitquat_to_rotmat(half), atol=1e-5)
    assert torch.allclose(mid.root[:, 0], 0.5 * (a.root[:, 0] + b.root[:, 0]), atol=1e-6)
    three = interpolate_frames(a, b, torch.full((len(pairs),), 3))
    assert torch.allclose(three.root[:, 0], 0.75 * a.root[:, 0] + 0.25 * b.root[:, 0], atol=1e-6)
    assert torch.allclose(three.root[:, 2], 0.25 * a.root[:, 0] + 0.75 * b.root[:, 0], atol=1e-6)


def test_interpolation_step_joins_prev_and_action(actor, pairs):
    gen = composite(Interpolation, actor, None)
    prev, l_p = pairs.prev()
    one = torch.ones(len(pairs), dtype=torch.long)
    out = gen.step(prev, l_p, pairs.labels, one, pairs.l_c, seed=4)
    T, _ = out.transition()
    S, _ = out.action()
    a = last_frames(prev, l_p, 1)
    assert torch.allclose(T.root[:, 0], 0.5 * (a.root[:, 0] + S.root[:, 0]), atol=1e-5)
    assert same(S, gen.actor_action(pairs.labels, pairs.l_c, seed=_action_seed(4), after=prev,
                                    after_lengths=l_p))


def _action_seed(seed):
    from repro.seeding import derive_seed

    return derive_seed(seed, "multiact_baselines", "action")


# -- ACTOR placement -----------------------------------------------------------------------------


def test_aligned_action_starts_at_prev_last_pose(actor, pairs):
    gen = composite(Interpolation, actor, None, align=True)
    prev, l_p = pairs.prev()
    free = gen.actor_action(pairs.labels, pairs.l_c, seed=1)               # ACTOR's own frame
    placed = gen.actor_action(pairs.labels, pairs.l_c, seed=1, after=prev, after_lengths=l_p)
    last = last_frames(prev, l_p, 1)
    _, params = marionette_normalize(last)
    exp = uncanonicalize(free, params)
    assert torch.allclose(placed.root, exp.root, atol=1e-5)
    assert torch.allclose(placed.rot6d, exp.rot6d, atol=1e-5)
    # heading of the action's first frame relative to the previous pose's = ACTOR's own
    def h(m):
        return motion_heading(m)[:, 0]

    dh = torch.remainder(h(placed.slice_time(0, 1)) - h(last) - h(free.slice_time(0, 1)) + math.pi,
                         2 * math.pi) - math.pi
    assert dh.abs().max() < 1e-4
    # distance from the previous pose's root is ACTOR's distance from the origin
    assert torch.allclose((placed.root[:, 0] - last.root[:, 0]).norm(dim=-1),
                          free.root[:, 0].norm(dim=-1), atol=1e-5)


def test_unaligned_action_ignores_prev(actor, pairs):
    gen = composite(Interpolation, actor, None, align=False)
    prev, l_p = pairs.prev()
    a = gen.actor_action(pairs.labels, pairs.l_c, seed=1, after=prev, after_lengths=l_p)
    b = gen.actor_action(pairs.labels, pairs.l_c, seed=1, after=moved(prev, 2.0, (5, 0, 5)),
                         after_lengths=l_p)
    assert same(a, b) and same(a, gen.actor_motion(pairs.labels, pairs.l_c, seed=1))
    # ACTOR's canonical poses, unplaced
    raw = actor.generate_poses(_cond(gen, pairs), seed=1)
    assert torch.allclose(a.root[0, : int(pairs.l_c[0])], raw[0, : int(pairs.l_c[0]), -3:])


def _cond(gen, pairs):
    from repro.data.action_items import condition_items

    prev, l_p = pairs.prev()
    return condition_items(last_frames(prev, l_p, 6), pairs.labels, pairs.labels, pairs.l_c,
                           pairs.label_names)


# -- composites: sampling ----------------------------------------------------------------------


@pytest.mark.parametrize("cls", [ActorSSMCT, Interpolation])
@pytest.mark.parametrize("align", [True, False])
def test_sample_reads_no_targets_and_is_seeded(cls, align, actor, trained, pairs):
    gen = composite(cls, actor, trained[0], align)
    out = gen.sample(pairs, seed=5)
    assert torch.equal(out.l_t, pairs.l_t) and torch.equal(out.l_c, pairs.l_c)
    assert out.motion.n_frames == int((pairs.l_t + pairs.l_c).max())
    assert torch.isfinite(out.motion.root).all() and torch.isfinite(out.motion.rot6d).all()
    # T and S_c of the condition changed: the same output
    m = pairs.motion
    t = torch.arange(m.n_frames)[None, :] >= pairs.l_p[:, None]
    g = torch.Generator().manual_seed(0)
    root = torch.where(t[..., None], m.root + torch.randn(m.root.shape, generator=g), m.root)
    rot = torch.where(t[..., None, None], m.rot6d + torch.randn(m.rot6d.shape, generator=g), m.rot6d)
    other = dataclasses.replace(pairs, motion=m.replace(root=root, rot6d=rot))
    assert same(out.motion, gen.sample(other, seed=5).motion)
    # seeds: the same seed repeats, another changes ACTOR's action
    assert same(out.motion, gen.sample(pairs, seed=5).motion)
    assert not same(out.motion, gen.sample(pairs, seed=6).motion)
    assert same(gen.sample(pairs, seed=5, use_mean=True).motion,
                gen.sample(pairs, seed=6, use_mean=True).motion)
    # step on S_p is sample
    prev, l_p = pairs.prev()
    assert same(out.motion, gen.step(prev, l_p, pairs.labels, pairs.l_t, pairs.l_c,
                                     seed=5).motion)


def test_both_composites_share_the_action(actor, trained, pairs):
    a = composite(ActorSSMCT, actor, trained[0]).sample(pairs, seed=2)
    b = composite(Interpolation, actor, None).sample(pairs, seed=2)
    assert same(a.action()[0], b.action()[0])
    assert not same(a.transition()[0], b.transition()[0])


def test_actor_ssmct_transition_is_ssmct(actor, trained, pairs):
    gen = composite(ActorSSMCT, actor, trained[0])
    out = gen.sample(pairs, seed=2)
    prev, l_p = pairs.prev()
    S, _ = out.action()
    T = trained[0].inbetween(prev, l_p, S, pairs.l_t)
    assert torch.allclose(out.transition()[0].root, T.root, atol=1e-6)


# -- composites: construction, fit, save ------------------------------------------------------------


def test_composite_api(clips, actor, trained, tmp_path, pairs):
    with pytest.raises(ConfigError, match="ssmct"):
        ActorSSMCT.from_components({"actor": actor}, {"align": True})
    with pytest.raises(ConfigError, match="must be a 'ssmct'"):
        ActorSSMCT.from_components({"actor": actor, "ssmct": actor}, None)
    gen = composite(ActorSSMCT, actor, trained[0])
    assert isinstance(gen.network, nn.ModuleDict) and set(gen.network) == {"actor", "ssmct"}
    with pytest.raises(ConfigError, match="trained separately"):
        gen.fit(pairs, seed=0)
    gen.save(tmp_path / "c")
    back = ActorSSMCT.load(tmp_path / "c")
    assert type(back) is ActorSSMCT and back.config == gen.config
    assert same(back.sample(pairs, seed=3).motion, gen.sample(pairs, seed=3).motion)
    bare = Generator.load(tmp_path / "c")                        # no crash; no components
    assert type(bare) is ActorSSMCT
    with pytest.raises(ConfigError, match="not attached"):
        bare.sample(pairs, seed=3)
    # SSMCT alone saves and loads through the generic path
    trained[0].save(tmp_path / "s")
    s = Generator.load(tmp_path / "s")
    prev, l_p = pairs.prev()
    act, _ = pairs.action()
    assert same(s.inbetween(prev, l_p, act, pairs.l_t),
                trained[0].inbetween(prev, l_p, act, pairs.l_t))
