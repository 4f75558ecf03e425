"""Synthetic motions for the upstream-reader tests: joints from FK of known skeletons.

Clips are made by forward kinematics of a joint set's rest directions scaled to plausible bone
lengths, with random (seeded) local rotations near the identity, so they are upright, their
bone lengths are known exactly, and fitted rotations can be checked against them.
"""

from __future__ import annotations

import numpy as np

from repro.data.upstream.axes import to_y_up_matrix
from repro.data.upstream.skeletons import JointSet
from repro.motion.skeleton import Skeleton, forward_kinematics


def skeleton_of(joint_set: JointSet, seed: int = 0) -> Skeleton:
    rng = np.random.default_rng(seed)
    lengths = rng.uniform(0.08, 0.35, size=joint_set.n_joints)
    off = joint_set.directions() * lengths[:, None]
    off[0] = 0.0
    return Skeleton(joint_set.names, joint_set.parents, off)


def random_rotmats(rng: np.random.Generator, shape: tuple, scale: float) -> np.ndarray:
    import roma
    import torch

    rv = rng.normal(scale=scale, size=shape + (3,))
    return roma.rotvec_to_rotmat(torch.from_numpy(rv)).numpy()


def fk_clip(skel: Skeleton, T: int, rng: np.random.Generator, scale: float = 0.3) -> np.ndarray:
    """(T, J, 3) Y-up joints: random rotations near identity, root walking near 0.9 m height."""
    R = random_rotmats(rng, (T, skel.n_joints), scale)
    root = np.cumsum(rng.normal(scale=0.01, size=(T, 3)), axis=0) + np.array([0.0, 0.9, 0.0])
    return forward_kinematics(skel, R, root)


def from_y_up(points: np.ndarray, up: str) -> np.ndarray:
    """Inverse of :func:`repro.data.upstream.axes.to_y_up` (to write source-convention files)."""
    return np.asarray(points) @ to_y_up_matrix(up)


def body_model_arrays(joint_set: JointSet, seed: int = 0, n_betas: int = 10,
                      pose_blend: float = 0.01, rigid: bool = False) -> dict:
    """A tiny SMPL-family model in SMPL's own key names and shapes (3 vertices per joint).

    Vertex 3j sits on joint j and vertices 3j+1, 3j+2 symmetrically around it, so the regressor
    (0.5, 0.25, 0.25) returns the joint exactly.  ``rigid``: each vertex skinned to its own joint
    only and no pose blend shapes (then mesh-regressed joints equal FK joints exactly).
    """
    rng = np.random.default_rng(seed)
    skel = skeleton_of(joint_set, seed=seed)
    J = joint_set.n_joints
    Jrest = forward_kinematics(skel, np.broadcast_to(np.eye(3), (J, 3, 3)).copy(), np.zeros(3))
    V = 3 * J
    d = rng.normal(scale=0.02, size=(J, 3))
    v = np.empty((V, 3))
    v[0::3], v[1::3], v[2::3] = Jrest, Jrest + d, Jrest - d
    Jreg = np.zeros((J, V))
    for j in range(J):
        Jreg[j, 3 * j], Jreg[j, 3 * j + 1], Jreg[j, 3 * j + 2] = 0.5, 0.25, 0.25
    W = np.zeros((V, J))
    for j, p in enumerate(joint_set.parents):
        for k in range(3):
            if rigid or p < 0:
                W[3 * j + k, j] = 1.0
            else:
                W[3 * j + k, j], W[3 * j + k, p] = 0.8, 0.2
    shapedirs = rng.normal(scale=0.01, size=(V, 3, n_betas))
    posedirs = (np.zeros((V, 3, 9 * (J - 1))) if rigid
                else rng.normal(scale=pose_blend, size=(V, 3, 9 * (J - 1))))
    kintree = np.stack([np.array([p if p >= 0 else 4294967295 for p in joint_set.parents],
                                 dtype=np.int64), np.arange(J)])
    faces = np.arange(V).reshape(-1, 3)
    return {"v_template": v, "shapedirs": shapedirs, "posedirs": posedirs, "J_regressor": Jreg,
            "weights": W, "kintree_table": kintree, "f": faces}
