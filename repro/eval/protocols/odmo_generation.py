"""``odmo_generation``: ODMO's label-conditioned generation benchmark (Tables 1, 2 and S1;
ODMO §4.2, supplement §2.3, §2.5; protocols.md §3.2-3.6).

A replicate (:meth:`OdmoGeneration.generate`) is one generated set of ``per_class`` windows
per class from a trained model, seeded by ``(seed, replicate)`` (the reference's 10 files with
seeds 0..9).  It is scored (:meth:`OdmoGeneration.measure`) by the metric block of
:mod:`repro.eval.protocols.odmo_common` — ``acc`` (%), ``fid`` / ``fid_train`` / ``fid_test``
against the fixed real set 0 of each split, ``div``, ``multimod`` — and ``n_apd``: 100 × the
mean over classes of APD(generated_c) / APD(real_c), with the replicate's own real training-split
set (protocols.md §3.6: generated file *i* against real file *i*; APD on the flattened
(T·J·3) windows, :func:`repro.metrics.apd.n_apd`).

The "Real motions" row (:meth:`OdmoGeneration.real_replicate`) scores, per replicate, the same
real set n-APD pairs with (so its n-APD is 100 by construction, as in the paper) like a
generated one; its FID is against the fixed real set 0 (an independent draw of the same kind;
the reference's real row includes set 0 itself, whose FID is noise around 0).

Row options read from the row's method config (inference only, so ODMO_conv shares ODMO's
training): ``sampling`` ("mode_preserving" | "conventional"), ``k_rule`` and
``conventional_form``; the group's ``bank_iters`` sets the code bank's size.
"""

from __future__ import annotations

from repro.eval.protocols import register
from repro.eval.protocols.odmo_common import OdmoContext, OdmoProtocol, OdmoSamples, real_set

METRICS = ("acc", "fid", "fid_train", "fid_test", "div", "multimod", "n_apd")


@register
class OdmoGeneration(OdmoProtocol):
    """ODMO Tables 1, 2, S1 (module docstring)."""

    id = "odmo_generation"
    metrics = METRICS
    real_metrics = METRICS
    version = 1

    def generate(self, generator, ctx: OdmoContext, *, seed: int, replicate: int, need=None,
                 models=None, row_config=None) -> OdmoSamples:
        s = self.replicate_seed(seed, replicate)
        joints = self.sample_joints(generator, ctx.labels, seed=s, pool=ctx.train,
                                    row_config=row_config)
        return OdmoSamples(joints, ctx.labels, ctx.train.skeleton, ctx.train.fps)

    def apd_reference(self, ctx: OdmoContext, seed: int):
        """The replicate's real training-split set n-APD is normalised by (§3.6)."""
        return real_set(ctx.train, self.params.per_class, seed, "train", "apd")

    def _n_apd(self, joints, labels, ctx: OdmoContext, seed: int) -> float:
        from repro.metrics.apd import n_apd

        real, real_labels = self.apd_reference(ctx, seed)
        return n_apd(joints, labels, real, real_labels, ctx.train.n_classes)

    def measure(self, generated: OdmoSamples, ctx: OdmoContext, evaluator, *, seed: int,
                clipset=None) -> dict[str, float]:
        out = self.metric_block(generated.joints, generated.labels, evaluator, ctx, seed=seed)
        out["n_apd"] = self._n_apd(generated.joints, generated.labels, ctx, seed)
        return out

    def real_replicate(self, clipset, ctx: OdmoContext, evaluator, *, seed: int,
                       replicate: int) -> dict[str, float]:
        joints, labels = self.apd_reference(ctx, seed)
        out = self.metric_block(joints, labels, evaluator, ctx, seed=seed)
        out["n_apd"] = self._n_apd(joints, labels, ctx, seed)
        return out


__all__ = ["OdmoGeneration", "METRICS"]
