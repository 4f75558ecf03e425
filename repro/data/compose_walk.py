"""The motion graph behind :mod:`repro.data.sequences`: features, junctions, the tag matrix and
the walk (COMPOSE_VERSION 2, issue 26).

Neural Marionette composes its test chains "according to the transition matrix where the number
of connections between different action categories in the training set is calculated in
advance" (Sec. 5.2.1; supp. Sec. 2.1, Fig. 1) and describes that matrix as sparse and skewed:
"except for a few tag pairs (e.g. turn-walk), most of the tag pairs have only limited connected
samples" (Sec. 4.3.2).  BABEL-MAG's actions are cut from continuous recordings, so an action ends
where the next begins and the frames around a junction are recorded motion.  This module makes
the stand-in's compositions hold those properties by design (every number is a
:class:`repro.data.sequences.ComposeConfig` field):

- **Tag matrix** (:func:`tag_matrix`).  Every tag pair is joined by its median best junction
  cost over ``preference_samples`` seeded pairs of training clips.  Each tag's ``n_frequent``
  frequent successors are other tags, chosen by a linear assignment on that cost, rank by rank
  (the diagonal excluded), so that every tag is the rank-r successor of exactly one tag: the
  matrix is doubly stochastic, its stationary class mix is uniform, and chain position does not
  decide class.  Frequent ranks get ``frequent_weights`` (scaled to ``1 − rare_share``); every
  other tag, the tag itself included, is a rare successor sharing ``rare_share`` (Neural
  Marionette's only named frequent pair is cross-class, "turn-walk", Sec. 4.3.2, and supp. §4.2
  lists "the current action tag" beside the top 4).  So every class is one step from every
  class, and the top-4 share is about ``1 − rare_share``.
- **Quotas** (:func:`quotas`).  A split's transitions out of tag ``a`` are drawn without
  replacement from ``round(n_a × P[a])`` (largest remainders; ``n_a`` its clips of ``a``); in
  the training split every pair with ``P > 0`` gets at least one, so every transition a test
  chain can take was seen in training.
- **Junctions** (:func:`best_join`).  A junction from clip A (exit cut ``i``) into clip B (entry
  cut ``j``) may sit anywhere inside the clips.  Its cost compares A's frame ``e = i + k + 1``
  (``k = blend_frames``), i.e. where A would be had it gone on, with B's frame ``j``: the
  Euclidean distance of the root-relative, facing-normalised joint positions plus
  ``velocity_weight`` × that of the facing-normalised world joint velocities (A's backward
  difference at ``e``, B's forward difference at ``j``).  The transition frames are A's own
  recorded frames ``i+1 … i+k`` carried smoothly (smoothstep weights, zero slope at both ends)
  onto B's frame ``j`` (:func:`transition_frames`), so they hold no frame of B's clip and move
  like A's recording.
- **Whole actions.**  An action segment is ``min_action_frames … max_action_frames`` frames of
  its clip (cut anywhere), so no scale profile whose ``max_frames`` is at least
  ``max_action_frames`` truncates an action: the next action starts where the item ends.

Units: frames at the clip set's fps, metres, radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from repro.data.clipset import TRAIN, ClipSet
from repro.errors import DataError
from repro.seeding import numpy_rng

__all__ = ["ROLE_LEAD_IN", "ROLE_ACTION", "ROLE_LEAD_OUT", "ROLE_NAMES", "Features",
           "features", "best_join", "tag_matrix", "quotas", "Walk", "walk_split",
           "rot_y", "quat_yaw_mul", "anchor_joints", "transition_frames"]

ROLE_LEAD_IN, ROLE_ACTION, ROLE_LEAD_OUT = 0, 1, 2
ROLE_NAMES = ("lead_in", "action", "lead_out")
#: frames over which a transition's velocity is brought to the next segment's
#: (:func:`transition_frames`; 10 at 30 fps = 1/3 s)
VELOCITY_FRAMES = 10


# ============================================================================ small math
def rot_y(v: np.ndarray, angle) -> np.ndarray:
    """``R_y(angle) @ v`` for vectors (..., 3); ``angle`` broadcasts to ``v[..., 0]``."""
    c, s = np.cos(angle), np.sin(angle)
    x, z = v[..., 0], v[..., 2]
    out = np.array(v, dtype=np.float64, copy=True)
    out[..., 0] = c * x + s * z
    out[..., 2] = -s * x + c * z
    return out


def quat_yaw_mul(angle, q: np.ndarray) -> np.ndarray:
    """Quaternion product ``q_y(angle) ⊗ q`` (xyzw), i.e. the rotation ``R_y(angle) · R(q)``."""
    angle = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(angle / 2.0), np.sin(angle / 2.0)
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([c * x + s * z, c * y + s * w, c * z - s * x, c * w - s * y], axis=-1)


# ============================================================================ features
@dataclass
class Features:
    """Per-frame junction features of a ClipSet's packed frames.

    ``p`` (F, D) root-relative joint positions rotated by the inverse body heading (m);
    ``vb``/``vf`` (F, D) facing-normalised world joint velocities, backward ``x[t] − x[t−1]``
    and forward ``x[t+1] − x[t]`` differences (the other one at a clip's first / last frame);
    ``h`` (F,) body heading (radians); ``starts``/``lengths`` of the clips.
    """

    p: np.ndarray
    vb: np.ndarray
    vf: np.ndarray
    h: np.ndarray
    starts: np.ndarray
    lengths: np.ndarray


def _headings(clips: ClipSet, rows: np.ndarray, axis: str) -> np.ndarray:
    """Body heading (radians) of packed frame ``rows``: :func:`repro.motion.heading.body_heading`
    computed from the root-to-pelvis chain only (the other joints do not enter it)."""
    import torch

    from repro.motion.heading import HEADING_AXES, body_frame, heading_angle
    from repro.motion.rotations import quat_to_matrix

    sk = clips.skeleton
    body = body_frame(sk)
    chain = [body.pelvis]
    while sk.parents[chain[-1]] != -1:
        chain.append(sk.parents[chain[-1]])
    chain = chain[::-1]
    out = np.empty(rows.shape[0], np.float64)
    step = 65536
    for s in range(0, rows.shape[0], step):
        q = torch.from_numpy(np.asarray(clips.rotations[rows[s:s + step]][:, chain], np.float64))
        R = quat_to_matrix(q)
        G = R[:, 0]
        for k in range(1, len(chain)):
            G = G @ R[:, k]
        out[s:s + step] = heading_angle(G, body.axis(axis), HEADING_AXES[axis]).numpy()
    return out


def features(clips: ClipSet, axis: str, feet: list[int] = (), foot_weight: float = 1.0
             ) -> Features:
    """:class:`Features` of every frame of ``clips`` (float32 positions/velocities); the
    coordinates of the ``feet`` joints are multiplied by ``foot_weight`` (a junction then
    prefers stances that agree, so the transition barely moves a planted foot)."""
    starts = np.asarray(clips.starts, np.int64)
    L = np.asarray(clips.lengths, np.int64)
    F = int(clips.joints.shape[0])
    rows = np.arange(F, dtype=np.int64)
    h = _headings(clips, rows, axis)
    first = np.zeros(F, bool)
    last = np.zeros(F, bool)
    nz = L > 0
    first[starts[nz]] = True
    last[(starts + L - 1)[nz]] = True
    D = clips.joints.shape[1] * 3
    p = np.empty((F, D), np.float32)
    vb = np.empty((F, D), np.float32)
    vf = np.empty((F, D), np.float32)
    scale = np.ones((clips.joints.shape[1], 1))
    scale[list(feet)] = foot_weight
    step = 65536
    for s in range(0, F, step):
        r = rows[s:s + step]
        jnt = np.asarray(clips.joints[r], np.float64)
        root = np.asarray(clips.root[r], np.float64)
        a = np.where(first[r], r, r - 1)
        b = np.where(last[r], r, r + 1)
        back = jnt - np.asarray(clips.joints[a], np.float64)
        fwd = np.asarray(clips.joints[b], np.float64) - jnt
        back = np.where(first[r][:, None, None], fwd, back)   # 1-frame clips: both zero
        fwd = np.where(last[r][:, None, None], back, fwd)
        hh = -h[r][:, None]
        p[s:s + step] = (rot_y(jnt - root[:, None], hh) * scale).reshape(len(r), D)
        vb[s:s + step] = (rot_y(back, hh) * scale).reshape(len(r), D)
        vf[s:s + step] = (rot_y(fwd, hh) * scale).reshape(len(r), D)
    return Features(p=p, vb=vb, vf=vf, h=h, starts=starts, lengths=L)


def best_join(ft: Features, a: int, ex_lo: int, ex_hi: int, b: int, en_lo: int, en_hi: int,
              k: int, vw: float) -> tuple[float, int, int]:
    """Cheapest junction from clip ``a`` (exit cut ``i`` in ``[ex_lo, ex_hi]``) into clip ``b``
    (entry cut ``j`` in ``[en_lo, en_hi]``): ``(cost, i, j)`` as local frame indices, or
    ``(inf, -1, -1)`` when a range is empty.  Cost: module docstring (A's frame ``i + k + 1``
    against B's frame ``j``).  Ties go to the first ``(i, j)`` in row-major order."""
    if ex_hi < ex_lo or en_hi < en_lo:
        return math.inf, -1, -1
    sa, sb = int(ft.starts[a]), int(ft.starts[b])
    e = np.arange(ex_lo, ex_hi + 1) + k + 1 + sa
    j = np.arange(en_lo, en_hi + 1) + sb
    pa, va = ft.p[e].astype(np.float64), ft.vb[e].astype(np.float64)
    pb, vb = ft.p[j].astype(np.float64), ft.vf[j].astype(np.float64)
    best, bi, bj = math.inf, -1, -1
    step = max(1, 65536 // max(1, j.size * pa.shape[1]))
    for s in range(0, e.size, step):
        dp = np.sqrt(((pa[s:s + step, None] - pb[None]) ** 2).sum(-1))
        dv = np.sqrt(((va[s:s + step, None] - vb[None]) ** 2).sum(-1))
        c = dp + vw * dv
        kk = int(np.argmin(c))
        v = float(c.reshape(-1)[kk])
        if v < best:
            best, bi, bj = v, ex_lo + s + kk // j.size, en_lo + kk % j.size
    return best, bi, bj


# ============================================================================ ranges
def action_min_len(L: int, cfg) -> int:
    """An action segment's minimum length in a clip of ``L`` frames (room for the exit
    transition's ``blend_frames + 1`` source frames after it)."""
    return max(1, min(cfg.min_action_frames, L - cfg.blend_frames - 1))


def usable(L: int, cfg) -> bool:
    """Whether a clip of ``L`` frames can be a segment (it must hold the exit transition)."""
    return L >= cfg.blend_frames + 2


def entry_range(L: int, cfg, role: int) -> tuple[int, int]:
    """Allowed entry cuts of a segment of ``role`` in a clip of ``L`` frames."""
    k = cfg.blend_frames
    if role == ROLE_LEAD_OUT:
        return 0, max(0, L - cfg.lead_frames)
    return 0, L - k - 1 - action_min_len(L, cfg)


def exit_range(L: int, cfg, role: int, entry: int) -> tuple[int, int]:
    """Allowed exit cuts of a segment of ``role`` entered at ``entry`` (lead-ins: -1)."""
    k = cfg.blend_frames
    hi = L - k - 2
    if role == ROLE_LEAD_IN:
        return min(cfg.lead_frames - 1, hi), hi
    m = action_min_len(L, cfg)
    return entry + m - 1, min(entry + cfg.max_action_frames - 1, hi)


# ============================================================================ the tag matrix
def tag_matrix(clips: ClipSet, ft: Features, cfg, version: int) -> tuple[np.ndarray, np.ndarray]:
    """(P (C, C) target transition matrix, median best junction cost (C, C)); module docstring."""
    from scipy.optimize import linear_sum_assignment

    C = clips.n_classes
    S = cfg.preference_samples
    L = np.asarray(clips.lengths, np.int64)
    labels = np.asarray(clips.labels, np.int64)
    split = np.asarray(clips.split)
    ok = np.array([usable(int(x), cfg) for x in L])
    pools = []
    for c in range(C):
        idx = np.flatnonzero((labels == c) & (split == TRAIN) & ok)
        if idx.size == 0:  # no train clip of this tag: fall back to all its clips
            idx = np.flatnonzero((labels == c) & ok)
        pools.append(idx)
    rng = numpy_rng(cfg.seed, "compose", version, "preference-samples")
    med = np.full((C, C), np.inf)
    for a in range(C):
        for b in range(C):
            pa, pb = pools[a], pools[b]
            if pa.size == 0 or pb.size == 0:
                continue
            ca = rng.choice(pa, S, replace=pa.size < S)
            cb = rng.choice(pb, S, replace=pb.size < S)
            costs = []
            for x, y in zip(ca.tolist(), cb.tolist()):
                if x == y:
                    continue
                # any exit of x (an action entered at 0 .. its end): the pair's best junction
                e_lo = action_min_len(int(L[x]), cfg) - 1
                e_hi = int(L[x]) - cfg.blend_frames - 2
                f_lo, f_hi = entry_range(int(L[y]), cfg, ROLE_ACTION)
                c, _, _ = best_join(ft, x, e_lo, e_hi, y, f_lo, f_hi, cfg.blend_frames,
                                    cfg.velocity_weight)
                costs.append(c)
            if costs:
                med[a, b] = float(np.median(costs))
    ties = numpy_rng(cfg.seed, "compose", version, "preference-ties").permutation(C)
    present = np.array([p.size > 0 for p in pools])
    nf = min(cfg.n_frequent, int(present.sum()) - 1)
    rank = np.full((C, C), -1, np.int64)   # rank of b among a's frequent successors (0 = first)
    big = 1e12
    act = np.flatnonzero(present)
    for r in range(nf):
        cost = np.where(np.isfinite(med), med, big) + 1e-9 * ties[None, :]
        cost[np.arange(C), np.arange(C)] = big * 10      # the tag itself is never frequent
        cost = np.where(rank >= 0, big * 10, cost)
        sub = cost[np.ix_(act, act)]
        rows, cols = linear_sum_assignment(sub)
        for x, y in zip(rows, cols):
            if sub[x, y] < big:
                rank[act[x], act[y]] = r
    w = np.asarray(cfg.frequent_weights, np.float64)
    P = np.zeros((C, C))
    for a in act:
        freq = rank[a] >= 0
        rare = present & ~freq
        share = cfg.rare_share if rare.any() and freq.any() else float(not freq.any())
        if freq.any():
            ww = w[:int(rank[a, freq].max()) + 1]
            P[a, freq] = (1.0 - share) * ww[rank[a, freq]] / ww[rank[a, freq]].sum()
        if rare.any():
            P[a, rare] = share / rare.sum()
    return P, med


def quotas(P: np.ndarray, n: np.ndarray, at_least_one: bool) -> np.ndarray:
    """(C, C) int64 transition quotas: row ``a`` holds ``n[a]`` transitions split by
    ``P[a]`` (largest remainders, ties to the lower tag), each pair with ``P > 0`` at least
    one when ``at_least_one`` and ``n[a]`` allows (taken from the largest quotas)."""
    C = P.shape[0]
    Q = np.zeros((C, C), np.int64)
    for a in range(C):
        if n[a] <= 0 or P[a].sum() <= 0:
            continue
        x = n[a] * P[a] / P[a].sum()
        q = np.floor(x).astype(np.int64)
        rest = int(n[a] - q.sum())
        order = np.lexsort((np.arange(C), -(x - q)))
        q[order[:rest]] += 1
        if at_least_one:
            need = np.flatnonzero((P[a] > 0) & (q == 0))
            for b in need:
                donor = int(np.lexsort((np.arange(C), -q))[0])
                if q[donor] <= 1:
                    break
                q[donor] -= 1
                q[b] += 1
        Q[a] = q
    return Q


# ============================================================================ the walk
class Walk:
    """One sequence of a split: its clips, roles and cuts (``-1``: none)."""

    __slots__ = ("clips", "roles", "entry", "exit")

    def __init__(self):
        self.clips: list[int] = []
        self.roles: list[int] = []
        self.entry: list[int] = []
        self.exit: list[int] = []


def _draw(rng: np.random.Generator, weights: np.ndarray) -> int:
    return int(rng.choice(weights.shape[0], p=weights / weights.sum()))


class _Walker:
    """One split's walk (:func:`walk_split`): its clips by tag, the transition quotas left, the
    clips not yet used as an action and the split's seeded draws, in the order the walk makes
    them."""

    def __init__(self, clips: ClipSet, ft: Features, P: np.ndarray, cfg, split: int,
                 version: int, members: np.ndarray):
        self.clips, self.ft, self.P, self.cfg, self.split = clips, ft, P, cfg, split
        self.C = clips.n_classes
        self.L = np.asarray(clips.lengths, np.int64)
        self.labels = np.asarray(clips.labels, np.int64)
        self.rng = numpy_rng(cfg.seed, "compose", version, "walk", split)
        self.by_tag = [members[self.labels[members] == c] for c in range(self.C)]
        n = np.array([x.size for x in self.by_tag], np.int64)
        self.Q = quotas(P, n, at_least_one=(split == TRAIN))
        self.unused = [set(x.tolist()) for x in self.by_tag]
        self.n_left = int(members.size)

    def others(self, t: int, clip: int) -> np.ndarray:
        """The split's clips of tag ``t`` other than ``clip``."""
        return self.by_tag[t][self.by_tag[t] != clip]

    def sample(self, pool: np.ndarray) -> np.ndarray:
        """``candidates_per_step`` clips of ``pool`` drawn without replacement (all when fewer)."""
        K = self.cfg.candidates_per_step
        return self.rng.choice(pool, K, replace=False) if pool.size > K else pool

    def cheapest(self, cand: np.ndarray, join) -> tuple[float, int, int, int]:
        """``(cost, c, i, j)`` of the cheapest ``join(c) = (cost, i, j)`` among ``cand`` (ties
        to the first candidate); ``(inf, -1, -1, -1)`` when none joins."""
        best = (math.inf, -1, -1, -1)
        for c in cand.tolist():
            cost, i, j = join(c)
            if cost < best[0]:
                best = (cost, c, i, j)
        return best

    def join_into(self, cand: np.ndarray, b: int):
        """Cheapest lead-in among ``cand`` into action ``b``."""
        L, cfg = self.L, self.cfg
        en = entry_range(int(L[b]), cfg, ROLE_ACTION)

        def join(c: int):
            ex = exit_range(int(L[c]), cfg, ROLE_LEAD_IN, -1)
            return best_join(self.ft, c, ex[0], ex[1], b, en[0], en[1], cfg.blend_frames,
                             cfg.velocity_weight)
        return self.cheapest(cand, join)

    def join_from(self, a: int, entry: int, cand: np.ndarray, role: int):
        """Cheapest continuation from action ``a`` (entered at ``entry``) among ``cand``."""
        L, cfg = self.L, self.cfg
        ex = exit_range(int(L[a]), cfg, ROLE_ACTION, entry)

        def join(c: int):
            en = entry_range(int(L[c]), cfg, role)
            return best_join(self.ft, a, ex[0], ex[1], c, en[0], en[1], cfg.blend_frames,
                             cfg.velocity_weight)
        return self.cheapest(cand, join)

    def next_tag(self, cur: int) -> int:
        """Next tag ∝ the remaining quota of ``cur``'s row (else ``P``) among tags with a clip
        other than ``cur``.  Every departure consumes one quota element, so a split's quotas
        are realised exactly (a tag whose clips are all used ends the sequence with a
        lead-out of that tag instead of an action)."""
        a = self.labels[cur]
        avail = np.array([self.others(t, cur).size > 0 for t in range(self.C)])
        for w in (self.Q[a] * avail, self.P[a] * avail):
            if w.sum() > 0:
                return _draw(self.rng, w.astype(np.float64))
        raise DataError(f"{self.clips.name}: no clip to follow clip {cur} in the "
                        f"{('train', 'test')[self.split]} split")

    def start(self, wk: Walk) -> int:
        """Open ``wk`` with an unused clip drawn as its first action and a lead-in of a tag
        drawn ∝ ``P``'s column of that action's tag; the first action."""
        labels, rng = self.labels, self.rng
        pool = np.array(sorted(set().union(*self.unused)), dtype=np.int64)
        first = int(rng.choice(pool))
        self.unused[labels[first]].discard(first)
        self.n_left -= 1
        avail = np.array([self.others(t, first).size > 0 for t in range(self.C)])
        col = self.P[:, labels[first]] * avail
        t = _draw(rng, col if col.sum() > 0 else avail.astype(np.float64))
        cost, c, i, j = self.join_into(self.sample(self.others(t, first)), first)
        wk.clips += [c, first]
        wk.roles += [ROLE_LEAD_IN, ROLE_ACTION]
        wk.entry += [-1, j]
        wk.exit += [i]
        return first

    def walk(self) -> Walk:
        """The next sequence: a lead-in, ``min_actions … max_actions`` actions (fewer when the
        next tag has no unused clip left) and a lead-out."""
        wk = Walk()
        n_target = int(self.rng.integers(self.cfg.min_actions, self.cfg.max_actions + 1))
        cur, n_act = self.start(wk), 1
        while True:
            t = self.next_tag(cur)
            if self.Q[self.labels[cur], t] > 0:
                self.Q[self.labels[cur], t] -= 1
            end = n_act >= n_target or not self.unused[t]
            if end:
                cost, c, i, j = self.join_from(cur, wk.entry[-1],
                                               self.sample(self.others(t, cur)), ROLE_LEAD_OUT)
                wk.exit.append(i)
                wk.clips.append(c)
                wk.roles.append(ROLE_LEAD_OUT)
                wk.entry.append(j)
                wk.exit.append(-1)
                return wk
            cost, c, i, j = self.join_from(
                cur, wk.entry[-1], self.sample(np.array(sorted(self.unused[t]), np.int64)),
                ROLE_ACTION)
            self.unused[t].discard(c)
            self.n_left -= 1
            wk.exit.append(i)
            wk.clips.append(c)
            wk.roles.append(ROLE_ACTION)
            wk.entry.append(j)
            cur, n_act = c, n_act + 1


def walk_split(clips: ClipSet, ft: Features, P: np.ndarray, cfg, split: int,
               version: int) -> list[Walk]:
    """The sequences of one split (module docstring): every usable clip of the split is the
    action of exactly one sequence; lead-ins and lead-outs reuse other clips of the split."""
    L = np.asarray(clips.lengths, np.int64)
    ok = np.array([usable(int(x), cfg) for x in L])
    members = np.flatnonzero((np.asarray(clips.split) == split) & ok)
    if members.size == 0:
        return []
    if members.size < 2:
        raise DataError(f"{clips.name}: the {('train', 'test')[split]} split has one usable "
                        "clip; composing sequences needs at least two (lead-ins/lead-outs "
                        "reuse another clip of the split)")
    walker = _Walker(clips, ft, P, cfg, split, version, members)
    walks: list[Walk] = []
    while walker.n_left:
        walks.append(walker.walk())
    return walks


# ============================================================================ frames
def anchor_joints(skeleton, feet: list[int]) -> list[int]:
    """Joints whose mean ground-plane position places the next segment: the feet when the
    skeleton has them (a planted foot then stays close), else the root."""
    return list(feet) if feet else [0]


def transition_frames(rot_a: np.ndarray, root_a: np.ndarray, rot_b: np.ndarray,
                      root_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` transition frames from A's recorded frames ``i+1 … e`` (``rot_a`` (k+1, J, 4)
    xyzw and ``root_a`` (k+1, 3), in the sequence frame; ``e = i + k + 1``, ``k ≥ 1``) onto B's
    frames ``j, j+1`` (``rot_b`` (2, J, 4), ``root_b`` (2, 3)).

    Frame ``t`` (``s = t / (k + 1)``) is A's frame ``i + t`` under a displacement map: zero with
    zero slope at ``s = 0`` (A's motion goes on untouched), at ``s = 1`` the difference
    ``B(j) ⊖ A(e)`` (smoothstep ``w = 3s² − 2s³`` over the whole transition) with slope
    ``v_B(j) − v_A(e)`` per frame (a cubic ``g = m·(u³ − u²)`` over the last
    ``m = VELOCITY_FRAMES`` frames, ``u`` running 0 → 1 there; zero before), so the sequence
    arrives at B's first frame with B's velocity (no seam) without a long bulge.  Rotations
    (every joint, world-aligned root): ``q_t = exp(w·log Δ + g·(ω_B − ω_A)) ⊗ q_A(i+t)``
    with ``Δ = q_B(j) ⊗ q_A(e)⁻¹`` and ω the rotation vector of a frame-to-frame step
    (``log(q(t+1) ⊗ q(t)⁻¹)``); the root: ``r_A(i+t) + w·(r_B(j) − r_A(e)) +
    g·(v_B − v_A)``."""
    import roma
    import torch

    from repro import kernels

    k = rot_a.shape[0] - 1
    t = np.arange(1, k + 1, dtype=np.float64)
    s = t / (k + 1)
    w = torch.from_numpy(3.0 * s ** 2 - 2.0 * s ** 3)[:, None, None]
    m = min(VELOCITY_FRAMES, k + 1)
    u = np.clip((t - (k + 1 - m)) / m, 0.0, 1.0)
    h = torch.from_numpy((u ** 3 - u ** 2) * m)[:, None, None]
    qa = torch.from_numpy(np.asarray(rot_a, np.float64))
    qb = torch.from_numpy(np.asarray(rot_b, np.float64))
    inv = roma.quat_conjugation
    delta = roma.unitquat_to_rotvec(roma.quat_product(qb[0], inv(qa[k])))        # (J, 3)
    prev = qa[k - 1] if k >= 1 else qa[k]
    omega_a = roma.unitquat_to_rotvec(roma.quat_product(qa[k], inv(prev)))
    omega_b = roma.unitquat_to_rotvec(roma.quat_product(qb[1], inv(qb[0])))
    corr = roma.rotvec_to_unitquat(w * delta[None] + h * (omega_b - omega_a)[None])  # (k, J, 4)
    q = roma.quat_product(corr, qa[:k])
    q = q / kernels.sqrt((q * q).sum(dim=-1, keepdim=True))   # host-independent bits
    ra, rb = np.asarray(root_a, np.float64), np.asarray(root_b, np.float64)
    va = ra[k] - (ra[k - 1] if k >= 1 else ra[k])
    vb = rb[1] - rb[0]
    root = (ra[:k] + w.numpy()[:, :, 0] * (rb[0] - ra[k])[None]
            + h.numpy()[:, :, 0] * (vb - va)[None])
    return q.numpy(), root
