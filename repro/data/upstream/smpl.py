"""SMPL / SMPL-H body models: locating the user's licensed files, joint regression, skinning.

The body models are licensed by the Max Planck Institute and cannot ship with ``repro``.  The
user downloads them and points ``$REPRO_SMPL_DIR`` (or an explicit ``path``) at them;
:func:`locate_body_model` says exactly which file it expects where when it is absent.

Accepted files (``D`` = ``$REPRO_SMPL_DIR`` or the ``path`` directory), first match wins:

- SMPL (24 joints; ACTOR uses ``SMPL_NEUTRAL``): ``D/smpl/SMPL_<GENDER>.npz``,
  ``D/smpl/SMPL_<GENDER>.pkl``, ``D/SMPL_<GENDER>.npz``, ``D/SMPL_<GENDER>.pkl``;
  from https://smpl.is.tue.mpg.de (or SMPLify's neutral model, https://smplify.is.tue.mpg.de).
- SMPL-H (52 joints; AMASS poses, MultiAct's evaluator, which uses the **male** model):
  ``D/smplh/<gender>/model.npz`` (the "Extended SMPL+H model used in AMASS"),
  ``D/smplh/SMPLH_<GENDER>.npz``, ``D/smplh/SMPLH_<GENDER>.pkl``, ``D/<gender>/model.npz``;
  from https://mano.is.tue.mpg.de (downloads -> "Extended SMPL+H model").

File contents used (SMPL's own key names): ``v_template`` (V, 3) rest vertices, metres;
``shapedirs`` (V, 3, B) shape blend shapes; ``posedirs`` (V, 3, 9(J-1)) pose blend shapes;
``J_regressor`` (J, V) (dense or scipy sparse); ``weights`` (V, J) skinning weights;
``kintree_table`` (2, J) whose first row holds parent indices; ``f`` (faces, optional).
``.pkl`` files are read with the restricted unpickler (numpy + scipy sparse only); SMPL's
original ``.pkl`` files store ``chumpy`` objects and are refused with a message explaining how
to convert them to ``.npz``.

Maths (SMPL, Loper et al. 2015, eqs. 1-4; the same for SMPL-H):

- shaped rest mesh ``T(β) = v_template + Σ_b β_b S_b``; rest joints ``J(β) = J_regressor · T(β)``;
- forward kinematics (:meth:`BodyModel.fk_joints`): local rotations ``R_j = exp(θ_j)`` from the
  axis-angle pose, rest offsets ``J_j − J_parent``, root at ``J_0 + trans``;
- linear blend skinning (:meth:`BodyModel.vertices`): pose blend shapes
  ``Σ (R_j − I) ⊙ P`` added to ``T(β)``, vertices moved by ``Σ_j w_vj A_j`` with
  ``A_j = [G_j | g_j − G_j J_j]`` (global rotation ``G_j``, posed joint ``g_j``), plus ``trans``;
- regressed joints (:meth:`BodyModel.mesh_joints`): ``J_regressor`` applied to the *posed* mesh,
  as MultiAct computes its 52 evaluator joints.  These differ slightly from FK joints because
  pose blend shapes and skinning move the vertices the regressor averages.

Units: metres, radians.  Coordinates are the model's (AMASS data: Z up; convert with
:mod:`repro.data.upstream.axes`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from repro.errors import DataError, MissingDataError

from .restricted_pickle import load_restricted
from .skeletons import SMPL_24, SMPLH_52

BodyKind = Literal["smpl", "smplh"]
SMPL_DIR_ENV = "REPRO_SMPL_DIR"

LICENCE_SOURCES = {
    "smpl": "https://smpl.is.tue.mpg.de (SMPL; register and accept the licence)",
    "smplh": "https://mano.is.tue.mpg.de (Downloads -> 'Extended SMPL+H model' used in AMASS; "
             "register and accept the licence)",
}

_SPARSE_CLASSES = tuple(
    (mod, cls) for cls, short in (("csc_matrix", "csc"), ("csr_matrix", "csr"),
                                  ("coo_matrix", "coo"))
    for mod in (f"scipy.sparse._{short}", f"scipy.sparse.{short}")
)


def _candidates(kind: str, gender: str, d: Path) -> list[Path]:
    g, G = gender.lower(), gender.upper()
    if kind == "smpl":
        return [d / "smpl" / f"SMPL_{G}.npz", d / "smpl" / f"SMPL_{G}.pkl",
                d / f"SMPL_{G}.npz", d / f"SMPL_{G}.pkl"]
    return [d / "smplh" / g / "model.npz", d / "smplh" / f"SMPLH_{G}.npz",
            d / "smplh" / f"SMPLH_{G}.pkl", d / g / "model.npz"]


def locate_body_model(kind: BodyKind = "smpl", path: str | Path | None = None,
                      gender: str = "neutral") -> Path:
    """The body-model file to use, or :class:`MissingDataError` saying what to put where.

    ``path``: a model file, or a directory laid out as in the module docstring; default
    ``$REPRO_SMPL_DIR``.  ``gender``: ``neutral``, ``male`` or ``female``.
    """
    if kind not in ("smpl", "smplh"):
        raise ValueError(f"unknown body model kind {kind!r} (smpl or smplh)")
    if gender.lower() not in ("neutral", "male", "female"):
        raise ValueError(f"unknown gender {gender!r} (neutral, male or female)")
    label = "SMPL" if kind == "smpl" else "SMPL-H"
    if path is not None and Path(path).expanduser().is_file():
        return Path(path).expanduser()
    if path is not None:
        base, how = Path(path).expanduser(), f"in {Path(path).expanduser()}"
    elif os.environ.get(SMPL_DIR_ENV):
        env = os.environ[SMPL_DIR_ENV]
        base, how = Path(env).expanduser(), f"in ${SMPL_DIR_ENV}={env}"
    else:
        cands = _candidates(kind, gender, Path(f"${SMPL_DIR_ENV}"))
        raise MissingDataError(
            f"{label} body model ({gender}) not found: ${SMPL_DIR_ENV} is not set. Put the "
            f"model at {cands[0]} (or {cands[1]}) and set {SMPL_DIR_ENV} to that folder; the "
            f"model is licensed from {LICENCE_SOURCES[kind]}")
    cands = _candidates(kind, gender, base)
    for c in cands:
        if c.is_file():
            return c
    raise MissingDataError(
        f"{label} body model ({gender}) not found {how}: expected {cands[0]} (or one of "
        f"{', '.join(str(c) for c in cands[1:])}); the model is licensed from "
        f"{LICENCE_SOURCES[kind]}")


def _dense(a, name: str, file) -> np.ndarray:
    if hasattr(a, "toarray"):
        a = a.toarray()
    try:
        return np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError):
        raise DataError(f"body model entry {name!r} is not numeric", file) from None


@dataclass(frozen=True, eq=False)
class BodyModel:
    """An SMPL-family body model (arrays as in the module docstring, float64)."""

    kind: str
    v_template: np.ndarray = field(repr=False)
    shapedirs: np.ndarray = field(repr=False)
    posedirs: np.ndarray = field(repr=False)
    J_regressor: np.ndarray = field(repr=False)
    weights: np.ndarray = field(repr=False)
    parents: tuple[int, ...]
    faces: np.ndarray | None = field(repr=False, default=None)
    source: str = ""

    @property
    def n_joints(self) -> int:
        return len(self.parents)

    @property
    def joint_names(self) -> tuple[str, ...]:
        if self.n_joints == SMPL_24.n_joints and self.parents == SMPL_24.parents:
            return SMPL_24.names
        if self.n_joints == SMPLH_52.n_joints and self.parents == SMPLH_52.parents:
            return SMPLH_52.names
        return tuple(f"joint{j}" for j in range(self.n_joints))

    # -- shape ---------------------------------------------------------------------------
    def shaped_vertices(self, betas=None) -> np.ndarray:
        """Rest-pose vertices (V, 3) for shape ``betas`` (extra coefficients ignored)."""
        v = self.v_template.copy()
        if betas is not None:
            b = np.asarray(betas, dtype=np.float64).reshape(-1)
            n = min(b.shape[0], self.shapedirs.shape[-1])
            v = v + self.shapedirs[..., :n] @ b[:n]
        return v

    def rest_joints(self, betas=None) -> np.ndarray:
        """Rest joints (J, 3) = ``J_regressor · T(β)``, metres."""
        return self.J_regressor @ self.shaped_vertices(betas)

    def skeleton(self, betas=None):
        """A :class:`~repro.motion.skeleton.Skeleton` with the rest offsets of shape ``betas``."""
        from repro.motion.skeleton import Skeleton

        J = self.rest_joints(betas)
        off = np.zeros_like(J)
        for j, p in enumerate(self.parents):
            if p >= 0:
                off[j] = J[j] - J[p]
        return Skeleton(self.joint_names, self.parents, off)

    # -- pose ----------------------------------------------------------------------------
    def _rotmats(self, pose) -> np.ndarray:
        import roma
        import torch

        p = np.asarray(pose, dtype=np.float64)
        T = p.shape[0]
        if p.ndim != 2 or p.shape[1] != 3 * self.n_joints:
            raise ValueError(f"pose must be (T, {3 * self.n_joints}) axis-angle for this "
                             f"{self.n_joints}-joint model, got {p.shape}")
        return roma.rotvec_to_rotmat(torch.from_numpy(p.reshape(T, self.n_joints, 3))).numpy()

    def fk_joints(self, pose, betas=None, trans=None) -> np.ndarray:
        """Posed joints (T, J, 3) by forward kinematics of axis-angle ``pose`` (T, 3J)."""
        from repro.motion.skeleton import forward_kinematics

        R = self._rotmats(pose)
        skel = self.skeleton(betas)
        root = np.broadcast_to(self.rest_joints(betas)[0], (R.shape[0], 3)).copy()
        if trans is not None:
            root = root + np.asarray(trans, dtype=np.float64).reshape(-1, 3)
        return forward_kinematics(skel, R, root)

    def vertices(self, pose, betas=None, trans=None, chunk: int = 64) -> np.ndarray:
        """Skinned vertices (T, V, 3) (linear blend skinning with pose blend shapes)."""
        from repro.motion.skeleton import forward_kinematics, global_rotations

        R_all = self._rotmats(pose)
        T = R_all.shape[0]
        vs = self.shaped_vertices(betas)
        Jr = self.J_regressor @ vs
        skel = self.skeleton(betas)
        tr = (np.zeros((T, 3)) if trans is None
              else np.asarray(trans, dtype=np.float64).reshape(T, 3))
        V = vs.shape[0]
        P = self.posedirs.reshape(V * 3, -1)
        out = np.empty((T, V, 3))
        eye = np.eye(3)
        for s in range(0, T, chunk):
            R = R_all[s:s + chunk]
            n = R.shape[0]
            feat = (R[:, 1:] - eye).reshape(n, -1)
            if feat.shape[1] != P.shape[1]:
                raise DataError(f"posedirs has {P.shape[1]} pose features, the pose gives "
                                f"{feat.shape[1]}", self.source)
            v_posed = vs[None] + (feat @ P.T).reshape(n, V, 3)
            G = np.asarray(global_rotations(skel, R))                      # (n, J, 3, 3)
            g = forward_kinematics(skel, R, np.broadcast_to(Jr[0], (n, 3)).copy())
            t = g - np.einsum("njab,jb->nja", G, Jr)                        # (n, J, 3)
            # Blend the per-joint transforms per vertex (matrix products, BLAS-backed).
            A_R = np.matmul(self.weights[None], G.reshape(n, -1, 9)).reshape(n, V, 3, 3)
            A_t = np.matmul(self.weights[None], t)
            out[s:s + n] = np.einsum("nvab,nvb->nva", A_R, v_posed) + A_t + tr[s:s + n, None]
        return out

    def mesh_joints(self, pose, betas=None, trans=None) -> np.ndarray:
        """Joints (T, J, 3) regressed from the skinned mesh (MultiAct's evaluator joints)."""
        v = self.vertices(pose, betas, trans)
        return np.einsum("jv,tva->tja", self.J_regressor, v)


def load_body_model(path: str | Path, kind: BodyKind | None = None) -> BodyModel:
    """Read an SMPL-family model from ``.npz`` or (chumpy-free) ``.pkl``; errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise MissingDataError("body model file not found", path)
    if path.suffix == ".npz":
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except ValueError as e:
            raise DataError(f"body model .npz needs pickled objects ({e}); re-save it with plain "
                            "numpy arrays", path) from None
        except OSError as e:
            raise DataError(f"not a readable .npz ({e})", path) from None
    elif path.suffix == ".pkl":
        try:
            data = load_restricted(path, extra=_SPARSE_CLASSES)
        except DataError as e:
            if "chumpy" in str(e):
                raise DataError(
                    "this SMPL .pkl stores chumpy objects, which repro does not unpickle; "
                    "convert it once to .npz with the keys v_template, shapedirs, posedirs, "
                    "J_regressor, weights, kintree_table, f (plain numpy arrays) and point "
                    f"{SMPL_DIR_ENV} at the .npz", path) from None
            raise
        if not isinstance(data, dict):
            raise DataError("body model pickle does not hold a dict", path)
    else:
        raise DataError("body model must be a .npz or .pkl file", path)
    missing = [k for k in ("v_template", "shapedirs", "posedirs", "J_regressor", "weights",
                           "kintree_table") if k not in data]
    if missing:
        raise DataError(f"body model lacks {', '.join(missing)}", path)
    v = _dense(data["v_template"], "v_template", path)
    Jreg = _dense(data["J_regressor"], "J_regressor", path)
    W = _dense(data["weights"], "weights", path)
    S = _dense(data["shapedirs"], "shapedirs", path)
    Pd = _dense(data["posedirs"], "posedirs", path)
    kt = np.asarray(data["kintree_table"]).astype(np.int64)
    V = v.shape[0] if v.ndim == 2 else -1
    J = Jreg.shape[0] if Jreg.ndim == 2 else -1
    if v.ndim != 2 or v.shape[1] != 3:
        raise DataError(f"v_template must be (V, 3), got {v.shape}", path)
    if Jreg.shape != (J, V) or W.shape != (V, J):
        raise DataError(f"J_regressor {Jreg.shape} / weights {W.shape} do not match "
                        f"{V} vertices", path)
    if S.ndim != 3 or S.shape[:2] != (V, 3):
        raise DataError(f"shapedirs must be (V, 3, B), got {S.shape}", path)
    if Pd.ndim != 3 or Pd.shape[:2] != (V, 3) or Pd.shape[2] != 9 * (J - 1):
        raise DataError(f"posedirs must be ({V}, 3, {9 * (J - 1)}), got {Pd.shape}", path)
    if kt.ndim != 2 or kt.shape != (2, J):
        raise DataError(f"kintree_table must be (2, {J}), got {kt.shape}", path)
    parents = tuple(int(p) if 0 <= p < J else -1 for p in kt[0])
    if parents[0] != -1 or any(not 0 <= p < j for j, p in enumerate(parents) if j > 0):
        raise DataError("kintree_table is not a tree in topological order with root 0", path)
    if kind is None:
        kind = "smpl" if J == 24 else "smplh"
    faces = np.asarray(data["f"]).astype(np.int64) if "f" in data else None
    return BodyModel(kind=kind, v_template=v, shapedirs=S, posedirs=Pd, J_regressor=Jreg,
                     weights=W, parents=parents, faces=faces, source=str(path))
