"""The footer of a table: what made its numbers, in words, for every output format.

Built when a run ends (stored in its summary, so ``repro show`` prints what the run was) or,
before any run, from the plan.  Split from :mod:`repro.engine.runner` (issue 28), which runs
tables; this module only words them.
"""

from __future__ import annotations

from typing import Any

from repro.errors import ReproError


def group_lines(plan) -> list[str]:
    """One line per column group that sets its own protocol parameters: what the group (a
    paper data set) is on the data set actually run, with the values the run resolved (scale
    overrides included) for the parameters the spec's group names."""
    spec, out, seen = plan.spec, [], set()
    for b in plan.bands:
        if not b.implemented:
            continue
        for col in b.columns:
            g = spec.group_of(col)
            if g is None or not g.protocol_params or g.id in seen:
                continue
            seen.add(g.id)
            vals = ", ".join(f"{k} {b.params.get(k, v)!r}".replace("'", "")
                             for k, v in g.protocol_params.items())
            paper = f" (the paper's {g.paper_dataset})" if g.paper_dataset else ""
            out.append(f"Group {g.label}{paper} on {plan.dataset}: {vals}.")
    return out


def data_words(dataset: str) -> str:
    """What a data set is, for a footer: a built-in stand-in is called one (``STAND-IN
    bandai2-mini``); a data set a spec file declares is the user's own, never called a
    stand-in; any other name as it is."""
    from repro.specs import names

    kind = names.dataset_kind(dataset)
    if kind != names.OWN:
        return f"STAND-IN {dataset}" if kind == names.STANDIN else dataset
    try:
        from repro.data.dataset_registration import spec_file_of

        path = spec_file_of(dataset)
    except ReproError:
        path = None
    return (f"{dataset} (declared by {path})" if path is not None else
            f"{dataset} (a declared data set)")


def scale_words(scale, spec, dataset: str) -> str:
    """``quick (its description)``; when the run's data set is not the profile's own, the
    description (which names the profile's data set, "bundled bandai2-mini stand-in") is
    said to be the profile's and the data set used is named (issue 28)."""
    from repro.specs.scales import resolve_scale

    try:  # the profile as written: ``scale`` carries --dataset in place of its own
        own = resolve_scale(scale.name).dataset_for(spec)
    except ReproError:
        own = scale.dataset_for(spec)
    if dataset == own:
        return f"{scale.name} ({scale.description})"
    return (f"{scale.name} (the profile's sizes, made for {own}: \"{scale.description}\"; "
            f"this run's data set: {dataset})")


def table_footer(plan, evaluators: dict[str, Any], run_id: str | None,
            budgets: dict | None = None, trainings: list | None = None,
            kernels: dict | None = None, gate: dict | None = None) -> list[str]:
    """The lines under a table: the data set used, the scale, intervals, budgets, validation,
    evaluators, the real-data gate (:func:`repro.eval.gate.gate_line`), the column groups,
    protocol notes, unbuilt columns, kernels and the spec and run ids."""
    from repro.engine.evidence import budgets_text
    from repro.stats.intervals import INTERVAL_DESCRIPTIONS

    spec, scale = plan.spec, plan.scale
    lines = []
    if plan.dataset != spec.paper_dataset:
        lines.append(f"Data: {data_words(plan.dataset)} (the paper used {spec.paper_dataset}); "
                     "numbers are not comparable in absolute value, only in ordering and gaps.")
    sw = scale_words(scale, spec, plan.dataset)
    if plan.retrain:
        lines.append(f"Scale: {sw}; replicates: {len(plan.seeds)} "
                     f"independent trainings of each row's model, one sampling pass each (seeds "
                     f"{list(plan.seeds)}, --retrain); the intervals include training-seed "
                     "variance.")
    else:
        lines.append(f"Scale: {sw}; replicates: {len(plan.seeds)} "
                     f"sampling passes of one trained model per row (seeds {list(plan.seeds)}); "
                     "training-seed variance is not inside the intervals (--retrain puts it in).")
    lines.append(f"Paper ±: {INTERVAL_DESCRIPTIONS.get(spec.interval, spec.interval)}; ours: mean "
                 f"±(paper convention) [95% percentile bootstrap over replicates, "
                 f"B={scale.bootstrap_resamples}].")
    text = budgets_text((budgets or {}).values())
    if text or plan.budget != 1.0:
        factor = "" if plan.budget == 1.0 else f"epochs × {plan.budget:g} of the profile's; "
        lines.append(f"Training budget: {factor}against the paper's schedule on this data: "
                     + (text or "no trained row") + ". A claim contradicted "
                     "below the paper's budget reads 'not reproduced at this budget'.")
    held = sorted({(t["training"].get("n_train"), t["training"].get("n_validation"))
                   for t in trainings or [] if (t.get("training") or {}).get("n_validation")})
    if held:
        counts = ", ".join(f"{a} of {a + b}" for a, b in held)
        lines.append(f"Validation: the models trained on {counts} training items; the rest "
                     "(a per-class share of the training clips, the scale's "
                     "validation_fraction) only draws their learning curves (repro runs show).")
    for desc in evaluators.values():
        lines.append(f"Evaluator: {desc}")
    if run_id:
        from repro.eval.gate import gate_line

        lines.append(gate_line(gate))
    lines += group_lines(plan)
    from repro.eval.protocols import protocol_class

    notes = [getattr(protocol_class(b.protocol), "footer_note", None) for b in plan.bands
             if b.implemented]  # a band is implemented only when its protocol is importable
    lines += [n for i, n in enumerate(notes) if n and n not in notes[:i]]
    for b in plan.bands:
        if not b.implemented:
            lines.append(f"Columns {', '.join(b.columns)}: {b.reason}.")
    if run_id:
        from repro.kernels import describe

        lines.append(f"Kernels: {describe(kernels)}"
                     + ("" if (kernels or {}).get("mode") == "pinned" else
                        "; not comparable bit for bit with runs on other CPUs"))
    lines.append(f"Spec {spec.id} v{spec.version} [{spec.spec_hash[:12]}]"
                 + (f"; run {run_id}" if run_id else "; not run yet"))
    return lines


def gate_mark(gate: dict | None) -> str | None:
    """The short mark a table's title carries when its run was made under a non-standard
    real-data gate (the footer's gate line says the rest), else None."""
    if not gate or gate.get("standard", True):
        return None
    if not gate.get("enabled", True):
        return "NON-STANDARD GATE: off"
    m = gate.get("margin")
    return "NON-STANDARD GATE: margin " + ("-" if m is None else f"{float(m):.3f}")


#: longest error text a failed run's footer line quotes (``repro runs show`` has all of it)
ERROR_CHARS = 400


def one_line(text: str | None, limit: int = ERROR_CHARS) -> str:
    """``text`` on one line (whitespace runs as one space), cut to ``limit`` characters."""
    flat = " ".join(str(text or "").split())
    return flat if len(flat) <= limit else flat[:limit - 1] + "…"


def failure_line(failed: dict, shown: str | None) -> str:
    """The footer line of a table whose newest run did not finish: which run, when, why (one
    line), and which run the table shows instead (``shown``, or none)."""
    status = failed.get("status", "FAILED")
    why = one_line(failed.get("error") or failed.get("note") or "no error recorded")
    tail = (f"the table shows the newest finished run, {shown}" if shown else
            "no finished run to show: the cells are the paper's only")
    return (f"NEWEST RUN {status}: run {failed.get('run_id')} ({status.lower()} at "
            f"{failed.get('ended') or '?'}): {why}. {tail} (`repro runs show "
            f"{failed.get('run_id')}` has the whole record).")


def run_hint(table: str, scale: str, dataset: str | None = None) -> str:
    """The command that makes the run a message asks for: ``repro run TABLE --scale S``, with
    ``--dataset D`` when the caller named a data set (issue 28: the hint of ``repro strips``
    left it out, so it made a run on the profile's data set instead)."""
    import shlex

    cmd = ["repro", "run", table, "--scale", scale]
    if dataset:
        cmd += ["--dataset", dataset]
    return " ".join(shlex.quote(c) for c in cmd)


def no_run_message(table: str, scale: str, dataset: str | None, failed: dict | None) -> str:
    """``T: no finished run at scale S[ on D][; the newest run R FAILED at T: why]; run: ...``."""
    on = f" on {dataset}" if dataset else ""
    why = ""
    if failed is not None:
        why = (f"; the newest run, {failed.get('run_id')}, {failed.get('status')} at "
               f"{failed.get('ended') or '?'}: {one_line(failed.get('error') or failed.get('note'), 200)}")
    return f"{table}: no finished run at scale {scale}{on}{why}; run: {run_hint(table, scale, dataset)}"
