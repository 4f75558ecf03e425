"""What the three adapted baselines (MANN, Action2Motion, ACTOR) share: item checks, the pose
vector, seeded noise and the way generated poses go back to the world.

Neural Marionette (supp. Sec. 4.1) trains every baseline "on the same data" as MarioNet, so all
three read :class:`repro.data.action_items.ActionItems` in each item's Marionette-normalised frame
(the last initial pose ``P₋₁`` at the origin facing +Z, Alg. 1) and return their motions through
the same inverse (Eq. 5), :meth:`ActionItems.to_world`.

**Pose vector** (the one MarioNet uses, supp. Table 2): ``J×6`` local 6D rotations (joint-major,
joint 0's being the root's global rotation) followed by the root translation in metres:
``6J + 3`` numbers per frame.
"""

from __future__ import annotations

import torch

from repro.data.action_items import ActionItems, GeneratedItems, pad_last
from repro.errors import ConfigError, DataError
from repro.motion.motion import Motion
from repro.motion.rotations import matrix_to_6d, sixd_to_matrix
from repro.motion.skeleton import forward_kinematics
from repro.seeding import torch_generator


def pose_dim(n_joints: int) -> int:
    """Length of the pose vector: 6 per joint plus the 3-D root translation."""
    return 6 * n_joints + 3


def pack_poses(motion: Motion) -> torch.Tensor:
    """(B, T, 6J + 3) float32: local 6D rotations (joint-major), then the root translation (m)."""
    B, T = motion.batch_size, motion.n_frames
    return torch.cat([motion.rot6d.reshape(B, T, -1), motion.root], dim=-1).float()


def unpack_poses(poses: torch.Tensor, n_joints: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Inverse of :func:`pack_poses`: (rot6d (..., J, 6), root (..., 3))."""
    return poses[..., :-3].reshape(poses.shape[:-1] + (n_joints, 6)), poses[..., -3:]


def pose_joints(skeleton, poses: torch.Tensor, *, with_root: bool = True) -> torch.Tensor:
    """Joint positions (..., J, 3) in metres of pose vectors (..., 6J + 3) by forward kinematics
    (Gram-Schmidt on the 6D first); ``with_root=False`` leaves the root translation out (joints
    relative to the root, the root's rotation kept)."""
    rot6d, root = unpack_poses(poses, skeleton.n_joints)
    if not with_root:
        root = torch.zeros_like(root)
    return forward_kinematics(skeleton, sixd_to_matrix(rot6d), root)


def length_mask(lengths: torch.Tensor, T: int) -> torch.Tensor:
    """(B, T) bool, True on each item's first ``lengths[b]`` frames."""
    return torch.arange(T, device=lengths.device)[None, :] < lengths[:, None]


def check_matches_model(who: str, items, noun: str, *, skeleton=None, n_joints=None,
                        n_classes=None, fps=None, empty: str | None = None) -> None:
    """The checks every method makes of its training or condition items, in this order, each
    only where its argument is given: the same ``skeleton`` (a DataError naming both
    fingerprints), ``n_joints`` (DataError), ``n_classes`` (ConfigError) and ``fps`` (DataError)
    as the model, then at least one item (DataError ``"{who}: {empty}"``).  ``noun`` names the
    items in the messages (``items``, ``pairs``, ``windows``)."""
    if skeleton is not None and items.skeleton != skeleton:
        raise DataError(f"{who}: {noun} use a different skeleton "
                        f"({items.skeleton.fingerprint()[:12]} vs {skeleton.fingerprint()[:12]})")
    if n_joints is not None and items.n_joints != n_joints:
        raise DataError(f"{who}: {noun} have {items.n_joints} joints, the model {n_joints}")
    if n_classes is not None and items.n_classes != n_classes:
        raise ConfigError(f"{who}: {noun} have {items.n_classes} classes, the model {n_classes}")
    if fps is not None and abs(items.fps - fps) > 1e-6:
        raise DataError(f"{who}: {noun} are at {items.fps} fps, the model at {fps}")
    if empty is not None and len(items) == 0:
        raise DataError(f"{who}: {empty}")


def check_items(gen, items) -> None:
    """``items`` must be non-empty ActionItems on the generator's skeleton, classes and fps."""
    who = gen.method_id
    if not isinstance(items, ActionItems):
        raise TypeError(f"{who} needs repro.data.action_items.ActionItems, got {type(items).__name__}")
    check_matches_model(who, items, "items", skeleton=gen.skeleton, n_classes=gen.n_classes,
                        fps=gen.fps, empty="no items")


def item_noise(seed: int, method_id: str, shape: tuple[int, ...], *labels) -> torch.Tensor:
    """Standard normal noise for sampling, drawn per item in item order from ``seed`` only (so a
    sample does not depend on the sampling batch size); float32."""
    return torch.randn(shape, generator=torch_generator(seed, method_id, "sample", *labels))


def to_generated(gen, items: ActionItems, poses: torch.Tensor) -> GeneratedItems:
    """Raw poses (N, T_max, 6J + 3) in the items' normalised frames → world-frame GeneratedItems:
    6D orthonormalised by Gram-Schmidt, frames past an item's length repeat its last valid
    frame, then the inverse normalisation of each item (Eq. 5: ``P̂ = R_z·P̃ + D``)."""
    rot6d, root = unpack_poses(poses.detach().float(), gen.skeleton.n_joints)
    rot6d, root = pad_last(rot6d, items.lengths), pad_last(root, items.lengths)
    rot6d = matrix_to_6d(sixd_to_matrix(rot6d))
    motion = Motion(root, rot6d, gen.skeleton, gen.fps)
    return GeneratedItems(items.to_world(motion), items.lengths.clone(), items.labels.clone())
