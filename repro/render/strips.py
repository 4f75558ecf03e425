"""Comparison strips of stick figures: one band per motion, one cell per key frame.

What a strip shows: a header (the ``title``, a legend of the multi-action marks when any panel
has segments, the frame index of each column), then one horizontal band per :class:`Panel`,
top to bottom in the given order.  A band is a left margin with the row label (and the panel's
``tag`` under it, grey) followed by one cell per key frame; every panel is drawn at the *same*
frame indices so that rows compare like with like.  Each cell prints ``frame_offset + f`` in
its top-left corner (the header prints the same number when all panels share their
``frame_offset``, else the raw index ``f``).  With
``top_view=True`` each band ends with one more cell: the root's ground-plane trajectory over the
whole motion (polyline) with a dot at each key frame (in its segment's colour for multi-action
panels), at one scale for all bands (fitted to the largest extent over panels), each band's
path centred on its bounding box; seen from above with image right = world -z (as in the side
cells) and image down = world +x (towards the side camera).

Multi-action panels (``segments`` given) get a bar under each cell in the colour of the
segment the frame belongs to (:data:`SEGMENT_PALETTE`, Okabe-Ito, cycling per segment index)
and the segment's tag under the bar of its first key-frame cell; a key frame that starts a
segment other than the first (a junction) gets a dark vertical line at the cell's left edge; a
key frame inside any segment's ``transition`` window gets a dashed border in that segment's
colour and a "T" in the top-right corner.  A legend line in the header explains the marks.

Camera (a documented project convention): orthographic side view from +x looking along -x;
image up = world +y, image right = world **-z** (a true, unmirrored view: the figure's +x side
is the near side, a figure walking towards +z faces left).  One scale everywhere: a cell is
``metres_per_cell_height`` metres tall (``pixels_per_metre = cell height / that``).  Each cell
is centred horizontally on the root joint (joint 0) at that frame; nothing rotates or rescales.
The ground (y = 0) is a thin grey line 10% of the cell height above the cell's bottom edge.
Geometry is clipped to its cell.

Depth: ``depth = x_cam - x`` with ``x_cam`` = the largest x of all drawn joints (all panels, all
key frames) + 1 m, so depth > 0 and nearer is smaller; along a bone it is interpolated between
its ends.  Painter's order: in each cell bones and joint discs are drawn far to near (sorted by
mean depth, descending), so where two overlap the nearer one wins in all three buffers.  The
colour image is anti-aliased (``skimage.draw.line_aa``, 2 px bones; joint discs from
``disk`` + ``circle_perimeter_aa``); a pixel enters the depth and joint-index buffers when its
coverage is at least 0.5.  Text, ground lines, borders and marks are colour only
(``joint_index`` 0, depth inf); so is the top view.

Colours: bones (from a joint to its parent) and discs take the side of the joint's name:
left (``*_L``, ``L_*``, ``Left*``, ``*Left``, ``left_*`` ...) blue :data:`LEFT_RGB`, right
likewise vermillion :data:`RIGHT_RGB`, others (spine, head) dark grey :data:`CENTRE_RGB`.
A skeleton whose hips are declared (a data-set spec's ``[skeleton] hips``: CMU's ``lfemur`` /
``rfemur``) gives the sides by its own naming instead (:func:`skeleton_sides`), passed as
``sides``.
The background is transparent (alpha 0, RGB white); ``rgba`` is straight (not premultiplied)
alpha.  Same input -> identical pixels (no randomness, no time stamps).
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from repro.render import _raster as R
from repro.render._raster import dashed_border, fill, font

LEFT_RGB = (0, 114, 178)
RIGHT_RGB = (213, 94, 0)
CENTRE_RGB = (64, 64, 64)
SEGMENT_PALETTE = ((230, 159, 0), (86, 180, 233), (0, 158, 115), (204, 121, 167),
                   (0, 114, 178), (213, 94, 0), (240, 228, 66))
_TRAJ, _DOT, _INK, _GREY, _FAINT, _GROUND = (150,) * 3, (30,) * 3, (20,) * 3, (105,) * 3, \
    (222,) * 3, (170,) * 3
_COLOURS = np.array([LEFT_RGB, RIGHT_RGB, CENTRE_RGB, _TRAJ, _DOT, *SEGMENT_PALETTE],
                    np.float32) / 255.0
_SEG0 = 5                      # colour id of SEGMENT_PALETTE[0] in _COLOURS
_PAD, _GAP, _BAR_H, _GROUND_FRAC = 4, 6, 20, 0.10


@dataclass
class Segment:
    """Frames ``[start, stop)`` of one action; ``transition``: frames ``[a, b)`` of its blended
    transition / initial-motion window, if any."""

    start: int
    stop: int
    tag: str
    transition: tuple[int, int] | None = None


@dataclass
class Panel:
    """One band of a strip: one motion, ``joints`` (T, J, 3) in metres, y up, ground y = 0."""

    label: str
    joints: np.ndarray
    tag: str = ""
    segments: list[Segment] | None = None
    frame_offset: int = 0


@dataclass
class StripImage:
    """A rendered strip.  ``rgba`` (H, W, 4) uint8, straight alpha; ``depth`` (H, W) float32
    metres from the camera plane, inf where nothing; ``joint_index`` (H, W) uint32, 0 for none,
    ``j + 1`` for joint j's disc or the bone from j to its parent.

    Layout, for overlays and tests: ``frames`` the key frames; ``boxes[(panel, column)]`` =
    ``(x0, y0, x1, y1)`` (end exclusive) of each cell, the top view being column
    ``len(frames)``.  A point (x, y, z) of a cell whose root has z = ``zr`` lies at column
    ``(x0 + x1) / 2 - (z - zr) * pixels_per_metre`` and row
    ``y0 + ground_offset - y * pixels_per_metre`` (rounded)."""

    rgba: np.ndarray
    depth: np.ndarray
    joint_index: np.ndarray
    frames: list[int] = field(default_factory=list)
    boxes: dict = field(default_factory=dict)
    pixels_per_metre: float = 0.0
    ground_offset: int = 0


def key_frame_indices(n_frames: int, k: int, include: Sequence[int] = ()) -> list[int]:
    """``k`` frames evenly spaced over ``[0, n_frames - 1]`` (rounded, deduplicated) plus
    ``include``, sorted."""
    if n_frames < 1:
        raise ValueError(f"key frames need at least one frame, got n_frames={n_frames}")
    if k < 0:
        raise ValueError(f"k must be >= 0, got {k}")
    out = {int(f) for f in np.rint(np.linspace(0, n_frames - 1, k)).astype(int)} if k else set()
    for f in include:
        if not 0 <= int(f) < n_frames:
            raise ValueError(f"included frame {f} is out of range [0, {n_frames - 1}]")
        out.add(int(f))
    return sorted(out)


def side_of(name: str) -> int:
    """0 left, 1 right, 2 centre, from a joint name (see the module docstring)."""
    low = name.lower()
    for side, word, tag in ((0, "left", "l"), (1, "right", "r")):
        if low.startswith((word, tag + "_")) or low.endswith((word, "_" + tag)):
            return side
    return 2


def skeleton_sides(names: Sequence[str], hips: Sequence[str] | None) -> list[int]:
    """Per joint 0 left, 1 right, 2 centre, by the naming of the declared ``hips`` (left,
    right): the two names less their common beginning and end are the side marks (``lfemur``
    / ``rfemur``: ``l`` / ``r``; ``Hip.L`` / ``Hip.R``: ``L`` / ``R``), and a joint is on a
    side when the name made by putting the other side's mark in place of one of its own is also
    a joint (``lhumerus`` / ``rhumerus``; ``lowerback`` has no ``rowerback``).  Joints the rule
    leaves unpaired take :func:`side_of`; without ``hips``, every joint does."""
    if not hips:
        return [side_of(n) for n in names]
    left, right = hips
    k = 0
    while k < min(len(left), len(right)) and left[k] == right[k]:
        k += 1
    e = 0
    while e < min(len(left), len(right)) - k and left[-1 - e] == right[-1 - e]:
        e += 1
    marks = (left[k:len(left) - e], right[k:len(right) - e])
    known = set(names)

    def paired(n: str, mine: str, other: str) -> bool:
        at = n.find(mine)
        while mine and at >= 0:
            if n[:at] + other + n[at + len(mine):] in known:
                return True
            at = n.find(mine, at + 1)
        return False

    return [0 if paired(n, *marks) else 1 if paired(n, *marks[::-1]) else side_of(n)
            for n in names]


def _check(panels, parents, names):
    if not panels:
        raise ValueError("render_strip needs at least one panel")
    parents = np.asarray(parents, dtype=np.int64).reshape(-1)
    J = len(parents)
    if len(names) != J:
        raise ValueError(f"{len(names)} joint names for {J} parents")
    if np.any((parents < -1) | (parents >= J) | (parents == np.arange(J))):
        raise ValueError(f"parents must be -1 or another joint's index in [0, {J}): {parents}")
    for p in panels:
        a = np.asarray(p.joints)
        if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 1:
            raise ValueError(f"panel {p.label!r}: joints must be (T, J, 3), got {a.shape}")
        if a.shape[1] != J:
            raise ValueError(f"panel {p.label!r}: {a.shape[1]} joints, skeleton has {J}")
        if not np.isfinite(a).all():
            raise ValueError(f"panel {p.label!r}: joints contain NaN or inf")
        for s in p.segments or ():
            if not 0 <= s.start < s.stop:        # a segment may run past the motion's end
                raise ValueError(f"panel {p.label!r}: segment {s.tag!r} has frames "
                                 f"[{s.start}, {s.stop})")
    return parents


def _clip_text(text: str, size: int, width: float) -> str:
    f = font(size)
    if f.getlength(text) <= width:
        return text
    while text and f.getlength(text + "..") > width:
        text = text[:-1]
    return text + ".." if text else ""


@dataclass
class _Layout:
    """Where a strip's parts go (:func:`_strip_layout`): the label margin, the image size, the
    header's rows, each band's top and each cell's box."""

    margin: int
    W: int
    H: int
    multi: bool
    legend_y: int | None
    head_y: int
    tops: list[int]
    boxes: dict


def _strip_frames(panels, joints, frames, key_frames: int) -> list[int]:
    """The key frames of :func:`render_strip` (its docstring), checked against every panel."""
    T = min(len(a) for a in joints)
    if frames is None:
        sp = next((p for p in panels if p.segments), None)
        inc = [s.start for s in sp.segments if 0 < s.start < T] if sp else []
        frames = key_frame_indices(T, key_frames, include=inc)
    frames = [int(f) for f in frames]
    if not frames:
        raise ValueError("no frames to draw")
    for p, a in zip(panels, joints):
        bad = [f for f in frames if not 0 <= f < len(a)]
        if bad:
            raise ValueError(f"panel {p.label!r}: frame {bad[0]} is out of range "
                             f"[0, {len(a) - 1}]")
    return frames


def _strip_sides(sides, names) -> np.ndarray:
    """Per joint 0 left, 1 right, 2 centre: ``sides`` checked, or :func:`side_of` of each
    name."""
    if sides is not None and len(sides) != len(names):
        raise ValueError(f"{len(sides)} sides for {len(names)} joints")
    sides = np.array([side_of(n) for n in names] if sides is None else sides, np.int64)
    if ((sides < 0) | (sides > 2)).any():
        raise ValueError("sides are 0 (left), 1 (right) or 2 (centre)")
    return sides


def _strip_layout(panels, frames, top_view: bool, title: str | None, cw: int, ch: int,
                  texts: list) -> _Layout:
    """Lay a strip out top to bottom (title, legend, header, one band per panel); the title's
    text goes into ``texts``."""
    multi = any(p.segments for p in panels)
    margin = int(max(72, min(220, max(font(11).getlength(p.label) for p in panels) + 2 * _PAD)))
    ncol = len(frames) + bool(top_view)
    W = margin + ncol * cw + _PAD
    y = _PAD
    if title:
        texts.append((_PAD, y, _clip_text(title, 13, W - 2 * _PAD), 13, _INK))
        y += 18
    legend_y = y if multi else None
    y += 16 if multi else 0
    head_y, y = y, y + 15
    tops = []
    for p in panels:
        tops.append(y)
        y += ch + (_BAR_H if p.segments else 0) + _GAP
    H = y - _GAP + _PAD
    boxes = {(i, k): (margin + k * cw, tops[i], margin + (k + 1) * cw, tops[i] + ch)
             for i in range(len(panels)) for k in range(ncol)}
    return _Layout(margin, W, H, multi, legend_y, head_y, tops, boxes)


def _strip_header(canvas, texts, panels, frames, lay: _Layout, cw: int, top_view: bool):
    """The header row: "frame", each column's frame number, the top view's title, and the
    legend of the multi-action marks when any panel has segments."""
    head_y, margin = lay.head_y, lay.margin
    texts.append((_PAD, head_y, "frame", 10, _GREY))
    offsets = {p.frame_offset for p in panels}
    shared = offsets.pop() if len(offsets) == 1 else 0
    for k, f in enumerate(frames):
        s = str(shared + f)
        texts.append((int(margin + k * cw + (cw - font(10).getlength(s)) / 2), head_y, s, 10,
                      _INK))
    if top_view:
        texts.append((margin + len(frames) * cw + 4, head_y, "top view (x, z)", 10, _INK))
    if lay.multi:
        _strip_legend(canvas, texts, lay.legend_y)


def _strip_legend(canvas, texts, legend_y: int) -> None:
    """The legend line of the multi-action marks: junction, transition window, segments."""
    x = _PAD
    fill(canvas, legend_y + 1, legend_y + 12, x, x + 2, _INK)
    texts.append((x + 6, legend_y, "junction", 10, _INK))
    x += 12 + int(font(10).getlength("junction"))
    dashed_border(canvas, (x, legend_y, x + 14, legend_y + 12), _GREY, 3, 2)
    texts.append((x + 4, legend_y, "T", 10, _INK))
    texts.append((x + 18, legend_y, "transition window", 10, _INK))
    x += 24 + int(font(10).getlength("transition window"))
    for i in range(4):
        fill(canvas, legend_y + 4, legend_y + 9, x + 8 * i, x + 8 * i + 7, SEGMENT_PALETTE[i])
    texts.append((x + 36, legend_y, "action segments", 10, _INK))


def _top_view_parts(canvas, panels, joints, frames, boxes, cw: int, ch: int, W: int) -> list:
    """Each band's top-view cell (module docstring): its outline drawn, its trajectory and
    key-frame dots returned as parts to composite, at one scale for all bands."""
    parts = []
    roots = [a[:, 0, [0, 2]] for a in joints]
    ext = np.max([r.max(0) - r.min(0) for r in roots], axis=0)
    scale = min((ch - 16) / max(ext[0], 0.5), (cw - 16) / max(ext[1], 0.5))
    for i, (p, r) in enumerate(zip(panels, roots)):
        box = boxes[(i, len(frames))]
        _outline(canvas, box)
        cids = np.array([R.DOT_ID if s < 0 else _SEG0 + s % len(SEGMENT_PALETTE)
                         for s in _segment_index(p, frames)])
        parts.append(R.top_view(r, np.array(frames), cids, box, scale, W))
    return parts


def render_strip(panels: list[Panel], parents: Sequence[int], names: Sequence[str], *,
                 frames: Sequence[int] | None = None, key_frames: int = 8,
                 top_view: bool = False, title: str | None = None,
                 cell: tuple[int, int] = (96, 144),
                 metres_per_cell_height: float = 2.4,
                 sides: Sequence[int] | None = None) -> StripImage:
    """Render ``panels`` (top to bottom) at the same key frames; ``cell`` = (width, height) px;
    ``sides`` (per joint 0 left, 1 right, 2 centre; default :func:`side_of` of each name, see
    :func:`skeleton_sides`) chooses the bone colours.

    ``frames`` None: ``key_frame_indices(min T, key_frames, include=<segment starts but 0 of
    the first panel with segments>)``.  Raises ValueError on bad shapes or frame indices."""
    parents = _check(panels, parents, names)
    joints = [np.asarray(p.joints, dtype=np.float64) for p in panels]
    frames = _strip_frames(panels, joints, frames, key_frames)
    cw, ch = int(cell[0]), int(cell[1])
    ppm = ch / float(metres_per_cell_height)
    ground_off = ch - round(_GROUND_FRAC * ch)
    sides = _strip_sides(sides, names)
    child = np.flatnonzero(parents >= 0)
    texts: list[tuple[int, int, str, int, tuple]] = []
    lay = _strip_layout(panels, frames, top_view, title, cw, ch, texts)
    margin, W, tops, boxes = lay.margin, lay.W, lay.tops, lay.boxes
    canvas = np.zeros((lay.H, W, 4), np.float32)
    depth = np.full((lay.H, W), np.inf, np.float32)
    jidx = np.zeros((lay.H, W), np.uint32)
    x_cam = max(float(a[frames, :, 0].max()) for a in joints) + 1.0
    _strip_header(canvas, texts, panels, frames, lay, cw, top_view)
    # cells
    parts = []
    for i, (p, a) in enumerate(zip(panels, joints)):
        texts.append((_PAD, tops[i] + 4, _clip_text(p.label, 11, margin - 2 * _PAD), 11, _INK))
        if p.tag:
            texts.append((_PAD, tops[i] + 20, _clip_text(p.tag, 10, margin - 2 * _PAD), 10, _GREY))
        for k, f in enumerate(frames):
            x0, y0, x1, _ = box = boxes[(i, k)]
            _outline(canvas, box)
            fill(canvas, y0 + ground_off, y0 + ground_off + 1, x0 + 1, x1 - 1, _GROUND)
            parts.append(R.figure(a[f], parents, child, sides, box, y0 + ground_off, ppm, x_cam,
                                  W))
            texts.append((x0 + 3, y0 + 2, str(p.frame_offset + f), 10, _GREY))
        if p.segments:
            _segment_marks(canvas, texts, p, frames, [boxes[(i, k)] for k in range(len(frames))],
                           cw)
    if top_view:
        parts += _top_view_parts(canvas, panels, joints, frames, boxes, cw, ch, W)
    R.composite(canvas, depth, jidx, parts, _COLOURS)
    R.draw_texts(canvas, texts)
    return StripImage(R.to_rgba8(canvas), depth, jidx, frames, boxes, ppm, ground_off)


def _outline(canvas, box, rgb=_FAINT):
    x0, y0, x1, y1 = box
    fill(canvas, y0, y1, x0, x0 + 1, rgb)
    fill(canvas, y0, y1, x1 - 1, x1, rgb)
    fill(canvas, y0, y0 + 1, x0, x1, rgb)
    fill(canvas, y1 - 1, y1, x0, x1, rgb)


def _segment_index(p: Panel, frames) -> list[int]:
    """Index of the segment each frame belongs to, -1 for none."""
    out = []
    for f in frames:
        hit = [n for n, s in enumerate(p.segments or ()) if s.start <= f < s.stop]
        out.append(hit[0] if hit else -1)
    return out


def _segment_marks(canvas, texts, p, frames, boxes, cw):
    seg_of = _segment_index(p, frames)
    for k, (f, s) in enumerate(zip(frames, seg_of)):
        x0, y0, x1, y1 = boxes[k]
        if s < 0:
            continue
        seg = p.segments[s]
        rgb = SEGMENT_PALETTE[s % len(SEGMENT_PALETTE)]
        fill(canvas, y1 + 2, y1 + 8, x0 + 1, x1 - 1, rgb)
        if k == 0 or seg_of[k - 1] != s:
            span = 1
            while k + span < len(frames) and seg_of[k + span] == s:
                span += 1
            texts.append((x0 + 2, y1 + 8, _clip_text(seg.tag, 10, span * cw - 4), 10, _INK))
        win = [n for n, w in enumerate(p.segments)
               if w.transition is not None and w.transition[0] <= f < w.transition[1]]
        if win:                                  # drawn in the colour of the window's segment
            dashed_border(canvas, boxes[k], SEGMENT_PALETTE[win[0] % len(SEGMENT_PALETTE)])
            texts.append((x1 - 10, y0 + 2, "T", 10, _INK))
        if s > 0 and f == seg.start:
            fill(canvas, y0, y1 + 8, x0, x0 + 2, _INK)


def atomic_write(path, write) -> Path:
    """Call ``write(tmp)`` for a fresh temporary path beside ``path`` (created with the usual
    permissions, i.e. the umask), then ``os.replace`` it onto ``path``; returns ``path``.
    The rename replaces a link at ``path`` instead of writing through it; an OS error is a
    ConfigError naming the file."""
    from repro.errors import ConfigError

    path = Path(path)
    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}-{secrets.token_hex(4)}{path.suffix}"
    try:
        write(str(tmp))
        os.replace(tmp, path)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise ConfigError(f"cannot write {str(path)!r}: {e.strerror or e}") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def save_png(image: StripImage, path) -> Path:
    """Write ``image.rgba`` as a PNG (no metadata, fixed compression), atomically."""
    def write(tmp):
        with open(tmp, "xb") as fh:
            Image.fromarray(image.rgba, "RGBA").save(fh, format="PNG", compress_level=6)

    return atomic_write(path, write)


__all__ = ["CENTRE_RGB", "LEFT_RGB", "RIGHT_RGB", "SEGMENT_PALETTE", "Panel", "Segment",
           "StripImage", "atomic_write", "key_frame_indices", "render_strip", "save_png",
           "side_of", "skeleton_sides"]
