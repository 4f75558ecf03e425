"""``repro cache ls | verify | gc``: inspect, check and prune the content-addressed store."""

from __future__ import annotations

import argparse
import json

from cli.commands import command_group


def register(subparsers) -> None:
    sub = command_group(subparsers, "cache", "inspect, verify and prune the artifact store",
                        "The content-addressed store under REPRO_HOME/store.",
                        "cache_command")

    ls = sub.add_parser("ls", help="list stored objects (kind, size, created)")
    ls.add_argument("--kind", help="only objects of this kind")
    ls.add_argument("--json", action="store_true", help="machine-readable output")
    ls.set_defaults(func=_ls)

    vf = sub.add_parser("verify", help="re-hash every object; quarantine corrupt ones "
                                       "(exit 1 if any was found)")
    vf.add_argument("--json", action="store_true", help="machine-readable output")
    vf.set_defaults(func=_verify)

    gc = sub.add_parser("gc", help="remove objects no run record references, stale temp "
                                   "folders and the quarantine")
    gc.add_argument("--dry-run", action="store_true", help="only report what would be removed")
    gc.add_argument("--scratch", action="store_true",
                    help="also remove unfinished jobs' scratch folders (their checkpoints)")
    gc.add_argument("--json", action="store_true", help="machine-readable output")
    gc.set_defaults(func=_gc)


def _ls(args: argparse.Namespace) -> int:
    from repro.store.object_files import describe_bytes
    from repro.store.objects import Store

    store = Store()
    infos = store.ls(kind=args.kind)
    if args.json:
        print(json.dumps([{"key": i.key, "kind": i.kind, "size": i.size, "files": i.n_files,
                           "created": i.created, "label": i.meta.get("label"),
                           "problem": i.problem} for i in infos], indent=2))
        return 0
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    t = Table(title=f"store {store.root}", title_justify="left")
    for col in ("key", "kind", "label", "size", "files", "created"):
        t.add_column(col, justify="right" if col in ("size", "files") else "left")
    for i in infos:
        t.add_row(i.key[:12], escape(i.kind), escape(str(i.meta.get("label") or "")),
                  describe_bytes(i.size), str(i.n_files), i.created[:19].replace("T", " ")
                  + ("" if i.problem is None else f" [red]{escape(i.problem)}[/]"))
    con = Console()
    con.print(t)
    con.print(f"{len(infos)} objects, {describe_bytes(sum(i.size for i in infos))}")
    return 0


def _verify(args: argparse.Namespace) -> int:
    from repro.store.objects import Store

    store = Store()
    rep = store.verify()
    if args.json:
        print(json.dumps({"ok": len(rep.ok), "corrupt": [
            {"key": c.key, "problem": c.problem,
             "quarantined_to": None if c.quarantined_to is None else str(c.quarantined_to)}
            for c in rep.corrupt]}, indent=2))
    else:
        from rich.console import Console
        from rich.markup import escape

        con = Console()
        for c in rep.corrupt:
            where = f" -> {c.quarantined_to}" if c.quarantined_to else " (being rebuilt elsewhere)"
            con.print(f"[red]corrupt[/] {c.key[:12]}: {escape(c.problem)}{escape(where)}")
        con.print(f"{len(rep.ok)} objects verified, {len(rep.corrupt)} corrupt"
                  + (" (quarantined; the next run rebuilds them)" if rep.corrupt else ""))
    return 1 if rep.corrupt else 0


def _gc(args: argparse.Namespace) -> int:
    from repro.store.object_files import describe_bytes
    from repro.store.runs import collect_garbage

    rep = collect_garbage(dry_run=args.dry_run, include_scratch=args.scratch)
    if args.json:
        print(json.dumps({
            "dry_run": rep.dry_run, "freed_bytes": rep.freed_bytes,
            "objects": [{"key": o.key, "kind": o.kind, "size": o.size} for o in rep.objects],
            "temp_dirs": [str(p) for p in rep.temp_dirs],
            "scratch_dirs": [str(p) for p in rep.scratch_dirs],
            "quarantine_dirs": [str(p) for p in rep.quarantine_dirs],
            "kept_locked": rep.kept_locked}, indent=2))
        return 0
    from rich.console import Console

    con = Console()
    verb = "would remove" if rep.dry_run else "removed"
    for o in rep.objects:
        con.print(f"{verb} {o.key[:12]} {o.kind} {describe_bytes(o.size)}")
    con.print(f"{verb} {len(rep.objects)} objects, {len(rep.temp_dirs)} temp, "
              f"{len(rep.scratch_dirs)} scratch and {len(rep.quarantine_dirs)} quarantined "
              f"folders ({describe_bytes(rep.freed_bytes)})"
              + (f"; kept {len(rep.kept_locked)} in use" if rep.kept_locked else ""))
    return 0
