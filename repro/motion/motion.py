"""``Motion``: a batch of equally long motions as torch tensors (what models and metrics pass).

- ``root``  (B, T, 3)    root translation, metres, Y up (world frame);
- ``rot6d`` (B, T, J, 6) local joint rotations in 6D (Zhou et al. 2019; first two matrix
  columns, see :mod:`repro.motion.rotations`), joint 0's being its global rotation;
- ``skeleton``, ``fps`` (frames per second).

Joint positions are derived on demand with the differentiable forward kinematics of
:mod:`repro.motion.skeleton`.  Conversions to and from :class:`repro.data.clipset.ClipSet`
(packed ``xyzw`` quaternions, float32) live here too.
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from repro.keys import content_key
from repro.motion.rotations import matrix_to_6d, matrix_to_quat, quat_to_6d, sixd_to_matrix
from repro.motion.skeleton import Skeleton, forward_kinematics, global_rotations

__all__ = ["Motion"]


@dataclass(frozen=True, eq=False)
class Motion:
    root: torch.Tensor
    rot6d: torch.Tensor
    skeleton: Skeleton
    fps: float

    def __post_init__(self) -> None:
        import torch

        root = torch.as_tensor(self.root)
        rot6d = torch.as_tensor(self.rot6d)
        J = self.skeleton.n_joints
        if root.dim() != 3 or root.shape[-1] != 3:
            raise ValueError(f"Motion.root must be (B, T, 3), got {tuple(root.shape)}")
        if rot6d.shape != root.shape[:2] + (J, 6):
            raise ValueError(f"Motion.rot6d must be (B, T, {J}, 6) to match root "
                             f"{tuple(root.shape)}, got {tuple(rot6d.shape)}")
        if not (root.is_floating_point() and rot6d.is_floating_point()):
            raise ValueError("Motion tensors must be floating point")
        if root.dtype != rot6d.dtype:
            rot6d = rot6d.to(root.dtype)
        fps = float(self.fps)
        if not fps > 0:
            raise ValueError(f"Motion.fps must be positive, got {self.fps!r}")
        object.__setattr__(self, "root", root)
        object.__setattr__(self, "rot6d", rot6d)
        object.__setattr__(self, "fps", fps)

    # --- shape ---------------------------------------------------------------------------
    @property
    def batch_size(self) -> int:
        return int(self.root.shape[0])

    @property
    def n_frames(self) -> int:
        return int(self.root.shape[1])

    @property
    def n_joints(self) -> int:
        return self.skeleton.n_joints

    @property
    def duration(self) -> float:
        """Seconds spanned from the first to the last frame."""
        return (self.n_frames - 1) / self.fps

    @property
    def dtype(self) -> torch.dtype:
        return self.root.dtype

    # --- construction --------------------------------------------------------------------
    @classmethod
    def from_rotmats(cls, root, rotmats, skeleton: Skeleton, fps: float) -> "Motion":
        """From local rotation matrices (B, T, J, 3, 3)."""
        import torch

        return cls(torch.as_tensor(root), matrix_to_6d(torch.as_tensor(rotmats)), skeleton, fps)

    @classmethod
    def from_quaternions(cls, root, quats, skeleton: Skeleton, fps: float) -> "Motion":
        """From local ``xyzw`` quaternions (B, T, J, 4)."""
        import torch

        return cls(torch.as_tensor(root), quat_to_6d(torch.as_tensor(quats)), skeleton, fps)

    def replace(self, **changes) -> "Motion":
        return dataclasses.replace(self, **changes)

    # --- derived quantities --------------------------------------------------------------
    def rotmats(self) -> torch.Tensor:
        """Local rotation matrices (B, T, J, 3, 3) (Gram-Schmidt of the 6D)."""
        return sixd_to_matrix(self.rot6d)

    def quaternions(self) -> torch.Tensor:
        """Local ``xyzw`` quaternions (B, T, J, 4)."""
        return matrix_to_quat(self.rotmats())

    def global_rotmats(self) -> torch.Tensor:
        """World rotation matrices (B, T, J, 3, 3)."""
        return global_rotations(self.skeleton, self.rotmats())

    def joints(self) -> torch.Tensor:
        """World joint positions (B, T, J, 3), metres (forward kinematics; differentiable)."""
        return forward_kinematics(self.skeleton, self.rotmats(), self.root)

    # --- slicing -------------------------------------------------------------------------
    def slice_time(self, start: int | None = None, stop: int | None = None,
                   step: int | None = None) -> "Motion":
        """Frames ``start:stop:step`` (a ``step`` > 1 divides the frame rate)."""
        sl = slice(start, stop, step)
        fps = self.fps / (step or 1)
        return Motion(self.root[:, sl], self.rot6d[:, sl], self.skeleton, fps)

    def select(self, index) -> "Motion":
        """A sub-batch (``index``: int, slice, sequence or tensor of batch indices)."""
        if isinstance(index, int):
            index = [index]
        return Motion(self.root[index], self.rot6d[index], self.skeleton, self.fps)

    def to(self, device=None, dtype: torch.dtype | None = None) -> "Motion":
        return Motion(self.root.to(device=device, dtype=dtype),
                      self.rot6d.to(device=device, dtype=dtype), self.skeleton, self.fps)

    def detach(self) -> "Motion":
        return Motion(self.root.detach(), self.rot6d.detach(), self.skeleton, self.fps)

    @staticmethod
    def _cat(motions: Sequence["Motion"], dim: int, same: str, what: str) -> "Motion":
        """Concatenate along ``dim``; every motion's skeleton, fps and ``same`` (an attribute)
        must be the first's, else a ValueError ``{what}``."""
        import torch

        first = motions[0]
        for m in motions[1:]:
            if m.skeleton != first.skeleton or m.fps != first.fps \
                    or getattr(m, same) != getattr(first, same):
                raise ValueError(what)
        return Motion(torch.cat([m.root for m in motions], dim),
                      torch.cat([m.rot6d for m in motions], dim), first.skeleton, first.fps)

    @staticmethod
    def cat_time(motions: Sequence["Motion"]) -> "Motion":
        """Concatenate along time (same batch size, skeleton and fps)."""
        return Motion._cat(motions, 1, "batch_size",
                           "cat_time needs the same skeleton, fps and batch size")

    @staticmethod
    def cat_batch(motions: Sequence["Motion"]) -> "Motion":
        """Concatenate along the batch (same length, skeleton and fps)."""
        return Motion._cat(motions, 0, "n_frames", "cat_batch needs the same skeleton, fps and length")

    # --- ClipSet bridge ------------------------------------------------------------------
    @classmethod
    def from_clipset(cls, clipset, indices: Sequence[int], start: int | Sequence[int] = 0,
                     length: int | None = None, *, pad: bool = False,
                     dtype: torch.dtype | None = None) -> "Motion":
        """Frames ``start : start + length`` of clips ``indices`` of a ClipSet, as one batch.

        ``start``: one frame index for all clips or one per clip.  ``length=None``: to each
        clip's end (all must then give the same length).  ``pad=True`` repeats a clip's last
        frame past its end (ODMO/Action2Motion padding); otherwise running past the end is an
        error.  ``dtype``: None is float32.
        """
        import torch

        dtype = torch.float32 if dtype is None else dtype
        idx = np.asarray(indices, dtype=np.int64).reshape(-1)
        if idx.size == 0:
            raise ValueError("from_clipset needs at least one clip index")
        starts = np.broadcast_to(np.asarray(start, dtype=np.int64), idx.shape)
        lens = clipset.lengths[idx].astype(np.int64)
        if np.any(starts < 0) or np.any(starts >= lens):
            bad = int(np.flatnonzero((starts < 0) | (starts >= lens))[0])
            raise ValueError(f"clip {clipset.clip_names[idx[bad]]!r}: start {starts[bad]} outside "
                             f"its {lens[bad]} frames")
        if length is None:
            rest = lens - starts
            if np.any(rest != rest[0]):
                raise ValueError("clips differ in remaining length; pass length=")
            length = int(rest[0])
        if length < 1:
            raise ValueError("length must be at least 1")
        offs = np.arange(length, dtype=np.int64)
        local = starts[:, None] + offs[None, :]
        over = local >= lens[:, None]
        if over.any() and not pad:
            bad = int(np.flatnonzero(over.any(1))[0])
            raise ValueError(f"clip {clipset.clip_names[idx[bad]]!r}: frames {starts[bad]}.."
                             f"{starts[bad] + length - 1} run past its {lens[bad]} frames "
                             "(pass pad=True to repeat the last frame)")
        local = np.minimum(local, lens[:, None] - 1)
        rows = clipset.starts[idx].astype(np.int64)[:, None] + local
        quats = torch.from_numpy(np.ascontiguousarray(clipset.rotations[rows])).to(dtype)
        root = torch.from_numpy(np.ascontiguousarray(clipset.root[rows])).to(dtype)
        return cls(root, quat_to_6d(quats), clipset.skeleton, clipset.fps)

    def to_clip_arrays(self, lengths: Sequence[int] | None = None) -> dict[str, np.ndarray]:
        """Packed ClipSet arrays (float32 ``rotations`` xyzw, ``root``, ``joints``; int64
        ``starts``, ``lengths``); ``lengths`` trims each motion to its valid frames."""
        import torch

        T = self.n_frames
        lens = np.full(self.batch_size, T, dtype=np.int64) if lengths is None else \
            np.asarray(lengths, dtype=np.int64).reshape(self.batch_size)
        if np.any(lens < 1) or np.any(lens > T):
            raise ValueError(f"lengths must lie in 1..{T}")
        with torch.no_grad():
            q = self.quaternions().detach().cpu().to(torch.float32).numpy()
            root = self.root.detach().cpu().to(torch.float32).numpy()
            joints = self.joints().detach().cpu().to(torch.float32).numpy()
        keep = np.arange(T)[None, :] < lens[:, None]
        return {
            "rotations": np.ascontiguousarray(q[keep]),
            "root": np.ascontiguousarray(root[keep]),
            "joints": np.ascontiguousarray(joints[keep]),
            "starts": np.concatenate([[0], np.cumsum(lens)[:-1]]).astype(np.int64),
            "lengths": lens,
        }

    def to_clipset(self, name: str, labels: Sequence[int], label_names: Sequence[str], *,
                   lengths: Sequence[int] | None = None, styles: Sequence[int] | None = None,
                   style_names: Sequence[str] = (), clip_names: Sequence[str] | None = None,
                   split: Sequence[int] | None = None, fingerprint: str | None = None):
        """A :class:`~repro.data.clipset.ClipSet` holding these motions (generated samples,
        windows).  ``split`` defaults to all TEST; ``fingerprint`` to a hash of the content."""
        from repro.data.clipset import TEST, ClipSet

        B = self.batch_size
        arr = self.to_clip_arrays(lengths)
        labels = np.asarray(labels, dtype=np.int64).reshape(B)
        styles = np.full(B, -1, np.int64) if styles is None else np.asarray(styles, np.int64).reshape(B)
        split = np.full(B, TEST, np.int8) if split is None else np.asarray(split, np.int8).reshape(B)
        names = tuple(clip_names) if clip_names is not None else tuple(f"{name}_{i:05d}" for i in range(B))
        if fingerprint is None:
            h = hashlib.sha256()
            for k in ("rotations", "root", "lengths"):
                h.update(arr[k].tobytes())
            h.update(labels.tobytes())
            h.update(styles.tobytes())
            fingerprint = content_key({"arrays": h.hexdigest(), "fps": self.fps,
                                       "skeleton": self.skeleton.fingerprint()})
        return ClipSet(name=name, skeleton=self.skeleton, fps=self.fps, labels=labels,
                       label_names=tuple(label_names), styles=styles, style_names=tuple(style_names),
                       clip_names=names, split=split, fingerprint=fingerprint, **arr)
