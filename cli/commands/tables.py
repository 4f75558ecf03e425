"""``repro list | plan | run | sweep | show | rescore | verify``: tables from spec to report."""

from __future__ import annotations

import argparse
import functools
import json
import sys

from cli.commands import gate_options, int_at_least, run_ref

SCALES = ("quick", "medium", "paper", "converged")


def output_format(text: str) -> str:
    """argparse type: a report format, checked before anything is computed."""
    from repro.report import FORMATS

    if text not in FORMATS:
        raise argparse.ArgumentTypeError(f"unknown format {text!r} (choose from "
                                         f"{', '.join(FORMATS)})")
    return text


def device_option(text: str) -> str:
    """argparse type: a device name (cpu, cuda, cuda:N), checked before anything is computed."""
    from repro.specs.scales import device_problem

    problem = device_problem(text)
    if problem is not None:
        raise argparse.ArgumentTypeError(problem)
    return text


def _common(p: argparse.ArgumentParser) -> None:
    _claim_option(p)
    p.add_argument("--scale", default="quick", help="quick | medium | paper (default: quick)")
    p.add_argument("--dataset", default=None, help="override the scale profile's data set")
    p.add_argument("--device", default=None, type=device_option,
                   help="cpu | cuda | cuda:N: where train and generate jobs compute (default: "
                   "the scale profile's device; paper's is cuda); part of every job key")


def _claim_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--claim-id", action="store_true",
                   help="let a spec file given by path use the id of a table under tables/ "
                   "(its runs then count as that table's)")


def _on_device(computes: bool):
    """Decorator of a table command: run it with ``--device`` overriding every scale profile's
    device (:func:`repro.specs.scales.device_override`); a command that ``computes`` first
    checks that this machine has the device (one clear error, exit 2, before any work), unless
    its jobs run on Ray (``--executor ray``): the GPUs are then the cluster's, checked against
    its resources before a task is submitted (:class:`~repro.engine.ray_executor.RayBackend`),
    and a driver without a GPU may run a CUDA table there."""
    def wrap(cmd):
        @functools.wraps(cmd)
        def run(args) -> int:
            from repro.engine.runner import claiming_ids
            from repro.specs.scales import device_override, require_device, resolve_scale

            with device_override(args.device), claiming_ids(getattr(args, "claim_id", False)):
                if computes and getattr(args, "executor", "local") != "ray":
                    require_device(resolve_scale(args.scale, args.dataset))
                return cmd(args)
        return run
    return wrap


def _positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    import math

    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return v


def _fast_kernels_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--fast-kernels", action="store_true",
                   help="keep this CPU's fastest kernel paths instead of the portable pin "
                   "(job keys and the run record say so; verify refuses such runs against "
                   "pinned baselines; docs/engine.md)")


def _computing_options(p: argparse.ArgumentParser, func) -> None:
    """The tail of a computing command (``run``, ``sweep``): ``--quiet``, the gate options,
    ``--fast-kernels``, then its handler ``func``."""
    p.add_argument("--quiet", action="store_true", help="no progress: neither bars (stdout "
                   "a terminal) nor progress lines on stderr (stdout redirected)")
    gate_options(p)
    _fast_kernels_option(p)
    p.set_defaults(func=func)


def _retrain_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--retrain", action="store_true",
                   help="train one model per replicate (training seed = replicate seed), so the "
                   "intervals include training-seed variance (R x the training cost)")


def register(sub) -> None:
    _register_list(sub)
    _register_plan(sub)
    _register_run(sub)
    _register_sweep(sub)
    _register_show(sub)
    _register_rescore(sub)
    _register_verify(sub)


def _register_list(sub) -> None:
    """``repro list``: every table spec with its state."""
    p = sub.add_parser("list", help="every table spec with its state")
    p.add_argument("--scale", default="quick")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_list)


def _register_plan(sub) -> None:
    """``repro plan``: what a run would do, without computing."""
    p = sub.add_parser("plan", help="what a run would do: jobs, keys, cache hits, and why")
    p.add_argument("table")
    _common(p)
    p.add_argument("--why", action="store_true", help="for a miss, say which part of the key changed")
    p.add_argument("--seeds", default=None, help="replicate seeds, e.g. 0-9 or 0,3,7 (default: the scale's)")
    _retrain_option(p)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_plan)


def _register_run(sub) -> None:
    """``repro run``: compute and print one or more tables."""
    p = sub.add_parser("run", help="train/load, sample, measure and print one or more tables",
                       description="Several tables run as one job graph (shared jobs once; "
                       "--jobs N overlaps their trainings); each gets its own run record.")
    p.add_argument("tables", nargs="+", metavar="TABLE")
    _common(p)
    p.add_argument("--jobs", type=int_at_least(1), default=1,
                   help="jobs run side by side (default 1); each computes with the scale's "
                   "`threads` (1), so N up to the core count; results do not depend on N")
    p.add_argument("--force", nargs="?", const=True, default=None, metavar="KIND",
                   help="recompute everything, or only jobs of KIND (train, generate, measure, ...)")
    p.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="where the graph's jobs run: local (this machine, --jobs side by side) "
                   "or ray (a Ray cluster; pip install 'repro[ray]'); same keys, same numbers")
    p.add_argument("--address", default=None, metavar="ADDR",
                   help="with --executor ray: the cluster (HOST:PORT of the head node, "
                   "ray://HOST:PORT with ray[client], auto), checked to answer within 5 s "
                   "before any work; default: RAY_ADDRESS, else a Ray started here")
    p.add_argument("--seeds", default=None, help="replicate seeds, e.g. 0-9 or 0,3,7 (default: the "
                   "scale's); the first is also the training seed")
    _retrain_option(p)
    p.add_argument("--format", default="term", type=output_format,
                   help="term | md | latex | html | json | csv")
    _computing_options(p, cmd_run)


def _register_sweep(sub) -> None:
    """``repro sweep``: a table rerun along a budget or evaluator-seed axis."""
    p = sub.add_parser("sweep", help="rerun a table at several training budgets or with "
                       "several evaluator seeds; cells and verdicts against the axis",
                       description="Each point is an ordinary run (cached jobs reused; the x1 "
                       "point and evaluator seed 0 are the plain run). The sweep record goes to "
                       "REPRO_HOME/sweeps/.")
    p.add_argument("table")
    _common(p)
    axis = p.add_mutually_exclusive_group(required=True)
    axis.add_argument("--budget", default=None, metavar="FACTORS",
                      help="epoch multipliers, e.g. 0.5,1,2,4; add 'plateau' for a point "
                      "trained until each model's validation curve stops improving (the largest "
                      "factor's epochs as the cap)")
    axis.add_argument("--evaluator-seeds", default=None, metavar="SEEDS",
                      help="evaluator training seeds, e.g. 0-2 or 0,1,2")
    p.add_argument("--jobs", type=int_at_least(1), default=1, help="jobs run side by side")
    p.add_argument("--seeds", default=None, help="replicate seeds (default: the scale's)")
    _retrain_option(p)
    p.add_argument("--format", default="term", choices=("term", "md", "json"),
                   help="term | md | json (default term)")
    _computing_options(p, cmd_sweep)


def _register_show(sub) -> None:
    """``repro show``: a table from a stored run, without computing."""
    p = sub.add_parser("show", help="print a table from its newest run (no computing)")
    p.add_argument("table")
    _common(p)
    p.add_argument("--run", default=None, type=run_ref,
                   help="a run id (default: the newest finished run)")
    p.add_argument("--format", default="term", type=output_format,
                   help="term | md | latex | html | json | csv")
    p.set_defaults(func=cmd_show)


def _register_rescore(sub) -> None:
    """``repro rescore``: metrics and intervals recomputed from stored samples."""
    p = sub.add_parser("rescore", help="recompute metrics and intervals from stored samples")
    p.add_argument("table")
    _common(p)
    p.add_argument("--format", default="term", type=output_format)
    gate_options(p)
    _fast_kernels_option(p)
    p.set_defaults(func=cmd_rescore)


def _register_verify(sub) -> None:
    """``repro verify``: the newest run against a committed baseline."""
    p = sub.add_parser("verify", help="compare the newest run with a committed baseline (exit 1 on drift)")
    p.add_argument("tables", nargs="+", metavar="TABLE")
    _common(p)
    p.add_argument("--baseline", required=True, help="baseline folder, e.g. tables/baselines/quick")
    p.add_argument("--update", action="store_true", help="write the baseline from the newest run")
    p.add_argument("--tolerance", type=_positive_float, default=None, metavar="K",
                   help="compare across hosts or unpinned runs: a cell passes within K x the "
                   "spread of training seeds (the newest run's interval when made with "
                   "--retrain; else sampling spread), verdicts one step apart pass; off by "
                   "default (docs/engine.md)")
    p.set_defaults(func=cmd_verify)


def cmd_list(args) -> int:
    from repro.engine.runner import latest_run
    from repro.specs.load import load_all

    rows = []
    for sid, spec in sorted(load_all().items()):
        run = latest_run(sid, args.scale)
        rows.append({"table": sid, "title": spec.title, "protocol": spec.protocol,
                     "rows": len(spec.rows), "reported": spec.n_reported(),
                     "last_run": run.name if run else None})
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"tables (last run at scale {args.scale})", title_justify="left")
    for h in ("table", "title", "protocol", "rows", "reported cells", "last run"):
        t.add_column(h)
    for r in rows:
        t.add_row(r["table"], r["title"], r["protocol"], str(r["rows"]), str(r["reported"]),
                  r["last_run"] or "-")
    Console(width=140).print(t)
    return 0


@_on_device(computes=False)
def cmd_plan(args) -> int:
    from repro.engine.runner import plan_table
    from repro.engine.table_plan import parse_seeds

    entries = plan_table(args.table, scale=args.scale, dataset=args.dataset, why=args.why,
                         seeds=parse_seeds(args.seeds) if args.seeds is not None else None,
                         retrain=args.retrain)
    if args.json:
        print(json.dumps(entries, indent=2))
        return 0
    n_hit = sum(1 for e in entries if e["cached"])
    n_job = sum(1 for e in entries if e["kind"] != "row")
    for e in entries:
        mark = "cached" if e["cached"] else ("-" if e["kind"] == "row" else "run")
        line = f"{mark:7} {e['kind']:13} {e['job']:40} {e['key']}"
        if e.get("why") and (args.why or e["kind"] == "row"):
            line += f"  ({e['why']})"
        print(line)
    print(f"{n_job} jobs, {n_hit} cached, {n_job - n_hit} to run")
    return 0


@_on_device(computes=True)
def cmd_run(args) -> int:
    from repro.engine.runner import run_tables, table_view
    from repro.engine.table_plan import parse_seeds
    from repro.report import render

    rc = 0
    runs = run_tables(args.tables, scale=args.scale, dataset=args.dataset, jobs=args.jobs,
                      force=args.force, seeds=parse_seeds(args.seeds) if args.seeds is not None
                      else None, retrain=args.retrain, backend=executor_backend(args),
                      gate_margin=args.gate_margin, no_gate=args.no_gate, **progress_mode(args))
    for plan, summary, run_id in runs:
        name = plan.spec.id
        counts = summary.get("counts", {})
        print(f"repro: {plan.spec.id}: run {run_id} "
              f"({', '.join(f'{v} {k}' for k, v in sorted(counts.items())) or 'nothing to compute'})",
              file=sys.stderr)
        view = table_view(name, scale=args.scale, dataset=args.dataset, run=run_id)
        sys.stdout.write(render(view, args.format))
        if plan.data_missing:  # the table still prints (the paper's values), then one line
            print(f"repro: error: {plan.spec.id}: data set {plan.dataset!r}: {plan.data_missing}",
                  file=sys.stderr)
            rc = max(rc, 2)
            continue
        failed = [r for r, st in summary.get("rows", {}).items() if st.get("status") == "failed"]
        if failed:
            print(f"repro: {plan.spec.id}: rows failed: {', '.join(failed)}", file=sys.stderr)
            rc = max(rc, 1)
    return rc


def progress_mode(args) -> dict:
    """How a computing command shows progress: ``--quiet`` nothing; stdout a terminal: today's
    rich bars on stderr (when stderr is one too); stdout redirected (a log, a pipe): plain
    progress lines on stderr, one per finished job with the elapsed time (issue 28: a
    redirected run printed nothing for 9 minutes)."""
    if args.quiet:
        return {"progress": False, "lines": False}
    if sys.stdout.isatty():
        return {"progress": sys.stderr.isatty(), "lines": False}
    return {"progress": False, "lines": True}


@_on_device(computes=True)
def executor_backend(args):
    """The back end ``--executor`` / ``--address`` ask for: None (this machine) or a
    :class:`~repro.engine.ray_executor.RayBackend`, made before anything is computed (Ray is
    imported only then; a missing install is one line, exit 2)."""
    from repro.errors import ConfigError

    if args.executor != "ray":
        if args.address is not None:
            raise ConfigError("--address names a Ray cluster: it needs --executor ray")
        return None
    from repro.engine.ray_executor import RayBackend

    return RayBackend(args.address)


def cmd_sweep(args) -> int:
    from repro.engine.sweep import parse_factors, render_sweep, sweep_table
    from repro.engine.table_plan import parse_seeds

    if args.budget is not None:
        axis, points = "budget", list(parse_factors(args.budget))
    else:
        axis, points = "evaluator_seed", list(parse_seeds(args.evaluator_seeds))
    record = sweep_table(args.table, axis=axis, points=points, scale=args.scale,
                         dataset=args.dataset, jobs=args.jobs,
                         seeds=parse_seeds(args.seeds) if args.seeds is not None else None,
                         retrain=args.retrain, gate_margin=args.gate_margin,
                         no_gate=args.no_gate, **progress_mode(args))
    print(f"repro: sweep record {record['path']}/sweep.json", file=sys.stderr)
    if args.format == "json":
        print(json.dumps(record, indent=1, sort_keys=True))
    else:
        sys.stdout.write(render_sweep(record, args.format))
    return 0


@_on_device(computes=False)
def cmd_show(args) -> int:
    from repro.engine.runner import table_view
    from repro.report import render

    view = table_view(args.table, scale=args.scale, dataset=args.dataset, run=args.run)
    sys.stdout.write(render(view, args.format))
    return 0


@_on_device(computes=True)
def cmd_rescore(args) -> int:
    from repro.engine.runner import latest_run, run_table, table_scale, table_spec, table_view
    from repro.errors import ConfigError
    from repro.report import render

    spec, sc = table_spec(args.table), table_scale(args.scale, args.dataset)
    ds = args.dataset or sc.dataset_for(spec)
    if latest_run(spec.id, sc.name, ds) is None:  # nothing stored to re-measure: say so, train nothing
        from repro.engine.footer import run_hint

        raise ConfigError(f"{spec.id}: no earlier run at scale {sc.name} on {ds} to rescore; "
                          f"run: {run_hint(spec.id, sc.name, args.dataset)}")
    _, _, run_id = run_table(args.table, scale=args.scale, dataset=args.dataset,
                             force="measure", progress=sys.stderr.isatty(),
                             gate_margin=args.gate_margin, no_gate=args.no_gate)
    sys.stdout.write(render(table_view(args.table, scale=args.scale, dataset=args.dataset,
                                       run=run_id), args.format))
    return 0


@_on_device(computes=False)
def cmd_verify(args) -> int:
    import json as _json
    from pathlib import Path

    from repro.engine.baselines import write_baseline
    from repro.engine.runner import latest_run, table_scale, table_spec, verify_table
    from repro.errors import ConfigError
    from repro.store.runs import read_run_json

    failed = False
    for name in args.tables:
        spec = table_spec(name)
        if args.update:
            sc = table_scale(args.scale, args.dataset)
            ds = args.dataset or sc.dataset_for(spec)
            path = latest_run(spec.id, sc.name, ds, retrain=False)  # baselines: one model per row
            if path is None:
                raise ConfigError(f"no finished run of {spec.id} at scale {sc.name} to write a baseline from")
            summary = _json.loads((path / "summary.json").read_text())
            kernels = (read_run_json(path).get("env") or {}).get("kernels")
            if (kernels or {}).get("mode") != "pinned":
                raise ConfigError(f"{spec.id}: run {path.name} was not made under the pinned "
                                  "kernel paths; a committed baseline must be (rerun without "
                                  "--fast-kernels)")
            out = write_baseline(Path(args.baseline), summary, scale=sc.name, dataset=ds,
                                 run_id=path.name, kernels=kernels)
            print(f"repro: wrote {out}")
            continue
        problems, notes = verify_table(name, args.baseline, scale=args.scale,
                                       dataset=args.dataset, tolerance=args.tolerance)
        for line in notes:
            print(f"repro: {spec.id}: {line}")
        if problems:
            failed = True
            print(f"repro: {spec.id}: {len(problems)} problem(s) against the baseline:")
            for p in problems:
                print(f"  {p}")
        else:
            print(f"repro: {spec.id}: matches the baseline")
    return 1 if failed else 0
