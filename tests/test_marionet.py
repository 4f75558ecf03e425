"""MarioNet (repro.models.marionet): paper widths, key/value cache, the four ablation switches,
losses, training, determinism, save/load.  Tiny widths everywhere except the width check."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from repro.errors import ConfigError, DataError, MissingDataError
from repro.models.base import Generator, generator_class
from repro.models.layers import TransformerDecoder
from repro.models.marionet import (MarioNet, MarioNetConfig, _term, kl_divergence, pack_poses)
from model_fixtures import clips, items, one_torch_thread, test_items  # noqa: F401 (fixtures)

TINY = dict(d_model=16, traj_dim=4, cond_heads=2, cond_ff=32, cond_layers=1, traj_heads=1,
            traj_ff=8, unroll_heads=2, unroll_ff=32, unroll_layers=1, dec_heads=2, dec_ff=32,
            dec_layers=2, batch_size=8, lr=1e-3, epochs=2, ss_activate_epoch=1,
            ss_accomplish_epoch=3, sample_batch_size=4)


def model(clips, **over):
    return MarioNet({**TINY, **over}, clips.skeleton, clips.n_classes, clips.fps)


def batch(m, items):
    return m._crop(m._tensors(items, True), torch.arange(len(items)))


# -- configuration and widths (supp. Table 2) -------------------------------------------------


def test_paper_defaults_and_table2_widths(clips):
    cfg = MarioNetConfig()
    assert (cfg.d_model, cfg.traj_dim, cfg.dec_layers, cfg.dec_heads, cfg.dec_ff) == (256, 32, 6, 8, 1024)
    assert (cfg.batch_size, cfg.lr, cfg.epochs, cfg.ss_activate_epoch, cfg.ss_accomplish_epoch) == \
        (30, 1e-4, 1000, 250, 750)
    assert (cfg.lambda_kl, cfg.lambda_d, cfg.lambda_r, cfg.lambda_j, cfg.lambda_v) == (1e-8, 0.5, 1, 2, 2)
    net = MarioNet(None, clips.skeleton, 31, 30.0).network
    J = clips.skeleton.n_joints
    assert net.tag_embed[0].in_features == 31 and net.tag_embed[0].out_features == 256
    assert net.pose_encode[0].in_features == 6 * J + 3 and net.pose_decode.out_features == 6 * J + 3
    assert net.unroll_proj[0].out_features == 224 and net.traj_embed[0].out_features == 32
    assert net.traj_embed[0].in_features == 2 and len(net.decoder.layers) == 6
    assert len(net.cond_encoder.layers) == 2 and len(net.unroll.layers) == 2
    assert len(net.traj_encoder.layers) == 1
    assert net.decoder.layers[0].ff.lin1.out_features == 1024
    assert net.traj_encoder.layers[0].ff.lin1.out_features == 64


def test_bad_config_is_a_config_error(clips):
    with pytest.raises(ConfigError, match="dec_layerz"):
        MarioNet({"dec_layerz": 3}, clips.skeleton, 3, 30.0)
    with pytest.raises(ConfigError, match="divisible"):
        MarioNet({"d_model": 30}, clips.skeleton, 3, 30.0)
    assert generator_class("marionet") is MarioNet
    with pytest.raises(ConfigError, match="marionet"):
        generator_class("marionett")


# -- key/value cache ---------------------------------------------------------------------------


def test_decoder_cache_equals_parallel_causal_pass():
    torch.manual_seed(0)
    dec = TransformerDecoder(3, 16, 4, 32, 0.1, "gelu").eval()
    x, mem = torch.randn(3, 9, 16), torch.randn(3, 7, 16)
    pad = torch.zeros(3, 7, dtype=torch.bool)
    pad[1, 5:] = True
    full = dec(x, mem, causal=True, mem_padding_mask=pad)
    cache = dec.init_cache(mem, pad)
    steps = torch.cat([dec.step(x[:, t:t + 1], cache) for t in range(9)], 1)
    assert cache.length == 9
    assert torch.allclose(full, steps, atol=1e-5)
    # causality: changing a later input leaves earlier outputs alone
    x2 = x.clone()
    x2[:, 6:] += 1.0
    assert torch.allclose(dec(x2, mem, causal=True, mem_padding_mask=pad)[:, :6], full[:, :6], atol=1e-6)


def test_cached_sampler_matches_uncached_and_teacher_forcing(clips, items):
    m = model(clips)
    net = m.network.eval()
    b = batch(m, items)
    with torch.no_grad():
        mu, _, tag, _ = net.encode(b["init"], b["labels"], b["next_labels"])
        ctrl = net.controls(mu, tag, b["trajectory"], b["lengths"])
        bop = b["init"][:, -1]
        cached = net.generate(bop, ctrl, b["lengths"], use_cache=True)
        full = net.generate(bop, ctrl, b["lengths"], use_cache=False)
        assert torch.allclose(cached, full, atol=1e-5)
        # the training-mode causal pass equals step-by-step decoding under teacher forcing
        gt_in = torch.cat([bop[:, None], b["target"][:, :-1]], 1)
        par = net.decode(gt_in, ctrl, b["lengths"])
        cache = net.decoder.init_cache(ctrl, net.padding_mask(b["lengths"], ctrl.shape[1]))
        steps = torch.stack([net.decode_poses(net.decoder.step(net._query(gt_in[:, t:t + 1], t), cache))[:, 0]
                             for t in range(gt_in.shape[1])], 1)
        mask = ~net.padding_mask(b["lengths"], ctrl.shape[1])
        assert torch.allclose(par[mask], steps[mask], atol=1e-5)
        # Shadow Start hook: passing the BOP's own embedding changes nothing
        same = net.generate(bop, ctrl, b["lengths"], first_feature=net.embed_poses(bop))
        assert torch.allclose(same, cached, atol=1e-6)
    s1 = m.sample(items, seed=3, use_cache=True)
    s2 = m.sample(items, seed=3, use_cache=False)
    assert torch.allclose(s1.joints(), s2.joints(), atol=1e-5)


def _bench_kv_cache():
    """benchmarks/bench_kv_cache.py (its path entry removed again once imported); skips when
    the git history holding its "before" commit is missing (a tarball, a shallow clone)."""
    import importlib.util
    import sys
    from pathlib import Path

    bench_dir = Path(__file__).resolve().parents[1] / "benchmarks"
    spec = importlib.util.spec_from_file_location("bench_kv_cache", bench_dir / "bench_kv_cache.py")
    mod = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(mod)
    finally:
        while str(bench_dir) in sys.path:
            sys.path.remove(str(bench_dir))
    try:
        mod.old_cached_sampler()
    except sys.modules["_before"].BeforeUnavailable as e:
        pytest.skip(f"no 'before' sampler to compare with: {e}")
    return mod


def test_cached_sampler_matches_the_pre_issue17_sampler(clips, items):
    """Issue 17: the preallocated, fused cached sampler gives the old cached sampler's poses
    (and the uncached ones) to 1e-5, with padded items and with Shadow Start's first feature;
    sampling leaves the parameters as they were."""
    from repro.models.marionet import MarioNetNet

    bench = _bench_kv_cache()
    library_generate = MarioNetNet.generate
    m = model(clips, dec_layers=3, sample_batch_size=32)
    assert len(set(items.lengths.tolist())) > 1            # padded memory keys are exercised
    state = {k: v.clone() for k, v in m.network.state_dict().items()}
    new = m.generate_poses(items, seed=5)
    ff = torch.randn(len(items), TINY["d_model"], generator=torch.Generator().manual_seed(1))
    new_ff = m.generate_poses(items, seed=5, first_feature=ff)
    with bench.old_cached_sampler():
        assert MarioNetNet.generate is not library_generate
        old = m.generate_poses(items, seed=5)
        old_ff = m.generate_poses(items, seed=5, first_feature=ff)
    full = m.generate_poses(items, seed=5, use_cache=False)
    assert MarioNetNet.generate is library_generate          # the swap is undone
    assert generator_class("marionet") is MarioNet           # importing the old one left it
    assert (new - old).abs().max() <= 1e-5 and (new - full).abs().max() <= 1e-5
    assert (new_ff - old_ff).abs().max() <= 1e-5
    assert not torch.allclose(new_ff, new, atol=1e-3)       # the first feature is used
    after = m.network.state_dict()
    assert after.keys() == state.keys()
    assert all(torch.equal(after[k], v) for k, v in state.items())


def test_decoder_cache_is_written_in_place():
    """The per-layer key/value buffers are allocated once for ``max_len`` steps: steps within
    it write in place (same storage), a step past it grows the buffers and keeps the filled
    prefix."""
    torch.manual_seed(0)
    dec = TransformerDecoder(2, 16, 4, 32, 0.0, "relu").eval()
    x, mem = torch.randn(2, 6, 16), torch.randn(2, 5, 16)
    full = dec(x, mem, causal=True)
    cache = dec.init_cache(mem, max_len=4)
    ptrs = [b.data_ptr() for kv in cache.self_kv for b in kv]
    outs = [dec.step(x[:, t:t + 1], cache) for t in range(4)]
    assert cache.length == 4 and cache.capacity == 4
    assert [b.data_ptr() for kv in cache.self_kv for b in kv] == ptrs
    outs += [dec.step(x[:, t:t + 1], cache) for t in range(4, 6)]
    assert cache.length == 6 and cache.capacity >= 6
    assert torch.allclose(torch.cat(outs, 1), full, atol=1e-5)


def test_kv_cache_benchmark_runs_and_agrees(capsys):
    """benchmarks/bench_kv_cache.py at a tiny size: before/after/uncached in one run, the chain
    figure, outputs equal to 1e-5 (the speed target is not checked at this size)."""
    mod = _bench_kv_cache()
    mod.main(["--batch", "2", "--frames", "3", "--repeats", "1", "--chain-actions", "2",
              "--json"])
    res = json.loads(capsys.readouterr().out)
    assert res["max_abs_diff_poses"] <= 1e-5 and res["max_abs_diff_poses_vs_before"] <= 1e-5
    assert res["chain_actions"] == 2 and res["chain_after_fps"] > 0 and res["chain_frames"] > 0
    assert {"before_s", "cached_s", "uncached_s", "speedup", "speedup_before"} <= res.keys()


# -- ablation switches -------------------------------------------------------------------------


def test_time_unrolling_off_gives_identical_frame_controls(clips, items):
    b = None
    for tu in (True, False):
        m = model(clips, time_unrolling=tu)
        net = m.network.eval()
        b = batch(m, items)
        with torch.no_grad():
            mu, _, tag, _ = net.encode(b["init"], b["labels"], b["next_labels"])
            ctrl = net.controls(mu, tag, b["trajectory"], b["lengths"])
        lat = ctrl[..., :TINY["d_model"] - TINY["traj_dim"]]
        same = torch.allclose(lat, lat[:, :1].expand_as(lat))
        assert same is (not tu)
        if not tu:  # the unrolling decoder is not even used
            hits = []
            h = net.unroll.register_forward_hook(lambda *a: hits.append(1))
            with torch.no_grad():
                net.controls(mu, tag, b["trajectory"], b["lengths"])
            h.remove()
            assert hits == []


def test_tag_injection_off_query_ignores_tag(clips, items):
    for ti in (True, False):
        net = model(clips, tag_injection=ti).network.eval()
        lengths = items.lengths
        T = int(lengths.max())
        with torch.no_grad():
            tag_a = net.embed_tags(torch.zeros_like(items.labels))
            tag_b = net.embed_tags(torch.full_like(items.labels, 2))
            qa = net.unroll_query(tag_a, lengths, T)
            qb = net.unroll_query(tag_b, lengths, T)
            z = torch.randn(len(items), TINY["d_model"])
            fa = net.frame_latents(z, tag_a, lengths, T)
            fb = net.frame_latents(z, tag_b, lengths, T)
        assert torch.equal(qa, qb) is (not ti)
        assert torch.allclose(fa, fb) is (not ti)
        # the query is the reverse positional encoding: time to arrival 0 on each item's last frame
        if not ti:
            from repro.models.layers import sinusoidal_encoding

            k = int(torch.argmax(lengths))
            L = int(lengths[k])
            assert torch.allclose(qa[k, L - 1], sinusoidal_encoding(torch.tensor(0), 16))


def _grads(m, b, epoch=0):
    m.network.train()
    m.network.zero_grad()
    torch.manual_seed(7)
    out = m.training_step(m.network, b, epoch)
    out["loss"].backward()
    return out, {n: p.grad.clone() for n, p in m.network.named_parameters() if p.grad is not None}


def test_next_tag_off_gets_no_gradient(clips, items):
    for nt in (True, False):
        m = model(clips, next_tag=nt)
        net = m.network.train()
        b = batch(m, items)
        mu, logvar, tag, nxt = net.encode(b["init"], b["labels"], b["next_labels"])
        nxt.retain_grad()
        (mu.square().sum() + logvar.sum()).backward()
        assert (float(nxt.grad.abs().max()) == 0.0) is (not nt)
        # through the whole training step: the next labels change nothing, gradients included
        b2 = dict(b, next_labels=(b["next_labels"] + 1) % clips.n_classes)
        o1, g1 = _grads(m, b)
        o2, g2 = _grads(m, b2)
        same = torch.equal(o1["loss"], o2["loss"]) and all(torch.equal(g1[k], g2[k]) for k in g1)
        assert same is (not nt)


def test_scheduled_sampling_switch_passes_and_weights(clips, items):
    def run(epoch, **over):
        m = model(clips, **over)
        b = batch(m, items)
        calls = []
        orig = m.network.decode
        m.network.decode = lambda x, *a, **k: (calls.append(x.detach().clone()), orig(x, *a, **k))[1]
        torch.manual_seed(0)
        out = m.training_step(m.network.train(), b, epoch)
        return out, calls

    # off: one pass, lambda1/lambda2 = 1/0, even long after the accomplish epoch
    out, calls = run(10, scheduled_sampling=False, ss_threshold_m=1e9)
    assert len(calls) == 1 and (float(out["lambda1"]), float(out["lambda2"])) == (1.0, 0.0)
    # on, after activation and close enough: two weight-sharing passes, 0.1/0.9, xi ramps
    out, calls = run(2, ss_threshold_m=1e9)
    assert len(calls) == 2 and float(out["ss_active"]) == 1.0
    assert (round(float(out["lambda1"]), 6), round(float(out["lambda2"]), 6)) == (0.1, 0.9)
    assert float(out["xi"]) == pytest.approx(0.5)
    # at xi = 1 the second pass reads the first pass's predictions only (BOP first)
    m = model(clips, ss_threshold_m=1e9)
    b = batch(m, items)
    seen = []
    orig = m.network.decode

    def record(x, *a, **k):
        y = orig(x, *a, **k)
        seen.append((x.detach().clone(), y.detach().clone()))
        return y

    m.network.decode = record
    m.network.eval()  # no dropout, so the first pass is reproducible
    m.training_step(m.network, b, 5)
    (x1, p1), (x2, _) = seen
    assert torch.equal(x2[:, 0], x1[:, 0]) and torch.allclose(x2[:, 1:], p1[:, :-1])
    # not active before the activate epoch, nor when the first pass is too far from the truth
    for epoch, thr in ((0, 1e9), (5, 0.0)):
        out, calls = run(epoch, ss_threshold_m=thr)
        assert len(calls) == 1 and float(out["lambda2"]) == 0.0


# -- losses ---------------------------------------------------------------------------------


def test_loss_terms_follow_eq1():
    pred = torch.tensor([[[1.0, 0.0], [2.0, 0.0], [9.0, 9.0]]])
    target = torch.zeros(1, 3, 2)
    mask = torch.tensor([[True, True, False]])
    got = _term(pred, target, mask, torch.tensor([2]), lambda_v=2.0)
    # (1/T) sum ||x||^2 = (1 + 4)/2; velocity (1/(T-1)) ||(2-1)||^2 = 1, times lambda_v
    assert float(got) == pytest.approx(2.5 + 2.0)
    assert float(kl_divergence(torch.zeros(2, 3), torch.zeros(2, 3))) == 0.0
    assert float(kl_divergence(torch.ones(1, 3), torch.zeros(1, 3))) == pytest.approx(1.5)


# -- training, sampling, determinism, persistence --------------------------------------------


@pytest.mark.parametrize("mode", ["eval", "train"])
@pytest.mark.parametrize("over", [{}, {"standardize_poses": False, "time_unrolling": False}])
def test_packed_frames_compute_the_padded_step(clips, items, over, mode, monkeypatch):
    """Issue 31: a training step over the valid frames only (``packed_frames``, the default)
    computes the padded step's loss terms and gradients (to rounding) when no dropout draws
    differ (eval mode; or train mode, with the written-out attention, and dropout made the
    identity), both passes of scheduled sampling included; the padded frames of a packed
    decode are the rest pose."""
    from repro.models import layers

    if mode == "train":
        monkeypatch.setattr(layers, "dropout", lambda x, p, training=True: x)
    torch.manual_seed(0)
    m = model(clips, ss_threshold_m=1e9, **over)
    b = batch(m, items)
    assert int(b["lengths"].min()) < b["target"].shape[1]          # the batch has padding
    unpacked = MarioNet(m.config.model_copy(update={"packed_frames": False}), clips.skeleton,
                        clips.n_classes, clips.fps)
    unpacked.network.load_state_dict(m.network.state_dict())
    outs, grads = [], []
    for g in (m, unpacked):
        g.network.train(mode == "train")
        g.network.zero_grad()
        torch.manual_seed(3)
        out = g.training_step(g.network, b, epoch=2)
        out["loss"].backward()
        outs.append(out)
        grads.append([p.grad.clone() for p in g.network.parameters() if p.grad is not None])
    assert outs[0]["ss_active"] == 1.0
    for k in ("loss", "rec1", "rec2", "L_J", "kl", "mpjpe"):
        assert torch.allclose(outs[0][k], outs[1][k], rtol=1e-5, atol=1e-7), k
    assert len(grads[0]) == len(grads[1])
    scale = max(float(c.abs().max()) for c in grads[1])
    for a, c in zip(*grads):  # to rounding, against the gradients' scale
        assert float((a - c).abs().max()) <= 1e-5 * scale
    net = m.network
    mask = ~net.padding_mask(b["lengths"], b["target"].shape[1])
    from repro.models.layers import Packing
    packing = Packing(mask)
    with torch.no_grad():
        mu, _, tag, _ = net.encode(b["init"], b["labels"], b["next_labels"])
        ctrl = net.controls(mu, tag, b["trajectory"], b["lengths"], packing)
        assert ctrl.shape == (int(mask.sum()), m.config.d_model)
        gt_in = torch.cat([b["init"][:, -1:], b["target"][:, :-1]], 1)
        p = net.decode(gt_in, ctrl, b["lengths"], packing=packing)
        full = net.decode(gt_in, net.controls(mu, tag, b["trajectory"], b["lengths"]), b["lengths"])
    assert p.shape == full.shape and torch.isfinite(p).all()
    assert torch.allclose(p[mask], full[mask], atol=1e-5)
    from repro.motion.rotations import matrix_to_6d
    rest = torch.cat([matrix_to_6d(torch.eye(3)).repeat(clips.skeleton.n_joints), torch.zeros(3)])
    assert torch.allclose(p[~mask], rest.expand(int((~mask).sum()), -1), atol=1e-6)


def test_fit_learns_and_is_deterministic(clips, items, test_items, tmp_path):
    hist = []
    run = dict(epochs=6, lr=3e-3, ss_threshold_m=1e9)
    m1 = model(clips, **run)
    r = m1.fit(items, seed=5, ckpt_dir=tmp_path / "ck", on_epoch=lambda e, rec: hist.append(rec))
    assert len(r.history) == 6 and hist[-1]["rec1"] < 0.8 * hist[0]["rec1"]
    assert any(h["ss_active"] > 0 for h in hist)
    assert not torch.equal(m1.network.pose_std, torch.ones_like(m1.network.pose_std))
    m2 = model(clips, **run)
    m2.fit(items, seed=5)
    for (k, a), b in zip(m1.network.state_dict().items(), m2.network.state_dict().values()):
        assert torch.equal(a, b), k
    s1 = m1.sample(test_items, seed=11)
    s2 = m2.sample(test_items, seed=11)
    assert torch.equal(s1.root, s2.root) and torch.equal(s1.rot6d, s2.rot6d)
    assert not torch.equal(m1.sample(test_items, seed=12).root, s1.root)
    assert torch.equal(m1.sample(test_items, seed=1, use_mean=True).root,
                       m1.sample(test_items, seed=2, use_mean=True).root)
    # batching does not change what is generated
    m1b = MarioNet(m1.config.model_copy(update={"sample_batch_size": 1}), clips.skeleton,
                   clips.n_classes, clips.fps)
    m1b.network.load_state_dict(m1.network.state_dict())
    assert torch.allclose(m1b.sample(test_items, seed=11).root, s1.root, atol=1e-5)
    # output shape, lengths, padding repeats the last valid frame
    assert s1.root.shape == (len(test_items), int(test_items.lengths.max()), 3)
    assert torch.equal(s1.lengths, test_items.lengths) and torch.equal(s1.labels, test_items.labels)
    k = int(torch.argmin(test_items.lengths))
    L = int(test_items.lengths[k])
    assert torch.equal(s1.root[k, L:], s1.root[k, L - 1:L].expand_as(s1.root[k, L:]))
    # resuming a finished run trains nothing more
    m3 = model(clips, **run)
    r3 = m3.fit(items, seed=5, ckpt_dir=tmp_path / "ck")
    assert r3.resumed_from == 6
    assert torch.equal(m3.network.pose_decode.weight, m1.network.pose_decode.weight)


def test_sample_is_in_world_frame(clips, test_items):
    m = model(clips)
    g = m.sample(test_items, seed=0)
    raw = m.generate_poses(test_items, seed=0)
    # undoing the items' normalisation by hand gives the same world roots
    root_item = raw[..., -3:]
    G, o = test_items.canon.rotation, test_items.canon.origin
    world = torch.einsum("bji,btj->bti", G, root_item) + o[:, None]
    k = int(torch.argmax(test_items.lengths))
    assert torch.allclose(g.root[k], world[k], atol=1e-5)


def test_save_load_roundtrip(clips, items, test_items, tmp_path):
    m = model(clips, epochs=1)
    m.fit(items, seed=0)
    d = m.save(tmp_path / "m")
    meta = json.loads((d / "config.json").read_text())
    assert meta["method_id"] == "marionet" and meta["config"]["d_model"] == 16
    for loaded in (MarioNet.load(d), Generator.load(d)):
        assert isinstance(loaded, MarioNet) and loaded.config == m.config
        assert torch.equal(loaded.sample(test_items, seed=4).root, m.sample(test_items, seed=4).root)
    with pytest.raises(MissingDataError):
        MarioNet.load(tmp_path / "nothing")
    (d / "weights.pt").write_bytes(b"garbage")
    with pytest.raises(DataError, match="weights.pt"):
        MarioNet.load(d)


def test_items_must_fit_the_model(clips, items):
    m = MarioNet(TINY, clips.skeleton, clips.n_classes + 1, clips.fps)
    with pytest.raises(ConfigError, match="classes"):
        m.sample(items, seed=0)
    m = MarioNet(TINY, clips.skeleton, clips.n_classes, 25.0)
    with pytest.raises(DataError, match="fps"):
        m.sample(items, seed=0)


def test_pack_poses_layout(items):
    p = pack_poses(items.action)
    J = items.skeleton.n_joints
    assert p.shape[-1] == 6 * J + 3
    assert torch.equal(p[..., -3:], items.action.root)
    assert torch.equal(p[..., 6:12], items.action.rot6d[..., 1, :])


def test_a_marionet_sample_leaves_as_bvh_within_1e4_cm(clips, items, test_items, tmp_path):
    """Issue 12: a MarioNet sample (decoded 6D rotations, generated root) written as BVH the
    way `repro export` writes it re-imports through the project's reader within 1e-4 cm."""
    from repro.data.bvh import parse_bvh
    from repro.data.bvh_write import write_bvh

    m = model(clips, epochs=1)
    m.fit(items, seed=0)
    g = m.sample(test_items, seed=5)
    for i in (0, len(test_items) - 1):
        n = int(g.lengths[i])
        one = g.motion.select(i).slice_time(0, n)
        path = write_bvh(tmp_path / f"s{i}.bvh", one.skeleton, one.root[0].double().numpy(),
                         one.rotmats()[0].double().numpy(), one.fps)
        got = parse_bvh(path.read_bytes(), path).world_positions()
        want = one.joints()[0].double().numpy() * 100.0
        assert got.shape == want.shape and np.abs(got - want).max() < 1e-4
