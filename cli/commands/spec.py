"""``repro spec check [FILES...]`` and ``repro spec schema``.

``check`` validates table specs (all of ``tables/<paper>/*.toml`` plus ``tables/scales.toml``
when no file is named), printing one line per valid spec and one line per problem (file,
location, field, problem) on stderr; any problem ends with exit code 2.  ``schema`` prints the
JSON Schema of a table spec (or of the scale file with ``--scales``).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from cli.commands import command_group


def register(subparsers) -> None:
    sub = command_group(subparsers, "spec", "validate table specs, print their JSON Schema",
                        "Validate table specs and scale profiles; print the spec JSON Schema.",
                        "spec_command")

    c = sub.add_parser("check", help="validate specs (all of tables/ when no file is given)")
    c.add_argument("files", nargs="*", metavar="FILE",
                   help="spec TOML files (tables/scales.toml is checked as a scale file)")
    c.add_argument("--json", action="store_true", help="one JSON object per spec on stdout")
    c.set_defaults(func=_check)

    s = sub.add_parser("schema", help="print the JSON Schema of a table spec")
    s.add_argument("--scales", action="store_true", help="the schema of tables/scales.toml instead")
    s.set_defaults(func=_schema)


def _check(args) -> int:
    from repro.errors import SpecError
    from repro.paths import tables_root
    from repro.specs.load import SpecValidationError, display_path, load_spec, spec_paths
    from repro.specs.scales import load_scales, scales_path

    if args.files:
        paths = [Path(f) for f in args.files]
    else:
        paths = spec_paths()
        if scales_path().is_file():
            paths.append(scales_path())
        if not paths:
            print(f"repro: error: no specs found under {tables_root()}", file=sys.stderr)
            return 2

    n_bad = 0
    seen_ids: dict[str, str] = {}
    for path in paths:
        shown = display_path(path)
        try:
            if path.name == "scales.toml":
                sf = load_scales(path)
                line = {"file": shown, "ok": True, "kind": "scales", "version": sf.version}
                text = f"ok  {shown:<34} scales v{sf.version}: quick, medium, paper"
            else:
                spec = load_spec(path)
                if spec.id in seen_ids:
                    raise SpecError(f"duplicate spec id {spec.id!r} (also {seen_ids[spec.id]})",
                                    shown, "id")
                seen_ids[spec.id] = shown
                line = {"file": shown, "ok": True, "kind": spec.kind, "id": spec.id,
                        "version": spec.version, "spec_hash": spec.spec_hash,
                        "rows": len(spec.rows), "columns": len(spec.columns),
                        "reported": spec.n_reported(), "claims": len(spec.claims)}
                text = (f"ok  {spec.id:<20} v{spec.version}  {spec.kind:<6} "
                        f"{len(spec.rows):>2} rows × {len(spec.columns):>2} cols, "
                        f"{spec.n_reported():>3} reported, {len(spec.claims):>2} claims  "
                        f"{spec.spec_hash[:12]}")
        except SpecValidationError as e:
            n_bad += 1
            for prob in e.problems:
                print(f"repro: error: {prob}", file=sys.stderr)
            line = {"file": shown, "ok": False, "problems": [str(p) for p in e.problems]}
            text = None
        except SpecError as e:
            n_bad += 1
            print(f"repro: error: {e}", file=sys.stderr)
            line = {"file": shown, "ok": False, "problems": [str(e)]}
            text = None
        if args.json:
            print(json.dumps(line, ensure_ascii=False))
        elif text:
            print(text)
    if n_bad:
        print(f"repro: error: {n_bad} of {len(paths)} file(s) invalid", file=sys.stderr)
        return 2
    return 0


def _schema(args) -> int:
    if args.scales:
        from repro.specs.scales import ScaleFile

        schema = ScaleFile.model_json_schema(by_alias=True)
    else:
        from repro.specs.schema import TableSpec

        schema = TableSpec.model_json_schema(by_alias=True)
    try:
        sys.stdout.write(json.dumps(schema, indent=2, ensure_ascii=False) + "\n")
        sys.stdout.flush()
    except BrokenPipeError:  # `repro spec schema | head`
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0

