"""``long_term``: recurrent long-term generation scored per step (MultiAct Fig. 6; paper
"Comparison with state-of-the-art methods", supp. "Test data for MultiAct"; protocols.md §4.8).
No released code computes this figure; every choice below is recorded as a parameter.
Shared pieces: :mod:`repro.eval.protocols.multiact_common`,
:mod:`repro.eval.protocols.multiact_conditions`.

**Test plan** (:meth:`LongTerm.test_items`, fixed by ``sequence_seed``, the same for every
method and replicate): ``sequences`` label sequences of ``steps`` labels, drawn as walks over
the ``(a_p, a_c)`` label pairs seen in the test split (supp.: "a_1 randomly sampled in A, then
a_{k+1} from {a | (a_k, a) in test set}"): a_1 uniform, each next label uniform among the
successors of the current one.  ``successors = "train_counts"`` walks instead over every pair
the *training* sequences join (``SequenceSet.tag_pair_counts(TRAIN) > 0``, the composer's
matrix read through its public API; a reading, not the paper's).  Labels from which no walk of any length continues (sinks, and
labels leading only to sinks) are pruned first, so every step is a test pair (our choice; the
paper does not say what happens at a dead end).

Lengths (supp.; the released generator's ``recursive/stats.pkl``, §4.8) from
:meth:`repro.data.pairs_build.PairSource.length_stats` (per ``S_c`` label over the training pairs):
``l_T(a)`` = mean transition length before an action of ``a``, ``l_S(a)`` = mean ``S_c`` length
+ 2, both rounded (at least 1 frame).  The previous motion of step x is ``S_{x−1}`` without its
last ``prev_trim`` (2) frames (the reference's "prev S2_len − 2"), cut to its last frames so that
previous + ``l_T`` + ``l_S`` ≤ ``total_cap`` (115, the reference's cap); when even
``min_prev_frames`` would not fit, ``l_S`` is shortened.

**Generation** (:meth:`generate`; all sequences advance together, one batched call per step,
seed ``(replicate seed, step)``):

- step 1 (``initial_generator``): ``"actor"`` (the paper): ACTOR's action for ``a_1`` at the
  origin — the extra model ``"actor"`` for MACVAE / MultiAct, a composite's own ACTOR;
  ``"macvae"`` (the released generator's, §7 MultiAct-9): the method's ``Ŝ_c`` from a real test
  pair with ``a_c = a_1`` (a fixed seeded choice; its lengths);
- steps 2..N: ``method.step(previous action (world), prev length, a_x, l_T, l_S)`` →
  ``[T̂_x, Ŝ_x]``, continuing the previous action;
- the ``"actor"`` row: every step is ACTOR independently (placed at the end of the previous
  action); it makes no transitions, so only its accuracy is measured.

**Columns** (:meth:`measure`), per step x (the figure's axis):

- ``acc@x``: top-1 accuracy (label merging as ``label_merge``) of ``Ŝ_x`` against ``a_x``, scored
  face-front at the last frame of the previous motion given to the step (step 1: at its own
  first frame);
- ``fid_test@x`` (x ≥ 2, methods that make transitions): FID of the ``sequences`` transitions
  ``T̂_x`` against the real transitions of every valid test pair ("All-GT" val, capped at the
  PairSource's ``all_cap_per_label``), each scored at its own anchor;
- the plain ``acc`` (mean over steps) and ``fid_test`` (steps 2..N pooled) are given too.

FID from few samples: the covariance of ``sequences`` 30-d features has rank
``min(sequences − 1, 30)``; below ~2 × 30 samples per step the FID is dominated by its
small-sample bias (it grows as the count falls, for real data too), so per-step values from
fewer than 60 sequences compare methods only at equal counts (docs/evaluators.md, MultiAct).

``segment`` is a label of the spec's column groups (the part a group's columns read); the
protocol measures both parts at once and the field does not enter content keys, so the two
groups of Fig. 6 share their jobs.  ``per_label`` is not read by this protocol.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from repro.data.clipset import TEST
from repro.data.pairs import PairItems, gather_frames
from repro.errors import ConfigError, DataError
from repro.eval.protocols import register
from repro.eval.protocols.multiact_common import (
    MultiActParams,
    MultiActProtocol,
    MultiActSamples,
)
from repro.eval.protocols.multiact_conditions import (
    actor_action_items,
    actor_motion,
    actor_sample,
    anchor_frames,
    at_origin,
    blind,
    check_generated_pairs,
    first_frames,
    generator_name,
    is_pair_generator,
    method_is_composite,
)
from repro.keys import content_key
from repro.motion.motion import Motion
from repro.seeding import derive_seed, numpy_rng


class LongTermParams(MultiActParams):
    """Parameters of :class:`LongTerm` (frames at ``fps``)."""

    UNKEYED: ClassVar[frozenset[str]] = frozenset({"replicates", "segment"})

    steps: int = Field(20, ge=2, description="recurrent steps per sequence (Fig. 6: 20)")
    sequences: int = Field(100, ge=2, description="label sequences (not stated; our choice)")
    initial_generator: Literal["actor", "macvae"] = Field(
        "actor", description="step 1: ACTOR (paper) or the method on a real test pair "
        "(released generator)")
    successors: Literal["test_pairs", "train_counts"] = Field(
        "test_pairs", description="label pairs the walks follow: the (a_p, a_c) of the test "
        "pairs (supp. 'Test data for MultiAct') or every pair with a training count "
        "(SequenceSet.tag_pair_counts(TRAIN) > 0; a reading, not the paper's)")
    sequence_seed: int = Field(0, description="seed of the label sequences and step-1 pairs")
    prev_trim: int = Field(2, ge=0, description="frames dropped from the end of the previous "
                           "action before it conditions the next step (reference: 2)")
    total_cap: int = Field(115, ge=3, description="previous + l_T + l_S at most (reference: 115)")
    min_prev_frames: int = Field(5, ge=1, description="previous frames kept at least "
                                 "(PrevNet's 4 + 1)")
    segment: Literal["action", "transition", "both"] = Field(
        "both", description="the part a column group reads (a spec label; not keyed)")


@dataclass(frozen=True, eq=False)
class LongTermItems:
    """The fixed test plan: ``labels``, ``l_t``, ``l_c``, ``prev_len`` (S, N) int64 per
    sequence and step (``l_t`` = 0 and ``prev_len`` = 0 at step 1 unless seeded from a pair);
    ``pairs`` the test pairs (FID reference of transitions, step-1 seeds); ``init_rows`` (S,)
    the seed pair of each sequence (``initial_generator = "macvae"``, else -1)."""

    pairs: PairItems
    labels: torch.Tensor
    l_t: torch.Tensor
    l_c: torch.Tensor
    prev_len: torch.Tensor
    init_rows: torch.Tensor
    source: str = ""

    @property
    def label_names(self) -> tuple[str, ...]:
        return self.pairs.label_names

    @property
    def skeleton(self):
        return self.pairs.skeleton

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.labels.shape)

    def __len__(self) -> int:
        S, N = self.shape
        return S * N

    def key(self) -> str:
        return content_key({"pairs": self.pairs.key(), "labels": self.labels.tolist(),
                            "l_t": self.l_t.tolist(), "l_c": self.l_c.tolist(),
                            "prev": self.prev_len.tolist(), "init": self.init_rows.tolist(),
                            "source": self.source})


def prune_walk_graph(label_pairs, n_classes: int) -> dict[int, list[int]]:
    """Successor lists of the labels from which a walk can always continue: sinks and labels
    leading only to sinks removed, repeatedly."""
    succ: dict[int, set[int]] = {}
    for a, b in label_pairs:
        if not (0 <= int(a) < n_classes and 0 <= int(b) < n_classes):
            raise DataError(f"label pair ({a}, {b}) outside the {n_classes} labels")
        succ.setdefault(int(a), set()).add(int(b))
    while True:
        nodes = {a for a, s in succ.items() if s}
        changed = False
        for a in list(succ):
            keep = succ[a] & nodes
            if keep != succ[a]:
                succ[a] = keep
                changed = True
            if not keep:
                del succ[a]
                changed = True
        if not changed:
            return {a: sorted(s) for a, s in sorted(succ.items())}


def draw_label_sequences(label_pairs, n_classes: int, sequences: int, steps: int, seed: int,
                         start: Iterable[int] | None = None) -> np.ndarray:
    """(sequences, steps) int64 walks (module docstring); ``start`` restricts a_1."""
    succ = prune_walk_graph(label_pairs, n_classes)
    if not succ:
        raise DataError("the test split's label pairs hold no walk that can continue (every "
                        "label pair leads to a dead end)")
    firsts = sorted(succ)
    if start is not None:
        allowed = sorted({int(a) for a in start} & set(firsts))
        firsts = allowed or firsts
    rng = numpy_rng(seed, "long_term", "labels")
    out = np.zeros((sequences, steps), dtype=np.int64)
    for s in range(sequences):
        a = firsts[int(rng.integers(0, len(firsts)))]
        out[s, 0] = a
        for x in range(1, steps):
            nxt = succ[a]
            a = nxt[int(rng.integers(0, len(nxt)))]
            out[s, x] = a
    return out


@register
class LongTerm(MultiActProtocol):
    """MultiAct's long-term protocol (module docstring)."""

    id = "long_term"
    Params = LongTermParams
    metrics = ("acc", "fid_test")
    real_metrics = ()
    version = 1

    params: LongTermParams

    # -- test plan -------------------------------------------------------------------------
    def walk_pairs(self, clipset) -> list[tuple[int, int]]:
        """The ``(a, b)`` label pairs the walks follow (``successors``): the test pairs' own
        (:meth:`repro.data.pairs_build.PairSource.label_pairs` on TEST; the paper's rule), or every
        pair the training sequences join at least once (the public
        :meth:`repro.data.sequences.SequenceSet.tag_pair_counts` ``(TRAIN)``)."""
        src = self.item_source()
        if self.params.successors == "test_pairs":
            return src.label_pairs(clipset, TEST)
        from repro.data.clipset import TRAIN

        counts = src.sequences(clipset).tag_pair_counts(TRAIN)
        return [(int(a), int(b)) for a, b in zip(*np.nonzero(counts > 0))]

    def test_items(self, clipset) -> LongTermItems:
        """The fixed test plan (module docstring)."""
        import torch

        p = self.params
        src = self.item_source()
        pairs = src.pairs(clipset, TEST)
        C = pairs.n_classes
        stats = src.length_stats(clipset)
        names = pairs.label_names
        if not stats:
            raise DataError(f"data set {clipset.name!r}: no training pair gives lengths")
        mean_T = float(np.mean([v["l_T"] for v in stats.values()]))
        mean_S = float(np.mean([v["l_S"] for v in stats.values()]))
        lT = np.array([max(1, round(stats.get(n, {}).get("l_T", mean_T))) for n in names])
        lS = np.array([max(1, round(stats.get(n, {}).get("l_S", mean_S))) for n in names])
        start = None
        if p.initial_generator == "macvae":
            start = np.unique(pairs.labels.numpy())
        labels = draw_label_sequences(self.walk_pairs(clipset), C, p.sequences, p.steps,
                                      p.sequence_seed, start)
        S, N = labels.shape
        l_t, l_c = lT[labels].copy(), lS[labels].copy()
        l_t[:, 0] = 0
        init = np.full(S, -1, dtype=np.int64)
        if p.initial_generator == "macvae":
            rng = numpy_rng(p.sequence_seed, "long_term", "init")
            y = pairs.labels.numpy()
            for s in range(S):
                pos = np.flatnonzero(y == labels[s, 0])
                if pos.size == 0:
                    raise DataError(f"no test pair has label {names[labels[s, 0]]!r} as S_c")
                init[s] = pos[int(rng.integers(0, pos.size))]
            l_c[:, 0] = pairs.l_c.numpy()[init]
        prev = np.zeros((S, N), dtype=np.int64)
        for x in range(1, N):
            before = l_c[:, x - 1]
            trimmed = np.where(before > p.prev_trim, before - p.prev_trim, before)
            room = p.total_cap - l_t[:, x] - l_c[:, x]
            short = room < p.min_prev_frames
            l_c[short, x] = np.maximum(1, p.total_cap - l_t[short, x] - p.min_prev_frames)
            room = p.total_cap - l_t[:, x] - l_c[:, x]
            prev[:, x] = np.maximum(1, np.minimum(trimmed, room))
        t = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.int64))
        return LongTermItems(pairs, t(labels), t(l_t), t(l_c), t(prev), t(init),
                             source=content_key(self.describe()))

    def extra_models(self, method_id: str, row_config: Mapping | None = None) -> dict[str, str]:
        """``{"actor": "actor"}`` for a pair method without its own ACTOR when step 1 is
        ACTOR's (``initial_generator = "actor"``)."""
        if method_id == "actor" or method_is_composite(method_id):
            return {}
        return {"actor": "actor"} if self.params.initial_generator == "actor" else {}

    # -- generation -------------------------------------------------------------------------
    def generate(self, generator, items: LongTermItems, *, seed: int, replicate: int,
                 need: Iterable[str] | None = None, models: Mapping | None = None,
                 row_config: Mapping | None = None) -> MultiActSamples:
        """Replicate ``replicate``: every sequence generated step by step (module docstring)."""
        import torch

        s0 = self.replicate_seed(seed, replicate)
        S, N = items.shape
        pairs = items.pairs
        K = self.params.actor_initial_frames
        pairgen = is_pair_generator(generator)
        who = f"generator {generator_name(generator)}"
        # step 1
        seed1 = derive_seed(s0, "step", 1)
        a1 = items.labels[:, 0]
        if self.params.initial_generator == "macvae":
            seeds = pairs.subset(items.init_rows)
            cond = blind(seeds)
            place = anchor_frames(cond.motion, cond.l_p)
            if pairgen:
                out = check_generated_pairs(generator.sample(cond, seed=seed1), cond.l_t,
                                            cond.l_c, S, who)
                act = gather_frames(out.motion, out.l_t, out.l_c)
            else:
                act, _ = actor_sample(generator, actor_action_items(
                    generator, a1, items.l_c[:, 0], place, items.label_names, n_init=K),
                    seed=seed1)
        else:
            # step 1 at the origin facing +Z (ACTOR's own frame; the template's pose only)
            template = at_origin(anchor_frames(pairs.motion, pairs.l_p).select(
                torch.zeros(S, dtype=torch.long)))
            act = actor_motion(generator, models, a1, items.l_c[:, 0], template,
                               items.label_names, seed=seed1, n_init=K)
        act = gather_frames(act, torch.zeros(S, dtype=torch.long), items.l_c[:, 0])
        motions = [act]
        l_ts = [torch.zeros(S, dtype=torch.long)]
        anchors = [first_frames(act)]
        prev_act = act
        for x in range(1, N):
            sx = derive_seed(s0, "step", x + 1)
            lt, lc, plen = items.l_t[:, x], items.l_c[:, x], items.prev_len[:, x]
            end = (items.l_c[:, x - 1] - torch.where(items.l_c[:, x - 1] > self.params.prev_trim,
                                                     self.params.prev_trim, 0))
            prev = gather_frames(prev_act, end - plen, plen)
            anchor = anchor_frames(prev, plen)
            if pairgen:
                out = check_generated_pairs(generator.step(prev, plen, items.labels[:, x], lt, lc,
                                                           seed=sx), lt, lc, S, who)
                motions.append(out.motion)
                l_ts.append(lt.clone())
                prev_act = gather_frames(out.motion, out.l_t, out.l_c)
            else:
                m, _ = actor_sample(generator, actor_action_items(
                    generator, items.labels[:, x], lc, anchor, items.label_names, n_init=K),
                    seed=sx)
                m = gather_frames(m, torch.zeros(S, dtype=torch.long), lc)
                motions.append(m)
                l_ts.append(torch.zeros(S, dtype=torch.long))
                prev_act = m
            anchors.append(anchor)
        return self._stack(motions, l_ts, items, anchors, transitions=pairgen)

    def _stack(self, motions, l_ts, items: LongTermItems, anchors, *, transitions: bool):
        import torch

        S, N = items.shape
        W = max(m.n_frames for m in motions)
        lt = torch.stack(l_ts, 1)                       # (S, N)
        lc = items.l_c
        padded = [gather_frames(m, torch.zeros(S, dtype=torch.long), lt[:, x] + lc[:, x], W)
                  for x, m in enumerate(motions)]
        ref = padded[0]
        root = torch.stack([m.root.to(ref.dtype) for m in padded], 1).reshape(S * N, W, 3)
        rot = torch.stack([m.rot6d.to(ref.dtype) for m in padded], 1).reshape(
            S * N, W, *ref.rot6d.shape[2:])
        a_root = torch.stack([a.root.to(ref.dtype) for a in anchors], 1).reshape(S * N, 1, 3)
        a_rot = torch.stack([a.rot6d.to(ref.dtype) for a in anchors], 1).reshape(
            S * N, 1, *ref.rot6d.shape[2:])
        return MultiActSamples(Motion(root, rot, ref.skeleton, ref.fps), lt.reshape(-1),
                               lc.reshape(-1), items.labels.reshape(-1),
                               Motion(a_root, a_rot, ref.skeleton, ref.fps),
                               transitions=transitions, n_sequences=S, n_steps=N,
                               items_key=items.key())

    # -- scoring ----------------------------------------------------------------------------
    def measure(self, generated: MultiActSamples, items: LongTermItems, evaluator, *, seed: int,
                clipset=None) -> dict[str, float]:
        """``acc@x`` (x = 1..N), ``fid_test@x`` (x = 2..N, when the method made transitions),
        ``acc`` and ``fid_test`` (module docstring)."""
        from repro.metrics.fid import FeatureStats

        S, N = items.shape
        self.check_samples(generated, items.key(), S * N)
        if (generated.n_sequences, generated.n_steps) != (S, N):
            raise DataError(f"samples hold {generated.n_sequences}x{generated.n_steps} steps, "
                            f"the plan {S}x{N}")
        self.check_evaluator(evaluator, items.label_names, items.skeleton)
        names = items.label_names
        seg, l_c = generated.action()
        _, logits = self.encode(evaluator, seg, l_c, generated.anchor,
                                derive_seed(seed, self.id, "actions"))
        logits = np.asarray(logits).reshape(S, N, -1)
        y = generated.labels.numpy().reshape(S, N)
        out: dict[str, float] = {}
        accs = []
        for x in range(N):
            a = self.accuracy(logits[:, x], y[:, x], names, 1)
            out[f"acc@{x + 1}"] = a
            accs.append(a)
        out["acc"] = float(np.mean(accs))
        if generated.transitions and N > 1:
            ref_f, _ = self.real_features(evaluator, items.pairs, "transition",
                                          derive_seed(seed, self.id, "reference"))
            ref = FeatureStats.of(ref_f)
            rows = (np.arange(S)[:, None] * N + np.arange(1, N)[None, :]).reshape(-1)
            sub = generated.select(rows)
            tseg, l_t = sub.transition()
            feats, _ = self.encode(evaluator, tseg, l_t, sub.anchor,
                                   derive_seed(seed, self.id, "transitions"))
            feats = np.asarray(feats).reshape(S, N - 1, -1)
            for x in range(1, N):
                out[f"fid_test@{x + 1}"] = self.fid(feats[:, x - 1], ref)
            out["fid_test"] = self.fid(feats.reshape(S * (N - 1), -1), ref)
        return out

    def real_replicate(self, clipset, items, evaluator, *, seed: int, replicate: int):
        raise ConfigError(f"protocol {self.id!r} has no Real row (Fig. 6 shows none)")


__all__ = [
    "LongTerm",
    "LongTermItems",
    "LongTermParams",
    "draw_label_sequences",
    "prune_walk_graph",
]
