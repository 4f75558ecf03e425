"""Kinematic trees and batched, differentiable forward kinematics (torch).

Conventions (DESIGN.md): Y up, metres.  Rotation matrices act on column vectors and compose
``world = parent · local``.  A joint's rest offset is expressed in its parent's frame.  The
root's position is the root translation (its offset is ignored), as in BVH files whose root
position channels replace the root OFFSET.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from repro.keys import content_key


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A kinematic tree in topological order (every parent index precedes its child).

    ``names``: joint names; ``parents``: parent index per joint, ``-1`` for the single root;
    ``offsets``: (J, 3) rest offsets from the parent, metres, in the parent's frame.
    ``hips``, ``up_joint``: optional names of the (left, right) hip joints and of a joint above
    the pelvis, for :func:`repro.motion.heading.body_frame` when the names are not ones it
    knows (a data-set spec's ``[skeleton] hips``: CMU's ``lhipjoint`` / ``rhipjoint`` both start
    at the root, so its hips are ``lfemur`` / ``rfemur``).  Stored and keyed only when set.
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray = field(repr=False)
    hips: tuple[str, str] | None = None
    up_joint: str | None = None

    def __post_init__(self) -> None:
        names = tuple(str(n) for n in self.names)
        parents = tuple(int(p) for p in self.parents)
        offsets = np.asarray(self.offsets, dtype=np.float64).reshape(len(names), 3).copy()
        offsets.setflags(write=False)
        if len(parents) != len(names):
            raise ValueError("names and parents differ in length")
        if not names:
            raise ValueError("a skeleton needs at least one joint")
        if parents[0] != -1 or any(p == -1 for p in parents[1:]):
            raise ValueError("joint 0 must be the only root (parent -1)")
        for j, p in enumerate(parents[1:], start=1):
            if not 0 <= p < j:
                raise ValueError(f"joint {names[j]!r}: parent index {p} must precede it")
        if len(set(names)) != len(names):
            raise ValueError("joint names must be unique")
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "parents", parents)
        object.__setattr__(self, "offsets", offsets)
        if self.hips is not None:
            object.__setattr__(self, "hips", tuple(str(n) for n in self.hips))
        for n in (*(self.hips or ()), *((self.up_joint,) if self.up_joint else ())):
            if n not in names:
                raise ValueError(f"body joint {n!r} is not a joint of the skeleton")

    @property
    def n_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no joint named {name!r}") from None

    def children(self, j: int) -> list[int]:
        return [c for c, p in enumerate(self.parents) if p == j]

    def subset(self, keep: Sequence[str]) -> "Skeleton":
        """The skeleton restricted to ``keep`` (each kept joint's nearest kept ancestor becomes
        its parent; offsets are composed only when the dropped joints carry no rotation, so use
        this for display/evaluation joint sets, not for FK of rotated chains)."""
        keep_idx = [self.index(n) for n in keep]
        pos = {j: i for i, j in enumerate(keep_idx)}
        parents, offsets = [], []
        for j in keep_idx:
            off = self.offsets[j].copy()
            p = self.parents[j]
            while p != -1 and p not in pos:
                off = off + self.offsets[p]
                p = self.parents[p]
            parents.append(-1 if p == -1 else pos[p])
            offsets.append(off)
        hips = self.hips if self.hips and set(self.hips) <= set(keep) else None
        up = self.up_joint if self.up_joint in keep else None
        return Skeleton(tuple(keep), tuple(parents), np.array(offsets), hips, up)

    def _body(self) -> dict:
        """The named body joints, only those set (absent from older files and keys)."""
        out = {}
        if self.hips is not None:
            out["hips"] = list(self.hips)
        if self.up_joint is not None:
            out["up_joint"] = self.up_joint
        return out

    def to_dict(self) -> dict:
        return {"names": list(self.names), "parents": list(self.parents),
                "offsets": self.offsets.tolist(), **self._body()}

    @classmethod
    def from_dict(cls, d: dict) -> "Skeleton":
        hips = d.get("hips")
        return cls(tuple(d["names"]), tuple(d["parents"]), np.asarray(d["offsets"], dtype=np.float64),
                   None if hips is None else tuple(hips), d.get("up_joint"))

    def fingerprint(self) -> str:
        """Content key of the tree (names, parents, offsets rounded to 1e-9 m; named body
        joints when set)."""
        return content_key({"names": self.names, "parents": self.parents,
                            "offsets": np.round(self.offsets, 9), **self._body()})

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, Skeleton) and self.names == other.names
                and self.parents == other.parents and np.array_equal(self.offsets, other.offsets)
                and self.hips == other.hips and self.up_joint == other.up_joint)

    def __hash__(self) -> int:
        return hash((self.names, self.parents))


def forward_kinematics(skeleton: Skeleton, rotations, root_translation, offsets=None):
    """Joint positions from local rotations and root translation; batched and differentiable.

    ``rotations``: (..., J, 3, 3) local rotation matrices; ``root_translation``: (..., 3);
    ``offsets``: optional (..., J, 3) per-frame offsets replacing the rest offsets (BVH position
    channels on non-root joints).  Returns (..., J, 3) world positions in the units of the
    offsets and translation.  Accepts torch tensors (gradients flow) or numpy arrays (returns
    numpy).
    """
    import torch

    as_numpy = isinstance(rotations, np.ndarray)
    R = torch.as_tensor(rotations)
    dtype = R.dtype if R.is_floating_point() else torch.float64
    R = R.to(dtype)
    t = torch.as_tensor(root_translation, dtype=dtype, device=R.device)
    J = skeleton.n_joints
    if R.shape[-3:] != (J, 3, 3):
        raise ValueError(f"rotations must end in ({J}, 3, 3), got {tuple(R.shape)}")
    if offsets is None:
        off = torch.tensor(skeleton.offsets, dtype=dtype, device=R.device)
    else:
        off = torch.as_tensor(offsets, dtype=dtype, device=R.device)
    off = off.expand(R.shape[:-1])
    glob_R: list = [None] * J
    glob_p: list = [None] * J
    local = R.unbind(-3)  # one view per joint; backward stacks their gradients once
    offs = off.unbind(-2)
    for j, p in enumerate(skeleton.parents):
        Rj = local[j]
        if p < 0:
            glob_R[j] = Rj
            glob_p[j] = t
        else:
            glob_R[j] = glob_R[p] @ Rj
            glob_p[j] = glob_p[p] + (glob_R[p] @ offs[j].unsqueeze(-1)).squeeze(-1)
    pos = torch.stack(glob_p, dim=-2)
    return pos.numpy() if as_numpy else pos


def global_rotations(skeleton: Skeleton, rotations):
    """World rotation matrices (..., J, 3, 3) from local ones (same conventions as FK)."""
    import torch

    R = torch.as_tensor(rotations)
    out: list = [None] * skeleton.n_joints
    for j, p in enumerate(skeleton.parents):
        out[j] = R[..., j, :, :] if p < 0 else out[p] @ R[..., j, :, :]
    return torch.stack(out, dim=-3)
