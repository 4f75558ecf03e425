"""Entry point of the ``repro`` console script.

Each command group lives in ``cli/commands/<name>.py`` and exposes ``register(subparsers)``,
which adds its sub-commands and sets ``func`` on them.  A :class:`repro.errors.ReproError`
raised anywhere ends the command with one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from repro import __version__

# Command-group modules in help order.  A module not (yet) present is skipped, so the command
# grows as the library does; a module that is present but broken fails loudly.
COMMAND_MODULES = (
    "tables",   # list, plan, run, show, rescore, verify
    "spec",     # spec check | schema
    "data",     # data prepare | info | bundle
    "eval",     # eval classifier | real
    "runs",     # runs ls | show | diff | reindex
    "report",   # report | strips | export
    "cache",    # cache ls | verify | gc
    "doctor",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="repro",
        description="Reproduce the tables of Neural Marionette, MultiAct and ODMO, "
        "with intervals and verdicts.",
    )
    parser.add_argument("--version", action="version", version=f"repro {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            mod = importlib.import_module(f"cli.commands.{name}")
        except ModuleNotFoundError as e:
            if e.name == f"cli.commands.{name}":
                continue
            raise
        mod.register(sub)
    return parser


#: an error message longer than this is shortened in the middle (a value quoted in it may be
#: megabytes long: a 5,000,000-digit number, a pasted file)
MAX_ERROR_CHARS = 2000


def _one_line(msg: str) -> str:
    if len(msg) <= MAX_ERROR_CHARS:
        return msg
    half = MAX_ERROR_CHARS // 2
    return f"{msg[:half]} … [{len(msg) - 2 * half} characters left out] … {msg[-half:]}"


def _dataset_specs(args) -> None:
    """``--dataset path/to/spec.toml``: register the declared data set (for this process and
    the job processes it starts) and go on with its name, so records and job keys name the
    data set, not a path on this machine."""
    text = getattr(args, "dataset", None)
    if isinstance(text, str) and text.endswith(".toml"):
        from repro.data.dataset_spec import is_spec_path, register_spec_path
        from repro.errors import ConfigError

        if not is_spec_path(text):
            raise ConfigError(f"--dataset {text}: no such data-set spec file")
        args.dataset = register_spec_path(text)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    func = getattr(args, "func", None)
    if func is None:
        parser.print_help()
        return 0
    from repro.errors import ReproError

    try:
        _dataset_specs(args)
        rc = func(args)
    except ReproError as e:
        print(f"repro: error: {_one_line(str(e))}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("repro: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `repro ... | head`: the reader left; say nothing more
        import os

        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 0
    return int(rc or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
