"""Harness columns beyond the papers (issue 11, item 5): how close generated actions lie to
the training data, and how well they cover the real distribution.

The papers' metrics (FID, Acc, Div, Multimod) reward a generator that copies its training
set: the harness's own nearest-training-clip reference beats every model on FID.  These
columns let a reviewer see that, on every single-action table:

- ``nn_train_feat``: mean over generated actions of the Euclidean distance, in the
  evaluator's feature space (the features FID uses), to the nearest *training* action;
- ``nn_train_joint``: the same in joint space: each action's first ``W`` frames (``W`` = the
  evaluator's window), normalised at its own first frame (Neural Marionette's normalisation,
  :func:`repro.motion.canon.marionette_normalize` with anchor 0: that frame's root at the origin
  facing +Z, as the items' own normalisation removes the 3-D root position; the pose itself,
  crouched or standing, is kept relative to the root), the distance being the root-mean-square per-joint distance in metres over the
  generated action's valid frames (:func:`repro.metrics.memorisation.masked_nearest_rms`), so a
  copy of a training action scores 0 whatever its duration or where it was placed (only the
  first window is compared: a copy of a training action's later part is not caught);
- ``precision``, ``recall``, ``density``, ``coverage`` of the generated features against the
  real test features, each real action once (Kynkäänniemi et al. 2019; Naeem et al. 2020;
  k = ``prdc_k``, 5 as Naeem et al.; Kynkäänniemi et al. used 3).

The "Real" row gets the two nearest-training distances of the real test actions: the level
of a generator that generalises as well as fresh data does.  A copier sits near 0 on both;
a model far above the real level generates actions unlike any training one.  None of this is
in the papers; the columns are marked "harness" wherever they are shown.
"""

from __future__ import annotations

import numpy as np

HARNESS_METRICS = ("nn_train_feat", "nn_train_joint", "precision", "recall", "density",
                   "coverage")


def action_windows(motion, lengths: torch.Tensor, window: int) -> tuple[np.ndarray, np.ndarray]:
    """(N, W, J, 3) float64 joint positions of each action's first ``W`` frames, normalised at
    its first frame (module docstring; frames past an action's end repeat its last valid
    frame), and the valid counts ``min(length, W)``."""
    import torch

    from repro.motion.canon import marionette_normalize

    # 3-D translation as the items' own normalisation (D = the anchor's root position): the
    # generators place actions relative to the previous pose's root, height included
    norm, _ = marionette_normalize(motion, anchor=0)
    pts = norm.joints()
    lens = lengths.long().clamp(min=1)
    t = torch.minimum(torch.arange(window)[None, :], (lens - 1)[:, None])
    t = t.clamp(max=pts.shape[1] - 1)
    out = pts[torch.arange(pts.shape[0])[:, None], t]
    return out.detach().cpu().double().numpy(), torch.clamp(lens, max=window).numpy()


def harness_columns(protocol, motion, feats, evaluator, clipset, *, bank_seed: int,
                    real_feats=None) -> dict[str, float]:
    """The harness columns of ``motion`` (a GeneratedItems whose evaluator features are
    ``feats``) against ``protocol``'s training items (the actions its models train on, encoded
    by the protocol's own ``_encode`` with ``bank_seed``): what :func:`harness_values`
    computes, with ``protocol.params.prdc_k``."""
    bank = protocol.train_items(clipset)
    real = bank.real()
    bank_feats, _ = protocol._encode(evaluator, real, bank_seed)
    return harness_values(motion.motion, motion.lengths, feats, real.motion, bank.lengths,
                          bank_feats, evaluator.settings.window, real_feats,
                          k=protocol.params.prdc_k)


def harness_values(gen_motion, gen_lengths, gen_feats, bank_motion, bank_lengths, bank_feats,
                   window: int, real_feats=None, k: int = 5) -> dict[str, float]:
    """The harness columns (module docstring): generated actions (``gen_motion`` world-frame
    Motion, valid ``gen_lengths``, evaluator features ``gen_feats``) against the training bank
    (likewise); precision/recall/density/coverage only when ``real_feats`` is given."""
    from repro.metrics.memorisation import masked_nearest_rms, nearest_distances, prdc

    out = {"nn_train_feat": float(np.mean(nearest_distances(
        np.asarray(gen_feats, dtype=np.float64), np.asarray(bank_feats, dtype=np.float64))))}
    windows, lens = action_windows(gen_motion, gen_lengths, window)
    bank, _ = action_windows(bank_motion, bank_lengths, window)
    d, _ = masked_nearest_rms(windows, lens, bank)
    out["nn_train_joint"] = float(np.mean(d))
    if real_feats is not None:
        out.update(prdc(np.asarray(real_feats, dtype=np.float64),
                        np.asarray(gen_feats, dtype=np.float64), k=k))
    return out
