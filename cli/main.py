"""Entry point of the ``repro`` console script.

Each command group lives in ``cli/commands/<name>.py`` and exposes ``register(subparsers)``,
which adds its sub-commands and sets ``func`` on them.  A :class:`repro.errors.ReproError`
raised anywhere ends the command with one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import sys

# `--fast-kernels` must reach the environment before `import repro` pins the kernel paths
# (repro/kernels.py): numeric libraries read them once, at load.  The option itself is
# declared (and documented) on the commands that compute.
if "--fast-kernels" in sys.argv[1:]:
    os.environ["REPRO_FAST_KERNELS"] = "1"

from repro import __version__  # noqa: E402

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


class _Parser(argparse.ArgumentParser):
    """argparse's parser whose usage errors quote long values clipped, as repro's own errors
    (:func:`_one_line`); its sub-command parsers are of the same class."""

    def error(self, message: str):
        super().error(_one_line(message))


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
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


#: a run of non-blank characters longer than this in an error message (a value quoted from
#: the input: a 5,000,000-digit number, a pasted line) is shortened in the middle
MAX_QUOTE_CHARS = 200
#: ... and a whole message longer than this (many long words) too
MAX_ERROR_CHARS = 2000
_LONG_WORD = re.compile(r"\S{%d,}" % (MAX_QUOTE_CHARS + 1))
#: a quoted value ('...' or "...", spaces allowed) longer than the cap
_LONG_QUOTE = re.compile(r"'[^'\n]{%d,}'|\"[^\"\n]{%d,}\"" % ((MAX_QUOTE_CHARS - 1,) * 2))


def _shorten(text: str, limit: int) -> str:
    half = limit // 2 - 20
    return f"{text[:half]}…[{len(text) - 2 * half} characters left out]…{text[-half:]}"


def _one_line(msg: str) -> str:
    """The message as printed: on one line (CR/LF escaped), each quoted value or long run of
    non-blank characters clipped to ~:data:`MAX_QUOTE_CHARS`, the whole to
    ~:data:`MAX_ERROR_CHARS`."""
    msg = msg.replace("\r", "\\r").replace("\n", "\\n")  # one line, whatever was quoted
    clip = lambda m: _shorten(m.group(0), MAX_QUOTE_CHARS)  # noqa: E731
    msg = _LONG_WORD.sub(clip, _LONG_QUOTE.sub(clip, msg))
    return msg if len(msg) <= MAX_ERROR_CHARS else _shorten(msg, MAX_ERROR_CHARS)


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

    fast_before = os.environ.get("REPRO_FAST_KERNELS")
    if getattr(args, "fast_kernels", False) and fast_before != "1":
        # main(argv) called in a process that imported repro (hence pinned torch / numpy)
        # without the flag: its jobs would compute pinned but be keyed and recorded as fast
        if "torch" in sys.modules or "numpy" in sys.modules:
            print("repro: error: --fast-kernels must be given when the process starts (the "
                  "kernel paths are fixed when torch and numpy load); run `repro ... "
                  "--fast-kernels` or set REPRO_FAST_KERNELS=1", file=sys.stderr)
            return 2
        os.environ["REPRO_FAST_KERNELS"] = "1"
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
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 0
    finally:
        if fast_before is None:
            os.environ.pop("REPRO_FAST_KERNELS", None)
        else:
            os.environ["REPRO_FAST_KERNELS"] = fast_before
    return int(rc or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
