"""Hypothesis strategies for the fuzz suite's data-set targets (issue 29; ``tests/test_fuzz.py``,
docs/fuzzing.md): declared data sets whose source is a tar archive built in memory, and labels
side files.  Split from ``tests/fuzz_strategies.py`` (which holds the BVH, TOML and pickle
generators) along what they feed.

- :func:`archive_cases`: a ``.tar`` / ``.tar.gz`` / ``.tar.xz`` holding four valid clips (at
  the archive's root or in folders) and up to six hostile members: names 4,000-6,000
  characters long, 60-70 folders deep, with ``..``, absolute, ``./``, control characters,
  C1 controls, bytes that are not UTF-8, duplicates of another member; entries that are
  folders, symbolic and hard links (out of the archive, to another member, to themselves),
  FIFOs, character and block devices, GNU sparse headers; contents that are a clip, a damaged
  clip, garbage or nothing.  The spec labels them from the file name (an ordinary pattern, one
  matching everything, or a hostile one), or from a CSV / JSON file of :func:`label_texts`.
- :func:`label_texts`: CSV and JSON labels files for clips ``c0``, ``c1`` with repeated keys
  and columns, lone surrogates, C0 / C1 controls, BOMs, deep nesting, wrong types, and sizes
  past the (test-lowered) cap.
"""

from __future__ import annotations

import io
import json
import tarfile

from hypothesis import strategies as st

#: the start of a BVH hierarchy: root Hips with two legs (the joints the heading check finds by
#: name); the rest of the hierarchy and the MOTION block follow
HIPS_AND_LEGS = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT LeftUpLeg
  {
    OFFSET 10 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 -40 0
    }
  }
  JOINT RightUpLeg
  {
    OFFSET -10 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 -40 0
    }
  }
"""
#: a tiny valid clip: hips with two legs and a head (the heading and posture checks pass)
BVH = (HIPS_AND_LEGS + """  JOINT Head
  {
    OFFSET 0 50 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 10 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.0333333
0 90 0 0 0 0 0 0 0 0 0 0 0 0 0
0 90 1 0 0 0 0 0 0 0 0 0 0 0 0
0 90 2 0 0 0 0 0 0 0 0 0 0 0 0
""").encode()

CLIPS = ("walk_01", "walk_02", "run_01", "run_02")
#: labels patterns: ordinary, loose, and ones the shape check must refuse
PATTERNS = (r"^(?P<action>[a-z]+)_\d+$", r"(?P<action>[a-z]+)", r"(?P<action>.*)",
            r"^(?P<action>(a+)+)$", r"(?P<action>a{4294967296})", "(" * 400 + "?P<action>a"
            + ")" * 400, r"^(?P<action>(w|wa)*)", r"(?P<action>x)(?P<style>\1)",
            r"^(?P<action>[a-z]+)_(?P<subject>\d)\d$")
_CTRL = ("\x1b", "\x07", "\x00", "\x7f", "\x9b", "\x85", "\u2028", "\u202e", "\r", "\n", "\t")
_TYPES = (tarfile.REGTYPE, tarfile.REGTYPE, tarfile.REGTYPE, tarfile.DIRTYPE, tarfile.SYMTYPE,
          tarfile.LNKTYPE, tarfile.FIFOTYPE, tarfile.CHRTYPE, tarfile.BLKTYPE, tarfile.CONTTYPE,
          tarfile.GNUTYPE_SPARSE)


@st.composite
def _member_name(draw, others: list[str]) -> str:
    stem = draw(st.sampled_from(CLIPS + ("notes", "x", "")))
    ext = draw(st.sampled_from((".bvh", ".BVH", ".txt", "", ".bvh/")))
    kind = draw(st.integers(0, 9))
    if kind == 0:
        return "n" * draw(st.integers(4000, 6000)) + ext
    if kind == 1:
        return "d/" * draw(st.integers(60, 70)) + stem + ext
    if kind == 2:
        return draw(st.sampled_from(("../", "a/../../", "/", "./", "a/./", "a//"))) + stem + ext
    if kind == 3:
        at = draw(st.integers(0, len(stem)))
        return stem[:at] + draw(st.sampled_from(_CTRL)) + stem[at:] + ext
    if kind == 4:
        return stem + "\udcff" + ext  # a raw 0xff byte in the header
    if kind == 5 and others:
        return draw(st.sampled_from(others))  # a duplicate
    if kind == 6:
        return draw(st.text(max_size=12)) + ext
    return draw(st.sampled_from(("", "sub/", "a/b/"))) + stem + ext


def _content(draw) -> bytes:
    how = draw(st.integers(0, 4))
    if how == 0:
        return BVH
    if how == 1:
        cut = draw(st.integers(0, len(BVH)))
        return BVH[:cut] + draw(st.binary(max_size=8)) + BVH[cut:]
    if how == 2:
        return BVH.replace(b"0.0333333", draw(st.sampled_from((b"0", b"-1", b"1e-300", b"nan"))))
    if how == 3:
        return draw(st.binary(max_size=64))
    return b""


def _add(tf: tarfile.TarFile, name: str, typ: bytes, data: bytes, link: str = "") -> None:
    ti = tarfile.TarInfo(name)
    ti.type = typ
    ti.linkname = link
    if typ in (tarfile.REGTYPE, tarfile.CONTTYPE):
        ti.size = len(data)
        tf.addfile(ti, io.BytesIO(data))
    else:
        tf.addfile(ti)


@st.composite
def archive_cases(draw) -> dict:
    """{"archive": bytes, "ext": "tar"|"tar.gz"|"tar.xz", "labels": how, "pattern": str,
    "side": (name, bytes) or None, "include": str or None, "by": "clip"|"subject"}."""
    ext = draw(st.sampled_from(("tar", "tar.gz", "tar.xz")))
    fmt = draw(st.sampled_from((tarfile.PAX_FORMAT, tarfile.GNU_FORMAT)))
    root = draw(st.sampled_from(("", "", "clips/", "a/b/")))
    members = [(root + c + ".bvh", tarfile.REGTYPE, BVH, "") for c in CLIPS]
    for _ in range(draw(st.integers(0, 6))):
        name = draw(_member_name([m[0] for m in members]))
        typ = draw(st.sampled_from(_TYPES))
        link = draw(st.sampled_from(("../../etc/passwd", "/dev/zero", members[0][0], name,
                                     "x" * 200)))
        members.append((name, typ, _content(draw), link))
    order = draw(st.permutations(range(len(members))))
    buf = io.BytesIO()
    mode = {"tar": "w", "tar.gz": "w:gz", "tar.xz": "w:xz"}[ext]
    kwargs = {"preset": 0} if ext == "tar.xz" else {}
    try:
        with tarfile.open(fileobj=buf, mode=mode, format=fmt, errors="surrogateescape",
                          **kwargs) as tf:
            for i in order:
                _add(tf, *members[i])
    except (ValueError, UnicodeError):  # a name this format cannot hold: drop the extras
        buf = io.BytesIO()
        with tarfile.open(fileobj=buf, mode=mode, **kwargs) as tf:
            for m in members[:4]:
                _add(tf, *m)
    labels = draw(st.sampled_from(("filename", "filename", "csv", "json")))
    side = None
    if labels != "filename":
        side = (f"labels.{labels}", draw(label_texts(labels, stems=CLIPS)))
    return {"archive": buf.getvalue(), "ext": ext, "labels": labels, "side": side,
            "pattern": draw(st.sampled_from(PATTERNS[:1] * 4 + PATTERNS)),
            "include": draw(st.sampled_from((None, None, "*", "*.BVH", "clips/*"))),
            "by": draw(st.sampled_from(("clip", "clip", "subject")))}


_VALUES = ("walk", "run", "walk\ud800", "walk\x1b[2J", "wa\x07lk", "walk\x9b", "walk\x85",
           "\u202ewalk", "", " ", None, 1, 1.5, True, [], {}, "w" * 300)


@st.composite
def _json_value(draw):
    v = draw(st.sampled_from(_VALUES))
    if draw(st.booleans()):
        return v
    d = {"action": v}
    for k in draw(st.lists(st.sampled_from(("style", "subject", "other")), max_size=2)):
        d[k] = draw(st.sampled_from(_VALUES))
    return d


def _dump_pairs(pairs: list[tuple]) -> str:
    """A JSON object from (key, value) pairs, keys repeated as given (json.dumps cannot)."""
    return "{" + ", ".join(f"{json.dumps(k)}: {json.dumps(v)}" for k, v in pairs) + "}"


@st.composite
def label_texts(draw, kind: str | None = None, stems=("c0", "c1")) -> bytes:
    """A labels file's bytes for the clips ``stems``: CSV or JSON (``kind``, else drawn)."""
    kind = kind or draw(st.sampled_from(("csv", "json")))
    keys = st.sampled_from((*stems, *stems, "c2", "c0\x1b", "c0\ud800", "", "c0 "))
    if kind == "json":
        pairs = draw(st.lists(st.tuples(keys, _json_value()), min_size=0, max_size=6))
        if draw(st.booleans()):
            good = [(s, "walk" if "walk" in s or s == stems[0] else "run") for s in stems]
            pairs = good + (pairs if draw(st.booleans()) else [])
        text = _dump_pairs(pairs)
        how = draw(st.integers(0, 5))
        if how == 0:  # nested deep
            n = draw(st.integers(100, 5000))
            text = "[" * n + "]" * n
        elif how == 1:  # repeated key inside a record
            text = '{"%s": {"action": "walk", "action": "run"}}' % stems[0]
        elif how == 2:
            text = draw(st.sampled_from(("[]", "null", "1", '"x"', "{", "")))
    else:
        cols = draw(st.lists(st.sampled_from(("clip", "action", "style", "subject", "action",
                                              "clip", "x", "", " action ", "act\x1bion")),
                             min_size=0, max_size=5))
        if draw(st.booleans()):
            cols = ["clip", "action"] + cols[:2]
        rows = [",".join(cols)]
        for s in stems:
            rows.append(",".join([s, "walk" if "walk" in s or s == stems[0] else "run"]
                                 + ["x"] * max(0, len(cols) - 2)))
        for _ in range(draw(st.integers(0, 3))):
            cells = st.sampled_from((*stems, "walk", "run", "", '"a,b"', '"multi\nline"',
                                     "walk\x9b", "\x00", "w\x85", '"'))
            rows.append(",".join(draw(st.lists(cells, max_size=5))))
        text = draw(st.sampled_from(("\n", "\r\n", "\r"))).join(rows) + "\n"
    data = text.encode("utf-8", "surrogatepass")
    pre = draw(st.sampled_from((b"", b"", b"\xef\xbb\xbf", b"\xff\xfe")))
    big = draw(st.sampled_from((0, 0, 0, 5000)))  # past the 4 KiB cap the fuzz sets
    return pre + data + b" " * big
