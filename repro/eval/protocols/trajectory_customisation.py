"""``trajectory_customisation``: ODMO's end-point customisation (Table 4; ODMO §4.4;
protocols.md §3.8, §7-5).

A replicate (the reference's seed 0..9) rebuilds the code bank of the trained model from the
training pool (``bank_iters`` = 5 loader passes for every data set, as the reference's
customisation script), then per class draws ``codes_per_class`` (40) *real* bank codes (a
random bank window of the class: the code is its encoder mean, not a GMM sample, §7-5) and for
each a second random bank window of the same class; the targets are
``linspace(end_1, end_2, end_points_per_code)`` (10, both ends included) where ``end_1`` is the
code's own end location and ``end_2`` the other window's.  Each (code, target) pair is decoded
(trajectory generator given the target, then the motion generator, teacher forcing off).

Columns (:meth:`TrajectoryCustomisation.measure`):

- ``dist_e``: the squared Euclidean distance, summed over xyz, between the target and the
  *motion generator's* root at the last frame, averaged per class then over classes
  (:func:`repro.metrics.trajectory.endpoint_error`), in squared dataset units (m² on the
  stand-in; MoCap's table is in (m/20)²-like units of CMU data, so magnitudes differ);
- ``acc``: recognition accuracy (%) of the decoded motions against their class (the
  reference runs its metric script on the saved motions).

Only methods with a code bank and an end-point input (ODMO and its trajectory ablations)
can be customised; any other method is an error naming it.  There is no Real row.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from repro.errors import DataError
from repro.eval.protocols import register
from repro.eval.protocols.odmo_common import OdmoContext, OdmoParams, OdmoProtocol, OdmoSamples
from repro.seeding import derive_seed, numpy_rng


class TrajectoryParams(OdmoParams):
    """:class:`OdmoParams` plus the customisation counts (ODMO §4.4)."""

    bank_iters: int = Field(5, ge=1, description="the customisation script's num_itr (5 for "
                            "every data set, protocols.md §3.8)")
    codes_per_class: int = Field(40, ge=1, description="real codes per class (§4.4)")
    end_points_per_code: int = Field(10, ge=2, description="targets per code: 2 real end "
                                     "points and the interpolated ones between (§4.4)")


@register
class TrajectoryCustomisation(OdmoProtocol):
    """ODMO Table 4 (module docstring)."""

    id = "trajectory_customisation"
    Params = TrajectoryParams
    params: TrajectoryParams
    metrics = ("acc", "dist_e")
    real_metrics = ()
    version = 1

    def test_items(self, clipset) -> OdmoContext:
        p = self.params
        return self.context(clipset, p.codes_per_class * p.end_points_per_code)

    def generate(self, generator, ctx: OdmoContext, *, seed: int, replicate: int, need=None,
                 models=None, row_config=None) -> OdmoSamples:
        import torch

        p = self.params
        who = getattr(generator, "method_id", type(generator).__name__)
        if not (hasattr(generator, "bank") and hasattr(generator, "decode")):
            raise DataError(f"method {who!r} has no code bank and end-point input: trajectory "
                            "customisation needs ODMO or one of its ablations")
        s = self.replicate_seed(seed, replicate)
        bank = generator.bank(ctx.train, n_iter=p.bank_iters, seed=derive_seed(s, "bank"))
        codes, labels, targets = self.pairs(bank, ctx.train.n_classes, s)
        joints = generator.decode(torch.from_numpy(codes), torch.from_numpy(labels),
                                  torch.from_numpy(targets), p.window)
        joints = joints.detach().cpu().numpy() if isinstance(joints, torch.Tensor) else joints
        return OdmoSamples(joints, labels, ctx.train.skeleton, ctx.train.fps, targets=targets)

    def pairs(self, bank, n_classes: int, seed: int):
        """(codes (N, D), labels (N,), targets (N, 3)), class-major, ``codes_per_class`` ×
        ``end_points_per_code`` per class (module docstring)."""
        p = self.params
        rng = numpy_rng(seed, "trajectory_customisation", "pairs")
        b_codes = np.asarray(bank.codes, dtype=np.float64)
        b_ends = np.asarray(bank.ends, dtype=np.float64)
        b_labels = np.asarray(bank.labels, dtype=np.int64)
        E = p.end_points_per_code
        codes, labels, targets = [], [], []
        w = np.linspace(0.0, 1.0, E)[:, None]
        for c in range(n_classes):
            rows = np.flatnonzero(b_labels == c)
            if rows.size == 0:
                raise DataError(f"trajectory customisation: the code bank has no window of class {c}")
            src = rows[rng.integers(0, rows.size, size=p.codes_per_class)]
            other = rows[rng.integers(0, rows.size, size=p.codes_per_class)]
            for a, b in zip(src, other):
                codes.append(np.repeat(b_codes[a][None], E, axis=0))
                targets.append((1.0 - w) * b_ends[a][None] + w * b_ends[b][None])
                labels.append(np.full(E, c, dtype=np.int64))
        return (np.concatenate(codes).astype(np.float32), np.concatenate(labels),
                np.concatenate(targets).astype(np.float32))

    def measure(self, generated: OdmoSamples, ctx: OdmoContext, evaluator, *, seed: int,
                clipset=None) -> dict[str, float]:
        from repro.metrics.accuracy import accuracy
        from repro.metrics.trajectory import endpoint_error

        if generated.targets is None:
            raise DataError("trajectory customisation samples carry no targets")
        self.check_evaluator(evaluator, ctx.train)
        _, logits = evaluator.encode(generated.joints, None,
                                     seed=derive_seed(seed, "odmo", "features"))
        end = generated.joints[:, -1, 0, :]  # the motion generator's root, last frame
        return {"acc": 100.0 * accuracy(logits, generated.labels, top_k=1).value,
                "dist_e": endpoint_error(end, generated.targets, generated.labels,
                                         ctx.train.n_classes)}

    def real_replicate(self, clipset, ctx, evaluator, *, seed: int, replicate: int) -> dict:
        return {}  # Table 4 has no Real row


__all__ = ["TrajectoryCustomisation", "TrajectoryParams"]
