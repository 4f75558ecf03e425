"""``repro data prepare | info | bundle``: the data sets (see docs/data.md)."""

from __future__ import annotations

import argparse
import json
import sys

from cli.commands import command_group


def register(subparsers) -> None:
    sub = command_group(subparsers, "data", "prepare, describe and bundle data sets",
                        "Prepare, describe and bundle data sets.",
                        "data_command")

    pp = sub.add_parser("prepare", help="parse a data set's source into the local cache")
    pp.add_argument("name", help="data set name (bandai2) or sequence view (bandai2-seq, "
                    "bandai2-seq-mini)")
    pp.add_argument("--source", help="the upstream archive or an extracted folder "
                    "(default: ../shared/data/bandai-namco-2/ or $REPRO_DATA)")
    pp.add_argument("--workers", type=int, default=2, help="parser threads (0: in the main thread)")
    pp.add_argument("--force", action="store_true", help="rebuild even if the cache is valid")
    pp.add_argument("--json", action="store_true", help="print the result as JSON")
    pp.set_defaults(func=_prepare)

    pi = sub.add_parser("info", help="counts, classes, styles, lengths of a data set")
    pi.add_argument("name", help="data set name (see `repro data info --list`)", nargs="?")
    pi.add_argument("--json", action="store_true", help="machine-readable output")
    pi.add_argument("--list", action="store_true", help="list registered data sets and status")
    pi.set_defaults(func=_info)

    pc = sub.add_parser("check", help="validate data-set spec files (or print their JSON "
                        "Schema)")
    pc.add_argument("spec", nargs="*", help="data-set spec files (.toml)")
    pc.add_argument("--schema", action="store_true", help="print the JSON Schema of a spec")
    pc.set_defaults(func=_check_spec)

    pb = sub.add_parser("bundle", help="rebuild the bundled bandai2-mini subset")
    pb.add_argument("--source", help="bandai2 archive or folder (default: as for prepare)")
    pb.add_argument("--out", help="output folder (default: the package's repro/data/bundled/)")
    pb.add_argument("--workers", type=int, default=2, help="parser threads for prepare")
    pb.set_defaults(func=_bundle)


def _default_source(given: str | None):
    from pathlib import Path

    from repro.errors import MissingDataError
    from repro.paths import BANDAI_ARCHIVE_NAME, find_bandai_archive, shared_data_dir

    if given:
        return Path(given)
    found = find_bandai_archive()
    if found is None:
        raise MissingDataError(f"no --source given and {BANDAI_ARCHIVE_NAME} is not in "
                               f"{shared_data_dir()} (set REPRO_DATA or pass --source)")
    return found


def _progress():
    """A rich progress callback on stderr when it is a terminal, else ``None``."""
    if not sys.stderr.isatty():
        return None, None
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn

    prog = Progress("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
                    TimeElapsedColumn(), console=Console(stderr=True), transient=True)
    task = prog.add_task("parsing clips", total=None)

    def cb(done: int, total: int | None) -> None:
        prog.update(task, completed=done, total=total)

    return prog, cb


def _prepare_bandai(name: str, source, workers: int, force: bool):
    from repro.data.bandai import BANDAI2_CARD, prepare_bandai2
    from repro.errors import ConfigError

    if name != "bandai2":
        raise ConfigError(f"`repro data prepare` knows bandai2, not {name!r}")
    prog, cb = _progress()
    if prog is not None:
        with prog:
            return prepare_bandai2(source, card=BANDAI2_CARD, workers=workers, force=force,
                                   progress=cb)
    return prepare_bandai2(source, card=BANDAI2_CARD, workers=workers, force=force)


def _prepare(args: argparse.Namespace) -> int:
    from repro.data.registry import get_entry
    from repro.data.sequence_views import SEQUENCE_VIEWS
    from repro.errors import ConfigError

    if args.name in SEQUENCE_VIEWS:
        return _prepare_view(args)
    from repro.data.dataset_registration import is_spec_path, spec_file_of

    spec_file = args.name if is_spec_path(args.name) else spec_file_of(args.name)
    if spec_file is not None:
        return _prepare_spec(args, spec_file)
    entry = get_entry(args.name)
    if args.name == "bandai2-mini":
        raise ConfigError("bandai2-mini is bundled with the package; rebuild it with "
                          "`repro data bundle`")
    if args.name != "bandai2":
        st = entry.status()
        raise ConfigError(f"{args.name} needs no prepare step here"
                          + (f"; {st.missing}" if st.missing else ""))
    res = _prepare_bandai(args.name, _default_source(args.source), args.workers, args.force)
    out = {"name": args.name, "path": str(res.path), "fingerprint": res.fingerprint,
           "reused": res.reused, "clips": res.clips, "frames": res.frames,
           "seconds": round(res.seconds, 2)}
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        how = "already prepared" if res.reused else "prepared"
        print(f"{args.name}: {how}: {res.clips} clips, {res.frames} frames in {res.seconds:.1f} s "
              f"-> {res.path}")
    return 0


def _prepare_spec(args: argparse.Namespace, spec_file) -> int:
    """A data set declared by a spec file (repro.data.dataset_spec)."""
    from repro.data.dataset_prepare import prepare_dataset
    from repro.data.dataset_registration import register_spec_path
    from repro.data.registry import clipset_summary, get_entry
    from repro.errors import ConfigError

    if args.source:
        raise ConfigError(f"{spec_file}: a declared data set names its source in the spec "
                          "([source] path); --source is for bandai2")
    name = register_spec_path(str(spec_file))
    res = prepare_dataset(spec_file, force=args.force)
    summary = clipset_summary(get_entry(name).load())
    card = json.loads((res.path / "meta.json").read_text())["card"]
    if args.json:
        print(json.dumps({"name": name, "path": str(res.path), "fingerprint": res.fingerprint,
                          "reused": res.reused, "seconds": round(res.seconds, 2),
                          "card": summary, "prepared_card": card}, indent=1))
        return 0
    how = "already prepared" if res.reused else "prepared"
    print(f"{name}: {how}: {res.clips} clips, {res.frames} frames in {res.seconds:.1f} s "
          f"-> {res.path}")
    _print_summary(summary)
    _print_declared_card(card)
    return 0


def _print_declared_card(card: dict) -> None:
    """A declared data set's card beyond the counts: per-class durations, subjects, and what
    the source held that was not read."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    con = Console()
    t = Table("class", "clips", "frames", "mean s", "total s", title="per class")
    for k, v in card["per_class"].items():
        t.add_row(k, str(v["clips"]), str(v["frames"]), f"{v['seconds_mean']:.2f}",
                  f"{v.get('seconds_total', 0.0):.1f}")
    con.print(t)
    if card.get("subjects"):
        con.print(f"subjects: {card['subjects']}")
    for w in card.get("warnings", []):
        con.print(f"[yellow]warning[/yellow]: {escape(w)}")  # "[skeleton] ..." is no markup
    for key, what in (("skipped_files", "file(s) in the source matched no pattern"),
                      ("unused_label_rows", "label row(s) name no clip of the source"),
                      ("unlisted_clips", "clip(s) dropped: the labels do not name them")):
        d = card.get(key) or {}
        if d.get("count"):
            more = " …" if d["count"] > len(d["first"]) else ""
            con.print(f"{d['count']} {what}: {', '.join(d['first'])}{more}", markup=False)
    if card.get("excluded_files"):
        con.print(f"{card['excluded_files']} file(s) left out by [source] exclude",
                  markup=False)
    dropped = (card.get("dropped_clips") or {}).get("by_class") or {}
    if dropped:
        con.print(f"{sum(dropped.values())} clip(s) dropped, their class not in [labels] "
                  "classes: " + ", ".join(f"{k} {v}" for k, v in dropped.items()), markup=False)


def _check_spec(args: argparse.Namespace) -> int:
    from repro.data.dataset_spec import json_schema, load_dataset_spec

    if args.schema:
        print(json.dumps(json_schema(), indent=1))
        return 0
    from repro.errors import ConfigError

    if not args.spec:
        raise ConfigError("repro data check: give a data-set spec file (or --schema)")
    for f in args.spec:
        spec = load_dataset_spec(f)
        print(f"{f}: ok: data set {spec.name!r}, {spec.source.format} files in "
              f"{spec.source.path!r}, labels from {spec.labels.from_}")
        _check_labels(spec, f)
    return 0


def _check_labels(spec, spec_file: str) -> None:
    """The label rules applied to the source's file names (and labels file), no clip parsed
    (:func:`repro.data.dataset_clips.check_report`): per-class clips and the data set's own
    train / test counts, what is dropped, and a DataError (exit 2) for the problems prepare
    would refuse: unused classes, a class without a test or training clip."""
    from pathlib import Path

    from rich.console import Console
    from rich.table import Table

    from repro.data.dataset_clips import check_report
    from repro.errors import DataError

    source = Path(spec_file).resolve().parent / spec.source.path
    if not source.exists():
        print(f"  source {source} is not there: labels and split not checked")
        return
    r = check_report(spec, Path(spec_file))
    if not r["files"]:
        from repro.data.dataset_spec import clip_patterns

        print(f"  no file in the source matches {' or '.join(clip_patterns(spec))}: labels and "
              "split not checked (`repro data prepare` refuses such a source)")
        return
    con = Console()
    con.print(f"  {r['files']} clip file(s), {r['clips']} clip(s) kept"
              + (f", {r['excluded']} file(s) excluded" if r["excluded"] else ""))
    t = Table("class", "clips", "train", "test", "NM test", title="per class (the data set's "
              "split; NM: Neural Marionette's per-class split)")
    for k, v in r["per_class"].items():
        t.add_row(k, str(v["clips"]), str(v["train"]), str(v["test"]), str(v["marionette_test"]))
    con.print(t)
    for what, n in r["dropped_by_class"].items():
        con.print(f"  dropped (not in [labels] classes): {what}: {n} clip(s)", markup=False)
    if r["unlisted"]:
        con.print(f"  dropped (the labels do not name them): {r['unlisted']} clip(s)")
    if r["marionette_no_test"]:
        con.print(f"  warning: Neural Marionette's split (the marionette/* tables) gives no "
                  f"test clip to {', '.join(r['marionette_no_test'])} (a class needs at least "
                  f"{r['marionette_min_clips']} clips); `repro run` refuses those tables until "
                  "the class is dropped or has more clips", markup=False)
    if r["problems"]:
        raise DataError("; ".join(r["problems"]), spec_file)


def _prepare_view(args: argparse.Namespace) -> int:
    from repro.data.sequence_views import SEQUENCE_VIEWS, prepare_view
    from repro.errors import ConfigError

    if args.source:
        raise ConfigError(f"{args.name} is composed from {SEQUENCE_VIEWS[args.name]} and takes no "
                          f"--source (prepare {SEQUENCE_VIEWS[args.name]} with it instead)")
    res = prepare_view(args.name)
    if args.json:
        print(json.dumps(res["card"], indent=1))
        return 0
    how = "already prepared" if res["reused"] else "prepared"
    print(f"{args.name}: {how} in {res['seconds']:.1f} s -> {res['path']}")
    _print_seq_card(res["card"], matrix=False)
    return 0


def _info(args: argparse.Namespace) -> int:
    from repro.data.registry import DATASETS, clipset_summary, get_entry
    from repro.data.sequence_views import SEQUENCE_VIEWS, view_card, view_status

    if args.name in SEQUENCE_VIEWS and not args.list:
        card = view_card(args.name)
        if args.json:
            print(json.dumps(card, indent=1))
        else:
            _print_seq_card(card)
        return 0
    if args.list or not args.name:
        rows = []
        for name, e in DATASETS.items():
            st = e.status()
            rows.append({"name": name, "paper_dataset": e.is_paper_dataset,
                         "prepared": st.prepared, "location": st.location,
                         "fingerprint": st.fingerprint, "missing": st.missing,
                         "description": e.description})
        for name, source in SEQUENCE_VIEWS.items():
            st = view_status(name)
            rows.append({"name": name, "paper_dataset": False, "view_of": source,
                         "prepared": st.prepared, "location": st.location,
                         "fingerprint": st.fingerprint, "missing": st.missing,
                         "description": f"composed multi-action sequences over {source} "
                         "(motion-graph stand-in for BABEL-MAG; a view, not a data set)"})
        if args.json:
            print(json.dumps(rows, indent=1))
        else:
            for r in rows:
                state = "ready" if r["prepared"] else "missing"
                print(f"{r['name']:<16} {state:<8} {r['description']}")
                if r["missing"]:
                    print(f"{'':<16} {'':<8} {r['missing']}")
        return 0
    summary = clipset_summary(get_entry(args.name).load())
    if args.json:
        print(json.dumps(summary, indent=1))
        return 0
    _print_summary(summary)
    return 0


def _print_summary(s: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console()
    L = s["length_frames"]
    con.print(f"[bold]{s['name']}[/bold]: {s['clips']} clips, {s['frames']} frames, "
              f"{s['classes']} classes, {s['styles']} styles, {s['fps']:g} fps, "
              f"{s['joints']} joints")
    con.print(f"clip length (frames): min {L['min']}, mean {L['mean']:.1f}, max {L['max']}; "
              f"split: {s['split']['train']} train / {s['split']['test']} test")
    con.print(f"fingerprint: {s['fingerprint']}")
    t = Table("class", "clips")
    for k, v in s["per_class"].items():
        t.add_row(k, str(v))
    con.print(t)
    if s["per_style"]:
        t = Table("style", "clips")
        for k, v in s["per_style"].items():
            t.add_row(k, str(v))
        con.print(t)


def _fmt_stats(d: dict) -> str:
    return "n/a" if d["mean"] is None else f"{d['mean']:.3f} (median {d['median']:.3f})"


def _print_seq_card(c: dict, matrix: bool = True) -> None:
    """The card of a sequence view: counts, actions per sequence, junction quality and the
    train tag-pair count matrix (rows: from, columns: to, by label index)."""
    from rich.console import Console
    from rich.table import Table

    con = Console()
    sq, seg, fr = c["sequences"], c["segments"], c["frames"]
    con.print(f"[bold]{c['name']}[/bold]: {sq['total']} sequences ({sq['train']} train / "
              f"{sq['test']} test) over {c['source']['name']} ({c['source']['clips']} clips); "
              f"{seg['action']} actions, {seg['lead_in']} lead-ins, {seg['lead_out']} lead-outs")
    a = c["actions_per_sequence"]
    if a:
        con.print(f"actions per sequence: min {a['min']}, mean {a['mean']:.2f}, max {a['max']}")
    con.print(f"frames: {fr['total']} ({fr['transition']} transition frames in "
              f"{fr['transitions']} transitions of {c['config']['blend_frames']}) "
              f"at {c['fps']:g} fps")
    q = c["junction_quality"]
    for key, title, unit in (("velocity_jump", "velocity jump", "cm/frame^2"),
                             ("foot_slide", "foot slide", "cm/frame")):
        con.print(f"{title} ({unit}): junctions {_fmt_stats(q[key]['junction'])}, inside clips "
                  f"{_fmt_stats(q[key]['inside'])}")
    ts = c["tag_pairs"]["train_summary"]
    con.print(f"train tag pairs: {ts['pairs']} pairs, {ts['zero_pairs']}/{ts['cells']} cells zero, "
              f"top 10% of cells hold {100 * (ts['top10pct_pairs_mass'] or 0):.1f}% of pairs")
    _print_fidelity(con, c.get("fidelity"))
    con.print(f"fingerprint: {c['fingerprint']}")
    con.print(f"[dim]{c['stand_in']}[/dim]")
    if not matrix:
        return
    from rich import box

    names = c["tag_pairs"]["label_names"]
    t = Table(title="train tag-pair counts (consecutive segments, all roles; . = 0)",
              box=box.SIMPLE_HEAD, pad_edge=False)
    t.add_column("from \\ to", no_wrap=True)
    for i in range(len(names)):
        t.add_column(str(i), justify="right", no_wrap=True)
    for i, row in enumerate(c["tag_pairs"]["train"]):
        t.add_row(f"{i} {names[i]}", *[str(v) if v else "." for v in row])
    con.print(t)


def _print_fidelity(con, f: dict | None) -> None:
    """The card's ``fidelity`` object in a few lines (issue 26; docs/data.md)."""
    if not f:
        return
    import statistics

    succ, top4 = f["successors_per_tag"], [x for x in f["top4_share"] if x is not None]
    con.print(f"fidelity: successors per tag {min(succ)}-{max(succ)}, median top-4 share "
              f"{statistics.median(top4) if top4 else float('nan'):.3f}")
    for name, ts in (f.get("test_sets") or {}).items():
        con.print(f"  {name} chains: unseen transitions {100 * ts['unseen_share']:.1f}%, median "
                  f"training support {ts['median_support']:g}")
    trunc = ", ".join(f"{k} {100 * v['share']:.1f}% > {v['max_frames']}"
                      for k, v in f["truncated_actions"].items() if v["share"] is not None)
    con.print(f"  truncated training actions: {trunc}")
    j = f["junction"]
    if j["above_p99_share"] is not None:
        con.print(f"  junction windows above the inside p99: {100 * j['above_p99_share']:.1f}%; "
                  f"foot slide (median, cm/frame) junction {j['foot_slide_junction']} vs inside "
                  f"{j['foot_slide_inside']}")
    p = f.get("pairs")
    if p:
        con.print(f"  MultiAct pairs: S_p heading median {p['sp_heading_deg_median']:.1f} deg, "
                  f"transition linear ratio {p['transition_linear_ratio']:.3f}")


def _bundle(args: argparse.Namespace) -> int:
    import subprocess

    from repro.data.bandai import load_bandai2
    from repro.data.bundle import MINI_MAX_BYTES, build_mini
    from repro.errors import DataError
    from repro.store.atomic import output_dir

    if args.out is not None:  # a file, a device, '' or /proc/x: one line, before any work
        output_dir(args.out, create=False)
    res = _prepare_bandai("bandai2", _default_source(args.source), args.workers, False)
    clips = load_bandai2("bandai2")
    if clips.fingerprint != res.fingerprint:  # pragma: no cover (prepare sets the pointer)
        raise DataError("prepared cache changed while bundling; run the command again")
    # the folder made (and written into) by the same helper as the check: one line, no
    # traceback, when it cannot be; a write failing later is one line too
    out_dir = output_dir(args.out) if args.out is not None else None
    try:
        out = build_mini(clips, out_dir)
    except OSError as e:
        raise DataError(f"cannot write the bundle ({e.strerror or e})",
                        getattr(e, "filename", None) or out_dir) from None
    try:
        du = subprocess.run(["du", "-sb", *[f"{out['out']}/{f}" for f in out["files"]]],
                            capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        du = ""
    print(f"bandai2-mini: {out['clips']} clips, {out['frames']} frames, {out['bytes']} bytes "
          f"-> {out['out']}")
    if du:
        print(du)
    if out["bytes"] > MINI_MAX_BYTES:
        raise DataError(f"bundle is {out['bytes']} bytes, over the {MINI_MAX_BYTES} byte limit",
                        out["out"])
    return 0
