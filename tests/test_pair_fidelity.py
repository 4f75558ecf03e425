"""repro.data.pair_fidelity on the bandai2-mini sequence view (issue 26, the card's ``pairs``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from repro.data.clipset import TEST, TRAIN
from repro.data.pair_fidelity import linear_deviation_cm, pair_fidelity
from repro.data.pairs_build import PairSource
from repro.keys import content_key


@pytest.fixture(scope="module")
def seqs():
    from repro.data.registry import load_clipset
    from repro.data.sequences import sequences_for

    torch.set_num_threads(1)
    return sequences_for(load_clipset("bandai2-mini"))


def _yawed(seqs, seed: int):
    """``seqs`` with every sequence turned about +Y by its own seeded yaw (frames, joints and
    ``seg_yaw``; a new fingerprint), as a composer that randomises world yaw would place it."""
    rng = np.random.default_rng(seed)
    yaw_seq = rng.uniform(-np.pi, np.pi, len(seqs))
    yaw = np.repeat(yaw_seq, seqs.seq_lengths)
    c, s = np.cos(yaw), np.sin(yaw)

    def rot(v):
        v = np.asarray(v, np.float64)
        out = v.copy()
        out[..., 0] = c.reshape((-1,) + (1,) * (v.ndim - 2)) * v[..., 0] + \
            s.reshape((-1,) + (1,) * (v.ndim - 2)) * v[..., 2]
        out[..., 2] = -s.reshape((-1,) + (1,) * (v.ndim - 2)) * v[..., 0] + \
            c.reshape((-1,) + (1,) * (v.ndim - 2)) * v[..., 2]
        return out

    q = np.asarray(seqs.rotations, np.float64).copy()          # xyzw
    x, y, z, w = (q[:, 0, i] for i in range(4))
    hs, hc = np.sin(yaw / 2), np.cos(yaw / 2)                  # (0, hs, 0, hc) ⊗ q
    q[:, 0] = np.stack([hc * x + hs * z, hc * y + hs * w, hc * z - hs * x, hc * w - hs * y], -1)
    return dataclasses.replace(
        seqs, rotations=q.astype(np.float32), root=rot(seqs.root).astype(np.float32),
        joints=rot(seqs.joints).astype(np.float32),
        seg_yaw=np.asarray(seqs.seg_yaw) + yaw_seq[seqs.seg_seq],
        fingerprint=content_key({"base": seqs.fingerprint, "test-yaw": seed}), memo={})


def test_keys_values_and_determinism(seqs):
    a = pair_fidelity(seqs)
    assert set(a) == {"sp_heading_deg_median", "transition_linear_ratio"}
    assert 0.0 <= a["sp_heading_deg_median"] <= 180.0
    assert np.isfinite(a["transition_linear_ratio"]) and a["transition_linear_ratio"] > 0
    assert pair_fidelity(seqs) == a                                   # deterministic
    assert pair_fidelity(seqs, PairSource()) == a                     # the default source


def test_heading_is_sp_last_frame_against_the_canonical_facing(seqs):
    """The statistic is the lateral-axis heading of S_p's last frame in the pairs' (world)
    frame; turning every sequence by its own yaw spreads it, as a recording would."""
    from repro.motion.heading import motion_heading

    tr = PairSource().train_items(seqs)
    last = tr.motion.replace(root=tr.motion.root[torch.arange(len(tr)), tr.l_p - 1][:, None],
                             rot6d=tr.motion.rot6d[torch.arange(len(tr)), tr.l_p - 1][:, None])
    h = np.degrees(np.abs(motion_heading(last.to(dtype=torch.float64), axis="lateral").numpy()))
    assert pair_fidelity(seqs)["sp_heading_deg_median"] == pytest.approx(float(np.median(h)))
    turned = pair_fidelity(_yawed(seqs, 7))
    assert turned["sp_heading_deg_median"] > 30
    # a rigid yaw per sequence moves no joint relative to its own run: the ratio is unchanged
    assert turned["transition_linear_ratio"] == pytest.approx(
        pair_fidelity(seqs)["transition_linear_ratio"], rel=1e-3)


def test_linear_deviation():
    t = torch.linspace(0, 1, 7, dtype=torch.float64)[:, None, None]
    line = torch.tensor([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]], dtype=torch.float64) * t
    assert linear_deviation_cm(line) == pytest.approx(0.0, abs=1e-9)
    bent = line.clone()
    bent[3, :, 2] += 0.05                                  # 5 cm off the line at one interior frame
    assert linear_deviation_cm(bent) == pytest.approx(5.0 / 5, rel=1e-9)   # mean over 5 frames
    with pytest.raises(ValueError):
        linear_deviation_cm(line[:2])


def test_pairs_no_leak_on_the_view(seqs):
    """As the pairs' own tests: S_p and S_c come from different clips; test pairs only from
    test clips (on the real mini view)."""
    src = PairSource()
    split = np.asarray(seqs.clips.split)
    for which in (TRAIN, TEST):
        tab = src.pair_table(seqs, which)
        assert np.all(tab["prev_clip"] != tab["clip"])
        assert np.all(split[tab["clip"]] == which) and np.all(split[tab["prev_clip"]] == which)
