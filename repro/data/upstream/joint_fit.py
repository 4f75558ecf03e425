"""From joint positions to a :class:`~repro.data.clipset.ClipSet`: bone lengths + fitted rotations.

HumanAct12, UESTC and CMU MoCap (as Action2Motion and ODMO use them) are *joint positions*
only.  A ClipSet also holds local rotations, so this module fits them:

1. **Skeleton** (:func:`skeleton_from_joints`): each bone's length is the median, over every
   frame of every clip, of the distance between the joint and its parent (metres); its rest
   offset is that length times the joint set's unit rest direction
   (:mod:`repro.data.upstream.skeletons`).
2. **Rotations** (:func:`fit_local_rotations`), joint by joint from the root, per frame.  With
   ``G_p`` the parent's fitted global rotation, ``o_c`` a child's rest offset and
   ``u_c = G_pᵀ (x_c − x_j)`` the observed bone expressed in the parent's frame, the local
   rotation ``L_j`` is
   - the identity for a leaf;
   - the shortest-arc rotation taking ``o_c`` to ``u_c`` for one child (its twist about the
     bone, which positions cannot determine, is thereby the parent's);
   - the least-squares rotation ``argmin_R Σ_c ‖R o_c − u_c‖²`` (Wahba's problem, solved as the
     closest rotation to ``Σ_c u_c o_cᵀ`` with :func:`roma.special_procrustes`) for several.
   Then ``G_j = G_p L_j``.  The root's translation is its observed position.

Forward kinematics of the fitted rotations reproduces every bone *direction* of single-child
joints exactly and of branching joints in the least-squares sense; positions differ from the
data only by each clip's bone lengths differing from the dataset medians (subjects differ).
The ClipSet therefore stores the **data's joint positions** in ``joints`` (what the papers'
evaluators consume) and the fitted rotations in ``rotations``; :func:`fk_residual` measures
the gap between them.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from repro.errors import DataError
from repro.keys import content_key
from repro.motion.skeleton import Skeleton, forward_kinematics

from .skeletons import JointSet

#: Frames fitted per batch (bounds memory on UESTC-sized sets).
FIT_CHUNK = 65536


def skeleton_from_joints(joint_set: JointSet, clips: Sequence[np.ndarray]) -> Skeleton:
    """A :class:`Skeleton` of ``joint_set`` whose bone lengths are the data's median lengths.

    ``clips``: arrays (T_i, J, 3) in metres, Y up.  A bone of median length 0 (coincident joints)
    keeps offset 0.
    """
    if not clips:
        raise ValueError("no clips to measure bones on")
    J = joint_set.n_joints
    parents = np.asarray(joint_set.parents)
    lengths = []
    for c in clips:
        c = np.asarray(c, dtype=np.float64)
        if c.ndim != 3 or c.shape[1:] != (J, 3):
            raise ValueError(f"clip shape {c.shape} does not fit the {joint_set.name} joint set "
                             f"(T, {J}, 3)")
        d = c[:, 1:] - c[:, parents[1:]]
        lengths.append(np.linalg.norm(d, axis=-1))
    med = np.median(np.concatenate(lengths, axis=0), axis=0)
    offsets = np.zeros((J, 3))
    offsets[1:] = joint_set.directions()[1:] * med[:, None]
    return Skeleton(joint_set.names, joint_set.parents, offsets)


def _shortest_arc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched rotation matrices (N, 3, 3) taking direction a (3,) to directions b (N, 3)."""
    N = b.shape[0]
    out = np.broadcast_to(np.eye(3), (N, 3, 3)).copy()
    na = np.linalg.norm(a)
    nb = np.linalg.norm(b, axis=1)
    ok = (nb > 1e-12) & (na > 1e-12)
    if not ok.any():
        return out
    ua = a / na
    ub = b[ok] / nb[ok, None]
    v = np.cross(np.broadcast_to(ua, ub.shape), ub)
    c = ub @ ua
    K = np.zeros((ub.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2] = -v[:, 2], v[:, 1]
    K[:, 1, 0], K[:, 1, 2] = v[:, 2], -v[:, 0]
    K[:, 2, 0], K[:, 2, 1] = -v[:, 1], v[:, 0]
    R = np.eye(3) + K
    anti = c < -1.0 + 1e-9
    denom = np.where(anti, 1.0, 1.0 + c)
    R = R + (K @ K) / denom[:, None, None]
    if anti.any():
        # Half turn about an axis perpendicular to a.
        e = np.eye(3)[int(np.argmin(np.abs(ua)))]
        n = np.cross(ua, e)
        n /= np.linalg.norm(n)
        R[anti] = 2.0 * np.outer(n, n) - np.eye(3)
    out[ok] = R
    return out


def _procrustes(M: np.ndarray) -> np.ndarray:
    import roma
    import torch

    return roma.special_procrustes(torch.from_numpy(M)).numpy()


def fit_local_rotations(skeleton: Skeleton, joints: np.ndarray) -> np.ndarray:
    """Local rotation matrices (F, J, 3, 3) fitted to joint positions (F, J, 3) (module doc)."""
    P = np.asarray(joints, dtype=np.float64)
    J = skeleton.n_joints
    if P.ndim != 3 or P.shape[1:] != (J, 3):
        raise ValueError(f"joints must be (F, {J}, 3), got {P.shape}")
    out = np.empty(P.shape[:2] + (3, 3))
    for s in range(0, P.shape[0], FIT_CHUNK):
        out[s:s + FIT_CHUNK] = _fit_chunk(skeleton, P[s:s + FIT_CHUNK])
    return out


def _fit_chunk(skeleton: Skeleton, P: np.ndarray) -> np.ndarray:
    F, J = P.shape[:2]
    children = [skeleton.children(j) for j in range(J)]
    off = skeleton.offsets
    L = np.empty((F, J, 3, 3))
    G = np.empty((F, J, 3, 3))
    eye = np.broadcast_to(np.eye(3), (F, 3, 3))
    for j, p in enumerate(skeleton.parents):
        Gp = eye if p < 0 else G[:, p]
        kids = children[j]
        if not kids:
            Lj = eye.copy()
        else:
            u = np.stack([P[:, c] - P[:, j] for c in kids], axis=1)          # (F, C, 3) world
            u = np.einsum("fji,fcj->fci", Gp, u)                              # parent frame
            if len(kids) == 1:
                Lj = _shortest_arc(off[kids[0]], u[:, 0])
            else:
                M = np.einsum("fci,cj->fij", u, off[kids])
                Lj = _procrustes(M)
        L[:, j] = Lj
        G[:, j] = Gp @ Lj
    return L


def fk_residual(skeleton: Skeleton, rotations: np.ndarray, joints: np.ndarray) -> float:
    """Mean distance (metres) between FK of fitted rotations (root at the data's root) and data."""
    P = np.asarray(joints, dtype=np.float64)
    pos = forward_kinematics(skeleton, np.asarray(rotations, dtype=np.float64), P[:, 0])
    return float(np.linalg.norm(pos - P, axis=-1).mean())


def check_upright(clips: Sequence[np.ndarray], joint_set: JointSet, top: str, bottom: str,
                  file, up_option: str) -> None:
    """Refuse data that is upside down after axis conversion (a wrong up-axis assumption).

    Over all frames, ``top`` (a head joint) must be above ``bottom`` (the pelvis) along +y in
    the majority of frames; otherwise :class:`DataError` names the file and the option to change.
    """
    t, b = joint_set.index(top), joint_set.index(bottom)
    above = total = 0
    for c in clips:
        above += int(np.count_nonzero(c[:, t, 1] > c[:, b, 1]))
        total += c.shape[0]
    if total and above < 0.5 * total:
        raise DataError(
            f"after converting with up-axis {up_option!r}, the {top} is below the {bottom} in "
            f"{100.0 * (total - above) / total:.0f}% of frames: the file's up-axis is not "
            f"{up_option!r}; pass the right one (up='+y', '-y' or '+z')", file)


def build_clipset(*, name: str, joint_set: JointSet, fps: float, clips: Sequence[np.ndarray],
                  labels: Sequence[int], label_names: Sequence[str], clip_names: Sequence[str],
                  split: Sequence[int], source_fingerprint: str, options: dict):
    """A ClipSet from joint clips (Y up, metres): median-length skeleton + fitted rotations.

    ``fingerprint`` = content key of the source fingerprint, the joint set, fps and ``options``
    (every reader choice that changes the arrays).
    """
    import roma
    import torch

    from repro.data.clipset import ClipSet

    if not clips:
        raise ValueError(f"{name}: no clips")
    skel = skeleton_from_joints(joint_set, clips)
    lengths = np.array([c.shape[0] for c in clips], dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    P = np.concatenate([np.asarray(c, dtype=np.float64) for c in clips], axis=0)
    R = fit_local_rotations(skel, P)
    quats = roma.rotmat_to_unitquat(torch.from_numpy(R)).numpy().astype(np.float32)
    fp = content_key({"source": source_fingerprint, "joint_set": joint_set.name,
                      "fps": float(fps), "options": options, "reader": "upstream-joints-v1"})
    return ClipSet(
        name=name, skeleton=skel, fps=float(fps), rotations=quats,
        root=P[:, 0].astype(np.float32), joints=P.astype(np.float32), starts=starts,
        lengths=lengths, labels=np.asarray(labels, dtype=np.int64),
        label_names=tuple(label_names), styles=np.full(len(clips), -1, dtype=np.int64),
        style_names=(), clip_names=tuple(clip_names),
        split=np.asarray(split, dtype=np.int8), fingerprint=fp,
    )
