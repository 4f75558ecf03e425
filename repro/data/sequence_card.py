"""The card of a composed sequence set: counts, tag pairs, junction quality and the
``fidelity`` object a reviewer checks the composition with (issue 26).

``fidelity`` holds exactly:

- ``successors_per_tag``: per tag, the distinct next tags with training count ≥ 1 (Neural
  Marionette supp. Fig. 1's matrix, :meth:`SequenceSet.tag_pair_counts`);
- ``top4_share``: per tag, the share of its training transitions that go to its 4 most frequent
  successors (Sec. 4.3.2: "a few tag pairs" carry most of the support);
- ``test_sets``: for ``overall`` and ``sufficient`` (supp. §4.2), tag chains of 20 drawn by the
  protocol's own rule (:func:`repro.data.tag_chains.draw_test_sequences`) from every test action
  (seeded, 500 chains): ``unseen_share``, ``median_support``, ``class_share_by_position``
  (:func:`repro.data.tag_chains.test_set_stats`);
- ``truncated_actions``: per scale profile of ``tables/scales.toml``, the share of training
  action segments longer than that profile's ``max_frames`` (the smallest over the Neural
  Marionette protocols of the profile);
- ``junction``: ``above_p99_share`` (5-frame windows at junctions whose mean joint acceleration
  exceeds the 99th percentile of the same statistic over windows inside one segment),
  ``foot_slide_junction`` and ``foot_slide_inside`` (median foot speed during contact, cm/frame);
- ``pairs``: MultiAct's samples (:func:`repro.data.pair_fidelity.pair_fidelity`):
  ``sp_heading_deg_median`` and ``transition_linear_ratio``.
"""

from __future__ import annotations

import json

import numpy as np

from repro.data.clipset import TEST, TRAIN
from repro.data.sequences import (COMPOSE_VERSION, CARD_SCHEMA, ROLE_ACTION, ROLE_NAMES,
                                  STAND_IN_NOTE, foot_joints)
from repro.data.tag_chains import draw_test_sequences, test_set_stats

__all__ = ["card", "card_of", "fidelity", "junction_quality", "quality_of", "junction_fidelity",
           "truncated_actions", "CHAINS", "CHAIN_LENGTH", "TOP_K"]

#: tag chains per test set, their length and the sufficient set's top-k (supp. §4.2)
CHAINS, CHAIN_LENGTH, TOP_K = 500, 20, 4
#: the NM protocols whose items cap an action at ``max_frames`` (repro.data.contexts.ActionSource)
_NM_PROTOCOLS = ("single_action", "multi_action", "ss_ar")


def _stats(x: np.ndarray) -> dict:
    if x.size == 0:
        return {"mean": None, "median": None, "n": 0}
    return {"mean": round(float(x.mean()), 4), "median": round(float(np.median(x)), 4),
            "n": int(x.size)}


def junction_quality(seqs) -> dict:
    """Velocity jump and foot slide at junctions vs inside the clips (docs/data.md).

    - velocity jump: mean over joints of ``||v_t − v_{t−1}||`` (cm/frame², ``v`` the joint
      frame difference) at frames ``t`` whose stencil ``t−2..t`` touches a transition frame
      or spans two segments ("junction"), vs stencils inside one segment ("inside").
    - foot slide: horizontal speed (cm/frame) of the foot joints on frames where that foot is
      within ``foot_contact_m`` of its lowest height in its source clip (transition frames:
      the lower of the two neighbouring clips'), same junction/inside partition.
    """
    F = seqs.n_frames
    cfg = seqs.config
    piece, seq_of = _pieces(seqs)
    out = {"units": {"velocity_jump": "cm/frame^2", "foot_slide": "cm/frame"},
           "foot_contact_m": cfg.foot_contact_m}
    feet = foot_joints(seqs.clips, cfg)
    out["foot_joints"] = [seqs.skeleton.names[j] for j in feet]
    ground = None
    if feet:
        cl = seqs.clips
        fy = np.asarray(cl.joints[:, feet, 1], np.float64)
        L = np.asarray(cl.lengths, np.int64)
        clip_min = np.full((len(cl), len(feet)), np.inf)
        nz = L > 0
        clip_min[nz] = np.minimum.reduceat(fy, np.asarray(cl.starts, np.int64)[nz], axis=0)
        ground = np.full((F, len(feet)), np.nan)
        ground[piece >= 0] = clip_min[seqs.seg_clip[piece[piece >= 0]]]
        # transition frames: the lower ground of the two neighbouring segments
        tl = seqs.trans_length
        if tl.size and int(tl.max()) > 0:
            first = seqs.seq_starts[seqs.trans_seq] + seqs.trans_start
            g = np.minimum(ground[first - 1], ground[first + tl])
            rows = np.repeat(first, tl) + (np.arange(int(tl.sum()))
                                           - np.repeat(np.cumsum(tl) - tl, tl))
            ground[rows] = np.repeat(g, tl, axis=0)
    acc_j, acc_i, slide_j, slide_i = [], [], [], []
    step = 65536
    for s0 in range(0, F, step):  # chunks of frames t (stencils reach back 2 frames)
        lo = max(0, s0 - 2)
        X = seqs.joints[lo:s0 + step].astype(np.float64) * 100.0  # cm
        t = np.arange(max(s0, 2), min(F, s0 + step))
        if t.size:
            x0, x1, x2 = X[t - 2 - lo], X[t - 1 - lo], X[t - lo]
            ok = seq_of[t - 2] == seq_of[t]
            acc = np.linalg.norm(x2 - 2.0 * x1 + x0, axis=-1).mean(axis=-1)
            p0, p1, p2 = piece[t - 2], piece[t - 1], piece[t]
            inside = ok & (p0 >= 0) & (p0 == p1) & (p1 == p2)
            acc_i.append(acc[inside])
            acc_j.append(acc[ok & ~inside])
        t = np.arange(max(s0, 1), min(F, s0 + step))
        if feet and t.size:
            ok = seq_of[t - 1] == seq_of[t]
            cur, prev = X[t - lo][:, feet], X[t - 1 - lo][:, feet]
            contact = (cur[..., 1] / 100.0 - ground[t]) < cfg.foot_contact_m
            speed = np.linalg.norm((cur - prev)[..., [0, 2]], axis=-1)  # (n, feet) cm/frame
            inside = ok & (piece[t - 1] >= 0) & (piece[t - 1] == piece[t])
            slide_i.append(speed[inside[:, None] & contact])
            slide_j.append(speed[(ok & ~inside)[:, None] & contact])
    cat = lambda xs: np.concatenate(xs) if xs else np.zeros(0)  # noqa: E731
    out["velocity_jump"] = {"junction": _stats(cat(acc_j)), "inside": _stats(cat(acc_i))}
    out["foot_slide"] = {"junction": _stats(cat(slide_j)), "inside": _stats(cat(slide_i))}
    for k in ("velocity_jump", "foot_slide"):
        j, i = out[k]["junction"]["mean"], out[k]["inside"]["mean"]
        out[k]["ratio_of_means"] = round(j / i, 3) if (j is not None and i) else None
    return out


def quality_of(seqs) -> dict:
    """:func:`junction_quality` of the sequence set ``seqs``, computed once and kept in its
    ``memo`` (a copy renamed by :func:`repro.data.sequences.sequences_for` shares it)."""
    if "junction_quality" not in seqs.memo:
        seqs.memo["junction_quality"] = junction_quality(seqs)
    return seqs.memo["junction_quality"]


def card_of(seqs) -> dict:
    """The card of the sequence set ``seqs`` (:func:`card`: what ``repro data info`` prints and
    ``card.json`` stores), computed once and kept in its ``memo``; a fresh JSON-able copy on
    every call."""
    if "card" not in seqs.memo:
        seqs.memo["card"] = card(seqs)
    return json.loads(json.dumps(seqs.memo["card"]))


def _pair_summary(counts: np.ndarray, pref: np.ndarray) -> dict:
    total = int(counts.sum())
    flat = np.sort(counts.reshape(-1))[::-1]
    k = max(1, int(round(0.1 * flat.size)))
    top = float(flat[:k].sum() / total) if total else None
    frequent = pref > pref.min(axis=1, keepdims=True)  # every row's frequent successors
    freq = float(counts[frequent].sum() / total) if total and frequent.any() else None
    return {"pairs": total, "zero_pairs": int((counts == 0).sum()), "cells": int(counts.size),
            "top10pct_pairs_mass": None if top is None else round(top, 4),
            "frequent_pairs_mass": None if freq is None else round(freq, 4)}


def card(seqs) -> dict:
    """The view's card (``repro data info``, ``card.json``), with its ``fidelity`` object."""
    names = list(seqs.label_names)
    per_split = {}
    for sname, s in (("train", TRAIN), ("test", TEST)):
        sq = np.flatnonzero(seqs.seq_split == s)
        acts = np.bincount(seqs.seg_seq[seqs.segments(split=s)], minlength=len(seqs))[sq]
        per_split[sname] = {
            "sequences": int(sq.size),
            "clips": int((np.asarray(seqs.clips.split) == s).sum()),
            "segments": {r: int(seqs.segments(split=s, role=i).size)
                         for i, r in enumerate(ROLE_NAMES)},
            "actions_per_sequence": ({"min": int(acts.min()), "mean": round(float(acts.mean()), 3),
                                      "max": int(acts.max())} if acts.size else None),
            "frames": int(seqs.seq_lengths[sq].sum()),
        }
    acts = np.bincount(seqs.seg_seq[seqs.segments()], minlength=len(seqs))
    train_counts = seqs.tag_pair_counts(TRAIN)
    test_counts = seqs.tag_pair_counts(TEST)
    return {
        "schema": CARD_SCHEMA,
        "kind": "composed multi-action sequences",
        "name": seqs.name,
        "fingerprint": seqs.fingerprint,
        "compose_version": COMPOSE_VERSION,
        "source": {"name": seqs.clips.name, "fingerprint": seqs.clips.fingerprint,
                   "clips": len(seqs.clips), "frames": seqs.clips.n_frames},
        "stand_in": STAND_IN_NOTE,
        "config": seqs.config.model_dump(mode="json"),
        "fps": seqs.fps,
        "joints": seqs.skeleton.n_joints,
        "label_names": names,
        "sequences": {"total": len(seqs), "train": per_split["train"]["sequences"],
                      "test": per_split["test"]["sequences"]},
        "segments": {r: int(seqs.segments(role=i).size) for i, r in enumerate(ROLE_NAMES)},
        "actions_per_sequence": ({"min": int(acts.min()), "mean": round(float(acts.mean()), 3),
                                  "max": int(acts.max())} if acts.size else None),
        "frames": {"total": seqs.n_frames,
                   "transition": int((seqs.frame_label < 0).sum()),
                   "transitions": int(seqs.trans_seq.size)},
        "splits": per_split,
        "tag_pairs": {"label_names": names, "rows": "from (earlier segment)",
                      "columns": "to (next segment)",
                      "train": train_counts.tolist(), "test": test_counts.tolist(),
                      "train_summary": _pair_summary(train_counts, seqs.preference),
                      "test_summary": _pair_summary(test_counts, seqs.preference)},
        "preference": {"label_names": names, "matrix": seqs.preference.tolist(),
                       "nonzero": int((seqs.preference > 0).sum())},
        "junction_quality": quality_of(seqs),
        "fidelity": fidelity(seqs),
    }


# ============================================================================ fidelity
def _pieces(seqs) -> tuple[np.ndarray, np.ndarray]:
    """Per packed frame: its segment index (-1 on transition frames) and its sequence."""
    F = seqs.n_frames
    piece = np.full(F, -1, np.int64)
    lens = seqs.seg_length
    if lens.size:
        ramp = np.arange(int(lens.sum())) - np.repeat(np.cumsum(lens) - lens, lens)
        rows = np.repeat(seqs.seq_starts[seqs.seg_seq] + seqs.seg_start, lens) + ramp
        piece[rows] = np.repeat(np.arange(lens.size), lens)
    return piece, np.repeat(np.arange(len(seqs)), seqs.seq_lengths)


def junction_fidelity(seqs) -> dict:
    """``above_p99_share``, ``foot_slide_junction``, ``foot_slide_inside`` (module docstring),
    and ``above_p99_share_seam``: the same share over the windows that hold the seam itself,
    the last transition frame and the next segment's first frame (where every ``P^ini`` ends;
    most junction windows lie in the transition, the previous clip's own warped recording).

    A 5-frame window ``w … w+4`` has the mean, over its three interior frames and the joints,
    of ``||x[t+1] − 2x[t] + x[t−1]||`` (cm/frame²); it is "inside" when its 5 frames lie in one
    segment, "at a junction" when it lies in one sequence and touches a transition frame or two
    segments.  Foot slide: :func:`junction_quality`'s per-frame speeds, medians.
    """
    piece, seq_of = _pieces(seqs)
    F = seqs.n_frames
    # the seam: the last transition frame and the next segment's first frame (where P^ini ends)
    seam = np.zeros(F, bool)
    tl = seqs.trans_length
    if tl.size:
        seam[seqs.seq_starts[seqs.trans_seq] + seqs.trans_start + tl - 1] = True
    inside_s, junction_s, seam_s = [], [], []
    step = 65536
    for s0 in range(0, max(F - 4, 0), step):
        w = np.arange(s0, min(F - 4, s0 + step))
        X = seqs.joints[s0:min(F, s0 + step + 4)].astype(np.float64) * 100.0
        acc = np.linalg.norm(X[2:] - 2.0 * X[1:-1] + X[:-2], axis=-1).mean(-1)  # centre s0+1..
        a = w - s0                                  # acc index of centre w+1 is a
        stat = (acc[a] + acc[a + 1] + acc[a + 2]) / 3.0
        same_seq = seq_of[w] == seq_of[w + 4]
        p = np.stack([piece[w + d] for d in range(5)])
        inside = same_seq & (p[0] >= 0) & (p == p[0]).all(axis=0)
        inside_s.append(stat[inside])
        junction_s.append(stat[same_seq & ~inside])
        # windows holding both the seam's frames (w+d and w+d+1 for some d in 0..3)
        across = np.zeros(w.size, bool)
        for d in range(4):
            across |= seam[w + d] & (piece[w + d + 1] >= 0)
        seam_s.append(stat[same_seq & across])
    ins = np.concatenate(inside_s) if inside_s else np.zeros(0)
    jun = np.concatenate(junction_s) if junction_s else np.zeros(0)
    sea = np.concatenate(seam_s) if seam_s else np.zeros(0)
    p99 = float(np.percentile(ins, 99)) if ins.size else None
    q = junction_quality(seqs)
    fs = q.get("foot_slide", {})
    return {
        "above_p99_share": (round(float((jun > p99).mean()), 4)
                            if jun.size and p99 is not None else None),
        "above_p99_share_seam": (round(float((sea > p99).mean()), 4)
                                 if sea.size and p99 is not None else None),
        "foot_slide_junction": fs.get("junction", {}).get("median"),
        "foot_slide_inside": fs.get("inside", {}).get("median"),
        "inside_p99_cm_per_frame2": None if p99 is None else round(p99, 4),
        "windows": {"junction": int(jun.size), "seam": int(sea.size), "inside": int(ins.size)},
    }


def truncated_actions(seqs) -> dict:
    """Per scale profile: share of training action segments longer than its ``max_frames``."""
    from repro.data.contexts import ActionSource
    from repro.specs.scales import SCALE_NAMES, resolve_scale

    lens = seqs.seg_length[seqs.segments(split=TRAIN, role=ROLE_ACTION)]
    default = ActionSource.model_fields["max_frames"].default
    out = {}
    for name in SCALE_NAMES:
        prof = resolve_scale(name)
        cap = min(int(prof.protocol_config(p).get("max_frames", default)) for p in _NM_PROTOCOLS)
        out[name] = {"max_frames": cap,
                     "share": round(float((lens > cap).mean()), 4) if lens.size else None}
    return out


def _chain_params(test_set: str):
    from types import SimpleNamespace

    return SimpleNamespace(test_set=test_set, sufficient_top_k=TOP_K, sequences=CHAINS,
                           actions_per_sequence=CHAIN_LENGTH, test_set_seed=0,
                           last_next_tag="same")


def fidelity(seqs) -> dict:
    """The card's ``fidelity`` object (module docstring)."""
    C = seqs.n_classes
    counts = seqs.tag_pair_counts(TRAIN)
    row = counts.sum(axis=1)
    top4 = np.sort(counts, axis=1)[:, ::-1][:, :TOP_K].sum(axis=1)
    test = seqs.segments(split=TEST, role=ROLE_ACTION)
    test_sets = None
    if test.size:
        labels = seqs.seg_label[test]
        own = seqs.next_labels(test)
        sets = {}
        for name in ("overall", "sufficient"):
            acts, _ = draw_test_sequences(labels, own, np.arange(test.size), counts, C,
                                          _chain_params(name), "sequence_card")
            sets[name] = test_set_stats(labels[acts], counts, C)
        test_sets = sets
    from repro.data.pair_fidelity import pair_fidelity

    pairs = pair_fidelity(seqs)
    return {
        "successors_per_tag": (counts > 0).sum(axis=1).astype(int).tolist(),
        "top4_share": [round(float(t / r), 4) if r else None for t, r in zip(top4, row)],
        "test_sets": test_sets,
        "truncated_actions": truncated_actions(seqs),
        "junction": junction_fidelity(seqs),
        "pairs": pairs,
    }
