"""Declarative data sets: a user's own motion capture described by one TOML file (issue 16).

A data-set spec names where the files are, their format, how each clip gets its action label,
the skeleton's conventions, the frame rate and the split::

    schema = 1
    name = "mylab"                      # the name --dataset takes once registered
    description = "our lab's actions"
    license = "CC BY 4.0"

    [source]
    path = "mocap"                      # a folder or a .tar/.tar.gz/.tar.xz archive, relative
    format = "bvh"                      # to the spec file; "bvh" or "asf_amc"
    include = "*.bvh"                   # clip files, fnmatch over the path inside the source
                                        # ("*" crosses folders; default *.bvh / *.amc)
    # asf = "skeleton.asf"              # asf_amc: the one skeleton every AMC clip moves

    [labels]
    from = "filename"                   # "filename" (regex), "csv" or "json" (a side file)
    pattern = '^(?P<subject>s\\d+)_(?P<action>[a-z-]+)_\\d+$'   # over the file stem
    # file = "labels.csv"               # csv: columns clip, action[, style]; json: {clip: ...}
    # classes = ["walk", "jump"]        # the tag order (default: sorted names found)

    [skeleton]
    up_axis = "y"                       # "y" or "z" (z-up data is turned to y-up)
    units = "cm"                        # "m", "cm", "mm", "inch", or length_scale = 0.01
    # dummy_root = "reference"          # an all-zero root joint above the hips, dropped

    [frames]
    # fps = 30.0                        # expected rate (checked); default: the files'
    # resample_to = 30.0                # resample every clip (slerp / linear)

    [split]
    test_fraction = 0.2                 # stratified by action (and style when labelled)
    seed = 0

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

Registration: ``--dataset path/to/spec.toml`` anywhere a data set is named, or a folder of
spec files in ``$REPRO_DATASETS`` (os.pathsep-separated folders), each registered under its
``name``; a name may not shadow a built-in data set.
"""

from __future__ import annotations

import csv
import fnmatch
import io
import json
import os
import re
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from repro.errors import DataError, MissingDataError, SpecError

SCHEMA = 1
#: Bump when the conversion changes: it enters the cache fingerprint.
PREPARE_VERSION = 1
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "inch": 0.0254}
ENV = "REPRO_DATASETS"
#: how far (metres) clips' OFFSETs, or a joint's position channels from its OFFSET, may differ
#: and still be one skeleton (the built-in stand-in's 1e-3 cm)
POSITION_TOL_M = 1e-5
#: relative difference of frame rates that are one rate: files print their frame time rounded
#: (``0.008333`` is 120.005 fps)
FPS_RTOL = 1e-3


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)


class SourceSpec(_Strict):
    path: str = Field(description="folder or tar archive, relative to the spec file")
    format: Literal["bvh", "asf_amc"] = "bvh"
    include: str | None = Field(None, description="fnmatch pattern of clip files over the path "
                                "inside the source ('*' crosses folders; default *.bvh / *.amc)")
    asf: str | None = Field(None, description="asf_amc: the ASF skeleton file in the source")


class LabelSpec(_Strict):
    from_: Literal["filename", "csv", "json"] = Field("filename", alias="from")
    pattern: str | None = Field(None, description="regex over the file stem with group "
                                "'action' (and optionally 'style')")
    file: str | None = Field(None, description="csv/json side file, relative to the spec")
    classes: list[str] | None = None
    styles: list[str] | None = None

    @field_validator("pattern")
    @classmethod
    def _regex(cls, v):
        if v is None:
            return v
        try:
            rx = re.compile(v)
        except re.error as e:
            raise ValueError(f"not a regular expression ({e})") from None
        if "action" not in rx.groupindex:
            raise ValueError("the pattern needs a named group 'action': (?P<action>...)")
        return v


class SkeletonSpec(_Strict):
    up_axis: Literal["y", "z"] = "y"
    units: Literal["m", "cm", "mm", "inch"] = "cm"
    length_scale: float | None = Field(None, gt=0, description="metres per file unit "
                                       "(overrides units)")
    dummy_root: str | None = None

    @property
    def scale(self) -> float:
        return self.length_scale if self.length_scale is not None else UNITS[self.units]


class FramesSpec(_Strict):
    fps: float | None = Field(None, gt=0)
    resample_to: float | None = Field(None, gt=0)


class SplitSpec(_Strict):
    test_fraction: float = Field(0.2, gt=0, lt=1)
    seed: int = 0


class DatasetSpec(_Strict):
    schema_: Literal[1] = Field(alias="schema")
    name: str = Field(pattern=r"^[a-z0-9][a-z0-9._-]{0,63}$")
    description: str = ""
    license: str = "unknown"
    credit: str = ""
    source: SourceSpec
    labels: LabelSpec = LabelSpec()
    skeleton: SkeletonSpec = SkeletonSpec()
    frames: FramesSpec = FramesSpec()
    split: SplitSpec = SplitSpec()


def json_schema() -> dict:
    """The JSON Schema of a data-set spec (``repro data schema``)."""
    return DatasetSpec.model_json_schema(by_alias=True)


def load_dataset_spec(path: str | Path) -> DatasetSpec:
    """Read and validate a spec file; SpecError naming the file and field otherwise."""
    from repro.specs.load import _problems_from_validation, read_toml

    path = Path(path)
    data = read_toml(path)
    try:
        spec = DatasetSpec.model_validate(data)
    except ValidationError as e:
        from repro.specs.load import SpecValidationError

        raise SpecValidationError(_problems_from_validation(e, data, DatasetSpec, path),
                                  path) from None
    lab = spec.labels
    if lab.from_ == "filename" and not lab.pattern:
        raise SpecError("labels from 'filename' need a 'pattern'", path, "labels")
    if lab.from_ in ("csv", "json") and not lab.file:
        raise SpecError(f"labels from {lab.from_!r} need a 'file'", path, "labels")
    if spec.source.format == "asf_amc" and not spec.source.asf:
        raise SpecError("format 'asf_amc' needs 'asf' (the skeleton file)", path, "source")
    from repro.data.registry import builtin_names

    if spec.name in builtin_names():
        raise SpecError(f"name {spec.name!r} is a built-in data set; choose another", path,
                        "name")
    return spec


# ------------------------------------------------------------------------ registration
def spec_files() -> tuple[list[Path], list[Path]]:
    """(files named in ``$REPRO_DATASETS``, ``*.toml`` of the folders named there), sorted.
    A named file must be a valid spec; a folder's other files may be anything (only the
    valid specs among them are registered)."""
    named: list[Path] = []
    found: list[Path] = []
    for item in filter(None, os.environ.get(ENV, "").split(os.pathsep)):
        p = Path(item)
        if p.is_dir():
            found += sorted(p.glob("*.toml"))
        else:
            named.append(p)
    return named, found


def declared_specs() -> tuple[dict[str, tuple[Path, DatasetSpec]], list[str]]:
    """{name: (spec file, spec)} of every registered spec, and the problems of folder files skipped
    (not data-set specs, or invalid).  Two files declaring one name is a ConfigError naming
    both; so is a named file that is not a valid spec."""
    from repro.errors import ConfigError

    named, found = spec_files()
    out: dict[str, tuple[Path, DatasetSpec]] = {}
    skipped: list[str] = []
    for path, must in [(p, True) for p in named] + [(p, False) for p in found]:
        try:
            spec = load_dataset_spec(path)
        except SpecError as e:
            if must:
                raise
            skipped.append(str(e))
            continue
        other = out.get(spec.name)
        if other is not None and other[0].resolve() != path.resolve():
            raise ConfigError(f"data set {spec.name!r} is declared by two spec files: "
                              f"{other[0]} and {path}")
        out[spec.name] = (path, spec)
    return out, skipped


def spec_file_of(name: str) -> Path | None:
    """The registered spec file that declares ``name``, if any."""
    found = declared_specs()[0].get(name)
    return None if found is None else found[0]


def is_spec_path(text: str) -> bool:
    return text.endswith(".toml") and Path(text).is_file()


def register_spec_path(text: str) -> str:
    """Register the spec file ``text`` for this process and the job processes it starts (its
    path joins ``$REPRO_DATASETS``); returns the data set's name."""
    path = Path(text).resolve()
    spec = load_dataset_spec(path)
    items = [f for f in os.environ.get(ENV, "").split(os.pathsep) if f]
    if str(path) not in items:
        os.environ[ENV] = os.pathsep.join(items + [str(path)])
    from repro.data import registry

    registry.reset()
    return spec.name


def spec_key(spec: DatasetSpec, spec_path: Path) -> str:
    """What a prepared copy must have been made from, cheap to recompute on every load: the
    validated spec less its words (description, license, credit), the labels side file's
    bytes, and the source's size and modification time (its bytes enter the fingerprint at
    prepare time)."""
    import hashlib

    from repro.keys import content_key

    here = Path(spec_path).resolve().parent
    side = here / spec.labels.file if spec.labels.file else None
    src = here / spec.source.path
    try:
        st = src.stat()
        src_state = [st.st_size, st.st_mtime_ns] if src.is_file() else sorted(
            [q.relative_to(src).as_posix(), q.stat().st_size, q.stat().st_mtime_ns]
            for q in src.rglob("*") if q.is_file())
    except OSError:
        src_state = None
    return content_key({
        "spec": spec.model_dump(mode="json", by_alias=True,
                                exclude={"description", "license", "credit"}),
        "labels": hashlib.sha256(side.read_bytes()).hexdigest() if side and side.is_file()
        else None,
        "source": src_state})


def check_current(name: str, spec_path: Path, pointer: dict) -> str | None:
    """Why the prepared copy ``pointer`` (current.json) is not the one ``spec_path``
    describes now, or None."""
    try:
        spec = load_dataset_spec(spec_path)
    except SpecError as e:
        return str(e)
    if pointer.get("spec_file") != str(Path(spec_path).resolve()):
        made_from = pointer.get("spec_file") or "another spec file"
        return f"data set {name!r} was prepared from {made_from}, not {spec_path}"
    if pointer.get("spec_key") != spec_key(spec, spec_path):
        return (f"{spec_path}, its labels file or its source changed since data set {name!r} "
                "was prepared")
    return None


# ------------------------------------------------------------------------ reading files
def _iter_files(source: Path, pattern: str):
    """(label, bytes) of the files matching ``pattern`` (``fnmatch`` on the path inside the
    source) in a folder or tar archive, read as the built-in stand-in's are
    (:func:`repro.data.sources.iter_source`: one decompression pass, its size caps, no links
    out of a folder)."""
    from repro.data.sources import iter_source

    def kind(name: str) -> str | None:
        return "clip" if fnmatch.fnmatch(name, pattern) else None

    for _, label, data in iter_source(source, kind_of=kind):
        yield label, data


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


def _name(v, what: str, clip: str, where) -> str | None:
    """A label value as a non-empty name (``None`` stays None: no style)."""
    if v is None:
        return None
    if not isinstance(v, str) or not v.strip():
        raise DataError(f"clip {clip!r}: {what} must be a non-empty name, got {v!r:.60}", where)
    return v.strip()


def _side_table(lab: LabelSpec, side: Path) -> dict[str, tuple]:
    """clip -> (action, style) of a CSV or JSON labels file (duplicates refused)."""
    try:
        text = side.read_text(encoding="utf-8-sig")  # a spreadsheet's BOM is no header
    except OSError as e:
        raise MissingDataError(f"cannot read the labels file ({e.strerror})", side) from None
    except UnicodeDecodeError as e:
        raise DataError(f"the labels file is not UTF-8 text (byte {e.start})", side) from None
    table: dict[str, tuple] = {}

    def put(clip, action, style, where: str) -> None:
        clip = _name(clip, "the clip name", str(clip), side)
        if clip in table:
            raise DataError(f"clip {clip!r} is labelled twice ({where})", side)
        table[clip] = (_name(action, "action", clip, side), _name(style, "style", clip, side))

    if lab.from_ == "csv":
        reader = csv.DictReader(io.StringIO(text))
        reader.fieldnames = [f.strip() for f in reader.fieldnames or []]
        if not {"clip", "action"} <= set(reader.fieldnames):
            raise DataError("a labels CSV needs a header row with columns clip, action[, style]"
                            f" (found {reader.fieldnames})", side)
        for n, r in enumerate(reader, start=2):
            put(r.get("clip"), r.get("action"), r.get("style") or None, f"line {n}")
        return table
    try:
        raw = json.loads(text)
    except ValueError as e:
        raise DataError(f"not JSON ({e})", side) from None
    if not isinstance(raw, dict):
        raise DataError("labels JSON must map clip -> action or {action, style}", side)
    for k, v in raw.items():
        if isinstance(v, dict):
            put(k, v.get("action"), v.get("style"), f"key {k!r}")
        else:
            put(k, v, None, f"key {k!r}")
    return table


def _labels_for(spec: DatasetSpec, spec_dir: Path, stems: list[str]):
    """(labels, styles, class names, style names) of the clips ``stems`` (every name checked:
    a non-empty string, each clip labelled once, classes and styles unique and used)."""
    lab = spec.labels
    got: dict[str, tuple[str, str | None]] = {}
    where = spec_dir / (lab.file or spec.source.path)
    if lab.from_ == "filename":
        rx = re.compile(lab.pattern)
        for s in stems:
            m = rx.search(s)
            if m is None or m.group("action") is None:
                raise DataError(f"file name {s!r} does not match the labels pattern "
                                f"{lab.pattern!r}", where)
            got[s] = (_name(m.group("action"), "action", s, where),
                      _name(m.groupdict().get("style"), "style", s, where))
    else:
        table = _side_table(lab, where)
        for s in stems:
            if s not in table:
                raise DataError(f"clip {s!r} has no label", where)
            got[s] = table[s]
    for what, given in (("classes", lab.classes), ("styles", lab.styles)):
        if given is not None and len(set(given)) != len(given):
            raise DataError(f"[labels] {what} repeats a name: {given}", spec_dir)
    classes = list(lab.classes) if lab.classes else sorted({a for a, _ in got.values()})
    style_vals = {st for _, st in got.values() if st is not None}
    styles = list(lab.styles) if lab.styles else sorted(style_vals)
    cidx, sidx = {c: i for i, c in enumerate(classes)}, {s: i for i, s in enumerate(styles)}
    labels, style_ids = [], []
    for s in stems:
        a, st = got[s]
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
            styles if style_vals else [])


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


def _card(spec: DatasetSpec, classes, styles, labels, lengths, fps) -> dict:
    per_class = {}
    for i, n in enumerate(classes):
        ls = lengths[labels == i]
        per_class[n] = {"clips": int(ls.size), "frames": int(ls.sum()),
                        "seconds_mean": round(float(ls.mean()) / fps, 3) if ls.size else 0.0}
    return {"name": spec.name, "clips": int(lengths.size), "frames": int(lengths.sum()),
            "fps": fps, "class_names": list(classes), "style_names": list(styles),
            "per_class": per_class, "license": spec.license, "credit": spec.credit,
            "description": spec.description}


def prepare_dataset(spec_path: str | Path, *, force: bool = False):
    """Prepare the data set a spec file describes (module docstring); returns a
    :class:`repro.data.cache.PrepareResult`.  A cache of the same fingerprint is reused."""
    import hashlib
    import time

    from filelock import FileLock

    from repro.data.cache import (POINTER, PrepareResult, dataset_dir, valid_cache, write_cache,
                                  write_json_atomic)
    from repro.data.splits import stratified_split
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
    pattern = spec.source.include or ("*.bvh" if fmt == "bvh" else "*.amc")
    digest = hashlib.sha256()
    asf = None
    if fmt == "asf_amc":
        from repro.data import asf_amc

        asf_path = source / spec.source.asf if source.is_dir() else None
        if asf_path is None or not asf_path.is_file():
            raise MissingDataError("the spec's ASF skeleton file is not in the source folder",
                                   source / spec.source.asf)
        asf_bytes = asf_path.read_bytes()
        digest.update(b"asf\0" + hashlib.sha256(asf_bytes).digest())
        asf = asf_amc.parse_asf(asf_bytes, asf_path)
    from repro.data.sources import source_fingerprint

    if spec.labels.file:  # a side file of labels is part of what the data set is
        side = here / spec.labels.file
        if side.is_file():
            digest.update(b"labels\0" + hashlib.sha256(side.read_bytes()).digest())

    # the source is named by its bytes (as the built-in stand-in's), the spec by its content
    src_fp = source_fingerprint(source)
    pointer = {"fingerprint": None, "source": str(spec_path),
               "spec_file": str(spec_path.resolve()), "spec_key": spec_key(spec, spec_path)}
    fp = content_key({"kind": "dataset_spec", "version": PREPARE_VERSION,
                      "spec": spec.model_dump(mode="json", by_alias=True,
                                              exclude={"description", "license", "credit"}),
                      "source": src_fp, "asf": digest.hexdigest()})
    pointer["fingerprint"] = fp
    root = dataset_dir(spec.name)
    root.mkdir(parents=True, exist_ok=True)
    with FileLock(str(root / ".lock")):
        meta = None if force else valid_cache(root / fp)
        if meta is not None:
            write_json_atomic(root / POINTER, pointer)
            return PrepareResult(root / fp, fp, True, time.perf_counter() - t0,
                                 len(meta["clip_names"]), int(meta["stats"]["frames"]))
        sk = spec.skeleton
        clips = []
        for label, data in _iter_files(source, pattern):  # converted as they stream
            clips.append(_convert_bvh(label, data, sk) if fmt == "bvh" else
                         _convert_amc(label, data, asf, sk, spec.frames.fps))
        if not clips:
            raise DataError(f"no file matches {pattern!r}", source)
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
        skel = Skeleton(tuple(first["names"]), tuple(first["parents"]),
                        first["offsets"] * sk.scale)
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
        from repro.motion.heading import body_frame

        try:  # every protocol finds the body's heading from the hips, by name
            body_frame(skel)
        except ValueError as e:
            raise DataError(f"{e} (the harness finds the hips by joint names such as "
                            "LeftUpLeg / UpperLeg_L / l_hip; rename them in the files)",
                            spec_path) from None
        labels, styles, classes, style_names = _labels_for(spec, here, stems)
        quats = [clips[i]["quats"].astype(np.float32) for i in order]
        roots = [clips[i]["root"].astype(np.float32) for i in order]
        joints = [forward_kinematics(skel, quat_to_matrix(q.astype(np.float64)),
                                     r.astype(np.float64)).astype(np.float32)
                  for q, r in zip(quats, roots)]
        lengths = np.array([q.shape[0] for q in quats], np.int64)
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
        split = stratified_split(labels, styles, test_fraction=spec.split.test_fraction,
                                 seed=spec.split.seed)
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
                "split": {"method": "stratified(action, style)", **spec.split.model_dump()},
                "card": _card(spec, classes, style_names, labels, lengths, fps),
                "stats": {"clips": len(stems), "frames": int(lengths.sum())},
                "repro_version": __version__, "dataset_spec_version": PREPARE_VERSION}
        write_cache(root, fp, arrays, meta)
        write_json_atomic(root / POINTER, pointer)
    return PrepareResult(root / fp, fp, False, time.perf_counter() - t0, len(stems),
                         int(lengths.sum()))
