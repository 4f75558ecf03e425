"""Comparison strips of a run: for a few test items, one band per table row, the real motion on
top, every row drawn for the *same* item (same tag, context and replicate seed), so the strips
compare like with like (issue 12; drawing in :mod:`repro.render.strips`).

What a strip shows:

- **single action** (Tables 1, 2, 4-single): the item's initial motion ``P^ini`` (its ``K``
  context frames, real for every row, a segment of its own called "context") followed by the
  action: the real test action on top, each row's generated action below.  Key frames are
  evenly spaced over context and action, plus the first generated frame (the junction).
- **multi action** (Tables 3-5, Figs 8, 10): one test sequence: the real ``P^ini`` of action 1,
  then the first ``max_actions`` actions of the chain, each a coloured segment with its tag;
  every junction (an action's first frame) is a key frame, as are each action's middle frame
  and the frame before each later junction; the last ``K`` frames of an action are the context
  the next one was conditioned on (Alg. 1), marked as the next action's transition window; an
  action that Action Revision regenerated (ss_ar, Table 5 / Fig. 10) has "(AR)" after its tag.
  The real band shows the real test actions at the same test-set positions, each in its own
  world frame (they were never one take).

Items: single action: ``items`` test items of different tags (a seeded choice, ``seed``);
multi action: the first ``items`` test sequences (the test set is already a seeded draw).

MultiAct's bands (test pairs ``[S_p, T, S_c]``, long-term label sequences) are drawn by
:mod:`repro.report.pair_strips`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from repro.errors import DataError
from repro.report.strip_parts import Strip, pick_items, strip_joints
from repro.seeding import derive_seed


def _single_strips(band, rows, n_items: int, replicate: int, key_frames: int,
                   seed: int) -> list[Strip]:
    from repro.render.strips import Panel, Segment, key_frame_indices

    items = band.items
    names = items.label_names
    K = items.n_init
    picks = pick_items(items.labels.numpy(), n_items, seed)
    init_w = items.initial_world()
    real = items.real()
    out = []
    for i in picks:
        L = int(items.lengths[i])
        ctx = strip_joints(init_w.select(i))
        tag, nxt = names[int(items.labels[i])], names[int(items.next_labels[i])]
        segs = [Segment(0, K, "context"), Segment(K, K + L, tag)]

        def panel(label, motion):
            act = strip_joints(motion.select(i))[:L]
            return Panel(label, np.concatenate([ctx, act]), tag=tag, segments=segs,
                         frame_offset=-K)

        panels = [panel("Real (test action)", real.motion)]
        shown = []
        for r, g in rows:
            panels.append(panel(r.label, g.motion))
            shown.append(r.row_id)
        frames = key_frame_indices(K + L, key_frames, include=[K - 1, K])
        out.append(Strip(f"band{band.index}-item{i}",
                         f"{band.label}: item {i}: {tag} (next: {nxt}), {L} frames after {K} "
                         "context frames",
                         panels, frames,
                         {"band": band.index, "protocol": band.protocol_id, "item": i, "tag": tag,
                          "next_tag": nxt, "frames": L, "context_frames": K, "rows": shown,
                          "replicate": replicate, "band_label": band.label}))
    return out


def _grounded(joints) -> np.ndarray:
    """A window (first-frame root at the origin) lifted so its lowest joint touches y = 0
    (display only: the strips draw the ground at y = 0)."""
    j = np.asarray(joints, dtype=np.float32)
    return j - np.array([0.0, float(j[..., 1].min()), 0.0], dtype=np.float32)


def _window_strips(band, rows, n_items: int, replicate: int, key_frames: int,
                   seed: int) -> list[Strip]:
    """ODMO's label-conditioned windows (``odmo_generation``, ``trajectory_customisation``):
    per picked sample position (one per tag, seeded), a real training window of the tag on top
    (a real reference-set draw, never a scored clip) and every row's sample at that position
    (same tag, same replicate seed); a customised sample names its target end point."""
    from repro.eval.protocols.odmo_common import real_batch
    from repro.render.strips import Panel, Segment, key_frame_indices

    ctx = band.items
    labels = np.asarray(rows[0][1].labels)
    picks = pick_items(labels, n_items, seed)
    names = ctx.train.label_names
    real = real_batch(ctx.train, 1, derive_seed(seed, "strips", "real"), "strips")
    out = []
    for i in picks:
        tag = names[int(labels[i])]
        T = int(rows[0][1].joints.shape[1])
        segs = [Segment(0, T, tag)]
        top = real.joints[int(np.flatnonzero(real.labels == labels[i])[0])]
        panels = [Panel("Real (a training window)", _grounded(top), tag=tag, segments=segs)]
        shown = []
        for r, g in rows:
            panels.append(Panel(r.label, _grounded(g.joints[i]), tag=tag, segments=segs))
            shown.append(r.row_id)
        target = getattr(rows[0][1], "targets", None)
        extra = "" if target is None else \
            f", target end ({', '.join(f'{v:.2f}' for v in target[i])}) m"
        out.append(Strip(f"band{band.index}-sample{i}",
                         f"{band.label}: sample {i}: {tag}, {T} frames{extra}",
                         panels, key_frame_indices(T, key_frames, include=[0, T - 1]),
                         {"band": band.index, "protocol": band.protocol_id, "item": i,
                          "tag": tag, "frames": T, "context_frames": 0, "rows": shown,
                          "replicate": replicate, "band_label": band.label}))
    return out


def _sequence_strips(band, rows, n_items: int, replicate: int, max_actions: int) -> list[Strip]:
    from repro.render.strips import Panel, Segment

    items = band.items
    ts = band.test_set
    names = items.label_names
    K = items.n_init
    S, L = ts.actions.shape
    A = min(L, max_actions)
    init_w = items.initial_world()
    real = items.real()
    out = []
    for s in range(min(n_items, S)):
        pos = [int(p) for p in ts.actions[s, :A]]
        lens = [int(items.lengths[p]) for p in pos]
        tags = [names[int(items.labels[p])] for p in pos]
        starts = np.concatenate([[K], K + np.cumsum(lens)[:-1]]).astype(int).tolist()
        segs = [Segment(0, K, "context")] + [
            Segment(a, a + n, t, transition=None if j == 0 else (a - K, a))
            for j, (a, n, t) in enumerate(zip(starts, lens, tags))]
        ctx = strip_joints(init_w.select(pos[0]))
        real_j = np.concatenate([ctx] + [strip_joints(real.motion.select(p))[:n]
                                         for p, n in zip(pos, lens)])
        panels = [Panel("Real (test-set actions)", real_j, tag=" > ".join(tags), segments=segs,
                        frame_offset=-K)]
        shown = []
        revised_any = False
        for r, g in rows:
            acts = [strip_joints(g.motion.select(s * L + j))[:n] for j, n in enumerate(lens)]
            rev = [bool(g.revised[s * L + j]) if g.revised is not None else False
                   for j in range(A)]
            revised_any |= any(rev)
            own = [segs[0]] + [Segment(sg.start, sg.stop, sg.tag + (" (AR)" if v else ""),
                                       transition=sg.transition)
                               for sg, v in zip(segs[1:], rev)]
            panels.append(Panel(r.label, np.concatenate([ctx] + acts), tag=" > ".join(tags),
                                segments=own, frame_offset=-K))
            shown.append(r.row_id)
        # P₋₁ of action 1, each junction, each action's middle, and the last frame before each
        # later junction (inside the window the next action is conditioned on)
        frames = sorted({K - 1, *starts, *[a + n // 2 for a, n in zip(starts, lens)],
                         *[a - 1 for a in starts[1:]]})
        out.append(Strip(f"band{band.index}-seq{s}",
                         f"{band.label}: test sequence {s}: actions 1-{A} of {L} "
                         f"({' > '.join(tags)})",
                         panels, frames,
                         {"band": band.index, "protocol": band.protocol_id, "sequence": s,
                          "tags": tags, "frames": lens, "context_frames": K, "rows": shown,
                          "replicate": replicate, "actions_shown": A, "actions": L,
                          "band_label": band.label}))
    return out


def table_strips(rs, *, items: int = 2, replicate: int = 0, key_frames: int = 8,
                 max_actions: int = 4, seed: int = 0) -> tuple[list[Strip], list[str]]:
    """The strips of a run (:class:`repro.engine.run_samples.RunSamples`) and notes on rows
    that have none."""
    from repro.report.pair_strips import long_term_strips, multiact_kind, pair_strips

    reps = sorted({r.replicate for b in rs.bands for r in b.rows})
    if reps and replicate not in reps:
        from repro.errors import ConfigError

        raise ConfigError(f"--replicate {replicate}: the run has replicates "
                          f"{', '.join(map(str, reps))}")
    strips: list[Strip] = []
    notes: list[str] = []
    for band in rs.bands:
        loaded = []
        want_key = None  # the band's test-set key, computed once
        items_key = None  # the band's test items' key (samples that record one: MultiAct)
        for r in (r for r in band.rows if r.replicate == replicate):
            try:
                g = band.load(r)  # DataError: not recorded, gone from the store, malformed
                if band.is_sequence and want_key is None:
                    want_key = band.test_set.key()
                if band.is_sequence and g.test_set_key != want_key:
                    raise DataError("its stored samples are of another test set")
                if getattr(g, "items_key", ""):
                    items_key = items_key or band.items.key()
                    if g.items_key != items_key:
                        raise DataError("its stored samples are of other test items")
                loaded.append((r, g))
            except DataError as e:
                notes.append(f"{r.row_id} ({band.label}): {e}")
        if not loaded:
            continue
        try:
            kind = multiact_kind(band)
            if band.protocol_id == "latent_modes":
                notes.append(f"{band.label}: no strips: its samples are real windows and "
                             "their latent codes (Table 3 scores modes, not generations)")
            elif band.protocol_id in ("odmo_generation", "trajectory_customisation"):
                strips += _window_strips(band, loaded, items, replicate, key_frames, seed)
            elif kind == "pairs":
                strips += pair_strips(band, loaded, items, replicate, key_frames, seed)
            elif kind == "long_term":
                strips += long_term_strips(band, loaded, items, replicate, max_actions)
            elif band.is_sequence:
                strips += _sequence_strips(band, loaded, items, replicate, max_actions)
            else:
                strips += _single_strips(band, loaded, items, replicate, key_frames, seed)
        except DataError as e:  # the band's items or test set cannot be rebuilt
            notes.append(f"{band.label}: no strips: {e}")
    return strips, notes


def write_strips(rs, out_dir: str | Path, *, formats=("png", "exr"), **kw) -> dict:
    """Render every strip of the run into ``out_dir`` (``NAME.png``, ``NAME.exr``) and write
    ``strips.json`` (what each strip shows); returns that record."""
    from repro.render.exr import write_exr
    from repro.render.strips import render_strip, save_png, skeleton_sides

    from repro.store.atomic import output_dir

    out_dir = output_dir(out_dir)  # a file, a device, '' or /proc/x: one error line
    strips, notes = table_strips(rs, **kw)
    sk = None
    record = {"schema": 1, "table": rs.spec.id, "run": rs.run_id, "notes": notes, "strips": []}
    for st in strips:
        if sk is None:
            sk = rs.bands[st.meta["band"]].items.skeleton
        img = render_strip(st.panels, sk.parents, sk.names, frames=st.frames,
                           top_view=True, title=f"{rs.spec.id} | {st.title}",
                           sides=skeleton_sides(sk.names, sk.hips))  # the spec's hips' naming
        files = {}
        if "png" in formats:
            save_png(img, out_dir / f"{st.name}.png")
            files["png"] = f"{st.name}.png"
        if "exr" in formats:
            write_exr(img, out_dir / f"{st.name}.exr")
            files["exr"] = f"{st.name}.exr"
        record["strips"].append({"name": st.name, "title": st.title, "frames": st.frames,
                                 "files": files, **st.meta})
    from repro.store.atomic import write_output

    write_output(out_dir / "strips.json", json.dumps(record, indent=1, sort_keys=True) + "\n")
    return record


__all__ = ["Strip", "table_strips", "write_strips"]
