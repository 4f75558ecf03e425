"""ODMO's paper ↔ code readings (issue 27; repro.models.odmo, odmo_nets; docs/odmo.md): the
trajectory loss on positions (the released trainer's ``to_location``) against Eq. 2's velocities,
a motion decoder that sees the trajectory only through ``h_0`` and reads the code's time input
``(t + 1)/T``, the code's layer shapes (parameter counts at HumanAct12's sizes from hand
arithmetic), the code's loss reduction on planted errors, and −L_es without a μᵀμ prior.
Tiny sizes, one torch thread, planted windows."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from repro.data.registry import load_clipset
from repro.models.odmo import ODMO, PAIR
from repro.models.odmo_nets import MotionGenerator, ODMONet, class_code, squared_error
from model_fixtures import one_torch_thread  # noqa: F401 (autouse fixture)

T, C = 12, 2
TINY = {"enc_hidden": 16, "enc_feature": 16, "hidden": 32, "window": T, "y_weight": 1.0,
        "tf_start": 1.0, "tf_end": 1.0, "tf_decay_epochs": 0}


@pytest.fixture(scope="module")
def skeleton():
    return load_clipset("bandai2-mini").skeleton


def planted_batch(n_joints: int, n_pairs: int = 16, seed: int = 0) -> dict:
    """Pairs of windows whose root moves on a straight line from the origin (speed and heading
    per window) carrying a fixed pose (offsets per joint, root offset 0)."""
    rng = np.random.default_rng(seed)
    n = 2 * n_pairs
    heading = rng.uniform(0.0, 2 * np.pi, n)
    dist = rng.uniform(0.5, 2.0, n)
    direction = np.stack([np.cos(heading), np.zeros(n), np.sin(heading)], 1)
    root = dist[:, None, None] * np.linspace(0.0, 1.0, T)[None, :, None] * direction[:, None]
    offsets = rng.normal(scale=0.3, size=(1, 1, n_joints, 3))
    offsets[..., 0, :] = 0.0
    joints = torch.from_numpy((root[:, :, None] + offsets).astype(np.float32))
    labels = torch.from_numpy(rng.integers(0, C, n))
    return {"anchor": joints[:n_pairs], "partner": joints[n_pairs:],
            "labels_a": labels[:n_pairs], "labels_p": labels[n_pairs:], "y_weight": 1.0}


def make(skeleton, **over) -> ODMO:
    return ODMO({**TINY, **over}, skeleton, C, 30.0)


def end_error_after_training(skeleton, traj_target: str, steps: int = 40) -> float:
    """Mean squared distance (summed over xyz) of Gr's last trajectory point to the real end,
    after ``steps`` Adam steps on one planted batch (same seeds for every reading)."""
    g = make(skeleton, traj_target=traj_target)
    batch = planted_batch(skeleton.n_joints)
    opt = torch.optim.Adam(g.net.parameters(), lr=3e-3)
    g.net.train()
    for i in range(steps):
        torch.manual_seed(i)
        opt.zero_grad()
        g.training_step(g.net, batch, epoch=0)["loss"].backward()
        opt.step()
    x = torch.cat([batch["anchor"], batch["partner"]])
    labels = torch.cat([batch["labels_a"], batch["labels_p"]])
    with torch.no_grad():  # train mode: BatchNorm on the batch, as in training
        mu, _ = g.net.encode(x)
        _, traj, _ = g.net.generate(mu, labels, x[:, -1, 0], T)
    return float(((traj[:, -1] - x[:, -1, 0]) ** 2).sum(-1).mean())


def test_position_reading_brings_the_trajectory_end_closer(skeleton):
    pos = end_error_after_training(skeleton, "position")
    vel = end_error_after_training(skeleton, "velocity")
    assert pos == end_error_after_training(skeleton, "position")  # deterministic
    assert pos < 0.5 * vel, (pos, vel)


def _terms_with_trajectory(g: ODMO, batch: dict) -> tuple[dict, tuple]:
    seen = []
    h = g.net.trajectory.register_forward_hook(lambda mod, args, out: seen.append(out))
    torch.manual_seed(7)
    g.net.train()
    out = {k: float(v.detach()) for k, v in g.training_step(g.net, batch, 0).items()}
    h.remove()
    return out, seen[0]


def _code_formula(err: np.ndarray, yw: float) -> float:
    """The released trainer's reduction written out: per window, Σ over frames of the mean over
    the frame's coordinates of the y-weighted squared error; then the batch mean."""
    total = 0.0
    for w in err:
        for frame in w.reshape(w.shape[0], -1, 3):
            sq = frame ** 2
            sq[:, 1] *= yw
            total += sq.mean()
    return total / err.shape[0]


@pytest.mark.parametrize("target", ["position", "velocity"])
def test_trajectory_term_compares_what_its_reading_says(skeleton, target):
    batch = {**planted_batch(skeleton.n_joints, n_pairs=4), "y_weight": 3.0}
    g = make(skeleton, traj_target=target)
    out, (vel, traj) = _terms_with_trajectory(g, batch)
    root = torch.cat([batch["anchor"], batch["partner"]])[:, :, 0].double().numpy()
    if target == "position":  # T positions (a leading 0) against the real root
        err = traj.detach().double().numpy() - root
        assert err.shape[1] == T
    else:                     # T − 1 velocities against the root's steps (Eq. 2)
        err = vel.detach().double().numpy() - np.diff(root, axis=1)
        assert err.shape[1] == T - 1
    assert out["traj"] == pytest.approx(PAIR * _code_formula(err, 3.0), rel=1e-5)


def test_decoder_sees_the_trajectory_only_through_h0(skeleton):
    g = make(skeleton)
    net = g.net.eval()
    J = skeleton.n_joints
    assert net.motion.dec_embed.in_features == 3 * J + C * 20 + 1  # pose, one-hot ⊗ z, time
    torch.manual_seed(0)
    z, lab = torch.randn(3, 20), torch.tensor([0, 1, 1])
    cond = class_code(lab, z, C)
    t1, t2 = torch.randn(3, T, 3), torch.randn(3, T, 3)
    with torch.no_grad():
        a, b = net.motion(t1, cond), net.motion(t2, cond)
        assert not torch.equal(a, b)
        _, state1 = net.motion.traj_lstm(net.motion.act(net.motion.traj_embed(t1)))
        # the second trajectory with the first one's encoder state: the first one's poses
        h = net.motion.traj_lstm.register_forward_hook(
            lambda mod, args, out: (out[0], state1))
        torch.testing.assert_close(net.motion(t2, cond), a, rtol=0, atol=0)
        h.remove()


def test_decoder_is_the_codes_step_with_time_t_plus_1_over_T(skeleton):
    """The fused decoder equals the plain step of the released code: embed(PReLU(FC([prev,
    one-hot ⊗ z, (t + 1)/T]))) with the first step reading 1/T and the last 1."""
    net = make(skeleton).net.eval()
    m = net.motion
    assert torch.equal(MotionGenerator.time_input(T, torch.zeros(1)),
                       torch.arange(1, T + 1, dtype=torch.float32) / T)
    _fused_equals_plain_step(m, seed=1, time=True)


def _fused_equals_plain_step(m: MotionGenerator, *, seed: int, time: bool) -> None:
    """``m``'s fused forward equals the plain per-step loop: FC over [prev, one-hot ⊗ z] plus
    ``(t + 1)/T`` when ``time``, the shared PReLU, one LSTM step, the output FC."""
    torch.manual_seed(seed)
    cond, traj = class_code(torch.tensor([1, 0]), torch.randn(2, 20), C), torch.randn(2, T, 3)
    with torch.no_grad():
        got = m(traj, cond)
        _, state = m.traj_lstm(m.act(m.traj_embed(traj)))
        prev, outs = torch.zeros(2, m.pose_dim), []
        for t in range(T):
            parts = [prev, cond] + ([torch.full((2, 1), (t + 1) / T)] if time else [])
            x = m.act(m.dec_embed(torch.cat(parts, -1)))
            h, state = m.dec_lstm(x[:, None], state)
            prev = m.out(h[:, 0])
            outs.append(prev)
    torch.testing.assert_close(got, torch.stack(outs, 1), rtol=1e-5, atol=1e-5)


# -- the code's shapes: parameter counts at HumanAct12's sizes (J 24, C 12, D 20, T 60) --------

def lin(i, o):
    return i * o + o


def lstm(i, h, layers=1):
    return 4 * h * (i + h) + 8 * h + (layers - 1) * (4 * h * (h + h) + 8 * h)


def test_code_shapes_have_the_released_codes_parameter_count():
    J3, CD, T60, H, E, F, D = 72, 12 * 20, 60, 128, 64, 256, 20
    # LMPEncoder: LSTM(72, 64); FC 256 + BN + PReLU; FC 256 + BN + PReLU; FC 2·D
    enc = lstm(J3, E) + lin(E, F) + 2 * F + 1 + lin(F, F) + 2 * F + 1 + lin(F, 2 * D)
    # TrajGenerator: expand FC(243 → 243·59); one PReLU; FC 243 → 128; 2 LSTM; 3 FC; FC → 3
    x = CD + 3
    traj = lin(x, x * (T60 - 1)) + 1 + lin(x, H) + lstm(H, H, 2) + 3 * lin(H, H) + lin(H, 3)
    # MotionGenerator: FC 3 → 128, one shared PReLU, 2 LSTM; FC 313 → 128, 2 LSTM, FC → 72
    motion = lin(3, H) + 1 + lstm(H, H, 2) + lin(J3 + CD + 1, H) + lstm(H, H, 2) + lin(H, J3)
    net = ODMONet(24, 12, latent=20, enc_hidden=64, hidden=128, window=60)
    count = lambda mod: sum(p.numel() for p in mod.parameters())
    assert (count(net.encoder), count(net.trajectory), count(net.motion)) == (enc, traj, motion)
    assert count(net) == enc + traj + motion == 4_551_019
    # the harness variants are what their docs say (and not the code's count)
    compact = ODMONet(24, 12, encoder_head="compact", enc_feature=64, window=60)
    assert count(compact.encoder) == lstm(J3, E) + lin(E, 64) + 2 * 64 + 1 + 2 * lin(64, D)
    rep = ODMONet(24, 12, trajectory_input="repeat", embed=128)
    assert count(rep.trajectory) == (lin(x, H) + 1 + lin(H, H) + lstm(H, H, 2)
                                     + 3 * (lin(H, H) + 1) + lin(H, 3))


# -- the code's reduction on planted errors ---------------------------------------------------

def test_reductions_on_a_planted_case():
    err = torch.tensor([[[1.0, 2.0, 0.0], [0.0, 0.0, 3.0]],
                        [[0.0, 1.0, 0.0], [2.0, 0.0, 0.0]]])   # 2 windows × 2 frames × xyz
    # y weight 5: window 1 frames 21, 9; window 2 frames 5, 4 (summed over xyz)
    assert float(squared_error(err, 5.0, "code")) == pytest.approx(((21 + 9) / 3 + 9 / 3) / 2)
    assert float(squared_error(err, 5.0, "sum")) == pytest.approx((30 + 9) / 2)
    assert float(squared_error(err, 5.0, "mean")) == pytest.approx((30 / 6 + 9 / 6) / 2)
    poses = torch.from_numpy(np.random.default_rng(3).normal(size=(3, 4, 5, 3)))  # (N, T, J, 3)
    assert float(squared_error(poses, 5.0, "code")) == pytest.approx(
        _code_formula(poses.numpy(), 5.0), rel=1e-12)


def test_no_mu_prior_in_minus_les_by_default(skeleton):
    batch = planted_batch(skeleton.n_joints, n_pairs=4)
    full, _ = _terms_with_trajectory(make(skeleton), batch)
    les, _ = _terms_with_trajectory(make(skeleton, contrastive=False), batch)
    assert set(les) == {"loss", "mre", "traj", "cons", "kl"}
    assert les["loss"] == pytest.approx(full["loss"] - full["contrastive"], rel=1e-6)
    vae, _ = _terms_with_trajectory(make(skeleton, contrastive=False, classic_mu_prior=True),
                                    batch)
    assert vae["mu_prior"] > 0 and vae["loss"] == pytest.approx(les["loss"] + vae["mu_prior"],
                                                                rel=1e-6)


def test_the_sampler_keeps_a_planted_latents_modes_in_a_small_bank():
    """Issue 27: the sampler's small-component threshold (the code's ``<= 10``) scales with the
    bank against the reference's (``windows_per_epoch / 2048``), so a quick-sized bank of 64
    codes of a 7-mode class still draws from >= 5 of the modes; unscaled it collapses."""
    from repro.models.odmo import REFERENCE_WINDOWS_PER_EPOCH, mode_preserving_codes

    for seed in range(2):
        rng = np.random.default_rng(seed)
        centres = rng.normal(scale=6.0, size=(7, 20))
        codes = centres[rng.integers(0, 7, 64)] + rng.normal(size=(64, 20))

        def modes_drawn(scale):
            drawn = mode_preserving_codes(codes, 700, rule="code", seed=seed,
                                          rng=np.random.default_rng(1), bank_scale=scale)
            nearest = np.argmin(((drawn[:, None] - centres[None]) ** 2).sum(-1), axis=1)
            return np.unique(nearest).size

        assert modes_drawn(128 / REFERENCE_WINDOWS_PER_EPOCH) >= 5, seed
        assert modes_drawn(None) <= 2, seed


def test_consistency_term_has_no_y_weight_and_the_codes_reduction(skeleton):
    """L_cons (Eq. 4): Gr's r̂_t against Gm's root joint, every frame, not y-weighted, reduced as
    the configured reduction (the code's here: mean over xyz, sum over frames)."""
    batch = {**planted_batch(skeleton.n_joints, n_pairs=4), "y_weight": 3.0}
    g = make(skeleton)
    seen = []
    h = g.net.motion.register_forward_hook(lambda mod, args, out: seen.append(out))
    out, (_, traj) = _terms_with_trajectory(g, batch)
    h.remove()
    root_hat = seen[0].detach().double().numpy()[:, :, :3]  # the pose's first joint
    err = traj.detach().double().numpy() - root_hat
    assert out["cons"] == pytest.approx(PAIR * _code_formula(err, 1.0), rel=1e-5)
    assert out["cons"] != pytest.approx(PAIR * _code_formula(err, 3.0), rel=1e-3)


def test_paper_decoder_has_no_time_input(skeleton):
    """decoder_time = False (§3.2(iii): previous pose and one-hot ⊗ z only) is the plain step
    without the time feature; the fused form matches it."""
    m = make(skeleton, decoder_time=False).net.eval().motion
    assert m.dec_embed.in_features == 3 * skeleton.n_joints + C * 20
    _fused_equals_plain_step(m, seed=2, time=False)


# -- every "(paper reading)" row selects every paper reading that applies to it ---------------

ABLATION_SWITCHES = ("traj_loss", "cons_loss", "contrastive", "use_end", "sampling", "sigma2")
NO_PAPER_READING = {"cons_loss", "encoder_head", "enc_feature", "trajectory_input", "window",
                    "embed"}  # an ablation switch; shapes Table S2 agrees on or gives no width


def _paper_rows():
    from repro.specs.load import find_spec

    for t in ("table1", "table2", "table3", "table4", "tableS1"):
        spec = find_spec(f"odmo/{t}")
        rows = {r.id: r for r in spec.rows}
        for row in spec.rows:
            if "(paper reading)" in row.label:
                base_id = row.id.removesuffix("_paper_reading")
                base = rows.get(base_id) or rows["sigma2_0_05"]  # S1 has no plain "odmo" row
                yield t, row, base


def test_the_paper_readings_are_the_docs_table():
    """The constants the rows are checked against name every field of docs/odmo.md's table that
    has a paper reading, and nothing else."""
    from repro.models.odmo import (PAPER_ABLATION_READINGS, PAPER_SAMPLING_READINGS,
                                   PAPER_TRAINING_READINGS)
    from repro.paths import repo_root

    text = (repo_root() / "docs" / "odmo.md").read_text()
    table = text[text.index("| difference | field |"):]
    table = table[:table.index("\n\n")]
    fields = set()
    for line in table.splitlines()[2:]:
        cell = line.split("|")[2]
        fields |= {f.strip("` ") for f in cell.split(",") if f.strip("` ")}
    readings = {**PAPER_TRAINING_READINGS, **PAPER_SAMPLING_READINGS, **PAPER_ABLATION_READINGS}
    assert fields - NO_PAPER_READING == set(readings)


def test_each_paper_reading_row_carries_every_paper_switch():
    from repro.models.odmo import (ODMOConfig, PAPER_ABLATION_READINGS, PAPER_SAMPLING_READINGS,
                                   PAPER_TRAINING_READINGS)

    defaults = ODMOConfig().model_dump()
    seen = 0
    for t, row, base in _paper_rows():
        assert row.method == base.method == "odmo", (t, row.id)
        over, base_over = dict(row.overrides), dict(base.overrides)
        seen += 1
        for k, v in PAPER_TRAINING_READINGS.items():
            assert over.get(k) == v, (t, row.id, k)
        # the same ablation as the row it reads: only the readings differ
        for k in ABLATION_SWITCHES:
            assert over.get(k, defaults[k]) == base_over.get(k, defaults[k]), (t, row.id, k)
        sampling = over.get("sampling", defaults["sampling"])
        if t != "table3":  # Table 3 encodes real windows and never samples
            key = "k_rule" if sampling == "mode_preserving" else "conventional_form"
            assert over.get(key) == PAPER_SAMPLING_READINGS[key], (t, row.id)
        if over.get("contrastive") is False:
            assert over.get("classic_mu_prior") == PAPER_ABLATION_READINGS["classic_mu_prior"]
        assert set(over) <= set(ABLATION_SWITCHES) | set(PAPER_TRAINING_READINGS) \
            | set(PAPER_SAMPLING_READINGS) | set(PAPER_ABLATION_READINGS), (t, row.id)
    assert seen == 3 + 3 + 1 + 3 + 1  # ODMO in all five, ODMO_conv and −L_es in 1-2, −L_traj and −L_cons in 4
