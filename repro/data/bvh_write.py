"""Export any motion (a skeleton, a root track and local rotations) as a BVH file.

This is the inverse of the reading path (:mod:`repro.data.bvh` + :mod:`repro.data.bandai`),
so generated motion can leave the harness for Blender, Maya or MotionBuilder, and an exported
file reads back through :func:`repro.data.bvh.parse_bvh` to the same pose.

Conventions of the written file:

- **Hierarchy**: the skeleton's tree, joints in the skeleton's (topological) order.  The root
  joint gets ``CHANNELS 6 Xposition Yposition Zposition`` followed by three rotation channels
  in ``order``; every other joint gets the three rotation channels only.
- **Rotations**: Euler angles in degrees, composed *intrinsically in channel order* with
  column vectors, as the reader interprets them: ``order="ZXY"`` writes ``Zrotation Xrotation
  Yrotation`` with ``R = Rz·Rx·Ry`` (roma/scipy convention ``"ZXY"``).  The conversion is
  :func:`repro.motion.rotations.matrix_to_euler` (roma).  ``order`` must be an upper-case
  permutation of ``XYZ`` (lower case means *extrinsic* in roma/scipy, so it is refused).
- **Units**: ``units="cm"`` multiplies metres by 100 (Bandai's files are in centimetres),
  ``units="m"`` keeps metres; this applies to OFFSETs, End Sites and root positions.
- **Root OFFSET** is written as ``0 0 0``: the root's position lies wholly in its position
  channels, so readers that *replace* the OFFSET by the channels (ours) and readers that *add*
  them agree.  The project's forward kinematics ignores the root offset as well.
- **End Sites**: every leaf joint gets one, continuing the leaf's bone in its own direction at
  :data:`END_SITE_FRACTION` of its length (a zero offset for a leaf with a zero OFFSET, e.g. a
  one-joint skeleton).  Viewers need it to draw the last bone; the reader ignores it for FK.
- **Dummy root**: with ``dummy_root="joint_Root"`` (:data:`repro.data.bandai.DUMMY_ROOT`) an
  extra ROOT of that name with a zero OFFSET and six all-zero channels (positions + rotations
  in ``order``) is written above the skeleton's root, as in the Bandai files, so the export is
  accepted by :func:`repro.data.bandai.convert_clips`.
- **Joint names** may hold single spaces (our reader joins the words back), but some readers
  keep only the first word (bvhio does), so names without spaces are the portable choice.
- **Motion**: ``Frames: T``, ``Frame Time: 1/fps`` (7 significant digits), one line per frame.
- **Precision**: every number is printed with ``precision`` digits after the point (fixed
  notation; default 6, i.e. 1e-6 degree and 1e-6 cm).  The text depends only on the input, so
  the same input gives the same bytes.

Bad input (shapes, non-finite values, matrices that are not rotations, a bad ``order``,
``units``, ``fps`` or joint name) raises :class:`ValueError` naming the problem.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Sequence

import numpy as np

from repro.data.bvh import Bvh

#: Length of an End Site as a fraction of its leaf joint's own OFFSET (same direction).
END_SITE_FRACTION = 0.5
#: Largest tolerated deviation of a rotation matrix from orthonormality (max |RᵀR − I|).
ROTATION_TOL = 1e-3
UNITS = {"cm": 100.0, "m": 1.0}
_POS = ("Xposition", "Yposition", "Zposition")
_RESERVED = frozenset(("{", "}", "OFFSET", "CHANNELS", "JOINT", "End", "ROOT", "MOTION",
                       "HIERARCHY"))


def _array(x, what: str) -> np.ndarray:
    """A float64 numpy copy of a numpy array, torch tensor (any device, grad) or sequence."""
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    try:
        return np.array(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{what} must be a numeric array ({e})") from None


def _check_name(name: str, what: str) -> None:
    if not isinstance(name, str) or not name or name != " ".join(name.split()):
        raise ValueError(f"{what} {name!r}: must be non-empty, without tabs, newlines, or "
                         f"leading/trailing/double spaces")
    if any(tok in _RESERVED for tok in name.split()):
        raise ValueError(f"{what} {name!r}: contains a BVH keyword or brace")


def _validate(skeleton, root, rotmats, fps, order: str, units: str):
    J = skeleton.n_joints
    if units not in UNITS:
        raise ValueError(f"units must be one of {sorted(UNITS)}, got {units!r}")
    if not (isinstance(order, str) and len(order) == 3 and sorted(order) == ["X", "Y", "Z"]):
        raise ValueError(f"order must be an upper-case permutation of 'XYZ' (intrinsic, in "
                         f"channel order), got {order!r}")
    try:
        fps = float(fps)
    except (TypeError, ValueError):
        raise ValueError(f"fps must be a number, got {fps!r}") from None
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive finite number, got {fps!r}")
    R = _array(rotmats, "rotmats")
    t = _array(root, "root")
    if R.ndim != 4 or R.shape[1:] != (J, 3, 3):
        raise ValueError(f"rotmats must have shape (T, {J}, 3, 3) for this {J}-joint skeleton, "
                         f"got {R.shape}")
    T = R.shape[0]
    if T < 1:
        raise ValueError("rotmats has no frames (a BVH clip needs at least one)")
    if t.shape != (T, 3):
        raise ValueError(f"root must have shape ({T}, 3) to match rotmats, got {t.shape}")
    for a, what in ((R, "rotmats"), (t, "root"), (skeleton.offsets, "skeleton offsets")):
        if not np.isfinite(a).all():
            bad = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])
            raise ValueError(f"{what} holds a non-finite value (first at index {bad})")
    dev = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(axis=(-1, -2))
    det = np.linalg.det(R)
    bad = (dev > ROTATION_TOL) | (det <= 0)
    if bad.any():
        f, j = (int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"rotmats[{f}, {j}] (joint {skeleton.names[j]!r}) is not a rotation "
                         f"matrix: max |RᵀR − I| = {dev[f, j]:.3g}, det = {det[f, j]:.3g}")
    for n in skeleton.names:
        _check_name(n, "joint name")
    return R, t, fps


def bvh_text(skeleton, root, rotmats, fps, *, precision: int = 6, **kw) -> str:
    """BVH text of a motion (:func:`bvh_of`; module docstring for the conventions)."""
    return format_bvh(bvh_of(skeleton, root, rotmats, fps, precision=precision, **kw), precision)


def bvh_of(skeleton, root, rotmats, fps, *, order: str = "ZXY", units: str = "cm",
           dummy_root: str | None = None, precision: int = 6) -> Bvh:
    """The :class:`~repro.data.bvh.Bvh` of a motion, numbers rounded to ``precision``
    (module docstring for the conventions): :func:`bvh_from_motion` builds it,
    then the root offset, the dummy root and the rounding are applied.

    ``skeleton``: :class:`repro.motion.skeleton.Skeleton` (offsets in metres); ``root``: (T, 3)
    root translation in metres; ``rotmats``: (T, J, 3, 3) local rotation matrices (numpy or
    torch); ``fps``: frames per second.
    """
    R, t, fps = _validate(skeleton, root, rotmats, fps, order, units)
    if not (isinstance(precision, int) and 0 <= precision <= 17):
        raise ValueError(f"precision must be an integer from 0 to 17, got {precision!r}")
    T, J = R.shape[0], R.shape[1]
    rot = tuple(f"{a}rotation" for a in order)
    leaves = sorted(set(range(J)) - set(skeleton.parents))
    base = bvh_from_motion(skeleton, R, t, fps, order=order, scale=UNITS[units],
                           end_sites=[(j, np.asarray(skeleton.offsets[j]) * END_SITE_FRACTION)
                                      for j in leaves])
    names, parents = list(base.names), list(base.parents)
    offsets = np.array(base.offsets, np.float64)
    offsets[0] = 0.0  # the root's position is all in its channels (module docstring)
    channels, motion = list(base.channels), base.motion
    end_parents, end_offsets = list(base.end_parents), base.end_offsets

    if dummy_root is not None:
        _check_name(dummy_root, "dummy_root")
        if dummy_root in names:
            raise ValueError(f"dummy_root {dummy_root!r} is already a joint of the skeleton")
        names = [dummy_root] + names
        parents = [-1] + [p + 1 for p in parents]
        offsets = np.concatenate([np.zeros((1, 3)), offsets])
        channels = [_POS + rot] + channels
        end_parents = [j + 1 for j in end_parents]
        motion = np.concatenate([np.zeros((T, 6)), motion], axis=1)

    def clean(a):  # round first so tiny negatives print as 0.000000, not -0.000000
        return np.round(np.asarray(a, np.float64), precision) + 0.0

    return Bvh(tuple(names), tuple(parents), clean(offsets), tuple(channels), tuple(end_parents),
               clean(np.reshape(end_offsets, (-1, 3))), 1.0 / fps, clean(motion))


def write_bvh(path, skeleton, root, rotmats, fps, *, precision: int = 6, **kw) -> Path:
    """Write :func:`bvh_of` (same arguments) to ``path`` atomically (temporary file beside
    it, then rename: :func:`save_bvh`).  Returns the path."""
    return save_bvh(bvh_of(skeleton, root, rotmats, fps, precision=precision, **kw), path,
                        precision)


# =========================================================================== any Bvh
# format_bvh, save_bvh and bvh_from_motion lived in repro.data.bvh until issue 29 (the reader
# alone is ~550 lines); bvh_write imports bvh, never the other way round
def format_bvh(bvh: Bvh, decimals: int = 6) -> str:
    """BVH text of ``bvh``; values printed with ``decimals`` digits after the point."""
    f = f"{{:.{decimals}f}}"
    out: list[str] = ["HIERARCHY"]
    children: dict[int, list[int]] = {}
    for j, p in enumerate(bvh.parents):
        children.setdefault(p, []).append(j)
    ends: dict[int, list[int]] = {}
    for e, p in enumerate(bvh.end_parents):
        ends.setdefault(p, []).append(e)

    def vec(v) -> str:
        return " ".join(f.format(float(x)) for x in v)

    # Iterative depth-first emission: ("open", j, depth) / ("end", e, depth) / ("close", depth).
    todo: list[tuple] = [("open", j, 0) for j in reversed(children.get(-1, []))]
    while todo:
        item = todo.pop()
        kind = item[0]
        if kind == "close":
            out.append("\t" * item[1] + "}")
            continue
        if kind == "end":
            _, e, d = item
            ind = "\t" * d
            out += [f"{ind}End Site", f"{ind}{{", f"{ind}\tOFFSET {vec(bvh.end_offsets[e])}",
                    f"{ind}}}"]
            continue
        _, j, d = item
        ind = "\t" * d
        out.append(f"{ind}{'ROOT' if bvh.parents[j] < 0 else 'JOINT'} {bvh.names[j]}")
        out.append(f"{ind}{{")
        out.append(f"{ind}\tOFFSET {vec(bvh.offsets[j])}")
        if bvh.channels[j]:
            out.append(f"{ind}\tCHANNELS {len(bvh.channels[j])} {' '.join(bvh.channels[j])}")
        todo.append(("close", d))
        for e in reversed(ends.get(j, [])):
            todo.append(("end", e, d + 1))
        for c in reversed(children.get(j, [])):
            todo.append(("open", c, d + 1))
    out.append("MOTION")
    out.append(f"Frames: {bvh.n_frames}")
    out.append(f"Frame Time: {bvh.frame_time:.7g}")
    buf = io.StringIO()
    if bvh.n_channels:
        np.savetxt(buf, bvh.motion, fmt=f"%.{decimals}f", delimiter=" ")
    else:
        buf.write("\n" * bvh.n_frames)
    return "\n".join(out) + "\n" + buf.getvalue()


def save_bvh(bvh: Bvh, path: str | Path, decimals: int = 6) -> Path:
    """Write the parsed or built ``bvh`` to ``path`` atomically (temp file beside it, then
    rename): :func:`format_bvh`'s text."""
    import os
    import tempfile

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", dir=p.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(format_bvh(bvh, decimals))
        os.chmod(tmp, 0o644)
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return p


def bvh_from_motion(skeleton, rotations, root_translation, fps: float, *, order: str = "ZXY",
                    scale: float = 100.0, end_sites: Sequence[tuple[int, Sequence[float]]] | None = None
                    ) -> Bvh:
    """Build a :class:`Bvh` from a skeleton and local rotations (e.g. generated motion).

    ``rotations``: (F, J, 3, 3) matrices or (F, J, 4) xyzw quaternions; ``root_translation``:
    (F, 3); lengths are multiplied by ``scale`` (metres -> centimetres by default).  The root gets
    ``Xposition Yposition Zposition`` + rotation channels in ``order`` (intrinsic, e.g. ``"ZXY"``);
    other joints get rotation channels only.  Leaf joints get a zero End Site unless
    ``end_sites`` (joint index, offset in skeleton units) are given.
    """
    import roma
    import torch

    R = torch.as_tensor(np.asarray(rotations), dtype=torch.float64)
    if R.shape[-1] == 4:
        R = roma.unitquat_to_rotmat(R / R.norm(dim=-1, keepdim=True))
    F, J = R.shape[0], R.shape[1]
    if J != skeleton.n_joints:
        raise ValueError(f"rotations have {J} joints, skeleton {skeleton.n_joints}")
    order = order.upper()
    if sorted(order) != ["X", "Y", "Z"]:
        raise ValueError(f"order must be a permutation of XYZ, got {order!r}")
    ang = roma.rotmat_to_euler(order, R, degrees=True).numpy()  # (F, J, 3)
    t = np.asarray(root_translation, np.float64).reshape(F, 3) * scale
    rot_ch = tuple(f"{a}rotation" for a in order)
    channels = [("Xposition", "Yposition", "Zposition") + rot_ch] + [rot_ch] * (J - 1)
    motion = np.concatenate([t, ang.reshape(F, J * 3)], axis=1)
    if end_sites is None:
        leaves = [j for j in range(J) if j not in set(skeleton.parents)]
        end_sites = [(j, (0.0, 0.0, 0.0)) for j in leaves]
    ends_p = tuple(int(j) for j, _ in end_sites)
    ends_o = np.array([np.asarray(o, np.float64) * scale for _, o in end_sites]).reshape(-1, 3)
    return Bvh(skeleton.names, skeleton.parents, np.asarray(skeleton.offsets) * scale,
               tuple(channels), ends_p, ends_o, 1.0 / float(fps), motion)
