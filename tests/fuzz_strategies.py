"""Hypothesis strategies shared by the fuzz suite (``tests/test_fuzz.py``, docs/fuzzing.md).

Three families of input, one per fuzzed reader:

- **BVH** (:func:`repro.data.bvh.parse_bvh`): :func:`bvh_cases` builds a *valid* document (a
  random hierarchy of joints, channels in any order and case, End Sites, frames written in
  several number formats, CR / LF / CRLF / mixed line ends, tabs, BOM) together with what a
  correct parser must return; :func:`mutated_bvh` damages one at the token level (tokens
  deleted, duplicated, swapped, moved, replaced by huge / NaN / inf / garbage numbers or
  keywords, the file truncated, NUL bytes and broken UTF-8 inserted);
  :func:`bvh_header_variants` replaces only the ``Frames:`` / ``Frame Time:`` values;
  :func:`byte_mutated_bvh` flips, inserts and deletes raw bytes of a small valid file;
  :func:`deep_bvh` nests a chain of joints up to and past the parser's depth limit.
- **TOML specs** (:func:`repro.specs.load.load_spec`, :func:`repro.specs.scales.load_scales` /
  :func:`~repro.specs.scales.resolve_scale`): :func:`mutated_toml_doc` takes a real file under
  ``tables/`` and deletes, renames, retypes (str / int / float / bool / date / list / table),
  swaps, duplicates and enlarges its fields or nests them deeply, then writes it back as TOML;
  :func:`toml_texts` damages the text itself and builds documents nested far deeper than any
  spec (arrays, inline tables, dotted keys and headers).
- **Pickles** (:func:`repro.data.upstream.restricted_pickle.loads_restricted`,
  :func:`~repro.data.upstream.humanact12.read_humanact12`): :func:`humanact12_payloads`
  builds HumanAct12-like objects (``poses`` / ``joints3D`` / ``y`` of random types, shapes and
  dtypes), pickled with protocols 0-5 (:func:`payload_pickles`), then byte-mutated
  (:func:`mutated_pickles`); :func:`evil_pickles` names globals that would run code
  (``os.system``, ``builtins.eval``, ``subprocess.Popen``, ``open``, :func:`fire_sentinel`, ...)
  whose only effect, if run, is to create a sentinel file; :func:`call_pickles` hand-assembles
  pickle programs that call the *admitted* globals with hostile arguments.

Only generation lives here; the properties are in ``tests/test_fuzz.py``.
"""

from __future__ import annotations

import copy
import io
import math
import os
import pickle
import pickletools
import random
import struct
import subprocess
import tempfile
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

REPO = Path(__file__).resolve().parents[1]
TABLES = REPO / "tables"

# Hypothesis keeps caches (unicode tables; constants found in local modules, which its pytest
# plugin collects whenever a Hypothesis test is collected) in ./.hypothesis by default; keep
# them out of the repository.  Read lazily at the first use, so setting it here (before any
# strategy below is built) is early enough; a value the user set wins.
os.environ.setdefault("HYPOTHESIS_STORAGE_DIRECTORY",
                      str(Path(tempfile.gettempdir()) / "repro-hypothesis"))

# ============================================================================ shared pieces

#: number-like tokens a hostile or broken file may hold where a number is expected
BAD_NUMBERS = (
    "nan", "NaN", "-nan", "inf", "-inf", "Infinity", "-Infinity", "1e309", "-1e309", "1e-400",
    "1e99999999999", "9" * 400, "9" * 5000, "-" + "9" * 4301, str(2 ** 63), str(-2 ** 63 - 1),
    str(10 ** 30), str(2 ** 64), "0", "-0", "+0.0", "-1", "0x10", "0b1", "1_000", "1e", "1e+",
    ".", "-", "+", "", "1.5.5", "1,5", "١٢٣", "１２", "½", "1e5e5", "--1", "\x00", "1\x00",
    "3.0", "2.5", "-3", "1" + "0" * 18, "1" + "0" * 19,
)

_BYTE_INSERTS = (b"\x00", b"\r", b"\n", b"\r\n", b"\xff", b"\xfe\xff", b"\xef\xbb\xbf", b"\xc3",
                 b"\xed\xa0\x80", b"\x85", b"\xe2\x80\xa8", b"\t", b" ", b"{", b"}", b"[", b"]",
                 b"=", b'"', b"'", b"#", b"MOTION\n", b"1e999", b"nan", b"-", b"9" * 30)


@st.composite
def byte_mutations(draw, data: bytes, max_ops: int = 8) -> bytes:
    """``data`` with 1..max_ops random byte edits (flip, set, insert, delete, duplicate, move,
    truncate)."""
    buf = bytearray(data)
    for _ in range(draw(st.integers(1, max_ops))):
        op = draw(st.sampled_from(("flip", "set", "insert", "insert_special", "delete",
                                   "duplicate", "move", "truncate")))
        n = len(buf)
        i = draw(st.integers(0, n))
        if op == "flip" and i < n:
            buf[i] ^= 1 << draw(st.integers(0, 7))
        elif op == "set" and i < n:
            buf[i] = draw(st.integers(0, 255))
        elif op == "insert":
            buf[i:i] = draw(st.binary(min_size=1, max_size=8))
        elif op == "insert_special":
            buf[i:i] = draw(st.sampled_from(_BYTE_INSERTS))
        elif op == "delete":
            buf[i:i + draw(st.integers(1, 16))] = b""
        elif op == "duplicate":
            j = draw(st.integers(i, min(n, i + 64)))
            buf[j:j] = buf[i:j]
        elif op == "move" and n:
            j = draw(st.integers(i, min(n, i + 64)))
            chunk = bytes(buf[i:j])
            del buf[i:j]
            k = draw(st.integers(0, len(buf)))
            buf[k:k] = chunk
        elif op == "truncate":
            del buf[i:]
    return bytes(buf)


# ============================================================================ BVH

CHANNELS = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
#: tokens that end a joint name in the parser, plus MOTION (a name word alone on a line would
#: be read as the MOTION line, which is the format's rule, not a parser bug)
_NOT_A_NAME = frozenset({"{", "}", "OFFSET", "CHANNELS", "JOINT", "End", "ROOT", "MOTION"})
_KEYWORDS = ("HIERARCHY", "ROOT", "JOINT", "End", "Site", "{", "}", "OFFSET", "CHANNELS",
             "MOTION", "Frames:", "Frame Time:", "Frame", "Time:", "6", "3", "0", "7", "-1") \
    + CHANNELS
_NL = "\x00NL\x00"  # line-break marker inside a token stream (never a real token)

_name_words = st.text(st.characters(categories=("L", "N")) | st.sampled_from("_-.:"),
                      min_size=1, max_size=8).filter(lambda w: w not in _NOT_A_NAME)
_joint_names = st.lists(_name_words, min_size=1, max_size=2).map(" ".join)
_values = st.one_of(st.floats(-1000, 1000), st.integers(-500, 500).map(float),
                    st.floats(allow_nan=False, allow_infinity=False))
_FORMATS = ("repr", "%.6f", "%.17g", "%.3e", "%+.9g", "%.2f")


def _fmt(x: float, style: str) -> str:
    """``x`` as text in ``style``; repr when the style would round it to infinity."""
    txt = style % x if style != "repr" else ""
    return txt if txt and math.isfinite(float(txt)) else repr(float(x))


@dataclass(eq=False)
class BvhCase:
    """A generated BVH file (``data``) and what parsing it must give.

    ``lines``: the document as token lines (hierarchy, MOTION header, frame rows), before
    whitespace and line ends were chosen; the expected fields mirror :class:`repro.data.bvh.Bvh`.
    """

    lines: list[list[str]]
    data: bytes
    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    end_parents: tuple[int, ...]
    end_offsets: np.ndarray
    frame_time: float
    motion: np.ndarray

    def __repr__(self) -> str:  # what Hypothesis prints for a falsifying example
        return f"BvhCase(data={self.data!r})"


def render_bvh(lines: list[list[str]], rng: random.Random, *, join_hierarchy: bool = True,
               bom: bool = False) -> bytes:
    """Token lines -> bytes with random separators, indentation and line ends (LF, CRLF, CR or a
    mix).  Hierarchy lines may be joined (the hierarchy is whitespace-token based); the MOTION
    line, the two header lines and each frame row keep their own line."""
    nl_style = rng.choice(("\n", "\r\n", "\r", "mixed", "\n"))
    seps = rng.choice(((" ",), ("\t",), (" ", "\t", "  ")))
    out: list[str] = ["\ufeff"] if bom else []
    in_head = True
    for k, toks in enumerate(lines):
        if toks == ["MOTION"]:
            in_head = False
        indent = rng.choice(("", "", "\t", "  ")) if in_head or rng.random() < 0.1 else ""
        line = indent + "".join(t + (rng.choice(seps) if i < len(toks) - 1 else "")
                                for i, t in enumerate(toks))
        if rng.random() < 0.05:
            line += rng.choice((" ", "\t"))
        out.append(line)
        if k == len(lines) - 1 and rng.random() < 0.3:
            break  # no final line end
        nxt_head = in_head and k + 1 < len(lines) and lines[k + 1] != ["MOTION"]
        if join_hierarchy and nxt_head and toks != ["MOTION"] and rng.random() < 0.2:
            out.append(" ")
            continue
        out.append(rng.choice(("\n", "\r\n", "\r")) if nl_style == "mixed" else nl_style)
        if rng.random() < 0.05:  # a blank (or blank-looking) line
            out.append(rng.choice(("", " ", "\t")) + ("\n" if nl_style == "mixed" else nl_style))
    return "".join(out).encode("utf-8")


@st.composite
def bvh_cases(draw, max_joints: int = 8, max_frames: int = 6,
              no_channels: bool = False) -> BvhCase:
    """A valid BVH document with a random hierarchy and the values a parser must return
    (``no_channels``: a static skeleton, no joint declares a channel)."""
    n = draw(st.integers(1, max_joints))
    names = draw(st.lists(_joint_names, min_size=n, max_size=n, unique=True))
    # parents in depth-first (declaration) order: each new joint hangs off the open path
    parents, path = [-1], [0]
    for j in range(1, n):
        del path[draw(st.integers(1, len(path))):]
        parents.append(path[-1])
        path.append(j)
    mode = "none" if no_channels else draw(st.sampled_from(("random", "random", "none",
                                                             "root6", "all3")))
    channels: list[tuple[str, ...]] = []
    written: list[tuple[str, ...] | None] = []  # the spelling in the file (None: no CHANNELS line)
    for j in range(n):
        if mode == "none":
            k = 0
        elif mode == "root6":
            k = 6 if j == 0 else 3
        elif mode == "all3":
            k = 3
        else:
            k = draw(st.integers(0, 6))
        perm = draw(st.permutations(CHANNELS))[:k] if k else ()
        case = draw(st.sampled_from((str, str, str.lower, str.upper)))
        channels.append(tuple(perm))
        written.append(None if (k == 0 and draw(st.booleans())) else tuple(case(c) for c in perm))
    offsets = [tuple(draw(_values) for _ in range(3)) for _ in range(n)]
    n_ends = [draw(st.integers(0, 2)) if draw(st.booleans()) else int(j not in parents)
              for j in range(n)]
    end_offsets_raw = [[tuple(draw(_values) for _ in range(3)) for _ in range(e)] for e in n_ends]
    n_frames = draw(st.integers(1, max_frames))
    n_ch = sum(len(c) for c in channels)
    motion_raw = draw(hnp.arrays(np.float64, (n_frames, n_ch), elements=_values))
    num_style = draw(st.sampled_from(_FORMATS))
    frame_time_raw = draw(st.floats(1e-4, 1.0))
    ft_style = draw(st.sampled_from(("repr", "%.6f", "%.7g")))
    rng = random.Random(draw(st.integers(0, 2 ** 32 - 1)))

    # ---- token lines, depth-first
    lines: list[list[str]] = [["HIERARCHY"]]
    exp_off, exp_end_p, exp_end_o = [], [], []

    def vec(v) -> tuple[list[str], tuple[float, ...]]:
        txt = [_fmt(x, num_style) for x in v]
        return txt, tuple(float(t) for t in txt)

    children: dict[int, list[int]] = {}
    for j, p in enumerate(parents):
        children.setdefault(p, []).append(j)

    def emit(j: int) -> None:
        lines.append(["ROOT" if j == 0 else "JOINT", *names[j].split(" ")])
        lines.append(["{"])
        txt, val = vec(offsets[j])
        exp_off.append(val)
        lines.append(["OFFSET", *txt])
        if written[j] is not None:
            lines.append(["CHANNELS", str(len(written[j])), *written[j]])
        # End Sites and child joints in a random interleaving
        items = [("end", o) for o in end_offsets_raw[j]] + [("joint", c) for c in children.get(j, [])]
        # children must stay in index order (declaration order = index order); ends go anywhere
        ends = [it for it in items if it[0] == "end"]
        joints = [it for it in items if it[0] == "joint"]
        merged: list = []
        while ends or joints:
            if ends and (not joints or rng.random() < 0.5):
                merged.append(ends.pop(0))
            else:
                merged.append(joints.pop(0))
        for kind, x in merged:
            if kind == "end":
                t, v = vec(x)
                exp_end_p.append(j)
                exp_end_o.append(v)
                lines.extend([["End", "Site"], ["{"], ["OFFSET", *t], ["}"]])
            else:
                emit(x)
        lines.append(["}"])

    # depth-first over index-ordered children is index order, because each parent was drawn
    # on the open path (so declaration order = the order of `names`)
    emit(0)
    ft_txt = _fmt(frame_time_raw, ft_style)
    lines += [["MOTION"], ["Frames:", str(n_frames)], ["Frame Time:", ft_txt]]
    mot_txt = [[_fmt(x, num_style) for x in row] for row in motion_raw]
    if n_ch:
        lines += mot_txt
    elif draw(st.booleans()):
        lines += [[""] for _ in range(n_frames)]  # zero channels: empty frame lines
    motion = np.array([[float(t) for t in row] for row in mot_txt], np.float64).reshape(n_frames, n_ch)
    data = render_bvh(lines, rng, bom=draw(st.booleans()) and rng.random() < 0.2)
    return BvhCase(lines, data, tuple(names), tuple(parents), np.array(exp_off).reshape(-1, 3),
                   tuple(channels), tuple(exp_end_p), np.array(exp_end_o, np.float64).reshape(-1, 3),
                   float(ft_txt), motion)


_HEADER_VALUES = BAD_NUMBERS + (str(2 ** 31), str(2 ** 63 - 1), str(10 ** 18), "1e3", "5.0",
                                "٣", "1e-320", "5e-324", "1e308", "0.0", "-0.033")
_FRAME_COUNTS = ("0", "-1", "2", "1000", str(2 ** 31), str(2 ** 32 + 1), str(2 ** 62),
                 str(2 ** 63 - 1), str(2 ** 63), str(10 ** 19), str(2 ** 64), str(10 ** 30),
                 "9" * 400, "9" * 4300, "9" * 4301)


def _token_stream(case: BvhCase) -> list[str]:
    toks: list[str] = []
    for line in case.lines:
        toks += line + [_NL]
    return toks


def _lines_of(toks: list[str]) -> list[list[str]]:
    lines, cur = [], []
    for t in toks:
        if t == _NL:
            lines.append(cur)
            cur = []
        else:
            cur.append(t)
    if cur:
        lines.append(cur)
    return lines


@st.composite
def bvh_header_variants(draw) -> bytes:
    """A valid document whose ``Frames:`` and/or ``Frame Time:`` value is replaced (huge,
    negative, zero, fractional, NaN, subnormal, unicode digits...), the rest intact, so that the
    value reaches the MOTION block's checks; hierarchies without channels are half of them."""
    case = draw(bvh_cases(max_joints=4, max_frames=3, no_channels=draw(st.booleans())))
    toks = _token_stream(case)
    which = draw(st.sampled_from(("frames", "time", "both")))
    if which != "time":
        toks[toks.index("Frames:") + 1] = draw(st.sampled_from(_FRAME_COUNTS)
                                               | st.sampled_from(_HEADER_VALUES))
    if which != "frames":
        toks[toks.index("Frame Time:") + 1] = draw(st.sampled_from(_HEADER_VALUES))
    rng = random.Random(draw(st.integers(0, 2 ** 32 - 1)))
    return render_bvh(_lines_of(toks), rng)


@st.composite
def mutated_bvh(draw) -> bytes | str:
    """A valid document damaged at the token level, then at the byte level; sometimes as str."""
    case = draw(bvh_cases(max_joints=6, max_frames=4))
    toks = _token_stream(case)
    for _ in range(draw(st.integers(1, 5))):    rng = random.Random(draw(st.integers(0, 2 ** 32 - 1)))
    data = render_bvh(_lines_of(toks), rng, join_hierarchy=False)
    if draw(st.booleans()):
        data = draw(byte_mutations(data, max_ops=3))
    if draw(st.integers(0, 3)) == 0:
        try:
            return data.decode("utf-8")  # the str entry point (only text that is valid UTF-8)
        except UnicodeDecodeError:
            pass
    return data


_SMALL_BVH = (b"HIERARCHY\nROOT Hips\n{\n\tOFFSET 0.0 90.0 0.0\n"
              b"\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n"
              b"\tJOINT Spine\n\t{\n\t\tOFFSET 0.0 10.0 0.0\n\t\tCHANNELS 3 Zrotation Xrotation Yrotation\n"
              b"\t\tEnd Site\n\t\t{\n\t\t\tOFFSET 0.0 5.0 0.0\n\t\t}\n\t}\n}\n"
              b"MOTION\nFrames: 3\nFrame Time: 0.033333\n"
              b"0.0 90.0 0.0 0.0 0.0 0.0 10.0 -5.0 2.5\n"
              b"1.0 90.5 0.1 1.5 -2.0 0.5 11.0 -4.0 2.0\n"
              b"2.0 91.0 0.2 3.0 -4.0 1.0 12.0 -3.0 1.5\n")


@st.composite
def byte_mutated_bvh(draw) -> bytes:
    """Raw byte edits of a small valid file (a fixed one, or a small generated one)."""
    base = draw(st.sampled_from((_SMALL_BVH, None)))
    if base is None:
        base = draw(bvh_cases(max_joints=3, max_frames=3)).data
    return draw(byte_mutations(base, max_ops=10))


@st.composite
def deep_bvh(draw) -> tuple[int, bool, bytes]:
    """(depth, has an End Site, document): a chain of ``depth`` joints, the deepest with an End Site or not."""
    depth = draw(st.integers(1, 400) | st.sampled_from((255, 256, 257, 258)))
    end = draw(st.booleans())
    chans = draw(st.booleans())
    parts = ["HIERARCHY"]
    for d in range(depth):
        parts += [f"{'ROOT' if d == 0 else 'JOINT'} j{d}", "{", "OFFSET 0 1 0"]
        if chans:
            parts.append("CHANNELS 3 Zrotation Xrotation Yrotation")
    if end:
        parts += ["End Site", "{", "OFFSET 0 1 0", "}"]
    parts += ["}"] * depth
    parts += ["MOTION", "Frames: 2", "Frame Time: 0.1"]
    n_ch = 3 * depth if chans else 0
    if n_ch:
        parts += [" ".join(["0"] * n_ch)] * 2
    return depth, end, ("\n".join(parts) + "\n").encode()


# ============================================================================ TOML specs

def _load(path: Path) -> dict:
    return tomllib.loads(path.read_text(encoding="utf-8"))


SPEC_FILES = tuple(sorted(p for p in TABLES.glob("*/*.toml")))
SCALES_FILE = TABLES / "scales.toml"
TABLE1 = TABLES / "marionette" / "table1.toml"


def _all_keys(doc: Any, out: set[str]) -> set[str]:
    if isinstance(doc, dict):
        for k, v in doc.items():
            out.add(k)
            _all_keys(v, out)
    elif isinstance(doc, list):
        for v in doc:
            _all_keys(v, out)
    return out


_BASE_DOCS: dict[Path, dict] = {}


def base_doc(path: Path) -> dict:
    if path not in _BASE_DOCS:
        _BASE_DOCS[path] = _load(path)
    return copy.deepcopy(_BASE_DOCS[path])


#: every key and string value that real specs use, so renames and retypes stay plausible
_KNOWN_KEYS = tuple(sorted(set().union(*(_all_keys(_load(p), set())
                                         for p in (*SPEC_FILES, SCALES_FILE)))))
_INTERESTING_STRINGS = ("", " ", "marionette/table1", "marionette/table3", "odmo/table1",
                        "single_action", "multi_action", "bandai2", "bandai2-mini", "humanact12",
                        "fid", "acc", "div", "real", "marionet", "quick", "paper", "order", "gap",
                        "higher", "lower", "none", "bootstrap", "1", "0.5", "±", "nan", "-",
                        "/", "1.115", "x" * 300, "é\u0301", "\u202e", "a\nb", "\x7f", "{}", "[]")
_HUGE_INTS = (2 ** 63 - 1, -2 ** 63, 2 ** 64, 10 ** 30, -(10 ** 30), 10 ** 400, 0, -1, 1, 10 ** 9)

toml_keys = st.sampled_from(_KNOWN_KEYS) | st.text(max_size=12)
toml_scalars = st.one_of(
    st.text(max_size=20), st.sampled_from(_INTERESTING_STRINGS), st.integers(-10, 10 ** 6),
    st.sampled_from(_HUGE_INTS), st.floats(), st.booleans(), st.dates(), st.times(),
    st.datetimes(),
)
toml_values = st.recursive(
    toml_scalars,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(toml_keys, inner, max_size=4),
    max_leaves=12,
)


def _deep_value(depth: int, kind: str) -> Any:
    v: Any = 1
    for d in range(depth):
        if kind == "list" or (kind == "mixed" and d % 2):
            v = [v]
        else:
            v = {"a": v}
    return v


def _positions(doc: Any, limit: int = 4000) -> list[tuple[Any, Any]]:
    """(container, key or index) of every value inside ``doc``, breadth-first."""
    out: list[tuple[Any, Any]] = []
    todo = [doc]
    while todo and len(out) < limit:
        c = todo.pop(0)
        items = c.items() if isinstance(c, dict) else enumerate(c)
        for k, v in list(items):
            out.append((c, k))
            if isinstance(v, (dict, list)):
                todo.append(v)
    return out


def _retype(v: Any, to: str) -> Any:
    if to == "str":
        return str(v)
    if to == "int":
        try:
            return int(float(v)) if not isinstance(v, (dict, list)) else len(v)
        except (TypeError, ValueError, OverflowError):
            return len(str(v))
    if to == "float":
        try:
            return float(v)
        except (TypeError, ValueError, OverflowError):
            return float(len(str(v)))
    if to == "bool":
        return bool(v)
    if to == "list":
        return list(v.values()) if isinstance(v, dict) else [v]
    if to == "table":
        return {str(i): x for i, x in enumerate(v)} if isinstance(v, list) else {"value": v}
    if to == "first":
        if isinstance(v, list) and v:
            return v[0]
        if isinstance(v, dict) and v:
            return next(iter(v.values()))
        return v
    raise AssertionError(to)


@st.composite
def mutated_toml_doc(draw, paths: tuple[Path, ...]) -> tuple[Path, bytes]:
    """(the real file it came from, TOML bytes of a damaged copy of it)."""
    path = draw(st.sampled_from(paths))
    doc = base_doc(path)
    for _ in range(draw(st.integers(1, 6))):
        pos = _positions(doc)
        if not pos:
            break
        c, k = pos[draw(st.integers(0, len(pos) - 1))]
        op = draw(st.sampled_from(("delete", "delete", "rename", "retype", "retype", "value",
                                   "huge", "nonfinite", "duplicate", "swap", "deep", "copy")))
        if op == "delete":
            del c[k]
        elif op == "rename" and isinstance(c, dict):
            new = draw(toml_keys)
            c[new] = c.pop(k)
        elif op == "retype":
            c[k] = _retype(c[k], draw(st.sampled_from(("str", "int", "float", "bool", "list",
                                                        "table", "first"))))
        elif op == "value":
            c[k] = draw(toml_values)
        elif op == "huge":
            what = draw(st.sampled_from(("int", "str", "list", "float")))
            if what == "int":
                c[k] = draw(st.sampled_from(_HUGE_INTS))
            elif what == "str":
                c[k] = "x" * draw(st.sampled_from((1000, 100_000)))
            elif what == "float":
                c[k] = draw(st.sampled_from((1e308, -1e308, float("inf"), float("nan"), 5e-324,
                                             -0.0)))
            else:
                big = isinstance(c[k], (dict, list))
                c[k] = [copy.deepcopy(c[k])] * draw(st.sampled_from((2, 50) if big else (2, 1000)))
        elif op == "nonfinite":
            c[k] = draw(st.sampled_from((float("nan"), float("inf"), float("-inf"))))
        elif op == "duplicate" and isinstance(c, list):
            c.insert(k, copy.deepcopy(c[k]))
        elif op == "swap":
            c2, k2 = pos[draw(st.integers(0, len(pos) - 1))]
            if c2 is not c or k2 != k:
                a, b = c[k], c2[k2]
                if not _contains(a, c2) and not _contains(b, c):
                    c[k], c2[k2] = b, a
        elif op == "deep":
            c[k] = _deep_value(draw(st.sampled_from((5, 31, 32, 33, 60, 200))),
                               draw(st.sampled_from(("list", "dict", "mixed"))))
        elif op == "copy":
            c2, k2 = pos[draw(st.integers(0, len(pos) - 1))]
            if not _contains(c2[k2], c):
                c[k] = copy.deepcopy(c2[k2])
    return path, tomli_w.dumps(doc).encode("utf-8")


def _contains(haystack: Any, needle: Any) -> bool:
    """Whether ``needle`` is ``haystack`` or inside it (to keep swaps free of cycles)."""
    todo = [haystack]
    while todo:
        x = todo.pop()
        if x is needle:
            return True
        if isinstance(x, dict):
            todo.extend(x.values())
        elif isinstance(x, list):
            todo.extend(x)
    return False


@st.composite
def deep_toml_text(draw) -> bytes:
    depth = draw(st.sampled_from((31, 32, 33, 34, 100, 1000, 5000, 50_000)) | st.integers(1, 300))
    kind = draw(st.sampled_from(("array", "inline", "dotted", "header", "array_tables")))
    if kind == "array":
        body = "deep = " + "[" * depth + "1" + "]" * depth
    elif kind == "inline":
        body = "deep = " + "{a = " * depth + "1" + "}" * depth
    # dotted keys: tomllib's time grows with the square of the key's length (a 50,000-part
    # key takes ~30 s before the depth check can refuse it), so these stop at 5,000 parts
    elif kind == "dotted":
        body = "deep" + ".a" * min(depth, 5000) + " = 1"
    elif kind == "header":
        body = "[deep" + ".a" * min(depth, 5000) + "]\nx = 1"
    else:
        body = "[[deep" + ".a" * min(depth, 5000) + "]]\nx = 1"
    prefix = draw(st.sampled_from((b"", TABLE1.read_bytes() + b"\n", b"schema = 1\n")))
    if kind in ("header", "array_tables") or not prefix:
        return prefix + body.encode()
    # a key line must come before the file's first [table] header to stay top-level
    return body.encode() + b"\n" + prefix


@st.composite
def toml_texts(draw, paths: tuple[Path, ...]) -> bytes:
    """TOML bytes damaged as text, or nested deeper than any spec."""
    if draw(st.integers(0, 3)) == 0:
        return draw(deep_toml_text())
    _, data = draw(mutated_toml_doc(paths)) if draw(st.booleans()) else \
        (None, draw(st.sampled_from(paths)).read_bytes())
    return draw(byte_mutations(data, max_ops=6))


# ============================================================================ pickles

def fire_sentinel(path: str) -> None:
    """The global a malicious pickle may name: if the unpickler ever called it, ``path`` would
    exist afterwards."""
    Path(path).write_text("the restricted unpickler ran a disallowed global\n")


class Reduce:
    """Pickles as ``fn(*args)`` (via ``__reduce__``); callable so that it can itself be the
    function of an outer reduction (``getattr(__import__('os'), 'system')(...)``)."""

    def __init__(self, fn, args: tuple):
        self.fn, self.args = fn, args

    def __reduce__(self):
        return self.fn, self.args

    def __call__(self, *a):  # pragma: no cover - only pickled
        raise AssertionError("never called")

    def __repr__(self) -> str:
        return f"Reduce({getattr(self.fn, '__qualname__', self.fn)!r}, {self.args!r})"


def evil_objects(sentinel: str) -> list[Reduce]:
    """Objects whose unpickling would run a disallowed global that creates ``sentinel``."""
    py = f"open({sentinel!r}, 'w').close()"
    return [
        Reduce(os.system, (f"touch {sentinel}",)),
        Reduce(eval, (py,)),
        Reduce(exec, (py,)),
        Reduce(subprocess.Popen, (["touch", sentinel],)),
        Reduce(subprocess.call, (["touch", sentinel],)),
        Reduce(subprocess.run, (["touch", sentinel],)),
        Reduce(open, (sentinel, "w")),
        Reduce(io.open, (sentinel, "w")),
        Reduce(fire_sentinel, (sentinel,)),
        Reduce(Reduce(getattr, (Reduce(__import__, ("os",)), "system")), (f"touch {sentinel}",)),
        Reduce(pickle.loads, (pickle.dumps(Reduce(fire_sentinel, (sentinel,)), protocol=2),)),
        Reduce(Path.write_text, (Path(sentinel), "x")),
    ]


def _global_op(module: str, name: str, how: str) -> bytes:
    if how == "stack":
        m, n = module.encode(), name.encode()
        return b"\x8c" + bytes([len(m)]) + m + b"\x8c" + bytes([len(n)]) + n + b"\x93"
    return b"c" + module.encode() + b"\n" + name.encode() + b"\n"


def crafted_evil(sentinel: str) -> list[bytes]:
    """Hand-written pickles naming disallowed globals with the GLOBAL, INST, STACK_GLOBAL and
    OBJ opcodes and with module spellings the unpickler maps (``__builtin__``, ``numpy.core``)."""
    s = sentinel.encode()
    touch = b"S'touch " + s + b"'\n"
    py = b"S\"open('" + s + b"', 'w').close()\"\n"
    out = [
        b"cos\nsystem\n(" + touch + b"tR.",
        b"cposix\nsystem\n(" + touch + b"tR.",
        b"(" + touch + b"ios\nsystem\n.",                     # INST
        b"c__builtin__\neval\n(" + py + b"tR.",
        b"cbuiltins\nexec\n(" + py + b"tR.",
        b"(cos\nsystem\n" + touch + b"o.",                    # OBJ
        b"\x80\x04" + _global_op("os", "system", "stack") + b"\x8c" + bytes([len(b"touch " + s)])
        + b"touch " + s + b"\x85R.",
        b"\x80\x02" + _global_op("subprocess", "Popen", "glob") + b"(](S'touch'\nS'" + s
        + b"'\netR.",
        b"\x80\x02" + _global_op("fuzz_strategies", "fire_sentinel", "glob") + b"(S'" + s
        + b"'\ntR.",
        b"\x80\x02" + _global_op("tests.fuzz_strategies", "fire_sentinel", "glob") + b"(S'" + s
        + b"'\ntR.",
        b"\x80\x02" + _global_op("builtins", "getattr", "glob") + b"(" + _global_op(
            "builtins", "__import__", "glob") + b"(S'os'\ntRS'system'\ntR(" + touch + b"tR.",
        b"\x80\x02" + _global_op("numpy.core", "os", "glob") + b".",
        b"\x80\x02" + _global_op("numpy.testing._private.utils", "runstring", "glob")
        + b"(" + py + b"}tR.",
        b"\x80\x04" + _global_op("numpy", "ndarray.__reduce_ex__", "stack") + b".",
        b"\x80\x04" + _global_op("builtins", "str.__class__", "stack") + b".",
        b"\x80\x02" + _global_op("io", "open", "glob") + b"(S'" + s + b"'\nS'w'\ntR.",
        b"\x80\x02\x82\x01.",                                 # EXT1 (unregistered code)
    ]
    return out


_FLOAT_DTYPES = (np.float64, np.float32)
_ODD_DTYPES = (np.float16, np.int64, np.int32, np.int8, np.uint8, np.bool_, np.complex64,
               np.complex128, np.dtype("U4"), np.dtype("S4"), np.dtype("M8[s]"),
               np.dtype("m8[ms]"), np.dtype([("a", "<f4"), ("b", "<i2")]), np.dtype(">f8"), object)
_object_elements = st.one_of(st.none(), st.integers(-5, 5), st.floats(), st.text(max_size=3),
                             st.just([1.0, 2.0]))


@st.composite
def np_arrays(draw, shape=None, dtypes=_FLOAT_DTYPES + _ODD_DTYPES) -> np.ndarray:
    dtype = draw(st.sampled_from(dtypes))
    if shape is None:
        shape = draw(hnp.array_shapes(min_dims=0, max_dims=4, min_side=0, max_side=4))
    if dtype is object:
        return draw(hnp.arrays(object, shape, elements=_object_elements))
    return draw(hnp.arrays(np.dtype(dtype), shape))


def _ragged(draw) -> list:
    leaf = st.floats() | st.integers(-3, 3) | st.text(max_size=2)
    return draw(st.recursive(leaf, lambda c: st.lists(c, max_size=3), max_leaves=10))


@st.composite
def _clip_entry(draw, shape_of) -> Any:
    kind = draw(st.sampled_from(("good", "good", "good", "dtype", "shape", "ragged", "scalar",
                                 "list")))
    T = draw(st.integers(0, 3))
    shape = shape_of(T, draw(st.booleans()))
    if kind == "good":
        return draw(np_arrays(shape, _FLOAT_DTYPES))
    if kind == "dtype":
        return draw(np_arrays(shape, _ODD_DTYPES))
    if kind == "shape":
        return draw(np_arrays())
    if kind == "ragged":
        return _ragged(draw)
    if kind == "list":
        return draw(np_arrays(shape, _FLOAT_DTYPES)).tolist()
    return draw(_junk)


_junk = st.one_of(st.none(), st.integers(-2, 2), st.sampled_from(_HUGE_INTS), st.floats(),
                  st.text(max_size=4), st.binary(max_size=4), st.booleans(),
                  st.complex_numbers(max_magnitude=10), st.just(()), st.just({}),
                  st.just({"poses": 1}), st.just(np.float32(1.5)), st.just(np.int64(3)),
                  st.just(np.str_("7")), st.just(frozenset({1, 2})), st.just(range(3)),
                  st.just(slice(1, 2)), st.just(bytearray(b"ab")))

_labels = st.one_of(st.integers(0, 11), st.integers(-3, 15), st.sampled_from(_HUGE_INTS),
                    st.sampled_from((1.5, 3.0, float("nan"), float("inf"), 1e300, -0.0)),
                    st.integers(0, 11).map(np.int64), st.integers(0, 11).map(np.float32),
                    st.just(np.float64(2.5)), st.booleans(), st.text(max_size=3), st.none(),
                    st.just(np.array([1, 2])), st.just(np.array(3)), st.just(1 + 2j),
                    st.just(np.array([[4]])))


def _container(draw, items: list) -> Any:
    how = draw(st.sampled_from(("list", "list", "tuple", "object_array", "stack", "dict",
                                "junk")))
    if how == "list":
        return items
    if how == "tuple":
        return tuple(items)
    if how == "object_array":
        arr = np.empty(len(items), dtype=object)
        for i, x in enumerate(items):
            arr[i] = x
        return arr
    if how == "stack":
        try:
            return np.array(items)
        except (ValueError, TypeError):
            return items
    if how == "dict":
        return {i: x for i, x in enumerate(items)}
    return draw(_junk)


_TWISTS = ("none", "none", "huge", "nan", "label_float", "label_integral_float", "label_bool",
           "label_str", "frames", "empty_clip", "float16")


@st.composite
def well_formed_humanact12(draw) -> tuple[dict, str]:
    """(payload, twist): a payload as ACTOR writes it, with at most one ``twist`` applied
    (``"none"``: a reader must accept it)."""
    n = draw(st.integers(1, 3))
    poses, joints, ys = [], [], []
    for _ in range(n):
        T = draw(st.integers(1, 3))
        small = st.floats(-10, 10, width=32)
        poses.append(draw(hnp.arrays(draw(st.sampled_from(_FLOAT_DTYPES)),
                                     draw(st.sampled_from(((T, 72), (T, 24, 3)))), elements=small)))
        joints.append(draw(hnp.arrays(draw(st.sampled_from(_FLOAT_DTYPES)), (T, 24, 3),
                                      elements=small)))
        ys.append(draw(st.integers(0, 11) | st.integers(0, 11).map(np.int64)))
    twist = draw(st.sampled_from(_TWISTS))
    i = draw(st.integers(0, n - 1))
    target = draw(st.sampled_from((poses, joints)))
    if twist == "huge":
        target[i] = target[i].astype(np.float64)
        target[i].flat[0] = draw(st.sampled_from((1e39, 3.5e38, 1e300, -1e300)))
    elif twist == "nan":
        target[i] = target[i].astype(np.float64)
        target[i].flat[-1] = draw(st.sampled_from((np.nan, np.inf, -np.inf)))
    elif twist == "label_float":
        ys[i] = draw(st.sampled_from((1.5, np.float64(2.5), np.float32(0.25), 11.999)))
    elif twist == "label_integral_float":
        ys[i] = draw(st.sampled_from((3.0, np.float64(4.0), np.float32(5.0))))
    elif twist == "label_bool":
        ys[i] = draw(st.sampled_from((True, np.bool_(False))))
    elif twist == "label_str":
        ys[i] = draw(st.sampled_from(("3", np.str_("4"), b"5")))
    elif twist == "frames":
        joints[i] = np.concatenate([joints[i], joints[i][:1]])
    elif twist == "empty_clip":
        poses[i], joints[i] = poses[i][:0], joints[i][:0]
    elif twist == "float16":
        target[i] = target[i].astype(np.float16)
    wrap = draw(st.sampled_from((list, list, tuple)))
    return {"poses": wrap(poses), "joints3D": wrap(joints), "y": wrap(ys)}, twist


@st.composite
def humanact12_payloads(draw) -> Any:
    """A HumanAct12-like object: a quarter well-formed (with at most one twist), the rest a
    dict with poses / joints3D / y of random type, length, shape and dtype, or no dict at all."""
    if draw(st.integers(0, 3)) == 0:
        return draw(well_formed_humanact12())[0]
    n = draw(st.integers(0, 3))
    lens = [n, n, n] if draw(st.integers(0, 3)) else [draw(st.integers(0, 3)) for _ in range(3)]
    poses = [draw(_clip_entry(lambda T, alt: (T, 24, 3) if alt else (T, 72))) for _ in range(lens[0])]
    joints = [draw(_clip_entry(lambda T, alt: (T, 24, 3))) for _ in range(lens[1])]
    ys = [draw(_labels) for _ in range(lens[2])]
    doc: dict[Any, Any] = {"poses": _container(draw, poses), "joints3D": _container(draw, joints),
                           "y": _container(draw, ys)}
    for _ in range(draw(st.integers(0, 2))):
        op = draw(st.sampled_from(("drop", "extra", "odd_key")))
        if op == "drop" and doc:
            del doc[draw(st.sampled_from(sorted(doc, key=repr)))]
        elif op == "extra":
            doc[draw(st.text(max_size=5))] = draw(_junk)
        elif op == "odd_key":
            doc[draw(st.sampled_from((1, b"poses", ("y",), None, 2.5)))] = draw(_junk)
    top = draw(st.sampled_from(("dict",) * 8 + ("list", "array", "junk", "tuple")))
    if top == "dict":
        return doc
    if top == "list":
        return list(doc.values())
    if top == "array":
        return draw(np_arrays())
    if top == "tuple":
        return (doc,)
    return draw(_junk)


@st.composite
def payload_pickles(draw) -> tuple[Any, bytes]:
    """(object, its pickle with a random protocol 0-5)."""
    obj = draw(humanact12_payloads())
    return obj, pickle.dumps(obj, protocol=draw(st.integers(0, pickle.HIGHEST_PROTOCOL)))


@st.composite
def mutated_pickles(draw) -> bytes:
    _, data = draw(payload_pickles())
    return draw(byte_mutations(data, max_ops=6))


def _place(draw, obj: Any, evil: Any) -> Any:
    """``obj`` with ``evil`` put somewhere inside it (or ``evil`` itself)."""
    where = draw(st.sampled_from(("top", "poses", "y", "joints3D", "nested", "key_value")))
    if where == "top" or not isinstance(obj, dict):
        return evil
    if where == "nested":
        return {"poses": [[evil]], "joints3D": obj.get("joints3D"), "y": [0]}
    if where == "key_value":
        obj = dict(obj)
        obj["extra"] = {"a": (1, evil)}
        return obj
    obj = dict(obj)
    obj[where] = [evil] + (list(obj[where]) if isinstance(obj.get(where), list) else [])
    return obj


@st.composite
def evil_pickles(draw, sentinel: str) -> tuple[bytes, bool]:
    """(pickle, was byte-mutated): a pickle naming a disallowed global that would create
    ``sentinel``, hidden in a random payload (any protocol) or hand-written; a quarter of them
    are then byte-mutated (which may remove the global)."""
    data = None
    if draw(st.integers(0, 2)):
        evil = draw(st.sampled_from(evil_objects(sentinel)))
        obj = _place(draw, draw(humanact12_payloads()), evil)
        try:
            data = pickle.dumps(obj, protocol=draw(st.integers(0, pickle.HIGHEST_PROTOCOL)))
        except (pickle.PicklingError, TypeError, AttributeError):
            data = None  # this callable cannot be written with this protocol
    if data is None:
        data = draw(st.sampled_from(crafted_evil(sentinel)))
    mutated = draw(st.integers(0, 3)) == 0
    if mutated:
        data = draw(byte_mutations(data, max_ops=3))
    return data, mutated


# ---- hand-assembled pickle programs calling the admitted globals with hostile arguments

#: (module, name) pairs the restricted unpickler admits (both numpy spellings), and a few that
#: it must refuse although they look harmless
CALLABLES = (
    ("numpy._core.multiarray", "_reconstruct"), ("numpy.core.multiarray", "_reconstruct"),
    ("numpy._core.multiarray", "scalar"), ("numpy.core.multiarray", "scalar"),
    ("numpy._core.numeric", "_frombuffer"), ("numpy.core.numeric", "_frombuffer"),
    ("numpy", "ndarray"), ("numpy", "dtype"), ("_codecs", "encode"),
    *(("builtins", n) for n in ("list", "dict", "tuple", "set", "frozenset", "bytearray",
                                "bytes", "str", "int", "float", "complex", "bool", "slice",
                                "range")),
    ("__builtin__", "bytearray"), ("copyreg", "_reconstructor"), ("numpy", "frombuffer"),
)
_ARG_STRINGS = ("latin1", "latin-1", "utf-8", "utf-16", "rot13", "zlib", "zlib_codec", "hex",
                "base64", "bz2", "uu", "idna", "punycode", "undefined", "bogus-codec", "",
                "f8", "<f4", "O", "U10", "S5", "V8", "M8[s]", "i4,f8", "(3,)f4",
                "(100000,100000)f8", "|V99999999999999", "f8" + ",f8" * 50, "C", "F", "K", "x",
                "\x00", "9" * 5000)


def _push(value: Any) -> bytes:
    """Opcodes (protocol 2, no STOP) that push ``value``."""
    return pickletools.optimize(pickle.dumps(value, protocol=2))[2:-1]


_scalar_args = st.one_of(
    st.integers(-3, 300), st.sampled_from(_HUGE_INTS + (2 ** 31 - 1, 2 ** 31, 2 ** 32, 2 ** 40,
                                                        -(2 ** 63) - 1, 10 ** 8)),
    st.sampled_from((0.0, -1.0, 1.5, float("nan"), float("inf"), 1e308)),
    st.sampled_from(_ARG_STRINGS), st.text(max_size=8), st.binary(max_size=24),
    st.sampled_from((b"\x00" * 8, b"\x01" * 72, b"\x00" * 96)), st.none(), st.booleans(),
)


@st.composite
def _pickle_expr(draw, depth: int) -> bytes:
    kind = draw(st.sampled_from(("scalar", "scalar", "call", "call", "newobj", "build", "tuple",
                                 "list", "dict", "memo", "noise")
                                if depth > 0 else ("scalar",)))
    if kind == "scalar":
        return _push(draw(_scalar_args))
    sub = _pickle_expr(depth - 1)
    if kind in ("call", "newobj"):
        module, name = draw(st.sampled_from(CALLABLES))
        args = draw(st.lists(sub, max_size=4))
        out = _global_op(module, name, "glob") + b"(" + b"".join(args) + b"t"
        return out + (b"R" if kind == "call" else b"\x81")
    if kind == "build":
        return draw(sub) + draw(sub) + b"b"
    if kind == "tuple":
        return b"(" + b"".join(draw(st.lists(sub, max_size=4))) + b"t"
    if kind == "list":
        return b"](" + b"".join(draw(st.lists(sub, max_size=4))) + b"e"
    if kind == "dict":
        items = draw(st.lists(st.tuples(sub, sub), max_size=3))
        return b"}(" + b"".join(k + v for k, v in items) + b"u"
    if kind == "memo":
        idx = draw(st.sampled_from((0, 1, 255, 10 ** 4, 10 ** 6, 2 ** 31, 2 ** 32 - 1)))
        op = draw(st.sampled_from(("long_binput", "put", "get", "long_binget")))
        if op == "long_binput":
            return draw(sub) + b"r" + struct.pack("<I", idx)
        if op == "put":
            return draw(sub) + b"p" + str(idx).encode() + b"\n"
        if op == "get":
            return b"g" + str(idx).encode() + b"\n"
        return b"j" + struct.pack("<I", idx)
    # noise: a random opcode byte with random following bytes
    return draw(st.binary(min_size=1, max_size=6))


@st.composite
def call_pickles(draw) -> bytes:
    """A pickle program calling admitted (and a few refused) globals with hostile arguments:
    huge sizes, odd dtype strings, unknown codecs, out-of-range memo indices."""
    proto = draw(st.integers(2, 5))
    return b"\x80" + bytes([proto]) + draw(_pickle_expr(3)) + b"."
