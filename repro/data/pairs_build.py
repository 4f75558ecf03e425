"""The MultiAct sample builder: ``[S_p, T, S_c]`` pairs from composed sequences (data layer).

:class:`PairSource` (an :class:`repro.data.item_sources.ItemSource`) describes how MultiAct's
training and test samples (protocols.md §4.1; MultiAct supp. "Training data for MACVAE" /
"Test data for MACVAE") are made from a prepared single-action clip set, and builds them as
:class:`repro.data.pairs.PairItems`.  Its ``describe()`` enters the training key of every method
trained on pairs (``builder = "multiact_pairs"``, :func:`repro.engine.steps.training_items`).

Construction (every number is a :class:`PairSource` field; "frames" are frames at ``fps``,
20 for MultiAct, unless "source frames" is said):

1. **Sequences.**  The clip set is composed at its native fps into multi-action sequences
   (:func:`repro.data.sequences.sequences_for`, the composition the Neural Marionette
   protocols use; split by source clip, so a sequence of split ``s`` holds only clips of ``s``).
2. **Resampling.**  Each sequence is converted to a :class:`~repro.motion.motion.Motion`
   (quaternions → 6D) and resampled **once, as a whole**, to ``fps`` with
   :func:`repro.motion.resample.resample_fps` (slerp / linear root).  A pair's window
   ``[S_p, T, S_c]`` is a contiguous run of rows of its resampled sequence, so the three parts
   are continuous by construction (resampling the window alone would give the same curve up
   to a sub-frame phase).  A boundary at source frame ``b`` (relative to the sequence start)
   maps by time to resampled frame ``round(b · fps / src_fps)`` (half up).
   MultiAct's reference instead keeps every ``int(src/20)``-th frame (§4.1); for a 30-fps
   source that step is ``int(30/20) = 1``, which would leave the data at 30 fps, so we
   resample.
3. **Which segments pair up.**  ``S_c`` is every ``ROLE_ACTION`` segment; ``S_p`` is the
   segment before it: another action, or (``lead_in_pairs``, default) the sequence's lead-in,
   a real clip of the same split with a real label.  So every action segment is ``S_c`` of
   exactly one candidate pair, each source clip is scored as ``S_c`` at most once, and the
   first action of each sequence is not lost.  Lead-outs are never ``S_c`` (they are reused
   clips cut to ``lead_frames``).  ``S_p`` and ``S_c`` always come from different source
   clips (the composer never joins a clip to itself).
4. **Transition** (the reference's labelled-transition branch, §4.1 and §7 MultiAct-10): the
   composed transition frames (``blend_frames`` source frames, label -1) extended on both
   sides by ``e = min(round(trans_ext_fraction · l_S1), trans_ext_cap)`` frames, ``l_S1`` the
   whole previous segment's length at ``fps`` (the reference uses S1's length for both
   sides), taken from the end of ``S_p``'s segment and the start of ``S_c``'s.
5. **Crops** (a stand-in choice): bandai2 clips are long (median 5.6 s) while MultiAct's
   samples must total < 119 frames at 20 fps, which BABEL's short segments meet by
   filtering.  Filtering bandai2 would discard almost everything, so ``S_p`` is the last
   ``≤ max_prev_frames`` (40 = 2 s) frames of its segment before the extension and ``S_c``
   the first ``≤ max_curr_frames`` (60 = 3 s) frames of its segment after the extension.
6. **Extra S_c frames.**  The reference appends ``extra_curr_frames`` (3) frames to S2 "when
   the clip continues".  Our reading: ``l_c = min(l_S2', max_curr_frames) + 3`` where
   ``l_S2'`` is what is left of the segment after the extension; the 3 frames are the ones
   following the cut in the sequence (more frames of the same clip when the crop cut it; the
   next transition's blended frames and the next segment's start when the whole segment was
   used, as in BABEL), fewer only if the sequence ends.
7. **Filters** (after resampling): ``l_p + l_t + l_c < max_len − 1``; ``> min_len``; every
   part (``S_p``, ``T``, ``S_c`` and the action frames of ``S_c`` before the extras) ``≥
   min_part``; ``l_p ≥ s1_end_len + 1``.
8. **Sets** (§4.1 "Per-label caps"; per ``S_c`` label, seeded draws without replacement):
   training set = ``train_per_label`` pairs per label (fewer when fewer exist); test sets =
   ``per_label`` per label with labels of fewer pairs **repeated** cyclically (the reference's
   while loop); "All-GT" sets = every pair, capped at ``all_cap_per_label`` per label.

Units: metres, frames at ``fps``.
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from repro.data.clipset import TEST, TRAIN
from repro.data.item_sources import ItemSource, SplitView, cached
from repro.data.pairs import PAIRS_VERSION, PairItems
from repro.errors import DataError
from repro.keys import content_key
from repro.seeding import numpy_rng

__all__ = ["PairSource", "resample_clipset", "resampled_sequences"]

_SPLITS = {TRAIN: "train", TEST: "test"}


class PairSource(ItemSource):
    """How MultiAct's ``[S_p, T, S_c]`` samples are made from a data set (module docstring;
    protocols.md §4.1).  Every field enters :meth:`describe` and so the content keys."""

    VERSION_FIELD: ClassVar[str] = "pairs_version"
    VERSION: ClassVar[int] = PAIRS_VERSION
    ITEM_KIND: ClassVar[str] = "pairs"

    builder: Literal["multiact_pairs"] = "multiact_pairs"   # the engine dispatches on this
    fps: float = Field(20.0, gt=0)          # MultiAct's 20 fps (slerp-resampled, docstring 2.)
    split: Literal["dataset"] = "dataset"   # the data set's stored split (BABEL train / val)
    compose: dict = Field(default_factory=dict)  # repro.data.sequences.ComposeConfig overrides
    lead_in_pairs: bool = True              # also pair a sequence's lead-in with its 1st action
    seed: int = 0                           # seeds every per-label draw
    train_per_label: int = Field(20, ge=1)  # training set: pairs per S_c label
    test_per_label: int = Field(20, ge=1)   # test sets: pairs per S_c label (repeated if fewer)
    all_cap_per_label: int = Field(1000, ge=1)  # "All-GT" sets: cap per S_c label
    max_prev_frames: int = Field(40, ge=1)  # S_p = the last <= 40 frames of its segment
    max_curr_frames: int = Field(60, ge=1)  # S_c = the first <= 60 frames (+ extras)
    trans_ext_fraction: float = Field(0.1, ge=0)  # T extension: fraction of l_S1 per side
    trans_ext_cap: int = Field(5, ge=0)     # ... capped at this many frames per side
    extra_curr_frames: int = Field(3, ge=0)  # frames appended to S_c when the sequence goes on
    max_len: int = Field(120, ge=2)         # keep l_p + l_t + l_c < max_len - 1
    min_len: int = Field(20, ge=0)          # keep l_p + l_t + l_c > min_len
    min_part: int = Field(3, ge=1)          # every part at least this long
    s1_end_len: int = Field(4, ge=1)        # PrevNet's frames: l_p >= s1_end_len + 1

    @field_validator("compose")
    @classmethod
    def _compose_ok(cls, v: dict) -> dict:
        from repro.data.sequences import ComposeConfig

        # a ValidationError here is reported under "compose"; kept as the overrides that
        # differ from the defaults, so equal compositions give equal sources
        full = ComposeConfig(**v).model_dump(mode="json")
        default = ComposeConfig().model_dump(mode="json")
        return {k: full[k] for k in sorted(full) if full[k] != default[k]}

    @field_validator("trans_ext_fraction")
    @classmethod
    def _finite(cls, v: float) -> float:
        if not math.isfinite(v):
            raise ValueError("must be finite")
        return v

    @model_validator(mode="after")
    def _lengths_consistent(self):
        if self.min_len >= self.max_len - 2:
            raise ValueError(f"min_len {self.min_len} leaves no total length below max_len "
                             f"{self.max_len} - 1")
        return self

    # -- description ----------------------------------------------------------------------
    def describe_fields(self) -> dict:
        """Every field, the composition fully resolved."""
        from repro.data.sequences import ComposeConfig

        d = self.model_dump(mode="json")
        d["compose"] = ComposeConfig(**self.compose).model_dump(mode="json")
        return d

    # -- data -----------------------------------------------------------------------------
    def split_clipset(self, clipset):
        """``clipset`` resampled to ``fps`` with its stored split: what the evaluator trains on
        (no test clip is seen by the recogniser).  In-process cached by fingerprint."""
        return cached(content_key({"what": "clipset", "data": clipset.fingerprint,
                                   "fps": self.fps}),
                      lambda: resample_clipset(clipset, self.fps))

    def split_view(self, clipset):
        """What a plan reads of :meth:`split_clipset` without resampling (torch, seconds):
        resampling keeps every clip's label and split."""
        fp = resampled_fingerprint(clipset, self.fps)
        if fp is None:
            return clipset
        return SplitView(fp, clipset.labels, clipset.split, tuple(clipset.label_names))

    def sequences(self, clipset):
        """The composed sequences of ``clipset`` at its native fps (in-process cached).  A
        :class:`~repro.data.sequences.SequenceSet` given instead of a clip set is used as it is
        (its own composition; ``compose`` is not applied): every method below then cuts its
        pairs from those sequences (:func:`repro.data.pair_fidelity.pair_fidelity` does)."""
        from repro.data.sequences import ComposeConfig, SequenceSet, sequences_for

        if isinstance(clipset, SequenceSet):
            return clipset
        return sequences_for(clipset, ComposeConfig(**self.compose))

    def pair_table(self, clipset, split: int) -> dict:
        """Every valid pair of ``split`` (before caps) as arrays, in sequence order:
        ``seq``, ``prev_segment``, ``segment`` (S_c's), ``start`` (row of the pair's first
        frame in its resampled sequence), ``l_p``, ``l_t``, ``l_c``, ``prev_label``, ``label``,
        ``prev_clip``, ``clip``; ``dropped``: {filter: count} of candidates removed."""
        split = _check_split(split)
        tab = self.cached_build("table", clipset, lambda: self._table(clipset, split),
                                kind=type(clipset).__name__, split=split)
        return {**tab, "dropped": dict(tab["dropped"])}   # arrays are read-only

    def pairs(self, clipset, split: int) -> PairItems:
        """Every valid pair of ``split`` (TRAIN or TEST), capped at ``all_cap_per_label`` per
        ``S_c`` label by a seeded draw, in sequence order (the "All-GT" sets, §4.1)."""
        split = _check_split(split)
        tab = self.pair_table(clipset, split)
        rows = []
        for lab in np.unique(tab["label"]):
            idx = np.flatnonzero(tab["label"] == lab)
            rows.append(_draw(idx, self.all_cap_per_label, False,
                              numpy_rng(self.seed, "multiact_pairs", "all", split, int(lab))))
        rows = np.sort(np.concatenate(rows)) if rows else np.zeros(0, np.int64)
        return self._items(clipset, tab, rows, f"all:{_SPLITS[split]}")

    def train_items(self, clipset) -> PairItems:
        """The training set: ``train_per_label`` pairs per ``S_c`` label from the train split
        (fewer when fewer exist), a seeded, deterministic draw; label-major order (§4.1,
        ``sampled_training_data.pkl``)."""
        tab = self.pair_table(clipset, TRAIN)
        rows = self._per_label(tab, self.train_per_label, False, ("train",))
        return self._items(clipset, tab, rows, "train")

    def test_items(self, clipset, per_label: int | None = None) -> PairItems:
        """``per_label`` (default ``test_per_label``) pairs per ``S_c`` label of the test split;
        a label with fewer pairs repeats them cyclically (the reference's while loop, §4.1);
        label-major, deterministic."""
        k = self.test_per_label if per_label is None else int(per_label)
        if k < 1:
            raise ValueError("per_label must be >= 1")
        tab = self.pair_table(clipset, TEST)
        rows = self._per_label(tab, k, True, ("test", k))
        return self._items(clipset, tab, rows, f"test:{k}")

    def reference(self, clipset, split: int, per_label: int, seed: int) -> PairItems:
        """A fresh ``per_label``-per-label subset for an FID reference, redrawn per replicate
        (``seed``), labels with fewer pairs repeated (§4.3-4.4).  TRAIN draws from the training
        set (the reference's all-GT train loader *is* the 1,060 training pairs, §7 MultiAct-8),
        TEST from every test pair (capped at ``all_cap_per_label``).

        Our deviation: a TEST label with no more pairs than ``per_label`` is drawn *with
        replacement* (a bootstrap draw), where the reference repeats the pool, which would
        make every replicate's reference the same set (on bandai2-mini every label has 7 test
        pairs, so Real-test FID_test would be exactly 0); on BABEL val few labels are that
        small.  TRAIN keeps the repetition (the training set is the fixed reference)."""
        split = _check_split(split)
        pool = self.train_items(clipset) if split == TRAIN else self.pairs(clipset, TEST)
        labels = pool.labels.numpy()
        rows = []
        for lab in np.unique(labels):
            idx = np.flatnonzero(labels == lab)
            rng = numpy_rng(seed, "multiact_pairs", "reference", split, int(per_label), int(lab))
            if split == TEST and 0 < idx.size <= int(per_label):
                rows.append(np.sort(rng.choice(idx, size=int(per_label), replace=True)))
            else:
                rows.append(_draw(idx, int(per_label), True, rng))
        sub = pool.subset(np.concatenate(rows))
        return _with_source(sub, f"{sub.source}|reference:{_SPLITS[split]}:{per_label}:{seed}")

    def label_pairs(self, clipset, split: int) -> list[tuple[int, int]]:
        """Sorted ``(a_p, a_c)`` label pairs seen in the valid pairs of ``split`` (the long-term
        test's successor sets, MultiAct supp. "Test data for MultiAct")."""
        tab = self.pair_table(clipset, _check_split(split))
        return sorted({(int(a), int(b)) for a, b in zip(tab["prev_label"], tab["label"])})

    def length_stats(self, clipset) -> dict[str, dict]:
        """Per ``S_c`` label over the training set (:meth:`train_items`): ``n``, the raw means
        ``mean_l_t`` and ``mean_l_c``, and MultiAct's long-term lengths (§4.8,
        ``recursive/stats.pkl``): ``l_T`` = mean transition length before an action of the
        label, ``l_S`` = mean S2 length + 2 (floats; callers round).  Labels without a
        training pair are absent."""
        tr = self.train_items(clipset)
        out = {}
        for lab in np.unique(tr.labels.numpy()).tolist():
            m = tr.labels == lab
            lt, lc = float(tr.l_t[m].double().mean()), float(tr.l_c[m].double().mean())
            out[tr.label_names[lab]] = {"n": int(m.sum()), "mean_l_t": lt, "mean_l_c": lc,
                                        "l_T": lt, "l_S": lc + 2.0}
        return out

    # -- construction ---------------------------------------------------------------------
    def _per_label(self, tab: dict, k: int, repeat: bool, tag: tuple) -> np.ndarray:
        rows = [_draw(np.flatnonzero(tab["label"] == lab), k, repeat,
                      numpy_rng(self.seed, "multiact_pairs", *tag, int(lab)))
                for lab in np.unique(tab["label"])]
        return np.concatenate(rows) if rows else np.zeros(0, np.int64)

    def _table(self, clipset, split: int) -> dict:
        from repro.data.sequences import ROLE_ACTION, ROLE_LEAD_IN

        seqs = self.sequences(clipset)
        res = _resampled(seqs, self.fps)
        segs = seqs.segments(split=split, role=ROLE_ACTION)
        prev = segs - 1
        if segs.size and (prev.min() < 0 or (seqs.seg_seq[prev] != seqs.seg_seq[segs]).any()):
            raise DataError(f"sequences {seqs.name!r}: an action segment opens its sequence")
        roles = (ROLE_ACTION, ROLE_LEAD_IN) if self.lead_in_pairs else (ROLE_ACTION,)
        ok_role = np.isin(seqs.seg_role[prev], roles)
        dropped = {"prev_lead_in": int((~ok_role).sum())}
        segs, prev = segs[ok_role], prev[ok_role]
        s = seqs.seg_seq[segs].astype(np.int64)
        K = res["lengths"][s]
        ratio_num, ratio_den = float(self.fps), float(seqs.fps)

        def m(b):  # source frame (relative to the sequence) -> resampled frame, by time
            return np.minimum(np.floor(b * ratio_num / ratio_den + 0.5 + 1e-9).astype(np.int64), K)

        a0 = m(seqs.seg_start[prev])
        a1 = m(seqs.seg_start[prev] + seqs.seg_length[prev])
        b0 = m(seqs.seg_start[segs])
        b1 = m(seqs.seg_start[segs] + seqs.seg_length[segs])
        la = a1 - a0
        ext = np.array([min(round(self.trans_ext_fraction * int(x)), self.trans_ext_cap)
                        for x in la], dtype=np.int64)
        p_end, t_end = a1 - ext, b0 + ext
        l_p = np.minimum(self.max_prev_frames, p_end - a0)
        start = p_end - l_p
        l_t = t_end - p_end
        own = np.minimum(b1 - t_end, self.max_curr_frames)    # S_c's own action frames
        l_c = np.minimum(own + self.extra_curr_frames, K - t_end)
        total = l_p + l_t + l_c
        checks = [("prev_part", l_p >= max(self.min_part, self.s1_end_len + 1)),
                  ("transition_part", l_t >= self.min_part),
                  ("curr_part", (own >= self.min_part) & (l_c >= self.min_part)),
                  ("max_len", total < self.max_len - 1),
                  ("min_len", total > self.min_len)]
        keep = np.ones(segs.size, dtype=bool)
        for name, ok in checks:
            dropped[name] = int((keep & ~ok).sum())
            keep &= ok
        def pick(x):
            out = np.ascontiguousarray(np.asarray(x, np.int64)[keep])
            out.setflags(write=False)
            return out

        return {"seq": pick(s), "prev_segment": pick(prev), "segment": pick(segs),
                "start": pick(start), "l_p": pick(l_p), "l_t": pick(l_t), "l_c": pick(l_c),
                "prev_label": pick(seqs.seg_label[prev]), "label": pick(seqs.seg_label[segs]),
                "prev_clip": pick(seqs.seg_clip[prev]), "clip": pick(seqs.seg_clip[segs]),
                "dropped": dropped, "sequences": seqs.fingerprint}

    def _items(self, clipset, tab: dict, rows: np.ndarray, what: str) -> PairItems:
        import torch

        from repro.motion.motion import Motion

        seqs = self.sequences(clipset)
        if rows.size == 0:
            raise DataError(f"sequences {seqs.name!r}: no valid MultiAct pair for {what!r} "
                            f"(dropped: {tab['dropped']})")
        res = _resampled(seqs, self.fps)
        rows = np.asarray(rows, np.int64)
        l_p, l_t, l_c = tab["l_p"][rows], tab["l_t"][rows], tab["l_c"][rows]
        total = l_p + l_t + l_c
        W = int(total.max())
        first = res["starts"][tab["seq"][rows]] + tab["start"][rows]
        idx = torch.from_numpy(first[:, None] + np.minimum(np.arange(W)[None, :],
                                                           total[:, None] - 1))
        motion = Motion(res["root"][idx], res["rot6d"][idx], seqs.skeleton, float(self.fps))
        source = "multiact_pairs:" + content_key({"source": self.describe(),
                                                  "sequences": seqs.fingerprint, "set": what})
        return PairItems(motion, l_p, l_t, l_c, tab["prev_label"][rows], tab["label"][rows],
                         tuple(seqs.label_names), segment_index=tab["segment"][rows],
                         source=source, clip_index=tab["clip"][rows])


def _check_split(split) -> int:
    split = int(split)
    if split not in _SPLITS:
        raise ValueError(f"split must be TRAIN ({TRAIN}) or TEST ({TEST}), got {split}")
    return split


def _draw(idx: np.ndarray, k: int, repeat: bool, rng: np.random.Generator) -> np.ndarray:
    """``k`` of ``idx``: a seeded draw without replacement, in ``idx`` order, when there are
    more; all of them when fewer (cyclically repeated up to ``k`` when ``repeat``)."""
    idx = np.asarray(idx, np.int64)
    if idx.size > k:
        return np.sort(rng.choice(idx, size=k, replace=False))
    if repeat and 0 < idx.size < k:
        return np.resize(idx, k)
    return idx


def _with_source(items: PairItems, source: str) -> PairItems:
    import dataclasses

    return dataclasses.replace(items, source=source)


def _resampled(seqs, fps: float) -> dict:
    """Every sequence of ``seqs`` resampled once to ``fps`` (module docstring, step 2):
    ``root`` (F, 3) and ``rot6d`` (F, J, 6) float32 tensors packed by sequence, ``starts`` and
    ``lengths`` (S,) int64.  In-process cached by the sequences' fingerprint."""
    import torch

    from repro.motion.motion import Motion
    from repro.motion.resample import resample_fps
    from repro.motion.rotations import quat_to_6d

    def build():
        roots, rots = [], []
        with _one_thread():
            for s in range(len(seqs)):
                a, n = int(seqs.seq_starts[s]), int(seqs.seq_lengths[s])
                q = torch.from_numpy(np.asarray(seqs.rotations[a:a + n], np.float64))
                r = torch.from_numpy(np.asarray(seqs.root[a:a + n], np.float64))
                mo = resample_fps(Motion(r[None], quat_to_6d(q)[None], seqs.skeleton, seqs.fps),
                                  float(fps))
                roots.append(mo.root[0].to(torch.float32))
                rots.append(mo.rot6d[0].to(torch.float32))
        lengths = np.array([r.shape[0] for r in roots], np.int64)
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
        return {"root": torch.cat(roots), "rot6d": torch.cat(rots), "starts": starts,
                "lengths": lengths}

    return cached(content_key({"what": "resampled", "sequences": seqs.fingerprint,
                               "fps": float(fps), "version": PAIRS_VERSION}), build)


def resampled_sequences(seqs, fps: float) -> dict:
    """Every sequence of ``seqs`` resampled once to ``fps``, as the pairs are cut from them
    (module docstring, step 2): ``root`` (F, 3) and ``rot6d`` (F, J, 6) float32 tensors packed
    by sequence, ``starts`` and ``lengths`` (S,) int64 (in-process cached; read only)."""
    return _resampled(seqs, fps)


def resampled_fingerprint(clips, fps: float) -> str | None:
    """The fingerprint of :func:`resample_clipset` ``(clips, fps)``, computed without
    resampling; None when ``clips`` already runs at ``fps`` (the same object comes back)."""
    if abs(float(clips.fps) - float(fps)) < 1e-9:
        return None
    return content_key({"base": clips.fingerprint, "resample": "slerp", "fps": float(fps)})


def resample_clipset(clips, fps: float):
    """``clips`` with every clip resampled to ``fps`` (slerp rotations, linear root,
    :func:`repro.motion.resample.resample_clip`; joints by forward kinematics), split, labels
    and styles kept; the same object when it already runs at ``fps``."""
    import torch

    from repro.data.clipset import ClipSet
    from repro.motion.resample import resample_clip
    from repro.motion.rotations import quat_to_matrix
    from repro.motion.skeleton import forward_kinematics

    fp = resampled_fingerprint(clips, fps)
    if fp is None:
        return clips
    quats, roots = [], []
    with _one_thread():
        for i in range(len(clips)):
            q, r = resample_clip(np.asarray(clips.clip_rotations(i), np.float64),
                                 np.asarray(clips.clip_root(i), np.float64), clips.fps, fps)
            quats.append(np.asarray(q))
            roots.append(np.asarray(r))
        q = np.concatenate(quats)
        r = np.concatenate(roots)
        joints = np.empty(q.shape[:2] + (3,), np.float32)
        step = 32768
        for s0 in range(0, q.shape[0], step):
            joints[s0:s0 + step] = forward_kinematics(
                clips.skeleton, quat_to_matrix(torch.from_numpy(q[s0:s0 + step])),
                torch.from_numpy(r[s0:s0 + step])).numpy()
    lengths = np.array([x.shape[0] for x in quats], np.int64)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    return ClipSet(name=f"{clips.name}@{float(fps):g}fps", skeleton=clips.skeleton,
                   fps=float(fps), rotations=q.astype(np.float32), root=r.astype(np.float32),
                   joints=joints, starts=starts, lengths=lengths, labels=clips.labels,
                   label_names=clips.label_names, styles=clips.styles,
                   style_names=clips.style_names, clip_names=clips.clip_names,
                   split=clips.split, fingerprint=fp)


class _one_thread:
    """Run torch on one thread (batched kernels round differently with the thread count)."""

    def __enter__(self):
        import torch

        self.before = torch.get_num_threads()
        torch.set_num_threads(1)

    def __exit__(self, *exc):
        import torch

        torch.set_num_threads(self.before)

