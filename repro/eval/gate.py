"""The real-data gate: methods are scored only when the real rows look sane.

The engine computes :func:`repro.eval.real.real_rows` first for a table and calls
:func:`check_real_gate`; it raises :class:`RealGateError` (a :class:`~repro.errors.ReproError`:
one line, exit 2) naming every failed check:

1. every per-replicate value is finite;
2. real accuracy (mean over replicates) ≥ the classifier's test accuracy − ``margin``: the
   real reference sets are drawn as the classifier was tested, so a lower value means the
   sets, the windows or the evaluator disagree;
3. FID(train, test) of real data ≤ ``max_fid`` (real train and test motions must look alike
   to the evaluator; a large value means a broken split or an overfitted feature layer);
4. diversity > multimodality: features must spread more across classes than within one;
5. n-APD of the real set is 100 (its definition; anything else is a bug in the pipeline).
"""

from __future__ import annotations

import math
from typing import Any, Mapping

from repro.errors import ReproError


class RealGateError(ReproError):
    """The real rows failed their sanity bounds; methods are not scored."""

    def __init__(self, dataset: str, evaluator: str, reasons: list[str]):
        self.dataset, self.evaluator, self.reasons = dataset, evaluator, list(reasons)
        super().__init__(f"real-data gate failed for {dataset} (evaluator {evaluator}); methods "
                         f"are not scored: " + "; ".join(reasons))


def _test_top1(evaluator_stats: Any) -> float | None:
    if evaluator_stats is None:
        return None
    if isinstance(evaluator_stats, Mapping):
        for k in ("top1", "test_top1", "test_accuracy", "accuracy"):
            if evaluator_stats.get(k) is not None:
                return float(evaluator_stats[k])
        return None
    v = getattr(evaluator_stats, "top1", None)
    return None if v is None else float(v)


def gate_failures(real_rows: Mapping, evaluator_stats: Any = None, margin: float | None = None,
                  max_fid: float | None = None) -> list[str]:
    """The reasons the gate fails (empty when it passes); see the module docstring."""
    gate = real_rows.get("gate", {})
    margin = float(gate.get("margin", 0.05) if margin is None else margin)
    max_fid = float(gate.get("max_fid", math.inf) if max_fid is None else max_fid)
    row = real_rows["rows"]["real"]
    reasons: list[str] = []
    for name, m in row.items():
        if not all(math.isfinite(float(x)) for x in m["values"]):
            reasons.append(f"{name} has non-finite replicate values")
    top1 = _test_top1(evaluator_stats)
    if top1 is None:
        top1 = _test_top1(real_rows.get("evaluator", {}))
    acc = row.get("accuracy", {}).get("mean")
    if top1 is not None and acc is not None and acc < top1 - margin:
        reasons.append(f"real accuracy {acc:.3f} is below the classifier's test accuracy "
                       f"{top1:.3f} minus the margin {margin:.3f}")
    if top1 is None:
        reasons.append("the classifier's test accuracy is unknown, so real accuracy cannot be checked")
    fid_tr = row.get("fid_train", {}).get("mean")
    if fid_tr is not None and fid_tr > max_fid:
        reasons.append(f"real FID(train, test) {fid_tr:.3f} exceeds the bound {max_fid:.3f}")
    div, mm = row.get("diversity", {}).get("mean"), row.get("multimodality", {}).get("mean")
    if div is not None and mm is not None and not div > mm:
        reasons.append(f"real diversity {div:.3f} is not above real multimodality {mm:.3f} "
                       "(features do not separate classes)")
    napd = row.get("n_apd", {}).get("values")
    if napd is not None and any(abs(float(x) - 100.0) > 1e-6 for x in napd):
        reasons.append(f"real n-APD is not 100 (got {row['n_apd']['mean']:.4f})")
    return reasons


def check_real_gate(real_rows: Mapping, evaluator_stats: Any = None, margin: float | None = None,
                    *, max_fid: float | None = None) -> None:
    """Raise :class:`RealGateError` saying why when the real rows fail the gate; else None.

    ``evaluator_stats``: the classifier's recorded test statistics (a dict with ``top1``, a
    :class:`~repro.eval.training.TestAccuracy`, or None to use the copy inside ``real_rows``);
    ``margin``/``max_fid`` default to the values recorded in ``real_rows["gate"]``.
    """
    reasons = gate_failures(real_rows, evaluator_stats, margin, max_fid)
    if reasons:
        ev = real_rows.get("evaluator", {})
        name = f"{ev.get('kind', '?')} [{str(ev.get('fingerprint', '?'))[:12]}]"
        raise RealGateError(str(real_rows.get("dataset", "?")), name, reasons)
