"""The README is true: every command in its ```bash blocks is known here and runs.

Each command gets a mode: ``fast`` (runs in ``make test`` on the bundled data), ``data``
(needs the stand-in archive), ``slow`` (minutes: training every method of a table), or ``ci``
(``make setup`` / ``make test``, which ``.ci/run`` itself runs).  A README command missing from
:data:`MODES` fails the test, so the README cannot grow an unchecked command.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys

import pytest

from repro.paths import find_bandai_archive, repo_root

MODES = {
    "make setup": "ci",
    "make test": "ci",
    "make browser": "ci",
    "repro report marionette/table1 --out report/": "slow",
    "repro strips marionette/table1 --out strips/": "slow",
    "repro export marionette/table1 --row marionet --item 0 --out export/": "slow",
    "make table3": "slow",
    "make table1": "slow",
    "repro list": "fast",
    "repro plan marionette/table1 --why": "fast",
    "repro run marionette/table1 --scale quick": "slow",
    "repro show marionette/table1 --format md": "fast",
    "repro rescore marionette/table1": "slow",
    "repro sweep marionette/table1 --budget 0.5,1,2,4": "slow",
    "repro runs show latest": "slow",
    "repro runs ls": "fast",
    "repro claims": "fast",
    "repro cache verify": "fast",
    "repro spec check": "fast",
    "repro doctor": "fast",
    "repro data info bandai2-mini": "fast",
    "repro data info bandai2-seq-mini": "fast",
    "repro data prepare bandai2 --source ../shared/data/bandai-namco-2/bandai-namco-research-motiondataset-2.tar.xz": "data",
    "repro data info bandai2 --json": "data",
    "repro data check docs/examples/bandai2-declared.toml": "fast",
    "repro data prepare docs/examples/bandai2-declared.toml": "data",
    "repro run marionette/table1 --dataset docs/examples/bandai2-declared.toml": "slow",
    "repro eval classifier --dataset bandai2 --scale medium": "slow",
    "repro eval real --dataset bandai2 --json": "slow",
    "repro run marionette/table1 --scale quick --executor ray": "slow",
    "repro runs export latest --mlflow mlruns/": "slow",
    "make ci-tables": "slow",
    "repro run marionette/table1 --scale quick --fast-kernels": "slow",
    # the lab example: one sequence (each step needs the one before), tests below
    ".venv/bin/python docs/examples/lab_example.py build/lab": "lab",
    "repro data prepare build/lab/lab.toml": "lab",
    "repro eval real --dataset build/lab/lab.toml --json": "lab-slow",
    "repro run marionette/table1 --scale quick --dataset build/lab/lab.toml": "lab-slow",
}


def readme_commands() -> list[str]:
    text = (repo_root() / "README.md").read_text()
    cmds = []
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
        for line in block.splitlines():
            line = line.split("  #", 1)[0].strip()
            if not line:
                continue
            cmds.append(line.replace(".venv/bin/repro", "repro"))  # .venv/bin/python stays
    return cmds


def test_every_readme_command_is_known():
    unknown = [c for c in readme_commands() if c not in MODES]
    assert not unknown, f"README commands with no test mode: {unknown}"


def _run(cmd: str, home) -> subprocess.CompletedProcess:
    env = {**os.environ, "REPRO_HOME": str(home)}
    if cmd.startswith("make "):
        argv = ["make", "-s", *cmd.split()[1:], f"REPRO={sys.executable} -m cli.main"]
    elif cmd.startswith(".venv/bin/python "):
        argv = [sys.executable, *shlex.split(cmd)[1:]]
    else:
        argv = [sys.executable, "-m", "cli.main", *shlex.split(cmd)[1:]]
    return subprocess.run(argv, capture_output=True, text=True, env=env, cwd=repo_root(),
                          timeout=3600)


def _params(mode: str):
    return [c for c in readme_commands() if MODES.get(c) == mode]


@pytest.mark.parametrize("cmd", _params("fast"))
def test_fast_readme_command_runs(cmd, _repro_home):
    out = _run(cmd, _repro_home)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "Traceback" not in out.stderr


@pytest.mark.data
def test_data_readme_commands_run(tmp_path_factory):
    if find_bandai_archive() is None:
        pytest.skip("needs the stand-in archive")
    home = tmp_path_factory.mktemp("readme-data-home")
    for cmd in _params("data"):
        out = _run(cmd, home)
        assert out.returncode == 0, (cmd, out.stderr[-3000:])


@pytest.mark.slow
@pytest.mark.parametrize("cmd", _params("slow"))
def test_slow_readme_command_runs(cmd, _repro_home):
    if "bandai2" in cmd.split() and find_bandai_archive() is None:
        pytest.skip("needs the stand-in archive")
    if "--dataset bandai2" in cmd:
        prep = _run("repro data prepare bandai2", _repro_home)
        assert prep.returncode == 0, prep.stderr[-3000:]
    out = _run(cmd, _repro_home)
    assert out.returncode == 0, out.stderr[-3000:]


def _lab_sequence(modes: tuple[str, ...], home, tmp_path):
    """The README's lab example in order, writing into ``tmp_path`` instead of build/lab."""
    for cmd in [c for c in readme_commands() if MODES.get(c) in modes]:
        out = _run(cmd.replace("build/lab", str(tmp_path / "lab")), home)
        assert out.returncode == 0, (cmd, out.stderr[-3000:])
        assert "Traceback" not in out.stderr
    return out


def test_lab_example_prepares(_repro_home, tmp_path):
    out = _lab_sequence(("lab",), _repro_home, tmp_path)
    assert "lab-example: prepared: 280 clips" in out.stdout and "per class" in out.stdout


@pytest.mark.slow
def test_lab_example_end_to_end(_repro_home, tmp_path):
    out = _lab_sequence(("lab", "lab-slow"), _repro_home, tmp_path)
    assert "[OWN DATA: lab-example]" in out.stdout
