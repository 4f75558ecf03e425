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
    # file = "labels.csv"               # csv: columns clip, action[, style][, subject]
    # classes = ["walk", "jump"]        # the tag order (default: sorted names found)

    [skeleton]
    up_axis = "y"                       # "y" or "z" (z-up data is turned to y-up)
    units = "cm"                        # "m", "cm", "mm", "inch", or length_scale = 0.01
    # dummy_root = "reference"          # an all-zero root joint above the hips, dropped
    # hips = ["lfemur", "rfemur"]       # the heading's hip joints when not found by name
    # up_joint = "head"                 # a joint above the pelvis, likewise

    [frames]
    # fps = 30.0                        # expected rate (checked); default: the files'
    # resample_to = 30.0                # resample every clip (slerp / linear)

    [split]
    test_fraction = 0.2                 # stratified by action (and style when labelled)
    seed = 0
    # by = "subject"                    # whole subjects to test (needs subject labels)

    [expect]                            # optional facts checked at prepare (and on reuse)
    # clips = 120
    # frames = 36000
    # joints = 31

Preparing (reading, converting, labelling, splitting) lives in :mod:`repro.data.dataset_prepare`.

Registration: ``--dataset path/to/spec.toml`` anywhere a data set is named, or a folder of
spec files in ``$REPRO_DATASETS`` (os.pathsep-separated folders), each registered under its
``name``; a name may not shadow a built-in data set.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from repro.errors import SpecError

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
                                "inside the source, case-insensitive ('*' crosses folders; "
                                "default *.bvh / *.amc)")
    asf: str | None = Field(None, description="asf_amc: the ASF skeleton file, its path inside "
                            "the source folder or archive (case-insensitive)")

    @field_validator("asf")
    @classmethod
    def _inside(cls, v):
        if v is None:
            return v
        parts = v.replace("\\", "/").split("/")
        if v.startswith(("/", "\\")) or ".." in parts or ":" in parts[0]:
            raise ValueError("the ASF file is named by its path inside the source (no '..', "
                             "not absolute)")
        return "/".join(q for q in parts if q not in ("", "."))


class LabelSpec(_Strict):
    from_: Literal["filename", "csv", "json"] = Field("filename", alias="from")
    pattern: str | None = Field(None, description="regex over the file stem with group "
                                "'action' (and optionally 'style', 'subject')")
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
    hips: list[str] | None = Field(None, min_length=2, max_length=2, description="the (left, "
                                   "right) hip joints the body's heading is taken from, when "
                                   "their names are not ones the harness knows")
    up_joint: str | None = Field(None, description="a joint above the pelvis (head, neck, "
                                 "spine) giving the body's up direction, when not found by name")

    @field_validator("hips")
    @classmethod
    def _two_hips(cls, v):
        if v is not None and (len(set(v)) != 2 or not all(n.strip() for n in v)):
            raise ValueError("hips names two different joints: [left, right]")
        return v

    @property
    def scale(self) -> float:
        return self.length_scale if self.length_scale is not None else UNITS[self.units]


class FramesSpec(_Strict):
    fps: float | None = Field(None, gt=0)
    resample_to: float | None = Field(None, gt=0)


class SplitSpec(_Strict):
    test_fraction: float = Field(0.2, gt=0, lt=1)
    seed: int = 0
    by: Literal["clip", "subject"] = Field("clip", description="'clip': stratified by action "
                                           "(and style); 'subject': whole subjects go to test "
                                           "(needs subject labels)")


class ExpectSpec(_Strict):
    """Facts the prepared data must show (a truncated download, a missing folder or a wrong
    skeleton then ends in one error naming every disagreement instead of a smaller data set)."""

    clips: int | None = Field(None, gt=0)
    frames: int | None = Field(None, gt=0)
    joints: int | None = Field(None, gt=0, description="after a dummy root is dropped")


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
    expect: ExpectSpec | None = None


#: fields added after the first data-set specs were prepared: left out of the key material
#: while at their defaults, so a spec that does not use them keeps its fingerprint
_LATER_DEFAULTS = {("skeleton", "hips"): None, ("skeleton", "up_joint"): None,
                   ("split", "by"): "clip"}
#: the built-in stand-in's own declaration (:mod:`repro.data.bandai` reads its facts from it)
BUILTIN_SPECS = {"bandai2": "bandai2.toml"}


def key_material(spec: DatasetSpec) -> dict:
    """The spec as it enters a prepared copy's fingerprint and :func:`spec_key`: validated,
    less its words (description, license, credit: editing them retrains nothing) and less the
    later fields at their defaults."""
    d = spec.model_dump(mode="json", by_alias=True, exclude={"description", "license", "credit"})
    for (section, field), default in _LATER_DEFAULTS.items():
        if d[section].get(field) == default:
            d[section].pop(field, None)
    d.pop("expect", None)  # a check on the prepared data, not part of what it is
    return d


def clip_pattern(spec: DatasetSpec) -> str:
    """The spec's ``include`` pattern, or the format's default."""
    return spec.source.include or ("*.bvh" if spec.source.format == "bvh" else "*.amc")


def matches(name: str, pattern: str) -> bool:
    """``fnmatch`` of a path inside the source, case-insensitive on every system (``*.bvh``
    takes ``TAKE01.BVH``)."""
    import fnmatch

    return fnmatch.fnmatchcase(name.lower(), pattern.lower())


def role_of(spec: DatasetSpec, name: str) -> str | None:
    """What the spec reads a file of the source as (its path inside the source): "asf",
    "clip", or None (not read)."""
    if spec.source.asf and name.strip("/").lower() == spec.source.asf.lower():
        return "asf"
    return "clip" if matches(name, clip_pattern(spec)) else None


def builtin_spec_path(name: str) -> Path:
    """The shipped spec file that declares the built-in data set ``name``."""
    from repro.data.bundle import bundled_dir

    return bundled_dir() / BUILTIN_SPECS[name]


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

        raise SpecValidationError(_problems_from_validation(e, data, DatasetSpec, path), path,
                                  check_command=f"repro data check {path}") from None
    lab = spec.labels
    if lab.from_ == "filename" and not lab.pattern:
        raise SpecError("labels from 'filename' need a 'pattern'", path, "labels")
    if lab.from_ in ("csv", "json") and not lab.file:
        raise SpecError(f"labels from {lab.from_!r} need a 'file'", path, "labels")
    if spec.source.format == "asf_amc" and not spec.source.asf:
        raise SpecError("format 'asf_amc' needs 'asf' (the skeleton file)", path, "source")
    if spec.split.by == "subject" and not _has_subjects(lab):
        raise SpecError("split by 'subject' needs subject labels: a (?P<subject>...) group in "
                        "the pattern, or a subject column/key in the labels file", path, "split")
    from repro.data.registry import builtin_names

    if spec.name in builtin_names() and not (
            spec.name in BUILTIN_SPECS and path.resolve() == builtin_spec_path(spec.name).resolve()):
        raise SpecError(f"name {spec.name!r} is a built-in data set; choose another", path,
                        "name")
    return spec


def _has_subjects(lab: LabelSpec) -> bool:
    """Whether the labels can name subjects (a side file may; checked again at prepare)."""
    return lab.from_ != "filename" or "subject" in re.compile(lab.pattern or "").groupindex


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
    try:  # a folder: only the files the spec reads (another file beside them changes nothing)
        st = src.stat()
        src_state = [st.st_size, st.st_mtime_ns] if src.is_file() else sorted(
            [r, q.stat().st_size, q.stat().st_mtime_ns] for q in src.rglob("*")
            if q.is_file() and role_of(spec, r := q.relative_to(src).as_posix()))
    except OSError:
        src_state = None
    return content_key({
        "spec": key_material(spec),
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
