"""Comparison strips of MultiAct's protocols (:mod:`repro.eval.protocols.multiact_common`),
called by :func:`repro.report.strip_sets.table_strips` for bands whose test items are
:class:`~repro.data.pairs.PairItems` (``multiact_conditioned``, ``transition``: Tables 1-3, A,
B) or :class:`~repro.eval.protocols.long_term.LongTermItems` (``long_term``: Fig. 6).

**Single step** (one strip per picked test pair; ``items`` pairs of different ``S_c`` labels,
the seeded choice of the single-action strips): the top panel is the real ``[S_p, T, S_c]``
(segments "previous: a_p", "transition" (a transition window), "a_c"); below it, per row, the
``S_p`` the row was conditioned on followed by its generated ``[T̂, Ŝ_c]``, all in the world
frame the samples were made in.  The samples keep only the *last* frame of the previous motion
a row used (its scoring anchor): a row whose anchor is the real ``S_p``'s last frame shows the
real ``S_p``; any other row (Table 3's "prev. motion from ACTOR", ACTOR + SSMCT, ACTOR +
interpolation) took its ``S_p`` from ACTOR, which the samples do not store, so that panel holds
the anchor pose over the ``S_p`` frames, its segment says "generated, not stored" and the
strip's title and ``meta["prev"]`` say so.  A label-only row (ACTOR, Table 2) has no transition:
its ``Ŝ_c`` follows ``S_p`` at once (drawn in the other rows' action colour).  Frames are
numbered from the first generated frame (``S_p`` negative); a panel shorter than the longest
holds its last frame (its tag says "held from" the first held frame).  Key frames:
``key_frames`` evenly spaced over the longest panel plus the last ``S_p`` frame, the first
generated frame and the real ``S_c``'s first frame.

**Long term** (one strip per label sequence, the first ``items`` of the fixed test plan): per
row, the generated chain of the first ``max_actions`` steps, one segment per step (its label;
its generated transition as the segment's transition window).  Step ``x + 1`` continued from
step ``x``'s action without its last ``prev_trim`` frames, so every action but the last shown is
cut there and the chain plays as it was conditioned (:func:`chain_parts`; ``repro export``
writes the same chains).  There is no top panel: no real motion has these label sequences (the
title says "no real counterpart (generated from labels)").  Key frames, on the first row that
made transitions: each step's first frame, its action's first and middle frames, and the last
frame.
"""

from __future__ import annotations

import numpy as np

from repro.errors import DataError

#: metres: a row's anchor within this of the real S_p's last frame used the real S_p
PREV_TOLERANCE = 1e-3
_NO_FRAME = 1_000_000


def multiact_kind(band) -> str | None:
    """``"pairs"``, ``"long_term"`` or None (not a MultiAct band)."""
    from repro.data.pairs import PairItems

    items = band.items
    if isinstance(items, PairItems):
        return "pairs"
    from repro.eval.protocols.long_term import LongTermItems

    return "long_term" if isinstance(items, LongTermItems) else None


def chain_parts(g, sequence: int, steps: int, prev_trim: int) -> list[tuple[int, int, int]]:
    """``(sample row, transition frames, action frames shown)`` of the first ``steps`` steps of
    ``sequence`` in long-term samples ``g``: every action but the last cut to the frames the
    next step continued from (``prev_trim`` fewer when it is longer than that)."""
    N = int(g.n_steps)
    out = []
    for x in range(steps):
        row = sequence * N + x
        lt, lc = int(g.l_t[row]), int(g.l_c[row])
        if x < steps - 1 and lc > prev_trim:
            lc -= prev_trim
        out.append((row, lt, lc))
    return out


def _hold(a: np.ndarray, n: int) -> np.ndarray:
    """``a`` (T, J, 3) extended to ``n`` frames by repeating its last frame."""
    return a if len(a) >= n else np.concatenate([a, np.repeat(a[-1:], n - len(a), 0)])


def _pair_segments(lp: int, lt: int, lc: int, prev_tag: str, tag: str):
    from repro.render.strips import Segment

    end = lp + lt + lc
    # no transition (a label-only row): a one-frame slot past every drawn frame keeps the
    # segment colours (by index) the same as the other rows'
    segs = [Segment(0, lp, prev_tag),
            Segment(lp, lp + lt, "transition", transition=(lp, lp + lt)) if lt > 0
            else Segment(end + _NO_FRAME, end + _NO_FRAME + 1, "no transition")]
    segs.append(Segment(lp + lt, end, tag))
    return segs


def pair_strips(band, rows, n_items: int, replicate: int, key_frames: int, seed: int) -> list:
    """Single-step strips of a ``multiact_conditioned`` / ``transition`` band (module
    docstring); ``rows``: (RowSamples, MultiActSamples) pairs."""
    from repro.render.strips import Panel, key_frame_indices
    from repro.report.strip_parts import Strip, pick_items, strip_joints

    items = band.items
    names = items.label_names
    for r, g in rows:
        if len(g) != len(items):
            raise DataError(f"row {r.row_id}: {len(g)} samples for {len(items)} test pairs")
    out = []
    for i in pick_items(items.labels.numpy(), n_items, seed):
        lp, lt, lc = (int(x[i]) for x in (items.l_p, items.l_t, items.l_c))
        a_p, a_c = names[int(items.prev_labels[i])], names[int(items.labels[i])]
        real = strip_joints(items.motion.select(i))[:lp + lt + lc]
        panels = [Panel("Real (test pair)", real, tag=f"{a_p} > {a_c}",
                        segments=_pair_segments(lp, lt, lc, f"previous: {a_p}", a_c),
                        frame_offset=-lp)]
        shown, prev_of, lengths = [], {}, {}
        for r, g in rows:
            glt, glc = int(g.l_t[i]), int(g.l_c[i])
            gen = strip_joints(g.motion.select(i))[:glt + glc]
            anchor = strip_joints(g.anchor.select(i))[0]
            if float(np.abs(anchor - real[lp - 1]).max()) <= PREV_TOLERANCE:
                prev, ptag, note = real[:lp], f"previous: {a_p}", "S_p real"
                prev_of[r.row_id] = "real"
            else:
                prev = np.repeat(anchor[None], lp, 0)
                ptag = f"prev. {a_p}: generated, not stored (last frame held)"
                note = "S_p not stored"
                prev_of[r.row_id] = "generated (not stored; its last frame held)"
            if glt == 0:
                note += ", no T"
            panels.append(Panel(r.label, np.concatenate([prev, gen]), tag=note,
                                segments=_pair_segments(lp, glt, glc, ptag, a_c),
                                frame_offset=-lp))
            shown.append(r.row_id)
            lengths[r.row_id] = {"transition": glt, "action": glc}
        total = max(len(p.joints) for p in panels)
        for p in panels:
            if len(p.joints) < total:
                p.tag += f", held from {len(p.joints) - lp}"
                p.joints = _hold(p.joints, total)
        inc = [lp - 1, lp] + ([lp + lt] if lt > 0 else [])
        frames = key_frame_indices(total, key_frames, include=[f for f in inc if f < total])
        gen_prev = sorted(k for k, v in prev_of.items() if v != "real")
        out.append(Strip(
            f"band{band.index}-pair{i}",
            f"{band.label}: test pair {i}: {a_p} > {a_c}, S_p {lp} + T {lt} + S_c {lc} frames"
            + ("; generated S_p not stored (its last frame held)" if gen_prev else ""),
            panels, frames,
            {"band": band.index, "protocol": band.protocol_id, "item": i, "tag": a_c,
             "prev_tag": a_p, "frames": {"prev": lp, "transition": lt, "action": lc},
             "row_frames": lengths, "prev": prev_of, "rows": shown, "replicate": replicate,
             "band_label": band.label}))
    return out


def long_term_strips(band, rows, n_items: int, replicate: int, max_actions: int) -> list:
    """Long-term strips of a ``long_term`` band (module docstring)."""
    from repro.render.strips import Panel, Segment
    from repro.report.strip_parts import Strip, strip_joints

    items = band.items
    names = items.label_names
    S, N = items.shape
    A = min(N, max_actions)
    trim = int(band.protocol.params.prev_trim)
    for r, g in rows:
        if (g.n_sequences, g.n_steps) != (S, N):
            raise DataError(f"row {r.row_id}: samples hold {g.n_sequences}x{g.n_steps} steps, "
                            f"the plan {S}x{N}")
    out = []
    for s in range(min(n_items, S)):
        tags = [names[int(items.labels[s, x])] for x in range(A)]
        panels, shown, ref, row_frames = [], [], None, {}
        for r, g in rows:
            parts = chain_parts(g, s, A, trim)
            joints, segs, start = [], [], 0
            for (row, lt, lc), tag in zip(parts, tags):
                joints.append(strip_joints(g.motion.select(row))[:lt + lc])
                segs.append(Segment(start, start + lt + lc, tag,
                                    transition=(start, start + lt) if lt else None))
                start += lt + lc
            panels.append(Panel(r.label, np.concatenate(joints), tag=" > ".join(tags),
                                segments=segs))
            if ref is None and g.transitions:
                ref = panels[-1]
            shown.append(r.row_id)
            row_frames[r.row_id] = [{"transition": lt, "action": lc} for _, lt, lc in parts]
        ref = ref or panels[0]
        total = max(len(p.joints) for p in panels)
        for p in panels:
            if len(p.joints) < total:
                p.tag = f"held from {len(p.joints)}; " + p.tag
                p.joints = _hold(p.joints, total)
        frames = set()
        for sg in ref.segments:
            a = sg.transition[1] if sg.transition else sg.start
            frames |= {sg.start, a, (a + sg.stop - 1) // 2}
        frames.add(ref.segments[-1].stop - 1)
        out.append(Strip(
            f"band{band.index}-seq{s}",
            f"{band.label}: label sequence {s}: steps 1-{A} of {N} ({' > '.join(tags)}); "
            "no real counterpart (generated from labels)",
            panels, sorted(f for f in frames if f < total),
            {"band": band.index, "protocol": band.protocol_id, "sequence": s, "tags": tags,
             "row_frames": row_frames, "prev_trim": trim, "rows": shown,
             "replicate": replicate, "actions_shown": A, "actions": N, "real": None,
             "band_label": band.label}))
    return out


__all__ = ["chain_parts", "long_term_strips", "multiact_kind", "pair_strips"]
