"""``repro runs ls | show | diff | reindex | export``: the run registry (folders + SQLite index),
and its copy into an MLflow tracking store."""

from __future__ import annotations

import argparse
import json
import math
from typing import Any

from cli.commands import command_group


def register(subparsers) -> None:
    sub = command_group(subparsers, "runs", "list, show and compare recorded runs",
                        "Run records under REPRO_HOME/runs, indexed in "
                        "REPRO_HOME/runs.sqlite.",
                        "runs_command")

    ls = sub.add_parser("ls", help="list runs, newest first")
    ls.add_argument("--table", help="only runs of this table (e.g. marionette/table3)")
    ls.add_argument("--status", help="only runs with this status (FINISHED, FAILED, ...)")
    ls.add_argument("--limit", type=int, default=None, help="at most this many")
    ls.add_argument("--json", action="store_true", help="machine-readable output")
    ls.set_defaults(func=_ls)

    show = sub.add_parser("show", help="one run: status, environment, jobs, cell values, "
                                       "learning curves")
    show.add_argument("run", help="run id, a unique prefix of one, or 'latest'")
    show.add_argument("--json", action="store_true",
                      help="run.json, values, summary and trainings as JSON")
    show.set_defaults(func=_show)

    diff = sub.add_parser("diff", help="compare runs side by side (runs as columns)")
    diff.add_argument("runs", nargs="+", metavar="RUN", help="two or more runs")
    diff.add_argument("--only-diff", action="store_true", help="only fields that differ")
    diff.add_argument("--json", action="store_true", help="machine-readable output")
    diff.set_defaults(func=_diff)

    ri = sub.add_parser("reindex", help="rebuild runs.sqlite from the run folders")
    ri.set_defaults(func=_reindex)

    ex = sub.add_parser("export", help="write runs to an MLflow tracking store (params, every "
                                       "replicate value, verdicts, table, pictures)",
                        description="Each run becomes one MLflow run, found again by its tag "
                                    "repro.run_id: exporting a run again changes nothing. "
                                    "Needs the mlflow extra (pip install 'repro[mlflow]'); "
                                    "docs/mlflow.md.")
    ex.add_argument("runs", nargs="*", metavar="RUN",
                    help="run ids, unique prefixes of them, or 'latest'")
    ex.add_argument("--all", action="store_true", help="every run that has ended")
    ex.add_argument("--mlflow", required=True, metavar="URI",
                    help="tracking store: a folder or file:/path (file store: new, empty "
                         "or a store already), http(s)://host:port (must answer within 5 s), "
                         "sqlite:///mlflow.db (needs the full mlflow)")
    ex.add_argument("--experiment", default=None,
                    help="MLflow experiment of new exports (default: the run's table id)")
    ex.add_argument("--no-pictures", action="store_true",
                    help="leave out the report page, plots and strips (record, table, values "
                         "still go)")
    ex.add_argument("--json", action="store_true", help="machine-readable output")
    ex.set_defaults(func=_export)


# ---------------------------------------------------------------------- helpers
def _fmt_num(v: Any) -> str:
    if v is None:
        return "—"
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        return f"{v:.4g}"
    return str(v)


def _cells(values: list[dict]) -> dict[tuple[str, str], dict[str, Any]]:
    """(row, column) -> mean, n, min, max over replicates (null values counted apart)."""
    acc: dict[tuple[str, str], list] = {}
    for v in values:
        acc.setdefault((str(v["row"]), str(v["column"])), []).append(v.get("value"))
    out = {}
    for rc, vals in acc.items():
        xs = [float(x) for x in vals if x is not None]
        out[rc] = {"mean": sum(xs) / len(xs) if xs else None, "n": len(xs),
                   "missing": len(vals) - len(xs), "min": min(xs) if xs else None,
                   "max": max(xs) if xs else None}
    return out


def _flatten(prefix: str, obj: Any, out: dict[str, str]) -> None:
    if isinstance(obj, dict) and obj:
        for k in sorted(obj):
            _flatten(f"{prefix}.{k}" if prefix else str(k), obj[k], out)
    else:
        out[prefix] = obj if isinstance(obj, str) else json.dumps(obj, sort_keys=True)


def _duration(run: dict) -> str:
    from datetime import datetime

    if not run.get("started") or not run.get("ended"):
        return "—"
    f = "%Y-%m-%dT%H:%M:%S.%fZ"
    try:
        s = (datetime.strptime(run["ended"], f) - datetime.strptime(run["started"], f))
    except ValueError:
        return "—"
    return f"{s.total_seconds():.1f} s"


def _esc(v: Any) -> str:
    from rich.markup import escape

    return escape("—" if v is None else str(v))


def _console():
    from rich.console import Console

    return Console()


# ---------------------------------------------------------------------- commands
def _ls(args: argparse.Namespace) -> int:
    from repro.store.index import RunIndex

    rows = RunIndex().list(table=args.table, status=args.status, limit=args.limit)
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    from rich.table import Table

    from repro.engine.footer import one_line

    t = Table()
    for col in ("run", "status", "table", "scale", "dataset", "created", "jobs (hit/new)",
                "values", "commit"):
        t.add_column(col)
    colour = {"FINISHED": "green", "FAILED": "red", "INTERRUPTED": "yellow", "RUNNING": "cyan"}
    for r in rows:
        st = r["status"]
        t.add_row(r["run_id"], f"[{colour.get(st, 'white')}]{st}[/]", _esc(r["table_id"]),
                  _esc(r["scale"]), _esc(r["dataset"]),
                  (r["created"] or "")[:19].replace("T", " "),
                  f"{r['n_jobs']} ({r['n_hits']}/{r['n_computed']})", str(r["n_values"]),
                  ((r["git_commit"] or "—")[:10] + ("+" if r["git_dirty"] else "")))
    con = _console()
    con.print(t)
    # each run that did not finish with its error (or note), one line each, under the table
    # (a column would fold to nothing in a narrow terminal); `runs show` has all of it
    for r in rows:
        text = r.get("error") or r.get("note")
        if text and r["status"] != "FINISHED":
            con.print(f"{r['run_id']} {r['status']}: {one_line(text, 300)}", highlight=False,
                      markup=False, soft_wrap=True)
    con.print(f"{len(rows)} runs")
    return 0


def _show(args: argparse.Namespace) -> int:
    from repro.store.runs import load_run, read_trainings, resolve_run

    rec = load_run(resolve_run(args.run))
    run = rec.run
    trainings = read_trainings(rec.path)
    if args.json:
        print(json.dumps({"run": run, "values": rec.values, "summary": rec.summary,
                          "trainings": trainings}, indent=2))
        return 0
    from rich.table import Table

    con = _console()
    con.print(f"[bold]{run['run_id']}[/]  {run['status']}  {_esc(run.get('table') or '')}")
    t = Table(show_header=False, box=None)
    t.add_column(style="dim")
    t.add_column()
    for k, v in _show_info(run):
        t.add_row(k, f"[red]{_esc(v)}[/]" if k == "error" else _esc(v))
    con.print(t)
    _show_jobs(con, run.get("jobs") or [])
    _show_cells(con, rec.values)
    _show_curves(con, trainings)
    if rec.summary is not None:
        con.print(f"summary: {rec.path / 'summary.json'}")
    return 0


def _show_info(run: dict) -> list[tuple[str, Any]]:
    """``runs show``'s (field, value) lines of a run: scale, spec, times, code, machine,
    packages, command, job counts, store keys, the real-data gate, error and note."""
    env = run.get("env") or {}
    git = run.get("git") or {}
    spec = run.get("spec") or {}
    info = [
        ("scale / dataset", f"{run.get('scale') or '—'} / {run.get('dataset') or '—'}"),
        ("spec", f"version {spec.get('version')}, hash {str(spec.get('hash'))[:12]}"),
        ("created / started / ended",
         f"{run.get('created')} / {run.get('started')} / {run.get('ended')}"),
        ("duration", _duration(run)),
        ("git", f"{git.get('commit')}" + (f" + changes {str(git.get('diff_sha256'))[:12]}"
                                          if git.get("dirty") else "") if git else "—"),
        ("device / dtype / threads",
         f"{env.get('device')} / {env.get('dtype')} / {env.get('threads')}"),
        ("host", f"{env.get('host')} (pid {env.get('pid')})"),
        ("kernels", _kernels_line(env.get("kernels"))),
        ("packages", ", ".join(f"{k} {v}" for k, v in (run.get("packages") or {}).items())),
        ("command", " ".join(run.get("command") or [])),
    ]
    counts: dict[str, int] = {}
    for j in run.get("jobs") or []:
        counts[j.get("status")] = counts.get(j.get("status"), 0) + 1
    info.append(("jobs", ", ".join(f"{n} {s}" for s, n in sorted(counts.items(),
                                                              key=lambda kv: str(kv[0])))
                 or "—"))
    keys = run.get("keys") or {}
    info.append(("store keys", f"{len(keys.get('read') or [])} read, "
                               f"{len(keys.get('written') or [])} written"))
    gate = (run.get("extra") or {}).get("gate")
    if gate:
        from repro.eval.gate import gate_line

        info.append(("real-data gate", gate_line(gate)))
    if run.get("error"):
        info.append(("error", run["error"]))
    if run.get("note"):
        info.append(("note", run["note"]))
    return info


def _show_jobs(con, jobs: list[dict]) -> None:
    """``runs show``'s table of the run's jobs (none printed when it has none)."""
    if not jobs:
        return
    from rich.table import Table

    jt = Table(title="jobs", title_justify="left")
    for col in ("job", "kind", "status", "seconds", "key"):
        jt.add_column(col)
    for j in jobs:
        jt.add_row(_esc(j.get("label") or j.get("kind")), _esc(j.get("kind")),
                   _esc(j.get("status")),
                   _fmt_num(j.get("seconds")), str(j.get("key"))[:12])
    con.print(jt)


def _show_cells(con, values: list[dict]) -> None:
    """``runs show``'s table of each cell's mean, count, min and max over replicates (none
    printed when the run has no value)."""
    cells = _cells(values)
    if not cells:
        return
    from rich.table import Table

    ct = Table(title="cells (mean over replicates)", title_justify="left")
    for col in ("row", "column", "mean", "n", "min", "max"):
        ct.add_column(col, justify="left" if col in ("row", "column") else "right")
    for (r, c), s in cells.items():
        ct.add_row(_esc(r), _esc(c), _fmt_num(s["mean"]), str(s["n"]), _fmt_num(s["min"]),
                   _fmt_num(s["max"]))
    con.print(ct)


def _show_curves(con, trainings: list[dict]) -> None:
    """``runs show``'s learning curves, one block per training (none printed without)."""
    if not trainings:
        return
    from repro.report.curves import format_learning_curve

    con.print("[bold]Learning curves[/]")
    for t in trainings:
        con.print(f"{_esc(t.get('row'))}  ({_esc(t.get('method'))}, seed {_esc(t.get('seed'))}, "
                  f"job {str(t.get('job'))[:12]})")
        for line in format_learning_curve(t.get("training") or {}):
            con.print("  " + line, markup=False, highlight=False, soft_wrap=True)


def _kernels_line(rec) -> str:
    from repro.kernels import describe

    return describe(rec)


def diff_rows(records) -> list[dict[str, Any]]:
    """Rows of ``repro runs diff``: {section, field, values (one per run), differs}."""
    sections: dict[str, list[dict[str, str]]] = {"config": [], "environment": [], "cells": []}
    for rec in records:
        run = rec.run
        cfg: dict[str, str] = {}
        _flatten("", run.get("config") or {}, cfg)
        env: dict[str, str] = {}
        _flatten("", {"status": run.get("status"), "table": run.get("table"),
                      "scale": run.get("scale"), "dataset": run.get("dataset"),
                      "spec": run.get("spec"), "git": run.get("git"),
                      "env": {k: v for k, v in (run.get("env") or {}).items()
                              if k not in ("pid", "pid_start")},
                      "packages": run.get("packages"), "duration": _duration(run)}, env)
        cells = {f"{r} | {c}": (f"{_fmt_num(s['mean'])} (n={s['n']})" if s["n"] else "—")
                 for (r, c), s in _cells(rec.values).items()}
        sections["config"].append(cfg)
        sections["environment"].append(env)
        sections["cells"].append(cells)
    rows = []
    for section, per_run in sections.items():
        names: list[str] = []
        for d in per_run:
            names.extend(n for n in d if n not in names)
        if section != "cells":
            names.sort()
        for n in names:
            vals = [d.get(n) for d in per_run]
            rows.append({"section": section, "field": n, "values": vals,
                         "differs": len({json.dumps(v) for v in vals}) > 1})
    return rows


def _diff(args: argparse.Namespace) -> int:
    from repro.errors import ConfigError
    from repro.store.runs import load_run, resolve_run

    if len(args.runs) < 2:
        raise ConfigError("runs diff needs at least two runs")
    records = [load_run(resolve_run(r)) for r in args.runs]
    rows = diff_rows(records)
    if args.only_diff:
        rows = [r for r in rows if r["differs"]]
    if args.json:
        print(json.dumps({"runs": [r.run_id for r in records], "rows": rows}, indent=2))
        return 0
    from rich.table import Table

    t = Table()
    t.add_column("section", style="dim")
    t.add_column("field")
    for r in records:
        t.add_column(r.run_id)
    for row in rows:
        vals = [_esc(v) for v in row["values"]]
        if row["differs"]:
            vals = [f"[yellow]{v}[/]" for v in vals]
        t.add_row(row["section"], _esc(row["field"]), *vals)
    con = _console()
    con.print(t)
    n = sum(1 for r in rows if r["differs"])
    con.print(f"{n} fields differ" + ("" if args.only_diff else f" of {len(rows)}"))
    return 0


def _reindex(args: argparse.Namespace) -> int:
    from repro.store.index import RunIndex

    idx = RunIndex()
    n = idx.reindex()
    print(f"indexed {n} runs into {idx.path}")
    return 0


def _export(args: argparse.Namespace) -> int:
    import sys

    from repro.errors import ConfigError
    from repro.exporters.mlflow_runs import export_runs

    if bool(args.runs) == bool(args.all):
        raise ConfigError("runs export: name the runs (RUN...) or give --all, not both")
    refs: list = list(args.runs)
    if args.all:
        from repro.store.runs import TERMINAL, load_run, reconcile_stale, run_dirs

        from repro.errors import DataError

        for d in run_dirs():
            try:  # the whole record (run.json, values, summary) read as the export will
                reconcile_stale(d)
                if load_run(d).status in TERMINAL:
                    refs.append(d)
            except DataError as e:  # one damaged record does not stop the others
                print(f"repro: warning: skipping run {d.name}: {e}", file=sys.stderr)
        if not refs:
            raise ConfigError("runs export --all: no run has ended yet")
    out = export_runs(refs, args.mlflow, experiment=args.experiment,
                      pictures=not args.no_pictures)
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    for r in out:
        what = "new MLflow run" if r["created"] else "MLflow run"
        print(f"{r['run']} -> {what} {r['mlflow_run']} in experiment {r['experiment']!r}: "
              f"{r['params']} params ({r['new_params']} new), {r['metric_values']} metric "
              f"values ({r['new_metric_values']} new), {r['tags']} tags, {r['artifacts']} "
              "artifact files")
        for n in r["notes"]:
            print(f"repro: {r['run']}: {n}", file=sys.stderr)
    print(f"repro: {len(out)} run(s) exported to {out[0]['uri'] if out else args.mlflow}",
          file=sys.stderr)
    return 0
