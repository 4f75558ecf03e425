"""``ClipSet``: a labelled set of motion clips in one packed, memory-friendly layout.

All clips share one :class:`~repro.motion.Skeleton` and one frame rate.  Frames of every clip
are concatenated; clip ``i`` occupies rows ``starts[i] : starts[i] + lengths[i]``.

Arrays (float32 unless stated):

- ``rotations``   (F, J, 4)  local joint rotations as unit quaternions, roma's ``xyzw`` order;
- ``root``        (F, 3)     root (pelvis) translation, metres, Y up;
- ``joints``      (F, J, 3)  world joint positions from forward kinematics, metres;
- ``labels``      (N,) int64 action class per clip; ``styles`` (N,) int64 style (``-1``: none);
- ``split``       (N,) int8  0 = train, 1 = test (deterministic; see ``repro.data.splits``).

``fingerprint`` identifies the content (source fingerprint + preparation code version); it
enters every downstream cache key.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from repro.motion.skeleton import Skeleton

TRAIN, TEST = 0, 1


@dataclass(frozen=True, eq=False)
class ClipSet:
    name: str
    skeleton: Skeleton
    fps: float
    rotations: np.ndarray = field(repr=False)
    root: np.ndarray = field(repr=False)
    joints: np.ndarray = field(repr=False)
    starts: np.ndarray = field(repr=False)
    lengths: np.ndarray = field(repr=False)
    labels: np.ndarray = field(repr=False)
    label_names: tuple[str, ...]
    styles: np.ndarray = field(repr=False)
    style_names: tuple[str, ...]
    clip_names: tuple[str, ...] = field(repr=False)
    split: np.ndarray = field(repr=False)
    fingerprint: str

    def __len__(self) -> int:
        return int(self.lengths.shape[0])

    @property
    def n_frames(self) -> int:
        return int(self.lengths.sum())

    @property
    def n_classes(self) -> int:
        return len(self.label_names)

    def _rows(self, i: int) -> slice:
        s = int(self.starts[i])
        return slice(s, s + int(self.lengths[i]))

    def clip_rotations(self, i: int) -> np.ndarray:
        """(T, J, 4) xyzw quaternions of clip ``i``."""
        return self.rotations[self._rows(i)]

    def clip_root(self, i: int) -> np.ndarray:
        """(T, 3) root translation of clip ``i`` (metres)."""
        return self.root[self._rows(i)]

    def clip_joints(self, i: int) -> np.ndarray:
        """(T, J, 3) joint positions of clip ``i`` (metres)."""
        return self.joints[self._rows(i)]

    def indices(self, split: int | None = None, label: int | None = None) -> np.ndarray:
        """Clip indices, optionally restricted to a split (TRAIN/TEST) and/or a label."""
        m = np.ones(len(self), dtype=bool)
        if split is not None:
            m &= self.split == split
        if label is not None:
            m &= self.labels == label
        return np.flatnonzero(m)
