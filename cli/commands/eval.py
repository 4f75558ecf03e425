"""``repro eval classifier | real``: the evaluation classifiers and the real-data rows
(see docs/evaluators.md)."""

from __future__ import annotations

import json
import sys

from cli.commands import command_group, gate_options, int_at_least

KINDS = ("a2m_gru", "uestc_gru", "multiact_gru", "transformer")


def register(subparsers) -> None:
    sub = command_group(subparsers, "eval", "evaluation classifiers and the real-data rows",
                        "Train/load evaluation classifiers; compute the real rows.",
                        "eval_command")

    def common(sp):
        sp.add_argument("--dataset", required=True, help="data set (bandai2, bandai2-mini, ...)")
        sp.add_argument("--scale", default=None, choices=("quick", "medium", "paper", "converged"),
                        help="scale profile (default: quick for bandai2-mini, else medium)")
        sp.add_argument("--kind", default="a2m_gru", choices=KINDS, help="recogniser (default a2m_gru)")
        sp.add_argument("--heading", default=None, choices=("raw", "yaw_augment", "remove"),
                        help="heading mode (default: the scale's, raw = A2M/ODMO convention)")
        sp.add_argument("--train-seed", type=int_at_least(0, "a seed must be >= 0, got {v}"),
                        default=0,
                        help="classifier training seed (default 0)")
        sp.add_argument("--json", action="store_true", help="machine-readable output")

    pc = sub.add_parser("classifier", help="train or load a classifier; test accuracy + confusion")
    common(pc)
    pc.add_argument("--force", action="store_true", help="retrain even if stored")
    pc.set_defaults(func=_classifier)

    pr = sub.add_parser("real", help="the Real rows (FID, Acc, Div, MModality, n-APD) + gate")
    common(pr)
    pr.add_argument("--replicates", type=int, default=None, help="replicates (default: the scale's)")
    pr.add_argument("--seed", type=int, default=0, help="seed of the real draws (default 0)")
    gate_options(pr)
    pr.set_defaults(func=_real)


def _scale(args) -> str:
    return args.scale or ("quick" if args.dataset == "bandai2-mini" else "medium")


def _progress_callback(total: int):
    """A training-progress callback: a rich bar on a terminal, else a line every ~10%."""
    if sys.stderr.isatty():
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn, \
            TimeRemainingColumn

        prog = Progress("[progress.description]{task.description}", BarColumn(),
                        MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn(),
                        "{task.fields[info]}", console=Console(stderr=True), transient=True)
        task = prog.add_task("training evaluator (epochs)", total=total, info="")

        def cb(epoch: int, rec: dict) -> None:
            if not prog.live.is_started:
                prog.start()
            prog.update(task, completed=epoch + 1,
                        info=f"loss {rec.get('loss', float('nan')):.3f} acc {rec.get('acc', float('nan')):.3f}")
            if epoch + 1 >= total:
                prog.stop()

        return cb
    step = max(1, total // 10)

    def cb(epoch: int, rec: dict) -> None:
        if (epoch + 1) % step == 0 or epoch + 1 == total:
            print(f"repro: evaluator epoch {epoch + 1}/{total}: loss {rec.get('loss', 0):.4f} "
                  f"train acc {rec.get('acc', 0):.3f}", file=sys.stderr, flush=True)

    return cb


def _get(args):
    from repro.eval.provider import get_evaluator
    from repro.eval.settings import resolve_settings

    scale = _scale(args)
    settings = resolve_settings(scale, {"heading": args.heading} if args.heading else None)
    cb = _progress_callback(settings.train.epochs)
    return get_evaluator(args.dataset, args.kind, scale, seed=args.train_seed, settings=settings,
                         on_epoch=cb, force=getattr(args, "force", False)), scale


def _confusion_table(test: dict):
    from rich.table import Table

    names = test["label_names"]
    t = Table(title="confusion matrix (rows: label, columns: prediction)", title_justify="left")
    t.add_column("label", no_wrap=True)
    for i, _ in enumerate(names):
        t.add_column(str(i), justify="right")
    t.add_column("recall", justify="right")
    for i, row in enumerate(test["confusion"]):
        n = sum(row)
        t.add_row(str(i), *[str(v) if v else "." for v in row], f"{row[i] / n:.3f}" if n else "-")
    legend = "classes: " + ", ".join(f"{i} {n}" for i, n in enumerate(names))
    return t, legend


def _classifier(args) -> int:
    ev, scale = _get(args)
    test = ev.meta.get("test", {})
    tr = ev.meta.get("training", {})
    if args.json:
        out = {"dataset": args.dataset, "scale": scale, "kind": ev.kind,
               "fingerprint": ev.fingerprint, "describe": ev.describe(),
               "store_key": ev.meta.get("store_key"), "store_hit": ev.meta.get("store_hit"),
               "architecture": ev.meta.get("architecture"), "input": ev.meta.get("input"),
               "training": {k: v for k, v in tr.items() if k != "loss_curve"}, "test": test}
        print(json.dumps(out, indent=2, sort_keys=True))
        return 0
    from rich.console import Console

    con = Console()
    con.print(ev.describe(), highlight=False, markup=False)
    con.print(f"fingerprint {ev.fingerprint}", highlight=False, markup=False)
    origin = "loaded from the store" if ev.meta.get("store_hit") else \
        f"trained now in {tr.get('seconds', 0):.0f} s"
    con.print(f"{origin}; {tr.get('epochs')} epochs, final train loss {tr.get('final_loss', 0):.4f}",
              highlight=False, markup=False)
    con.print(f"real test split: {test['n_windows']} windows of {test['window']} frames "
              f"(stride {test['stride']}) from {test['n_clips']} clips", highlight=False, markup=False)
    con.print(f"top-1 accuracy {test['top1']:.4f}   top-{test['top5_k']} accuracy {test['top5']:.4f}",
              highlight=False, markup=False)
    table, legend = _confusion_table(test)
    con.print(table)
    con.print(legend, highlight=False, markup=False)
    return 0


def _fmt(x, nd=4):
    return "-" if x is None else f"{x:.{nd}f}"


def _real(args) -> int:
    from repro.eval.gate import apply_gate, gate_line, gate_summary, raise_if_failed, resolve_gate
    from repro.eval.real import real_rows

    setting = resolve_gate(args.dataset, margin=args.gate_margin, no_gate=args.no_gate)
    ev, scale = _get(args)
    rows = real_rows(args.dataset, scale, args.replicates, args.seed, kind=args.kind, evaluator=ev)
    check = apply_gate(rows, ev.meta.get("test"), setting)  # the one gate `repro run` applies
    reasons = check["reasons"]
    record = gate_summary(setting, [check], check["standard_margin"])
    rows["gate"].update({k: record[k] for k in ("enabled", "margin", "standard_margin",
                                                "enabled_from", "margin_from", "standard",
                                                "relaxed")})
    rows["gate"]["passed"] = not reasons
    rows["gate"]["reasons"] = reasons
    if args.json:
        print(json.dumps(rows, indent=2, sort_keys=True))
    else:
        from rich.console import Console
        from rich.table import Table

        con = Console()
        t = Table(title=f"Real rows: {args.dataset}, {rows['replicates']} replicates x "
                  f"{rows['per_class']} windows/class ({rows['window']} frames)",
                  title_justify="left")
        for c in ("metric", "mean", f"± ({rows['intervals']['pm']})",
                  f"{rows['intervals']['bootstrap']} 95% CI", "sd"):
            t.add_column(c, justify="left" if c == "metric" else "right")
        for name, m in rows["rows"]["real"].items():
            nd = 2 if name == "n_apd" else 4
            t.add_row(name, _fmt(m["mean"], nd), _fmt(m["pm"], nd),
                      f"[{_fmt(m['ci'][0], nd)}, {_fmt(m['ci'][1], nd)}]", _fmt(m["sd"], nd))
        con.print(t)
        con.print(rows["evaluator"]["describe"], highlight=False, markup=False)
        con.print(f"evaluator fingerprint {rows['evaluator']['fingerprint']}", highlight=False, markup=False)
        con.print("gate: passed" if not reasons else "gate: FAILED", highlight=False, markup=False)
        con.print(gate_line(record), highlight=False, markup=False)
    raise_if_failed(check)
    return 0
