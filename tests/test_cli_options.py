"""Bad options end before anything is computed: one error line naming the option, exit 2, no
traceback, no run recorded (issue 16's crash paths for the table and eval commands)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from repro.paths import repo_root


def _repro(*args, home):
    env = {**os.environ, "REPRO_HOME": str(home)}
    return subprocess.run([sys.executable, "-m", "cli.main", *args], capture_output=True,
                          text=True, env=env, cwd=repo_root(), timeout=120)


@pytest.mark.parametrize("args, says", [
    (["run", "marionette/table1", "--jobs", "0"], "--jobs: must be at least 1"),
    (["run", "marionette/table1", "--jobs", "-1"], "--jobs: must be at least 1"),
    (["run", "marionette/table1", "--jobs", "two"], "--jobs: 'two' is not an integer"),
    (["run", "marionette/table1", "--format", "xml"], "--format: unknown format 'xml'"),
    (["show", "marionette/table1", "--format", "xml"], "--format: unknown format 'xml'"),
    (["run", "marionette/table1", "--seeds", ""], "--seeds ''"),
    (["run", "marionette/table1", "--seeds", "0-99999999999"], "more than 10000 seeds"),
    (["plan", "marionette/table1", "--seeds", "0-99999999999"], "more than 10000 seeds"),
    (["eval", "classifier", "--dataset", "bandai2-mini", "--train-seed", "-1"],
     "--train-seed: a seed must be >= 0"),
])
def test_bad_option_is_one_line_exit_2_and_nothing_runs(args, says, tmp_path):
    out = _repro(*args, home=tmp_path)
    assert out.returncode == 2, out.stderr
    assert says in out.stderr
    assert "Traceback" not in out.stderr
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_parse_seeds_caps_before_allocating():
    from repro.engine.table_plan import MAX_SEEDS, parse_seeds
    from repro.errors import ConfigError

    assert parse_seeds("0-4") == (0, 1, 2, 3, 4) and parse_seeds("0,3,7") == (0, 3, 7)
    assert len(parse_seeds(f"0-{MAX_SEEDS - 1}")) == MAX_SEEDS
    with pytest.raises(ConfigError, match="more than"):
        parse_seeds(f"0-{MAX_SEEDS}")
    with pytest.raises(ConfigError, match=r"\.\.\."):  # a long argument is shortened in the message
        parse_seeds("9" * 5000 + "x")


def test_rescore_without_an_earlier_run_says_so_and_trains_nothing(tmp_path):
    out = _repro("rescore", "marionette/table1", home=tmp_path)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert "no earlier run" in out.stderr and "repro run marionette/table1" in out.stderr
    store = tmp_path / "store" / "objects"
    assert not store.exists() or not any(store.rglob("weights.pt"))


def test_a_huge_value_quoted_in_an_error_is_shortened(tmp_path):
    out = _repro("run", "marionette/table1", "--seeds", "1" * 100_000 + "x", home=tmp_path)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert len(out.stderr) < 400
    # argparse's own refusals too: one line, clipped
    out = _repro("run", "marionette/table1", "--jobs", "1" * 5000, home=tmp_path)
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert out.stderr.count("\n") == 1, out.stderr
    line = out.stderr.strip()
    assert "--jobs" in line and "characters left out" in line and len(line) < 400


def test_error_messages_are_shortened_in_the_middle():
    from cli.main import MAX_ERROR_CHARS, MAX_QUOTE_CHARS, _one_line

    assert _one_line("short") == "short"
    long = "a" * 3000 + "b" * 3000
    got = _one_line(long)  # one long word: clipped to ~MAX_QUOTE_CHARS
    assert len(got) < MAX_QUOTE_CHARS + 50 and got.startswith("a") and got.endswith("b")
    assert "characters left out" in got
    words = " ".join(["w" * 150] * 100)  # many words under the quote cap: the whole is capped
    got = _one_line(f"file x.bvh: {words}")
    assert len(got) < MAX_ERROR_CHARS + 50 and got.startswith("file x.bvh: ")
    quoted = "'" + "q " * 150 + "'"  # a quoted value over the cap, spaces and all: clipped
    assert "characters left out" in _one_line(f"bad value {quoted} in x.toml")
    # an apostrophe and a closing quote are no opening quote: the files between them stay
    files = ", ".join(f"take_{k:03d}.bvh" for k in range(20))
    msg = (f"OFFSETs differ from the reference take_000.bvh's: joint 'Knee' by 0.04 cm in "
           f"{files}; raise offset_tolerance: every clip is posed on the reference's bones")
    assert len(files) > MAX_QUOTE_CHARS and _one_line(msg) == msg


def test_a_deeply_nested_spec_is_one_clear_error(tmp_path):
    """Issue 16 (part): nesting that would make the TOML parser (or anything after it) recurse
    past Python's limit is refused with one line naming the file, exit code 2."""
    import subprocess
    import sys

    for name, text in (("deep.toml", "x = " + "[" * 5000 + "]" * 5000),
                       ("deeptable.toml", "x = " + "{a = " * 3000 + "1" + "}" * 3000),
                       ("nested40.toml", "x = " + "[" * 40 + "]" * 40)):
        f = tmp_path / name
        f.write_text(text)
        r = subprocess.run([sys.executable, "-m", "cli.main", "spec", "check", str(f)],
                           capture_output=True, text=True)
        assert r.returncode == 2, r.stderr
        assert "Traceback" not in r.stderr and name in r.stderr and "nested" in r.stderr



def test_a_spec_file_may_not_claim_a_registered_table_id(tmp_path):
    """Issue 16 (part): a copy of a registered spec outside tables/ would have become that
    table's newest run; it is refused with one line, exit 2."""
    import shutil
    import subprocess
    import sys

    from repro.paths import tables_root

    copy = tmp_path / "mine.toml"
    shutil.copy(tables_root() / "marionette" / "table1.toml", copy)
    r = subprocess.run([sys.executable, "-m", "cli.main", "plan", str(copy)],
                       capture_output=True, text=True, env={"REPRO_HOME": str(tmp_path / "h"),
                                                            "PATH": "/usr/bin:/bin"})
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "claims the id 'marionette/table1'" in r.stderr and "--claim-id" in r.stderr
    r = subprocess.run([sys.executable, "-m", "cli.main", "plan", str(copy), "--claim-id"],
                       capture_output=True, text=True, env={"REPRO_HOME": str(tmp_path / "h"),
                                                            "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0, r.stderr  # asked for explicitly: allowed
    assert "jobs," in r.stdout and "to run" in r.stdout
