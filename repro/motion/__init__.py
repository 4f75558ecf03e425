"""Motion layer: skeletons, forward kinematics, rotations, canonicalisations, resampling."""

from repro.motion.skeleton import Skeleton, forward_kinematics

__all__ = ["Skeleton", "forward_kinematics", "Motion"]


def __getattr__(name: str):
    # Lazy: `Motion` pulls in torch and roma, which `repro --help` must not pay for.
    if name == "Motion":
        from repro.motion.motion import Motion

        return Motion
    raise AttributeError(f"module 'repro.motion' has no attribute {name!r}")
