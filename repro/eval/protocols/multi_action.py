"""``multi_action``: Neural Marionette's multi-action protocol (Table 3, Table 4's multi-action
columns, Fig. 8; paper §5.2.1-5.2.3, supp. §4.2-4.3 and Alg. 1).

**Test sets** (supp. §4.2).  The test actions (:class:`repro.data.contexts.ActionSource`: the
``ROLE_ACTION`` segments of the composed test sequences, each with its real previous motion and
next tag) are filtered by the evaluator's confidence in their own tag (softmax probability of
the true tag on the real action ≥ ``candidate_confidence`` = 0.5): the *action candidates*.
Each test sequence starts from a candidate (the paper "goes through the candidates set": one
sequence per candidate; at smaller scales a seeded choice of ``sequences`` of them) and grows to
``actions_per_sequence`` actions: the next tag is drawn uniformly among

- ``test_set = "overall"``: the tags connected to the current one at least once in training
  (the training sequences' tag-pair counts, :meth:`SequenceSet.tag_pair_counts`);
- ``test_set = "sufficient"``: the top ``sufficient_top_k`` (4) connected tags, the current tag
  and the current action sample's own next tag;

restricted to tags that have a candidate (our choice: a tag without one cannot be drawn); the
action instance is a uniform draw among that tag's candidates.  The test set is fixed by
``test_set_seed`` (the same for every method and replicate).  Each action contributes its tag,
its duration and its trajectory (root actions; zeros for in-place tags), from its real clip;
its next tag is the following action's tag in the test sequence (the last action: its own tag,
as supp. §5.2 assigns by default, ``last_next_tag = "same"``; or its real next tag, ``"own"``).

**Generation** (supp. Alg. 1, the pure generative pipeline): action 1 starts from the real
previous motion of the first candidate; every later action from the last ``initial_frames`` (6)
generated frames of the chain; each step normalises them at ``P₋₁`` (Eq. 3), generates (Eq. 4)
and rotates back (Eq. 5) — :func:`repro.data.action_items.condition_items` and the generator's
``sample``.  All sequences advance together, one batched call per action index.  A replicate
is one pass with its own sampling seed.

**Columns** (§5.2.2), on the evaluator's features of each generated action (the evaluator
removes heading: chained actions take any heading, ``evaluator_heading``), averaged from action
``score_from_action`` (2) on, as the paper's tables are:

- ``acc``: recognition accuracy; ``fid``: FID of the pooled actions against the real actions at
  the same test-set positions (``fid_reference = "test_positions"``: the same tag mix; or every
  candidate once, ``"candidates"``);
- ``pose_gap`` (cm): mean over joints of ||J_prev[T] − J_cur[1]|| at each junction;
- ``vel_gap`` (cm/frame): :func:`repro.metrics.transitions.velocity_gap` (``vel_gap_frames``);
- ``action_qr`` / ``motion_qr``: qualification ratios (Eq. 7).

Per action index x (Fig. 8), ``acc@x`` and ``fid@x`` score the actions at index x;
``action_qr@x`` / ``motion_qr@x`` the first x actions (``qr_over_prefix``);
``pose_gap@x`` / ``vel_gap@x`` the junction into action x.  The harness columns of
:mod:`repro.eval.memorisation` (in no paper; ``memorisation``) score the same actions (from
``score_from_action`` on) against the training items; the Real row gets the two
nearest-training distances of the real actions at the scored positions.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Literal

import numpy as np
from pydantic import Field

from repro.data.action_items import ActionItems, GeneratedItems, condition_items
from repro.data.clipset import TEST, TRAIN
from repro.data.item_sources import cached
from repro.errors import ConfigError, DataError
from repro.eval.memorisation import HARNESS_METRICS
from repro.eval.protocols import register
from repro.eval.protocols.marionette_common import MarionetteParams, MarionetteProtocol
from repro.eval.protocols.marionette_common import read_samples, write_samples
from repro.keys import content_key
from repro.motion.motion import Motion
from repro.seeding import derive_seed, numpy_rng

SAVE_FORMAT = 1
METRICS = ("acc", "fid", "pose_gap", "vel_gap", "action_qr", "motion_qr", *HARNESS_METRICS)
REAL_METRICS = ("acc", "fid", "action_qr", "motion_qr", "nn_train_feat", "nn_train_joint")


class MultiActionParams(MarionetteParams):
    """Parameters of :class:`MultiAction` (frames, fps; the paper's values first; the
    item-source and shared scoring fields come from :class:`MarionetteParams`)."""

    # fixed by the paper (§5.2.1, supp. §4.2)
    candidate_confidence: float = Field(0.5, ge=0, le=1,
                                        description="evaluator confidence a candidate needs")
    sequences: int | None = Field(764, ge=1, description="test sequences (None: one per candidate)")
    actions_per_sequence: int = Field(20, ge=2, description="actions per test sequence")
    score_from_action: int = Field(2, ge=1, description="first action (1-based) the averages count")
    test_set: Literal["overall", "sufficient"] = "overall"
    sufficient_top_k: int = Field(4, ge=1, description="top connected tags of the sufficient set")
    pipeline: Literal["pure_generative", "neural_marionette"] = "pure_generative"
    qr_over_prefix: bool = Field(True, description="per-index QR over the first x actions")
    # open choices (docs/protocols.md §5; docs/multi_action.md)
    test_set_seed: int = Field(0, description="seed of the test-set construction")
    last_next_tag: Literal["same", "own"] = "same"
    evaluator_heading: Literal["remove", "yaw_augment"] = Field(
        "remove", description="heading-free evaluator (chained actions take any heading)")
    fid_reference: Literal["test_positions", "candidates"] = Field(
        "test_positions", description="real features FID compares with: the real actions at the "
        "scored positions of the test set (per index for fid@x; same tag mix as the generated), "
        "or every candidate once")
    vel_gap_frames: Literal["boundary", "junction"] = "boundary"


@dataclass(frozen=True)
class TestSet:
    """``actions`` (S, L) positions in the test items; ``next_labels`` (S, L) the conditioning
    next tags; ``candidates`` the candidate positions (sorted)."""

    actions: np.ndarray
    next_labels: np.ndarray
    candidates: np.ndarray
    confidence: np.ndarray   # (n_test_items,) the evaluator's confidence in each true tag

    def key(self) -> str:
        return content_key({"actions": self.actions.tolist(),
                            "next": self.next_labels.tolist()})


@dataclass(frozen=True)
class FidReference:
    """Real feature statistics: ``pooled`` (for ``fid``) and ``per_index`` (for ``fid@x``)."""

    pooled: object
    per_index: list


@dataclass(frozen=True, eq=False)
class MultiActionSamples(GeneratedItems):
    """S·L generated actions (world frame), sequence-major (row ``s·L + i``); ``revised``
    (S·L,) bool: regenerated by Action Revision (ss_ar), else all False."""

    n_sequences: int = 0
    n_actions: int = 0
    revised: torch.Tensor | None = None
    test_set_key: str = ""


def _gather_frames(x: torch.Tensor, start: torch.Tensor, count: int) -> torch.Tensor:
    """(N, count, ...) frames ``start_n .. start_n + count − 1`` of each row of ``x`` (N, T, ...)."""
    import torch

    t = start[:, None] + torch.arange(count)[None, :]
    return x[torch.arange(x.shape[0])[:, None], t]


@register
class MultiAction(MarionetteProtocol):
    """Neural Marionette's multi-action protocol (module docstring)."""

    id = "multi_action"
    Params = MultiActionParams
    metrics = METRICS
    real_metrics = REAL_METRICS
    evaluator_kind = "transformer"
    version = 2  # 2: harness columns
    #: the engine gives generate jobs the evaluator (candidates, Action Revision)
    generation_uses_evaluator = True

    params: MultiActionParams

    @property
    def evaluator_heading(self) -> str:
        return self.params.evaluator_heading

    # -- data (item_source, split_clipset, train_items: MarionetteProtocol) ------------------
    def test_items(self, clipset) -> ActionItems:
        """Every test action (the candidates are chosen among them by :meth:`test_set`)."""
        return self.item_source().items(clipset, TEST)

    def _check_evaluator(self, evaluator, items: ActionItems) -> None:
        if tuple(evaluator.label_names) != tuple(items.label_names):
            raise DataError("the evaluator's classes differ from the items' tags")
        if tuple(evaluator.joint_names) != tuple(items.skeleton.names):
            raise DataError("the evaluator's joints differ from the items' skeleton")
        want = self.params.evaluator_heading
        got = getattr(evaluator.settings, "heading", None)
        if got != want:
            raise ConfigError(f"protocol {self.id!r} needs an evaluator with heading {want!r}, "
                              f"got {got!r}")

    def confidence(self, items: ActionItems, evaluator) -> np.ndarray:
        """The evaluator's softmax probability of each item's own tag on its real action."""
        _, logits = self._encode(evaluator, items.real(),
                                 derive_seed(0, MultiAction.id, "confidence"))
        z = np.asarray(logits, dtype=np.float64)
        z = z - z.max(axis=1, keepdims=True)
        p = np.exp(z)
        p /= p.sum(axis=1, keepdims=True)
        return p[np.arange(len(items)), items.labels.numpy()]

    def transition_counts(self, clipset) -> np.ndarray:
        """(C, C) tag-pair counts of the training sequences (row = current tag)."""
        if self.params.context != "sequence":
            raise ConfigError(f"protocol {self.id!r} needs context = 'sequence' (the tag "
                              "transitions of the training sequences)")
        return self.item_source().sequences(clipset).tag_pair_counts(TRAIN)

    def test_set(self, clipset, items: ActionItems, evaluator) -> TestSet:
        """The overall or sufficient test set (module docstring), cached per process."""
        key = content_key({"proto": self.describe(), "items": items.key(),
                           "evaluator": evaluator.fingerprint})
        return cached(key, lambda: self._build_test_set(clipset, items, evaluator))

    def test_set_record(self, clipset, evaluator) -> dict[str, dict]:
        """What this protocol's test set holds (issue 26; supp. §4.2), for a table's JSON
        (``test_sets``): ``{test_set: {...}}`` with :func:`repro.data.tag_chains.test_set_stats`
        of the tags of the test set actually drawn (:meth:`test_set`: the same chains every
        method is scored on) against the training tag-pair counts the draw used
        (:meth:`transition_counts`) — ``unseen_share``, ``median_support``,
        ``class_share_by_position`` (L × C, rows in action order, columns in ``classes``
        order) — plus the candidates' count, the classes and the test set's key.  Depends on
        the data set, the protocol's parameters and the evaluator only (no generator), so it is
        the same for every row and replicate."""
        from repro.data.tag_chains import chain_labels, test_set_stats

        items = self.test_items(clipset)
        ts = self.test_set(clipset, items, evaluator)
        tags = chain_labels(items.labels.numpy(), ts.actions)
        stats = test_set_stats(tags, self.transition_counts(clipset), items.n_classes)
        return {self.params.test_set: {
            **stats, "candidates": int(ts.candidates.size),
            "classes": [str(c) for c in items.label_names], "test_set_key": ts.key()}}

    def _build_test_set(self, clipset, items, evaluator) -> TestSet:
        p = self.params
        self._check_evaluator(evaluator, items)
        conf = self.confidence(items, evaluator)
        cand = np.flatnonzero(conf >= p.candidate_confidence)
        if cand.size == 0:
            raise DataError(f"no test action reaches the candidate confidence "
                            f"{p.candidate_confidence} (supp. §4.2)")
        from repro.data.tag_chains import draw_test_sequences

        acts, nl = draw_test_sequences(items.labels.numpy(), items.next_labels.numpy(), cand,
                                       self.transition_counts(clipset), items.n_classes, p,
                                       MultiAction.id)
        return TestSet(acts, nl, cand, conf)

    # -- generation -------------------------------------------------------------------------
    def generate(self, generator, items: ActionItems, *, seed: int, replicate: int,
                 need: Iterable[str] | None = None, evaluator=None, clipset=None,
                 evaluator_factory=None):
        """One replicate: every test sequence generated action by action (module docstring)."""
        if evaluator is None or clipset is None:
            raise ConfigError(f"protocol {self.id!r} generates with the evaluator and the data set")
        ts = self.test_set(clipset, items, evaluator)
        sampler = self._sampler(generator, clipset, evaluator, evaluator_factory)
        return self._chain(sampler, items, ts, seed=self.replicate_seed(seed, replicate))

    def _sampler(self, generator, clipset, evaluator, evaluator_factory=None):
        """``fn(cond_items, seed) -> (GeneratedItems, revised mask)``: the pure generative
        pipeline calls the generator as it is."""
        import torch

        if self.params.pipeline != "pure_generative":
            raise ConfigError(f"protocol {self.id!r}: pipeline {self.params.pipeline!r} belongs "
                              "to the ss_ar protocol")

        def fn(cond, seed):
            out = generator.sample(cond, seed=seed)
            return out, torch.zeros(len(cond), dtype=torch.bool)

        return fn

    def _chain(self, sampler, items: ActionItems, ts: TestSet, *, seed: int) -> MultiActionSamples:
        import torch

        p = self.params
        S, L = ts.actions.shape
        K = p.initial_frames
        first = torch.from_numpy(ts.actions[:, 0])
        tail = items.initial_world().select(first)           # real P^ini of action 1
        lens = items.lengths.numpy()
        motions, lengths, labels, revised = [], [], [], []
        for i in range(L):
            idx = torch.from_numpy(ts.actions[:, i])
            Li = items.lengths[idx]
            T = int(Li.max())
            traj = items.trajectory[idx, :T]
            cond = condition_items(tail, items.labels[idx], torch.from_numpy(ts.next_labels[:, i]),
                                   Li, items.label_names, trajectory=traj,
                                   in_place=items.in_place[idx], config=items.config)
            out, rev = sampler(cond, derive_seed(seed, "action", i))
            if len(out) != S or not torch.equal(out.lengths.long(), Li.long()):
                raise DataError(f"generator returned {len(out)} actions of other durations "
                                f"at action {i + 1}")
            m = out.motion.slice_time(0, T)
            motions.append(m)
            lengths.append(Li.clone())
            labels.append(items.labels[idx].clone())
            revised.append(torch.as_tensor(rev, dtype=torch.bool).reshape(S))
            # Alg. 1: the next initial motion is the last K frames of the chain so far
            both = Motion.cat_time([tail.to(dtype=m.dtype), m])
            start = Li.long()  # frames K..K+L-1 of `both` are the action; its last K end at K+L-1
            tail = both.replace(root=_gather_frames(both.root, start, K),
                                rot6d=_gather_frames(both.rot6d, start, K))
        del lens
        Tmax = max(m.n_frames for m in motions)
        padded = [m.replace(root=_pad_to(m.root, Tmax), rot6d=_pad_to(m.rot6d, Tmax))
                  for m in motions]
        stacked = Motion(torch.stack([m.root for m in padded], 1).reshape(S * L, Tmax, 3),
                         torch.stack([m.rot6d for m in padded], 1).reshape(
                             S * L, Tmax, *padded[0].rot6d.shape[2:]),
                         padded[0].skeleton, padded[0].fps)
        return MultiActionSamples(stacked, torch.stack(lengths, 1).reshape(-1),
                                  torch.stack(labels, 1).reshape(-1), n_sequences=S, n_actions=L,
                                  revised=torch.stack(revised, 1).reshape(-1),
                                  test_set_key=ts.key())

    # -- scoring ----------------------------------------------------------------------------
    def fid_reference(self, items: ActionItems, ts: TestSet, evaluator) -> "FidReference":
        """The real feature statistics FID compares with (``fid_reference``): the real actions
        at the test set's positions — pooled from ``score_from_action`` on for ``fid``, per
        index for ``fid@x``, so reference and generated share their tag mix — or every
        candidate once (the same statistics for all)."""
        from repro.metrics.fid import FeatureStats

        p = self.params
        S, L = ts.actions.shape
        seed = derive_seed(0, MultiAction.id, "fid-reference")
        if p.fid_reference == "candidates":
            feats, _ = self._encode(evaluator, items.subset(ts.candidates).real(), seed)
            one = FeatureStats.of(feats)
            return FidReference(one, [one] * L)
        feats, _ = self._encode(evaluator, items.subset(ts.actions.reshape(-1)).real(), seed)
        feats = np.asarray(feats).reshape(S, L, -1)
        f = p.score_from_action - 1
        pooled = FeatureStats.of(feats[:, f:].reshape(-1, feats.shape[-1]))
        per = [FeatureStats.of(feats[:, i]) if S >= 2 else None for i in range(L)]
        return FidReference(pooled, per)

    def measure(self, generated: MultiActionSamples, items: ActionItems, evaluator, *, seed: int,
                clipset=None, reference=None) -> dict[str, float]:
        """One replicate's values: the averages from ``score_from_action`` on and, per action
        index x (1-based), ``metric@x`` (module docstring)."""
        import torch

        from repro.metrics.transitions import pose_gap, velocity_gap

        if clipset is None:
            raise ConfigError(f"protocol {self.id!r} measures with the data set")
        ts = self.test_set(clipset, items, evaluator)
        if generated.test_set_key and generated.test_set_key != ts.key():
            raise DataError("the samples were generated for another test set")
        S, L = ts.actions.shape
        if (generated.n_sequences, generated.n_actions) != (S, L):
            raise DataError(f"samples hold {generated.n_sequences}x{generated.n_actions} actions, "
                            f"the test set {S}x{L}")
        feats, logits = self._encode(evaluator, generated, derive_seed(seed, self.id, "features"))
        if reference is None:
            reference = self.fid_reference(items, ts, evaluator)
        correct = (np.asarray(logits).argmax(1) == generated.labels.numpy()).reshape(S, L)
        feats = np.asarray(feats).reshape(S, L, -1)
        out = self._quality(feats, correct, reference)
        # transitions: the junction into action i (i >= 2); joints one action index at a time
        lens = generated.lengths.numpy().reshape(S, L)
        rows = np.arange(S) * L
        pg, vg = np.full((S, L), np.nan), np.full((S, L), np.nan)
        prev_j = None
        for i in range(L):
            cur_j = generated.motion.select(torch.from_numpy(rows + i)).joints().detach().numpy()
            if i:
                prev = [prev_j[s, :lens[s, i - 1]] for s in range(S)]
                cur = [cur_j[s, :lens[s, i]] for s in range(S)]
                pg[:, i] = pose_gap(prev, cur, reduce="none")
                vg[:, i] = velocity_gap(prev, cur, frames=self.params.vel_gap_frames,
                                        reduce="none")
            prev_j = cur_j
        lo = max(self.params.score_from_action - 1, 1)
        out["pose_gap"] = float(np.mean(pg[:, lo:]))
        out["vel_gap"] = float(np.mean(vg[:, lo:]))
        for i in range(1, L):
            out[f"pose_gap@{i + 1}"] = float(pg[:, i].mean())
            out[f"vel_gap@{i + 1}"] = float(vg[:, i].mean())
        if self.params.memorisation:
            # each real test action once: the test set draws positions with replacement, and a
            # repeated real sample would shrink its own k-NN ball (to 0 from k+1 copies on)
            real = items.subset(np.unique(self._scored_rows(ts.actions.reshape(-1), S, L))).real()
            real_feats, _ = self._encode(evaluator, real,
                                         derive_seed(0, MultiAction.id, "fid-reference"))
            out.update(self._harness(self._scored(generated, S, L),
                                     self._scored_rows(feats.reshape(S * L, -1), S, L),
                                     evaluator, clipset, seed, real_feats))
        return out

    def _scored_rows(self, x, S: int, L: int):
        """The rows of a sequence-major (S·L, ...) array that the averages count (actions from
        ``score_from_action`` on)."""
        import torch

        f = self.params.score_from_action - 1
        keep = (np.arange(S)[:, None] * L + np.arange(f, L)[None, :]).reshape(-1)
        return x[torch.from_numpy(keep)] if isinstance(x, torch.Tensor) else x[keep]

    def _scored(self, g: GeneratedItems, S: int, L: int) -> GeneratedItems:
        import torch

        keep = self._scored_rows(torch.arange(S * L), S, L)
        return GeneratedItems(g.motion.select(keep), g.lengths[keep], g.labels[keep])

    def _harness(self, motion: GeneratedItems, feats, evaluator, clipset, seed: int,
                 real_feats=None) -> dict[str, float]:
        """The harness columns (:mod:`repro.eval.memorisation`) of the scored actions against
        the training items (the same ones the models train on)."""
        from repro.eval.memorisation import harness_columns

        return harness_columns(self, motion, feats, evaluator, clipset, real_feats=real_feats,
                               bank_seed=derive_seed(seed, self.id, "bank"))

    def _quality(self, feats: np.ndarray, correct: np.ndarray, reference) -> dict[str, float]:
        """acc, fid, action_qr, motion_qr (from ``score_from_action`` on) and per index."""
        from repro.metrics.fid import fid
        from repro.metrics.qualification import qualification_curves, qualification_ratios

        p = self.params
        S, L = correct.shape
        f = p.score_from_action - 1
        if not 0 <= f < L:
            raise ConfigError(f"score_from_action {p.score_from_action} is beyond the "
                              f"{L} actions of a sequence")
        out: dict[str, float] = {}
        out["acc"] = float(correct[:, f:].mean())
        pooled = feats[:, f:].reshape(-1, feats.shape[-1])
        out["fid"] = fid(pooled, reference.pooled, method=p.fid_method).value \
            if pooled.shape[0] >= 2 else float("nan")
        out["action_qr"], out["motion_qr"] = qualification_ratios(correct, from_action=f)
        if p.qr_over_prefix:
            aq, mq = qualification_curves(correct, from_action=0)
        else:
            aq, mq = correct.mean(0), correct.mean(0)
        for i in range(L):
            out[f"acc@{i + 1}"] = float(correct[:, i].mean())
            ref = reference.per_index[i]
            out[f"fid@{i + 1}"] = (fid(feats[:, i], ref, method=p.fid_method).value
                                   if S >= 2 and ref is not None else float("nan"))
            out[f"action_qr@{i + 1}"] = float(aq[i])
            out[f"motion_qr@{i + 1}"] = float(mq[i])
        return out

    def real_replicate(self, clipset, items: ActionItems, evaluator, *, seed: int,
                       replicate: int, reference=None) -> dict[str, float]:
        """The real actions of the test sequences scored like generated ones (``acc``, ``fid``,
        QR; their junctions join different recordings, so no transition columns)."""
        ts = self.test_set(clipset, items, evaluator)
        S, L = ts.actions.shape
        rng = numpy_rng(seed, self.id, "real", int(replicate))
        rows = rng.integers(0, S, size=S)  # a bootstrap of the test sequences
        acts = ts.actions[rows]
        sub = items.subset(acts.reshape(-1))
        feats, logits = self._encode(evaluator, sub.real(),
                                     derive_seed(seed, self.id, "real", int(replicate)))
        if reference is None:
            reference = self.fid_reference(items, ts, evaluator)
        correct = (np.asarray(logits).argmax(1) == sub.labels.numpy()).reshape(S, L)
        out = self._quality(np.asarray(feats).reshape(S, L, -1), correct, reference)
        if self.params.memorisation:  # the level of fresh real data
            mem = self._harness(self._scored(sub.real(), S, L),
                                self._scored_rows(np.asarray(feats), S, L), evaluator, clipset,
                                derive_seed(seed, self.id, "real", int(replicate)))
            out.update({k: mem[k] for k in ("nn_train_feat", "nn_train_joint")})
        return out

    # -- keeping samples --------------------------------------------------------------------
    def save_generated(self, generated: MultiActionSamples, path: str | Path) -> Path:
        """The samples as npz (:func:`repro.eval.protocols.marionette_common.write_samples`)
        plus ``revised``; ``meta`` adds the sequence shape and the test set's key."""
        import torch

        rev = generated.revised if generated.revised is not None else \
            torch.zeros(len(generated), dtype=torch.bool)
        return write_samples(path, self.id, SAVE_FORMAT, generated,
                             meta={"n_sequences": generated.n_sequences,
                                   "n_actions": generated.n_actions,
                                   "test_set": generated.test_set_key},
                             arrays={"revised": rev.cpu().numpy().astype(bool)})

    def load_generated(self, path: str | Path) -> MultiActionSamples:
        """Read a file :meth:`save_generated` wrote (DataError naming it when it is not one)."""
        import torch

        f = read_samples(path, self.id, SAVE_FORMAT)
        g = f.motion_set()
        meta = f.meta
        try:
            S, L = int(meta["n_sequences"]), int(meta["n_actions"])
            revised = torch.from_numpy(f.arrays["revised"].astype(bool))
        except (KeyError, ValueError, TypeError) as e:
            raise DataError(f"malformed samples ({type(e).__name__}: {e})", path) from None
        n = len(g)
        if n != S * L or revised.shape != (n,):
            raise DataError("malformed samples: shapes do not fit", path)
        return MultiActionSamples(g.motion, g.lengths, g.labels, n_sequences=S, n_actions=L,
                                  revised=revised, test_set_key=str(meta.get("test_set", "")))


def _pad_to(x: torch.Tensor, T: int) -> torch.Tensor:
    """Repeat the last frame (dim 1) up to ``T`` frames."""
    import torch

    if x.shape[1] >= T:
        return x[:, :T]
    return torch.cat([x, x[:, -1:].expand(-1, T - x.shape[1], *x.shape[2:])], dim=1)
