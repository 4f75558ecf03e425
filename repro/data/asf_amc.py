"""Acclaim ASF (skeleton) and AMC (motion) files, as published by CMU MoCap.

:func:`parse_asf`/:func:`read_asf` give an :class:`Asf`; :func:`parse_amc`/:func:`read_amc` give
an :class:`AmcMotion` checked against it; :func:`to_skeleton_motion` turns both into the project's
kinematic model (:mod:`repro.motion.skeleton`).  Malformed input raises
:class:`repro.errors.DataError` naming the file, the line and the problem (quotes clipped).

Text: ``#`` starts a comment; commas and parentheses are whitespace; CR LF and CR line ends read
as LF; keywords and dof/order tokens are case-insensitive, bone names are not.  ASF sections:
``:version``, ``:name``, ``:units`` (``mass``, ``length``, ``angle deg|rad``; default 1, 1, deg),
``:documentation``, ``:root`` (``order``, ``axis``, ``position``, ``orientation``), ``:bonedata``
(``begin``/``end`` blocks of ``id``, ``name``, ``direction``, ``length``, ``axis a b c XYZ``,
``dof``, ``limits`` -- which may span lines -- and the ignored ``bodymass``/``cofmass``) and
``:hierarchy``; other ``:sections`` (``:skin``) are skipped.  AMC: header keywords
``:FULLY-SPECIFIED``, ``:DEGREES``, ``:RADIANS`` (neither: the ASF's angle unit; others ignored),
then frames: an integer line (each one more than the last) and ``bone v1 v2 ...`` lines, values
in the bone's ``dof`` order (the root's ``order``).  A frame must give every bone with dofs
(missing values are refused, not guessed).

Angles: an Euler order such as ``XYZ`` and a dof list such as ``rx ry rz`` mean rotations about
*fixed* axes applied in the listed order: with column vectors ``XYZ`` gives ``Rz·Ry·Rx`` and
``rz rx`` gives ``Rx·Rz``; unlisted rotation dofs are zero.  The three numbers of ``axis`` and
``orientation`` are the angles about X, Y and Z, whatever the order token (CMU always writes
``XYZ``, where every reading agrees).  ASF angles use ``:units angle``.

Kinematics (derivation).  Bone ``b`` with parent ``p`` has ``d_b`` (unit ``direction``, world
frame at rest), ``l_b`` (``length``), ``C_b`` (rotation of ``axis``) and, per frame, ``M_b``
(rotation of its dof values).  ``M_b`` acts in the bone's axis frame, whose rest orientation is
``C_b``, so the bone's world rotation is ``W_b = W_p · C_b · M_b · C_b⁻¹``; the root's is
``W_root = O · M_root`` (``O``: ``orientation`` in the root ``axis`` order).  A bone starts where
its parent ends, ``s_b = s_p + W_p · d_p l_p``; the root's children start at the root position
``P + O · T`` (``P``: ``position``, ``T``: the AMC translation; ``position``/``orientation`` are
one rigid placement of the whole motion).  The project's FK computes
``pos_j = pos_parent + G_parent · offset_j`` with ``G_j = G_parent · L_j``.  Joint ``j`` = bone
``b`` with world-aligned rest frames (``G_j = W_b``, the identity at rest, as in BVH) gives
``L_j = W_p⁻¹ W_b = C_b · M_b · C_b⁻¹`` and ``offset_j = d_p l_p`` (zero for the root's
children), and the root joint ``L = O · M_root`` at ``P + O · T``.  (Axis frames as joint frames,
``G_j = W_b C_b``, would give ``L_j = C_p⁻¹ C_b M_b`` and ``offset_j = C_p⁻¹ d_p l_p``: the same
positions, but a rest pose that is not the identity; not used.)  Joint positions are bone
*starts*; ``leaf_ends=True`` adds a ``<bone>_end`` joint at the end of each leaf bone.

Not supported (:func:`to_skeleton_motion` raises a DataError naming the ASF's dof line):
translation dofs ``tx ty tz`` and the length dof ``l`` on non-root bones.  Units: bone lengths
and root position/translation are multiplied by ``length_scale``, by default
``1 / (:units length)``, which undoes the ASF's length multiplier (CMU's ``length 0.45`` → inches;
pass :data:`CMU_METRES_PER_UNIT` for metres).  AMC files store no frame rate: ``fps`` defaults
to 120 Hz (CMU's).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from repro.errors import DataError

#: Metres per CMU ASF length unit (``:units length 0.45``, the inch being the local unit).
CMU_METRES_PER_UNIT = 0.0254 / 0.45
#: Frame rate assumed for AMC files (they store none); CMU captured at 120 Hz.
DEFAULT_FPS = 120.0
ROT_DOFS = ("rx", "ry", "rz")
BONE_DOFS = ("rx", "ry", "rz", "tx", "ty", "tz", "l")
ROOT_DOFS = ("tx", "ty", "tz", "rx", "ry", "rz")
_BONE_KEYS = ("id", "name", "direction", "length", "axis", "dof", "limits", "bodymass", "cofmass")


@dataclass(frozen=True)
class AsfBone:
    """One ``:bonedata`` block: angles in the ASF's angle unit, ``direction`` normalised,
    ``dof`` lower case in file order; ``line``/``dof_line``: its ``begin`` and ``dof`` lines."""

    name: str
    id: int | None
    direction: tuple[float, float, float]
    length: float
    axis: tuple[float, float, float]
    axis_order: str
    dof: tuple[str, ...]
    limits: tuple[tuple[float, float], ...]
    line: int
    dof_line: int | None = None


@dataclass(frozen=True, eq=False)
class Asf:
    """A parsed ASF.  ``order``: "root" then every bone, parents first (depth first, children in
    :hierarchy order); ``parent``: bone -> parent name ("root" for the root's children)."""

    source: str
    version: str | None
    name: str | None
    mass_unit: float
    length_unit: float
    angle_unit: str  # "deg" | "rad"
    documentation: str
    root_order: tuple[str, ...]
    root_axis: str
    root_position: tuple[float, float, float]
    root_orientation: tuple[float, float, float]
    bones: dict[str, AsfBone] = field(repr=False)
    parent: dict[str, str] = field(repr=False)
    order: tuple[str, ...] = field(repr=False)


@dataclass(frozen=True, eq=False)
class AmcMotion:
    """A parsed AMC: ``values[bone]`` (T, n_dof) float64 for every bone with dofs (and "root"),
    columns in dof (root: order) order, angles in ``angle_unit``, lengths in ASF units."""

    source: str
    angle_unit: str
    fully_specified: bool
    frame_numbers: np.ndarray = field(repr=False)
    values: dict[str, np.ndarray] = field(repr=False)

    @property
    def n_frames(self) -> int:
        return int(self.frame_numbers.shape[0])


# ------------------------------------------------------------------------------------ text
def _text(data: bytes | str) -> str:
    """The text of ``data`` (UTF-8, else Latin-1; no BOM), CR LF and CR read as LF."""
    if isinstance(data, str):
        text = data.lstrip("\ufeff")
    else:
        raw = bytes(data).removeprefix(b"\xef\xbb\xbf")
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            text = raw.decode("latin-1")
    return text.replace("\r\n", "\n").replace("\r", "\n")


def _lines(data: bytes | str) -> list[str]:
    return _text(data).split("\n")


_CONTENT_LINE = re.compile(r"^[^\S\n]*[^\s#][^\n]*", re.M)


def _content_lines(text: str):
    """(line number, line) of the lines of ``text`` that hold a token (not blank, not only a
    comment), one at a time: an AMC file's lines are not held as one list (60 MiB of empty
    lines made a 600 MB list and took 14 s; the regular expression skips them in C), and a
    cap on frames (``frame_check``) stops the read early (issue 29)."""
    ln, pos = 1, 0
    for m in _CONTENT_LINE.finditer(text):
        ln += text.count("\n", pos, m.start())
        pos = m.start()
        yield ln, m.group()


def _last_of(text: str) -> int:
    """:func:`_last` of ``text.split("\n")``, without the list."""
    return max(text.count("\n") + 1 - (text == "" or text.endswith("\n")), 1)


def _last(lines: list[str]) -> int:
    """Number of the last line (a final line end does not start another line)."""
    return max(len(lines) - (lines[-1] == ""), 1)


def _tokens(line: str) -> list[str]:
    return line.split("#", 1)[0].replace(",", " ").replace("(", " ").replace(")", " ").split()


def _q(tok: str) -> str:
    return repr(tok[:30] + ("..." if len(tok) > 30 else ""))


def _floats(toks, n, what, src, ln, finite=True) -> tuple[float, ...]:
    if n is not None and len(toks) != n:
        raise DataError(f"{what}: expected {n} numbers, found {len(toks)}", src, ln)
    out = []
    for t in toks:
        try:
            v = float(t)
        except ValueError:
            raise DataError(f"{what}: {_q(t)} is not a number", src, ln) from None
        if finite and not math.isfinite(v):
            raise DataError(f"{what}: {_q(t)} is not a finite number", src, ln)
        out.append(v)
    return tuple(out)


def _euler_order(toks, what, src, ln) -> str:
    o = toks[-1].upper() if toks else ""
    if sorted(o) != ["X", "Y", "Z"]:
        raise DataError(f"{what}: expected a rotation order such as XYZ, found "
                        f"{_q(' '.join(toks))}", src, ln)
    return o


def _dofs(toks, allowed, what, src, ln) -> tuple[str, ...]:
    d = tuple(t.lower() for t in toks)
    for t, low in zip(toks, d):
        if low not in allowed:
            raise DataError(f"{what}: unknown channel {_q(t)} (known: {' '.join(allowed)})", src, ln)
    if len(set(d)) != len(d):
        raise DataError(f"{what}: a channel is repeated", src, ln)
    return d


# ------------------------------------------------------------------------------------- ASF
def parse_asf(data: bytes | str, source: str | Path = "<asf>") -> Asf:
    """Parse ASF text (bytes or str); ``source`` names the file in error messages."""
    src, lines = str(source), _lines(data)
    info: dict = {"version": None, "name": None, "mass": 1.0, "length": 1.0, "angle": "deg",
                  "order": None, "axis": "XYZ", "position": (0.0,) * 3, "orientation": (0.0,) * 3}
    doc: list[str] = []
    seen: set[str] = set()
    bones: dict[str, AsfBone] = {}
    edges: list[tuple[str, str, int]] = []  # parent, child, line
    section, cur, last_key, hier = None, None, None, "before"
    for ln, line in enumerate(lines, start=1):
        if section == "documentation" and not line.lstrip().startswith(":"):
            doc.append(line.strip())
            continue
        toks = _tokens(line)
        if not toks:
            continue
        key = toks[0].lower()
        if key.startswith(":"):
            section = _asf_section(toks, line, section, cur, hier, info, doc, seen, src, ln)
        elif section in (None, "version", "name"):
            raise DataError(f"unexpected {_q(toks[0])} outside any section", src, ln)
        elif section == "units":
            if key == "angle" and len(toks) == 2 and toks[1].lower() in ("deg", "rad"):
                info["angle"] = toks[1].lower()
            elif key in ("mass", "length"):
                (info[key],) = _floats(toks[1:], 1, f"units {key}", src, ln)
                if info[key] <= 0:
                    raise DataError(f"units {key} must be positive", src, ln)
            else:
                raise DataError(f"bad :units entry {_q(line.strip())} (mass N, length N, angle "
                                "deg|rad)", src, ln)
        elif section == "root":
            if key == "order":
                info["order"] = _dofs(toks[1:], ROOT_DOFS, "root order", src, ln)
            elif key == "axis" and len(toks) == 2:
                info["axis"] = _euler_order(toks[1:], "root axis", src, ln)
            elif key in ("position", "orientation"):
                info[key] = _floats(toks[1:], 3, f"root {key}", src, ln)
            else:
                raise DataError(f"bad :root entry {_q(line.strip())}", src, ln)
        elif section == "bonedata":
            cur, last_key = _bonedata_line(key, toks, cur, last_key, bones, src, ln)
        elif section == "hierarchy":
            hier = _hierarchy_line(key, toks, hier, edges, src, ln)
    _check_asf_end(lines, cur, seen, hier, info, src)
    parent, order = _tree(bones, edges, src)
    return Asf(src, info["version"], info["name"], info["mass"], info["length"], info["angle"],
               "\n".join(doc).strip(), info["order"], info["axis"], info["position"],
               info["orientation"], bones, parent, order)


def _asf_section(toks, line, section, cur, hier, info, doc, seen, src, ln) -> str:
    """A ``:section`` line (the bone block and hierarchy before it closed): the section now read."""
    key = toks[0].lower()
    if cur is not None:
        raise DataError(f"bone block opened at line {cur['line']} has no 'end'", src, ln)
    if section == "hierarchy" and hier == "open":
        raise DataError(":hierarchy has no 'end'", src, ln)
    if key in seen and key in (":units", ":root", ":bonedata", ":hierarchy"):
        raise DataError(f"section {key} appears twice", src, ln)
    seen.add(key)
    section = key[1:]
    if section in ("version", "name"):
        info[section] = " ".join(toks[1:]) or None
    elif section == "documentation":
        doc.append(line.strip()[len(toks[0]):].strip())
    elif section not in ("units", "root", "bonedata", "hierarchy"):
        section = "skip"
    elif len(toks) > 1:
        raise DataError(f"unexpected {_q(toks[1])} after {toks[0]}", src, ln)
    return section


def _bonedata_line(key, toks, cur, last_key, bones, src, ln):
    """A ``:bonedata`` line: ``begin`` opens a bone block (``cur``), ``end`` adds it to ``bones``,
    others are its fields (``limits`` may span lines).  Returns the new ``(cur, last_key)``."""
    if cur is None:
        if key != "begin" or len(toks) != 1:
            raise DataError(f"expected 'begin' of a bone block, found {_q(toks[0])}", src, ln)
        return {"line": ln}, None
    if key == "end" and len(toks) == 1:
        bone = _bone(cur, src)
        if bone.name in bones or bone.name == "root":
            raise DataError(f"bone name {_q(bone.name)} is used twice (or is 'root')", src,
                            cur["line"])
        bones[bone.name] = bone
        return None, last_key
    if last_key == "limits" and key not in _BONE_KEYS:  # limits continued
        cur["limits"] += _floats(toks, None, "limits", src, ln, finite=False)
    elif key not in _BONE_KEYS:
        raise DataError(f"unknown bone field {_q(toks[0])}", src, ln)
    elif key in cur:
        raise DataError(f"bone field {key!r} is given twice", src, ln)
    else:
        last_key, cur[key], args = key, True, toks[1:]
        if key == "id":
            if len(args) != 1 or not args[0].isdecimal() or len(args[0]) > 9:
                raise DataError("bone id must be one non-negative integer", src, ln)
            cur["id"] = int(args[0])
        elif key == "name":
            if len(args) != 1:
                raise DataError("bone name must be one word", src, ln)
            cur["name"] = args[0]
        elif key in ("direction", "length"):
            cur[key] = _floats(args, 3 if key == "direction" else 1, key, src, ln)
        elif key == "axis":
            if len(args) != 4:
                raise DataError("axis: expected three angles and an order such as XYZ", src, ln)
            cur["axis"] = (_floats(args[:3], 3, "axis", src, ln),
                           _euler_order(args[3:], "axis", src, ln))
        elif key == "dof":
            cur["dof"] = (_dofs(args, BONE_DOFS, "dof", src, ln), ln)
        elif key == "limits":
            cur["limits"] = _floats(args, None, "limits", src, ln, finite=False)
            cur["limits_line"] = ln
    return cur, last_key


def _hierarchy_line(key, toks, hier, edges, src, ln) -> str:
    """A ``:hierarchy`` line (``begin``, ``end``, a parent and children): the state it leaves."""
    if hier == "before":
        if key != "begin" or len(toks) != 1:
            raise DataError(f"expected 'begin' of :hierarchy, found {_q(toks[0])}", src, ln)
        return "open"
    if hier == "done":
        raise DataError(f"unexpected {_q(toks[0])} after the end of :hierarchy", src, ln)
    if key == "end" and len(toks) == 1:
        return "done"
    if len(toks) < 2:
        raise DataError(f"hierarchy line names {_q(toks[0])} but no children", src, ln)
    edges.extend((toks[0], c, ln) for c in toks[1:])
    return hier


def _check_asf_end(lines, cur, seen, hier, info, src) -> None:
    """At the end: no bone block open, every section needed, the hierarchy closed, an ``order``."""
    end = _last(lines)
    if cur is not None:
        raise DataError(f"bone block opened at line {cur['line']} has no 'end'", src, end)
    for sec in (":root", ":bonedata", ":hierarchy"):
        if sec not in seen:
            raise DataError(f"no {sec} section", src, end)
    if hier != "done":
        raise DataError(f":hierarchy has no {'end' if hier == 'open' else 'begin'!r}", src, end)
    if info["order"] is None:
        raise DataError(":root has no 'order' line", src, end)


def _bone(cur: dict, src: str) -> AsfBone:
    for k in ("name", "direction", "length"):
        if k not in cur:
            raise DataError(f"bone block has no {k!r}", src, cur["line"])
    (length,), d = cur["length"], np.asarray(cur["direction"])
    if length < 0:
        raise DataError(f"bone {cur['name']!r} has a negative length", src, cur["line"])
    norm = float(np.linalg.norm(d))
    if norm == 0 and length != 0:
        raise DataError(f"bone {cur['name']!r} has a zero direction", src, cur["line"])
    dof, dof_line = cur.get("dof", ((), None))
    lim = cur.get("limits", ())
    if lim and len(lim) != 2 * len(dof):
        raise DataError(f"limits: expected {2 * len(dof)} numbers (a pair per dof), found "
                        f"{len(lim)}", src, cur["limits_line"])
    axis, axis_order = cur.get("axis", ((0.0, 0.0, 0.0), "XYZ"))
    return AsfBone(cur["name"], cur.get("id"), tuple(float(v) for v in d / (norm or 1.0)), length,
                   axis, axis_order, dof, tuple(zip(lim[0::2], lim[1::2])), cur["line"], dof_line)


def _tree(bones: dict[str, AsfBone], edges, src: str):
    parent: dict[str, str] = {}
    line_of: dict[str, int] = {}
    kids: dict[str, list[str]] = {}
    for p, c, ln in edges:
        for name in (p, c):
            if name != "root" and name not in bones:
                raise DataError(f"hierarchy names bone {_q(name)}, not defined in :bonedata", src, ln)
        if c == "root":
            raise DataError("the root cannot be a child in :hierarchy", src, ln)
        if c in parent:
            raise DataError(f"bone {c!r} is given a second parent (first at line {line_of[c]})",
                            src, ln)
        parent[c], line_of[c] = p, ln
        kids.setdefault(p, []).append(c)
    reaches_root = {"root"}
    for c in parent:  # walk up from every bone: a revisit is a cycle
        path, on_path, n = [], set(), c
        while n not in reaches_root and n not in on_path:
            path.append(n)
            on_path.add(n)
            n = parent.get(n, "root")  # a bone without parent is reported below
        reaches_root.update(path)
        if n in on_path:
            cyc = path[path.index(n):]
            raise DataError(f"cycle in :hierarchy: {' -> '.join(cyc + [n])}", src,
                            max(line_of[b] for b in cyc))
    for b in bones.values():
        if b.name not in parent:
            raise DataError(f"bone {b.name!r} is not attached to the tree in :hierarchy", src, b.line)
    order, stack = [], ["root"]
    while stack:
        order.append(stack.pop())
        stack.extend(reversed(kids.get(order[-1], [])))
    return parent, tuple(order)


# ------------------------------------------------------------------------------------- AMC
def parse_amc(data: bytes | str, source: str | Path, asf: Asf, *, frame_check=None) -> AmcMotion:
    """Parse AMC text against ``asf``; ``source`` names the file in error messages.
    ``frame_check(n)``, when given, is called as frame ``n`` (1-based count) begins, before its
    values are read: a caller's cap on frames raises there (issue 29)."""
    src, text = str(source), _text(data)
    counts = {"root": len(asf.root_order), **{n: len(b.dof) for n, b in asf.bones.items()}}
    needed = [n for n in asf.order if counts[n] > 0]
    angle, full = None, False
    numbers: list[int] = []
    frame_lines: list[int] = []
    frames: list[dict[str, tuple[float, ...]]] = []

    unknown: dict[str, int] = {}  # bones of the first frame the ASF lacks -> their line

    def check_frame() -> None:
        if len(frames) == 1:  # the first frame shows the clip's bone set: all of a misfit said
            missing = [n for n in needed if n not in frames[0]]
            if unknown or missing:
                raise DataError(bone_misfit(asf, list(unknown), missing, numbers[0]), src,
                                min(unknown.values()) if unknown else frame_lines[0])
        for n in needed if frames else ():
            if n not in frames[-1]:
                raise DataError(f"frame {numbers[-1]} gives no values for bone {n!r}", src,
                                frame_lines[-1])

    for ln, line in _content_lines(text):
        toks = line.split("#", 1)[0].split()
        if not toks:
            continue
        if toks[0].startswith(":"):
            if frames:
                raise DataError(f"header keyword {_q(toks[0])} after the first frame", src, ln)
            kw = toks[0].upper()
            if kw in (":DEGREES", ":RADIANS"):
                if angle not in (None, kw[1:4].lower()):
                    raise DataError("both :DEGREES and :RADIANS are given", src, ln)
                angle = kw[1:4].lower()
            full = full or kw == ":FULLY-SPECIFIED"
        elif len(toks) == 1 and toks[0] not in counts:
            digits = toks[0].removeprefix("-")
            if not (digits.isdecimal() and len(digits) < 19):
                raise DataError(f"{_q(toks[0])} is neither a frame number nor a bone name", src, ln)
            num = int(toks[0])
            if numbers and num != numbers[-1] + 1:
                raise DataError(f"frame number {num} does not follow frame {numbers[-1]}", src, ln)
            check_frame()
            if frame_check is not None:
                frame_check(len(frames) + 1)
            numbers.append(num)
            frame_lines.append(ln)
            frames.append({})
        else:
            name, n = toks[0], len(toks) - 1
            if not frames:
                raise DataError("bone values before the first frame number", src, ln)
            if name not in counts:
                if len(frames) == 1:  # said with every other misfit when the frame ends
                    unknown.setdefault(name, ln)
                    continue
                raise DataError(f"unknown bone {_q(name)} (not in the ASF {asf.source})", src, ln)
            if name in frames[-1]:
                raise DataError(f"bone {name!r} is given twice in frame {numbers[-1]}", src, ln)
            if n != counts[name]:
                raise DataError(f"bone {name!r} needs {counts[name]} values, found {n}", src, ln)
            frames[-1][name] = _floats(toks[1:], None, f"bone {name!r}", src, ln)
    if not frames:
        raise DataError("no frames", src, _last_of(text))
    check_frame()
    values = {n: np.array([f[n] for f in frames], dtype=np.float64).reshape(len(frames), counts[n])
              for n in needed}
    return AmcMotion(src, angle or asf.angle_unit, full, np.array(numbers, dtype=np.int64), values)


def bone_misfit(asf: Asf, unknown: list[str], missing: list[str], frame: int) -> str:
    """The message of an AMC clip whose bones (its first frame's) do not fit ``asf``: every
    bone it names that the ASF lacks, and every ASF bone with dofs it gives no values for
    (issue 28: clips paired with another subject's or another skeleton's ASF)."""
    def bones(names: list[str]) -> str:
        shown = ", ".join(_q(n) for n in names[:10])
        more = f" and {len(names) - 10} more" if len(names) > 10 else ""
        return f"bone{'s' if len(names) > 1 else ''} {shown}{more}"

    parts = ([f"unknown {bones(unknown)} (not in the ASF)"] if unknown else []) + (
        [f"frame {frame} gives no values for {bones(missing)}"] if missing else [])
    return (f"its bones do not fit the ASF {asf.source}: " + "; ".join(parts)
            + " (is the clip paired with the right ASF? [source] asf)")


def read_asf(path: str | Path) -> Asf:
    """Read an ASF file from disk (errors name ``path``)."""
    return parse_asf(_read(path), path)


def read_amc(path: str | Path, asf: Asf) -> AmcMotion:
    """Read an AMC file from disk against ``asf`` (errors name ``path``)."""
    return parse_amc(_read(path), path, asf)


def _read(path: str | Path) -> bytes:
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise DataError("file not found", path) from None
    except IsADirectoryError:
        raise DataError("is a directory, not a file", path) from None


# ------------------------------------------------------------------------------ kinematics
def _euler(angles, axes: str) -> np.ndarray:
    """Rotations (..., 3, 3) about fixed axes applied in ``axes`` order; angles (..., k) radians."""
    a = np.asarray(angles, dtype=np.float64)
    R = np.broadcast_to(np.eye(3), a.shape[:-1] + (3, 3)).copy()
    for k, ax in enumerate(axes):
        c, s = np.cos(a[..., k]), np.sin(a[..., k])
        i, j = {"X": (1, 2), "Y": (2, 0), "Z": (0, 1)}[ax.upper()]
        E = np.broadcast_to(np.eye(3), R.shape).copy()
        E[..., i, i], E[..., i, j], E[..., j, i], E[..., j, j] = c, -s, s, c
        R = E @ R
    return R


def _triple(xyz, order: str, to_rad: float) -> np.ndarray:
    """Rotation of an (x, y, z) angle triple applied in ``order`` (``axis``, ``orientation``)."""
    return _euler([xyz["XYZ".index(c)] * to_rad for c in order], order)


def _rot_part(vals: np.ndarray, dofs: tuple[str, ...], to_rad: float) -> np.ndarray:
    cols = [i for i, d in enumerate(dofs) if d in ROT_DOFS]
    return _euler(vals[:, cols] * to_rad, "".join(dofs[i][1] for i in cols))


def to_skeleton_motion(asf: Asf, amc: AmcMotion, *, length_scale: float | None = None,
                       fps: float = DEFAULT_FPS, leaf_ends: bool = False):
    """``(Skeleton, root (T, 3), rotations (T, J, 3, 3), fps)`` for the project's FK
    (:func:`repro.motion.skeleton.forward_kinematics`); conventions in the module docstring.

    Joints: ``asf.order``, then ``<bone>_end`` per leaf bone with ``leaf_ends``.  Lengths: ASF
    values × ``length_scale`` (default ``1 / asf.length_unit``).  Arrays are numpy float64.
    """
    from repro.motion.skeleton import Skeleton

    scale = 1.0 / asf.length_unit if length_scale is None else float(length_scale)
    if not (math.isfinite(scale) and scale > 0 and math.isfinite(fps) and fps > 0):
        raise ValueError(f"length_scale and fps must be positive, got {length_scale!r}, {fps!r}")
    for b in asf.bones.values():
        bad = [d for d in b.dof if d not in ROT_DOFS]
        if bad:
            raise DataError(f"bone {b.name!r}: dof {' '.join(bad)} (translation/length on a "
                            "non-root bone) is not supported", asf.source, b.dof_line)
    dims = {"root": len(asf.root_order), **{n: len(b.dof) for n, b in asf.bones.items()}}
    if any(k and amc.values.get(n, np.zeros((0, 0))).shape[1:] != (k,) for n, k in dims.items()):
        raise DataError(f"this motion was not read against the ASF {asf.source}", amc.source)
    T, names = amc.n_frames, list(asf.order)
    amc_rad = math.pi / 180 if amc.angle_unit == "deg" else 1.0
    asf_rad = math.pi / 180 if asf.angle_unit == "deg" else 1.0
    index = {n: j for j, n in enumerate(names)}
    parents = [-1] + [index[asf.parent[n]] for n in names[1:]]
    vec = {n: np.multiply(b.direction, b.length * scale) for n, b in asf.bones.items()}
    offsets = [np.zeros(3)] + [vec.get(asf.parent[n], np.zeros(3)) for n in names[1:]]
    if leaf_ends:
        for n in sorted(set(asf.bones) - set(asf.parent.values()), key=index.__getitem__):
            if n + "_end" in index:
                raise DataError(f"joint name {n + '_end'!r} is used twice", asf.source,
                                asf.bones[n].line)
            names.append(n + "_end")
            parents.append(index[n])
            offsets.append(vec[n])
    R = np.broadcast_to(np.eye(3), (T, len(names), 3, 3)).copy()
    O = _triple(asf.root_orientation, asf.root_axis, asf_rad)
    rv = amc.values.get("root", np.zeros((T, 0)))
    trans = np.zeros((T, 3))
    for i, d in enumerate(asf.root_order):
        if d[0] == "t":
            trans[:, "xyz".index(d[1])] = rv[:, i]
    R[:, 0] = O @ _rot_part(rv, asf.root_order, amc_rad)
    root = (np.asarray(asf.root_position) + trans @ O.T) * scale
    for j, n in enumerate(asf.order[1:], start=1):
        b = asf.bones[n]
        if b.dof:
            C = _triple(b.axis, b.axis_order, asf_rad)
            R[:, j] = C @ _rot_part(amc.values[n], b.dof, amc_rad) @ C.T
    return Skeleton(tuple(names), tuple(parents), np.array(offsets)), root, R, float(fps)
