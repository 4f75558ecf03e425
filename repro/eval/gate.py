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
from dataclasses import dataclass
from typing import Any, Mapping

from repro.errors import ReproError


class RealGateError(ReproError):
    """The real rows failed their sanity bounds; methods are not scored."""

    def __init__(self, dataset: str, evaluator: str, reasons: list[str], detail: str = ""):
        self.dataset, self.evaluator, self.reasons = dataset, evaluator, list(reasons)
        super().__init__(f"real-data gate failed for {dataset} (evaluator {evaluator}); methods "
                         f"are not scored: " + "; ".join(reasons) + (f" [{detail}]" if detail
                                                                      else ""))


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


def measured(real_rows: Mapping) -> str:
    """What the gate's two accuracies are, so a user can find both numbers: the real accuracy
    is the mean over the gate's own real reference sets (``repro eval real`` prints the same
    rows), not the table's Real row (the protocol's test items, scored like generated ones,
    one value per replicate seed); the test accuracy is the classifier's, over every test
    window (``repro eval classifier``)."""
    ev = real_rows.get("evaluator") or {}
    stride = ""
    if ev.get("test_windows"):
        stride = f" ({ev['test_windows']} windows)"
    return (f"real accuracy = mean over {real_rows.get('replicates', '?')} replicates of the "
            f"gate's real reference sets, {real_rows.get('per_class', '?')} class-balanced "
            f"test windows per class of {real_rows.get('window', '?')} frames, seed "
            f"{real_rows.get('seed', 0)}: `repro eval real` shows it, the table's Real row "
            f"scores the protocol's test items instead; test accuracy = the classifier's on "
            f"every test window{stride}, `repro eval classifier`")


#: how the accuracy check's failure begins (the check the margin relaxes; the others, a FID
#: over its bound, ..., pass only with the gate off)
ACCURACY_REASON = "real accuracy"


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
        reasons.append(f"{ACCURACY_REASON} {acc:.3f} is below the classifier's test accuracy "
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
        raise RealGateError(str(real_rows.get("dataset", "?")), _evaluator_name(real_rows),
                            reasons, _detail(real_rows, reasons))


def _evaluator_name(real_rows: Mapping) -> str:
    ev = real_rows.get("evaluator", {})
    return f"{ev.get('kind', '?')} [{str(ev.get('fingerprint', '?'))[:12]}]"


def _is_accuracy_reason(reason: str) -> bool:
    """Whether a gate failure is the accuracy check's (the one the margin relaxes)."""
    return reason.startswith(ACCURACY_REASON)


def _detail(real_rows: Mapping, reasons: list[str]) -> str:
    """What the accuracies of a failed accuracy check are (:func:`measured`), else ''."""
    return measured(real_rows) if any(map(_is_accuracy_reason, reasons)) else ""


# ---------------------------------------------------------------------- which gate a run used
#: where a gate setting came from, in the order a later one wins
PROFILE, SPEC, COMMAND_LINE = "profile", "spec", "command line"


@dataclass(frozen=True)
class GateSetting:
    """The gate a run asked for: ``enabled`` / ``margin`` None keep the profile's (on, its
    ``real.gate_margin``); ``*_from`` say who set each (:data:`SPEC` with the spec file, or
    :data:`COMMAND_LINE`).  One implementation for ``repro run`` / ``sweep`` / ``rescore``
    and ``repro eval real`` (:func:`resolve_gate`, :func:`apply_gate`)."""

    enabled: bool | None = None
    margin: float | None = None
    enabled_from: str = PROFILE
    margin_from: str = PROFILE


def resolve_gate(dataset: str | None, *, margin: float | None = None,
                 no_gate: bool = False) -> GateSetting:
    """The gate of a run on ``dataset``: the command line (``--gate-margin``, ``--no-gate``)
    over the data-set spec's ``[gate]`` over the profile (docs/engine.md, "The real-data
    gate").  ``margin`` is checked here too (a number in [0, 1]): the CLI's argparse type
    says so earlier."""
    from repro.errors import ConfigError

    if margin is not None and not (isinstance(margin, (int, float)) and 0 <= margin <= 1):
        raise ConfigError(f"--gate-margin must be a number in [0, 1], got {margin!r}")
    enabled, e_from, m, m_from = None, PROFILE, None, PROFILE
    spec_gate, spec_file = _spec_gate(dataset)
    if spec_gate is not None:
        where = f"{SPEC} {spec_file} [gate]"
        if not spec_gate.enabled:
            enabled, e_from = False, where
        if spec_gate.margin is not None:
            m, m_from = float(spec_gate.margin), where
    if no_gate:
        enabled, e_from = False, f"{COMMAND_LINE} (--no-gate)"
    if margin is not None:
        m, m_from = float(margin), f"{COMMAND_LINE} (--gate-margin)"
    return GateSetting(enabled, m, e_from, m_from)


def _spec_gate(dataset: str | None):
    """(the ``[gate]`` of the spec that declares ``dataset``, its file), or (None, None) for
    a built-in data set or one no spec declares."""
    if not dataset:
        return None, None
    from repro.data.dataset_registration import spec_file_of
    from repro.data.dataset_spec import load_dataset_spec

    path = spec_file_of(dataset)
    if path is None:
        return None, None
    return load_dataset_spec(path).gate, path


def apply_gate(real_rows: Mapping, evaluator_stats: Any, setting: GateSetting) -> dict:
    """The gate's record for one evaluator's real rows under ``setting`` (nothing raised):
    what it measured, the margin used and the profile's (the standard one), its reasons under
    both, and whether the gate was enabled.  :func:`raise_if_failed` then stops the run."""
    standard = float((real_rows.get("gate") or {}).get("margin", 0.05))
    margin = standard if setting.margin is None else float(setting.margin)
    enabled = setting.enabled is not False
    reasons = gate_failures(real_rows, evaluator_stats, margin)
    std = reasons if margin == standard else gate_failures(real_rows, evaluator_stats, standard)
    acc = ((real_rows.get("rows") or {}).get("real") or {}).get("accuracy") or {}
    top1 = _test_top1(evaluator_stats)
    return {"dataset": real_rows.get("dataset"), "evaluator": _evaluator_name(real_rows),
            "enabled": enabled, "margin": margin, "standard_margin": standard,
            "passed": not reasons, "reasons": reasons,
            "standard_passed": not std, "standard_reasons": std,
            "real_accuracy": acc.get("mean"),
            "test_accuracy": top1 if top1 is not None else _test_top1(
                real_rows.get("evaluator") or {}),
            "measured": measured(real_rows)}


def raise_if_failed(check: Mapping) -> None:
    """:class:`RealGateError` when the gate of ``check`` (:func:`apply_gate`) is enabled and
    failed; the message says what was measured and how to relax the gate (the run is then
    marked)."""
    if check["enabled"] and check["reasons"]:
        accuracy = [_is_accuracy_reason(r) for r in check["reasons"]]
        detail = check["measured"] if any(accuracy) else ""
        # the margin relaxes the accuracy check alone: another failed check (a FID over its
        # bound, ...) passes only with the gate off
        how = ("--gate-margin X or --no-gate (or set [gate] in the data-set spec)" if all(accuracy)
               else "--no-gate (or set [gate] enabled = false in the data-set spec; "
                    "--gate-margin relaxes only the accuracy check)")
        raise RealGateError(str(check.get("dataset") or "?"), check["evaluator"],
                            check["reasons"],
                            (detail + "; " if detail else "") + f"to score methods anyway pass "
                            f"{how}: the run is then marked as made under a non-standard gate")


def gate_summary(setting: GateSetting, checks: list[dict], profile_margin: float) -> dict:
    """What a run records of its gate (``summary.json`` and ``run.json`` ``extra.gate``): the
    setting used, each evaluator's check (:func:`apply_gate`), and whether it is the standard
    gate (on, at the profile's margin) or a relaxed one (off, or a wider margin)."""
    std = sorted({float(c["standard_margin"]) for c in checks}) or [float(profile_margin)]
    enabled = setting.enabled is not False
    m = setting.margin
    return {"schema": 1, "enabled": enabled,
            "margin": (float(m) if m is not None else std[0] if len(std) == 1 else None),
            "standard_margin": std[0] if len(std) == 1 else std,
            "enabled_from": setting.enabled_from, "margin_from": setting.margin_from,
            "standard": enabled and (m is None or all(m == s for s in std)),
            "relaxed": (not enabled) or (m is not None and any(m > s for s in std)),
            "checks": list(checks)}


def gate_line(gate: Mapping | None) -> str:
    """The footer's line for a run's gate record (:func:`gate_summary`).  A run recorded
    before runs named their gate ran under the profile's: nothing could relax it then."""
    if not gate:
        return "Real-data gate: standard (the scale profile's margin; not recorded by this run)."
    m = "-" if gate.get("margin") is None else f"{float(gate['margin']):.3f}"
    std = gate.get("standard_margin")
    s = f"{float(std):.3f}" if isinstance(std, (int, float)) else str(std)
    checks = gate.get("checks") or []
    outcome = ("no real row checked" if not checks else
               "passed" if all(c.get("passed") for c in checks) else
               "FAILED" if gate.get("enabled", True) else "FAILED, not enforced")
    if gate.get("standard"):
        return f"Real-data gate: standard (on, margin {m}, the scale profile's): {outcome}."
    kind = "NON-STANDARD, RELAXED" if gate.get("relaxed") else "NON-STANDARD"
    parts = ["on" if gate.get("enabled", True) else f"off ({gate.get('enabled_from')})"]
    if gate.get("margin_from", PROFILE) != PROFILE:
        parts.append(f"margin {m} ({gate.get('margin_from')}) instead of the profile's {s}")
    std_failed = [c for c in checks if not c.get("standard_passed", True)]
    verdict = ("" if not checks else
               " The standard gate would have FAILED: " + "; ".join(
                   r for c in std_failed for r in c.get("standard_reasons") or []) + "."
               if std_failed else " The standard gate would have passed.")
    return (f"Real-data gate: {kind}: {', '.join(parts)}: {outcome}; not a standard run."
            + verdict)
