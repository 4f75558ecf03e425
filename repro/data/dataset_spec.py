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
                                        # ("*" crosses folders; default *.bvh / *.amc); a list
    # exclude = ["*_calib*.bvh"]        # files include takes that are not read
    # asf = "skeleton.asf"              # asf_amc: the one skeleton every AMC clip moves, or
    # asf = "*.asf"                     # a pattern: each AMC takes the nearest ASF it matches
                                        # (its own folder first; CMU: one ASF per subject)

    [labels]
    from = "filename"                   # "filename" (regex), "csv" or "json" (a side file)
    pattern = '^(?P<subject>s\\d+)_(?P<action>[a-z-]+)_\\d+$'   # over the file stem
    # file = "labels.csv"               # csv: columns clip, action[, style][, subject]
    # classes = ["walk", "jump"]        # the tag order (default: sorted names found); a
                                        # subset drops the other actions' clips
    # unlisted = "drop"                 # clips the labels do not name: left out ("error")

    [skeleton]
    up_axis = "y"                       # "y" or "z" (z-up data is turned to y-up)
    units = "cm"                        # "m", "cm", "mm", "inch", or length_scale = 0.01
    # dummy_root = "reference"          # an all-zero root joint above the hips, dropped
    # hips = ["lfemur", "rfemur"]       # the heading's hip joints when not found by name
    # up_joint = "head"                 # a joint above the pelvis, likewise
    # offset_tolerance = 0.001          # metres two clips' OFFSETs may differ (default 1e-5)
    # fold_dummy_root = true            # a dummy root that moves: its motion joins the hips

    [frames]
    # fps = 30.0                        # expected rate (checked); default: the files'
    # resample_to = 30.0                # resample every clip (slerp / linear)

    [split]
    test_fraction = 0.2                 # stratified by action (and style when labelled)
    seed = 0
    # by = "subject"                    # whole subjects (or "style": styles) to test
    # stratify = "action"               # by subject: every action on both sides

    [expect]                            # optional facts checked at prepare (and on reuse)
    # clips = 120
    # frames = 36000
    # joints = 31

Preparing (reading, converting, labelling, splitting) lives in :mod:`repro.data.dataset_prepare`.

Registration (``--dataset path/to/spec.toml`` anywhere a data set is named, or spec files in
``$REPRO_DATASETS``, each registered under its ``name``; a name may not shadow a built-in data
set) and the checks that a prepared copy is still the one its spec describes live in
:mod:`repro.data.dataset_registration`.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Literal

from pydantic import (BaseModel, ConfigDict, Field, ValidationError, field_validator,
                      model_validator)

from repro.data.label_pattern import (MAX_PATTERN_CHARS, MAX_PATTERN_DEPTH,  # noqa: F401
                                      MAX_PATTERN_REPEAT, pattern_problem)
from repro.errors import SpecError

SCHEMA = 1
#: Bump when the conversion changes: it enters the cache fingerprint.
PREPARE_VERSION = 1
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "inch": 0.0254}
#: how far (metres) clips' OFFSETs, or a joint's position channels from its OFFSET, may differ
#: and still be one skeleton (the built-in stand-in's 1e-3 cm)
POSITION_TOL_M = 1e-5
#: relative difference of frame rates that are one rate: files print their frame time rounded
#: (``0.008333`` is 120.005 fps)
FPS_RTOL = 1e-3
#: Largest data-set spec file (bytes) read, and largest labels side file (CSV or JSON): both are
#: read through :func:`repro.data.sources.read_regular` (regular files only, at most cap + 1
#: bytes; issue 29: ``/dev/zero`` or a 3 GB sparse CSV was read whole).  A real spec is a few
#: KB; a labels file for 100,000 clips is a few MB.
MAX_SPEC_BYTES = 1024 ** 2
MAX_LABELS_BYTES = 16 * 1024 ** 2
#: Label patterns (issue 29) are checked for their shape by
#: :func:`repro.data.label_pattern.pattern_problem` (caps on length, nesting and counts; no
#: nested repeat or alternation in a repeat of the shapes that backtrack without end) and
#: matched under a time bound: :data:`MATCH_SECONDS` for all the file names together.
MATCH_SECONDS = 5.0


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, populate_by_name=True)


#: the characters a name may not hold (:func:`bad_char`)
NAME_UNSAFE = re.compile("[\x00-\x1f\x7f-\x9f\ud800-\udfff\u2028\u2029\u202a-\u202e"
                         "\u2066-\u2069]")


def bad_char(text: str) -> str | None:
    """The first character of ``text`` that a name may not hold, or None: C0 controls (ESC,
    BEL, NUL ...), DEL, C1 controls (U+0080-U+009F: U+009B is a terminal's CSI, U+0085 a line
    break), lone surrogates (not text: printing one fails), line/paragraph separators and the
    bidirectional overrides (issue 29: such names reached the terminal raw)."""
    m = NAME_UNSAFE.search(text)
    return m.group() if m else None


def escape_name(text: str) -> str:
    """``text`` with every character :func:`bad_char` refuses written as its Python escape
    (``\\x1b``, ``\\udcff``): for names shown on the card or in a warning."""
    return NAME_UNSAFE.sub(lambda m: ascii(m.group())[1:-1], text)


def _no_controls(v, what: str):
    """A field validator's check: ``v`` (a string or list of strings) holds no :func:`bad_char`."""
    for x in [v] if isinstance(v, str) else (v or []):
        ch = bad_char(x)
        if ch is not None:
            raise ValueError(f"{what} may not hold the control character U+{ord(ch):04X}")
    return v


def _refuse_controls(what: str, *fields: str):
    """A field validator of ``fields``: :func:`_no_controls`, ``what`` naming the value."""
    return field_validator(*fields)(lambda v: _no_controls(v, what))


class SourceSpec(_Strict):
    path: str = Field(description="folder or tar archive, relative to the spec file")
    format: Literal["bvh", "asf_amc"] = "bvh"
    include: str | list[str] | None = Field(
        None, description="fnmatch pattern (or list of patterns) of clip files over the path "
        "inside the source, case-insensitive ('*' crosses folders; default *.bvh / *.amc)")
    exclude: str | list[str] | None = Field(
        None, description="fnmatch pattern (or list) of files the include patterns take but "
        "that are not read (issue 28)")
    asf: str | None = Field(None, description="asf_amc: the ASF skeleton file, its path inside "
                            "the source folder or archive (case-insensitive); or a pattern "
                            "(with * ? or [): each AMC clip takes the ASF it matches in its own "
                            "folder, else in the nearest folder above (CMU: one per subject)")

    _plain = _refuse_controls("a path", "path")

    @field_validator("include", "exclude")
    @classmethod
    def _patterns(cls, v):
        """A list of one pattern is that pattern (one spelling, one key); an empty list or an
        empty pattern is refused (it would take nothing, or everything, silently)."""
        _no_controls(v, "a path")
        if isinstance(v, list):
            if not v:
                raise ValueError("give at least one pattern (or leave the field out)")
            if len(set(v)) != len(v):
                raise ValueError("a pattern is listed twice")
            if len(v) == 1:
                v = v[0]
        for x in [v] if isinstance(v, str) else (v or []):
            if not x.strip():
                raise ValueError("a pattern may not be empty")
        return v

    @field_validator("asf")
    @classmethod
    def _inside(cls, v):
        if v is None:
            return v
        _no_controls(v, "a path")
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
    classes: list[str] | None = Field(None, description="the tag order; a subset of the "
                                      "actions found drops the clips of every other action")
    styles: list[str] | None = None
    unlisted: Literal["error", "drop"] = Field(
        "error", description="a clip the labels do not name (no row in the side file, a file "
        "name the pattern does not match): 'error' refuses the data set, 'drop' leaves the "
        "clip out (counted on the card)")

    _plain = _refuse_controls("a path", "file")
    _names = _refuse_controls("a name", "classes", "styles")

    @field_validator("pattern")
    @classmethod
    def _regex(cls, v):
        if v is None:
            return v
        why = pattern_problem(v)
        if why is not None:
            raise ValueError(why)
        rx = re.compile(v)
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
    offset_tolerance: float | None = Field(None, gt=0, le=1.0, description="metres by which "
                                           "clips' OFFSETs (each coordinate), or a joint's "
                                           "position channels from its OFFSET, may differ and "
                                           "still be one skeleton (default 1e-5); every clip is "
                                           "then posed on the reference clip's skeleton")
    fold_dummy_root: bool = Field(False, description="with dummy_root: compose the dummy's "
                                  "motion (translation and rotation) into its child, the new "
                                  "root, instead of refusing a dummy that moves")

    @model_validator(mode="after")
    def _fold_needs_dummy(self):
        if self.fold_dummy_root and self.dummy_root is None:
            raise ValueError("fold_dummy_root needs dummy_root (the joint whose motion is "
                             "folded into its child)")
        return self

    @property
    def offset_tol(self) -> float:
        """The tolerance in metres: ``offset_tolerance``, else :data:`POSITION_TOL_M`."""
        return self.offset_tolerance if self.offset_tolerance is not None else POSITION_TOL_M

    @field_validator("hips")
    @classmethod
    def _two_hips(cls, v):
        if v is not None and (len(set(v)) != 2 or not all(n.strip() for n in v)):
            raise ValueError("hips names two different joints: [left, right]")
        return v

    @property
    def scale(self) -> float:
        return self.length_scale if self.length_scale is not None else UNITS[self.units]


#: bounds of ``[frames]`` (issue 29): a capture's rate is at most 10 kHz (high-speed systems
#: record 2 kHz), and a clip is resampled to 1 to 1,000 fps (the papers use 20 to 120)
MAX_FPS = 10_000.0
RESAMPLE_RANGE = (1.0, 1000.0)


class FramesSpec(_Strict):
    fps: float | None = Field(None, gt=0, le=MAX_FPS, description="the files' frame rate "
                              "(checked), at most 10,000")
    resample_to: float | None = Field(None, ge=RESAMPLE_RANGE[0], le=RESAMPLE_RANGE[1],
                                      description="resample every clip to this rate, 1 to "
                                      "1,000 fps (a clip must keep at least 2 frames)")


class SplitSpec(_Strict):
    test_fraction: float = Field(0.2, gt=0, lt=1)
    seed: int = 0
    by: Literal["clip", "subject", "style"] = Field(
        "clip", description="'clip': stratified by action (and style); 'subject' / 'style': "
        "whole subjects / styles go to test (needs subject / style labels)")
    stratify: Literal["action"] | None = Field(
        None, description="with by = 'subject': choose the whole subjects so that every action "
        "has test and training clips (repro.data.splits.group_split); by = 'style' always does")

    @model_validator(mode="after")
    def _stratify_needs_groups(self):
        if self.stratify is not None and self.by == "clip":
            raise ValueError("stratify is for by = 'subject' or 'style' (by = 'clip' is "
                             "stratified by action and style already)")
        return self

    @property
    def grouped_by_action(self) -> bool:
        """Whether the split keeps groups whole *and* covers every action
        (:func:`repro.data.splits.group_split`)."""
        return self.by == "style" or (self.by == "subject" and self.stratify == "action")


class ExpectSpec(_Strict):
    """Facts the prepared data must show (a truncated download, a missing folder or a wrong
    skeleton then ends in one error naming every disagreement instead of a smaller data set)."""

    clips: int | None = Field(None, gt=0)
    frames: int | None = Field(None, gt=0)
    joints: int | None = Field(None, gt=0, description="after a dummy root is dropped")


class LimitsSpec(_Strict):
    """Overrides of the caps on what preparing this data set may hold
    (:mod:`repro.data.prepare_caps`, docs/data.md "Frames and memory"); a key left out keeps
    the built-in cap.  Caps change what is refused, never the bytes prepared, so the table is
    not part of the fingerprint (:func:`key_material`).  The upper bounds keep a typo from
    lifting every cap: a clip at most 10 million frames (``bvh.MAX_FRAMES``), 200 million
    frame-joints (~34 GB), a data set at most 100 million frames, 2 billion frame-joints."""

    max_clip_frames: int | None = Field(None, ge=1, le=10_000_000, strict=True,
                                        description="frames of one clip after resampling")
    max_clip_joint_frames: int | None = Field(None, ge=1, le=200_000_000, strict=True,
                                              description="frames × joints of one clip (about "
                                              "170 bytes of memory each)")
    max_total_frames: int | None = Field(None, ge=1, le=100_000_000, strict=True,
                                         description="frames of every clip after resampling")
    max_total_joint_frames: int | None = Field(None, ge=1, le=2_000_000_000, strict=True,
                                               description="frames × joints of every clip after "
                                               "resampling (about 60 bytes of memory each)")


class GateSpec(_Strict):
    """The real-data gate (:mod:`repro.eval.gate`) on this data set's table runs: a small set
    whose real accuracy falls further below the classifier's test accuracy than the profile's
    ``gate_margin`` can relax it here instead of in a copy of ``tables/scales.toml``.  A run
    under a relaxed gate says so in its record, footer and report; ``--gate-margin`` and
    ``--no-gate`` on the command line win over this.  Not part of the fingerprint
    (:func:`key_material`): the gate decides whether methods are scored, never what the
    prepared clips hold."""

    enabled: bool = Field(True, strict=True, description="false: the gate is reported, "
                          "never fails the run")
    margin: float | None = Field(None, ge=0, le=1, description="real accuracy may fall this "
                                 "far below the classifier's test accuracy (default: the scale "
                                 "profile's real.gate_margin, 0.05)")


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
    limits: LimitsSpec = LimitsSpec()
    gate: GateSpec = GateSpec()


#: fields added after the first data-set specs were prepared: left out of the key material
#: while at their defaults, so a spec that does not use them keeps its fingerprint
_LATER_DEFAULTS = {("skeleton", "hips"): None, ("skeleton", "up_joint"): None,
                   ("split", "by"): "clip", ("source", "exclude"): None,
                   ("labels", "unlisted"): "error", ("split", "stratify"): None}
#: issue 28: the skeleton's tolerance and the dummy-root fold (both change what is prepared:
#: a clip accepted under a wider tolerance is posed on the reference skeleton)
_LATER_DEFAULTS.update({("skeleton", "offset_tolerance"): None,
                        ("skeleton", "fold_dummy_root"): False})
#: the built-in stand-in's own declaration (:mod:`repro.data.bandai` reads its facts from it)
BUILTIN_SPECS = {"bandai2": "bandai2.toml"}


def key_material(spec: DatasetSpec) -> dict:
    """The spec as it enters a prepared copy's fingerprint and :func:`spec_key`: validated,
    less its words (description, license, credit: editing them retrains nothing), its
    ``[expect]``, ``[limits]`` and ``[gate]`` and the later fields at their defaults."""
    d = spec.model_dump(mode="json", by_alias=True, exclude={"description", "license", "credit"})
    for (section, field), default in _LATER_DEFAULTS.items():
        if d[section].get(field) == default:
            d[section].pop(field, None)
    d.pop("expect", None)  # a check on the prepared data, not part of what it is
    d.pop("limits", None)  # caps refuse data; they never change the bytes prepared
    d.pop("gate", None)  # whether a run may score methods, not what the clips are
    return d


#: How an archive's clips are named, in the key of archive sources only (issue 29): a member
#: at an archive's root was named ``clips.tar.xz:stem`` and is now ``stem``, so a copy
#: prepared under the old rule must not be reused.  Folder sources (and the built-in sets,
#: keyed by :mod:`repro.data.bandai`) keep their fingerprints.
ARCHIVE_NAMING = {"archive_root_names": "stem"}


def naming_material(source: Path) -> dict:
    """:data:`ARCHIVE_NAMING` when ``source`` is an archive (a regular file), else ``{}``."""
    try:
        return dict(ARCHIVE_NAMING) if source.is_file() else {}
    except (OSError, ValueError):
        return {}


def clip_patterns(spec: DatasetSpec) -> list[str]:
    """The spec's ``include`` patterns, or the format's default."""
    inc = spec.source.include or ("*.bvh" if spec.source.format == "bvh" else "*.amc")
    return [inc] if isinstance(inc, str) else list(inc)


def exclude_patterns(spec: DatasetSpec) -> list[str]:
    """The spec's ``exclude`` patterns (none by default)."""
    exc = spec.source.exclude
    return [] if exc is None else [exc] if isinstance(exc, str) else list(exc)


def matches(name: str, pattern: str) -> bool:
    """``fnmatch`` of a path inside the source, case-insensitive on every system (``*.bvh``
    takes ``TAKE01.BVH``)."""
    import fnmatch

    return fnmatch.fnmatchcase(name.lower(), pattern.lower())


def is_pattern(asf: str) -> bool:
    """Whether the spec's ``asf`` is a pattern (``*``, ``?`` or ``[``: one ASF per folder,
    :mod:`repro.data.dataset_asf`) rather than one file's path."""
    return any(c in asf for c in "*?[")


def role_of(spec: DatasetSpec, name: str) -> str | None:
    """What the spec reads a file of the source as (its path inside the source): "asf",
    "clip", or None (not read)."""
    asf = spec.source.asf
    if asf and (matches(name.strip("/"), asf) if is_pattern(asf)
                else name.strip("/").lower() == asf.lower()):
        return "asf"
    if not any(matches(name, p) for p in clip_patterns(spec)):
        return None
    return None if any(matches(name, p) for p in exclude_patterns(spec)) else "clip"


def is_excluded(spec: DatasetSpec, name: str) -> bool:
    """Whether the file ``name`` (its path inside the source) is one an ``include`` pattern
    takes and an ``exclude`` pattern leaves out."""
    return any(matches(name, p) for p in exclude_patterns(spec)) and \
        any(matches(name, p) for p in clip_patterns(spec))


def builtin_spec_path(name: str) -> Path:
    """The shipped spec file that declares the built-in data set ``name``."""
    from repro.data.bundle import bundled_dir

    return bundled_dir() / BUILTIN_SPECS[name]


def json_schema() -> dict:
    """The JSON Schema of a data-set spec (``repro data schema``)."""
    return DatasetSpec.model_json_schema(by_alias=True)


def load_dataset_spec(path: str | Path) -> DatasetSpec:
    """Read and validate a spec file; SpecError naming the file and field otherwise."""
    from repro.specs.load import problems_from_validation, read_toml

    path = Path(path)
    # read once, a regular file of at most MAX_SPEC_BYTES (a FIFO or a device is refused)
    data = read_toml(path, MAX_SPEC_BYTES, "the data-set spec")
    try:
        spec = DatasetSpec.model_validate(data)
    except ValidationError as e:
        from repro.specs.load import SpecValidationError

        raise SpecValidationError(problems_from_validation(e, data, DatasetSpec, path), path,
                                  check_command=f"repro data check {path}") from None
    lab = spec.labels
    if lab.from_ == "filename" and not lab.pattern:
        raise SpecError("labels from 'filename' need a 'pattern'", path, "labels")
    if lab.from_ in ("csv", "json") and not lab.file:
        raise SpecError(f"labels from {lab.from_!r} need a 'file'", path, "labels")
    if spec.source.format == "asf_amc" and not spec.source.asf:
        raise SpecError("format 'asf_amc' needs 'asf' (the skeleton file)", path, "source")
    for group in ("subject", "style"):
        if spec.split.by == group and not _has_group(lab, group):
            raise SpecError(f"split by {group!r} needs {group} labels: a (?P<{group}>...) group "
                            f"in the pattern, or a {group} column/key in the labels file", path,
                            "split")
    from repro.data.builtin_sets import builtin_names

    if spec.name in builtin_names() and not (
            spec.name in BUILTIN_SPECS and path.resolve() == builtin_spec_path(spec.name).resolve()):
        raise SpecError(f"name {spec.name!r} is a built-in data set; choose another", path,
                        "name")
    return spec


def _has_group(lab: LabelSpec, group: str) -> bool:
    """Whether the labels can name ``group`` (subject, style) for each clip (a side file may;
    checked again at prepare)."""
    return lab.from_ != "filename" or group in re.compile(lab.pattern or "").groupindex
