"""The device path (issue 15, item 2): the scale profile's ``device`` and ``--device``, the
check that a CUDA device exists before any work, the device in job keys (nothing for the CPU),
the CUDA determinism settings, and models that train and sample on the device their network is
on.  No test needs a GPU: the device path runs on the CPU explicitly, and on PyTorch's ``meta``
device, where a tensor made on the CPU that meets the network's tensors raises (as it would on
CUDA)."""

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

TINY_MARIONET = dict(d_model=16, traj_dim=4, cond_heads=2, cond_ff=32, cond_layers=1, traj_heads=1,
                     traj_ff=8, unroll_heads=2, unroll_ff=32, unroll_layers=1, dec_heads=2,
                     dec_ff=32, dec_layers=2, batch_size=8, lr=1e-3, epochs=2,
                     ss_activate_epoch=0, ss_accomplish_epoch=3, sample_batch_size=4)
TINY_MANN = dict(n_experts=3, hidden=24, gating_hidden=8, batch_size=32, epochs=2, lr=3e-3,
                 restart_period=2, sample_batch_size=4)


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
    from repro.engine.tables import build_plan
    from repro.specs.load import find_spec

    spec = find_spec("marionette/table1")

    def train_keys(scale):
        plan = build_plan(spec, scale, "bandai2-mini")
        return sorted(j.key() for r in plan.rows for jobs in r.train.values() for j in jobs)

    cpu = train_keys(resolve_scale("quick"))
    assert cpu and cpu == train_keys(resolve_scale("quick", device="cpu"))
    cuda = train_keys(resolve_scale("quick", device="cuda"))
    assert len(cuda) == len(cpu) and not set(cuda) & set(cpu)


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


def _on_meta(gen, fit_items, sample):
    with MetaReadsAsZeros():
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


@pytest.mark.parametrize("method", ["odmo", "act_mocogan"])
def test_window_models_train_and_sample_on_the_networks_device(mini_clips, method):
    from repro.data.odmo_items import WindowSource
    from repro.models.base import generator_class

    cfg = {"odmo": {"reduction": "sum", "enc_hidden": 16, "enc_feature": 16, "embed": 32,
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
