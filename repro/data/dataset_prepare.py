"""Preparing a declared data set (issue 16): read, convert, label, split, publish.

``prepare_dataset(spec_path)`` reads and converts every clip (BVH through
:mod:`repro.data.bvh`, ASF/AMC through :mod:`repro.data.asf_amc`) to the harness conventions
(metres, y up, local rotations as xyzw quaternions, joint positions by forward kinematics),
checks that every clip shares one skeleton and frame rate, makes the split and a card (clips,
frames, classes, styles, per-class counts and durations), and publishes the same kind of cache
as the built-in stand-in (:func:`repro.data.cache.write_cache`) under
``datasets_root()/<name>/<fingerprint>/``.  An archive is read in one decompression pass and
each clip converted as it streams.  The fingerprint hashes the spec (as validated) and the
source (:func:`repro.data.sources.source_fingerprint`: the archive's bytes, or a folder's file
names, sizes and contents), so editing either makes a new cache; nothing old is overwritten.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from repro.data.dataset_asf import inner_path, read_skeleton_files
from repro.data.dataset_labels import clip_stem
from repro.data.dataset_registration import spec_key
from repro.data.dataset_skeleton import convert_amc, convert_bvh, one_skeleton
from repro.data.dataset_spec import (FPS_RTOL, MAX_LABELS_BYTES, PREPARE_VERSION, DatasetSpec,
                                     escape_name, is_excluded, key_material,
                                     load_dataset_spec, naming_material, role_of)
from repro.data.prepare_caps import FrameBudget, check_finite, joints_f32
from repro.data.prepare_caps import resample_clip as resample_long
from repro.errors import DataError, MissingDataError


# ------------------------------------------------------------------------ reading files
def _iter_files(source: Path, spec: DatasetSpec, skipped: "SkippedFiles | None" = None,
                keep: set[str] | None = None):
    """(label, bytes) of the clip files (:func:`repro.data.dataset_spec.role_of`: the
    ``include`` patterns, case-insensitive, over the path inside the source, less the
    ``exclude`` ones; never the ASF; only those in ``keep``, paths inside the source, when
    given) in a folder or tar archive, read as the built-in stand-in's are
    (:func:`repro.data.sources.iter_source`: one decompression pass, its size caps, no links
    out of a folder).  ``skipped`` is told the path of each file (not folder) not read that is
    no clip (a clip a class subset drops is counted on the card by class)."""
    from repro.data.sources import iter_source

    def kind(name: str) -> str | None:
        return "clip" if role_of(spec, name) == "clip" and (keep is None or name in keep) \
            else None

    def skip(name: str) -> None:  # the ASF is read (by read_skeleton_files), not skipped
        if role_of(spec, name) is None:
            skipped.add(name)

    for _, label, data in iter_source(source, kind_of=kind,
                                      on_skip=None if skipped is None else skip):
        yield label, data


#: how many of the files no pattern took the card names (all are counted)
SKIPPED_SHOWN = 10


class SkippedFiles:
    """The files of a source that no pattern took, in bounded memory (issue 29: every name of
    40,000 4 KB-named members was kept, sorted and escaped a character at a time in Python:
    66 s, 657 MB): a count and the :data:`SKIPPED_SHOWN` first names in sorted order.  The
    ``known`` files (the labels file and the spec itself, as paths inside the source, lower
    case) are not counted.  Folders never reach it (:func:`repro.data.sources.iter_source`
    tells them apart by the entry's type)."""

    def __init__(self, known: set[str] = frozenset(), spec: DatasetSpec | None = None):
        self.known, self.count, self._first = known, 0, []
        self.spec, self.excluded = spec, 0

    def add(self, name: str) -> None:
        import bisect

        if name.strip("/").lower() in self.known:
            return
        if self.spec is not None and is_excluded(self.spec, name):
            self.excluded += 1  # left out on purpose: counted, not listed
            return
        self.count += 1
        if len(self._first) < SKIPPED_SHOWN or name < self._first[-1]:
            bisect.insort(self._first, name)
            del self._first[SKIPPED_SHOWN:]

    def shown(self) -> list[str]:
        """The names the card lists, control characters and bytes that are not UTF-8 escaped
        (``\\x1b``, ``\\udcff``): one compiled pattern over those few names only."""
        return [escape_name(n) for n in self._first]


# ------------------------------------------------------------------------ prepare
def _finish_clip(c: dict, spec: DatasetSpec, fps: float) -> None:
    """In place, as soon as clip ``c`` is converted: its root in metres, y up, resampled from
    ``fps`` (the spec's ``fps``, else the first clip's rounded to 0.001: the rate the data set
    is checked to have) to ``[frames] resample_to``, its rotations cast to float32 as stored.
    Each step is the clip's own, so doing it as the clips stream gives the same bytes."""
    sk = spec.skeleton
    c["root"] = c["root"] * sk.scale
    if sk.up_axis == "z":
        _up_to_y(c)
    if spec.frames.resample_to is not None and abs(spec.frames.resample_to - fps) > 1e-9:
        n = len(c["quats"])
        q, r = resample_long(c["quats"], c["root"], fps, spec.frames.resample_to)
        c["quats"], c["root"] = np.asarray(q), np.asarray(r)
        if len(q) < 2 <= n:
            raise DataError(f"resampling its {n} frames from {fps:g} to "
                            f"{spec.frames.resample_to:g} fps leaves {len(q)} frame (a clip "
                            "needs at least 2): check [frames] resample_to", c["label"])
    c["quats"] = c["quats"].astype(np.float32)  # as stored; halves what clips hold


def _up_to_y(c: dict) -> None:
    """Turn a z-up clip y-up in place: a rotation of −90° about x applied to the root's
    rotation and translation (child offsets live in the root's frame, so they stay)."""
    import roma
    import torch

    R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # (x, y, z) -> (x, z, -y)
    q = torch.as_tensor(c["quats"][:, 0])
    Rq = roma.rotmat_to_unitquat(torch.as_tensor(R)).expand_as(q)
    c["quats"][:, 0] = roma.quat_product(Rq, q).numpy()
    c["root"] = c["root"] @ R.T


def _check_expect(spec: DatasetSpec, spec_path: Path, clips: int, frames: int, joints: int):
    """The spec's ``[expect]`` against the data (also on reusing a prepared copy: the section
    is a check, not part of the key)."""
    exp = spec.expect
    if exp is None:
        return
    bad = [f"{got} {what} ([expect] {what} = {want})" for what, got, want in (
        ("clips", clips, exp.clips), ("frames", frames, exp.frames), ("joints", joints, exp.joints))
        if want is not None and got != want]
    if bad:
        raise DataError("the data disagrees with the spec: " + "; ".join(bad), spec_path)


def _body(skel, spec_path: Path):
    """The body frame every protocol takes the heading from (the hips by name, or the spec's
    ``[skeleton] hips`` / ``up_joint``); an up joint in a leg is refused."""
    from repro.motion.heading import ancestors, body_frame

    try:
        body = body_frame(skel)
    except ValueError as e:
        raise DataError(f"{e} (the harness finds the hips by joint names such as "
                        "LeftUpLeg / UpperLeg_L / l_hip; or name them: [skeleton] hips = "
                        "[left, right], up_joint = ...)", spec_path) from None
    L, R, U = (skel.index(n) for n in body.joints)
    if {L, R} & set(ancestors(skel, U)):
        raise DataError(f"the up joint {body.joints[2]!r} is in a leg (below a hip); name a "
                        "joint above the pelvis: [skeleton] up_joint", spec_path)
    return body


#: the body's mean up direction (pelvis → up joint) must be this close to +y (cos ~ 60°)
UP_MIN_COS = 0.5
#: a mean speed (m/s) along the body's backward direction that is flagged on the card
BACKWARD_FLAG_MPS = 0.1


def _posture_checks(skel, body, joints: list, fps: float, spec_path: Path) -> list[str]:
    """Checks of the conventions on the motion itself: the body must stand up along +y on
    average (else ``up_axis`` / ``up_joint`` is wrong: refused); a data set whose roots move
    backwards relative to the hips' forward on average gets a card warning (swapped ``hips``?).
    Returns the warnings.  Written so that NaN fails (a comparison with NaN is False)."""
    pelvis, U = body.pelvis, skel.index(body.joints[2])
    L, R = skel.index(body.joints[0]), skel.index(body.joints[1])
    allj = np.concatenate([j[:, [U, pelvis]] for j in joints]).astype(np.float64)  # 2 joints
    up = (allj[:, 0] - allj[:, 1]).mean(0)
    n = np.linalg.norm(up)
    if not (n >= 1e-9 and up[1] / n >= UP_MIN_COS):
        raise DataError(f"the body's up direction ({body.joints[2]} above "
                        f"{skel.names[pelvis]}) points along {np.round(up / max(n, 1e-9), 2).tolist()} "
                        "on average, not +y: check [skeleton] up_axis (and up_joint)", spec_path)
    speeds = []
    for j in joints:
        if len(j) < 2:
            continue
        fwd = np.cross(j[:-1, L] - j[:-1, R], [0.0, 1.0, 0.0])  # left × up, on the floor
        fwd /= np.maximum(np.linalg.norm(fwd, axis=1, keepdims=True), 1e-9)
        speeds.append(((j[1:, pelvis] - j[:-1, pelvis]) * fwd).sum(1) * fps)
    mean = float(np.concatenate(speeds).mean()) if speeds else 0.0
    if mean < -BACKWARD_FLAG_MPS:
        return [f"the pelvis moves {-mean:.2f} m/s backwards on average relative to the body's "
                "forward (left hip × up): are [skeleton] hips swapped?"]
    return []


def _card(spec: DatasetSpec, classes, styles, labels, lengths, fps, subjects,
          skipped: SkippedFiles, unused_rows: list[str], warnings: list[str],
          dropped: dict[str, int], unlisted: list[str]) -> dict:
    """The generated card: counts, per-class clips / frames / durations, subjects, and what the
    source held that was not read (files no pattern took or an ``exclude`` left out, label rows
    naming no clip, clips of classes a ``classes`` subset drops, clips the labels do not name
    under ``unlisted = "drop"``)."""
    per_class = {}
    for i, n in enumerate(classes):
        ls = lengths[labels == i]
        per_class[n] = {"clips": int(ls.size), "frames": int(ls.sum()),
                        "seconds_mean": round(float(ls.mean()) / fps, 3) if ls.size else 0.0,
                        "seconds_total": round(float(ls.sum()) / fps, 3)}
    named = sorted({x for x in subjects if x is not None})
    return {"name": spec.name, "clips": int(lengths.size), "frames": int(lengths.sum()),
            "fps": fps, "class_names": list(classes), "style_names": list(styles),
            "subjects": len(named), "per_class": per_class,
            "skipped_files": {"count": skipped.count, "first": skipped.shown()},
            "unused_label_rows": {"count": len(unused_rows), "first": unused_rows[:10]},
            **({"excluded_files": skipped.excluded} if skipped.excluded else {}),
            **({"dropped_clips": {"by_class": dict(dropped), "count": sum(dropped.values())}}
               if dropped else {}),
            **({"unlisted_clips": {"count": len(unlisted), "first": unlisted[:10]}}
               if unlisted else {}),
            "warnings": list(warnings), "license": spec.license, "credit": spec.credit, "description": spec.description}


def _split_method(spec: DatasetSpec) -> str:
    """The split's name in ``meta.json`` (the wording before issue 28 kept for its splits)."""
    sp = spec.split
    if sp.grouped_by_action:
        return f"{sp.by}s whole to test, every action on both sides"
    return "subjects whole to test" if sp.by == "subject" else "stratified(action, style)"


def prepare_dataset(spec_path: str | Path, *, force: bool = False):
    """Prepare the data set a spec file describes (module docstring); returns a
    :class:`repro.data.cache.PrepareResult`.  A cache of the same fingerprint is reused."""
    import time

    from filelock import FileLock

    from repro.data.cache import (POINTER, PrepareResult, dataset_dir, valid_cache, write_cache,
                                  write_json_atomic)
    from repro.data.dataset_clips import select_clips

    t0 = time.perf_counter()
    spec_path = Path(spec_path)
    spec = load_dataset_spec(spec_path)
    here = spec_path.resolve().parent
    source = (here / spec.source.path)
    if not source.exists():
        raise MissingDataError("the spec's source folder or archive is not there", source)
    # the clips, their labels and split from the file names alone: a split that leaves a
    # class without a test or training clip is refused before any clip is parsed (issue 28)
    chosen = select_clips(spec, spec_path, source)
    asfs, src_fp, fp, pointer = _fingerprint(spec, spec_path, here, source)
    root = dataset_dir(spec.name)
    root.mkdir(parents=True, exist_ok=True)
    with FileLock(str(root / ".lock")):
        meta = None if force else valid_cache(root / fp)
        if meta is not None:
            _check_expect(spec, spec_path, len(meta["clip_names"]), int(meta["stats"]["frames"]),
                          len(meta["skeleton"]["names"]))
            write_json_atomic(root / POINTER, pointer)
            return PrepareResult(root / fp, fp, True, time.perf_counter() - t0,
                                 len(meta["clip_names"]), int(meta["stats"]["frames"]))
        clips, skipped, order, stems = _read_clips(spec, spec_path, here, source, chosen, asfs)
        skel, fps, skeleton_notes = _dataset_skeleton(clips, spec, spec_path, source)
        body = _body(skel, spec_path)
        quats, roots, joints = _cast_clips(clips, order, skel)
        lengths = np.array([q.shape[0] for q in quats], np.int64)
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
        lab = chosen.labels
        _check_expect(spec, spec_path, len(stems), int(lengths.sum()), skel.n_joints)
        checks = _posture_checks(skel, body, joints, fps, spec_path)
        arrays = {"rotations": np.concatenate(quats), "root": np.concatenate(roots),
                  "joints": np.concatenate(joints), "starts": starts, "lengths": lengths,
                  "labels": lab.labels, "styles": lab.styles, "split": chosen.split}
        meta = _meta(spec, spec_path, source, src_fp, fps, skel, lab, stems, lengths, skipped,
                     skeleton_notes + checks)
        write_cache(root, fp, arrays, meta)
        write_json_atomic(root / POINTER, pointer)
    return PrepareResult(root / fp, fp, False, time.perf_counter() - t0, len(stems),
                         int(lengths.sum()))


def _fingerprint(spec: DatasetSpec, spec_path: Path, here: Path, source: Path):
    """``(asfs, source fingerprint, fingerprint, pointer)``: the ASF file(s) of an ``asf_amc``
    source (read before the clips, :mod:`repro.data.dataset_asf`), the fingerprint of the spec
    (as validated), the source, the ASF files and the labels file, and the ``current.json``
    content naming it."""
    import hashlib

    from repro.keys import content_key

    digest = hashlib.sha256()
    asfs = None
    if spec.source.format == "asf_amc":  # the ASF file(s), read before the clips (dataset_asf)
        asfs = read_skeleton_files(source, spec)
        digest.update(asfs.digest())
    from repro.data.sources import read_regular, source_fingerprint

    if spec.labels.file:  # a side file of labels is part of what the data set is
        side = here / spec.labels.file
        if side.is_file():  # capped, regular files only (read again, checked, for labels)
            digest.update(b"labels\0" + hashlib.sha256(
                read_regular(side, MAX_LABELS_BYTES, "the labels file")).digest())

    # the source is named by its bytes (as the built-in stand-in's), the spec by its content
    src_fp = source_fingerprint(source, select=lambda n: role_of(spec, n))
    pointer = {"fingerprint": None, "source": str(spec_path),
               "spec_file": str(spec_path.resolve()), "spec_key": spec_key(spec, spec_path)}
    fp = content_key({"kind": "dataset_spec", "version": PREPARE_VERSION,
                      "spec": key_material(spec),
                      "source": src_fp, "asf": digest.hexdigest(),
                      **naming_material(source)})  # archives only: how root members are named
    pointer["fingerprint"] = fp
    return asfs, src_fp, fp, pointer


def _read_clips(spec: DatasetSpec, spec_path: Path, here: Path, source: Path, chosen, asfs):
    """``(clips, skipped, order, stems)``: the chosen clips read and converted as they stream
    (:func:`_finish_clip`), the files no pattern took, the clips' order by label and their
    names, which must be those :func:`repro.data.dataset_clips.select_clips` listed."""
    sk, fmt = spec.skeleton, spec.source.format
    known = {p.relative_to(source.resolve()).as_posix().lower()
             for p in (here / (spec.labels.file or ""), spec_path.resolve())
             if source.is_dir() and p.is_file() and p.is_relative_to(source.resolve())}
    clips, skipped = [], SkippedFiles(known, spec)  # a count and the first names: bounded
    budget = FrameBudget(spec.frames.resample_to, spec.frames.fps, spec.limits)  # caps
    for label, data in _iter_files(source, spec, skipped, chosen.kept_rel):  # as they stream
        clips.append(convert_bvh(label, data, sk, budget) if fmt == "bvh" else
                     convert_amc(label, data, asfs.parsed(asfs.asf_for(
                         inner_path(label, source))), sk, spec.frames.fps, budget))
        # scaled, turned, resampled and cast to float32 at once: what the clips hold until
        # they are published is what the total caps count (the float64 copy at the files'
        # rate was held for every clip: 4 × the frames counted, at twice the bytes)
        _finish_clip(clips[-1], spec, spec.frames.fps if spec.frames.fps is not None
                     else round(clips[0]["fps"], 3))
    order = sorted(range(len(clips)), key=lambda i: clips[i]["label"])
    stems = [clip_stem(clips[i]["label"], source) for i in order]
    if stems != chosen.stems:  # the clips listed before parsing are the ones read
        raise DataError("the source's clip files changed while it was read; run again",
                        source)
    return clips, skipped, order, stems


def _dataset_skeleton(clips: list[dict], spec: DatasetSpec, spec_path: Path, source: Path):
    """``(skeleton, fps, notes)``: the one skeleton and frame rate every clip shares (checked,
    and against the spec's ``[frames] fps`` and the joints ``[skeleton]`` names), the rate as
    stored (``resample_to`` when given), and the card's notes on the skeleton."""
    from repro.motion.skeleton import Skeleton

    sk = spec.skeleton
    first = clips[0]
    skeleton_notes = one_skeleton(clips, sk, lambda lab: inner_path(lab, source), source)
    for c in clips[1:]:
        if not abs(c["fps"] - first["fps"]) <= FPS_RTOL * first["fps"]:
            raise DataError(f"{c['fps']:g} fps, {first['label']} has {first['fps']:g}",
                            c["label"])
    fps = round(first["fps"], 3)
    if spec.frames.fps is not None:
        if not abs(spec.frames.fps - first["fps"]) <= FPS_RTOL * spec.frames.fps:
            raise DataError(f"the files run at {first['fps']:g} fps, the spec says "
                            f"{spec.frames.fps:g}", source)
        fps = float(spec.frames.fps)  # a printed frame time (0.008333) is a rounded 1/fps
    for n in (*(sk.hips or ()), *((sk.up_joint,) if sk.up_joint else ())):
        if n not in first["names"]:
            raise DataError(f"[skeleton] names joint {n!r}, which the files do not have "
                            f"(joints: {', '.join(first['names'])})", spec_path)
    skel = Skeleton(tuple(first["names"]), tuple(first["parents"]),
                    first["offsets"] * sk.scale,
                    None if sk.hips is None else tuple(sk.hips), sk.up_joint)
    if spec.frames.resample_to is not None:
        fps = float(spec.frames.resample_to)
    return skel, fps, skeleton_notes


def _cast_clips(clips: list[dict], order: list[int], skel):
    """``(rotations, roots, joints)`` per clip in ``order``, float32 (joints by forward
    kinematics), each clip's float64 copies dropped as they are cast; nothing non-finite
    (:func:`repro.data.prepare_caps.check_finite`)."""
    with np.errstate(over="ignore", invalid="ignore"):  # overflow: check_finite says it
        # float64 copies dropped as they are cast (memory: docs/data.md, Frames and memory)
        quats = [np.asarray(clips[i].pop("quats"), np.float32) for i in order]
        roots = [clips[i].pop("root").astype(np.float32) for i in order]
        joints = [joints_f32(skel, q, r) for q, r in zip(quats, roots)]
    for i, q, r, j in zip(order, quats, roots, joints):  # nothing non-finite is published
        check_finite(clips[i]["label"], rotations=q, root=r, joints=j)
    return quats, roots, joints


def _meta(spec: DatasetSpec, spec_path: Path, source: Path, src_fp: str, fps: float, skel,
          lab, stems: list[str], lengths: np.ndarray, skipped: SkippedFiles,
          warnings: list[str]) -> dict:
    """The published ``meta.json``: names, skeleton, units, labels, clips, split and card."""
    from repro import __version__

    return {"name": spec.name, "source_fingerprint": src_fp,
            "source_kind": "folder" if source.is_dir() else "archive",
            "spec_file": str(spec_path), "fps": fps, "skeleton": skel.to_dict(),
            "units": "metres, Y up",
            "rotations": f"local, xyzw, as the {spec.source.format} files give them",
            "label_names": lab.classes, "style_names": lab.style_names, "clip_names": stems,
            **({"clip_subjects": lab.subjects} if any(x is not None for x in lab.subjects)
               else {}),
            "split": {"method": _split_method(spec), **spec.split.model_dump(
                exclude={"stratify"} if spec.split.stratify is None else set())},
            "card": _card(spec, lab.classes, lab.style_names, lab.labels, lengths, fps,
                          lab.subjects, skipped, lab.unused_rows, warnings, lab.dropped,
                          lab.unlisted),
            "stats": {"clips": len(stems), "frames": int(lengths.sum())},
            "repro_version": __version__, "dataset_spec_version": PREPARE_VERSION}
