"""The device path (issue 15, item 2): the scale profile's ``device`` and ``--device``, the
check that a CUDA device exists before any work, the device in job keys (nothing for the CPU),
the CUDA determinism settings, and models that train and sample on the device their network is
on.  No test needs a GPU: the device path runs on the CPU explicitly, and on PyTorch's ``meta``
device, where a tensor made on the CPU that meets the network's tensors raises (as it would on
CUDA).  Every generator is run there: MarioNet, MANN, Action2Motion, ACTOR, MACVAE, SSMCT, the
MultiAct composites, ODMO, Act-MoCoGAN and DLow-Gen (boolean-mask losses through
:class:`MetaMasksAllTrue`)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.overrides import TorchFunctionMode

from repro.engine.job import Job
from repro.errors import ConfigError, SpecError
from repro.seeding import CUDA_DETERMINISM, device_key, prepare_device
from repro.specs.scales import (device_override, gpus_per_job, load_scales, require_device,
                                resolve_scale, scales_path)
from repro.train.loop import current_device, to_device, train, use_device
from model_fixtures import (clips, items, mini_clips, one_torch_thread,  # noqa: F401 (fixtures)
                            test_items)
from test_items import synthetic_clipset
from test_multiact_baselines import make_pairs

TINY_MARIONET = dict(d_model=16, traj_dim=4, cond_heads=2, cond_ff=32, cond_layers=1, traj_heads=1,
                     traj_ff=8, unroll_heads=2, unroll_ff=32, unroll_layers=1, dec_heads=2,
                     dec_ff=32, dec_layers=2, batch_size=8, lr=1e-3, epochs=2,
                     ss_activate_epoch=0, ss_accomplish_epoch=3, sample_batch_size=4)
TINY_MANN = dict(n_experts=3, hidden=24, gating_hidden=8, batch_size=32, epochs=2, lr=3e-3,
                 restart_period=2, sample_batch_size=4)
TINY_A2M = dict(dim_z=4, hidden=16, batch_size=8, epochs=1, lr=3e-3, sample_batch_size=4)
TINY_ACTOR = dict(latent_dim=16, ff_size=32, num_layers=1, num_heads=2, batch_size=8, epochs=1,
                  lr=1e-3, sample_batch_size=4)
TINY_MACVAE = dict(d_model=32, layers=1, heads=2, ff_size=64, batch_size=8, epochs=1, lr=1e-3,
                   sample_batch_size=5)
TINY_SSMCT = dict(d_model=32, layers=1, heads=2, ff_size=64, batch_size=8, epochs=1, lr=1e-3,
                  sample_batch_size=5, max_window=48)


@pytest.fixture
def no_cuda(monkeypatch):
    """This machine as one without CUDA, whatever it has."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)


# -- the profile's device ---------------------------------------------------------------------

def test_profiles_name_their_device_and_paper_is_cuda():
    assert resolve_scale("quick").device == "cpu"
    assert resolve_scale("medium").device == "cpu"
    assert resolve_scale("paper").device == "cuda"
    assert gpus_per_job(resolve_scale("quick")) == 0
    assert gpus_per_job(resolve_scale("paper")) == 1


@pytest.mark.parametrize("bad", ["gpu", "cuda:x", "CUDA", "cuda:", "mps", ""])
def test_an_unknown_device_in_the_profile_names_scales_toml(tmp_path, bad):
    text = scales_path().read_text().replace('device = "cuda"', f'device = "{bad}"', 1)
    path = tmp_path / "scales.toml"
    path.write_text(text)
    with pytest.raises(SpecError) as e:
        load_scales(path)
    assert "scales.toml" in str(e.value) and "paper" in str(e.value) and "device" in str(e.value)
    assert e.value.exit_code == 2


def test_device_override_and_explicit_device():
    with device_override("cuda:1"):
        assert resolve_scale("quick").device == "cuda:1"
        assert resolve_scale("quick", device="cpu").device == "cpu"  # explicit wins
    assert resolve_scale("paper").device == "cuda"  # the override ends with its block
    with device_override("cpu"):
        assert resolve_scale("paper").device == "cpu"
    with pytest.raises(ConfigError, match="--device: unknown device 'tpu'"):
        with device_override("tpu"):
            pass
    with pytest.raises(ConfigError, match="unknown device"):
        resolve_scale("quick", device="cuda0")


def test_cpu_profile_hash_has_no_device_entry():
    q = resolve_scale("quick")
    assert "device" not in q.to_dict()
    assert q.scale_hash == resolve_scale("quick", device="cpu").scale_hash
    assert resolve_scale("quick", device="cuda").to_dict()["device"] == "cuda"
    assert resolve_scale("quick", device="cuda").scale_hash != q.scale_hash


def test_cuda_unavailable_is_one_clear_error(no_cuda):
    assert require_device(resolve_scale("quick")) == "cpu"
    with pytest.raises(ConfigError) as e:
        require_device(resolve_scale("paper"))
    msg = str(e.value)
    assert "tables/scales.toml [paper] device" in msg and "--device cpu" in msg
    with device_override("cuda"), pytest.raises(ConfigError, match=r"\(--device\)"):
        require_device(resolve_scale("quick"))
    with pytest.raises(ConfigError, match="torch.cuda.is_available"):
        prepare_device("cuda")


def test_cli_refuses_cuda_before_any_work(no_cuda, tmp_path, monkeypatch, capsys):
    from cli.main import main

    monkeypatch.setenv("REPRO_HOME", str(tmp_path))
    assert main(["run", "marionette/table1", "--scale", "paper"]) == 2
    err = capsys.readouterr().err
    assert "scales.toml [paper] device" in err and "Traceback" not in err
    assert main(["run", "marionette/table1", "--scale", "quick", "--device", "cuda"]) == 2
    assert "(--device)" in capsys.readouterr().err
    assert not (tmp_path / "store").exists() and not (tmp_path / "runs").exists()
    with pytest.raises(SystemExit) as e:
        main(["plan", "marionette/table1", "--device", "gpu"])
    assert e.value.code == 2
    assert "argument --device: unknown device 'gpu'" in capsys.readouterr().err


# -- job keys ---------------------------------------------------------------------------------

def _job(device=None):
    return Job("train", "repro.engine.steps:train_method", {"a": 1}, seed=0, threads=1,
               device=device)


def test_cpu_adds_nothing_to_a_key_and_cuda_changes_it():
    plain = _job()
    assert "device" not in plain.key_parts()
    assert _job("cpu").key() == plain.key()
    cuda = _job("cuda")
    assert cuda.key() != plain.key()
    assert cuda.key_parts()["device"] == {"type": "cuda", **CUDA_DETERMINISM}
    assert _job("cuda:1").key() == cuda.key()  # the card's index is placement, not content
    assert device_key(None) is None and device_key("cpu") is None
    with pytest.raises(ValueError, match="job device"):
        _job("gpu")


def test_plan_keys_follow_the_device():
    from repro.engine.table_plan import build_plan
    from repro.specs.load import find_spec

    spec = find_spec("marionette/table1")

    def train_keys(scale):
        plan = build_plan(spec, scale, "bandai2-mini")
        return sorted(j.key() for r in plan.rows for jobs in r.train.values() for j in jobs)

    cpu = train_keys(resolve_scale("quick"))
    assert cpu and cpu == train_keys(resolve_scale("quick", device="cpu"))
    cuda = train_keys(resolve_scale("quick", device="cuda"))
    # every training but nearest_clip's (a retrieval on the CPU) changes key
    assert len(cuda) == len(cpu) and len(set(cuda) & set(cpu)) == 1


def _plan_jobs(scale):
    """label -> job of quick Table 1's graph at ``scale``."""
    from repro.engine.job import topo_order
    from repro.engine.table_plan import build_plan
    from repro.specs.load import find_spec

    plan = build_plan(find_spec("marionette/table1"), scale, "bandai2-mini")
    return {j.label: j for j in topo_order(plan.jobs())}


def test_only_jobs_computing_with_a_network_carry_the_device(no_cuda, tmp_path, monkeypatch,
                                                              capsys):
    """With --device cuda, train and generate of the neural methods carry the device (key and
    Ray's GPU); measure, measure_real and nearest_clip's jobs compute on the CPU and carry
    none, so their key material is the CPU plan's."""
    from cli.main import main

    monkeypatch.setenv("REPRO_HOME", str(tmp_path))
    assert main(["plan", "marionette/table1", "--device", "cuda", "--json"]) == 0  # no GPU needed
    capsys.readouterr()
    with device_override("cuda"):
        cuda = _plan_jobs(resolve_scale("quick"))
    cpu = _plan_jobs(resolve_scale("quick"))
    assert sorted(cuda) == sorted(cpu) and len(cuda) == 38
    on_device = {label for label, j in cuda.items() if "device" in j.key_parts()}
    neural = {label for label, j in cuda.items() if j.kind in ("train", "generate")
              and not label.startswith("nearest_clip/")}
    assert on_device == neural and len(neural) == 16
    for label, j in cuda.items():
        assert "device" not in cpu[label].key_parts()  # the CPU plan names no device anywhere
        if label in neural:
            assert j.key_parts()["device"]["type"] == "cuda" and j.device == "cuda"
        else:
            assert j.kind in ("measure", "measure_real") or label.startswith("nearest_clip/")
            assert j.device is None
            parts, cpu_parts = j.key_parts(), cpu[label].key_parts()
            # same key material apart from inputs that computed on the GPU
            assert {k: v for k, v in parts.items() if k != "inputs"} == \
                {k: v for k, v in cpu_parts.items() if k != "inputs"}
            if j.kind == "measure_real" or label.startswith("nearest_clip/"):
                assert j.key() == cpu[label].key()


def test_prepare_device_on_the_cpu_changes_nothing():
    before = (torch.backends.cudnn.deterministic, torch.are_deterministic_algorithms_enabled())
    assert prepare_device(None) == torch.device("cpu") == prepare_device("cpu")
    assert (torch.backends.cudnn.deterministic, torch.are_deterministic_algorithms_enabled()) \
        == before


# -- the loop and the models on a device -------------------------------------------------------

def test_to_device_and_use_device():
    sd = torch.nn.Linear(2, 2).state_dict()
    moved = to_device({"m": sd, "t": (torch.zeros(1), 3), "n": None}, "meta")
    assert moved["m"]["weight"].is_meta and moved["t"][0].is_meta and moved["t"][1] == 3
    assert moved["m"]._metadata == sd._metadata  # load_state_dict's module versions kept
    x = torch.ones(2)
    assert to_device(x, "cpu") is x
    assert current_device() == "cpu"
    with use_device("meta"):
        assert current_device() == "meta"
    assert current_device() == "cpu"


def test_marionet_trains_and_samples_on_the_cpu_explicitly(clips, items, test_items, tmp_path):
    """The device path with device "cpu" named everywhere is the plain path, bit for bit."""
    from repro.models.base import Generator
    from repro.models.marionet import MarioNet

    def run(explicit: bool):
        m = MarioNet(TINY_MARIONET, clips.skeleton, clips.n_classes, clips.fps)
        if explicit:
            with use_device(prepare_device("cpu")):
                res = m.fit(items, seed=1, val_items=test_items)
            m.to("cpu")
        else:
            res = m.fit(items, seed=1, val_items=test_items)
        return m, res, m.sample(test_items, seed=2)

    (a, ra, sa), (b, rb, sb) = run(False), run(True)
    assert b.device == torch.device("cpu")
    assert ra.history == rb.history
    assert torch.equal(sa.motion.root, sb.motion.root)
    assert torch.equal(sa.motion.rot6d, sb.motion.rot6d)
    back = Generator.load(b.save(tmp_path / "m"))
    assert back.device == torch.device("cpu")
    assert torch.equal(back.sample(test_items, seed=2).motion.root, sa.motion.root)


def test_train_moves_model_and_batches_to_its_device():
    """``train(device=...)`` puts the model and each batch on the device (here meta), and
    writes checkpoints whose tensors are CPU tensors."""
    seen = []
    net = torch.nn.Linear(3, 1)
    opt = torch.optim.SGD(net.parameters(), lr=0.1)

    def batches(epoch, gen):
        yield {"x": torch.randn(4, 3, generator=gen)}

    def step(model, batch, epoch):
        seen.append(batch["x"].device.type)
        return {"loss": model(batch["x"]).sum()}

    with MetaReadsAsZeros():
        train(net, opt, batches=batches, step=step, epochs=2, seed=0, config={},
              device="meta")
    assert seen == ["meta", "meta"] and net.weight.is_meta


class MetaReadsAsZeros(TorchFunctionMode):
    """Lets a model run with its network on PyTorch's ``meta`` device (shapes, no values):
    what the code reads back to Python or copies to the CPU comes back as zeros (a truth test
    as True, an integer as 1).  A tensor the code makes on the CPU that meets a tensor of the
    network raises "not on the expected device", as a device-less factory would on CUDA."""

    READS = {"item", "tolist", "numpy", "__bool__", "__float__", "__int__", "__index__", "cpu",
             "to", "__array__", "__len__"}

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        name = getattr(func, "__name__", "")
        t = args[0] if args else None
        if name not in self.READS or not isinstance(t, torch.Tensor) or not t.is_meta:
            return func(*args, **kwargs)
        if name == "to":
            dev, dtype, _, _ = torch._C._nn._parse_to(*args[1:], **kwargs)
            if dev is None or torch.device(dev).type == "meta":
                return func(*args, **kwargs)
            return torch.zeros(t.shape, dtype=dtype or t.dtype, device=dev)
        zeros = torch.zeros(t.shape, dtype=t.dtype)
        fixed = {"cpu": zeros, "__bool__": True, "__int__": 1, "__index__": 1, "__float__": 0.0,
                 "__len__": t.shape[0] if t.dim() else 0}
        return fixed[name] if name in fixed else getattr(zeros, name)()


def _on_meta(gen, fit_items, sample, mode=MetaReadsAsZeros):
    with mode():
        with use_device("meta"):
            gen.fit(fit_items, seed=0)
        assert gen.device.type == "meta"
        out = sample(gen)
    return out


def test_marionet_trains_and_samples_on_the_networks_device(clips, items, test_items):
    from repro.models.marionet import MarioNet

    m = MarioNet(TINY_MARIONET, clips.skeleton, clips.n_classes, clips.fps)
    out = _on_meta(m, items, lambda g: g.sample(test_items, seed=0))
    assert out.motion.root.device.type == "cpu"  # results come back on the CPU
    assert out.motion.root.shape[0] == len(test_items)
    with MetaReadsAsZeros():
        tf = m.teacher_forced(test_items, seed=0)
    assert tf.motion.root.device.type == "cpu"


def test_mann_samples_on_the_networks_device(clips, items, test_items):
    from repro.models.mann import MANN

    m = MANN(TINY_MANN, clips.skeleton, clips.n_classes, clips.fps)
    out = _on_meta(m, items, lambda g: g.sample(test_items, seed=0))
    assert out.motion.root.device.type == "cpu"


@pytest.mark.parametrize("method", ["odmo", "act_mocogan", "dlow_gen"])
def test_window_models_train_and_sample_on_the_networks_device(mini_clips, method):
    from repro.data.odmo_items import WindowSource
    from repro.models.base import generator_class

    cfg = {"dlow_gen": {"nz": 8, "nh_rnn": 16, "nh_mlp": (16,), "dlow_nh_mlp": (16,), "nk": 3,
                        "batch_size": 16, "windows_per_epoch": 32, "vae_epochs": 1,
                        "dlow_epochs": 1, "vae_epochs_fix": 1, "dlow_epochs_fix": 1,
                        "val_windows": 16, "sample_batch_size": 4},
           "odmo": {"reduction": "sum", "enc_hidden": 16, "enc_feature": 16, "embed": 32,
                    "hidden": 32, "epochs": 1, "windows_per_epoch": 32, "batch_size": 16,
                    "val_pairs": 16},
           "act_mocogan": {"dim_z_content": 8, "dim_z_motion": 4, "g_hidden": 32,
                           "di_hidden": 32, "dv_hidden": 16, "dv_layers": 1, "batch_size": 16,
                           "windows_per_epoch": 32, "epochs": 1, "val_windows": 16}}[method]
    pool = WindowSource(window=20).train_items(mini_clips)
    g = generator_class(method)(cfg, pool.skeleton, pool.n_classes, pool.fps)
    labels = np.arange(pool.n_classes).repeat(2)
    out = _on_meta(g, pool, lambda g: g.sample_windows(labels, 20, seed=0, pool=pool))
    assert out.device.type == "cpu" and out.shape[:2] == (labels.size, 20)


@pytest.mark.parametrize("representation", ["6d", "lie", "xyz"])
def test_a2m_trains_and_samples_on_the_networks_device(clips, items, test_items, representation):
    from repro.models.a2m import A2M

    cfg = {**TINY_A2M, "representation": representation,
           "initial_pose": representation != "xyz"}  # xyz without it: A2M's zero start vector
    m = A2M(cfg, clips.skeleton, clips.n_classes, clips.fps)
    if representation == "xyz":
        out = _on_meta(m, items, lambda g: g.sample_joints(test_items, seed=0))
        assert out.device.type == "cpu" and out.shape[0] == len(test_items)
    else:
        out = _on_meta(m, items, lambda g: g.sample(test_items, seed=0))
        assert out.motion.root.device.type == "cpu" and out.motion.root.shape[0] == len(test_items)
        with MetaReadsAsZeros():
            assert m.sample(test_items, seed=0, use_mean=True).motion.root.device.type == "cpu"


class MetaMasksAllTrue(MetaReadsAsZeros):
    """:class:`MetaReadsAsZeros` for models whose losses select frames with a boolean mask
    (ACTOR, MACVAE and SSMCT: ``out[valid]``).  Such an index has a data-dependent shape, which
    the ``meta`` device cannot compute (it refuses ``nonzero``); here a boolean mask over a
    tensor's leading dimensions reads as all True, so ``x[mask]`` is ``x`` with those
    dimensions flattened — the same shape for every tensor the same mask selects from, which is
    all a loss needs.  The device check stays PyTorch's own: every other op runs on ``meta`` as
    it is, and a mask on another device than the tensor it selects from raises here (on CUDA
    a CPU mask would cost a host round trip per use).  Integer tensors copied to the CPU read as
    ones (valid lengths for ``pack_padded_sequence`` in MACVAE's recurrent backbones).

    Why not record factory calls on the CPU instead: on the CPU a ``.to(self.device)`` is a
    no-op, so a recorder cannot tell a tensor meant for the host (the sampled output, the noise
    drawn on the CPU) from one that should have followed the network; on ``meta`` the network's
    tensors are on another device and every missed move raises where it happens."""

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        if func is torch.Tensor.__getitem__ and len(args) == 2:
            t, idx = args
            mask = idx[0] if isinstance(idx, tuple) and len(idx) == 1 else idx
            if (isinstance(t, torch.Tensor) and isinstance(mask, torch.Tensor)
                    and mask.dtype == torch.bool and (t.is_meta or mask.is_meta)):
                if t.device != mask.device:
                    raise RuntimeError(f"a boolean mask on {mask.device} selects from a tensor "
                                       f"on {t.device}")
                k = mask.dim()
                if tuple(mask.shape) != tuple(t.shape[:k]):
                    raise IndexError(f"mask {tuple(mask.shape)} does not match {tuple(t.shape)}")
                return t.reshape((-1,) + tuple(t.shape[k:]))
        t = args[0] if args else None
        if (getattr(func, "__name__", "") == "cpu" and isinstance(t, torch.Tensor) and t.is_meta
                and not t.is_floating_point() and t.dtype != torch.bool):
            return torch.ones(t.shape, dtype=t.dtype)
        return super().__torch_function__(func, types, args, kwargs)


def test_the_mask_mode_still_catches_host_tensors():
    """The mode lets masks through and nothing else: a CPU mask over a network tensor, a CPU
    tensor meeting one, and a mask that does not fit all still raise."""
    x = torch.zeros(2, 3, 4, device="meta")
    with MetaMasksAllTrue():
        assert x[torch.ones(2, 3, dtype=torch.bool, device="meta")].shape == (6, 4)
        with pytest.raises(RuntimeError, match="boolean mask on cpu"):
            x[torch.ones(2, 3, dtype=torch.bool)]
        with pytest.raises(RuntimeError, match="device"):
            x + torch.ones(4)
        with pytest.raises(IndexError):
            x[torch.ones(3, dtype=torch.bool, device="meta")]
        assert torch.equal(torch.tensor([2, 5], device="meta").cpu(), torch.ones(2, dtype=torch.long))


@pytest.fixture(scope="module")
def pair_clips():
    """Clips long enough to cut a [S_p, T, S_c] pair from each (test_multiact_baselines)."""
    return synthetic_clipset(n_per_class=8, min_len=30, max_len=44)


@pytest.fixture(scope="module")
def pairs(pair_clips):
    return make_pairs(pair_clips)


def test_actor_trains_and_samples_on_the_networks_device(clips, items, test_items):
    from repro.models.actor import ACTOR

    m = ACTOR(TINY_ACTOR, clips.skeleton, clips.n_classes, clips.fps)
    out = _on_meta(m, items, lambda g: g.sample(test_items, seed=0), MetaMasksAllTrue)
    assert out.motion.root.device.type == "cpu" and out.motion.root.shape[0] == len(test_items)


@pytest.mark.parametrize("backbone", ["transformer", "lstm", "mlp"])
def test_macvae_trains_and_samples_on_the_networks_device(pairs, backbone):
    from repro.models.macvae import MACVAE

    m = MACVAE({**TINY_MACVAE, "backbone": backbone}, pairs.skeleton, pairs.n_classes, pairs.fps)
    out = _on_meta(m, pairs, lambda g: g.sample(pairs, seed=0), MetaMasksAllTrue)
    assert out.motion.root.device.type == "cpu" and out.motion.root.shape[0] == len(pairs)


def test_ssmct_and_the_composites_train_and_sample_on_the_networks_device(pair_clips, pairs):
    """SSMCT trains and in-betweens on the device; the composites (ACTOR + SSMCT, ACTOR +
    Interpolation, aligned or not) sample with their components' networks there."""
    from repro.data.clipset import TRAIN
    from repro.models.actor import ACTOR
    from repro.data.contexts import build_items
    from repro.models.multiact_baselines import ActorSSMCT, Interpolation
    from repro.models.ssmct import SSMCT

    ss = SSMCT(TINY_SSMCT, pair_clips.skeleton, pair_clips.n_classes, pair_clips.fps)
    out = _on_meta(ss, pairs, lambda g: g.sample(pairs, seed=0), MetaMasksAllTrue)
    assert out.motion.root.device.type == "cpu" and out.motion.root.shape[0] == len(pairs)
    actor = ACTOR(TINY_ACTOR, pair_clips.skeleton, pair_clips.n_classes, pair_clips.fps)
    _on_meta(actor, build_items(pair_clips, TRAIN), lambda g: None, MetaMasksAllTrue)
    for cls in (ActorSSMCT, Interpolation):
        for align in (True, False):
            parts = {"actor": actor, "ssmct": ss} if cls is ActorSSMCT else {"actor": actor}
            comp = cls.from_components(parts, {"align": align})
            assert comp.device.type == "meta"
            with MetaReadsAsZeros():
                res = comp.sample(pairs, seed=0)
            assert res.motion.root.device.type == "cpu" and res.motion.root.shape[0] == len(pairs)


def _sampled(out) -> tuple:
    """A sample's tensors (GeneratedItems / GeneratedPairs: the motion's; else itself)."""
    motion = getattr(out, "motion", None)
    return (out,) if motion is None else (motion.root, motion.rot6d)


@pytest.mark.parametrize("method", ["a2m", "actor", "macvae", "ssmct"])
def test_baselines_on_the_cpu_explicitly_are_the_plain_path(method, clips, items, test_items,
                                                            pair_clips, pairs):
    """Training under ``use_device("cpu")`` and sampling after ``.to("cpu")`` give the plain
    path's history and samples bit for bit (the moves are no-ops on the CPU; the noise is
    drawn on the CPU in the same order either way)."""
    from repro.models.base import generator_class

    cfg = {"a2m": TINY_A2M, "actor": TINY_ACTOR, "macvae": TINY_MACVAE, "ssmct": TINY_SSMCT}
    fit_items, sample_items = ((pairs, pairs) if method in ("macvae", "ssmct")
                               else (items, test_items))
    src = pairs if method in ("macvae", "ssmct") else clips

    def run(explicit: bool):
        g = generator_class(method)(cfg[method], src.skeleton, src.n_classes, src.fps)
        if explicit:
            with use_device(prepare_device("cpu")):
                res = g.fit(fit_items, seed=1)
            g.to("cpu")
        else:
            res = g.fit(fit_items, seed=1)
        return res.history, _sampled(g.sample(sample_items, seed=2))

    (ha, sa), (hb, sb) = run(False), run(True)
    assert ha == hb
    assert all(torch.equal(a, b) for a, b in zip(sa, sb))


# -- run records ------------------------------------------------------------------------------

def test_run_record_names_the_device_and_the_gpu(tmp_path, monkeypatch):
    """A CUDA run's record says env.device "cuda" (the scale's device, passed by run_tables)
    and the GPU: the card's name, torch.version.cuda and cuDNN's version; a CPU run's has no
    gpu entry."""
    from repro.store import runs
    from repro.engine.runner import run_tables

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda device=None: "Test GPU 80GB")
    rec = runs.RunRecorder(table="toy/gpu", device="cuda", runs_dir=tmp_path)
    env = rec.data["env"]
    assert env["device"] == "cuda"
    assert env["gpu"]["name"] == "Test GPU 80GB" and env["gpu"]["cuda"] == torch.version.cuda
    assert "cudnn" in env["gpu"]
    assert "gpu" not in runs.RunRecorder(table="toy/cpu", runs_dir=tmp_path).data["env"]
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)  # a Ray driver: no card
    assert runs.RunRecorder(table="toy/ray", device="cuda:1",
                            runs_dir=tmp_path).data["env"]["gpu"]["name"] is None

    seen = []

    class Stop(Exception):
        pass

    def recorder(**kw):  # what run_tables gives the recorder, then stop before any work
        seen.append(kw.get("device"))
        raise Stop

    monkeypatch.setattr(runs, "RunRecorder", recorder)
    for device in ("cuda", None):
        with device_override(device), pytest.raises(Stop):
            run_tables(["marionette/table1"], progress=False)
    assert seen == ["cuda", "cpu"]
