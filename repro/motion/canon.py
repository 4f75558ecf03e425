"""Canonicalisations of motions, each with an exact inverse.

Every canonicalisation is one rigid map per batch item, applied to all frames:

    p_canonical = G · (p − o)          (positions: root translation and, by FK, every joint)
    R_root,canonical = G · R_root      (joint 0's rotation, i.e. its global rotation)

with a world rotation ``G`` (B, 3, 3) and an origin ``o`` (B, 3) recorded in
:class:`CanonParams`.  The inverse is ``p = Gᵀ·p_c + o``, ``R_root = Gᵀ·R_root,c``.  The root's
6D columns are rotated directly (``G·M``), which is exact because Gram-Schmidt is rotation
equivariant, so even raw (non-orthonormal) network outputs round-trip.  Other joints' local
rotations are untouched.  The anchor frame index is a parameter (an int for all items, or one
per item; negative counts from the end).

- :func:`face_front` (MultiAct, AAAI'23, "Face-front canonicalization of motions", Fig. 4a;
  reference code ``face_front_align``): the anchor's yaw is set to zero (pitch and roll kept),
  translation is made relative to the anchor and rotated into the yawed frame.
  ``G = Ry(−θ_anchor)``, ``o = root(anchor)``.
- :func:`zero_canon` (Zhang, Black & Tang 2021, as MultiAct's ablation): the anchor's whole
  global rotation is removed; translation as in face-front.
- :func:`marionette_normalize` (Neural Marionette, Alg. 1 and Sec. 4.3): rotate by ``R_z⁻¹``
  (the yaw of the last initial pose ``P₋₁``) and move that pose's root to the origin; the paper's
  inverse ``P̂ = R_z·P̃ + D`` is exactly ours.
- :func:`root_to_origin` / :func:`positions_root_to_origin` (ODMO / Action2Motion): subtract
  frame 0's root from every joint; positions only, no rotation.

Heading θ comes from :mod:`repro.motion.heading` (body axes from rest geometry; 0 = facing +Z).
Units: metres, radians.  Choices where the papers are silent are listed in docs/motion.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

from repro.motion.heading import (HEADING_AXES, BodyFrame, body_frame, chain_global_rotmat,
                                  heading_angle, yaw_matrix)
from repro.motion.motion import Motion
from repro.motion.rotations import sixd_to_matrix

__all__ = [
    "CanonParams", "face_front", "zero_canon", "marionette_normalize", "root_to_origin",
    "positions_root_to_origin", "uncanonicalize", "canonicalize_with", "TRANSLATION_MODES",
]

#: ``xyz``: the anchor's full root position goes to the origin; ``xz``: only its ground-plane
#: part (the height is kept).
TRANSLATION_MODES = ("xyz", "xz")


@dataclass(frozen=True, eq=False)
class CanonParams:
    """What a canonicalisation did, enough to undo it exactly.

    ``rotation`` (B, 3, 3) = G; ``origin`` (B, 3) = o (metres, world frame); ``anchor`` (B,)
    frame indices used (non-negative); ``kind`` and ``settings`` describe the method.
    """

    kind: str
    rotation: torch.Tensor
    origin: torch.Tensor
    anchor: torch.Tensor
    settings: dict = field(default_factory=dict)

    @property
    def batch_size(self) -> int:
        return int(self.rotation.shape[0])

    def _expand(self, points: torch.Tensor):
        extra = points.dim() - 2
        if points.shape[0] != self.batch_size or extra < 0:
            raise ValueError(f"points must be (B={self.batch_size}, ..., 3), got {tuple(points.shape)}")
        view = (self.batch_size,) + (1,) * extra
        G = self.rotation.to(points.dtype).reshape(view[:1] + (1,) * extra + (3, 3))
        o = self.origin.to(points.dtype).reshape(view + (3,))
        return G, o

    def apply_points(self, points: torch.Tensor) -> torch.Tensor:
        """Canonicalise world points (B, ..., 3): ``G·(p − o)``."""
        G, o = self._expand(points)
        return (G @ (points - o).unsqueeze(-1)).squeeze(-1)

    def invert_points(self, points: torch.Tensor) -> torch.Tensor:
        """Back to the world: ``Gᵀ·p + o``."""
        G, o = self._expand(points)
        return (G.transpose(-1, -2) @ points.unsqueeze(-1)).squeeze(-1) + o

    def select(self, index) -> "CanonParams":
        if isinstance(index, int):
            index = [index]
        return CanonParams(self.kind, self.rotation[index], self.origin[index],
                           self.anchor[index], dict(self.settings))

    def to_record(self) -> dict:
        """Plain-JSON description (for run records): kind, settings, and the numbers."""
        return {"kind": self.kind, "settings": dict(self.settings),
                "rotation": self.rotation.detach().cpu().tolist(),
                "origin": self.origin.detach().cpu().tolist(),
                "anchor": self.anchor.detach().cpu().tolist()}


def _anchors(anchor: int | Sequence[int] | torch.Tensor, B: int, T: int) -> torch.Tensor:
    import torch

    a = torch.as_tensor(anchor, dtype=torch.long).reshape(-1)
    if a.numel() == 1:
        a = a.expand(B).clone()
    if a.numel() != B:
        raise ValueError(f"anchor must be one index or one per batch item ({B}), got {a.numel()}")
    if torch.any(a < -T) or torch.any(a >= T):
        raise ValueError(f"anchor frame out of range for {T} frames: {a.tolist()}")
    return torch.remainder(a, T)


def _at(x: torch.Tensor, anchors: torch.Tensor) -> torch.Tensor:
    """x[b, anchors[b]] for x (B, T, ...)."""
    import torch

    return x[torch.arange(x.shape[0], device=x.device), anchors.to(x.device)]


def _origin(root_at_anchor: torch.Tensor, translation: str) -> torch.Tensor:
    if translation not in TRANSLATION_MODES:
        raise ValueError(f"translation must be one of {TRANSLATION_MODES}, got {translation!r}")
    o = root_at_anchor.clone()
    if translation == "xz":
        o[..., 1] = 0.0
    return o


def _apply(motion: Motion, G: torch.Tensor, pre: torch.Tensor | None = None,
           post: torch.Tensor | None = None) -> Motion:
    """root → G·(root − pre) + post; joint 0's 6D columns → G·M; other joints unchanged."""
    import torch

    B = motion.batch_size
    root = motion.root if pre is None else motion.root - pre[:, None]
    root = (G[:, None] @ root.unsqueeze(-1)).squeeze(-1)
    if post is not None:
        root = root + post[:, None]
    r0 = motion.rot6d[:, :, 0].reshape(B, -1, 3, 2)
    r0 = (G[:, None] @ r0).reshape(B, -1, 6)
    rot6d = torch.cat([r0.unsqueeze(2), motion.rot6d[:, :, 1:]], dim=2)
    return motion.replace(root=root, rot6d=rot6d)


def canonicalize_with(motion: Motion, params: CanonParams) -> Motion:
    """Apply recorded ``params`` to another motion of the same batch (e.g. the continuation
    of the motion the params were computed on, which shares its canonical frame)."""
    if motion.batch_size != params.batch_size:
        raise ValueError("params and motion differ in batch size")
    return _apply(motion, params.rotation.to(motion.dtype), pre=params.origin.to(motion.dtype))


def uncanonicalize(motion: Motion, params: CanonParams) -> Motion:
    """The exact inverse: ``root = Gᵀ·root_c + o``, ``R_root = Gᵀ·R_root,c``."""
    if motion.batch_size != params.batch_size:
        raise ValueError("params and motion differ in batch size")
    G = params.rotation.to(motion.dtype)
    return _apply(motion, G.transpose(-1, -2), post=params.origin.to(motion.dtype))


def _body(motion: Motion, body: BodyFrame | None) -> BodyFrame:
    return body if body is not None else body_frame(motion.skeleton)


def _yaw_canon(kind: str, motion: Motion, anchor, heading_axis: str, translation: str,
               body: BodyFrame | None) -> tuple[Motion, CanonParams]:
    if heading_axis not in HEADING_AXES:
        raise ValueError(f"heading_axis must be one of {sorted(HEADING_AXES)}, got {heading_axis!r}")
    body = _body(motion, body)
    a = _anchors(anchor, motion.batch_size, motion.n_frames)
    R_anchor = sixd_to_matrix(_at(motion.rot6d, a))                        # (B, J, 3, 3)
    pelvis = chain_global_rotmat(motion.skeleton, R_anchor, body.pelvis)  # (B, 3, 3)
    theta = heading_angle(pelvis, body.axis(heading_axis), HEADING_AXES[heading_axis])
    G = yaw_matrix(-theta)
    o = _origin(_at(motion.root, a), translation)
    params = CanonParams(kind, G, o, a, {"heading_axis": heading_axis, "translation": translation,
                                         "body_joints": list(body.joints)})
    return _apply(motion, G, pre=o), params


def face_front(motion: Motion, anchor: int | Sequence[int] | torch.Tensor = -1, *,
               heading_axis: str = "lateral", translation: str = "xyz",
               body: BodyFrame | None = None) -> tuple[Motion, CanonParams]:
    """MultiAct face-front canonicalisation (paper: "MACVAE" section, Fig. 4a).

    The anchor frame's heading becomes 0 (body faces +Z), its pitch and roll are kept;
    ``root_c = Ry(−θ)·(root − root[anchor])``.  MultiAct anchors at the last frame of the
    previous motion: index ``l_p − 1`` of [S_p, T, S_c] in training, ``-1`` on S_p alone.

    Defaults follow the reference code: ``heading_axis="lateral"`` (the Z angle of the ZYX Euler
    decomposition of the global orient, i.e. the body's left axis; see
    :mod:`repro.motion.heading`) and ``translation="xyz"`` (the full 3-D anchor translation is
    subtracted).  The code's extra ``basic_global_orient`` (axis-angle (1e-5, 0, 0), "≈ look
    forward") is a 1e-5 rad rotation and is omitted.
    """
    return _yaw_canon("face_front", motion, anchor, heading_axis, translation, body)


def marionette_normalize(motion: Motion, anchor: int | Sequence[int] | torch.Tensor = -1, *,
                         heading_axis: str = "forward", translation: str = "xyz",
                         body: BodyFrame | None = None) -> tuple[Motion, CanonParams]:
    """Neural Marionette normalisation (Alg. 1; Sec. 4.3 "multi-action synthesis").

    The initial motion is rotated by the inverse yaw ``R_z⁻¹`` of its last pose ``P₋₁``
    (``anchor=-1``) and that pose's translation ``D`` is removed, so ``P₋₁`` faces +Z at the
    origin.  The paper writes ``R_z⁻¹·P − D`` but inverts with ``R_z·P̃ + D``; the exact pair is
    ``R_z⁻¹·(P − D)`` / ``R_z·P̃ + D``, which is what this computes (``P₋₁`` lands on the origin,
    "moved to origin point").  Whether ``D`` is the full 3-D translation or its ground-plane part
    is unspecified: ``translation="xyz"`` (default, the text's ``D_t(x, y, z)``) or ``"xz"``.
    ``heading_axis="forward"`` follows the text's "facing" direction.
    """
    return _yaw_canon("marionette", motion, anchor, heading_axis, translation, body)


def zero_canon(motion: Motion, anchor: int | Sequence[int] | torch.Tensor = -1, *,
               target: str = "rest", translation: str = "xyz",
               body: BodyFrame | None = None) -> tuple[Motion, CanonParams]:
    """Zero-canonicalisation (MultiAct's ablation, after Zhang, Black & Tang 2021): the anchor's
    whole global rotation is removed (``f_zero = E(0, 0, 0)``), translation as in face-front.

    ``target="rest"`` (default, the paper's definition): the anchor pelvis' global rotation
    becomes the identity, i.e. the skeleton's rest orientation (upright for SMPL; lying along ±X
    for the raw stand-in BVH rest pose).  ``target="upright"``: the anchor's body frame is
    aligned with the world (up → +Y, forward → +Z), a skeleton-independent reading.
    """
    import torch

    if target not in ("rest", "upright"):
        raise ValueError(f"target must be 'rest' or 'upright', got {target!r}")
    body = _body(motion, body)
    a = _anchors(anchor, motion.batch_size, motion.n_frames)
    pelvis = chain_global_rotmat(motion.skeleton, sixd_to_matrix(_at(motion.rot6d, a)),
                                 body.pelvis)
    G = pelvis.transpose(-1, -2)
    if target == "upright":
        F = torch.as_tensor(body.matrix, dtype=G.dtype, device=G.device)
        G = F.transpose(-1, -2) @ G
    o = _origin(_at(motion.root, a), translation)
    params = CanonParams("zero", G, o, a, {"target": target, "translation": translation,
                                           "body_joints": list(body.joints)})
    return _apply(motion, G, pre=o), params


def root_to_origin(motion: Motion, frame: int = 0) -> tuple[Motion, CanonParams]:
    """ODMO / Action2Motion: subtract the root position of ``frame`` (default the first) from
    the whole motion; no rotation (protocols.md §3.1: "rotate2xz" rotates nothing)."""
    import torch

    a = _anchors(frame, motion.batch_size, motion.n_frames)
    o = _at(motion.root, a)
    G = torch.eye(3, dtype=motion.dtype, device=motion.root.device).expand(motion.batch_size, 3, 3)
    params = CanonParams("root_to_origin", G.clone(), o, a, {"translation": "xyz"})
    return _apply(motion, G, pre=o), params


def positions_root_to_origin(joints: torch.Tensor, frame: int = 0, root_joint: int = 0
                             ) -> tuple[torch.Tensor, CanonParams]:
    """The same on joint positions (B, T, J, 3) (ODMO's xyz representation): every joint
    minus joint ``root_joint`` at ``frame``.  Undo with ``params.invert_points``."""
    import torch

    p = torch.as_tensor(joints)
    if p.dim() != 4 or p.shape[-1] != 3:
        raise ValueError(f"joints must be (B, T, J, 3), got {tuple(p.shape)}")
    a = _anchors(frame, p.shape[0], p.shape[1])
    o = _at(p[:, :, root_joint], a)
    G = torch.eye(3, dtype=p.dtype, device=p.device).expand(p.shape[0], 3, 3).clone()
    params = CanonParams("root_to_origin", G, o, a, {"translation": "xyz", "root_joint": root_joint})
    return p - o[:, None, None], params
