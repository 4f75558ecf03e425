"""BVH (Biovision Hierarchy) reading: any hierarchy, any channel order per joint (writing:
:mod:`repro.data.bvh_write`).

A BVH file is a HIERARCHY block (nested ``ROOT``/``JOINT``/``End Site`` blocks, each with an
``OFFSET`` and, for joints, a ``CHANNELS`` declaration) followed by a MOTION block (``Frames:``,
``Frame Time:`` and one line of channel values per frame, in declaration order).

Semantics used here (they are those of the stand-in data; see its SOURCE.md and docs/data.md):

- Rotation channels compose as *intrinsic* rotations in the order they are listed, with column
  vectors: ``Zrotation Xrotation Yrotation`` gives ``R = Rz · Rx · Ry`` (roma convention
  ``"ZXY"``).  Angles are degrees.  A joint's world rotation is ``parent_world · local``.
- Position channels *replace* the matching component of the joint's OFFSET (they are not added).
  They are honoured on every joint, not only on the root.
- Units are whatever the file uses (centimetres for the Bandai stand-in); this module does not
  convert them, so read -> write -> read round-trips exactly (to the printed precision).

Malformed input raises :class:`repro.errors.DataError` naming the file, the line and the problem.
The MOTION block is read in one compiled pass (:mod:`repro.data.bvh_numbers`: fixed-point
decimals, bitwise what ``float`` reads); a block outside that subset goes to one C-level numpy
call (``np.loadtxt``), and only when that call or a count check fails is the block walked line
by line to find and name the culprit.  A HIERARCHY block seen before (byte for byte: the clips
of one capture session share one) is not parsed again (:data:`_HIERARCHIES`).
"""

from __future__ import annotations

import io
import math
import re
import threading
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from repro.data.bvh_numbers import read_rows
from repro.errors import DataError

#: Channel names accepted (case-insensitively) and their canonical spelling.
CHANNEL_NAMES = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
_CANON = {c.lower(): c for c in CHANNEL_NAMES}
#: Hierarchies nested deeper than this are refused (a real skeleton is < 30 levels deep).
MAX_DEPTH = 256


#: Bounds a clip's header must keep (issue 16): 10 million frames is 3.8 days at 30 fps, and
#: a frame time under 1 µs (a million fps) is no capture's.  Checked before anything is read.
MAX_FRAMES = 10_000_000
MIN_FRAME_TIME = 1e-6


@dataclass(frozen=True, eq=False)
class Bvh:
    """One BVH file in memory, in the file's own units.

    ``names``/``parents``: joints in declaration (depth-first) order, parent ``-1`` for the root;
    ``offsets`` (J, 3) float64: OFFSET of each joint in its parent's frame;
    ``channels``: per joint, the canonical channel names in declaration order;
    ``end_parents``/``end_offsets`` (E, 3): each ``End Site``'s joint and OFFSET;
    ``frame_time``: seconds per frame; ``motion`` (F, C) float64: the channel values, columns in
    declaration order (joint by joint).
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray = field(repr=False)
    channels: tuple[tuple[str, ...], ...] = field(repr=False)
    end_parents: tuple[int, ...] = field(repr=False)
    end_offsets: np.ndarray = field(repr=False)
    frame_time: float
    motion: np.ndarray = field(repr=False)

    def __post_init__(self) -> None:
        J = len(self.names)
        object.__setattr__(self, "offsets", np.asarray(self.offsets, np.float64).reshape(J, 3))
        object.__setattr__(self, "end_offsets",
                           np.asarray(self.end_offsets, np.float64).reshape(len(self.end_parents), 3))
        motion = np.asarray(self.motion, np.float64)
        if motion.ndim != 2 or motion.shape[1] != self.n_channels:
            raise ValueError(f"motion must be (frames, {self.n_channels}), got {motion.shape}")
        object.__setattr__(self, "motion", motion)
        for ch in self.channels:
            for c in ch:
                if c not in CHANNEL_NAMES:
                    raise ValueError(f"unknown channel {c!r}")

    # ---------------------------------------------------------------- sizes
    @property
    def n_joints(self) -> int:
        return len(self.names)

    @property
    def n_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def n_channels(self) -> int:
        return sum(len(c) for c in self.channels)

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    def channel_start(self, j: int) -> int:
        """Column of joint ``j``'s first channel in :attr:`motion`."""
        return sum(len(c) for c in self.channels[:j])

    def joint_channels(self, name: str) -> np.ndarray:
        """(F, k) channel values of the joint called ``name``."""
        j = self.names.index(name)
        s = self.channel_start(j)
        return self.motion[:, s:s + len(self.channels[j])]

    # ------------------------------------------------------------ kinematics
    def local_translations(self) -> np.ndarray:
        """(F, J, 3) per-frame local offsets: OFFSET with position channels replacing components."""
        out = np.broadcast_to(self.offsets, (self.n_frames, self.n_joints, 3)).copy()
        col = 0
        for j, chans in enumerate(self.channels):
            for c in chans:
                if c.endswith("position"):
                    out[:, j, "XYZ".index(c[0])] = self.motion[:, col]
                col += 1
        return out

    def rotation_orders(self) -> tuple[str, ...]:
        """Per joint, the rotation axes in channel order (e.g. ``"ZXY"``; ``""`` for none)."""
        return tuple("".join(c[0] for c in ch if c.endswith("rotation")) for ch in self.channels)

    def _grouped_angles(self):
        """Yield (order, joint indices, angles (F, Jg, k) degrees) for joints sharing an order."""
        orders = self.rotation_orders()
        cols = []
        col = 0
        for chans in self.channels:
            cols.append([col + i for i, c in enumerate(chans) if c.endswith("rotation")])
            col += len(chans)
        groups: dict[str, list[int]] = {}
        for j, o in enumerate(orders):
            groups.setdefault(o, []).append(j)
        for order, joints in groups.items():
            if not order:
                continue
            idx = np.array([cols[j] for j in joints])  # (Jg, k)
            yield order, joints, self.motion[:, idx]

    def local_rotations(self, as_quaternions: bool = False):
        """Local rotations as a torch float64 tensor: (F, J, 3, 3) matrices, or (F, J, 4) xyzw
        unit quaternions with ``as_quaternions``.  Joints without rotation channels get identity.

        Intrinsic composition in channel order (module docstring), converted with roma.
        """
        import roma
        import torch

        F, J = self.n_frames, self.n_joints
        from repro.data import prepare_caps  # its CHUNK_ABOVE / CHUNK (read at call time)

        if F * J > prepare_caps.CHUNK_ABOVE and F > 1:  # in slices: roma's temporaries stay small
            step = max(1, prepare_caps.CHUNK // J)
            return torch.cat([replace(self, motion=self.motion[s:s + step])
                              .local_rotations(as_quaternions) for s in range(0, F, step)])
        if as_quaternions:
            out = torch.zeros((F, J, 4), dtype=torch.float64)
            out[..., 3] = 1.0
        else:
            out = torch.eye(3, dtype=torch.float64).expand(F, J, 3, 3).clone()
        for order, joints, ang in self._grouped_angles():
            a = torch.from_numpy(np.ascontiguousarray(ang))
            if as_quaternions:
                out[:, joints] = roma.euler_to_unitquat(order, a, degrees=True)
            else:
                out[:, joints] = roma.euler_to_rotmat(order, a, degrees=True)
        return out

    def skeleton(self, scale: float = 1.0):
        """The hierarchy as a :class:`repro.motion.skeleton.Skeleton` (offsets × ``scale``)."""
        from repro.motion.skeleton import Skeleton

        return Skeleton(self.names, self.parents, self.offsets * scale)

    def world_positions(self, scale: float = 1.0) -> np.ndarray:
        """(F, J, 3) float64 world joint positions (file units × ``scale``), position channels
        honoured on every joint; forward kinematics of :mod:`repro.motion.skeleton`."""
        from repro.motion.skeleton import forward_kinematics

        trans = self.local_translations() * scale
        R = self.local_rotations()
        pos = forward_kinematics(self.skeleton(scale), R, trans[:, 0], offsets=trans)
        return pos.numpy()


# =========================================================================== reading
_NAME_STOP = frozenset(("{", "}", "OFFSET", "CHANNELS", "JOINT", "End", "ROOT"))


class _Tokens:
    """Whitespace tokens of the HIERARCHY block; line numbers are worked out only for errors."""

    def __init__(self, head: str, source: str):
        self.head = head
        self.toks: list[str] = head.split()
        self.n = len(self.toks)
        self.i = 0
        self.source = source

    def line_of(self, i: int) -> int:
        """1-based line of token ``i`` (the last line when ``i`` is past the end)."""
        seen = 0
        lines = self.head.split("\n")
        for ln_no, ln in enumerate(lines, start=1):
            seen += len(ln.split())
            if seen > i:
                return ln_no
        return max(len(lines) - (1 if self.head.endswith("\n") else 0), 1)

    def error(self, problem: str, at: int | None = None) -> DataError:
        return DataError(problem, self.source, self.line_of(self.i if at is None else at))

    def peek(self) -> str | None:
        return self.toks[self.i] if self.i < self.n else None

    def next(self, what: str) -> str:
        if self.i >= self.n:
            raise self.error(f"unexpected end of HIERARCHY block, expected {what}")
        self.i += 1
        return self.toks[self.i - 1]

    def expect(self, word: str) -> None:
        if self.i >= self.n:
            raise self.error(f"unexpected end of HIERARCHY block, expected {word!r}")
        t = self.toks[self.i]
        if t != word:
            raise self.error(f"expected {word!r}, found {t!r}")
        self.i += 1

    def name(self) -> str:
        """A joint name: every token up to the next '{' (names may hold spaces)."""
        k = self.i
        while k < self.n and self.toks[k] not in _NAME_STOP:
            k += 1
        if k == self.i:
            raise self.error("missing joint name")
        out = " ".join(self.toks[self.i:k])
        self.i = k
        return out

    def numbers3(self, what: str) -> tuple[float, float, float]:
        i = self.i
        if i + 3 > self.n:
            self.i = self.n
            raise self.error(f"unexpected end of HIERARCHY block in {what}")
        try:
            x, y, z = float(self.toks[i]), float(self.toks[i + 1]), float(self.toks[i + 2])
        except ValueError:
            for k in range(i, i + 3):
                try:
                    float(self.toks[k])
                except ValueError:
                    raise self.error(f"{what}: {self.toks[k][:30]!r} is not a number", k) from None
            raise  # pragma: no cover
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            raise self.error(f"{what}: values must be finite", i)
        self.i = i + 3
        return x, y, z


def _channels(tk: _Tokens, name: str) -> tuple[str, ...]:
    """Joint ``name``'s ``CHANNELS n c1 … cn`` declaration (``tk`` at ``CHANNELS``): the
    canonical channel names, in declaration order (0 to 6, none repeated)."""
    tk.i += 1
    nt = tk.next("channel count")
    try:
        n = int(nt)
    except ValueError:
        raise tk.error(f"channel count {nt!r} of {name!r} is not an integer", tk.i - 1) from None
    if not 0 <= n <= 6:
        raise tk.error(f"joint {name!r} declares {n} channels (0 to 6 allowed)", tk.i - 1)
    if tk.i + n > tk.n:
        tk.i = tk.n
        raise tk.error(f"unexpected end of HIERARCHY block in the channels of {name!r}")
    raw = tk.toks[tk.i:tk.i + n]
    try:
        chans = tuple(_CANON[c.lower()] for c in raw)
    except KeyError:
        k = next(k for k, c in enumerate(raw) if c.lower() not in _CANON)
        raise tk.error(f"unknown channel name {raw[k]!r} for joint {name!r} "
                       f"(known: {', '.join(CHANNEL_NAMES)})", tk.i + k) from None
    if len(set(chans)) != n:
        raise tk.error(f"a channel is repeated for joint {name!r}", tk.i)
    tk.i += n
    return chans


def _parse_hierarchy(tk: _Tokens):
    """The HIERARCHY block (``tk`` at its first token) up to ``MOTION``: names, parents,
    offsets, channels, End Site parents and offsets, in declaration order."""
    names: list[str] = []
    parents: list[int] = []
    offsets: list[tuple[float, float, float]] = []
    channels: list[tuple[str, ...]] = []
    end_parents: list[int] = []
    end_offsets: list[tuple[float, float, float]] = []
    seen: set[str] = set()

    tk.expect("HIERARCHY")
    tk.expect("ROOT")
    # Explicit stack (no recursion): entries are joint index, or -2 for an End Site block.
    stack: list[int] = []

    def open_joint(parent: int, at: int) -> None:
        name = tk.name()
        if name in seen:
            raise tk.error(f"joint name {name!r} is used twice", at)
        seen.add(name)
        tk.expect("{")
        if len(stack) >= MAX_DEPTH:
            raise tk.error(f"hierarchy is nested deeper than {MAX_DEPTH} levels", at)
        names.append(name)
        parents.append(parent)
        tk.expect("OFFSET")
        offsets.append(tk.numbers3("OFFSET"))
        channels.append(_channels(tk, name) if tk.peek() == "CHANNELS" else ())
        stack.append(len(names) - 1)

    open_joint(-1, tk.i - 1)
    while stack:
        at = tk.i
        t = tk.next("'}' closing a joint")
        if t == "}":
            stack.pop()
        elif t == "JOINT":
            if stack[-1] == -2:
                raise tk.error("an End Site cannot have child joints", at)
            open_joint(stack[-1], at)
        elif t == "End":
            if stack[-1] == -2:
                raise tk.error("an End Site cannot hold another End Site", at)
            tk.expect("Site")
            tk.expect("{")
            if len(stack) >= MAX_DEPTH:
                raise tk.error(f"hierarchy is nested deeper than {MAX_DEPTH} levels", at)
            tk.expect("OFFSET")
            end_offsets.append(tk.numbers3("End Site OFFSET"))
            end_parents.append(stack[-1])
            stack.append(-2)
        elif t == "ROOT":
            raise tk.error("more than one ROOT is not supported", at)
        elif t == "{":
            raise tk.error("unexpected '{' (a block must follow ROOT, JOINT or End Site)", at)
        else:
            raise tk.error(f"unexpected {t[:30]!r} inside the hierarchy", at)
    if tk.peek() is not None:
        raise tk.error(f"unexpected {tk.peek()[:30]!r} after the hierarchy (expected MOTION)")
    return names, parents, offsets, channels, end_parents, end_offsets


_MOTION_RE = re.compile(rb"^[ \t]*MOTION[ \t]*\r?$", re.M)


#: Parsed HIERARCHY blocks by their exact bytes (everything before the ``MOTION`` line), so that
#: a file whose block was seen before skips the hierarchy parse: the clips of one capture
#: session share one skeleton text (the 2,902 Bandai-2 clips have three), and parsing it token
#: by token cost about a fifth of reading a clip.  Only blocks that parsed without error are kept
#: (every error is raised, with its line, by the full parse); at most :data:`_HIERARCHIES_MAX`
#: blocks of up to :data:`_HIERARCHY_KEY_MAX` bytes each, the oldest dropped first.
_HIERARCHIES: dict[bytes, tuple] = {}
_HIERARCHIES_MAX = 64
_HIERARCHY_KEY_MAX = 256 * 1024
_HIERARCHIES_LOCK = threading.Lock()


def _remember_hierarchy(key: bytes, motion_line: int, names, parents, offsets, channels,
                        end_parents, end_offsets) -> tuple:
    """The cache entry for a parsed HIERARCHY block (arrays read-only; readers get copies)."""
    off = np.array(offsets, np.float64).reshape(-1, 3)
    end_off = np.array(end_offsets, np.float64).reshape(-1, 3)
    off.flags.writeable = False
    end_off.flags.writeable = False
    entry = (motion_line, tuple(names), tuple(parents), off, tuple(channels), tuple(end_parents),
             end_off)
    if len(key) <= _HIERARCHY_KEY_MAX:
        with _HIERARCHIES_LOCK:
            while len(_HIERARCHIES) >= _HIERARCHIES_MAX:
                _HIERARCHIES.pop(next(iter(_HIERARCHIES)))
            _HIERARCHIES[key] = entry
    return entry


def _text(b: bytes) -> str:
    try:
        return b.decode("utf-8")
    except UnicodeDecodeError:
        return b.decode("latin-1")


def _bytes_of(data: bytes | str, source: str) -> bytes:
    """The file's bytes: str encoded as UTF-8, a UTF-8 byte-order mark dropped, CR LF and
    CR-only line ends turned into LF."""
    if isinstance(data, str):
        try:
            raw = data.encode("utf-8")
        except UnicodeEncodeError as e:  # a lone surrogate: no file holds one
            raise DataError(f"text is not encodable as UTF-8 ({e.reason} at {e.start})",
                            source) from None
    else:
        raw = bytes(data)
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    if b"\r" in raw:  # CR LF (Windows) and CR-only (classic Mac) line ends read as LF
        raw = raw.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    return raw


def _hierarchy_entry(raw: bytes, m, source: str) -> tuple:
    """The HIERARCHY block before the ``MOTION`` line ``m`` (``None``: there is none), from
    :data:`_HIERARCHIES` or parsed and remembered: :func:`_remember_hierarchy`'s entry."""
    key = None if m is None else raw[: m.start()]
    known = None if key is None else _HIERARCHIES.get(key)
    if known is None:
        head = _text(raw if m is None else key)
        motion_line = head.count("\n") + 1
        tk = _Tokens(head, source)
        if not tk.toks:
            raise DataError("empty HIERARCHY block", source, 1)
        if tk.peek() != "HIERARCHY":
            raise DataError("not a BVH file (it must start with HIERARCHY)", source, tk.line_of(0))
        names, parents, offsets, channels, end_parents, end_offsets = _parse_hierarchy(tk)
        if m is None:
            raise DataError("no MOTION block after the hierarchy (the file is truncated)", source,
                            motion_line)
        known = _remember_hierarchy(key, motion_line, names, parents, offsets, channels,
                                    end_parents, end_offsets)
    return known


def _header_line(raw: bytes, pos: int, line: int, prefix: str,
                 source: str) -> tuple[str, int, int, int]:
    """The next non-blank line from byte ``pos`` (line ``line``), which must start with
    ``prefix``: (the rest of it stripped, its line, the byte and line after it)."""
    while True:
        if pos >= len(raw):
            raise DataError(f"truncated MOTION block: missing '{prefix}' line", source, line)
        nl = raw.find(b"\n", pos)
        nl = len(raw) if nl < 0 else nl
        ln = _text(raw[pos:nl]).strip()
        here = line
        pos, line = nl + 1, line + 1
        if ln:
            if not ln.startswith(prefix):
                raise DataError(f"expected '{prefix}', found {ln[:40]!r}", source, here)
            return ln[len(prefix):].strip(), here, pos, line


def _motion_header(raw: bytes, pos: int, line: int,
                   source: str) -> tuple[int, int, float, int, int]:
    """The MOTION header from byte ``pos`` (line ``line``): "Frames: N" then "Frame Time: t",
    each on its own line and within :data:`MAX_FRAMES` / :data:`MIN_FRAME_TIME`: (N, the
    Frames line, t, the byte and line after the header)."""
    ftxt, frames_line, pos, line = _header_line(raw, pos, line, "Frames:", source)
    try:
        n_frames = int(ftxt)
    except ValueError:
        raise DataError(f"Frames: {ftxt[:40]!r} is not an integer", source, frames_line) from None
    if n_frames <= 0:
        raise DataError(f"Frames: {n_frames} (a BVH clip needs at least one frame)", source, frames_line)
    if n_frames > MAX_FRAMES:
        raise DataError(f"Frames: {ftxt[:40]} is over the {MAX_FRAMES:,} frames a clip may have "
                        "(bvh.MAX_FRAMES)", source, frames_line)
    ttxt, time_line, pos, line = _header_line(raw, pos, line, "Frame Time:", source)
    try:
        frame_time = float(ttxt)
    except ValueError:
        raise DataError(f"Frame Time: {ttxt[:40]!r} is not a number", source, time_line) from None
    if not (math.isfinite(frame_time) and frame_time >= MIN_FRAME_TIME):
        raise DataError(f"Frame Time: {ttxt[:40]!r} must be a positive number of seconds (at "
                        f"least {MIN_FRAME_TIME:g}, bvh.MIN_FRAME_TIME)", source, time_line)
    return n_frames, frames_line, frame_time, pos, line


def parse_bvh(data: bytes | str, source: str | Path = "<bvh>", *, check=None) -> Bvh:
    """Parse BVH text (bytes or str); ``source`` names the file in error messages.

    Only the small HIERARCHY block is decoded to text; the MOTION rows go to numpy as bytes.
    ``check(n_frames, frame_time, n_joints)``, when given, is called once the MOTION header is
    read and before the frames are parsed or anything their size is allocated: a caller's caps
    (frames after resampling, memory) raise there (issue 29).
    """
    source = str(source)
    raw = _bytes_of(data, source)
    m = _MOTION_RE.search(raw)
    known = _hierarchy_entry(raw, m, source)
    motion_line, names, parents, offsets, channels, end_parents, end_offsets = known
    n_ch = sum(len(c) for c in channels)

    # ---- MOTION header: "Frames: N" then "Frame Time: t" (each on its own line)
    pos = m.end()
    if raw[pos:pos + 1] == b"\n":
        pos += 1
    n_frames, frames_line, frame_time, pos, line = _motion_header(raw, pos, motion_line + 1,
                                                                  source)
    if check is not None:
        check(n_frames, frame_time, len(names))
    body = memoryview(raw)[pos:]
    first_data_line = line

    # A claim the remaining bytes cannot hold is refused before anything is allocated:
    # every frame line needs at least one byte per value (a digit) plus a separator.
    min_bytes = n_frames * max(2 * n_ch - 1, 1)
    if n_ch and len(body) < min_bytes:
        n_lines = sum(1 for ln in bytes(body).split(b"\n") if ln.strip())
        raise DataError(f"truncated MOTION block: Frames: {n_frames} but only {n_lines} frame "
                        f"line(s) follow", source, frames_line)

    motion = _parse_frames(body, n_frames, n_ch, source, first_data_line, frames_line)
    return Bvh(names, parents, offsets.copy(), channels, end_parents, end_offsets.copy(),
               frame_time, motion)


def _parse_frames(body: memoryview, n_frames: int, n_ch: int, source: str, first_line: int,
                  frames_line: int) -> np.ndarray:
    if n_ch == 0:
        rows = sum(1 for ln in bytes(body).split(b"\n") if ln.strip())
        if rows not in (0, n_frames):
            raise DataError(f"no channels are declared but {rows} frame lines follow",
                            source, first_line)
        return np.zeros((n_frames, 0))
    arr = read_rows(body, n_frames, n_ch)  # exact fixed-point subset, compiled (bvh_numbers)
    if arr is not None:
        return arr
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "input contained no data" -> caught below
            arr = np.loadtxt(io.BytesIO(body), dtype=np.float64, comments=None, ndmin=2,
                             encoding="latin-1")
    except ValueError:
        arr = None
    if arr is not None and arr.shape == (n_frames, n_ch) and np.isfinite(arr).all():
        return arr
    _diagnose_frames(_text(bytes(body)), n_frames, n_ch, source, first_line, frames_line)
    raise DataError("MOTION block could not be parsed", source, first_line)  # pragma: no cover


def _diagnose_frames(body: str, n_frames: int, n_ch: int, source: str, first_line: int,
                     frames_line: int) -> None:
    """Walk the MOTION rows one by one and raise a DataError naming the first bad line."""
    k = 0
    last = first_line
    for i, ln in enumerate(body.split("\n")):
        toks = ln.split()
        if not toks:
            continue
        lineno = first_line + i
        last = lineno
        k += 1
        if k > n_frames:
            raise DataError(f"more frame lines than Frames: {n_frames} declares", source, lineno)
        for c, t in enumerate(toks):
            try:
                v = float(t)
            except ValueError:
                raise DataError(f"frame {k}: value {c + 1} {t[:30]!r} is not a number",
                                source, lineno) from None
            if not math.isfinite(v):
                raise DataError(f"frame {k}: value {c + 1} {t!r} is not finite", source, lineno)
        if len(toks) != n_ch:
            raise DataError(f"frame {k} has {len(toks)} values but the hierarchy declares "
                            f"{n_ch} channels", source, lineno)
    if k < n_frames:
        raise DataError(f"truncated MOTION block: Frames: {n_frames} but only {k} frame line(s) "
                        f"follow", source, last if k else frames_line)


def read_bvh(path: str | Path) -> Bvh:
    """Read a BVH file from disk (errors name ``path``)."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise DataError("file not found", p) from None
    except IsADirectoryError:
        raise DataError("is a directory, not a BVH file", p) from None
    return parse_bvh(data, p)
