"""The harness reference method ``nearest_clip`` (repro.models.nearest_clip) on bandai2-mini:
retrieval of the same-tag training action with the nearest initial motion, cut or padded to
the duration, world frame, deterministic, save/load."""

from __future__ import annotations

import pytest
import torch

from repro.errors import ConfigError, DataError
from repro.models.base import Generator, generator_class


@pytest.fixture(scope="module")
def data():
    from repro.data.registry import load_clipset
    from repro.eval.protocols import get_protocol

    torch.set_num_threads(1)
    clips = load_clipset("bandai2-mini")
    proto = get_protocol("single_action", {})
    sc = proto.split_clipset(clips)
    return sc, proto.train_items(clips), proto.test_items(clips)


@pytest.fixture(scope="module")
def fitted(data):
    sc, train, _ = data
    gen = generator_class("nearest_clip")(None, sc.skeleton, sc.n_classes, sc.fps)
    result = gen.fit(train, seed=0)
    assert result.epochs == 0
    return gen


def test_registered_and_labelled_as_a_harness_reference(fitted):
    from repro.specs.names import METHODS

    assert generator_class("nearest_clip") is type(fitted)
    assert fitted.uses == {"label", "initial_motion", "length"}
    assert "not a paper method" in fitted.describe()["note"]
    assert METHODS["nearest_clip"].defined_by == "harness"


def test_training_conditions_retrieve_themselves(data, fitted):
    _, train, _ = data
    pick = fitted.retrieve(train, seed=0)
    assert torch.equal(pick, torch.arange(len(train)))
    out = fitted.sample(train, seed=0)
    assert torch.equal(out.lengths, train.lengths) and torch.equal(out.labels, train.labels)
    torch.testing.assert_close(out.joints(), train.real().joints(), atol=1e-5, rtol=0)


def test_test_conditions_get_the_nearest_same_tag_training_action(data, fitted):
    _, train, test = data
    pick = fitted.retrieve(test, seed=0)
    assert torch.equal(train.labels[pick], test.labels)
    q = test.initial.joints().double().flatten(1)
    bank = train.initial.joints().double().flatten(1)
    for i in range(len(test)):
        same = torch.nonzero(train.labels == test.labels[i]).reshape(-1)
        d = torch.linalg.norm(bank[same] - q[i], dim=1)
        assert torch.isclose(torch.linalg.norm(bank[pick[i]] - q[i]), d.min())
    # the retrieved action continues from the condition's last initial pose (world frame)
    out = fitted.sample(test, seed=0)
    start_gap = (out.root[:, 0] - test.initial_world().root[:, -1]).norm(dim=-1)
    src_gap = train.action.root[pick, 0].norm(dim=-1)  # first action frame to P_-1, normalised
    torch.testing.assert_close(start_gap, src_gap, atol=1e-4, rtol=0)


def test_cut_or_padded_to_the_requested_duration(data, fitted):
    from repro.data.action_items import condition_items

    _, train, _ = data
    sub = train.subset([0, 1])
    src = sub.lengths
    want = torch.tensor([int(src[0]) + 9, max(1, int(src[1]) - 5)])
    cond = condition_items(sub.initial_world(), sub.labels, sub.next_labels, want, sub.label_names)
    out = fitted.sample(cond, seed=0)
    assert torch.equal(out.lengths, want)
    real = sub.real().joints()
    j = out.joints()
    n0 = int(src[0])
    torch.testing.assert_close(j[0, :n0], real[0, :n0], atol=1e-5, rtol=0)
    for t in range(n0, int(want[0])):  # padding repeats the last frame
        torch.testing.assert_close(j[0, t], real[0, n0 - 1], atol=1e-5, rtol=0)
    n1 = int(want[1])
    torch.testing.assert_close(j[1, :n1], real[1, :n1], atol=1e-5, rtol=0)


def test_deterministic_and_the_seed_only_breaks_exact_ties(data):
    sc, train, test = data
    doubled = train.subset(list(range(len(train))) * 2)  # every action indexed twice: all ties
    gen = generator_class("nearest_clip")(None, sc.skeleton, sc.n_classes, sc.fps)
    gen.fit(doubled, seed=0)
    n = len(train)
    a, b = gen.retrieve(test, seed=0), gen.retrieve(test, seed=0)
    assert torch.equal(a, b)
    picks = torch.stack([gen.retrieve(test, seed=s) for s in range(4)])
    assert torch.all(picks % n == picks[0] % n)  # always the same action (one of its twins)
    assert (picks >= n).any() and (picks < n).any()  # the seed picks between the twins
    x = gen.sample(test, seed=0).joints()
    y = gen.sample(test, seed=3).joints()
    assert torch.equal(x, y)  # twins are identical actions


def test_save_and_load_keep_the_index(tmp_path, data, fitted):
    _, _, test = data
    fitted.save(tmp_path / "g")
    back = Generator.load(tmp_path / "g")
    assert type(back) is type(fitted) and back.index.size == fitted.index.size
    assert torch.equal(back.sample(test, seed=0).joints(), fitted.sample(test, seed=0).joints())


def test_bad_use_is_a_clear_error(data):
    sc, train, test = data
    gen = generator_class("nearest_clip")(None, sc.skeleton, sc.n_classes, sc.fps)
    with pytest.raises(DataError, match="not fitted"):
        gen.sample(test, seed=0)
    only_walk = train.subset(torch.nonzero(train.labels == 0).reshape(-1))
    gen.fit(only_walk, seed=0)
    with pytest.raises(DataError, match="no training action of tag"):
        gen.sample(test, seed=0)
    with pytest.raises(ConfigError, match="match_frame.*not permitted"):
        generator_class("nearest_clip")({"match_frame": 2}, sc.skeleton, sc.n_classes, sc.fps)
    g2 = generator_class("nearest_clip")({"match_frames": 99}, sc.skeleton, sc.n_classes, sc.fps)
    with pytest.raises(ConfigError, match="exceeds"):
        g2.fit(train, seed=0)


def test_match_frames_limits_the_compared_frames(data):
    sc, train, test = data
    gen = generator_class("nearest_clip")({"match_frames": 1}, sc.skeleton, sc.n_classes, sc.fps)
    gen.fit(train, seed=0)
    pick = gen.retrieve(test, seed=0)
    q = test.initial.joints()[:, -1].double().flatten(1)
    bank = train.initial.joints()[:, -1].double().flatten(1)
    for i in range(0, len(test), 7):
        same = torch.nonzero(train.labels == test.labels[i]).reshape(-1)
        d = torch.linalg.norm(bank[same] - q[i], dim=1)
        assert torch.isclose(torch.linalg.norm(bank[pick[i]] - q[i]), d.min())
