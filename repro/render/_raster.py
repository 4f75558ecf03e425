"""Rasterisation for :mod:`repro.render.strips`: entry arrays and one vectorised composite.

Geometry is gathered as *entries* (flat pixel index, rank, coverage, colour id, depth,
joint id + 1) from ``skimage.draw`` and composited for the whole image at once: per pixel in
rank order with the "over" operator on a premultiplied float canvas; the depth and joint-index
buffers take the last (nearest, in painter's order) entry with coverage >= 0.5.  Text is drawn
by Pillow on a transparent layer and laid over the canvas.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont
from skimage.draw import circle_perimeter_aa, disk, line_aa

DISC_R = 2.5       # joint disc radius, px
TRAJ_ID, DOT_ID = 3, 4   # colour ids of the top view's polyline and its plain dots


#: characters Pillow's built-in font lacks, drawn as their plain forms (ODMO's "−L_es(θ)")
_PLAIN = str.maketrans({"\u2212": "-", "\u03b8": "theta", "\u03c3": "sigma", "\u00b2": "^2"})


@lru_cache(maxsize=8)
def font(size: int):
    return ImageFont.load_default(size=size)


@lru_cache(maxsize=4)
def disc_stamp(radius: float):
    """Offsets and coverage of an anti-aliased disc around (0, 0)."""
    R = int(np.ceil(radius)) + 1
    cov = np.zeros((2 * R + 1, 2 * R + 1), np.float32)
    cov[disk((R, R), radius)] = 1.0
    rr, cc, vv = circle_perimeter_aa(R, R, round(radius))
    np.maximum.at(cov, (rr, cc), vv.astype(np.float32))
    r, c = np.nonzero(cov > 0.02)
    return r - R, c - R, cov[r, c]


def figure(P, parents, child, sides, box, ground, ppm, x_cam, W):
    """Entry arrays (lin, rank, cov, colour, depth, joint+1) of one stick figure in one cell."""
    x0, y0, x1, y1 = box
    d = x_cam - P[:, 0]
    r = np.rint(ground - P[:, 1] * ppm).astype(np.int64)
    c = np.rint((x0 + x1) / 2 - (P[:, 2] - P[0, 2]) * ppm).astype(np.int64)
    pa = parents[child]
    nb, J = len(child), len(P)
    order = np.argsort(-np.concatenate([(d[child] + d[pa]) / 2, d]), kind="stable")
    rank = np.empty(nb + J, np.int64)
    rank[order] = np.arange(nb + J)
    rl, cl = r.tolist(), c.tolist()
    lines = [line_aa(rl[a], cl[a], rl[b], cl[b]) for a, b in zip(child.tolist(), pa.tolist())]
    lines = lines or [(np.zeros(0, np.int64),) * 3]
    n = np.array([len(t[0]) for t in lines[:nb]], np.int64)
    rep = np.repeat(np.arange(nb), n)
    rr = np.concatenate([t[0] for t in lines]).astype(np.int64)
    cc = np.concatenate([t[1] for t in lines]).astype(np.int64)
    vv = np.concatenate([t[2] for t in lines]).astype(np.float32)
    dr, dc = (r[pa] - r[child]), (c[pa] - c[child])
    t = ((rr - r[child][rep]) * dr[rep] + (cc - c[child][rep]) * dc[rep]) \
        / np.maximum(dr * dr + dc * dc, 1)[rep]
    bd = d[child][rep] + np.clip(t, 0, 1) * (d[pa] - d[child])[rep]
    flat = np.abs(dc) >= np.abs(dr)                     # 2 px wide: a copy shifted across
    rr = np.concatenate([rr, rr + flat[rep]])
    cc = np.concatenate([cc, cc + ~flat[rep]])
    rep, vv, bd = np.tile(rep, 2), np.tile(vv, 2), np.tile(bd, 2)
    sr, sc, sv = disc_stamp(DISC_R)
    S = len(sr)
    rr = np.concatenate([rr, (r[:, None] + sr).ravel()])
    cc = np.concatenate([cc, (c[:, None] + sc).ravel()])
    vv = np.concatenate([vv, np.tile(sv, J)])
    dep = np.concatenate([bd, np.repeat(d, S)])
    item = np.concatenate([rep, nb + np.repeat(np.arange(J), S)])
    joint = np.concatenate([child, np.arange(J)])[item]
    keep = (rr >= y0) & (rr < y1) & (cc >= x0) & (cc < x1)
    return (rr[keep] * W + cc[keep], rank[item][keep], vv[keep], sides[joint][keep],
            dep[keep], joint[keep] + 1)


def top_view(root_xz, key, dot_cids, box, scale, W):
    """Entry arrays of a trajectory cell: polyline of (x, z) root positions, key-frame dots."""
    x0, y0, x1, y1 = box
    mid = (root_xz.min(0) + root_xz.max(0)) / 2
    rows = (y0 + y1) / 2 + (root_xz[:, 0] - mid[0]) * scale       # image down = world +x
    cols = (x0 + x1) / 2 - (root_xz[:, 1] - mid[1]) * scale       # image right = world -z
    arc = np.concatenate([[0], np.cumsum(np.hypot(np.diff(rows), np.diff(cols)))])
    step = np.flatnonzero(np.diff(np.floor(arc / 3.0), prepend=-1) != 0)   # >= 3 px apart
    step = np.unique(np.append(step, len(rows) - 1))
    pr, pc = np.rint(rows[step]).astype(int).tolist(), np.rint(cols[step]).astype(int).tolist()
    parts = [line_aa(pr[i], pc[i], pr[i + 1], pc[i + 1]) for i in range(len(pr) - 1)]
    parts = parts or [(np.array([pr[0]]), np.array([pc[0]]), np.array([1.0]))]
    rr = [np.concatenate([p[0] for p in parts]).astype(np.int64)]
    cc = [np.concatenate([p[1] for p in parts]).astype(np.int64)]
    vv = [np.concatenate([p[2] for p in parts]).astype(np.float32)]
    cid = [np.full(len(rr[0]), TRAJ_ID)]
    sr, sc, sv = disc_stamp(2.0)
    kr, kc = np.rint(rows[key]).astype(np.int64), np.rint(cols[key]).astype(np.int64)
    rr.append((kr[:, None] + sr).ravel())
    cc.append((kc[:, None] + sc).ravel())
    vv.append(np.tile(sv, len(key)))
    cid.append(np.repeat(dot_cids, len(sr)))
    rank = [np.zeros(len(rr[0]), np.int64), np.ones(len(rr[1]), np.int64)]
    rr, cc, vv, cid, rank = map(np.concatenate, (rr, cc, vv, cid, rank))
    keep = (rr >= y0) & (rr < y1) & (cc >= x0) & (cc < x1)
    n = int(keep.sum())
    return (rr[keep] * W + cc[keep], rank[keep], vv[keep], cid[keep],
            np.full(n, np.inf), np.zeros(n, np.int64))


def composite(canvas, depth, jidx, parts, colours):
    """Draw entries in order (per pixel: by rank, "over"), vectorised over the whole image."""
    lin, rank, v, cid, d, j = (np.concatenate(a) for a in zip(*parts))
    o = np.argsort(lin * (int(rank.max()) + 1) + rank, kind="stable")
    lin, v, cid, d, j = lin[o], v[o].astype(np.float64), cid[o], d[o], j[o]
    starts = np.flatnonzero(np.diff(lin, prepend=-1))
    ends = np.append(starts[1:], len(lin)) - 1
    L = np.log1p(-np.minimum(v, 1 - 1e-6))
    cs = np.cumsum(L)
    end_of = np.repeat(ends, np.diff(np.append(starts, len(lin))))
    w = v * np.exp(cs[end_of] - cs)                   # coverage left after the later entries
    trans = np.exp(cs[ends] - cs[starts] + L[starts])  # what all entries leave of the old pixel
    add = np.add.reduceat(np.column_stack([w[:, None] * colours[cid], w]), starts, axis=0)
    flat = canvas.reshape(-1, 4)
    u = lin[starts]
    flat[u] = flat[u] * trans[:, None].astype(np.float32) + add.astype(np.float32)
    solid = np.flatnonzero((v >= 0.5) & np.isfinite(d))
    if len(solid):
        ls = lin[solid]
        last = solid[np.append(ls[1:] != ls[:-1], True)]
        depth.reshape(-1)[lin[last]] = d[last]
        jidx.reshape(-1)[lin[last]] = j[last]


def fill(canvas, y0, y1, x0, x1, rgb):
    canvas[y0:y1, x0:x1] = (*(np.asarray(rgb) / 255.0), 1.0)


def dashed_border(canvas, box, rgb, dash=4, gap=3):
    x0, y0, x1, y1 = box
    col = np.array([*(np.asarray(rgb) / 255.0), 1.0], np.float32)
    on_x = (np.arange(x1 - x0) % (dash + gap)) < dash
    on_y = (np.arange(y1 - y0) % (dash + gap)) < dash
    for r in (y0, y0 + 1, y1 - 2, y1 - 1):
        canvas[r, x0:x1][on_x] = col
    for c in (x0, x0 + 1, x1 - 2, x1 - 1):
        canvas[y0:y1, c][on_y] = col


def draw_texts(canvas, texts):
    """Text, anti-aliased by Pillow on a transparent layer, laid "over" the canvas."""
    H, W = canvas.shape[:2]
    layer = Image.new("RGBA", (W, H), (0, 0, 0, 0))
    draw = ImageDraw.Draw(layer)
    for x, y, s, size, rgb in texts:
        if s:
            draw.text((x, y), s.translate(_PLAIN), font=font(size), fill=(*rgb, 255))
    t = np.asarray(layer)
    hit = np.nonzero(t[..., 3])
    src = t[hit].astype(np.float32) / 255.0
    a = src[:, 3:4]
    canvas[hit] = canvas[hit] * (1.0 - a) + np.concatenate([src[:, :3] * a, a], axis=1)


def to_rgba8(canvas) -> np.ndarray:
    """Premultiplied float canvas -> straight-alpha uint8; transparent pixels are white."""
    out = np.full(canvas.shape, 255, np.uint8)
    out[..., 3] = 0
    hit = np.nonzero(canvas[..., 3] > 0)
    px = canvas[hit]
    a = np.clip(px[:, 3:4], 0.0, 1.0)
    rgb = np.clip(px[:, :3] / np.maximum(a, 1e-12), 0.0, 1.0)
    out[hit] = np.rint(np.concatenate([rgb, a], axis=1) * 255.0).astype(np.uint8)
    return out
