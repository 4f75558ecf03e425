"""What Neural Marionette's protocols share: ``single_action`` (Tables 1, 2, 4; paper
§5.1.1-5.1.4), ``multi_action`` (Table 3, Fig. 8; §5.2.1-5.2.3, supp. §4.2-4.3) and ``ss_ar``
(Table 5, Fig. 10; §5.2.6).

- :class:`ActionItemParams`: the fields that say how the items are made (§5.1.1, supp. §3:
  the Marionette test split, 30 fps, ``initial_frames`` = 6 frames of initial motion, the
  context of :mod:`repro.data.contexts`), mapped onto
  :class:`repro.data.contexts.ActionSource` (:class:`~repro.eval.protocols.base.ItemParams`);
  two protocols with equal values train on the same items, so they share trained models;
- :class:`MarionetteParams`: those plus the scoring fields both protocols read (what the
  evaluator sees of an action, FID's method, the harness columns, the replicate count);
- :class:`MarionetteProtocol`: the protocols' common data path (the item source, the split
  and the training items of :class:`~repro.eval.protocols.base.ItemProtocol`) and evaluator
  pass (:func:`evaluation_clips`);
- :func:`write_samples` / :func:`read_samples`: their sample files, one motion set (the
  samples) and optionally more under a prefix, plus protocol-specific ``meta`` entries and
  arrays, in the layout of :mod:`repro.eval.sample_files`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Literal, Mapping

import numpy as np
from pydantic import Field

from repro.data.contexts import ActionSource
from repro.errors import ConfigError
from repro.eval.protocols.base import ItemProtocol, SequenceItemParams


class ActionItemParams(SequenceItemParams):
    """The fields that say how a protocol's items are made, shared by every protocol that
    builds them with :class:`repro.data.contexts.ActionSource` (single-action, multi-action,
    SS/AR): two protocols with equal values train on the same items, so they share models."""

    ITEM_SOURCE: ClassVar[type] = ActionSource
    ITEM_FIELDS: ClassVar[Mapping[str, str]] = {
        "context": "context", "fps": "fps", "split": "split", "split_seed": "split_seed",
        "test_fraction": "test_fraction", "test_cap_per_class": "test_cap_per_class",
        "initial_frames": "n_init", "max_frames": "max_frames", "compose": "compose"}

    # fixed by Neural Marionette (§5.1.1, supp. §3)
    initial_frames: int = Field(6, ge=1, description="frames of initial motion (supp. §3)")
    fps: float = Field(30.0, gt=0, description="frame rate the data must have (supp. §3)")
    test_fraction: float = Field(0.2, gt=0, lt=1, description="test share per class (§5.1.1)")
    test_cap_per_class: int = Field(100, ge=1, description="test clips per class at most (§5.1.1)")
    # open choices (docs/protocols.md, docs/multi_action.md)
    split: Literal["marionette", "dataset"] = Field(
        "marionette", description="Marionette's per-class split, or the data set's stored one")
    split_seed: int = Field(0, description="seed of the Marionette split")
    context: Literal["sequence", "same_clip"] = Field(
        "sequence", description="where P^ini and the next tag come from: the action's composed "
        "sequence (repro.data.contexts), or the clip itself (the earlier, leaking construction)")
    max_frames: int = Field(120, ge=1, description="cap on an action's duration (frames)")


class MarionetteParams(ActionItemParams):
    """:class:`ActionItemParams` plus the scoring fields every Neural Marionette protocol reads
    (open choices, docs/protocols.md; the harness columns are in no paper)."""

    replicates: int | None = Field(None, ge=1, description="read by the engine (scale profile)")
    eval_clip: Literal["centre", "start", "whole"] = Field(
        "centre", description="what the evaluator sees of an action: its centred or first "
        "window of the evaluator's length, or the whole action")
    fid_method: Literal["eigh", "scipy"] = Field("eigh", description="repro.metrics.fid method")
    memorisation: bool = Field(True, description="harness columns beyond the paper "
                               "(repro.eval.memorisation): nearest-training distances, "
                               "precision/recall/density/coverage of the scored actions")
    prdc_k: int = Field(5, ge=1, description="k of precision/recall/density/coverage "
                        "(Naeem et al. 2020's 5)")


def evaluation_clips(joints, lengths, window: int, mode: str) -> tuple[np.ndarray, np.ndarray]:
    """What the evaluator sees of each action: joints (N, W, J, 3) and valid lengths (N,).

    ``mode``: ``"centre"`` (frames ``s .. s+W−1`` with ``s = (L − W) // 2``), ``"start"``
    (``s = 0``), both padded by repeating the last valid frame when ``L < W``; ``"whole"``
    (the padded action as it is).  Metres in, metres out.
    """
    import torch

    j = joints.detach().cpu().numpy() if isinstance(joints, torch.Tensor) else np.asarray(joints)
    lens = lengths.detach().cpu().numpy() if isinstance(lengths, torch.Tensor) else np.asarray(lengths)
    lens = lens.astype(np.int64).reshape(-1)
    if mode == "whole":
        return j, lens
    if mode not in ("centre", "start"):
        raise ConfigError(f"eval_clip must be 'centre', 'start' or 'whole', got {mode!r}")
    start = np.maximum(lens - window, 0) // 2 if mode == "centre" else np.zeros_like(lens)
    idx = np.minimum(start[:, None] + np.arange(window)[None, :], (lens - 1)[:, None])
    out = np.take_along_axis(j, idx[:, :, None, None], axis=1)
    return out, np.minimum(lens, window)


class MarionetteProtocol(ItemProtocol):
    """Base of Neural Marionette's protocols: items from :class:`ActionItemParams`
    (:class:`repro.data.contexts.ActionSource`: one item per action,
    :class:`repro.data.action_items.ActionItems`), actions shown to the evaluator as
    ``eval_clip`` says (:func:`evaluation_clips`)."""

    params: MarionetteParams

    # -- data ------------------------------------------------------------------------------
    def items_config(self):
        """The :class:`repro.data.action_items.ItemsConfig` the items are cut with."""
        return self.item_source().items_config()

    def evaluator_overrides(self) -> dict:
        """Evaluator settings this protocol asks for: with items from composed sequences, the
        recogniser trains on windows as short as the shortest action it scores
        (``min_window`` = the composition's ``min_action_frames``; issue 26), else nothing."""
        if self.params.context != "sequence":
            return {}
        from repro.data.sequences import ComposeConfig

        return {"min_window": ComposeConfig.resolve(self.params.compose).min_action_frames}

    # -- the evaluator's pass --------------------------------------------------------------
    def _encode(self, evaluator, motion, seed: int):
        """The evaluator's ``(features, logits)`` of the actions of ``motion`` (a
        GeneratedItems), each seen as ``eval_clip`` says (:func:`evaluation_clips`)."""
        T = int(motion.lengths.max())
        joints = motion.joints()[:, :T]
        j, lens = evaluation_clips(joints, motion.lengths, evaluator.settings.window,
                                   self.params.eval_clip)
        return evaluator.encode(j, lens, seed=seed)


# ---------------------------------------------------------------------------------------------
# sample files


@dataclass(frozen=True)
class SampleFile:
    """A samples file :func:`read_samples` read: its ``meta``, its ``arrays``, the skeleton
    ``meta`` names and the ``path`` (for messages)."""

    path: Path
    meta: dict
    arrays: dict
    skeleton: object

    def motion_set(self, prefix: str = ""):
        """The GeneratedItems stored under ``prefix`` (shapes checked; DataError naming the
        file when they do not fit)."""
        from repro.eval.sample_files import motion_set

        return motion_set(self.arrays, self.meta, self.skeleton, self.path, prefix)


def write_samples(path: str | Path, protocol_id: str, fmt: int, generated, *,
                  meta: Mapping | None = None, sets: Mapping | None = None,
                  arrays: Mapping[str, np.ndarray] | None = None) -> Path:
    """Write ``generated`` (a GeneratedItems) to the npz file ``path``, atomically
    (:mod:`repro.eval.sample_files`): ``meta`` holds ``format`` = ``fmt``, ``protocol``, the
    skeleton and ``fps`` plus the entries of ``meta``; the arrays are those of ``generated``,
    then of each further motion set of ``sets`` (``{prefix: GeneratedItems}``) under its
    prefix, then ``arrays``."""
    from repro.eval.sample_files import motion_arrays, save_samples

    m = generated.motion
    head = {"format": fmt, "protocol": protocol_id, "skeleton": m.skeleton.to_dict(),
            "fps": m.fps, **dict(meta or {})}
    out = motion_arrays(generated)
    for prefix, other in dict(sets or {}).items():
        out.update(motion_arrays(other, prefix))
    out.update(dict(arrays or {}))
    return save_samples(path, head, out)


def read_samples(path: str | Path, protocol_id: str, fmt: int) -> SampleFile:
    """Read a file :func:`write_samples` wrote for ``protocol_id`` in format ``fmt``
    (DataError naming it when it is not one)."""
    from repro.eval.sample_files import load_samples

    meta, data, skeleton = load_samples(path, protocol=protocol_id, fmt=fmt)
    return SampleFile(Path(path), meta, data, skeleton)
