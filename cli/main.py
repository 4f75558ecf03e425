"""Entry point of the ``repro`` console script.

Each command group lives in ``cli/commands/<name>.py`` and exposes ``register(subparsers)``,
which adds its sub-commands and sets ``func`` on them.  A :class:`repro.errors.ReproError`
raised anywhere ends the command with one line on stderr and exit code 2.

Terminal output (issue 29, item 10).  A name from the data (a source file called
``\x1b]0;PWNED\x07\x1b[2J.txt``, a label, a value of a stored record) must not reach the
terminal as the control sequence it spells.  So while a command runs, ``sys.stdout`` and
``sys.stderr`` are :class:`TerminalStream` filters: every C0 control but newline and tab, DEL,
every C1 control (U+0080-U+009F) and any lone surrogate is written as its escape (``\x1b``,
``\r``, ``\u009b``, ``\ud800``), whoever printed it; error lines (:func:`_one_line`) escape
newline and tab too.  The CLI's own styling is rich's: every piece of text rich renders is escaped the same way before
rich styles it, and what rich writes is marked so that the filter passes it as it is
(:func:`_escape_rich_segments`): the colours, progress bars and cursor moves rich makes itself
stay intact on a terminal, the data inside them cannot add any.  Should rich ever render
otherwise (another release), its output is escaped whole: styling lost on a terminal, nothing
raw.
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
    "claims",   # claims: every claim of every spec, one line each
    "report",   # report | strips | export
    "cache",    # cache ls | verify | gc
    "doctor",
)


class _Parser(argparse.ArgumentParser):
    """argparse's parser whose usage errors are one line (no usage block; the ``--help`` to ask
    for it named) and quote long values clipped, as repro's own errors (:func:`_one_line`); its
    sub-command parsers are of the same class."""

    def error(self, message: str):
        # one line, like every other refusal (issue 29): no usage block above it
        self.exit(2, f"{self.prog}: error: {_one_line(message)} (`{self.prog} --help` shows "
                     "the usage)\n")


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
#: a quoted value ('...' or "...", spaces allowed) longer than the cap; a single quote right
#: after a letter or digit is an apostrophe or a closing quote ("the reference x.bvh's",
#: "joint 'Knee' by 0.04 cm in a.bvh, b.bvh, ...": the files are no quoted value), never an
#: opening one
_LONG_QUOTE = re.compile(r"(?<!\w)'[^'\n]{%d,}'|\"[^\"\n]{%d,}\"" % ((MAX_QUOTE_CHARS - 1,) * 2))


#: what the terminal never gets raw (module docstring): C0 but newline, tab and a CR that ends
#: a line (CRLF, as ``csv`` writes rows: harmless on a terminal, and CSV output stays CSV), DEL,
#: C1 and lone surrogates; in an error line newline, tab and every CR too.  DEL and C1 are
#: written ``\u007f``, ``\u009b`` (valid inside a JSON string, unlike ``\x7f``).
_TERMINAL_UNSAFE = re.compile("\r(?!\n)|[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\ud800-\udfff]")
_LINE_UNSAFE = re.compile("[\x00-\x1f\x7f-\x9f\ud800-\udfff]")
_NAMED = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}


def _escape_char(m: re.Match) -> str:
    c = m.group(0)
    return _NAMED.get(c) or (f"\\x{ord(c):02x}" if ord(c) < 0x7f else f"\\u{ord(c):04x}")


def escape_terminal(text: str, *, one_line: bool = False) -> str:
    """``text`` with every character the terminal could take as a control written as its
    escape (module docstring, "Terminal output"); ``one_line``: newline and tab too."""
    return (_LINE_UNSAFE if one_line else _TERMINAL_UNSAFE).sub(_escape_char, text)


class TerminalStream:
    """``sys.stdout`` / ``sys.stderr`` while a command runs: text written is escaped with
    :func:`escape_terminal`; everything else (``isatty``, ``fileno``, ``flush``, ``buffer``,
    ``encoding``) is the real stream's."""

    def __init__(self, raw):
        self.raw = raw

    def write(self, text: str) -> int:
        if type(text) is _RichOutput:  # rich's own rendering, its text escaped already
            self.raw.write(text)
        else:
            self.raw.write(escape_terminal(text) if isinstance(text, str) else text)
        return len(text)

    def writelines(self, lines) -> None:
        for line in lines:
            self.write(line)

    def __getattr__(self, name: str):
        return getattr(self.raw, name)


class _RichOutput(str):
    """What rich rendered once every piece of text in it was escaped
    (:func:`_escape_rich_segments`): rich's styling in it passes the filter as it is."""

    __slots__ = ()


#: whether rich's rendering escapes the text it is given (:func:`_escape_rich_segments`)
_RICH_ESCAPES = False


def _escape_rich_segments() -> bool:
    """Make rich escape the text of every segment it renders before it styles it (module
    docstring), once per process, and mark the result (:class:`_RichOutput`) so that the
    filter lets it through; rich's own control segments (cursor moves) are left as they are.
    False when rich is missing or renders otherwise than this knows (its output is then
    escaped whole by the filter)."""
    global _RICH_ESCAPES
    try:
        from rich.console import Console
        from rich.segment import Segment
    except ImportError:
        return False
    original = getattr(Console, "_render_buffer", None)
    if original is None:
        return False
    if getattr(original, "_repro_escapes", False):  # this Console class is patched already
        _RICH_ESCAPES = True
        return True

    def _render_buffer(self, buffer):
        return _RichOutput(original(self, (
            seg if seg.control else Segment(escape_terminal(seg.text), seg.style, seg.control)
            for seg in buffer)))

    _render_buffer.__doc__ = original.__doc__
    _render_buffer._repro_escapes = True
    Console._render_buffer = _render_buffer
    _RICH_ESCAPES = True
    return True


class _PatchRichOnImport:
    """A ``sys.meta_path`` finder: when ``rich.console`` is imported, the module is executed
    as usual and :func:`_escape_rich_segments` patches it right after, before any code can
    render with it; then the finder leaves ``sys.meta_path``.  (A look-up that only asks for
    the spec, ``importlib.util.find_spec``, does not use it up.)  So a command that never styles
    anything (``repro plan``) does not pay rich's import (~40 ms) for the guard (issue 31:
    ``repro plan`` <= 0.5 s)."""

    def __init__(self):
        self._looking = False

    def find_spec(self, fullname, path=None, target=None):
        if fullname != "rich.console" or self._looking:
            return None
        import importlib.util

        self._looking = True  # the look-up below walks sys.meta_path, this finder included
        try:
            spec = importlib.util.find_spec(fullname)
        finally:
            self._looking = False
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        loader_exec, finder = spec.loader.exec_module, self

        def exec_module(module):
            loader_exec(module)
            _escape_rich_segments()
            if finder in sys.meta_path:
                sys.meta_path.remove(finder)

        spec.loader.exec_module = exec_module  # this spec's own loader instance
        return spec


#: the finder :func:`_patch_rich_when_imported` put in ``sys.meta_path`` (None: none pending)
_RICH_FINDER: _PatchRichOnImport | None = None


def _patch_rich_when_imported() -> None:
    """:func:`_escape_rich_segments` now if rich's console is loaded, else as soon as it is
    (:class:`_PatchRichOnImport`), once per process."""
    global _RICH_FINDER
    if "rich.console" in sys.modules:
        _escape_rich_segments()
    elif _RICH_FINDER is None or _RICH_FINDER not in sys.meta_path:
        _RICH_FINDER = _PatchRichOnImport()
        sys.meta_path.insert(0, _RICH_FINDER)


def _escaping_excepthook(kind, value, tb) -> None:
    """``sys.excepthook`` of a repro process: a traceback (a bug: every expected failure is one
    line) printed with its controls escaped too, as the exception's message may quote data."""
    import traceback

    text = "".join(traceback.format_exception(kind, value, tb))
    sys.stderr.write(escape_terminal(text))


class terminal_guard:
    """Context manager: :class:`TerminalStream` in front of ``sys.stdout`` and ``sys.stderr``
    (not twice), the real streams back afterwards; an uncaught exception's traceback, printed
    after that, is escaped by :func:`_escaping_excepthook` (installed unless another hook is)."""

    def __enter__(self):
        _patch_rich_when_imported()
        self.hook = sys.excepthook
        if sys.excepthook is sys.__excepthook__:
            sys.excepthook = _escaping_excepthook
        self.saved = (sys.stdout, sys.stderr)
        if sys.stdout is not None and not isinstance(sys.stdout, TerminalStream):
            sys.stdout = TerminalStream(sys.stdout)
        if sys.stderr is not None and not isinstance(sys.stderr, TerminalStream):
            sys.stderr = TerminalStream(sys.stderr)
        return self

    def __exit__(self, kind, value, tb) -> None:
        sys.stdout, sys.stderr = self.saved
        if kind is None or kind is SystemExit:  # nothing uncaught to print: the hook goes back
            sys.excepthook = self.hook


def _shorten(text: str, limit: int) -> str:
    half = limit // 2 - 20
    return f"{text[:half]}…[{len(text) - 2 * half} characters left out]…{text[-half:]}"


def _one_line(msg: str) -> str:
    """The message as printed: on one line with no control character (CR, LF, tab, ESC, NUL,
    C1 ... escaped: :func:`escape_terminal`), each quoted value or long run of non-blank
    characters clipped to ~:data:`MAX_QUOTE_CHARS`, the whole to ~:data:`MAX_ERROR_CHARS`."""
    msg = escape_terminal(msg, one_line=True)  # one line, whatever was quoted
    clip = lambda m: _shorten(m.group(0), MAX_QUOTE_CHARS)  # noqa: E731
    msg = _LONG_WORD.sub(clip, _LONG_QUOTE.sub(clip, msg))
    return msg if len(msg) <= MAX_ERROR_CHARS else _shorten(msg, MAX_ERROR_CHARS)


def _dataset_specs(args) -> None:
    """``--dataset path/to/spec.toml``: register the declared data set (for this process and
    the job processes it starts) and go on with its name, so records and job keys name the
    data set, not a path on this machine."""
    text = getattr(args, "dataset", None)
    if isinstance(text, str) and text.endswith(".toml"):
        from repro.data.dataset_registration import is_spec_path, register_spec_path
        from repro.errors import ConfigError

        if not is_spec_path(text):
            raise ConfigError(f"--dataset {text}: no such data-set spec file")
        args.dataset = register_spec_path(text)


def main(argv: list[str] | None = None) -> int:
    with terminal_guard():
        return _main(argv)


def _main(argv: list[str] | None) -> int:
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
    except MemoryError:
        # input within the documented caps (docs/data.md, "Caps") that still did not fit this
        # machine's memory or an address-space limit: one line, not a traceback; nothing is
        # published half-written (every store and cache write is atomic)
        print(f"repro: error: out of memory during `repro {getattr(args, 'command', '')}` "
              "(the input is larger than this machine or its memory limit allows; for data "
              "sets see docs/data.md, Caps)", file=sys.stderr)
        return 2
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
