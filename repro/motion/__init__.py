"""Motion layer: skeletons, forward kinematics, rotations, canonicalisations, resampling."""

from repro.motion.skeleton import Skeleton, forward_kinematics

__all__ = ["Skeleton", "forward_kinematics"]
