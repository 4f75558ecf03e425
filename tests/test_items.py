"""Single-action items (repro.data.action_items): cutting, Marionette normalisation and its exact
inverse, data-driven in-place classes and trajectories, motion-graph next tags, keys."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from repro.data.action_items import ItemsConfig, condition_items
from repro.data.clipset import TEST, TRAIN, ClipSet
from repro.data.contexts import build_items, in_place_classes, next_tags
from repro.errors import ConfigError
from repro.motion.heading import body_heading
from repro.motion.motion import Motion
from repro.motion.rotations import axis_angle_to_matrix, matrix_to_quat, quat_to_matrix
from repro.motion.skeleton import Skeleton, forward_kinematics

NAMES = ("Hips", "Spine", "Head", "UpperLeg_L", "LowerLeg_L", "UpperLeg_R", "LowerLeg_R")
PARENTS = (-1, 0, 1, 0, 3, 0, 5)
OFFSETS = [[0, 0, 0], [0, 0.25, 0], [0, 0.35, 0], [0.1, -0.05, 0], [0, -0.45, 0],
           [-0.1, -0.05, 0], [0, -0.45, 0]]
CLASSES = ("walk", "wave", "turn")


def synthetic_clipset(n_per_class: int = 8, seed: int = 0, fps: float = 30.0,
                      min_len: int = 20, max_len: int = 44) -> ClipSet:
    """A small real-shaped ClipSet: a 7-joint body facing +Z at rest; ``walk`` moves along its
    heading at ~1 m/s with swinging legs, ``turn`` walks while turning 90°, ``wave`` stays in
    place swaying its spine.  Random start heading, position, length and phase per clip."""
    rng = np.random.default_rng(seed)
    skel = Skeleton(NAMES, PARENTS, np.array(OFFSETS))
    rots, roots, starts, lengths, labels, styles, split = [], [], [], [], [], [], []
    s = 0
    for lab, cls in enumerate(CLASSES):
        for i in range(n_per_class):
            T = int(rng.integers(min_len, max_len + 1))
            t = np.arange(T) / fps
            h0 = rng.uniform(-math.pi, math.pi)
            phase = rng.uniform(0, 2 * math.pi)
            speed = rng.uniform(0.8, 1.4)
            heading = h0 + (np.linspace(0, math.pi / 2, T) if cls == "turn" else 0.0 * t)
            rv = np.zeros((T, len(NAMES), 3))
            rv[:, 0, 1] = heading
            swing = 0.5 * np.sin(2 * math.pi * 1.5 * t + phase)
            if cls == "wave":
                rv[:, 1, 2] = 0.3 * np.sin(2 * math.pi * 1.0 * t + phase)
                rv[:, 2, 0] = 0.1 * np.sin(2 * math.pi * 2.0 * t)
                vel = np.zeros((T, 3))
            else:
                rv[:, 3, 0], rv[:, 5, 0] = swing, -swing
                rv[:, 4, 0], rv[:, 6, 0] = np.abs(swing), np.abs(swing)
                vel = speed * np.stack([np.sin(heading), np.zeros(T), np.cos(heading)], -1)
            root = np.array([rng.uniform(-3, 3), 0.9, rng.uniform(-3, 3)]) + np.cumsum(vel, 0) / fps
            root[:, 1] += 0.02 * np.sin(2 * math.pi * 3 * t)
            R = axis_angle_to_matrix(rv)
            rots.append(matrix_to_quat(R).astype(np.float32))
            roots.append(root.astype(np.float32))
            starts.append(s)
            lengths.append(T)
            s += T
            labels.append(lab)
            styles.append(i % 2)
            split.append(TEST if i % 4 == 3 else TRAIN)
    rot = np.concatenate(rots)
    root = np.concatenate(roots)
    joints = forward_kinematics(skel, quat_to_matrix(rot.astype(np.float64)),
                                root.astype(np.float64)).astype(np.float32)
    n = len(labels)
    return ClipSet(name="synthetic", skeleton=skel, fps=fps, rotations=rot, root=root,
                   joints=joints, starts=np.array(starts, np.int64),
                   lengths=np.array(lengths, np.int64), labels=np.array(labels, np.int64),
                   label_names=CLASSES, styles=np.array(styles, np.int64),
                   style_names=("a", "b"), clip_names=tuple(f"clip{i:03d}" for i in range(n)),
                   split=np.array(split, np.int8), fingerprint=f"synthetic-{seed}")


@pytest.fixture(scope="module")
def clips():
    return synthetic_clipset()


def test_cut_shapes_and_caps(clips):
    cfg = ItemsConfig(max_frames=25)
    items = build_items(clips, TRAIN, cfg)
    n_train = int((clips.split == TRAIN).sum())
    assert len(items) == n_train and items.n_skipped == 0
    assert items.initial.n_frames == 6
    lens = clips.lengths[clips.indices(split=TRAIN)] - 6
    assert items.lengths.tolist() == np.minimum(lens, 25).tolist()
    assert items.action.n_frames == 25 and items.trajectory.shape == (n_train, 25, 2)
    # frames past an item's length repeat its last valid frame
    i = int(torch.argmin(items.lengths))
    L = int(items.lengths[i])
    assert torch.equal(items.action.root[i, L:], items.action.root[i, L - 1:L].expand(25 - L, 3))
    # clips too short for K + min_frames are skipped and counted
    short = build_items(clips, None, ItemsConfig(min_frames=30))
    assert short.n_skipped == int((clips.lengths < 36).sum()) and len(short) + short.n_skipped == len(clips)


def test_normalisation_and_exact_inverse(clips):
    items = build_items(clips, None, ItemsConfig(max_frames=1000))
    # P_-1 (last initial frame) at the origin, facing +Z
    assert torch.allclose(items.initial.root[:, -1], torch.zeros(len(items), 3), atol=1e-5)
    h = body_heading(clips.skeleton, items.initial.rotmats()[:, -1].double())
    assert torch.allclose(h, torch.zeros_like(h), atol=1e-5)
    # to_world restores the clip's own frames exactly
    real = items.real()
    for k in (0, 5, len(items) - 1):
        c = int(items.clip_index[k])
        L = int(items.lengths[k])
        w = Motion.from_clipset(clips, [c], 6, L)
        assert torch.allclose(real.root[k, :L], w.root[0], atol=1e-5)
        assert torch.allclose(real.motion.rotmats()[k, :L], w.rotmats()[0], atol=1e-5)
        assert torch.allclose(real.joints()[k, :L],
                              torch.from_numpy(clips.clip_joints(c)[6:6 + L]), atol=1e-4)
    ini = items.initial_world()
    c = int(items.clip_index[3])
    assert torch.allclose(ini.root[3], torch.from_numpy(clips.clip_root(c)[:6]), atol=1e-5)


def test_xz_translation_keeps_height(clips):
    items = build_items(clips, TRAIN, ItemsConfig(translation="xz"))
    c = int(items.clip_index[0])
    assert abs(float(items.initial.root[0, -1, 1]) - float(clips.clip_root(c)[5, 1])) < 1e-5
    assert torch.allclose(items.initial.root[:, -1, [0, 2]], torch.zeros(len(items), 2), atol=1e-5)


def test_in_place_classes_and_trajectories(clips):
    assert in_place_classes(clips) == ("wave",)
    items = build_items(clips, TEST)
    wave = items.labels == 1
    assert torch.equal(items.in_place, wave)
    assert float(items.trajectory[wave].abs().max()) == 0.0
    mov = ~wave
    assert torch.equal(items.trajectory[mov], items.action.root[mov][..., [0, 2]])
    # the normalised walker moves forward (+Z) from the origin
    walk = items.labels == 0
    last = items.trajectory[walk, 5]
    assert bool((last[:, 1] > 0.05).all()) and bool((last[:, 0].abs() < 0.05).all())
    # explicit list wins; unknown names are a ConfigError
    assert in_place_classes(clips, ItemsConfig(in_place_classes=("turn",))) == ("turn",)
    with pytest.raises(ConfigError, match="jump"):
        in_place_classes(clips, ItemsConfig(in_place_classes=("jump",)))
    with pytest.raises(ConfigError, match="max_frame"):
        build_items(clips, TRAIN, {"max_frame": 10})
    with pytest.raises(ConfigError, match="n_init"):
        build_items(clips, TRAIN, {"n_init": 0})
    # the threshold is what decides
    assert in_place_classes(clips, ItemsConfig(in_place_threshold_m=0.0)) == ()
    assert in_place_classes(clips, ItemsConfig(in_place_threshold_m=100.0)) == CLASSES


def test_next_tags_brute_force(clips):
    items = build_items(clips, None)
    idx = items.clip_index.numpy()
    ends = 6 + items.lengths.numpy() - 1
    labels, succ = next_tags(clips, idx, ends)
    assert np.array_equal(labels, items.next_labels.numpy())
    assert not np.any(succ == idx)
    assert np.all(clips.split[succ] == TRAIN)

    def feat(row):
        q = torch.from_numpy(clips.rotations[row]).double()
        h = float(body_heading(clips.skeleton, quat_to_matrix(q)[None])[0])
        j = clips.joints[row].astype(np.float64) - clips.root[row].astype(np.float64)
        c, s = math.cos(-h), math.sin(-h)
        R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        return (j @ R.T).ravel()

    pool = clips.indices(split=TRAIN)
    cand = np.stack([feat(clips.starts[p]) for p in pool])
    for k in (0, 7, 19):
        q = feat(clips.starts[idx[k]] + ends[k])
        d = np.linalg.norm(cand - q, axis=1)
        d[pool == idx[k]] = np.inf
        assert succ[k] == pool[int(np.argmin(d))]


def test_keys_subset_and_determinism(clips):
    a = build_items(clips, TRAIN)
    b = build_items(clips, TRAIN)
    assert a.key() == b.key()
    assert torch.equal(a.action.rot6d, b.action.rot6d) and torch.equal(a.next_labels, b.next_labels)
    assert build_items(clips, TRAIN, ItemsConfig(max_frames=20)).key() != a.key()
    assert build_items(clips, TEST).key() != a.key()
    sub = a.subset([2, 0])
    assert sub.action.n_frames == int(a.lengths[[2, 0]].max())
    assert torch.equal(sub.labels, a.labels[[2, 0]])
    assert torch.equal(sub.action.root[1], a.action.root[0, :sub.action.n_frames])


def test_condition_items_match_build(clips):
    items = build_items(clips, TEST)
    ini = items.initial_world()
    cond = condition_items(ini, items.labels, items.next_labels, items.lengths, items.label_names,
                           trajectory=items.trajectory)
    assert torch.allclose(cond.initial.root, items.initial.root, atol=1e-5)
    assert torch.allclose(cond.initial.rot6d, items.initial.rot6d, atol=1e-5)
    assert torch.allclose(cond.canon.origin, items.canon.origin, atol=1e-5)
    with pytest.raises(ValueError, match="trajectory"):
        condition_items(ini, items.labels, items.next_labels, items.lengths, items.label_names,
                        trajectory=torch.zeros(len(items), 3, 2))


def test_bundled_mini_items():
    """On the bundled real-mocap subset: waves and raises are in place, walkers and runners
    move forward (+Z) from the origin in their normalised frame."""
    from repro.errors import MissingDataError

    registry = pytest.importorskip("repro.data.registry")
    try:
        mini = registry.load_clipset("bandai2-mini")
    except MissingDataError as e:
        pytest.skip(str(e))
    items = build_items(mini, TRAIN)
    assert set(items.in_place_classes) == {n for n in mini.label_names
                                           if n.startswith(("wave", "raise"))}
    assert int(items.lengths.max()) == 120 and items.initial.n_frames == 6
    for name in ("walk", "run"):
        sel = items.labels == mini.label_names.index(name)
        end = items.trajectory[sel, 29]                     # one second into the action
        assert float(end[:, 1].median()) > 0.5 and float(end[:, 0].abs().median()) < 0.3
    assert torch.equal(items.next_labels, build_items(mini, TRAIN).next_labels)
