"""``repro report | strips | export``: the pictures behind the numbers, and samples out."""

from __future__ import annotations

import sys

from cli.commands import int_at_least, run_ref


def _which_run(p) -> None:
    p.add_argument("--scale", default="quick", help="quick | medium | paper (default: quick)")
    p.add_argument("--dataset", default=None, help="override the scale profile's data set")
    p.add_argument("--run", default=None, type=run_ref,
                   help="a run id (default: the newest finished run)")


def _check_out(out) -> None:
    """Refuse a bad ``--out`` ('' = the current folder, a file, a device, /proc/x) before any
    work; the writers check again (and create the folder) when they write."""
    from repro.store.atomic import output_dir

    if out is not None:
        output_dir(out, create=False)


def _replicate(text: str):
    return "all" if text == "all" else int_at_least(0)(text)


def register(sub) -> None:
    p = sub.add_parser("report", help="a self-contained HTML report (tables, verdicts, strips, "
                       "plots, provenance) that opens from disk",
                       description="One page per table plus index.html, with the images and "
                       "data files beside them; no server, no network.")
    p.add_argument("tables", nargs="+", metavar="TABLE")
    _which_run(p)
    p.add_argument("--out", required=True, help="folder to write (created if missing)")
    p.add_argument("--items", type=int_at_least(1), default=2,
                   help="test items (or test sequences) drawn per band (default 2)")
    p.add_argument("--no-strips", action="store_true", help="leave the strips out")
    p.add_argument("--check", action="store_true", help="then open every page in headless "
                   "chromium: exit 1 when an image does not decode or a script fails")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("strips", help="comparison strips (PNG + multi-channel EXR) of a run: "
                       "every row for the same test items, the real motion on top")
    p.add_argument("table")
    _which_run(p)
    p.add_argument("--out", required=True, help="folder to write (created if missing)")
    p.add_argument("--items", type=int_at_least(1), default=2,
                   help="test items (or test sequences) per band (default 2)")
    p.add_argument("--replicate", type=int_at_least(0), default=0)
    p.add_argument("--key-frames", type=int_at_least(2), default=8,
                   help="key frames of a single-action strip (default 8)")
    p.add_argument("--actions", type=int_at_least(1), default=4,
                   help="actions of a test sequence drawn (default 4)")
    p.add_argument("--format", default="png,exr", help="png, exr or png,exr (default)")
    p.set_defaults(func=cmd_strips)

    p = sub.add_parser("export", help="stored samples as BVH (or .npz joint positions)")
    p.add_argument("table")
    _which_run(p)
    p.add_argument("--out", default=None, help="folder to write (created if missing; required "
                   "unless --list)")
    p.add_argument("--band", type=int_at_least(0), default=None,
                   help="one band of the table (--list shows them; default: all)")
    p.add_argument("--row", default=None, help="one row (default: every generated row)")
    p.add_argument("--replicate", type=_replicate, default=0, help="N or all (default 0)")
    p.add_argument("--item", type=int_at_least(0), default=None,
                   help="one test item / test sequence (default: all)")
    p.add_argument("--format", default="bvh", choices=("bvh", "npz"))
    p.add_argument("--dummy-root", action="store_true",
                   help="add the all-zero root joint of the Bandai files (re-readable as data)")
    p.add_argument("--list", action="store_true", help="only list the run's stored samples")
    p.set_defaults(func=cmd_export)


def cmd_report(args) -> int:
    from repro.report.html_report import write_report

    _check_out(args.out)
    index = write_report(args.tables, args.out, scale=args.scale, dataset=args.dataset,
                         run=args.run, items=args.items, strips=not args.no_strips)
    print(f"repro: report written: {index}")
    if args.check:
        from repro.report.browser import check_report

        problems = check_report(index.parent)
        for p in problems:
            print(f"repro: report check: {p}", file=sys.stderr)
        if problems:
            return 1
        print("repro: report check: every page loaded in chromium, every image decoded, no "
              "script error")
    return 0


def cmd_strips(args) -> int:
    import time

    from repro.engine.run_samples import run_samples
    from repro.errors import ConfigError
    from repro.report.strip_sets import write_strips

    formats = tuple(f.strip() for f in args.format.split(",") if f.strip())
    bad = [f for f in formats if f not in ("png", "exr")]
    if bad or not formats:
        raise ConfigError(f"--format {args.format!r}: choose png, exr or png,exr")
    _check_out(args.out)
    rs = run_samples(args.table, scale=args.scale, dataset=args.dataset, run=args.run)
    t0 = time.perf_counter()
    rec = write_strips(rs, args.out, formats=formats, items=args.items,
                       replicate=args.replicate, key_frames=args.key_frames,
                       max_actions=args.actions)
    dt = time.perf_counter() - t0
    for st in rec["strips"]:
        print(f"{st['name']}: {st['title']} ({', '.join(st['files'].values())})")
    for n in rec["notes"]:
        print(f"repro: no strip: {n}", file=sys.stderr)
    print(f"repro: {len(rec['strips'])} strips of {rs.spec.id} (run {rs.run_id}) in {args.out} "
          f"({dt:.1f} s)", file=sys.stderr)
    return 0


def cmd_export(args) -> int:
    from repro.engine.run_samples import describe, run_samples
    from repro.exporters.samples import export_samples

    from repro.errors import ConfigError

    if args.out is None and not args.list:
        raise ConfigError("repro export: --out FOLDER is required (or --list)")
    if not args.list:
        _check_out(args.out)
    rs = run_samples(args.table, scale=args.scale, dataset=args.dataset, run=args.run)
    if args.list:
        print(describe(rs))
        return 0
    rec = export_samples(rs, args.out, row=args.row, replicate=args.replicate, item=args.item,
                         fmt=args.format, dummy_root=args.dummy_root, band=args.band)
    for s in rec.get("skipped", []):
        print(f"repro: skipped {s['row']}: {s['reason']}", file=sys.stderr)
    print(f"repro: {len(rec['files'])} {args.format} file(s) of {rs.spec.id} (run {rs.run_id}) "
          f"in {args.out}")
    return 0
