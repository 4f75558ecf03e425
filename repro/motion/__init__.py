"""Motion layer: skeletons, forward kinematics, rotations, canonicalisations, resampling."""

from repro.lazy_exports import lazy_getattr
from repro.motion.skeleton import Skeleton, forward_kinematics

__all__ = ["Skeleton", "forward_kinematics", "Motion"]

# Lazy: `Motion` pulls in torch and roma, which `repro --help` must not pay for.
__getattr__ = lazy_getattr(__name__, {"Motion": "motion"})
