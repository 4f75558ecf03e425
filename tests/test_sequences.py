"""Composed multi-action sequences (repro.data.sequences) on the bundled bandai2-mini."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from cli.main import main
from repro.data.clipset import TEST, TRAIN
from repro.data.compose_walk import features
from repro.data.sequence_card import card_of
from repro.data.sequence_views import SEQUENCE_VIEWS, load_view
from repro.data.sequences import (CARD_SCHEMA, COMPOSE_VERSION, ROLE_ACTION, ROLE_LEAD_IN,
                                  ROLE_LEAD_OUT, ComposeConfig, compose_sequences, sequences_for)
from repro.errors import ConfigError, DataError
from repro.motion.rotations import quat_to_matrix
from repro.motion.skeleton import forward_kinematics

K = 6


@pytest.fixture(scope="module")
def mini(tmp_path_factory):
    from repro.data.registry import load_clipset
    from repro.data.splits import marionette_clipset

    with pytest.MonkeyPatch.context() as mp:  # decode the bundle into a private REPRO_HOME
        mp.setenv("REPRO_HOME", str(tmp_path_factory.mktemp("seq-home")))
        return marionette_clipset(load_clipset("bandai2-mini"))


@pytest.fixture(scope="module")
def seqs(mini):
    return sequences_for(mini)


def subset(clips, idx):
    """A ClipSet of the clips ``idx`` (same skeleton, labels and split)."""
    idx = np.asarray(idx)
    rows = np.concatenate([np.arange(clips.starts[i], clips.starts[i] + clips.lengths[i])
                           for i in idx])
    lens = clips.lengths[idx].astype(np.int64)
    return dataclasses.replace(
        clips, name="sub", rotations=np.asarray(clips.rotations[rows]),
        root=np.asarray(clips.root[rows]), joints=np.asarray(clips.joints[rows]),
        starts=np.concatenate([[0], np.cumsum(lens)[:-1]]).astype(np.int64), lengths=lens,
        labels=clips.labels[idx], styles=clips.styles[idx], split=clips.split[idx],
        clip_names=tuple(clips.clip_names[i] for i in idx),
        fingerprint=f"sub-{clips.fingerprint}-{idx.tolist()}")


def fk(skeleton, q, root):
    R = quat_to_matrix(torch.from_numpy(np.asarray(q, np.float64)))
    return forward_kinematics(skeleton, R, torch.from_numpy(np.asarray(root, np.float64))).numpy()


FRAME_FIELDS = ("rotations", "root", "joints", "frame_label")


def test_deterministic_and_seeded(mini, seqs):
    again = compose_sequences(mini)
    assert again is not seqs and again.fingerprint == seqs.fingerprint
    for k, v in {**seqs.index_arrays(), **{f: getattr(seqs, f) for f in FRAME_FIELDS}}.items():
        w = getattr(again, k)
        assert v.dtype == w.dtype and v.shape == w.shape and v.tobytes() == w.tobytes(), k
    other = compose_sequences(mini, {"seed": 1})
    assert other.fingerprint != seqs.fingerprint
    assert sequences_for(mini) is seqs  # the in-process cache
    assert sequences_for(mini, ComposeConfig()) is seqs


def test_shapes_and_dtypes(mini, seqs):
    F, J = seqs.n_frames, mini.skeleton.n_joints
    assert seqs.rotations.shape == (F, J, 4) and seqs.rotations.dtype == np.float32
    assert seqs.root.shape == (F, 3) and seqs.root.dtype == np.float32
    assert seqs.joints.shape == (F, J, 3) and seqs.joints.dtype == np.float32
    assert seqs.frame_label.dtype == np.int64 and seqs.seq_split.dtype == np.int8
    A = seqs.seg_seq.shape[0]
    for k in ("seg_seq", "seg_pos", "seg_start", "seg_length", "seg_label", "seg_clip",
              "seg_clip_start"):
        assert getattr(seqs, k).shape == (A,) and getattr(seqs, k).dtype == np.int64, k
    assert seqs.seg_yaw.shape == (A,) and seqs.seg_offset.shape == (A, 3)
    assert seqs.preference.shape == (mini.n_classes,) * 2
    assert seqs.label_names == mini.label_names and seqs.fps == mini.fps
    assert seqs.skeleton == mini.skeleton and seqs.n_classes == mini.n_classes
    assert len(seqs) == seqs.seq_starts.shape[0] > 0
    np.testing.assert_array_equal(seqs.seq_starts[1:], np.cumsum(seqs.seq_lengths)[:-1])
    assert int(seqs.seq_lengths.sum()) == F
    assert not seqs.rotations.flags.writeable
    np.testing.assert_allclose(np.linalg.norm(seqs.rotations, axis=-1), 1.0, atol=1e-5)
    np.testing.assert_allclose(seqs.joints, fk(mini.skeleton, seqs.rotations, seqs.root), atol=1e-5)


def test_split_by_source_clip_and_structure(mini, seqs):
    cfg = seqs.config
    # every segment (all roles) uses a clip of its sequence's split
    np.testing.assert_array_equal(mini.split[seqs.seg_clip], seqs.seq_split[seqs.seg_seq])
    train_clips = set(seqs.seg_clip[seqs.seq_split[seqs.seg_seq] == TRAIN].tolist())
    test_clips = set(seqs.seg_clip[seqs.seq_split[seqs.seg_seq] == TEST].tolist())
    assert not train_clips & test_clips
    # every clip exactly once as an ACTION, in a sequence of its own split
    act = seqs.segments()
    np.testing.assert_array_equal(np.bincount(seqs.seg_clip[act], minlength=len(mini)), 1)
    both = np.concatenate([seqs.segments(TRAIN), seqs.segments(TEST)])
    np.testing.assert_array_equal(np.sort(both), act)
    assert len(seqs.segments(TEST)) == int((mini.split == TEST).sum())
    # [lead-in, actions, lead-out], lead clips differ from their neighbour
    for s in range(len(seqs)):
        a = np.flatnonzero(seqs.seg_seq == s)
        roles = seqs.seg_role[a]
        np.testing.assert_array_equal(seqs.seg_pos[a], np.arange(a.size))
        assert roles[0] == ROLE_LEAD_IN and roles[-1] == ROLE_LEAD_OUT
        assert (roles[1:-1] == ROLE_ACTION).all() and 1 <= a.size - 2 <= cfg.max_actions
        assert seqs.seg_clip[a[0]] != seqs.seg_clip[a[1]]
        assert seqs.seg_clip[a[-1]] != seqs.seg_clip[a[-2]]
        starts = seqs.seg_start[a]
        np.testing.assert_array_equal(starts[1:], starts[:-1] + seqs.seg_length[a[:-1]]
                                      + cfg.blend_frames)
        assert starts[0] == 0 and starts[-1] + seqs.seg_length[a[-1]] == seqs.seq_lengths[s]
    n_act = np.bincount(seqs.seg_seq[act], minlength=len(seqs))
    # (deterministic for this data and seed) most sequences reach their drawn length
    assert (n_act >= cfg.min_actions).mean() > 0.5
    # whole actions: min..max_action_frames cut anywhere, room left for the exit transition
    L = mini.lengths[seqs.seg_clip[act]]
    first, length = seqs.seg_clip_start[act], seqs.seg_length[act]
    assert (first >= 0).all() and (length <= cfg.max_action_frames).all()
    assert (first + length + cfg.blend_frames + 1 <= L).all()
    assert (length >= np.minimum(cfg.min_action_frames, L - cfg.blend_frames - 1)).all()
    assert (first > 0).mean() > 0.5      # cuts inside clips, not only at their ends
    for role in (ROLE_LEAD_IN, ROLE_LEAD_OUT):
        r = seqs.segments(role=role)
        assert (seqs.seg_length[r] >= 1).all() and (seqs.seg_length[r] <= cfg.lead_frames).all()


def test_every_action_has_context_and_next_tag(seqs):
    act = seqs.segments()
    nxt = seqs.next_labels(act)
    assert (nxt >= 0).all()
    assert all(seqs.next_label(a) == n for a, n in zip(act.tolist(), nxt.tolist()))
    assert all(seqs.previous_label(a) >= 0 for a in act.tolist())
    np.testing.assert_array_equal(nxt, seqs.seg_label[act + 1])
    for a in act.tolist():
        r, root = seqs.context(a, K)
        assert r.shape == (K, seqs.skeleton.n_joints, 4) and root.shape == (K, 3)
        assert r.dtype == np.float32 and root.dtype == np.float32
    lead_in = seqs.segments(role=ROLE_LEAD_IN)
    lead_out = seqs.segments(role=ROLE_LEAD_OUT)
    assert seqs.previous_label(int(lead_in[0])) == -1
    assert (seqs.next_labels(lead_out) == -1).all()
    with pytest.raises(DataError, match="fewer than"):
        seqs.context(int(lead_in[0]), 1)
    a = int(act[0])
    with pytest.raises(DataError):
        seqs.context(a, int(seqs.seg_start[a]) + 1)


def test_segments_are_rigidly_placed_source_frames(mini, seqs):
    for a in range(seqs.seg_seq.shape[0]):
        rows = seqs.segment_rows(a)
        c, s0, n = int(seqs.seg_clip[a]), int(seqs.seg_clip_start[a]), int(seqs.seg_length[a])
        q, root = seqs.to_clip_frame(a, seqs.rotations[rows], seqs.root[rows])
        np.testing.assert_allclose(root, mini.clip_root(c)[s0:s0 + n], atol=1e-4)
        np.testing.assert_allclose(q, mini.clip_rotations(c)[s0:s0 + n], atol=1e-5)
        yaw, off = -seqs.seg_yaw[a], seqs.seg_offset[a]
        back = seqs.joints[rows].astype(np.float64) - off
        c_, s_ = np.cos(yaw), np.sin(yaw)
        x, z = back[..., 0].copy(), back[..., 2].copy()
        back[..., 0], back[..., 2] = c_ * x + s_ * z, -s_ * x + c_ * z
        np.testing.assert_allclose(back, mini.clip_joints(c)[s0:s0 + n], atol=1e-3)
        assert (seqs.frame_label[rows] == seqs.seg_label[a]).all()
        assert seqs.seg_offset[a, 1] == 0.0  # height is never changed


def _angle(q0, q1):
    return 2 * np.arccos(np.clip(np.abs((q0 * q1).sum(-1)), 0, 1))


def test_context_then_clip_is_continuous(mini, seqs):
    ft = features(mini, seqs.config.heading_axis)
    rng = np.random.default_rng(0)
    A, B = rng.integers(0, ft.p.shape[0], 400), rng.integers(0, ft.p.shape[0], 400)
    random_dist = np.median(np.linalg.norm(ft.p[A].astype(np.float64) - ft.p[B], axis=-1))
    jumps, inner = [], []
    for a in seqs.segments().tolist():
        rot, root = seqs.context(a, K)
        c, s0 = int(seqs.seg_clip[a]), int(seqs.seg_clip_start[a])
        q = np.concatenate([rot, mini.clip_rotations(c)[s0:s0 + 4]])
        r = np.concatenate([root, mini.clip_root(c)[s0:s0 + 4]])
        P = fk(mini.skeleton, q, r).reshape(len(q), -1)
        d = np.linalg.norm(P[1:] - P[:-1], axis=1)
        jumps.append(d[K - 1])
        inner.append(np.median(d[K:]))
    jumps = np.array(jumps)
    # the step into the action is like a step of recorded motion, far from a random pose jump
    assert np.median(jumps) < 0.25 * random_dist
    assert np.median(jumps) < 1.5 * np.median(inner)


def test_transitions_carry_the_previous_clip_onto_the_next(mini, seqs):
    import roma

    n = seqs.config.blend_frames
    assert (seqs.trans_length == n).all()
    assert seqs.trans_seq.size == seqs.seg_seq.size - len(seqs)
    first = seqs.seq_starts[seqs.trans_seq] + seqs.trans_start
    rows = (first[:, None] + np.arange(n)[None]).reshape(-1)
    mask = np.zeros(seqs.n_frames, bool)
    mask[rows] = True
    assert (seqs.frame_label[mask] == -1).all() and (seqs.frame_label[~mask] >= 0).all()
    from repro.data.compose_walk import VELOCITY_FRAMES

    t_ = np.arange(1, n + 1)
    s = t_ / (n + 1)
    w = 3 * s ** 2 - 2 * s ** 3
    m = min(VELOCITY_FRAMES, n + 1)
    u = np.clip((t_ - (n + 1 - m)) / m, 0, 1)
    g = (u ** 3 - u ** 2) * m

    def placed(c, frames, yaw, off):
        src = mini.clip_root(c)[frames].astype(np.float64)
        cs, sn = np.cos(yaw), np.sin(yaw)
        out = src.copy()
        out[:, 0] = cs * src[:, 0] + sn * src[:, 2] + off[0]
        out[:, 2] = -sn * src[:, 0] + cs * src[:, 2] + off[2]
        return out

    after = np.flatnonzero(seqs.seg_pos > 0)
    for t in range(0, after.size, 7):
        b = int(after[t]); a = b - 1
        c, i = int(seqs.seg_clip[a]), int(seqs.seg_clip_start[a] + seqs.seg_length[a] - 1)
        # A's own recorded frames i+1 .. i+n+1 (no frame of B's clip), placed like A, carried
        # onto B's first frame with B's velocity (a smoothstep and a short Hermite ramp)
        pa = placed(c, np.arange(i + 1, i + n + 2), float(seqs.seg_yaw[a]), seqs.seg_offset[a])
        cb, j = int(seqs.seg_clip[b]), int(seqs.seg_clip_start[b])
        pb = placed(cb, np.array([j, j + 1]), float(seqs.seg_yaw[b]), seqs.seg_offset[b])
        want = (pa[:n] + w[:, None] * (pb[0] - pa[n])[None]
                + g[:, None] * ((pb[1] - pb[0]) - (pa[n] - pa[n - 1]))[None])
        np.testing.assert_allclose(seqs.root[first[t]:first[t] + n], want, atol=1e-4)
        np.testing.assert_allclose(seqs.root[first[t] + n], pb[0], atol=1e-4)
        # the last transition frame steps into B like B's own first step
        q_last = seqs.rotations[first[t] + n - 1].astype(np.float64)
        q_b = seqs.rotations[first[t] + n].astype(np.float64)
        q_b1 = seqs.rotations[first[t] + n + 1].astype(np.float64) \
            if seqs.seg_length[b] > 1 else q_b
        assert np.median(_angle(q_last, q_b)) < np.median(_angle(q_b, q_b1)) + 0.05


def test_tag_matrix_is_long_tailed_doubly_stochastic_and_realised(seqs):
    cfg, C = seqs.config, seqs.n_classes
    P = seqs.preference
    np.testing.assert_allclose(P.sum(1), 1.0, atol=1e-9)
    np.testing.assert_allclose(P.sum(0), 1.0, atol=1e-9)          # uniform stationary mix
    assert (P > 0).all()                                           # every class one step away
    assert (np.diag(P) == P.min(axis=1)).all()                     # itself a rare successor
    assert ((P > P.min(axis=1, keepdims=True)).sum(1) == cfg.n_frequent).all()
    top = np.sort(P, axis=1)[:, ::-1][:, :cfg.n_frequent].sum(1)
    np.testing.assert_allclose(top, 1 - cfg.rare_share, atol=1e-9)
    train, test = seqs.tag_pair_counts(TRAIN), seqs.tag_pair_counts(TEST)
    np.testing.assert_array_equal(seqs.tag_pair_counts(None), train + test)
    for split, m in ((TRAIN, train), (TEST, test)):
        assert m.dtype == np.int64 and m.shape == (C, C)
        n_seq = int((seqs.seq_split == split).sum())
        assert m.sum() == int((seqs.seq_split[seqs.seg_seq] == split).sum()) - n_seq
    assert (train >= 1).all()           # every transition a test chain can take was seen
    # test transitions are (almost) all among training's frequent pairs or seen ones
    assert (test[train == 0] == 0).all()


def test_sequences_start_anywhere_in_the_world(seqs):
    lead = seqs.segments(role=ROLE_LEAD_IN)
    yaw = np.degrees(np.abs(seqs.seg_yaw[lead]))
    assert np.median(yaw) > 45 and yaw.max() > 150
    assert np.median(np.abs(seqs.seg_offset[lead][:, [0, 2]])) > 0.3
    origin = compose_sequences(subset(seqs.clips, np.arange(0, len(seqs.clips), 4)),
                               {"world_placement": "origin"})
    first = origin.segments(role=ROLE_LEAD_IN)
    assert (origin.seg_yaw[first] == 0).all() and (origin.seg_offset[first] == 0).all()


def test_fidelity_meets_issue_26(seqs):
    """The card's fidelity numbers on the mini view (issue 26, "Done when")."""
    f = card_of(seqs)["fidelity"]
    C = seqs.n_classes
    assert min(f["successors_per_tag"]) >= 6
    assert np.median(f["top4_share"]) >= 0.6
    ov, su = f["test_sets"]["overall"], f["test_sets"]["sufficient"]
    assert su["unseen_share"] <= 0.01
    assert su["median_support"] >= 3 * ov["median_support"]
    share = np.array(ov["class_share_by_position"])
    assert share.shape == (20, C) and ov["chains"] >= 500
    assert share[1:].min() >= 0.3 / C and share[1:].max() <= 3 / C
    assert all(v["share"] <= 0.05 for v in f["truncated_actions"].values())
    assert set(f["truncated_actions"]) == {"quick", "medium", "paper", "converged"}
    j = f["junction"]
    assert j["above_p99_share"] <= 0.10 and j["foot_slide_junction"] <= 0.2
    assert j["above_p99_share_seam"] <= 0.10          # the seam itself, where P^ini ends
    assert f["pairs"]["sp_heading_deg_median"] >= 30
    # like recorded motion: neither a bend (> 1.5) nor a straight blend (well below 1)
    assert 0.67 <= f["pairs"]["transition_linear_ratio"] <= 1.5
    # the tag itself is a rare successor, not the favourite (review of issue 26)
    assert ov["self_share"] <= 0.2 and su["self_share"] <= 0.3


def test_card_is_json(seqs, mini):
    card = json.loads(json.dumps(card_of(seqs)))
    assert card["fingerprint"] == seqs.fingerprint and card["compose_version"] == COMPOSE_VERSION
    assert card["source"]["fingerprint"] == mini.fingerprint
    assert card["tag_pairs"]["label_names"] == list(mini.label_names)
    assert card["tag_pairs"]["train"] == seqs.tag_pair_counts(TRAIN).tolist()
    assert card["tag_pairs"]["test"] == seqs.tag_pair_counts(TEST).tolist()
    assert card["preference"]["matrix"] == seqs.preference.tolist()
    assert card["segments"] == {"lead_in": len(seqs), "action": len(mini), "lead_out": len(seqs)}
    assert card["sequences"]["train"] + card["sequences"]["test"] == len(seqs)
    assert card["config"] == ComposeConfig().model_dump(mode="json")
    assert "stand-in" in card["stand_in"]
    q = card["junction_quality"]
    for k in ("velocity_jump", "foot_slide"):
        assert q[k]["junction"]["n"] > 0 and q[k]["inside"]["n"] > 0
        assert q[k]["junction"]["mean"] >= 0 and q[k]["inside"]["mean"] > 0
    assert q["foot_joints"] == ["Foot_L", "Toes_L", "Foot_R", "Toes_R"]
    assert set(card["fidelity"]) == {"successors_per_tag", "top4_share", "test_sets",
                                     "truncated_actions", "junction", "pairs"}


def test_config_checks_and_edge_cases(mini):
    with pytest.raises(ConfigError, match="max_actions"):
        ComposeConfig.resolve({"min_actions": 4, "max_actions": 2})
    with pytest.raises(ConfigError, match="bogus"):
        ComposeConfig.resolve({"bogus": 1})
    # a small set: hard cuts (no blend), short sequences
    idx = np.concatenate([mini.indices(split=s, label=c)[:2] for s in (TRAIN, TEST)
                          for c in range(mini.n_classes)])
    sub = subset(mini, idx)
    s = compose_sequences(sub, {"blend_frames": 0, "min_actions": 1, "max_actions": 2})
    assert (s.frame_label >= 0).all() and (s.trans_length == 0).all()
    np.testing.assert_array_equal(np.bincount(s.seg_clip[s.segments()], minlength=len(sub)), 1)
    assert np.bincount(s.seg_seq[s.segments()]).max() <= 2
    assert (s.next_labels(s.segments()) >= 0).all()
    # a split of one clip cannot have lead-ins from another clip
    lone = subset(mini, np.concatenate([mini.indices(split=TRAIN)[:5],
                                        mini.indices(split=TEST)[:1]]))
    with pytest.raises(DataError, match="at least two"):
        compose_sequences(lone)
    with pytest.raises(ConfigError, match="did you mean"):
        load_view("bandai2-seq-mimi")


def test_view_matches_direct_composition(seqs):
    v = load_view("bandai2-seq-mini")
    assert v.name == "bandai2-seq-mini" and v.fingerprint == seqs.fingerprint
    assert card_of(v)["name"] == "bandai2-seq-mini" and card_of(seqs)["name"] != v.name
    assert SEQUENCE_VIEWS == {"bandai2-seq": "bandai2", "bandai2-seq-mini": "bandai2-mini"}


def test_cli_prepare_info(capsys, _repro_home, seqs):
    assert main(["data", "prepare", "bandai2-seq-mini", "--json"]) == 0
    first = json.loads(capsys.readouterr().out)
    assert main(["data", "prepare", "bandai2-seq-mini"]) == 0
    out = capsys.readouterr().out
    assert first["fingerprint"] == seqs.fingerprint and f"fingerprint: {seqs.fingerprint}" in out
    assert "already prepared" in out
    folder = _repro_home / "datasets" / "bandai2-seq-mini" / seqs.fingerprint
    card = json.loads((folder / "card.json").read_text())
    assert card["schema"] == CARD_SCHEMA == 2 and card["fingerprint"] == seqs.fingerprint
    with np.load(folder / "sequences.npz") as z:
        np.testing.assert_array_equal(z["seg_clip"], seqs.seg_clip)
        assert "rotations" not in z.files
    assert main(["data", "info", "bandai2-seq-mini", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["tag_pairs"]["train"] == seqs.tag_pair_counts(TRAIN).tolist()
    assert main(["data", "info", "bandai2-seq-mini"]) == 0
    out = capsys.readouterr().out
    assert "train tag-pair counts" in out and "raise-up-right-hand" in out
    assert main(["data", "info", "--list", "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    view = rows["bandai2-seq-mini"]
    assert view["prepared"] and view["view_of"] == "bandai2-mini"
    assert rows["bandai2-seq-mini"]["fingerprint"] == seqs.fingerprint
    assert "bandai2-seq" in rows


def test_cli_missing_bandai2_is_one_clear_line(capsys):
    assert main(["data", "prepare", "bandai2-seq"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("repro: error:") and "repro data prepare bandai2" in err
    assert "Traceback" not in err
    assert main(["data", "info", "bandai2-seq"]) == 2
