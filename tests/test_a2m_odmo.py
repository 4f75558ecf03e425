"""Action2Motion as ODMO's baselines (repro.models.a2m, "ODMO's baselines"): A2M-xyz (joint
positions, MSE on positions, no FK) and A2M-Lie (``lie`` from the rest pose), trained on ODMO's
fixed windows (``WindowItems.as_action_items``, one initial frame); ``sample_joints`` in the
world frame for every representation.  Tiny widths, one torch thread, bandai2-mini windows."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

import repro.models.a2m as a2m_module
from repro.data.odmo_items import WindowSource, label_condition_items
from repro.errors import ConfigError
from repro.models.a2m import A2M
from repro.models.base import Generator
from repro.models.baseline_io import pack_poses, pose_joints
from repro.motion.rotations import sixd_to_matrix
from model_fixtures import mini_clips, one_torch_thread  # noqa: F401 (fixtures)

TINY = {"dim_z": 8, "hidden": 32, "batch_size": 32, "epochs": 2, "lr": 3e-3,
        "sample_batch_size": 16}


@pytest.fixture(scope="module")
def windows(mini_clips):
    return WindowSource(window=20).train_items(mini_clips)


@pytest.fixture(scope="module")
def items(windows):
    """Every 7th fixed window (120 items of 20 frames, all 10 classes)."""
    ai = windows.as_action_items()
    return ai.subset(torch.arange(0, len(ai), 7))


@pytest.fixture(scope="module")
def cond(windows):
    """Condition items: 12 other windows (non-trivial canon: the window's first-frame root)."""
    ai = windows.as_action_items()
    return ai.subset(torch.arange(3, len(ai), 70))


def make(windows, **over):
    return A2M({**TINY, **over}, windows.skeleton, windows.n_classes, windows.fps)


@pytest.fixture(scope="module")
def trained(windows, items):
    out = {}
    for name, over in {"xyz": {"representation": "xyz", "initial_pose": False},
                       "lie": {"representation": "lie", "initial_pose": False},
                       "6d": {"epochs": 1}}.items():
        m = make(windows, **over)
        out[name] = (m, m.fit(items, seed=3))
    return out


# -- the window items ---------------------------------------------------------------------------


def test_window_action_items_have_one_initial_frame(items, windows):
    assert items.n_init == 1 and items.initial.n_frames == 1 and items.action.n_frames == 20
    assert items.n_classes == windows.n_classes == 10
    joints = items.action.joints()
    assert torch.allclose(joints[:, 0, 0], torch.zeros(len(items), 3), atol=1e-6)
    assert torch.equal(items.canon.rotation, torch.eye(3).expand(len(items), 3, 3))


# -- A2M-xyz ------------------------------------------------------------------------------------


def test_xyz_widths_targets_and_start(windows, items):
    J = windows.n_joints
    m = make(windows, representation="xyz", initial_pose=False)
    net = m.network
    assert m.n_params == 3 * J and net.decoder.out.out_features == 3 * J
    assert not net.decoder.lie and not hasattr(net.decoder, "out_lie")   # linear head
    assert net.posterior.embed.in_features == 3 * J + 10 + 1
    assert net.decoder.embed.in_features == 3 * J + 11 + 8
    assert m.uses == frozenset({"label", "length"})
    data = m._tensors(items)
    fk = pose_joints(windows.skeleton, pack_poses(items.action))
    assert torch.equal(data["params"], fk.reshape(len(items), 20, 3 * J))
    assert torch.equal(data["start"], torch.zeros(len(items), 3 * J))     # A2M's zero x_0
    withinit = make(windows, representation="xyz", initial_pose=True)
    assert "initial_motion" in withinit.uses
    start = withinit.start_params(items).reshape(len(items), J, 3)
    assert torch.allclose(start, fk[:, 0], atol=1e-6)                     # = the window's 1st frame
    assert torch.allclose(start[:, 0], torch.zeros(len(items), 3), atol=1e-6)


def test_xyz_loss_is_mse_on_positions_without_fk(windows, items, monkeypatch):
    """The reconstruction term is the MSE on the parameters themselves (the ``param`` term,
    computed on the raw parameters, equals it) and forward kinematics is never called."""
    m = make(windows, representation="xyz", initial_pose=False, lambda_param=1.0)
    batch = m._crop(m._tensors(items), torch.arange(16))

    def no_fk(*a, **k):
        raise AssertionError("xyz training must not run forward kinematics")

    monkeypatch.setattr(a2m_module, "pose_joints", no_fk)
    torch.manual_seed(0)
    out = m.training_step(m.network, batch, 0)
    assert torch.allclose(out["rec"], out["param"], rtol=1e-6)
    assert math.isfinite(float(out["loss"].detach())) and out["loss"].requires_grad


def test_xyz_training_lowers_the_loss(trained):
    _, result = trained["xyz"]
    losses = [h["loss"] for h in result.history]
    assert len(losses) == 2 and all(math.isfinite(v) for v in losses)
    assert losses[1] < losses[0]
    assert result.history[1]["rec"] < result.history[0]["rec"]


def test_xyz_sample_joints_shapes_and_determinism(trained, cond, windows):
    m, _ = trained["xyz"]
    a = m.sample_joints(cond, seed=7)
    assert a.shape == (len(cond), 20, windows.n_joints, 3) and a.dtype == torch.float32
    assert torch.isfinite(a).all()
    assert torch.equal(a, m.sample_joints(cond, seed=7))
    assert not torch.equal(a, m.sample_joints(cond, seed=8))
    assert torch.equal(m.sample_joints(cond, seed=7, use_mean=True),
                       m.sample_joints(cond, seed=8, use_mean=True))
    one = make(windows, representation="xyz", initial_pose=False, sample_batch_size=1)
    one.network.load_state_dict(m.network.state_dict())
    assert torch.allclose(one.sample_joints(cond, seed=7), a, atol=1e-5)


def test_xyz_sample_joints_are_in_the_world_frame(trained, cond, windows, items):
    """Items frame → world by the items' canon: the window's first-frame root comes back; a
    rotated canon rotates the samples (Gᵀ·p + o)."""
    m, _ = trained["xyz"]
    local = m.to_joints(m.generate_params(cond, seed=2))
    world = m.sample_joints(cond, seed=2)
    assert torch.allclose(world, local + cond.canon.origin[:, None, None], atol=1e-6)
    assert not torch.allclose(world, local, atol=1e-3)
    c = math.cos(0.7), math.sin(0.7)
    G = torch.tensor([[c[0], 0.0, c[1]], [0.0, 1.0, 0.0], [-c[1], 0.0, c[0]]])
    rotated = dataclasses.replace(cond, canon=dataclasses.replace(
        cond.canon, rotation=G.expand(len(cond), 3, 3).clone()))
    want = torch.einsum("ji,ntkj->ntki", G, local) + cond.canon.origin[:, None, None]
    assert torch.allclose(m.sample_joints(rotated, seed=2), want, atol=1e-5)
    # ODMO's label-only condition items (identity canon): samples stay in the window frame
    lab = label_condition_items(windows.label_names, [0, 3, 9], 20, windows.skeleton,
                                windows.fps, items.initial.select([0]))
    assert torch.equal(m.sample_joints(lab, seed=4), m.to_joints(m.generate_params(lab, seed=4)))


def test_xyz_sample_raises(trained, cond):
    m, _ = trained["xyz"]
    with pytest.raises(ConfigError, match="sample_joints"):
        m.sample(cond, seed=0)
    with pytest.raises(ConfigError, match="sample_joints"):
        m.generate_poses(cond, seed=0)
    with pytest.raises(ConfigError, match="representation"):
        A2M({"representation": "quat"}, cond.skeleton, cond.n_classes, cond.fps)


def test_xyz_save_load_round_trip(trained, cond, tmp_path):
    m, _ = trained["xyz"]
    a = m.sample_joints(cond, seed=5)
    m.save(tmp_path / "a2m_xyz")
    back = Generator.load(tmp_path / "a2m_xyz")
    assert type(back) is A2M and back.config == m.config and back.config.representation == "xyz"
    assert torch.equal(back.sample_joints(cond, seed=5), a)
    for (k, v), (k2, v2) in zip(m.network.state_dict().items(), back.network.state_dict().items()):
        assert k == k2 and torch.equal(v, v2), k


# -- sample_joints of the rotation paths ----------------------------------------------------------


@pytest.mark.parametrize("rep", ["6d", "lie"])
def test_sample_joints_equals_sample_joints_of_motion(trained, cond, windows, rep):
    m, _ = trained[rep]
    got = m.sample_joints(cond, seed=11)
    assert got.shape == (len(cond), 20, windows.n_joints, 3)
    assert torch.equal(got, m.sample(cond, seed=11).joints())
    assert torch.equal(m.sample_joints(cond, seed=11, use_mean=True),
                       m.sample(cond, seed=11, use_mean=True).joints())


# -- A2M-Lie: A2M's own setting (rest-pose start) ---------------------------------------------------


def test_lie_without_initial_pose_is_a2m_rest_pose_setting(trained, windows, items, cond):
    m, result = trained["lie"]
    J = windows.n_joints
    assert m.config.representation == "lie" and not m.config.initial_pose
    assert m.uses == frozenset({"label", "length"})
    start = m.start_params(items)
    assert start.shape == (len(items), 3 * J + 3)
    assert torch.allclose(start, torch.zeros_like(start), atol=1e-6)       # zero Lie vector
    rot = sixd_to_matrix(m.to_poses(start)[:, :-3].reshape(len(items), J, 6))
    assert torch.allclose(rot, torch.eye(3).expand(len(items), J, 3, 3), atol=1e-6)
    losses = [h["loss"] for h in result.history]
    assert all(math.isfinite(v) for v in losses) and losses[1] < losses[0]
    out = m.sample(cond, seed=1)
    assert torch.isfinite(out.motion.root).all() and out.motion.n_frames == 20
    # the one initial frame is never read
    init = cond.initial
    noisy = dataclasses.replace(cond, initial=init.replace(rot6d=init.rot6d + 0.3))
    assert torch.equal(m.sample_joints(noisy, seed=1), m.sample_joints(cond, seed=1))
