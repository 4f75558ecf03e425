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

import csv
import io
import json
import re
from pathlib import Path

import numpy as np

from repro.data.dataset_spec import (FPS_RTOL, POSITION_TOL_M, PREPARE_VERSION, DatasetSpec,
                                     LabelSpec, SkeletonSpec, clip_pattern, key_material,
                                     load_dataset_spec, role_of, spec_key)
from repro.errors import DataError, MissingDataError


# ------------------------------------------------------------------------ reading files
def _iter_files(source: Path, spec: DatasetSpec, skipped: list[str] | None = None):
    """(label, bytes) of the clip files (:func:`repro.data.dataset_spec.role_of`: the
    ``include`` pattern, case-insensitive, over the path inside the source; never the ASF) in a
    folder or tar archive, read as the built-in stand-in's are
    (:func:`repro.data.sources.iter_source`: one decompression pass, its size caps, no links
    out of a folder).  ``skipped`` collects the paths of the entries not read (folders
    included; :func:`_skipped_files` leaves those out)."""
    from repro.data.sources import iter_source

    def kind(name: str) -> str | None:
        role = role_of(spec, name)
        if role is None and skipped is not None:
            skipped.append(name)
        return "clip" if role == "clip" else None

    for _, label, data in iter_source(source, kind_of=kind):
        yield label, data


def _skipped_files(source: Path, skipped: list[str], read: list[str], known: set[str]) -> list[str]:
    """The files of the source that no pattern took: ``skipped`` less folders (a folder
    source's entries that are not files; an archive's names that lead to other entries) and
    the ``known`` files (the labels file and the spec itself, as paths inside the source,
    lower case)."""
    if source.is_dir():
        files = [n for n in skipped if (source / n).is_file()]
    else:
        inner = {r[len(f"{source}:"):] for r in read}  # iter_source's "archive:member"
        parents = {q.rsplit("/", i)[0] for q in [*skipped, *inner] for i in range(1, q.count("/") + 1)}
        files = [n for n in skipped if n not in parents]
    return sorted(n for n in files if n.strip("/").lower() not in known)


def _read_asf(source: Path, spec: DatasetSpec):
    """(bytes, where) of the spec's ASF skeleton file inside a source folder or archive, its
    path matched case-insensitively in both (an archive costs one more decompression pass,
    through the same caps; a folder's file must not be a link out of it)."""
    from repro.data.sources import inside, iter_source

    if source.is_dir():
        found = [q for q in sorted(source.rglob("*"))
                 if role_of(spec, q.relative_to(source).as_posix()) == "asf"]
        if not found or not found[0].is_file():
            raise MissingDataError("the spec's ASF skeleton file is not in the source folder",
                                   source / spec.source.asf)
        if not inside(found[0], source):
            raise DataError("a symbolic link that leads out of the source folder (copy the "
                            "file in instead)", found[0])
        return found[0].read_bytes(), found[0]
    for _, label, data in iter_source(source, kind_of=lambda n: role_of(spec, n) == "asf"
                                      and "asf" or None):
        return data, label
    raise MissingDataError(f"the spec's ASF skeleton file {spec.source.asf!r} is not in the "
                           "archive", source)


def _convert_bvh(label: str, data: bytes, sk: SkeletonSpec) -> dict:
    """One BVH clip in the harness conventions (metres, y up; dummy root dropped)."""
    from repro.data.bvh import parse_bvh

    b = parse_bvh(data, label)
    quats = np.asarray(b.local_rotations(as_quaternions=True), np.float64)  # (T, J, 4) xyzw
    trans = np.asarray(b.local_translations(), np.float64)                 # (T, J, 3)
    names, parents, offsets = list(b.names), list(b.parents), np.asarray(b.offsets, np.float64)
    if sk.dummy_root is not None:
        if names[0] != sk.dummy_root:
            raise DataError(f"root joint is {names[0]!r}, the spec's dummy_root is "
                            f"{sk.dummy_root!r}", label)
        if [p for p in parents[1:] if p == 0] != [0]:
            raise DataError(f"dummy root {sk.dummy_root!r} must have exactly one child", label)
        if np.abs(offsets[0]).max() > 1e-6 or np.abs(trans[:, 0]).max() > 1e-6 or \
                np.abs(quats[:, 0, :3]).max() > 1e-6:
            raise DataError(f"dummy root {sk.dummy_root!r} is not all zero (dropping it would "
                            "move the body)", label)
        names, offsets, quats, trans = names[1:], offsets[1:], quats[:, 1:], trans[:, 1:]
        parents = [p - 1 for p in parents[1:]]
    first = len(b.names) - len(names)
    if not {"Xposition", "Yposition", "Zposition"} <= set(b.channels[first]):
        raise DataError(f"root joint {names[0]!r} has no X/Y/Zposition channels", label)
    tol = POSITION_TOL_M / sk.scale
    for j, chans in enumerate(b.channels[first + 1:], start=1):
        if any(c.endswith("position") for c in chans):
            d = float(np.abs(trans[:, j] - offsets[j]).max())
            if d > tol:
                raise DataError(f"position channels of {names[j]!r} move it {d:.4g} units from "
                                "its OFFSET; one skeleton per data set is required", label)
    offsets = offsets.copy()
    offsets[0] = 0.0  # the root's OFFSET is replaced by its position channels
    return {"names": names, "parents": parents, "offsets": offsets, "quats": quats,
            "root": trans[:, 0], "fps": 1.0 / float(b.frame_time), "label": label}


def _convert_amc(label: str, data: bytes, asf, sk: SkeletonSpec, fps: float | None) -> dict:
    from repro.data import asf_amc
    from repro.motion.rotations import matrix_to_quat

    amc = asf_amc.parse_amc(data, label, asf)
    # the ASF's own ':units length' first (CMU's 0.45: lengths in inches), then the spec's units
    skel, root, rotmats, rate = asf_amc.to_skeleton_motion(
        asf, amc, **({} if fps is None else {"fps": fps}))
    quats = np.asarray(matrix_to_quat(np.asarray(rotmats)), np.float64)
    return {"names": list(skel.names), "parents": list(skel.parents),
            "offsets": np.asarray(skel.offsets, np.float64), "quats": quats, "root": root,
            "fps": float(rate), "label": label}


def _name(v, what: str, clip: str, where, *, required: bool = False) -> str | None:
    """A label value as a non-empty name without control characters (``None`` stays None: no
    style or subject, unless ``required``)."""
    if v is None and not required:
        return None
    if not isinstance(v, str) or not v.strip() or any(ord(ch) < 32 for ch in v):
        raise DataError(f"clip {clip!r:.80}: {what} must be a non-empty name (no control "
                        f"characters), got {v!r:.60}", where)
    return v.strip()


def _side_table(lab: LabelSpec, side: Path) -> dict[str, tuple]:
    """clip -> (action, style, subject) of a CSV or JSON labels file (duplicates refused)."""
    try:
        text = side.read_text(encoding="utf-8-sig")  # a spreadsheet's BOM is no header
    except OSError as e:
        raise MissingDataError(f"cannot read the labels file ({e.strerror})", side) from None
    except UnicodeDecodeError as e:
        raise DataError(f"the labels file is not UTF-8 text (byte {e.start})", side) from None
    table: dict[str, tuple] = {}

    def put(clip, action, style, subject, where: str) -> None:
        clip = _name(clip, f"the clip name ({where})", str(clip), side, required=True)
        if clip in table:
            raise DataError(f"clip {clip!r} is labelled twice ({where})", side)
        table[clip] = (_name(action, "action", clip, side, required=True),
                       _name(style, "style", clip, side), _name(subject, "subject", clip, side))

    if lab.from_ == "csv":
        reader = csv.DictReader(io.StringIO(text))
        try:
            reader.fieldnames = [f.strip() for f in reader.fieldnames or []]
            if not {"clip", "action"} <= set(reader.fieldnames):
                raise DataError("a labels CSV needs a header row with columns clip, action"
                                f"[, style][, subject] (found {reader.fieldnames!r:.200})", side)
            for n, r in enumerate(reader, start=2):
                put(r.get("clip"), r.get("action"), r.get("style") or None,
                    r.get("subject") or None, f"line {n}")
        except csv.Error as e:  # e.g. a field over the csv module's size limit
            raise DataError(f"not a readable CSV at line {reader.line_num} ({e})", side) from None
        return table
    try:
        raw = json.loads(text)
    except (ValueError, RecursionError) as e:
        raise DataError(f"not JSON ({type(e).__name__}: {str(e)[:80]})", side) from None
    if not isinstance(raw, dict):
        raise DataError("labels JSON must map clip -> action or {action, style, subject}", side)
    for k, v in raw.items():
        if isinstance(v, dict):
            put(k, v.get("action"), v.get("style"), v.get("subject"), f"key {k!r}")
        else:
            put(k, v, None, None, f"key {k!r}")
    return table


def _labels_for(spec: DatasetSpec, spec_dir: Path, stems: list[str]):
    """(labels, styles, class names, style names, subjects, unused label rows) of the clips
    ``stems`` (every name checked: a non-empty string, each clip labelled once, classes and
    styles unique and used; ``subjects`` a name per clip or None; the unused rows: side-file
    clips that name no clip of the source)."""
    lab = spec.labels
    got: dict[str, tuple[str, str | None, str | None]] = {}
    where = spec_dir / (lab.file or spec.source.path)
    unused_rows: list[str] = []
    if lab.from_ == "filename":
        rx = re.compile(lab.pattern)
        for s in stems:
            m = rx.search(s)
            if m is None or m.group("action") is None:
                raise DataError(f"file name {s!r} does not match the labels pattern "
                                f"{lab.pattern!r}", where)
            g = m.groupdict()
            got[s] = (_name(m.group("action"), "action", s, where),
                      _name(g.get("style"), "style", s, where),
                      _name(g.get("subject"), "subject", s, where))
    else:
        table = _side_table(lab, where)
        for s in stems:
            if s not in table:
                raise DataError(f"clip {s!r} has no label", where)
            got[s] = table[s]
        unused_rows = sorted(set(table) - set(stems))
    subjects = [got[s][2] for s in stems]
    if spec.split.by == "subject" and any(x is None for x in subjects):
        missing = next(s for s in stems if got[s][2] is None)
        raise DataError(f"clip {missing!r} has no subject; [split] by = 'subject' needs one "
                        "for every clip", where)
    for what, given in (("classes", lab.classes), ("styles", lab.styles)):
        if given is not None and len(set(given)) != len(given):
            raise DataError(f"[labels] {what} repeats a name: {given}", spec_dir)
    classes = list(lab.classes) if lab.classes else sorted({a for a, _, _ in got.values()})
    style_vals = {st for _, st, _ in got.values() if st is not None}
    styles = list(lab.styles) if lab.styles else sorted(style_vals)
    cidx, sidx = {c: i for i, c in enumerate(classes)}, {s: i for i, s in enumerate(styles)}
    labels, style_ids = [], []
    for s in stems:
        a, st, _ = got[s]
        if a not in cidx:
            raise DataError(f"clip {s!r}: action {a!r} is not one of the classes {classes}",
                            where)
        if st is not None and st not in sidx:
            raise DataError(f"clip {s!r}: style {st!r} is not one of {styles}", where)
        labels.append(cidx[a])
        style_ids.append(-1 if st is None else sidx[st])
    unused = [c for c in classes if c not in {got[s][0] for s in stems}]
    if unused:
        raise DataError(f"class(es) {unused} have no clip (remove them from [labels] classes)",
                        where)
    return (np.array(labels, np.int64), np.array(style_ids, np.int64), classes,
            styles if style_vals else [], subjects, unused_rows)


# ------------------------------------------------------------------------ prepare
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
    from repro.motion.heading import _ancestors, body_frame

    try:
        body = body_frame(skel)
    except ValueError as e:
        raise DataError(f"{e} (the harness finds the hips by joint names such as "
                        "LeftUpLeg / UpperLeg_L / l_hip; or name them: [skeleton] hips = "
                        "[left, right], up_joint = ...)", spec_path) from None
    L, R, U = (skel.index(n) for n in body.joints)
    if {L, R} & set(_ancestors(skel, U)):
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
    Returns the warnings."""
    pelvis, U = body.pelvis, skel.index(body.joints[2])
    L, R = skel.index(body.joints[0]), skel.index(body.joints[1])
    allj = np.concatenate(joints).astype(np.float64)
    up = (allj[:, U] - allj[:, pelvis]).mean(0)
    n = np.linalg.norm(up)
    if n < 1e-9 or up[1] / n < UP_MIN_COS:
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


def _test_warnings(classes, labels, split) -> list[str]:
    """A class with no test clip cannot be scored on the test split: said on the card."""
    none = [c for i, c in enumerate(classes) if not ((labels == i) & (split == 1)).any()]
    return [f"class(es) {', '.join(none)} have no test clip"] if none else []


def _card(spec: DatasetSpec, classes, styles, labels, lengths, fps, subjects,
          skipped: list[str], unused_rows: list[str], warnings: list[str]) -> dict:
    """The generated card: counts, per-class clips / frames / durations, subjects, and what the
    source held that was not read (files no pattern took, label rows naming no clip)."""
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
            "skipped_files": {"count": len(skipped), "first": skipped[:10]},
            "unused_label_rows": {"count": len(unused_rows), "first": unused_rows[:10]},
            "warnings": list(warnings), "license": spec.license, "credit": spec.credit, "description": spec.description}


def prepare_dataset(spec_path: str | Path, *, force: bool = False):
    """Prepare the data set a spec file describes (module docstring); returns a
    :class:`repro.data.cache.PrepareResult`.  A cache of the same fingerprint is reused."""
    import hashlib
    import time

    from filelock import FileLock

    from repro.data.cache import (POINTER, PrepareResult, dataset_dir, valid_cache, write_cache,
                                  write_json_atomic)
    from repro.data.splits import stratified_split, subject_split
    from repro.keys import content_key
    from repro.motion.resample import resample_clip
    from repro.motion.rotations import quat_to_matrix
    from repro.motion.skeleton import Skeleton, forward_kinematics

    t0 = time.perf_counter()
    spec_path = Path(spec_path)
    spec = load_dataset_spec(spec_path)
    here = spec_path.resolve().parent
    source = (here / spec.source.path)
    if not source.exists():
        raise MissingDataError("the spec's source folder or archive is not there", source)
    fmt = spec.source.format
    pattern = clip_pattern(spec)
    digest = hashlib.sha256()
    asf = None
    if fmt == "asf_amc":
        from repro.data import asf_amc

        asf_bytes, asf_where = _read_asf(source, spec)
        digest.update(b"asf\0" + hashlib.sha256(asf_bytes).digest())
        asf = asf_amc.parse_asf(asf_bytes, asf_where)
    from repro.data.sources import source_fingerprint

    if spec.labels.file:  # a side file of labels is part of what the data set is
        side = here / spec.labels.file
        if side.is_file():
            digest.update(b"labels\0" + hashlib.sha256(side.read_bytes()).digest())

    # the source is named by its bytes (as the built-in stand-in's), the spec by its content
    src_fp = source_fingerprint(source, select=lambda n: role_of(spec, n))
    pointer = {"fingerprint": None, "source": str(spec_path),
               "spec_file": str(spec_path.resolve()), "spec_key": spec_key(spec, spec_path)}
    fp = content_key({"kind": "dataset_spec", "version": PREPARE_VERSION,
                      "spec": key_material(spec),
                      "source": src_fp, "asf": digest.hexdigest()})
    pointer["fingerprint"] = fp
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
        sk = spec.skeleton
        clips, skipped = [], []
        for label, data in _iter_files(source, spec, skipped):  # converted as they stream
            clips.append(_convert_bvh(label, data, sk) if fmt == "bvh" else
                         _convert_amc(label, data, asf, sk, spec.frames.fps))
        if not clips:
            raise DataError(f"no file matches {pattern!r} (case-insensitive)", source)
        known = {p.relative_to(source.resolve()).as_posix().lower()
                 for p in (here / (spec.labels.file or ""), spec_path.resolve())
                 if source.is_dir() and p.is_file() and p.is_relative_to(source.resolve())}
        skipped = _skipped_files(source, skipped, [c["label"] for c in clips], known)
        first = clips[0]
        for c in clips[1:]:
            if c["names"] != first["names"] or c["parents"] != first["parents"]:
                raise DataError(f"hierarchy differs from {first['label']}'s; one skeleton per "
                                "data set is required", c["label"])
            if np.abs(c["offsets"] - first["offsets"]).max() * sk.scale > POSITION_TOL_M:
                raise DataError(f"OFFSETs differ from {first['label']}'s; one skeleton per data "
                                "set is required", c["label"])
            if abs(c["fps"] - first["fps"]) > FPS_RTOL * first["fps"]:
                raise DataError(f"{c['fps']:g} fps, {first['label']} has {first['fps']:g}",
                                c["label"])
        fps = round(first["fps"], 3)
        if spec.frames.fps is not None:
            if abs(spec.frames.fps - first["fps"]) > FPS_RTOL * spec.frames.fps:
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
        for c in clips:
            c["root"] = c["root"] * sk.scale
            if sk.up_axis == "z":
                _up_to_y(c)
            if spec.frames.resample_to is not None and abs(spec.frames.resample_to - fps) > 1e-9:
                q, r = resample_clip(c["quats"], c["root"], fps, spec.frames.resample_to)
                c["quats"], c["root"] = np.asarray(q), np.asarray(r)
        if spec.frames.resample_to is not None:
            fps = float(spec.frames.resample_to)
        order = sorted(range(len(clips)), key=lambda i: clips[i]["label"])
        stems = [Path(clips[i]["label"]).stem for i in order]
        seen: dict[str, str] = {}
        for i, st in zip(order, stems):
            if st in seen:
                raise DataError(f"two clips share the name {st!r}: {seen[st]} and "
                                f"{clips[i]['label']} (clip names must be unique)", source)
            seen[st] = clips[i]["label"]
        body = _body(skel, spec_path)
        labels, styles, classes, style_names, subjects, unused_rows = _labels_for(
            spec, here, stems)
        quats = [clips[i]["quats"].astype(np.float32) for i in order]
        roots = [clips[i]["root"].astype(np.float32) for i in order]
        joints = [forward_kinematics(skel, quat_to_matrix(q.astype(np.float64)),
                                     r.astype(np.float64)).astype(np.float32)
                  for q, r in zip(quats, roots)]
        lengths = np.array([q.shape[0] for q in quats], np.int64)
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
        if spec.split.by == "subject":
            try:
                split = subject_split(subjects, test_fraction=spec.split.test_fraction,
                                      seed=spec.split.seed)
            except ValueError as e:
                raise DataError(str(e), spec_path) from None
        else:
            split = stratified_split(labels, styles, test_fraction=spec.split.test_fraction,
                                     seed=spec.split.seed)
        _check_expect(spec, spec_path, len(stems), int(lengths.sum()), skel.n_joints)
        checks = _posture_checks(skel, body, joints, fps, spec_path)
        bare = [classes[c] for c in range(len(classes)) if not ((labels == c) & (split == 0)).any()]
        if bare:
            raise DataError(f"class(es) {', '.join(map(repr, bare))} have no training clip after "
                            f"the split (test_fraction {spec.split.test_fraction}); add clips or "
                            "lower test_fraction", spec_path)
        arrays = {"rotations": np.concatenate(quats), "root": np.concatenate(roots),
                  "joints": np.concatenate(joints), "starts": starts, "lengths": lengths,
                  "labels": labels, "styles": styles, "split": split}
        from repro import __version__

        meta = {"name": spec.name, "source_fingerprint": src_fp,
                "source_kind": "folder" if source.is_dir() else "archive",
                "spec_file": str(spec_path), "fps": fps, "skeleton": skel.to_dict(),
                "units": "metres, Y up",
                "rotations": f"local, xyzw, as the {fmt} files give them",
                "label_names": classes, "style_names": style_names, "clip_names": stems,
                **({"clip_subjects": subjects} if any(x is not None for x in subjects) else {}),
                "split": {"method": "subjects whole to test" if spec.split.by == "subject"
                          else "stratified(action, style)", **spec.split.model_dump()},
                "card": _card(spec, classes, style_names, labels, lengths, fps, subjects,
                              skipped, unused_rows, checks + _test_warnings(classes, labels, split)),
                "stats": {"clips": len(stems), "frames": int(lengths.sum())},
                "repro_version": __version__, "dataset_spec_version": PREPARE_VERSION}
        write_cache(root, fp, arrays, meta)
        write_json_atomic(root / POINTER, pointer)
    return PrepareResult(root / fp, fp, False, time.perf_counter() - t0, len(stems),
                         int(lengths.sum()))
