"""The real-data gate as a step of a table run (split from :mod:`repro.engine.runner`, issue
28): each band's evaluator's stored real rows checked under the gate the run asked for
(:mod:`repro.eval.gate`), the outcome written to the run record before a failing gate stops
the run, and the store objects the step read or wrote counted in that record."""

from __future__ import annotations

from repro.engine.table_facts import real_rows_stored


def stored_by(rec):
    """A ``stored(key, hit)`` callback adding a store object a run read (``hit``) or wrote to
    the run record ``rec``'s ``keys`` (evaluators, real rows, test sets and summaries are
    stored outside the job graph; the executor records the jobs)."""
    def stored(key: str, hit: bool) -> None:
        if key:
            rec.add_keys(read=[key]) if hit else rec.add_keys(written=[key])
    return stored


def check_gate(plan, setting, rec=None, log=None, check: bool = True) -> dict:
    """The real-data gate for every band that has a real row (evaluation issue, item 4), under
    ``setting`` (:func:`repro.eval.gate.resolve_gate`: the command line over the data-set
    spec's ``[gate]`` over the profile), unless ``check`` is False (a run with no job);
    returns what the run records of it
    (:func:`repro.eval.gate.gate_summary`), written to the run record ``rec`` before a failing
    gate stops the run, so the failed run names what was measured.

    The real rows the gate reads are stored by content
    (:func:`repro.engine.table_facts.real_rows_stored`), so a rerun
    checks the gate without recomputing them, from the evaluator's record (its weights are
    read only when the real rows must be computed); the check itself always runs."""
    from repro.engine.steps import clipset, evaluator_clipset, evaluator_for
    from repro.eval import evaluator_stats
    from repro.eval.gate import apply_gate, gate_line, gate_summary, raise_if_failed
    from repro.eval.protocols import get_protocol
    from repro.eval.settings import resolve_settings

    checks: list[dict] = []

    def record() -> dict:
        out = gate_summary(setting, checks, resolve_settings(plan.scale.name).real.gate_margin)
        if rec is not None:
            rec.add_extra("gate", out)
        return out

    if not check or not any(rp.method == "real" and rp.measures for rp in plan.rows):
        return record()  # nothing to score (no job), or no real row: nothing checked
    seen = set()
    for b in plan.bands:
        if b.evaluator is None or b.evaluator_key in seen:
            continue
        seen.add(b.evaluator_key)
        cfg = b.step_config(plan.dataset, with_evaluator=True)
        ev = evaluator_for(cfg, weights=False)
        clips = evaluator_clipset(get_protocol(b.protocol, b.params), clipset(plan.dataset))
        rows = real_rows_stored(b.evaluator, b.evaluator_key, ev, clips,
                                load=lambda cfg=cfg: evaluator_for(cfg),
                                stored=None if rec is None else stored_by(rec))
        checks.append(apply_gate(rows, evaluator_stats(ev), setting))
        if log is not None:
            c = checks[-1]
            log(f"real rows of {c['evaluator']}: real accuracy {_num(c['real_accuracy'])}, "
                f"test accuracy {_num(c['test_accuracy'])}")
    out = record()
    if log is not None:
        log(f"{plan.spec.id}: {gate_line(out)}")
    for c in checks:
        raise_if_failed(c)
    return out


def _num(x) -> str:
    return "-" if x is None else f"{float(x):.3f}"
