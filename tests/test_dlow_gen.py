"""DLow-Gen (repro/models/dlow_gen.py): shapes, seeded sampling, the flow assignment, both
training stages, the frozen VAE in stage 2, loss switches, save/load and resume."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch

from repro.data.odmo_items import WindowSource
from repro.data.registry import load_clipset
from repro.errors import ConfigError
from repro.models.base import Generator
from repro.models.baseline_io import item_noise
from repro.models.dlow_gen import DLowGen, DLowGenConfig
from repro.seeding import derive_seed, numpy_rng

torch.set_num_threads(1)

TINY = {"nz": 8, "nh_rnn": 32, "nh_mlp": (32,), "dlow_nh_mlp": (32,), "nk": 4,
        "batch_size": 32, "windows_per_epoch": 128, "vae_epochs": 6, "dlow_epochs": 6,
        "vae_epochs_fix": 6, "dlow_epochs_fix": 6, "d_scale": 1.0, "dlow_lr": 1e-3,
        "val_windows": 64, "sample_batch_size": 64}
SEED = 3


@pytest.fixture(scope="module")
def items():
    clips = load_clipset("bandai2-mini")
    return WindowSource(window=20).train_items(clips)


def make(items, **over):
    return DLowGen({**TINY, **over}, items.skeleton, items.n_classes, items.fps)


@pytest.fixture(scope="module")
def trained(items, tmp_path_factory):
    ckpt = tmp_path_factory.mktemp("dlow_ckpt")
    g = make(items)
    res = g.fit(items, seed=SEED, ckpt_dir=ckpt)
    return g, res, ckpt


def fixed_batch(items, n=64):
    wb = items.draw(n, numpy_rng(99, "test-batch"))
    return DLowGen._batch_of(wb)


def state(module):
    return {k: v.clone() for k, v in module.state_dict().items()}


def same_state(a, b):
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


# ---------------------------------------------------------------------------------------------


def test_config_defaults_and_validation():
    c = DLowGenConfig()
    assert (c.nz, c.nh_rnn, c.nk) == (128, 128, 10)
    assert (c.nh_mlp, c.dlow_nh_mlp) == ((300, 200), (1024, 512))
    assert (c.beta, c.lambda_kl, c.lambda_j) == (0.1, 1.0, 25.0)
    assert (c.d_scale, c.lambda_recon) == (100.0, 2.0)
    assert (c.vae_lr, c.dlow_lr, c.batch_size, c.windows_per_epoch) == (1e-3, 1e-4, 64, 2048)
    assert (c.vae_epochs, c.dlow_epochs) == (5000, 600)
    with pytest.raises(ConfigError):
        DLowGenConfig.resolve({"nk": 1})
    with pytest.raises(ConfigError):
        DLowGenConfig.resolve({"no_such_field": 1})
    # JSON round trip of the tuple fields (what save/load does)
    assert DLowGenConfig.resolve(c.model_dump(mode="json")) == c


def test_sample_shapes_determinism_and_batching(items):
    g = make(items)
    labels = torch.tensor([0, 3, 3, 9, 1, 0, 3])
    a = g.sample_windows(labels, 20, seed=5)
    assert a.shape == (7, 20, items.n_joints, 3) and a.dtype == torch.float32
    assert torch.isfinite(a).all()
    b = g.sample_windows(labels.numpy(), 20, seed=5)
    assert a.numpy().tobytes() == b.numpy().tobytes()
    c = g.sample_windows(labels, 20, seed=6)
    assert not torch.equal(a, c)
    assert g.sample_windows(labels, 7, seed=5).shape == (7, 7, items.n_joints, 3)
    small = DLowGen({**TINY, "sample_batch_size": 2}, items.skeleton, items.n_classes, items.fps)
    small.network.load_state_dict(g.network.state_dict())
    assert torch.allclose(small.sample_windows(labels, 20, seed=5), a, atol=1e-6)
    with pytest.raises(ConfigError):
        g.sample_windows([items.n_classes], 20, seed=0)
    with pytest.raises(ConfigError, match="sample_windows"):
        g.sample(None, seed=0)
    assert DLowGen.item_kind == "windows" and DLowGen.method_id == "dlow_gen"


def test_flow_assignment_and_shared_noise(items):
    g = make(items)          # nk = 4
    labels = torch.tensor([2, 5, 2, 2, 5, 2, 2, 2])
    flow, leader = g.flow_assignment(labels)
    # class 2 at positions 0,2,3,5,6,7 -> ranks 0..5 -> flows 0,1,2,3,0,1; groups {0,2,3,5},{6,7}
    assert flow.tolist() == [0, 0, 1, 2, 1, 3, 0, 1]
    assert leader.tolist() == [0, 1, 0, 0, 1, 0, 6, 6]
    out = g.sample_windows(labels, 12, seed=4)
    # row i decodes flow k of the DLow map applied to its group's noise
    eps = item_noise(4, "dlow_gen", (len(labels), g.config.nz))[leader]
    with torch.no_grad():
        z, _, _ = g.network.dlow(labels, eps)
        zk = z[torch.arange(len(labels)), flow]
        ref = g.network.vae.decode(labels, zk, 12).view(len(labels), 12, -1, 3)
    assert torch.allclose(out, ref, atol=1e-6)


def test_fit_history_both_stages(items, trained):
    g, res, ckpt = trained
    c = g.config
    assert res.epochs == c.vae_epochs + c.dlow_epochs and res.resumed_from is None
    assert [h["stage"] for h in res.history] == ["vae"] * c.vae_epochs + ["dlow"] * c.dlow_epochs
    assert [h["epoch"] for h in res.history] == list(range(res.epochs))
    assert [h["stage_epoch"] for h in res.history] == (list(range(c.vae_epochs))
                                                      + list(range(c.dlow_epochs)))
    assert all(h["batches"] == 4 for h in res.history)          # 128 windows / 32
    assert {"mse", "kld", "mpjpe"} <= set(res.history[0])
    assert {"kld", "div", "recon", "min_mpjpe"} <= set(res.history[-1])
    assert (ckpt / "vae" / "checkpoint.pt").is_file()
    assert (ckpt / "dlow" / "checkpoint.pt").is_file()


def test_training_lowers_each_stage_loss(items, trained):
    g, _, _ = trained
    batch = fixed_batch(items)
    init = make(items)
    init._build(derive_seed(SEED, "dlow_gen", "init"))      # the weights fit started from

    def vae_loss(gen):
        torch.manual_seed(0)
        with torch.no_grad():
            return float(gen.vae_step(gen.network.vae, batch, 0)["loss"])

    def dlow_loss(gen):
        torch.manual_seed(0)
        with torch.no_grad():
            return float(gen.dlow_step(gen.network.dlow, batch, 0)["loss"])

    assert vae_loss(g) < 0.8 * vae_loss(init)
    # stage 2 from its initial weights on the trained VAE, against the trained DLow network
    init.network.vae.load_state_dict(g.network.vae.state_dict())
    assert dlow_loss(g) < dlow_loss(init)


def test_stage_two_keeps_vae_weights(items, trained):
    g, _, ckpt = trained
    after_vae = torch.load(ckpt / "vae" / "checkpoint.pt", weights_only=True)["model"]
    assert same_state(after_vae, g.network.vae.state_dict())
    init = make(items)
    init._build(derive_seed(SEED, "dlow_gen", "init"))
    assert not same_state(init.network.dlow.state_dict(), g.network.dlow.state_dict())
    assert not same_state(init.network.vae.state_dict(), g.network.vae.state_dict())
    assert all(p.requires_grad for p in g.network.parameters())


def test_flows_give_different_samples(items, trained):
    g, _, _ = trained
    K = g.config.nk
    s = g.sample_windows(torch.full((K,), 4), 20, seed=0).reshape(K, -1)
    d = torch.cdist(s, s)
    off = d[~torch.eye(K, dtype=torch.bool)]
    assert off.min() > 1e-3                           # every pair of flows differs
    # a longer list repeats the first group (up to float batching) and starts a new one
    s2 = g.sample_windows(torch.full((2 * K,), 4), 20, seed=0).reshape(2 * K, -1)
    assert torch.allclose(s2[:K], s, atol=1e-5)
    assert not torch.equal(s2[K], s2[0])


def test_loss_switches_remove_terms(items, trained):
    g, _, _ = trained
    batch = fixed_batch(items, 32)
    terms = {"lambda_kl": "kld", "lambda_j": "div", "lambda_recon": "recon"}

    def run(gen, stage):
        torch.manual_seed(1)
        with torch.no_grad():
            if stage == "dlow":
                return gen.dlow_step(gen.network.dlow, batch, 0)
            return gen.vae_step(gen.network.vae, batch, 0)

    full = run(g, "dlow")
    w = {k: getattr(g.config, k) for k in terms}
    total = sum(w[k] * full[t] for k, t in terms.items())
    assert torch.allclose(full["loss"], total, rtol=1e-5)
    for off, term in terms.items():
        h = make(items, **{off: 0.0})
        h.network.load_state_dict(g.network.state_dict())
        out = run(h, "dlow")
        assert torch.allclose(out[term], full[term])                 # still logged
        rest = sum(w[k] * full[t] for k, t in terms.items() if k != off)
        assert torch.allclose(out["loss"], rest, rtol=1e-5)
        assert not torch.allclose(out["loss"], full["loss"], rtol=1e-4)
    h = make(items, beta=0.0)
    h.network.load_state_dict(g.network.state_dict())
    out = run(h, "vae")
    full_vae = run(g, "vae")
    assert torch.allclose(out["loss"], out["mse"]) and full_vae["loss"] > out["loss"]


def test_save_load_round_trip(items, trained, tmp_path):
    g, _, _ = trained
    g.save(tmp_path / "m")
    keys = list(torch.load(tmp_path / "m" / "weights.pt", weights_only=True))
    assert any(k.startswith("vae.") for k in keys) and any(k.startswith("dlow.") for k in keys)
    labels = torch.tensor([0, 1, 1, 7, 7, 7, 7, 7, 2])
    ref = g.sample_windows(labels, 20, seed=11)
    for loaded in (DLowGen.load(tmp_path / "m"), Generator.load(tmp_path / "m")):
        assert isinstance(loaded, DLowGen) and loaded.config == g.config
        assert loaded.sample_windows(labels, 20, seed=11).numpy().tobytes() == ref.numpy().tobytes()


def test_resume_is_exact(items, trained, tmp_path):
    g, res, ckpt = trained
    again = make(items)
    r2 = again.fit(items, seed=SEED, ckpt_dir=ckpt)           # both stages complete
    assert r2.resumed_from == res.epochs
    assert same_state(again.network.state_dict(), g.network.state_dict())
    assert r2.history == res.history
    # stage 2 lost: the VAE resumes complete, DLow retrains to the same bytes
    part = tmp_path / "ckpt"
    shutil.copytree(ckpt, part)
    shutil.rmtree(part / "dlow")
    third = make(items)
    r3 = third.fit(items, seed=SEED, ckpt_dir=part)
    assert r3.resumed_from == g.config.vae_epochs
    assert same_state(third.network.state_dict(), g.network.state_dict())


def test_validation_does_not_change_weights(items, trained):
    g, res, _ = trained
    val = items.subset(np.arange(0, len(items), 5))
    seen = []
    v = make(items)
    rv = v.fit(items, seed=SEED, val_items=val, on_epoch=lambda e, r: seen.append((e, r["stage"])))
    assert same_state(v.network.state_dict(), g.network.state_dict())
    assert "val_mse" in rv.history[0] and "val_recon" in rv.history[-1]
    assert all("val_loss" in h for h in rv.history)
    assert seen == [(h["epoch"], h["stage"]) for h in res.history]
    with pytest.raises(TypeError):
        v.fit(items.as_action_items(), seed=0)
