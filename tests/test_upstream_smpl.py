"""Body models: locating the user's files, loading npz/pkl, FK joints and linear blend skinning."""

import pickle
import sys
import types

import numpy as np
import pytest
from upstream_synth import body_model_arrays

from repro.data.upstream.skeletons import SMPL_24, SMPLH_52
from repro.data.upstream.smpl import load_body_model, locate_body_model
from repro.errors import DataError, MissingDataError


def test_absent_model_says_which_file_where_and_licence(monkeypatch, tmp_path):
    monkeypatch.delenv("REPRO_SMPL_DIR", raising=False)
    with pytest.raises(MissingDataError) as e:
        locate_body_model("smplh", gender="male")
    msg = str(e.value)
    assert "REPRO_SMPL_DIR is not set" in msg and "smplh/male/model.npz" in msg
    assert "mano.is.tue.mpg.de" in msg
    monkeypatch.setenv("REPRO_SMPL_DIR", str(tmp_path))
    with pytest.raises(MissingDataError) as e:
        locate_body_model("smpl")
    assert str(tmp_path / "smpl" / "SMPL_NEUTRAL.npz") in str(e.value)
    assert "smpl.is.tue.mpg.de" in str(e.value)


def test_locate_by_env_dir_and_explicit_path(monkeypatch, tmp_path):
    f = tmp_path / "smplh" / "male" / "model.npz"
    f.parent.mkdir(parents=True)
    np.savez(f, **body_model_arrays(SMPLH_52))
    monkeypatch.setenv("REPRO_SMPL_DIR", str(tmp_path))
    assert locate_body_model("smplh", gender="male") == f
    monkeypatch.delenv("REPRO_SMPL_DIR")
    assert locate_body_model("smplh", path=tmp_path, gender="male") == f
    assert locate_body_model("smpl", path=f) == f          # an explicit file is taken as is
    with pytest.raises(MissingDataError, match="female"):
        locate_body_model("smplh", path=tmp_path, gender="female")


def _reference_lbs(a: dict, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray):
    """Skinning written out joint by joint and vertex by vertex (independent of BodyModel)."""
    import roma
    import torch

    parents = [int(p) if p < len(a["weights"][0]) else -1 for p in a["kintree_table"][0]]
    J = len(parents)
    vs = a["v_template"] + a["shapedirs"][..., :len(betas)] @ betas
    Jr = a["J_regressor"] @ vs
    R = roma.rotvec_to_rotmat(torch.from_numpy(pose.reshape(J, 3))).numpy()
    feat = np.concatenate([(R[j] - np.eye(3)).ravel() for j in range(1, J)])
    vp = vs + a["posedirs"] @ feat
    G, g = [None] * J, [None] * J
    for j, p in enumerate(parents):
        if p < 0:
            G[j], g[j] = R[j], Jr[j]
        else:
            G[j], g[j] = G[p] @ R[j], g[p] + G[p] @ (Jr[j] - Jr[p])
    out = np.zeros_like(vs)
    for v in range(vs.shape[0]):
        for j in range(J):
            w = a["weights"][v, j]
            if w:
                out[v] += w * (G[j] @ (vp[v] - Jr[j]) + g[j])
    return out + trans, np.stack(g) + trans


@pytest.mark.parametrize("js", [SMPL_24, SMPLH_52], ids=lambda s: s.name)
def test_skinning_and_fk_match_a_written_out_reference(tmp_path, js):
    a = body_model_arrays(js, seed=1)
    np.savez(tmp_path / "m.npz", **a)
    m = load_body_model(tmp_path / "m.npz")
    assert m.kind == ("smpl" if js is SMPL_24 else "smplh")
    assert m.joint_names == js.names and m.parents == js.parents
    rng = np.random.default_rng(0)
    pose = rng.normal(scale=0.4, size=(2, 3 * js.n_joints))
    betas = rng.normal(size=10)
    trans = rng.normal(size=(2, 3))
    verts = m.vertices(pose, betas, trans)
    fk = m.fk_joints(pose, betas, trans)
    for t in range(2):
        ref_v, ref_j = _reference_lbs(a, pose[t], betas, trans[t])
        np.testing.assert_allclose(verts[t], ref_v, atol=1e-10)
        np.testing.assert_allclose(fk[t], ref_j, atol=1e-10)
    # Zero pose, zero translation: the shaped rest mesh and the rest joints.
    zero = np.zeros((1, 3 * js.n_joints))
    np.testing.assert_allclose(m.vertices(zero, betas)[0], m.shaped_vertices(betas), atol=1e-12)
    np.testing.assert_allclose(m.fk_joints(zero, betas)[0], m.rest_joints(betas), atol=1e-12)


def test_mesh_joints_equal_fk_joints_for_rigid_skinning(tmp_path):
    np.savez(tmp_path / "r.npz", **body_model_arrays(SMPLH_52, seed=2, rigid=True))
    m = load_body_model(tmp_path / "r.npz")
    pose = np.random.default_rng(1).normal(scale=0.5, size=(3, 156))
    np.testing.assert_allclose(m.mesh_joints(pose), m.fk_joints(pose), atol=1e-10)
    np.savez(tmp_path / "s.npz", **body_model_arrays(SMPLH_52, seed=2))
    soft = load_body_model(tmp_path / "s.npz")
    gap = np.abs(soft.mesh_joints(pose) - soft.fk_joints(pose)).max()
    assert 0 < gap < 0.2     # pose blend shapes and blended skinning move regressed joints


def test_pkl_models_with_sparse_regressor_load_and_chumpy_is_refused(tmp_path):
    import scipy.sparse as sp

    a = body_model_arrays(SMPL_24, seed=3)
    a["J_regressor"] = sp.csc_matrix(a["J_regressor"])
    p = tmp_path / "SMPL_NEUTRAL.pkl"
    p.write_bytes(pickle.dumps(a, protocol=2))
    m = load_body_model(p)
    np.testing.assert_allclose(m.J_regressor, a["J_regressor"].toarray())

    mod = types.ModuleType("chumpy.ch")

    class Ch:
        def __init__(self, x):
            self.x = x

    Ch.__module__, Ch.__qualname__ = "chumpy.ch", "Ch"
    mod.Ch = Ch
    sys.modules["chumpy"], sys.modules["chumpy.ch"] = types.ModuleType("chumpy"), mod
    try:
        raw = pickle.dumps({**a, "v_template": Ch(a["v_template"])}, protocol=2)
    finally:
        del sys.modules["chumpy"], sys.modules["chumpy.ch"]
    q = tmp_path / "chumpy.pkl"
    q.write_bytes(raw)
    with pytest.raises(DataError, match="chumpy objects.*convert it once to .npz") as e:
        load_body_model(q)
    assert str(q) in str(e.value)


def test_malformed_models_name_the_problem(tmp_path):
    a = body_model_arrays(SMPL_24)
    bad = {k: v for k, v in a.items() if k != "weights"}
    np.savez(tmp_path / "a.npz", **bad)
    with pytest.raises(DataError, match="a.npz: body model lacks weights"):
        load_body_model(tmp_path / "a.npz")
    np.savez(tmp_path / "b.npz", **{**a, "posedirs": a["posedirs"][..., :10]})
    with pytest.raises(DataError, match="posedirs must be"):
        load_body_model(tmp_path / "b.npz")
    np.savez(tmp_path / "c.npz", **{**a, "kintree_table": a["kintree_table"][:, ::-1]})
    with pytest.raises(DataError, match="kintree_table"):
        load_body_model(tmp_path / "c.npz")
