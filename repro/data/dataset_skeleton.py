"""Declared data sets: each clip's skeleton, and the one skeleton of the data set (issues 16, 28).

:func:`convert_bvh` / :func:`convert_amc` turn one file into a clip record (joint names,
parents, OFFSETs in file units, local xyzw quaternions, the root's path); :func:`one_skeleton`
checks that the clips share one skeleton and says which clip's is used.

What "one skeleton per data set" means.  The prepared copy holds one
:class:`repro.motion.skeleton.Skeleton` (``meta.json``), and everything downstream assumes it:
the models generate local rotations and pose them on that skeleton, the composed sequences
(:mod:`repro.data.sequences`) recompute joints from it, and the evaluators compare real joints
with generated ones.  So the clips must share the joint set and hierarchy exactly, and their
bone lengths (OFFSETs) to within ``[skeleton] offset_tolerance`` (metres, each coordinate;
default :data:`repro.data.dataset_spec.POSITION_TOL_M`, 1e-5 m).  Within the tolerance every
clip is posed on the **reference** skeleton, the first clip's (in the source's order): its
joints are forward kinematics of its own rotations and root path on the reference's bones, so
that real and generated motion are measured on the same body.  A data set of several subjects
whose bones differ by centimetres (CMU) is therefore either refused, naming the joints, the
differences and the files, or, with a tolerance raised above the difference, read as one
body (the subjects' rotations and paths on the reference's bones; the card says so).
Per-subject bone lengths in the prepared copy would need a skeleton per clip through every
model, sequence and evaluator, which none has.

A moving dummy root (``[skeleton] fold_dummy_root``): clips whose root motion is carried by a
joint above the hips (``joint_Root``) get that motion composed into the hips, which become the
root: ``q_hips' = q_dummy · q_hips`` and ``t_hips' = t_dummy + R(q_dummy) · t_hips`` (the
hips' local translation: its OFFSET, or its position channels), so every joint's world
position is unchanged (:func:`fold_dummy_root`).
"""

from __future__ import annotations

import numpy as np

from repro.data.dataset_asf import shown
from repro.data.dataset_spec import SkeletonSpec
from repro.data.prepare_caps import check_finite
from repro.errors import DataError


def fold_dummy_root(quats: np.ndarray, trans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Joint 1's local rotation and translation composed with joint 0's (its parent, the
    root): ``quats`` (T, J, 4) xyzw and ``trans`` (T, J, 3) local, float64; returns the
    (T, J - 1, ...) arrays of the skeleton without joint 0, whose new root is posed where the
    old joint 1 was (world positions unchanged; module docstring)."""
    import roma
    import torch

    q0, q1 = torch.as_tensor(quats[:, 0]), torch.as_tensor(quats[:, 1])
    t0, t1 = torch.as_tensor(trans[:, 0]), torch.as_tensor(trans[:, 1])
    q, t = quats[:, 1:].copy(), trans[:, 1:].copy()
    q[:, 0] = roma.quat_product(q0, q1).numpy()
    t[:, 0] = (t0 + roma.quat_action(q0, t1, is_normalized=True)).numpy()
    return q, t


def _dummy_hint(names, parents, j: int) -> str:
    """The advice when a joint below a one-child root carries the root's motion."""
    if parents[j] != 0 or [p for p in parents[1:] if p == 0] != [0]:
        return ""
    return (f" ('{names[0]}' above it looks like a dummy root; if it carries the body's motion: "
            f"[skeleton] dummy_root = {names[0]!r} and fold_dummy_root = true)")


def convert_bvh(label: str, data: bytes, sk: SkeletonSpec, budget=None) -> dict:
    """One BVH clip in the harness conventions (metres, y up; dummy root dropped, or folded
    into its child); ``budget`` (:class:`repro.data.prepare_caps.FrameBudget`) checks its header
    before its frames are parsed."""
    from repro.data.bvh import parse_bvh

    check = None if budget is None else (
        lambda n, frame_time, joints: budget.check(label, n, 1.0 / frame_time, joints))
    b = parse_bvh(data, label, check=check)
    trans = np.asarray(b.local_translations(), np.float64)                 # (T, J, 3)
    dummy = sk.dummy_root is not None and b.n_joints > 1
    with np.errstate(over="ignore"):  # a root the prepared copy could not hold, refused before
        # the rotations are converted (torch is not even loaded): 1e300 is inf in float32
        root = trans[:, int(dummy)] * sk.scale
        if dummy and sk.fold_dummy_root:
            root = root + trans[:, 0] * sk.scale  # the size the folded root reaches, at most
        check_finite(label, root=root.astype(np.float32))
    quats = np.asarray(b.local_rotations(as_quaternions=True), np.float64)  # (T, J, 4) xyzw
    names, parents, offsets = list(b.names), list(b.parents), np.asarray(b.offsets, np.float64)
    if sk.dummy_root is not None:
        if names[0] != sk.dummy_root:
            raise DataError(f"root joint is {names[0]!r}, the spec's dummy_root is "
                            f"{sk.dummy_root!r}", label)
        if [p for p in parents[1:] if p == 0] != [0]:
            raise DataError(f"dummy root {sk.dummy_root!r} must have exactly one child", label)
        if sk.fold_dummy_root:
            quats, trans = fold_dummy_root(quats, trans)
        elif not (np.abs(offsets[0]).max() <= 1e-6 and np.abs(trans[:, 0]).max() <= 1e-6 and
                  np.abs(quats[:, 0, :3]).max() <= 1e-6):  # NaN fails (issue 29)
            raise DataError(f"dummy root {sk.dummy_root!r} is not all zero (dropping it would "
                            f"move the body); to keep its motion, fold it into {names[1]!r}: "
                            "[skeleton] fold_dummy_root = true", label)
        else:
            quats, trans = quats[:, 1:], trans[:, 1:]
        names, offsets = names[1:], offsets[1:]
        parents = [p - 1 for p in parents[1:]]
    first = len(b.names) - len(names)
    if not sk.fold_dummy_root and not {"Xposition", "Yposition", "Zposition"} <= set(
            b.channels[first]):
        raise DataError(f"root joint {names[0]!r} has no X/Y/Zposition channels", label)
    tol = sk.offset_tol / sk.scale
    for j, chans in enumerate(b.channels[first + 1:], start=1):
        if any(c.endswith("position") for c in chans):
            d = float(np.abs(trans[:, j] - offsets[j]).max())
            if not d <= tol:  # NaN fails
                raise DataError(f"position channels of {names[j]!r} move it {d:.4g} units from "
                                "its OFFSET; one skeleton per data set is required"
                                + _dummy_hint(b.names, b.parents, j + first), label)
    offsets = offsets.copy()
    offsets[0] = 0.0  # the root's OFFSET is replaced by its position channels
    return {"names": names, "parents": parents, "offsets": offsets, "quats": quats,
            "root": trans[:, 0].copy(),  # a copy: a view would keep all of (T, J, 3) alive
            "fps": 1.0 / float(b.frame_time), "label": label}


def convert_amc(label: str, data: bytes, asf, sk: SkeletonSpec, fps: float | None,
                budget=None) -> dict:
    """One AMC clip against ``asf``; ``budget`` checks its frame count as it is read."""
    from repro.data import asf_amc
    from repro.motion.rotations import matrix_to_quat

    rate, joints = asf_amc.DEFAULT_FPS if fps is None else fps, len(asf.order)
    amc = asf_amc.parse_amc(data, label, asf, frame_check=None if budget is None else (
        lambda n: budget.check(label, n, rate, joints, count=False)))
    if budget is not None:
        budget.check(label, amc.n_frames, rate, joints)
    # the ASF's own ':units length' first (CMU's 0.45: lengths in inches), then the spec's units
    skel, root, rotmats, rate = asf_amc.to_skeleton_motion(
        asf, amc, **({} if fps is None else {"fps": fps}))
    quats = np.asarray(matrix_to_quat(np.asarray(rotmats)), np.float64)
    return {"names": list(skel.names), "parents": list(skel.parents),
            "offsets": np.asarray(skel.offsets, np.float64), "quats": quats, "root": root,
            "fps": float(rate), "label": label, "asf": asf.source}


def _hierarchy_difference(c: dict, ref: dict) -> str:
    """What differs between two clips' joint sets and parents, in words."""
    mine, theirs = set(c["names"]), set(ref["names"])
    if mine != theirs:
        parts = [f"{what}: {shown(sorted(s))}" for what, s in (
            ("joints only in this file", mine - theirs), ("joints it lacks", theirs - mine)) if s]
        return "; ".join(parts)
    if c["names"] != ref["names"]:
        return "the same joints in another order"
    j = next(j for j, (a, b) in enumerate(zip(c["parents"], ref["parents"])) if a != b)
    return (f"joint {c['names'][j]!r} hangs from {c['names'][c['parents'][j]]!r}, not "
            f"{ref['names'][ref['parents'][j]]!r}")


def _where(c: dict, rel) -> str:
    """A clip's file (path inside the source) and, for an AMC clip, the ASF it was read with."""
    return rel(c["label"]) + (f" (ASF {rel(c['asf'])})" if c.get("asf") else "")


def _cm(metres: float) -> str:
    return f"{metres * 100:.3g} cm"


def one_skeleton(clips: list[dict], sk: SkeletonSpec, rel, where) -> list[str]:
    """Check that ``clips`` share one skeleton (module docstring): the same joints and
    parents (else a DataError naming the first file that differs and how), OFFSETs within
    ``sk.offset_tol`` metres of the reference clip's (``clips[0]``; else one DataError naming,
    per file that differs, the joint that differs most and by how much, every file counted,
    the first :data:`repro.data.dataset_asf.SHOWN` named, and the fix).  ``rel`` turns a clip's
    label into its path inside the source; ``where`` is the source (the error's file).
    Returns the card's warning when clips differ within the tolerance (which reference)."""
    ref = clips[0]
    for c in clips[1:]:
        if c["names"] != ref["names"] or c["parents"] != ref["parents"]:
            raise DataError(f"{_where(c, rel)}: hierarchy differs from {_where(ref, rel)}'s "
                            f"({_hierarchy_difference(c, ref)}); one skeleton per data set is "
                            "required", where)
    tol = sk.offset_tol
    worst: list[tuple[str, float, dict]] = []  # (joint, metres, clip) of each differing clip
    for c in clips[1:]:
        d = np.abs(c["offsets"] - ref["offsets"]).max(axis=1) * sk.scale  # (J,), NaN kept
        d = np.where(np.isnan(d), np.inf, d)
        j = int(np.argmax(d))
        if d[j] > 0:
            worst.append((ref["names"][j], float(d[j]), c))
    over = [w for w in worst if not w[1] <= tol]
    if over:
        by_joint: dict[str, list[tuple[float, dict]]] = {}
        for name, m, c in sorted(over, key=lambda w: -w[1]):
            by_joint.setdefault(name, []).append((m, c))
        parts, named = [], 0
        for name, rows in by_joint.items():
            files = [_where(c, rel) for _, c in rows]
            take = max(0, min(len(files), 10 - named))
            named += take
            listed = shown(files, take) if take else f"{len(files)} file(s)"
            span = _cm(rows[0][0]) if len(rows) == 1 or rows[-1][0] == rows[0][0] else \
                f"{_cm(rows[-1][0])} to {_cm(rows[0][0])}"
            parts.append(f"joint {name!r} by {span} in {listed}")
        agree = len(clips) - 1 - len(over)
        odd = "" if agree >= len(over) else (
            f" (the reference agrees with {agree or 'no other'} file{'s' if agree > 1 else ''}"
            ": is it the odd one?)")
        raise DataError(
            f"OFFSETs of {len(over)} of {len(clips)} files differ from the reference "
            f"{_where(ref, rel)}'s (the first in the source) by more than [skeleton] "
            f"offset_tolerance = {tol:g} m{odd}: "
            + "; ".join(parts) + "; one skeleton per data set is required (if the differences "
            "are immaterial, raise offset_tolerance above them: every clip is then posed on "
            "the reference's bones with its own root path, so a body of other proportions "
            "keeps its recorded hip height: its feet float or sink by the difference)", where)
    if not worst:
        return []
    name, m, _ = max(worst, key=lambda w: w[1])
    return [f"OFFSETs of {len(worst)} file(s) differ from the reference {_where(ref, rel)}'s "
            f"by up to {_cm(m)} (joint {name!r}), within [skeleton] offset_tolerance = {tol:g} "
            "m: every clip is posed on the reference's bones with its own root path (feet may "
            "float or sink by the difference)"]


__all__ = ["convert_amc", "convert_bvh", "fold_dummy_root", "one_skeleton"]
