"""ODMO Table 3's calibration rows (random codes, PCA of the raw local movement), its
chance-corrected style columns and the padding exclusion (repro.eval.protocols.latent_modes;
issue 27)."""

from __future__ import annotations

import numpy as np
import pytest

from repro.data.registry import load_clipset
from repro.errors import ConfigError
from repro.eval.protocols import get_protocol
from repro.eval.protocols.latent_modes import (CALIBRATION_LATENTS, LatentModes, LatentSamples,
                                               calibration_codes)


@pytest.fixture(scope="module")
def clips():
    return load_clipset("bandai2-mini")


def _proto(**kw):
    return get_protocol("latent_modes", {"window": 20, "codes_per_class": 60, "gmm_inits": 2,
                                         **kw})


def test_random_codes_score_chance_on_every_column(clips):
    proto = _proto()
    ctx = proto.test_items(clips)
    v = proto.real_replicate(clips, ctx, None, seed=0, replicate=0, latent="random")
    assert set(v) == {"mode_homogeneity", "style_ami", "style_ari"}
    assert abs(v["style_ami"]) < 0.05 and abs(v["style_ari"]) < 0.05
    assert abs(v["mode_homogeneity"]) < 5.0  # modes of noise split no real motion
    # deterministic per (seed, replicate); another replicate draws other windows and codes
    assert proto.real_replicate(clips, ctx, None, seed=0, replicate=0, latent="random") == v
    assert proto.real_replicate(clips, ctx, None, seed=0, replicate=1, latent="random") != v


def test_pca_of_raw_movement_is_scored_by_the_same_code(clips):
    """A latent that learned nothing but the motion's own principal axes: its modes do split
    the real windows (far above random codes), which is what Table 3's rows must beat."""
    proto = _proto()
    ctx = proto.test_items(clips)
    v = proto.real_replicate(clips, ctx, None, seed=0, replicate=0, latent="pca")
    r = proto.real_replicate(clips, ctx, None, seed=0, replicate=0, latent="random")
    assert v["mode_homogeneity"] > r["mode_homogeneity"] + 10.0
    # the very scoring of a method row: a generator whose encoder is that PCA scores the same
    b = proto.windows(ctx, proto.replicate_seed(0, 0))

    class PcaEncoder:
        method_id = "pca"

        def latent_codes(self, joints):
            return calibration_codes("pca", joints, 20, 0)

    out = proto.generate(PcaEncoder(), ctx, seed=0, replicate=0)
    assert np.array_equal(out.joints, b.joints)
    assert proto.measure(out, ctx, None, seed=0) == pytest.approx(v)


def test_calibration_codes():
    rng = np.random.default_rng(0)
    joints = rng.normal(size=(50, 8, 4, 3))
    pca = calibration_codes("pca", joints, 5, 0)
    assert pca.shape == (50, 5)
    var = pca.var(axis=0)
    assert np.all(np.diff(var) <= 1e-9) and np.allclose(pca.mean(0), 0.0, atol=1e-9)
    # local movement: a global translation of a window changes nothing
    shifted = joints + rng.normal(size=(50, 1, 1, 3))
    assert np.allclose(np.abs(calibration_codes("pca", shifted, 5, 0)), np.abs(pca), atol=1e-8)
    rnd = calibration_codes("random", joints, 20, 3)
    assert rnd.shape == (50, 20) and np.array_equal(rnd, calibration_codes("random", joints, 20, 3))
    with pytest.raises(ConfigError, match="unknown calibration latent"):
        calibration_codes("umap", joints, 5, 0)


def test_padded_windows_are_left_out_of_the_style_columns(clips):
    """Codes that match the styles on unpadded windows and contradict them on heavily padded
    ones: with the exclusion the style columns see the match only."""
    rng = np.random.default_rng(0)
    n_per, n_cls, T = 42, 2, 20
    labels = np.repeat(np.arange(n_cls), n_per)
    styles = np.tile(np.arange(3).repeat(n_per // 3), n_cls)
    padded = np.zeros(labels.size, np.int64)
    padded[rng.random(labels.size) < 0.4] = 10  # half the window padded
    shown = np.where(padded > 0, (styles + 1) % 3, styles)  # padded windows lie about their style
    codes = 30.0 * np.eye(3)[shown] + 0.1 * rng.normal(size=(labels.size, 3))
    joints = rng.normal(size=(labels.size, T, 3, 3)) + 3.0 * shown[:, None, None, None]
    s = LatentSamples(joints, labels, styles, codes, clips.skeleton, 30.0, padded)
    keep = _proto(max_padded_share=0.25).score(s, n_cls, 0)
    every = _proto(max_padded_share=1.0).score(s, n_cls, 0)
    assert keep["style_ami"] > 0.95 and keep["style_ari"] > 0.95
    assert every["style_ami"] < 0.6
    assert keep["mode_homogeneity"] == every["mode_homogeneity"]  # modes use every window


def test_table3_spec_carries_the_calibration_rows_and_both_rules():
    from repro.specs.load import find_spec

    spec = find_spec("odmo/table3")
    calib = {r.id: r for r in spec.rows if r.method == "real" and r.overrides}
    assert set(calib) == {"random_codes", "pca_lmp"}
    for r in calib.values():
        assert set(r.overrides) <= set(LatentModes.real_row_options)  # the engine passes these
        assert r.overrides["latent"] in CALIBRATION_LATENTS
        assert "harness, not in the paper" in r.label and not r.reported
    metrics = {c.metric for c in spec.columns}
    assert {"style_ami", "style_ari"} <= metrics and not {"style_nmi", "style_coverage"} & metrics
    rules = {g.id: spec.protocol_params_for(f"{g.id}.mode_homogeneity").get("k_rule")
             for g in spec.groups}
    assert rules == {"humanact12": "discovery", "uestc": "discovery",
                     "humanact12_paper_rule": "paper", "uestc_paper_rule": "paper"}
    # the claim compares ODMO and ACTOR under one rule, the released discovery script's
    (claim,) = spec.claims
    assert all(rules[c.split(".")[0]] == "discovery" for c in claim.column)
    for g in spec.groups:  # the threshold's reference = the reference bank's codes per class
        p = spec.protocol_params_for(f"{g.id}.mode_homogeneity")
        assert p["reference_codes"] == p["codes_per_class"]
