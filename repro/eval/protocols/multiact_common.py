"""What MultiAct's three protocols share (``multiact_conditioned``, ``transition``,
``long_term``; MultiAct AAAI'23 §5 and supplement; protocols.md §1, §2.3, §4).

**Items.**  MultiAct's samples ``[S_p, T, S_c]`` at 20 fps come from
:class:`repro.data.pairs_build.PairSource` (:meth:`MultiActProtocol.item_source`, the fields
:class:`MultiActParams` maps onto it): its ``describe()``
is the training items' description, so every MultiAct protocol with equal item fields trains
one model.  The per-label test count (``per_label``) is *not* a PairSource field here: it is
passed to :meth:`PairSource.test_items`, so changing it leaves the trained models valid.

**Conditions** (:mod:`repro.eval.protocols.multiact_conditions`): every generator gets the
:func:`~repro.eval.protocols.multiact_conditions.blind` copy of the items (no leak by
construction); a generated previous motion is ACTOR's, placed where the real ``S_p`` starts
(:func:`~repro.eval.protocols.multiact_conditions.actor_motion`).

**The scoring frame.**  MultiAct scores motions canonicalised face-front at their pair's anchor
(protocols.md §4.1, §4.4): every scored segment (a generated ``Ŝ_c`` or ``T̂`` and every real
reference) is mapped by :func:`repro.motion.canon.face_front` computed on the *anchor* frame —
the last frame of the previous motion actually used (the real ``S_p``, or a generated one) —
then :func:`repro.motion.canon.canonicalize_with`.  So every method is scored in the same frame
as the real references.  (With the heading-free evaluator these protocols ask for,
``evaluator_heading = "remove"``, the recogniser's own input convention is invariant to that
rigid yaw + translation; the canonicalisation keeps the protocol correct for any evaluator.)

**The recogniser** (kind ``multiact_gru``, protocols.md §2.3): the A2M GRU family with 4 layers
× 256 and the 30-d tanh feature, first-frame root at the origin (``repro.eval.features``),
trained on the pairs' clip set resampled to 20 fps (:meth:`split_clipset`; no test clip is
seen).  The reference zero-pads every motion to ``max_input_len`` = 120 and reads frame 119.
Ours is trained on windows of the scale's ``window`` frames (clips shorter than the window
padded by repeating their last frame, the A2M convention), so a scored segment is fed as the
recogniser was trained (``eval_clip = "window"``, default): its centred window of ``window``
frames when longer, else the whole segment padded by repeating its last frame up to ``window``
frames, read at the last step.  ``eval_clip = "max_len"`` pads every segment to ``max_len``
(120) frames by repeating its last frame and reads the last step (the reference's fixed input
length, with repeat- instead of zero-padding, which our recogniser never saw); docs/evaluators.md.

**The metric block** (:meth:`MultiActProtocol.metric_block`, protocols.md §1, §4.3-4.6):
``fid_train`` / ``fid_test`` (FID against two reference feature sets), ``acc`` / ``acc_top5``
(top-1 / top-``top_k`` accuracy against ``a_c`` with label merging, ``label_merge``),
``div`` (``div_pairs`` = 200 random pairs) and ``multimod`` (``multimod_pairs`` = 20 same-label
pairs per label, divided by 20·C, MultiAct's early break when labels are absent).

``label_merge``: ``"multiact_babel"`` applies MultiAct's BABEL confusion table
(:data:`repro.metrics.label_merge.MULTIACT_LABEL_MERGE`, by label name); ``"none"`` is exact
match; ``"auto"`` (default) picks ``"multiact_babel"`` when every label name of the evaluator is
one of MultiAct's 53 BABEL labels, else ``"none"`` (on the stand-in's labels no merge group
applies, so both give exact match there).

Units: metres, frames at ``fps`` (20); FID in squared feature units, accuracy a fraction.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field

from repro.data.pairs import PairItems, gather_frames
from repro.data.pairs_build import PairSource
from repro.errors import ConfigError, DataError
from repro.eval.protocols.base import ItemProtocol, SequenceItemParams
from repro.eval.protocols.multiact_conditions import (
    actor_motion,
    actor_sample,
    anchor_frames,
    blind,
    check_generated_pairs,
    first_frames,
    generator_name,
    is_composite,
    is_pair_generator,
    method_is_composite,
    with_prev,
)
from repro.keys import content_key
from repro.motion.motion import Motion
from repro.seeding import derive_seed

SAVE_FORMAT = 1
METRIC_BLOCK = ("fid_train", "fid_test", "acc", "acc_top5", "div", "multimod")


class MultiActParams(SequenceItemParams):
    """What every MultiAct protocol reads (frames at ``fps``; the paper's values first).  The
    item fields (``fps``, ``max_len``, ``train_per_label``, ``compose``, ``pair_seed`` and the
    ``pairs`` dict) are :class:`repro.data.pairs_build.PairSource`'s."""

    ITEM_SOURCE: ClassVar[type] = PairSource
    ITEM_FIELDS: ClassVar[Mapping[str, str]] = {
        "fps": "fps", "max_len": "max_len", "train_per_label": "train_per_label",
        "compose": "compose", "pair_seed": "seed"}
    MORE_ITEM_FIELDS: ClassVar[str | None] = "pairs"

    # fixed by MultiAct (protocols.md §4.1, §4.3)
    fps: float = Field(20.0, gt=0, description="frame rate of the samples (§4.1)")
    max_len: int = Field(120, ge=2, description="max_input_len: samples total < max_len − 1")
    per_label: int = Field(20, ge=1, description="test pairs (and generated samples) per S_c "
                           "label, and the size per label of each FID_test reference draw")
    train_per_label: int = Field(20, ge=1, description="training pairs per S_c label (the "
                                 "1,060 = 20 × 53 of §4.1); FID_train's reference")
    prev_motion_source: Literal["test", "train", "actor"] = Field(
        "test", description="where S_p comes from: the test pairs (unseen), the training pairs "
        "(the reference's 'seen' loader) or ACTOR(a_p); a row's method config may say 'actor'")
    replicates: int | None = Field(None, ge=1, description="read by the engine (scale profile)")
    # how the pairs are made (PairSource; enter the training items' key; and ``compose``)
    pair_seed: int = Field(0, description="seed of the PairSource's per-label draws")
    pairs: dict = Field(default_factory=dict,
                        description="other PairSource fields (crops, filters), validated there")
    # open choices (docs/protocols.md §1, §4; module docstring)
    label_merge: Literal["auto", "multiact_babel", "none"] = Field(
        "auto", description="accuracy label merging (auto: BABEL's table when the labels are "
        "BABEL's, else exact match)")
    top_k: int = Field(5, ge=1, description="k of acc_top5 (capped at the class count)")
    div_pairs: int = Field(200, ge=1, description="Div pairs (§1.3)")
    multimod_pairs: int = Field(20, ge=1, description="Multimod pairs per label (§1.4)")
    multimod_early_break: bool = Field(True, description="MultiAct's early break: absent "
                                       "labels count 0 but still divide (§1.4)")
    classifier: Literal["multiact_gru", "a2m_gru"] = Field(
        "multiact_gru", description="recogniser: MultiAct's 4×256 GRU (§2.3), or the same GRU "
        "family at A2M's 2×128 (the quick profile's CI budget under the kernel pin)")
    evaluator_heading: Literal["remove", "yaw_augment"] = Field(
        "remove", description="heading-free recogniser (the stand-in's classes have fixed "
        "headings; MultiAct scores face-front canonicalised motions)")
    eval_clip: Literal["window", "max_len"] = Field(
        "window", description="how a scored segment is fed to the recogniser (module docstring)")
    fid_method: Literal["eigh", "scipy"] = Field("eigh", description="repro.metrics.fid method")
    actor_initial_frames: int = Field(4, ge=1, description="n_init of the ActionItems ACTOR "
                                      "is given (placement only: ACTOR reads labels, lengths)")


# ---------------------------------------------------------------------------------------------
# samples


@dataclass(frozen=True, eq=False)
class MultiActSamples:
    """Generated motions of one replicate, world frame.

    ``motion`` (N, T) holds ``[T̂, Ŝ]`` per row (``l_t`` frames of transition, then ``l_c`` of
    action; ``l_t = 0`` when the method made no transition, e.g. ACTOR), padded by repeating
    each row's last frame; ``labels`` the action labels (``a_c``); ``anchor`` (N, 1) the frame
    each row is scored at (face-front: the last frame of the previous motion actually used, or
    for a first long-term step its own first frame); ``transitions``: whether the method made
    transitions; ``n_sequences`` × ``n_steps`` the long-term shape (rows sequence-major,
    ``s·n_steps + x``; 0 × 0 otherwise); ``items_key`` the conditioning items' key."""

    motion: Motion
    l_t: torch.Tensor
    l_c: torch.Tensor
    labels: torch.Tensor
    anchor: Motion
    transitions: bool = True
    n_sequences: int = 0
    n_steps: int = 0
    items_key: str = ""

    def __post_init__(self) -> None:
        import torch

        N = self.motion.batch_size
        for name in ("l_t", "l_c", "labels"):
            t = torch.as_tensor(getattr(self, name), dtype=torch.long).reshape(-1)
            if t.numel() != N:
                raise DataError(f"samples: {name} has {t.numel()} entries for {N} motions")
            object.__setattr__(self, name, t)
        if self.anchor.batch_size != N or self.anchor.n_frames != 1:
            raise DataError("samples: anchor must hold one frame per motion")
        if N and (int(self.l_c.min()) < 1 or int(self.l_t.min()) < 0
                  or int((self.l_t + self.l_c).max()) > self.motion.n_frames):
            raise DataError("samples: lengths do not fit the motions")

    def __len__(self) -> int:
        return self.motion.batch_size

    def action(self) -> tuple[Motion, torch.Tensor]:
        """``Ŝ`` (N, max l_c) left-aligned, and ``l_c``."""
        return gather_frames(self.motion, self.l_t, self.l_c), self.l_c

    def transition(self) -> tuple[Motion, torch.Tensor]:
        """``T̂`` (N, max(l_t, 1)) left-aligned, and ``l_t``."""
        import torch

        return gather_frames(self.motion, torch.zeros_like(self.l_t), self.l_t.clamp(min=1)), self.l_t

    def select(self, index) -> MultiActSamples:
        import torch

        idx = torch.as_tensor(np.asarray(index), dtype=torch.long).reshape(-1)
        return MultiActSamples(self.motion.select(idx), self.l_t[idx], self.l_c[idx],
                               self.labels[idx], self.anchor.select(idx), self.transitions,
                               items_key=self.items_key)


def save_samples(protocol_id: str, samples: MultiActSamples, path: str | Path) -> Path:
    """Write ``samples`` to the npz file ``path`` atomically (:mod:`repro.eval.sample_files`)."""
    from repro.eval.sample_files import save_samples as _save

    m, a = samples.motion, samples.anchor
    meta = {"format": SAVE_FORMAT, "protocol": protocol_id, "skeleton": m.skeleton.to_dict(),
            "fps": m.fps, "transitions": bool(samples.transitions),
            "n_sequences": int(samples.n_sequences), "n_steps": int(samples.n_steps),
            "items": samples.items_key}
    arrays = {"root": m.root.detach().cpu().numpy(), "rot6d": m.rot6d.detach().cpu().numpy(),
              "l_t": samples.l_t.numpy().astype(np.int64),
              "l_c": samples.l_c.numpy().astype(np.int64),
              "labels": samples.labels.numpy().astype(np.int64),
              "anchor_root": a.root.detach().cpu().numpy(),
              "anchor_rot6d": a.rot6d.detach().cpu().numpy()}
    return _save(path, meta, arrays)


def load_samples(protocol_id: str, path: str | Path) -> MultiActSamples:
    """Read a file :func:`save_samples` wrote (DataError naming it when it is not one)."""
    import torch

    from repro.eval.sample_files import load_samples as _load

    meta, data, skeleton = _load(path, protocol=protocol_id, fmt=SAVE_FORMAT)
    try:
        fps = float(meta["fps"])
        motion = Motion(torch.from_numpy(data["root"]), torch.from_numpy(data["rot6d"]),
                        skeleton, fps)
        anchor = Motion(torch.from_numpy(data["anchor_root"]),
                        torch.from_numpy(data["anchor_rot6d"]), skeleton, fps)
        return MultiActSamples(motion, torch.from_numpy(data["l_t"].astype(np.int64)),
                               torch.from_numpy(data["l_c"].astype(np.int64)),
                               torch.from_numpy(data["labels"].astype(np.int64)), anchor,
                               transitions=bool(meta["transitions"]),
                               n_sequences=int(meta["n_sequences"]),
                               n_steps=int(meta["n_steps"]), items_key=str(meta["items"]))
    except (KeyError, ValueError, TypeError, DataError) as e:
        raise DataError(f"malformed samples ({type(e).__name__}: {e})", path) from None


# ---------------------------------------------------------------------------------------------
# the scoring frame


def to_scoring_frame(segment: Motion, anchor: Motion) -> Motion:
    """``segment`` (N, T) in the face-front frame of ``anchor`` (N, 1) (module docstring)."""
    from repro.motion.canon import canonicalize_with, face_front

    if anchor.batch_size != segment.batch_size:
        raise DataError("anchor and segment differ in batch size")
    _, params = face_front(anchor.to(dtype=segment.dtype), anchor=0)
    return canonicalize_with(segment, params)



# ---------------------------------------------------------------------------------------------
# the protocol base

_FEATURE_CACHE: OrderedDict[str, tuple] = OrderedDict()
_FEATURE_CACHE_SIZE = 16


#: the footer line of every MultiAct table: MACVAE's reading switches (the specs' notes too)
FOOTER_NOTE = (
    "Readings (docs/multiact.md, 'Paper and released code'): MACVAE rows without a mark run the "
    "released code's (posterior_pooling = \"per_part\", posterior_head = \"per_frame\", "
    "encoder_embedding = \"joint\", decoder_causal, transition_pos_enc, pos_encoding = "
    "\"transposed\", decoder_head = \"conv\", temporal_kernel = 5, acc_loss = "
    "\"squared_output\", loss_frames = \"whole\"); the row marked '(paper reading)' sets the "
    "paper's (posterior_pooling = \"global\", posterior_head = \"pooled\", encoder_embedding = "
    "\"split\", decoder_causal = false, transition_pos_enc = false, pos_encoding = "
    "\"standard\", decoder_head = \"conv_linear\", acc_loss = \"l1_target\", loss_frames = "
    "\"generated\"; the paper is silent on the kernel).")


class MultiActProtocol(ItemProtocol):
    """Base of MultiAct's protocols (module docstring)."""

    Params = MultiActParams
    footer_note = FOOTER_NOTE
    #: the engine passes extra models and the row's resolved config to :meth:`generate`
    takes_models = True
    #: :meth:`measure` gets the data set (training pairs, fresh test references)
    measure_uses_clipset = True
    #: a Real row's overrides this protocol reads (passed to :meth:`real_replicate`)
    real_row_options: tuple[str, ...] = ()

    params: MultiActParams

    @property
    def evaluator_kind(self) -> str:  # type: ignore[override]
        return self.params.classifier

    @property
    def evaluator_heading(self) -> str:
        return self.params.evaluator_heading

    # -- data (item_source, split_clipset, train_items: ItemProtocol, from PairSource) ---------
    def test_items(self, clipset) -> PairItems:
        """The conditioning pairs: the per-label test pairs (unseen previous motions), or the
        training pairs with ``prev_motion_source = "train"`` (the reference's "seen" loader)."""
        if self.params.prev_motion_source == "train":
            return self.train_items(clipset)
        return self.test_pairs(clipset)

    def test_pairs(self, clipset) -> PairItems:
        """``per_label`` test pairs per ``S_c`` label (repeated when fewer)."""
        return self.item_source().test_items(clipset, self.params.per_label)

    def extra_models(self, method_id: str, row_config: Mapping[str, Any] | None = None
                     ) -> dict[str, str]:
        """{name: method id} of extra trained models the generate step needs for a row:
        ``{"actor": "actor"}`` when a pair generator (MACVAE) takes its previous motion from
        ACTOR; composites use their own ACTOR, ACTOR itself needs nothing."""
        if method_id == "actor" or method_is_composite(method_id):
            return {}
        if self.prev_source(row_config) == "actor":
            return {"actor": "actor"}
        return {}

    def prev_source(self, row_config: Mapping[str, Any] | None, generator=None) -> str:
        """Where ``S_p`` comes from for a row: ``"actor"`` when the row's method config says
        so or the method is a composite (ACTOR + X), else ``prev_motion_source``."""
        if generator is not None and is_composite(generator):
            return "actor"
        if (row_config or {}).get("prev_motion_source") == "actor":
            return "actor"
        return self.params.prev_motion_source

    # -- evaluator -------------------------------------------------------------------------
    def check_evaluator(self, evaluator, label_names, skeleton) -> None:
        if tuple(evaluator.label_names) != tuple(label_names):
            raise DataError("the evaluator's classes differ from the pairs' labels "
                            f"({', '.join(evaluator.label_names)} vs {', '.join(label_names)})")
        if tuple(evaluator.joint_names) != tuple(skeleton.names):
            raise DataError("the evaluator's joints differ from the pairs' skeleton")
        want = self.params.evaluator_heading
        got = getattr(getattr(evaluator, "settings", None), "heading", None)
        if got != want:
            raise ConfigError(f"protocol {self.id!r} needs an evaluator with heading {want!r}, "
                              f"got {got!r}")

    def clips(self, joints: torch.Tensor, lengths: torch.Tensor, evaluator):
        """What the recogniser sees of each segment (``eval_clip``, module docstring):
        joints (N, W, J, 3) numpy and valid lengths (N,)."""
        import torch

        from repro.eval.protocols.single_action import evaluation_clips

        lengths = torch.as_tensor(lengths, dtype=torch.long).clamp(min=1)
        if self.params.eval_clip == "window":
            return evaluation_clips(joints, lengths, evaluator.settings.window, "centre")
        W = self.params.max_len
        j = joints.detach().cpu().numpy()
        lens = np.minimum(lengths.numpy(), W)
        idx = np.minimum(np.arange(W)[None, :], (lens - 1)[:, None])
        return np.take_along_axis(j, idx[:, :, None, None], axis=1), np.full_like(lens, W)

    def encode(self, evaluator, segment: Motion, lengths, anchor: Motion, seed: int):
        """(features (N, 30), logits (N, C)) of ``segment`` scored at ``anchor``."""
        import torch

        lengths = torch.as_tensor(lengths, dtype=torch.long)
        if segment.batch_size == 0:
            d = getattr(evaluator.settings, "feature_dim", 30)
            return np.zeros((0, d), np.float32), np.zeros((0, len(evaluator.label_names)),
                                                          np.float32)
        T = max(int(lengths.clamp(min=1).max()), 1)
        seg = to_scoring_frame(segment.slice_time(0, min(T, segment.n_frames)), anchor)
        j, lens = self.clips(seg.joints(), lengths, evaluator)
        return evaluator.encode(j, lens, seed=seed)

    def real_features(self, evaluator, items: PairItems, part: str, seed: int):
        """(features, logits) of ``items``' real ``S_c`` (``part = "action"``) or ``T``
        (``"transition"``), each at its own anchor (the last ``S_p`` frame); cached per process."""
        key = content_key({"items": items.key(), "part": part, "seed": int(seed),
                           "evaluator": getattr(evaluator, "fingerprint", id(evaluator)),
                           "clip": self.params.eval_clip, "max_len": self.params.max_len})
        hit = _FEATURE_CACHE.get(key)
        if hit is not None:
            _FEATURE_CACHE.move_to_end(key)
            return hit
        seg, lens = items.action() if part == "action" else items.transition()
        anchor = anchor_frames(items.motion, items.l_p)
        out = self.encode(evaluator, seg, lens, anchor, seed)
        _FEATURE_CACHE[key] = out
        while len(_FEATURE_CACHE) > _FEATURE_CACHE_SIZE:
            _FEATURE_CACHE.popitem(last=False)
        return out

    # -- metrics ---------------------------------------------------------------------------
    def label_merge(self, label_names):
        """The merge table accuracy uses (None: exact match; module docstring)."""
        from repro.metrics.label_merge import MULTIACT_LABEL_MERGE, MULTIACT_LABELS

        mode = self.params.label_merge
        if mode == "auto":
            mode = "multiact_babel" if set(label_names) <= set(MULTIACT_LABELS) else "none"
        if mode == "none":
            return None
        return MULTIACT_LABEL_MERGE.index_map(tuple(label_names))

    def accuracy(self, logits, labels, label_names, k: int = 1) -> float:
        from repro.metrics.accuracy import accuracy

        k = min(int(k), len(label_names))
        return accuracy(logits, np.asarray(labels, np.int64), top_k=k,
                        merge=self.label_merge(label_names) or None).value

    def fid(self, feats, reference) -> float:
        from repro.metrics.fid import fid

        n = reference.n if hasattr(reference, "n") else len(reference)
        if len(feats) < 2 or n < 2:
            return float("nan")
        return fid(feats, reference, method=self.params.fid_method).value

    def metric_block(self, feats, logits, labels, label_names, *, seed: int, train_ref,
                     test_ref) -> dict[str, float]:
        """The six columns of Tables 1, 2, A, B (module docstring)."""
        from repro.metrics.diversity import diversity, multimodality

        p = self.params
        y = np.asarray(labels, dtype=np.int64)
        return {
            "fid_train": self.fid(feats, train_ref),
            "fid_test": self.fid(feats, test_ref),
            "acc": self.accuracy(logits, y, label_names, 1),
            "acc_top5": self.accuracy(logits, y, label_names, p.top_k),
            "div": diversity(feats, n_pairs=p.div_pairs, seed=derive_seed(seed, "div")),
            "multimod": multimodality(feats, y, len(label_names), per_class=p.multimod_pairs,
                                      seed=derive_seed(seed, "multimod"),
                                      early_break=p.multimod_early_break),
        }

    # -- generation of one step [T̂, Ŝ_c] for pairs ------------------------------------------
    def generate_pairs(self, generator, items: PairItems, *, seed: int, models=None,
                       row_config=None, need_transitions: bool = False) -> MultiActSamples:
        """One replicate's samples for ``items`` (seeded by ``seed``): every generator sees
        :func:`blind` ``(items)`` only; ``S_p`` is the item's or ACTOR's (:meth:`prev_source`);
        the scoring anchor is the last frame of the ``S_p`` used."""
        import torch

        who = f"generator {generator_name(generator)}"
        cond = blind(items)
        source = self.prev_source(row_config, generator)
        n = len(cond)
        if source == "actor":
            prev_start = first_frames(cond.motion)          # the real S_p's placement
            prev = actor_motion(generator, models, cond.prev_labels, cond.l_p, prev_start,
                                cond.label_names, seed=derive_seed(seed, "actor-prev"),
                                n_init=self.params.actor_initial_frames)
            cond = with_prev(cond, prev)
        anchor = anchor_frames(cond.motion, cond.l_p)
        if is_pair_generator(generator):
            if source == "actor":
                prev, l_p = cond.prev()
                out = generator.step(prev, l_p, cond.labels, cond.l_t, cond.l_c, seed=seed)
            else:
                out = generator.sample(cond, seed=seed)
            out = check_generated_pairs(out, cond.l_t, cond.l_c, n, who)
            return MultiActSamples(out.motion, out.l_t, out.l_c, cond.labels.clone(), anchor,
                                   transitions=True, items_key=items.key())
        if need_transitions:
            raise ConfigError(f"protocol {self.id!r}: {who} generates no transitions (a "
                              "label-only method); use a pair generator or a composite")
        acts = cond.as_action_items(self.params.actor_initial_frames)
        m, l_c = actor_sample(generator, acts, seed=seed)
        return MultiActSamples(m, torch.zeros_like(l_c), l_c, cond.labels.clone(), anchor,
                               transitions=False, items_key=items.key())

    def check_samples(self, generated: MultiActSamples, items_key: str, n: int) -> None:
        if not isinstance(generated, MultiActSamples):
            raise DataError(f"expected MultiActSamples, got {type(generated).__name__}")
        if generated.items_key and items_key and generated.items_key != items_key:
            raise DataError("the samples were generated for other test items")
        if len(generated) != n:
            raise DataError(f"{len(generated)} samples for {n} test items")

    # -- keeping samples -------------------------------------------------------------------
    def save_generated(self, generated: MultiActSamples, path: str | Path) -> Path:
        return save_samples(self.id, generated, path)

    def load_generated(self, path: str | Path) -> MultiActSamples:
        return load_samples(self.id, path)


def replace_params(protocol: MultiActProtocol, **changes) -> MultiActProtocol:
    """A copy of ``protocol`` with parameters changed (tests, sweeps)."""
    return type(protocol)({**protocol.params.model_dump(), **changes})


__all__ = [
    "METRIC_BLOCK",
    "MultiActParams",
    "MultiActProtocol",
    "MultiActSamples",
    "load_samples",
    "replace_params",
    "save_samples",
    "to_scoring_frame",
]
