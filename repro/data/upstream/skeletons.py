"""Joint sets of the papers' datasets: names, kinematic trees and rest directions.

Topologies are facts of the upstream data (sources named per skeleton); joint *names* and rest
*directions* are ``repro``'s, chosen so that identity rotations give a T-like pose in the Y-up
frame (facing +z, the person's left at +x, as SMPL's rest pose).  Rest directions only fix what
"identity rotation" means for the rotations :mod:`repro.data.upstream.joint_fit` fits; bone
lengths come from the data.

- ``SMPL_24``: SMPL body joints (HumanAct12 ``joints3D``; ACTOR's 24-joint xyz), parents as in
  Action2Motion's ``smpl_tree`` and SMPL's ``kintree_table``.
- ``SMPLH_52``: SMPL-H = the 22 SMPL body joints + 15 per hand (MultiAct's 52-joint evaluator
  input; order Index, Middle, Pinky, Ring, Thumb, left hand then right, as in SMPL-H).
- ``UESTC_18``: the 18 joints ACTOR and ODMO keep from VIBE's 49 (``action2motion_joints`` =
  VIBE indices 8, 1, 2, 3, 4, 5, 6, 7, 0, 9, 10, 11, 12, 13, 14, 21, 24, 38: OpenPose-25
  MidHip, Neck, RShoulder, RElbow, RWrist, LShoulder, LElbow, LWrist, Nose, RHip, RKnee, RAnkle,
  LHip, LKnee, LAnkle, LHeel, RHeel and SPIN's head-top), tree = ODMO's ``uestc_kinematic_chain``.
- ``CMU_20``: Action2Motion's 20-joint CMU MoCap skeleton, tree = A2M/ODMO
  ``mocap_kinematic_chain`` ([0,1,2,3], [0,12,13,14,15], [0,16,17,18,19], [1,4,5,6,7],
  [1,8,9,10,11]).  Which chains are left is *inferred* (CMU's ASF lists left before right and
  A2M's raw offsets point the first arm to +x); A2M does not name its joints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class JointSet:
    """Names, parent indices (-1 for the root) and unit rest directions (J, 3) of a joint set."""

    name: str
    names: tuple[str, ...]
    parents: tuple[int, ...]
    rest_directions: tuple[tuple[float, float, float], ...]

    @property
    def n_joints(self) -> int:
        return len(self.names)

    def directions(self) -> np.ndarray:
        d = np.asarray(self.rest_directions, dtype=np.float64)
        n = np.linalg.norm(d, axis=1, keepdims=True)
        return np.divide(d, n, out=np.zeros_like(d), where=n > 0)

    def index(self, name: str) -> int:
        return self.names.index(name)


_UP, _DOWN, _L, _R = (0, 1, 0), (0, -1, 0), (1, 0, 0), (-1, 0, 0)

SMPL_BODY_NAMES = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
    "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar",
    "right_collar", "head", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
    "left_wrist", "right_wrist",
)
SMPL_BODY_PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19)
_SMPL_BODY_DIRS = (
    (0, 0, 0), (0.55, -0.83, 0), (-0.55, -0.83, 0), _UP, _DOWN, _DOWN, _UP, _DOWN, _DOWN, _UP,
    (0, -0.4, 0.9), (0, -0.4, 0.9), _UP, (0.55, 0.83, 0), (-0.55, 0.83, 0), _UP, _L, _R, _L, _R,
    _L, _R,
)

SMPL_24 = JointSet(
    "smpl24",
    SMPL_BODY_NAMES + ("left_hand", "right_hand"),
    SMPL_BODY_PARENTS + (20, 21),
    _SMPL_BODY_DIRS + (_L, _R),
)

_FINGERS = ("index", "middle", "pinky", "ring", "thumb")


def _hand(side: str, wrist: int, first: int, direction) -> tuple[list, list, list]:
    names, parents, dirs = [], [], []
    j = first
    for finger in _FINGERS:
        for k in (1, 2, 3):
            names.append(f"{side}_{finger}{k}")
            parents.append(wrist if k == 1 else j - 1)
            dirs.append(direction)
            j += 1
    return names, parents, dirs


_lh = _hand("left", 20, 22, _L)
_rh = _hand("right", 21, 37, _R)
SMPLH_52 = JointSet(
    "smplh52",
    SMPL_BODY_NAMES + tuple(_lh[0]) + tuple(_rh[0]),
    SMPL_BODY_PARENTS + tuple(_lh[1]) + tuple(_rh[1]),
    _SMPL_BODY_DIRS + tuple(_lh[2]) + tuple(_rh[2]),
)

#: VIBE (49-joint) indices of the 18 UESTC joints, in order (ACTOR ``action2motion_joints``).
VIBE_TO_UESTC18 = (8, 1, 2, 3, 4, 5, 6, 7, 0, 9, 10, 11, 12, 13, 14, 21, 24, 38)

UESTC_18 = JointSet(
    "uestc18",
    ("mid_hip", "neck", "right_shoulder", "right_elbow", "right_wrist", "left_shoulder",
     "left_elbow", "left_wrist", "nose", "right_hip", "right_knee", "right_ankle", "left_hip",
     "left_knee", "left_ankle", "left_heel", "right_heel", "head_top"),
    (-1, 0, 1, 2, 3, 1, 5, 6, 1, 0, 9, 10, 0, 12, 13, 14, 11, 8),
    ((0, 0, 0), _UP, _R, _R, _R, _L, _L, _L, (0, 0.6, 0.8), _R, _DOWN, _DOWN, _L, _DOWN,
     _DOWN, (0, -0.6, -0.8), (0, -0.6, -0.8), (0, 0.8, -0.6)),
)

CMU_20 = JointSet(
    "cmu20",
    ("root", "spine", "neck", "head", "left_clavicle", "left_shoulder", "left_elbow",
     "left_wrist", "right_clavicle", "right_shoulder", "right_elbow", "right_wrist", "left_hip",
     "left_knee", "left_ankle", "left_toe", "right_hip", "right_knee", "right_ankle",
     "right_toe"),
    (-1, 0, 1, 2, 1, 4, 5, 6, 1, 8, 9, 10, 0, 12, 13, 14, 0, 16, 17, 18),
    ((0, 0, 0), _UP, _UP, _UP, (0.7, 0.7, 0), _L, _L, _L, (-0.7, 0.7, 0), _R, _R, _R,
     (0.5, -0.85, 0), _DOWN, _DOWN, (0, -0.3, 0.95), (-0.5, -0.85, 0), _DOWN, _DOWN,
     (0, -0.3, 0.95)),
)

JOINT_SETS = {s.name: s for s in (SMPL_24, SMPLH_52, UESTC_18, CMU_20)}
