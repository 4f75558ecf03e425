"""Evaluation classifiers on small synthetic motion (fast): they learn, they are identified by
their fingerprint, their input convention is what the papers describe, and they are cached."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from repro.data.clipset import ClipSet
from repro.keys import content_key
from repro.motion.skeleton import Skeleton

# A small body facing +Z (left = +X), metres.
NAMES = ("Hips", "Spine", "Head", "UpperLeg_L", "Foot_L", "UpperLeg_R", "Foot_R",
         "UpperArm_L", "Hand_L", "UpperArm_R", "Hand_R")
PARENTS = (-1, 0, 1, 0, 3, 0, 5, 1, 7, 1, 9)
REST = np.array([
    [0, 0.9, 0], [0, 1.3, 0], [0, 1.6, 0], [0.1, 0.85, 0], [0.1, 0.05, 0], [-0.1, 0.85, 0],
    [-0.1, 0.05, 0], [0.2, 1.4, 0], [0.25, 0.9, 0], [-0.2, 1.4, 0], [-0.25, 0.9, 0]])
CLASSES = ("walk", "wave", "raise")


def _skeleton() -> Skeleton:
    offsets = REST - np.where(np.array(PARENTS)[:, None] >= 0, REST[np.maximum(PARENTS, 0)], 0)
    offsets[0] = 0
    return Skeleton(NAMES, PARENTS, offsets)


def _clip(label: int, t: int, rng: np.random.Generator, yaw: float) -> np.ndarray:
    """(t, J, 3) joints of one synthetic clip of class ``label`` facing ``yaw``."""
    tt = np.arange(t) / 30.0
    body = np.repeat(REST[None], t, axis=0).copy()
    amp = rng.uniform(0.7, 1.3)
    ph = rng.uniform(0, 2 * np.pi)
    root = np.zeros((t, 3))
    if label == 0:  # walk: forward along the facing direction, legs swing
        speed = rng.uniform(1.0, 1.4)
        root[:, 2] = speed * tt
        swing = 0.3 * amp * np.sin(2 * np.pi * 1.8 * tt + ph)
        body[:, 4, 2] += swing
        body[:, 6, 2] -= swing
        body[:, 8, 2] -= 0.5 * swing
        body[:, 10, 2] += 0.5 * swing
    elif label == 1:  # wave the left hand above the head
        body[:, 8] = [0.3, 1.8, 0.05]
        body[:, 8, 0] += 0.15 * amp * np.sin(2 * np.pi * 1.5 * tt + ph)
    else:  # raise both hands slowly
        up = np.clip(tt / (tt[-1] + 1e-9), 0, 1) * amp
        body[:, 8, 1] += 0.9 * up
        body[:, 10, 1] += 0.9 * up
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])  # about +Y
    world = (body - REST[0]) @ rot.T + (root @ rot.T)[:, None, :] + REST[0]
    world = world + rng.normal(0, 0.005, size=world.shape)
    start = np.array([rng.uniform(-2, 2), 0, rng.uniform(-2, 2)])
    return (world + start).astype(np.float32)


def synthetic_clipset(n_per_class: int = 16, n_classes: int = 2, seed: int = 0,
                      yaws: tuple[float, ...] | None = None, lengths=(25, 80),
                      name: str = "synthetic") -> ClipSet:
    """A deterministic labelled ClipSet; class c faces ``yaws[c]`` (default +Z for all)."""
    rng = np.random.default_rng(seed)
    yaws = yaws or (0.0,) * n_classes
    clips, labels, split = [], [], []
    for c in range(n_classes):
        for i in range(n_per_class):
            t = int(rng.integers(lengths[0], lengths[1] + 1))
            clips.append(_clip(c, t, rng, yaws[c]))
            labels.append(c)
            split.append(1 if i % 4 == 3 else 0)
    lens = np.array([len(c) for c in clips], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(lens)[:-1]]).astype(np.int64)
    joints = np.concatenate(clips)
    f, j = joints.shape[:2]
    rot = np.zeros((f, j, 4), np.float32)
    rot[..., 3] = 1
    return ClipSet(
        name=name, skeleton=_skeleton(), fps=30.0, rotations=rot, root=joints[:, 0].copy(),
        joints=joints, starts=starts, lengths=lens, labels=np.array(labels, np.int64),
        label_names=CLASSES[:n_classes], styles=np.full(len(lens), -1, np.int64), style_names=(),
        clip_names=tuple(f"clip{i:03d}" for i in range(len(lens))),
        split=np.array(split, np.int8),
        fingerprint=content_key({"synthetic": seed, "n": n_per_class, "c": n_classes,
                                 "yaws": list(yaws), "lengths": list(lengths)}))


def tiny_settings(**over):
    """Settings small enough for a few seconds of CPU training."""
    from repro.eval.settings import resolve_settings

    base = {"window": 24,
            "transformer": {"d_model": 32, "heads": 2, "layers": 1, "ff": 64, "dropout": 0.0},
            "train": {"epochs": 12, "windows_per_epoch": 128, "batch_size": 64, "lr": 3e-3,
                      "checkpoint_every": 4},
            "real": {"per_class": 12, "replicates": 3, "max_fid": 5.0}}
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(base.get(k), dict):
            base[k] = {**base[k], **v}
        else:
            base[k] = v
    return resolve_settings("quick", base)


@pytest.fixture(scope="module")
def two_class():
    return synthetic_clipset(n_per_class=16, n_classes=2, seed=1)


@pytest.fixture(scope="module")
def trained_gru(two_class):
    from repro.eval.training import test_accuracy, train_evaluator

    torch.set_num_threads(1)
    ev = train_evaluator(two_class, "a2m_gru", tiny_settings(), seed=0)
    ev.meta["test"] = test_accuracy(ev, two_class).to_dict()
    return ev


# --- learning -------------------------------------------------------------------------------

def test_gru_separates_two_synthetic_classes(trained_gru, two_class):
    from repro.eval.training import test_accuracy

    acc = test_accuracy(trained_gru, two_class)
    assert acc.top1 >= 0.95, acc
    assert acc.confusion.sum() == acc.n_windows and acc.confusion.shape == (2, 2)
    assert acc.top5 == 1.0 and acc.top5_k == 2  # k is capped at the number of classes
    loss = trained_gru.meta["training"]["loss_curve"]
    assert loss[-1] < 0.5 * loss[0]


def test_transformer_separates_two_synthetic_classes(two_class):
    from repro.eval.training import test_accuracy, train_evaluator

    ev = train_evaluator(two_class, "transformer", tiny_settings(), seed=0)
    assert test_accuracy(ev, two_class).top1 >= 0.9
    f = ev.features(two_class.clip_joints(0)[None, :20], seed=None)
    assert f.shape == (1, 30) and np.all(np.abs(f) <= 1)  # tanh feature layer


def test_architectures_follow_the_papers():
    from repro.eval.classifiers import GRURecogniser, build_module

    s = tiny_settings()
    a2m = build_module("a2m_gru", 63, 12, s)
    uestc = build_module("uestc_gru", 54, 40, s)
    assert isinstance(a2m, GRURecogniser)
    assert (a2m.gru.num_layers, a2m.gru.hidden_size) == (2, 128)  # ODMO supp. Table S3
    assert (uestc.gru.num_layers, uestc.gru.hidden_size) == (3, 256)  # ODMO supp. Table S4
    assert a2m.feature.out_features == 30 and a2m.classify.in_features == 30
    x = torch.randn(3, 60, 63)
    feat, logits = a2m(x)
    assert feat.shape == (3, 30) and logits.shape == (3, 12)
    # the logits are a linear function of the tanh features
    assert torch.allclose(logits, a2m.classify(feat), atol=1e-6)


# --- determinism and the random initial state ------------------------------------------------

def test_default_evaluator_is_deterministic(trained_gru, two_class):
    x = np.stack([two_class.clip_joints(i)[:24] for i in range(4)])
    x = np.concatenate([x, x[:1]])  # sample 0 twice
    f1, f2 = trained_gru.features(x), trained_gru.features(x)
    assert np.array_equal(f1, f2)
    assert np.array_equal(f1[0], f1[4])
    assert np.array_equal(trained_gru.features(x, seed=1), f1)  # the seed is ignored
    assert trained_gru.random_hidden is False


def test_random_hidden_state_gives_noisy_features(two_class):
    from repro.eval.training import train_evaluator

    ev = train_evaluator(two_class, "a2m_gru", tiny_settings(hidden_init="random",
                                                            train={"epochs": 2}), seed=0)
    x = np.stack([two_class.clip_joints(0)[:24]] * 2)  # identical inputs
    f = ev.features(x, seed=0)
    assert not np.allclose(f[0], f[1])  # protocols.md §1.5: noise even for identical inputs
    assert np.array_equal(ev.features(x, seed=0), f)  # but seeded, so reproducible
    assert not np.allclose(ev.features(x, seed=1), f)
    # features and logits use independent noise (the reference's two network instances)
    h_feat = ev.module.initial_state(2, __import__("repro.seeding").seeding.torch_generator(
        0, "evaluator-h0", "features"))
    assert h_feat.shape == (2, 2, 128)


def test_training_is_reproducible(two_class):
    from repro.eval.training import train_evaluator

    s = tiny_settings(train={"epochs": 2})
    a = train_evaluator(two_class, "a2m_gru", s, seed=3)
    b = train_evaluator(two_class, "a2m_gru", s, seed=3)
    c = train_evaluator(two_class, "a2m_gru", s, seed=4)
    assert a.weights_sha256 == b.weights_sha256 and a.fingerprint == b.fingerprint
    assert c.weights_sha256 != a.weights_sha256


# --- fingerprint ---------------------------------------------------------------------------

def test_fingerprint_changes_with_arch_heading_data_and_weights(trained_gru):
    from repro.eval.evaluator import fingerprint_of, input_representation
    from repro.eval.settings import architecture

    s = trained_gru.settings
    base = dict(kind="a2m_gru", architecture=architecture("a2m_gru", s),
                joint_names=trained_gru.joint_names, label_names=trained_gru.label_names,
                input_rep=input_representation(s, None), data_fingerprint="d" * 64,
                weights_sha="w" * 64)
    fp = fingerprint_of(**base)
    assert fp == fingerprint_of(**base)
    changed = [
        dict(kind="uestc_gru", architecture=architecture("uestc_gru", s)),
        dict(architecture=architecture("a2m_gru", s.model_copy(update={"hidden_init": "random"}))),
        dict(input_rep=input_representation(s.model_copy(update={"heading": "yaw_augment"}), None)),
        dict(input_rep=input_representation(s.model_copy(update={"heading": "remove"}),
                                            ["UpperLeg_L", "UpperLeg_R"])),
        dict(input_rep=input_representation(s.model_copy(update={"window": 60}), None)),
        dict(joint_names=trained_gru.joint_names[:-1]),
        dict(data_fingerprint="e" * 64),
        dict(weights_sha="v" * 64),
    ]
    fps = {fingerprint_of(**{**base, **c}) for c in changed}
    assert len(fps) == len(changed) and fp not in fps
    assert trained_gru.fingerprint[:12] in trained_gru.describe()


def test_trained_fingerprint_tracks_heading_and_data(two_class):
    from repro.eval.training import train_evaluator

    s = tiny_settings(train={"epochs": 1})
    raw = train_evaluator(two_class, "a2m_gru", s, seed=0)
    aug = train_evaluator(two_class, "a2m_gru", s.model_copy(update={"heading": "yaw_augment"}), seed=0)
    other = train_evaluator(synthetic_clipset(n_per_class=16, n_classes=2, seed=2), "a2m_gru", s, seed=0)
    assert len({raw.fingerprint, aug.fingerprint, other.fingerprint}) == 3


# --- input convention ------------------------------------------------------------------------

def test_input_convention_first_frame_root_at_origin_and_padding():
    from repro.eval.features import to_model_input

    rng = np.random.default_rng(0)
    j = rng.normal(size=(2, 5, 3, 3))
    x = to_model_input(j, np.array([5, 3]))
    assert x.shape == (2, 5, 9) and x.dtype == np.float32
    np.testing.assert_allclose(x[:, 0, :3], 0, atol=1e-7)  # root of frame 0 at the origin
    np.testing.assert_allclose(x[0], (j[0] - j[0, 0, 0]).reshape(5, 9), atol=1e-6)  # absolute
    np.testing.assert_allclose(x[1, 3], x[1, 2])  # repeat-last padding
    np.testing.assert_allclose(x[1, 4], x[1, 2])


def test_heading_removal_makes_features_rotation_invariant():
    from repro.eval.features import facing_joint_indices, to_model_input

    cs = synthetic_clipset(n_per_class=2, n_classes=1, seed=0)
    facing = facing_joint_indices(cs.skeleton)
    assert [cs.skeleton.names[i] for i in facing] == ["UpperLeg_L", "UpperLeg_R"]
    a = cs.clip_joints(0)[None, :20].astype(np.float64)
    c, s = np.cos(1.1), np.sin(1.1)
    rot = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    b = a @ rot.T + np.array([3.0, 0.2, -1.0])  # the same motion turned and moved
    raw_a, raw_b = to_model_input(a), to_model_input(b)
    assert np.abs(raw_a - raw_b).max() > 0.1  # raw keeps heading
    np.testing.assert_allclose(to_model_input(a, heading="remove", facing=facing),
                               to_model_input(b, heading="remove", facing=facing), atol=1e-5)


def test_bad_input_is_a_clear_error(trained_gru):
    from repro.errors import DataError

    with pytest.raises(DataError, match=r"\(N, T, 11, 3\)"):
        trained_gru.features(np.zeros((2, 24, 10, 3)))
    with pytest.raises(DataError, match="NaN"):
        trained_gru.features(np.full((1, 24, 11, 3), np.nan))
    with pytest.raises(DataError, match="lengths"):
        trained_gru.features(np.zeros((1, 24, 11, 3)), lengths=[30])


def test_settings_refuse_unknown_keys_and_values():
    from repro.errors import ConfigError, SpecError
    from repro.eval.settings import resolve_settings

    with pytest.raises(SpecError, match="hiden_init"):
        resolve_settings("quick", {"hiden_init": "zero"})
    with pytest.raises(SpecError, match="heading"):
        resolve_settings("quick", {"heading": "north"})
    with pytest.raises(ConfigError, match="unknown scale"):
        resolve_settings("huge")
    s = resolve_settings("paper")
    assert (s.train.lr, s.train.windows_per_epoch, s.train.epochs) == (1e-3, 2048, 15000)
    assert s.heading == "raw" and s.hidden_init == "zero" and s.window == 60


# --- store --------------------------------------------------------------------------------------

def test_get_evaluator_trains_once_then_loads_from_the_store(two_class):
    from repro.eval import provider

    s = tiny_settings(train={"epochs": 2})
    provider._LOADED.clear()
    a = provider.get_evaluator("synthetic", "a2m_gru", "quick", clipset=two_class, settings=s)
    assert a.meta["store_hit"] is False and a.path is not None
    provider._LOADED.clear()
    b = provider.get_evaluator("synthetic", "a2m_gru", "quick", clipset=two_class, settings=s)
    assert b.meta["store_hit"] is True
    assert b.fingerprint == a.fingerprint and b.weights_sha256 == a.weights_sha256
    x = np.stack([two_class.clip_joints(i)[:24] for i in range(3)])
    assert np.array_equal(a.features(x), b.features(x))
    assert b.meta["test"]["top1"] == a.meta["test"]["top1"]
    provider._LOADED.clear()
    c = provider.get_evaluator("synthetic", "a2m_gru", "quick", clipset=two_class, settings=s, seed=1)
    assert c.meta["store_hit"] is False and c.fingerprint != a.fingerprint


def test_get_evaluator_heading_override_is_a_different_evaluator(two_class):
    from repro.eval import provider

    s = tiny_settings(train={"epochs": 1})
    provider._LOADED.clear()
    raw = provider.get_evaluator("synthetic", "a2m_gru", "quick", clipset=two_class, settings=s)
    rem = provider.get_evaluator("synthetic", "a2m_gru", "quick", clipset=two_class, settings=s,
                                 heading="remove")
    assert rem.settings.heading == "remove" and rem.fingerprint != raw.fingerprint
    assert rem.meta["input"]["facing_joints"] == ["UpperLeg_L", "UpperLeg_R"]
    provider._LOADED.clear()


def test_interrupted_training_resumes_exactly(two_class):
    from repro.eval import provider
    from repro.eval.training import train_evaluator

    s = tiny_settings(train={"epochs": 4, "checkpoint_every": 1})
    straight = train_evaluator(two_class, "a2m_gru", s, seed=7)

    class Stop(Exception):
        pass

    def stop_in_epoch_1(epoch, rec):
        if epoch == 1:
            raise Stop

    provider._LOADED.clear()
    with pytest.raises(Stop):
        provider.get_evaluator("synthetic", "a2m_gru", "quick", seed=7, clipset=two_class,
                               settings=s, on_epoch=stop_in_epoch_1)
    resumed = provider.get_evaluator("synthetic", "a2m_gru", "quick", seed=7, clipset=two_class,
                                     settings=s)
    assert resumed.meta["training"]["resumed_from"] == 1  # epoch 0 was checkpointed
    assert resumed.weights_sha256 == straight.weights_sha256
    assert resumed.fingerprint == straight.fingerprint
    provider._LOADED.clear()


def test_min_window_trains_on_short_windows_and_only_when_asked(two_class, monkeypatch):
    """Issue 26: with ``min_window`` the recogniser's training windows keep valid lengths drawn
    in [min_window, window] (as short as the composed actions it scores); without it the
    training draw is the one it always was (other evaluators keep their weights)."""
    import repro.eval.training as training
    from repro.eval.training import train_evaluator

    seen = []
    real = training.to_model_input

    def spy(joints, lengths=None, **kw):
        seen.append(np.asarray(lengths).copy())
        return real(joints, lengths, **kw)

    monkeypatch.setattr(training, "to_model_input", spy)
    s = tiny_settings(train={"epochs": 2, "windows_per_epoch": 256})
    train_evaluator(two_class, "a2m_gru", s, seed=0)
    plain = np.concatenate(seen)
    seen.clear()
    short = train_evaluator(two_class, "a2m_gru", s.model_copy(update={"min_window": 8}), seed=0)
    lens = np.concatenate(seen)
    assert plain.max() == 24 and (plain == 24).mean() > 0.5
    assert lens.min() >= 8 and lens.max() <= 24 and (lens < 20).mean() > 0.3
    assert short.fingerprint != train_evaluator(two_class, "a2m_gru", s, seed=0).fingerprint
