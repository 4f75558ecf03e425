"""No control character from the data reaches the terminal (issue 29, item 10).

A source file named ``\\x1b]0;PWNED\\x07\\x1b[2J.txt`` used to reach stdout raw on the data-set
card (it sets the window title and clears the screen); error lines escaped CR/LF but not ESC or
NUL.  While a command runs, ``sys.stdout`` / ``sys.stderr`` escape every C0 control but newline
and tab, DEL, C1 and lone surrogates; error lines escape newline and tab too; rich's own styling
still reaches a terminal, the data inside it escaped (``cli/main.py``, "Terminal output").
"""

from __future__ import annotations

import csv
import io
import re
import subprocess
import sys
from pathlib import Path

from test_dataset_spec_options import fresh_registry  # noqa: F401 (fixture)

#: a raw control character as the terminal would get it (newline and tab are layout)
RAW = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\ud800-\udfff]")
EVIL = "\x1b]0;PWNED\x07\x1b[2J"


def _cli(capsys, *argv) -> tuple[int, str, str]:
    from cli.main import main

    rc = main(list(argv))
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_escape_terminal_names_every_control():
    from cli.main import _one_line, escape_terminal

    text = "a\x1b[2J\x00\x07\x7f\x9b\x85\ud800\rX\n\tz"
    assert escape_terminal(text) == "a\\x1b[2J\\x00\\x07\\u007f\\u009b\\u0085\\ud800\\rX\n\tz"
    line = _one_line(f"--dataset {text}: no such file")
    assert not RAW.search(line) and "\n" not in line and "\t" not in line
    assert "\\x1b[2J\\x00" in line and "\\n\\tz" in line


def test_a_file_name_with_escapes_is_printed_escaped_on_the_card(tmp_path, fresh_registry,
                                                                capsys):
    """The reproduction: `repro data prepare` on a folder that holds a file named with an
    OSC title sequence and a clear-screen; the card lists it among the files not read."""
    from test_dataset_spec_options import FOLDER_SPEC, _amc_folder

    src = _amc_folder(tmp_path)
    (src / f"{EVIL}.txt").write_text("not a clip\n")
    spec = tmp_path / "fold.toml"
    spec.write_text(FOLDER_SPEC.format(path=src, asf="body.asf", extra=""))
    rc, out, err = _cli(capsys, "data", "prepare", str(spec))
    assert rc == 0, err
    assert "matched no pattern" in out
    assert "\\x1b]0;PWNED" in out and "\\x1b[2J" in out  # shown, as escapes
    assert not RAW.search(out) and not RAW.search(err)


def test_error_lines_escape_esc_and_nul(tmp_path, capsys):
    """`--dataset PATH.toml` is quoted as given in its error (it used to be raw)."""
    rc, out, err = _cli(capsys, "plan", "marionette/table1", "--dataset",
                        str(tmp_path / f"{EVIL}\x00\x85.toml"))
    assert rc == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("repro: error: --dataset ")
    assert "\\x1b]0;PWNED\\x07\\x1b[2J\\x00\\u0085.toml" in err and not RAW.search(err)


def test_stdout_of_any_print_is_escaped_and_streams_come_back(tmp_path, capsys):
    """A data-set spec at a path with escapes, checked: the path is echoed on stdout."""
    from test_dataset_spec_options import FOLDER_SPEC

    spec = tmp_path / f"{EVIL}\x9b.toml"
    spec.write_text(FOLDER_SPEC.format(path=".", asf="body.asf", extra=""))
    before = sys.stdout, sys.stderr
    rc, out, err = _cli(capsys, "data", "check", str(spec))
    assert rc == 0, err
    assert "\\x1b[2J\\u009b.toml: ok" in out and not RAW.search(out)
    assert (sys.stdout, sys.stderr) == before  # the filters are gone after the command


def test_rich_styling_survives_and_the_data_inside_it_is_escaped(monkeypatch):
    """On a terminal rich still colours (its own ESC sequences pass), and a name inside a
    styled text comes out escaped; without the filter it would come out raw."""
    from rich.console import Console
    from rich.text import Text

    from cli.main import terminal_guard

    raw = io.StringIO()
    raw.isatty = lambda: True
    monkeypatch.setattr(sys, "stdout", raw)
    with terminal_guard():
        Console(force_terminal=True, color_system="standard").print(
            Text(f"clip {EVIL}\x9b", style="bold"))
        print(f"plain {EVIL}")
    got = raw.getvalue()
    assert got.startswith("\x1b[1m")  # rich's bold, raw: the terminal styles it
    assert "clip \\x1b]0;PWNED" in got and "\\x1b[2J\\u009b" in got
    assert "plain \\x1b]0;PWNED\\x07\\x1b[2J" in got
    assert "\x1b]" not in got and "\x1b[2J" not in got and "\x9b" not in got


def test_csv_rows_keep_their_crlf_and_del_is_json_safe():
    """``csv`` ends rows with CRLF: it passes the filter as it is (a CR that ends a line is
    harmless; `repro show --format csv` wrote a literal backslash-r before every LF); a CR
    alone is escaped; DEL and C1 come out as ``\\u007f`` / ``\\u009b``, valid in a JSON
    string."""
    import json

    from cli.main import TerminalStream, escape_terminal

    raw = io.StringIO()
    csv.writer(TerminalStream(raw)).writerows([["table", "n"], ["t1", "3"]])
    assert raw.getvalue() == "table,n\r\nt1,3\r\n"
    assert escape_terminal("a\rb\r\n") == "a\\rb\r\n"
    assert escape_terminal("x\x7fy\x9b") == "x\\u007fy\\u009b"
    assert json.loads('"' + escape_terminal("x\x7fy\x9b") + '"') == "x\x7fy\x9b"


def test_a_traceback_is_escaped_too():
    """A bug's traceback (printed after the command, by sys.excepthook) may quote data: an
    exception that leaves the guard is printed escaped by the hook the guard installed; a
    command that ends normally gives the process its hook back."""
    code = ("import sys, cli.main as m\n"
            "with m.terminal_guard():\n    pass\n"
            "assert sys.excepthook is sys.__excepthook__, 'hook left installed'\n"
            "with m.terminal_guard():\n"
            f"    raise ValueError('bad name ' + {EVIL!r})\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60, cwd=Path(__file__).resolve().parents[1])
    assert proc.returncode == 1 and "hook left installed" not in proc.stderr, proc.stderr
    assert "ValueError: bad name \\x1b]0;PWNED\\x07\\x1b[2J" in proc.stderr
    assert not RAW.search(proc.stderr)


def test_styling_passes_through_rich_s_own_stream_redirection(monkeypatch):
    """A progress display on a terminal redirects sys.stdout / sys.stderr to rich's FileProxy,
    whose real file is the filter: rich's codes still pass, data is still escaped."""
    from rich.console import Console
    from rich.file_proxy import FileProxy
    from rich.text import Text

    from cli.main import terminal_guard

    raw = io.StringIO()
    raw.isatty = lambda: True
    monkeypatch.setattr(sys, "stdout", raw)
    with terminal_guard():
        live = Console(force_terminal=True, color_system="standard")
        monkeypatch.setattr(sys, "stdout", FileProxy(live, sys.stdout))  # as rich's Live does
        Console(force_terminal=True, color_system="standard").print(
            Text(f"job {EVIL}", style="bold"))
        sys.stdout.write(f"printed meanwhile {EVIL}\n")
        sys.stdout.flush()
    got = raw.getvalue()
    assert "\x1b[1mjob \\x1b]0;PWNED\\x1b[2J\x1b[0m" in got  # rich's bold, the data escaped
    assert "printed meanwhile " in got  # (rich's FileProxy reads a print as ANSI: drops codes)
    assert "\x1b]" not in got and "\x1b[2J" not in got and "\x07" not in got


def test_rich_imported_after_the_guard_is_patched_before_it_renders():
    """The guard does not import rich (``repro plan`` prints without it: issue 31's 0.5 s); a
    rich imported later, inside the guard, is patched as it loads: its styling passes, the
    data inside is escaped (also after a look-up that only asked for rich's spec).  In a fresh
    process, so rich is not loaded beforehand."""
    code = ("import io, sys\n"
            "import cli.main as m\n"
            "raw = io.StringIO(); raw.isatty = lambda: True; sys.stdout = raw\n"
            "with m.terminal_guard():\n"
            "    assert 'rich.console' not in sys.modules, 'the guard imported rich'\n"
            "    import importlib.util\n"
            "    assert importlib.util.find_spec('rich.console') is not None\n"  # a probe
            "    from rich.console import Console\n"
            "    from rich.text import Text\n"
            "    Console(force_terminal=True, color_system='standard').print(\n"
            f"        Text('clip ' + {EVIL!r}, style='bold'))\n"
            "sys.stdout = sys.__stdout__\n"
            "print(repr(raw.getvalue()))\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60, cwd=Path(__file__).resolve().parents[1])
    assert proc.returncode == 0, proc.stderr
    import ast

    got = ast.literal_eval(proc.stdout.strip())
    assert got.startswith("\x1b[1m")  # rich's bold, raw
    assert "clip \\x1b]0;PWNED" in got and "\\x1b[2J" in got  # (rich drops the BEL itself)
    assert "\x1b]" not in got and "\x1b[2J" not in got
