"""Issue 28 end to end: data sets of one's own in the shapes the issue met, built from the
bundled clips (docs/examples/own_data_sets.py), taken through ``repro data check``, ``repro
data prepare`` and ``repro plan`` (and, marked slow, ``repro run marionette/table1 --scale
quick``) by their specs and the documented options alone: docs/datasets.md's walk-through,
"Walk-through: two data sets of one's own", whose commands these are.

- the **BVH set with styles** (one take per action × style cell, a moving dummy root in the
  ``youthful`` takes, ``LowerLeg_L`` 0.04 cm longer in the ``elderly`` ones, a class of 2
  takes) is refused, one line and exit 2 each, for its split (every class: no test clip; fix
  ``by = "style"``), its dummy root (``dummy_root`` + ``fold_dummy_root``), its OFFSETs (the
  joint, the size and every file; fix ``offset_tolerance``) and, at ``repro plan``, in
  seconds, for the class Neural Marionette's split cannot test (fix ``[labels] classes``);
  prepared, its joints are the bundled clips' own;
- the **ASF/AMC set with subjects** (one ASF per subject, bones 0 to 6 % longer, labels and
  subjects from a CSV, ``run`` by three subjects) is refused for its split (``run``: no test
  clip; fix ``stratify = "action"``), a single ASF across subjects (fix ``asf = "*.asf"``),
  the subjects' bone lengths (fix ``offset_tolerance`` above them) and the hips its names
  point to, which start at one point (fix ``[skeleton] hips``); prepared, every take is posed
  on subject 01's bones, the bundled clips' own.

The commands run in this process (``cli.main.main``: the same parser, the same one-line errors
and exit codes as the ``repro`` script) so that the whole walk-through takes seconds.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

from repro.paths import repo_root
from test_dataset_spec_options import fresh_registry  # noqa: F401 (fixture)

DOC = repo_root() / "docs" / "datasets.md"
SECTION = "### Walk-through: two data sets of one's own"
#: the folder the docs' commands write into (the tests replace it by a temporary one)
OUT = "build/own"


def builder():
    """docs/examples/own_data_sets.py as a module."""
    path = repo_root() / "docs" / "examples" / "own_data_sets.py"
    spec = importlib.util.spec_from_file_location("own_data_sets", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def add(text: str, section: str, *lines: str) -> str:
    """``text`` with ``lines`` at the end of its ``[section]`` (appended when absent)."""
    rows = text.rstrip("\n").split("\n")
    if f"[{section}]" not in rows:
        return "\n".join(rows + ["", f"[{section}]", *lines]) + "\n"
    i = rows.index(f"[{section}]") + 1
    while i < len(rows) and not rows[i].startswith("["):
        i += 1
    while rows[i - 1] == "":
        i -= 1
    return "\n".join(rows[:i] + list(lines) + rows[i:]) + "\n"


def repro(capsys, cmd: str, out: Path):
    """Run the docs' command ``cmd`` (``repro ...`` on ``build/own``) on ``out``: (exit code,
    stdout, stderr lines, seconds)."""
    from cli.main import main
    from repro.engine import steps

    argv = shlex.split(cmd.replace(OUT, str(out)))
    assert argv[0] == "repro"
    steps.clipset.cache_clear()  # loaded once per process: a new process each, as `repro` is
    capsys.readouterr()
    t0 = time.perf_counter()
    try:
        rc = main(argv[1:])
    except SystemExit as e:  # argparse
        rc = e.code
    seconds = time.perf_counter() - t0
    got = capsys.readouterr()
    return rc, got.out, got.err.strip().splitlines(), seconds


def refused(result, *needles: str) -> str:
    """The one error line of a refused command (exit 2), holding every needle."""
    rc, _out, err, _s = result
    assert rc == 2 and len(err) == 1, (rc, err)
    assert err[0].startswith("repro: error: ") and "Traceback" not in err[0]
    for n in needles:
        assert n in err[0], (n, err[0])
    return err[0]


def ok(result) -> str:
    rc, out, err, _s = result
    assert rc == 0, err
    return out


def per_class(out: str) -> dict[str, list[int]]:
    """`repro data check`'s per-class rows: class -> [clips, train, test, NM test]."""
    return {ln.split("│")[1].strip(): [int(c) for c in ln.split("│")[2:6]]
            for ln in out.splitlines() if ln.count("│") >= 6}


def check_cmd(name: str) -> str:
    return f"repro data check {OUT}/{name}/{name}.toml"


def prepare_cmd(name: str) -> str:
    return f"repro data prepare {OUT}/{name}/{name}.toml"


def plan_cmd(name: str) -> str:
    return f"repro plan marionette/table1 --dataset {OUT}/{name}/{name}.toml"


def run_cmd(name: str) -> str:
    return f"repro run marionette/table1 --scale quick --dataset {OUT}/{name}/{name}.toml"


BUILD_CMD = f".venv/bin/python docs/examples/own_data_sets.py {OUT}"
#: the ASF/AMC set, split by subject, fails the standard gate on FID(train, test): scored with
#: the gate off, the run marked NON-STANDARD
NO_GATE = " --no-gate"
#: every command of the walk-through (the docs may show no other)
COMMANDS = {BUILD_CMD, run_cmd("subjects") + NO_GATE,
            *(f(n) for f in (check_cmd, prepare_cmd, plan_cmd, run_cmd)
              for n in ("styles", "subjects"))}


@pytest.fixture(scope="module")
def bundled(tmp_path_factory):
    """The bundled clips, read once per module (into a REPRO_HOME of the module's own)."""
    from repro.data.bundle import load_mini

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("REPRO_HOME", str(tmp_path_factory.mktemp("own-data-home")))
        yield load_mini()


def walk(name: str, tmp_path: Path, capsys, bundled):
    """(the builder, the spec file of the set ``name`` written under ``tmp_path``, and
    ``run(cmd, text)``: the docs' command ``cmd`` with the spec holding ``text``)."""
    own = builder()
    spec = getattr(own, f"write_{name}_set")(tmp_path / name, bundled)

    def run(cmd: str, text: str):
        spec.write_text(text)
        return repro(capsys, cmd, tmp_path)
    return own, spec, run


def prepared(spec: Path):
    """The prepared ClipSet of ``spec``."""
    from repro.data.dataset_registration import register_spec_path
    from repro.data.registry import load_clipset

    return load_clipset(register_spec_path(str(spec)))


def _joints(clips, i: int) -> np.ndarray:
    s, n = int(clips.starts[i]), int(clips.lengths[i])
    return np.asarray(clips.joints[s:s + n], np.float64)


# ------------------------------------------------------------------ the BVH set with styles
def test_a_bvh_set_with_styles_by_its_spec_alone(tmp_path, fresh_registry, capsys, bundled):
    own, spec, run = walk("styles", tmp_path, capsys, bundled)
    takes = own.style_takes(bundled)
    assert len(takes) == 9 * 7 + 2 and spec.read_text() == own.STYLES_SPEC

    # 1. one take per (action, style) cell: the default split puts round(0.2 × 1) = 0 of each
    # cell in test; refused from the file names, before any clip is parsed
    text = own.STYLES_FIRST
    r = run(check_cmd("styles"), text)
    line = refused(r, "'wave-right-hand' (2 clips)", "'walk' (7 clips)", "would have no test "
                   "clip", '[split] by = "style"')
    assert line.count(" clips)") == 10 and r[3] < 10
    assert "65 clip file(s), 65 clip(s) kept" in r[1]
    assert "gives no test clip to wave-right-hand (a class needs at least 3 clips)" in \
        " ".join(r[1].split())

    # 2. whole styles to test: every class on both sides
    text = add(text, "split", 'by = "style"')
    out = ok(run(check_cmd("styles"), text))
    rows = per_class(out)
    assert len(rows) == 10 and all(c[1] >= 1 and c[2] >= 1 for c in rows.values())
    assert rows["wave-right-hand"] == [2, 1, 1, 0] and rows["walk"][3] == 1

    # 3. the dummy root above the hips: Hips' position channels move it
    r = run(prepare_cmd("styles"), text)
    refused(r, "dataset-2_raise-up-both-hands_active_039.bvh: position channels of 'Hips' move "
            "it", "dummy_root = 'joint_Root' and fold_dummy_root = true")
    text = add(text, "skeleton", 'dummy_root = "joint_Root"')
    r = run(prepare_cmd("styles"), text)
    refused(r, "dataset-2_raise-up-both-hands_youthful_", "dummy root 'joint_Root' is not all "
            "zero", "fold it into 'Hips': [skeleton] fold_dummy_root = true")

    # 4. the elderly session's LowerLeg_L: the joint, the size and every file
    text = add(text, "skeleton", "fold_dummy_root = true")
    r = run(prepare_cmd("styles"), text)
    line = refused(r, "OFFSETs of 9 of 65 files differ from the reference "
                   "dataset-2_raise-up-both-hands_active_039.bvh's",
                   "by more than [skeleton] offset_tolerance = 1e-05 m",
                   "joint 'LowerLeg_L' by 0.04 cm in ", "raise offset_tolerance")
    elderly = [f"dataset-2_{a}_elderly_" for a, s, _ in takes if s == "elderly"]
    assert len(elderly) == 9 and all(f in line for f in elderly), line
    assert "left out" not in line and line.count(".bvh") == 10  # the reference and the 9

    # 5. within the tolerance: prepared; every take on the reference's bones
    text = add(text, "skeleton", "offset_tolerance = 0.001")
    out = ok(run(prepare_cmd("styles"), text))
    assert "lab-styles: prepared: 65 clips" in out
    assert "10 classes, 7 styles, 30 fps, 21 joints" in out  # joint_Root folded away
    flat = " ".join(out.split())
    assert "by up to 0.04 cm (joint 'LowerLeg_L'), within [skeleton] offset_tolerance = 0.001 m"\
        in flat

    # 6. Neural Marionette's split cannot test a 2-take class: `repro plan` says so in seconds
    r = run(plan_cmd("styles"), text)
    refused(r, "marionette/table1 on data set 'lab-styles'", "'wave-right-hand' (2 clips) "
            "without a test clip", "at least 3 clips", "[labels] classes")
    assert r[3] < 10

    # 7. the class dropped by a classes subset: the spec as docs/examples writes it
    keep = sorted({a for a, _s, _i in takes} - {own.SMALL_CLASS})
    text = add(text, "labels", f"classes = {json.dumps(keep)}")
    assert tomllib.loads(text) == tomllib.loads(own.STYLES_SPEC)
    out = ok(run(prepare_cmd("styles"), own.STYLES_SPEC))
    assert "lab-styles: prepared: 63 clips" in out
    assert "2 clip(s) dropped, their class not in [labels] classes: wave-right-hand 2" in out
    out = ok(run(plan_cmd("styles"), own.STYLES_SPEC))
    assert "jobs" in out and "to run" in out

    # the prepared takes are the bundled clips' motion: the dummy folded back, the elderly
    # takes posed on the reference's (the bundled) bones
    got = prepared(spec)
    assert got.skeleton.names == bundled.skeleton.names and len(got) == 63
    assert np.allclose(got.skeleton.offsets, bundled.skeleton.offsets, atol=1e-7)
    for a, s, i in takes:
        if a == own.SMALL_CLASS:
            continue
        j = got.clip_names.index(bundled.clip_names[i])
        assert (got.label_names[got.labels[j]], got.style_names[got.styles[j]]) == (a, s)
        assert np.abs(_joints(got, j) - _joints(bundled, i)).max() < 1e-4, (a, s)
    st, split = np.asarray(got.styles), np.asarray(got.split)
    assert set(st[split == 1].tolist()).isdisjoint(st[split == 0].tolist())


# ------------------------------------------------------------ the ASF/AMC set with subjects
def test_an_asf_amc_set_with_subjects_by_its_spec_alone(tmp_path, fresh_registry, capsys,
                                                        bundled):
    own, spec, run = walk("subjects", tmp_path, capsys, bundled)
    takes = own.subject_takes(bundled)
    assert len(takes) == 9 * 7 + 3 and spec.read_text() == own.SUBJECTS_SPEC

    # 1. whole subjects to test, in the seeded order: none of run's three performers
    text = own.SUBJECTS_FIRST
    r = run(check_cmd("subjects"), text)
    refused(r, "class 'run' (3 clips) would have no test clip under the data set's split by "
            "whole subjects", '[split] stratify = "action"')
    assert r[3] < 10 and "66 clip file(s), 66 clip(s) kept" in r[1]
    text = add(text, "split", 'stratify = "action"')
    rows = per_class(ok(run(check_cmd("subjects"), text)))
    assert len(rows) == 10 and all(c[1] >= 1 and c[2] >= 1 for c in rows.values())
    assert rows["run"][:3] == [3, 2, 1]

    # 2. one ASF per subject
    r = run(prepare_cmd("subjects"), text)
    refused(r, "asf = '01/01.asf' is applied to every clip, but 6 folder(s) of clips hold their "
            "own ASF", 'one ASF per subject: write asf = "*.asf"')
    text = text.replace('asf = "01/01.asf"', 'asf = "*.asf"')

    # 3. the subjects' bones differ by up to 6 %: refused by joint, size and file (with the ASF
    # each was read with), then read as one body within a tolerance above the difference
    r = run(prepare_cmd("subjects"), text)
    line = refused(r, "OFFSETs of 56 of 66 files differ from the reference 01/01_01.amc (ASF "
                   "01/01.asf)'s", "offset_tolerance = 1e-05 m",
                   "joint 'Foot_L' by 0.41 cm to 2.46 cm in 07/07_01.amc (ASF 07/07.asf)",
                   "raise offset_tolerance")
    assert "and 46 more" in line  # 56 files counted, ten named
    text = add(text, "skeleton", "offset_tolerance = 0.03")

    # 4. the hips the names point to, Hip_L / Hip_R, both start at the root
    r = run(prepare_cmd("subjects"), text)
    refused(r, "subjects.toml: body frame: the hips found, 'Hip_L' and 'Hip_R', are at one "
            "point", "[skeleton] hips = [left, right]")
    text = add(text, "skeleton", 'hips = ["UpperLeg_L", "UpperLeg_R"]')
    assert tomllib.loads(text) == tomllib.loads(own.SUBJECTS_SPEC)
    out = ok(run(prepare_cmd("subjects"), own.SUBJECTS_SPEC))
    flat = " ".join(out.split())
    assert "lab-subjects: prepared: 66 clips" in out and "subjects: 7" in out
    assert "by up to 2.46 cm (joint 'Foot_L'), within [skeleton] offset_tolerance = 0.03 m: " \
        "every clip is posed on the reference's bones with its own root path (feet may float " \
        "or sink by the difference)" in flat
    ok(run(plan_cmd("subjects"), own.SUBJECTS_SPEC))

    # every take read with its own subject's ASF and posed on subject 01's bones, which are
    # the bundled skeleton's, with its own root path (subject n's: the bundled path times
    # 1 + 0.01 (n - 1)): the bundled joints moved by the root's difference, so a taller
    # subject's feet float by it (the root is 'root', the connector bones Hip_L ... are extra
    # joints)
    got = prepared(spec)
    names = ["root" if n == "Hips" else n for n in bundled.skeleton.names]
    cols = [got.skeleton.names.index(n) for n in names]
    meta_subjects = {}
    for subject, clip, action, i in takes:
        j = got.clip_names.index(clip)
        assert got.label_names[got.labels[j]] == action
        meta_subjects[clip] = subject
        want = _joints(bundled, i)
        want = want + (own.subject_scale(subject) - 1) * want[:, :1]
        assert np.abs(_joints(got, j)[:, cols] - want).max() < 1e-4, clip
    split = dict(zip(got.clip_names, np.asarray(got.split).tolist()))
    test_subjects = {meta_subjects[c] for c, s in split.items() if s == 1}
    assert test_subjects.isdisjoint({meta_subjects[c] for c, s in split.items() if s == 0})
    assert test_subjects & set(own.FEW_SUBJECTS)  # stratified: run has a test clip


def test_each_subjects_asf_has_its_own_bone_lengths():
    """The ASFs are the stand-in's skeleton, each subject's bones 1 + 0.01 (n - 1) times its
    lengths: read back, subject 07's thigh is 6 % longer than subject 01's."""
    from repro.data.asf_amc import parse_asf
    from repro.data.bundle import load_mini

    own = builder()
    sk = load_mini().skeleton
    lengths = {s: {b.name: b.length for b in parse_asf(own.asf_text(sk, own.subject_scale(s), s),
                                                       f"{s}.asf").bones.values()}
               for s in ("01", "07")}
    assert lengths["01"]["UpperLeg_L"] == pytest.approx(100 * np.linalg.norm(
        sk.offsets[sk.index("LowerLeg_L")]), abs=1e-5)
    for b, v in lengths["01"].items():
        assert lengths["07"][b] == pytest.approx(1.06 * v, rel=1e-5), b


# ---------------------------------------------------------------------------- the docs
def walkthrough() -> str:
    text = DOC.read_text()
    assert SECTION in text, f"{DOC} lost its section {SECTION!r}"
    part = text.split(SECTION, 1)[1]
    return part.split("\n## ", 1)[0].split("\n### ", 1)[0]


def test_the_docs_walkthrough_shows_these_commands_and_specs():
    """Every command the walk-through shows is one these tests run (and each is shown); its
    first and last spec of each set are the builder's, so docs and tests cannot drift."""
    own = builder()
    part = walkthrough()
    shown = [ln.split("  #", 1)[0].strip() for block in re.findall(r"```bash\n(.*?)```", part,
                                                                   flags=re.S)
             for ln in block.splitlines() if ln.strip()]
    assert set(shown) == COMMANDS, set(shown) ^ COMMANDS
    blocks = re.findall(r"```toml\n(.*?)```", part, flags=re.S)
    for spec in (own.STYLES_FIRST, own.SUBJECTS_FIRST, own.STYLES_SPEC, own.SUBJECTS_SPEC):
        assert spec in blocks, spec.splitlines()[:2]


RECORDS = repo_root() / "docs" / "results" / "own-data"
#: the walk-through's excerpt rows -> the records' rows; its columns -> the records' metrics
EXCERPT_ROWS = {"Real Test Data": "real", "MANN": "mann", "A2M": "a2m",
                "Ours (MARIONET)": "marionet", "ACTOR": "actor",
                "nearest training clip": "nearest_clip"}
EXCERPT_COLS = ("fid", "acc", "div", "multimod", "traj_err")


def _finished_runs(name: str) -> list[Path]:
    return sorted(p for p in (RECORDS / name).iterdir() if (p / "summary.json").is_file())


def test_the_recorded_tables_are_shown_as_they_render(tmp_path, monkeypatch):
    """docs/results/own-data/README.md shows each set's recorded table as `repro show`
    renders it, and the walk-through's excerpts are the records' cell means."""
    from repro.engine.runner import table_view
    from repro.report import render

    runs = {name: _finished_runs(name) for name in ("styles", "subjects")}
    assert [len(r) for r in runs.values()] == [1, 1]
    for r in runs.values():
        shutil.copytree(r[0], tmp_path / "runs" / r[0].name)
    monkeypatch.setenv("REPRO_HOME", str(tmp_path))
    readme = "\n".join(ln.rstrip() for ln in (RECORDS / "README.md").read_text().splitlines())
    tables = re.findall(r"\| row \| FID↓ \| Acc↑ \| Div↑ \| Multi-m↑ \| Δ_Traj↓ \|\n\|[-|]+\|\n"
                        r"((?:\|.*\|\n)+)", walkthrough())
    assert len(tables) == 2
    for (name, r), table in zip(runs.items(), tables):
        rj = json.loads((r[0] / "run.json").read_text())
        assert rj["dataset"] == f"lab-{name}" and rj["status"] == "FINISHED"
        md = render(table_view(rj["table"], scale=rj["scale"], run=rj["run_id"]), "md")
        assert "\n".join(ln.rstrip() for ln in md.strip().splitlines()) in readme, name
        cells = json.loads((r[0] / "summary.json").read_text())["cells"]
        rows = [[c.strip() for c in ln.strip("|").split("|")] for ln in table.splitlines()]
        assert [row[0] for row in rows] == list(EXCERPT_ROWS)
        for row in rows:
            for col, text in zip(EXCERPT_COLS, row[1:]):
                cell = cells[EXCERPT_ROWS[row[0]]].get(col)
                if text in ("/", "not measured"):  # not in the paper / no value (NaN)
                    assert cell is None, (name, row[0], col)
                    continue
                want = cell["mean"]
                got = float(text.replace("−", "-"))
                assert abs(got - want) <= (5e-4 if abs(want) > 1e-3 else 1e-8), \
                    (name, row[0], col, got, want)


# ---------------------------------------------------------------------------- end to end
def _cli(cmd: str, out: Path, home: Path) -> tuple[subprocess.CompletedProcess, float]:
    argv = shlex.split(cmd.replace(OUT, str(out)))
    argv = ([sys.executable, *argv[1:]] if argv[0] == ".venv/bin/python"
            else [sys.executable, "-m", "cli.main", *argv[1:]])
    t0 = time.perf_counter()
    r = subprocess.run(argv, capture_output=True, text=True, cwd=repo_root(), timeout=7200,
                       env={**os.environ, "REPRO_HOME": str(home), "REPRO_DATASETS": ""})
    return r, time.perf_counter() - t0


@pytest.mark.slow
@pytest.mark.parametrize("name", ["styles", "subjects"])
def test_marionette_table1_runs_on_each_set_by_its_spec_alone(name, tmp_path, _repro_home):
    """`repro run marionette/table1 --scale quick` on the spec as it ends the walk-through: a
    table marked as the declared data set's.  The BVH set passes the standard real-data gate;
    the ASF/AMC set (whole subjects, hence styles, in test) fails it on FID(train, test),
    one line naming --no-gate, and is then scored with the gate off, marked NON-STANDARD.
    With $REPRO_OWN_DATA_RECORD set, what the commands printed, their wall times and the
    runs' records are written there (docs/results/own-data/<name>/)."""
    steps = [BUILD_CMD, prepare_cmd(name), run_cmd(name)]
    if name == "subjects":
        steps.append(run_cmd(name) + NO_GATE)
    printed = {}
    for cmd in steps:
        r, seconds = _cli(cmd, tmp_path, _repro_home)
        assert "Traceback" not in r.stderr
        printed[cmd] = (r, seconds)
        if cmd == run_cmd("subjects"):
            lines = [ln for ln in r.stderr.splitlines() if ln.startswith("repro: error: ")]
            assert r.returncode == 2 and len(lines) == 1, r.stderr[-3000:]
            for needle in ("real-data gate failed for lab-subjects", "methods are not scored: "
                           "real FID(train, test) ", "exceeds the bound 3.000",
                           "pass --no-gate (or set [gate] enabled = false"):
                assert needle in lines[0], (needle, lines[0])
            assert "Real-data gate: standard (on, margin 0.050, the scale profile's): " \
                "FAILED." in r.stderr
        else:
            assert r.returncode == 0, (cmd, r.stderr[-3000:])
    r = printed[steps[-1]][0]
    data = f"lab-{name}"
    assert f"[OWN DATA: {data}]" in r.stdout
    assert f"Data: {data} (declared by {tmp_path / name / name}.toml)" in r.stdout
    if name == "styles":
        assert "Real-data gate: standard (on, margin 0.050, the scale profile's): passed." \
            in r.stdout and "NON-STANDARD" not in r.stdout
    else:
        assert "[NON-STANDARD GATE: off]" in r.stdout
        assert "Real-data gate: NON-STANDARD, RELAXED: off (command line (--no-gate)): " \
            "FAILED, not enforced; not a standard run. The standard gate would have FAILED: " \
            "real FID(train, test) " in " ".join(r.stdout.split())
    record = os.environ.get("REPRO_OWN_DATA_RECORD")
    if record:
        _record(Path(record) / name, printed, tmp_path, _repro_home)


def _record(dest: Path, printed: dict, out: Path, home: Path) -> None:
    """What the commands printed (the temporary folder shown as the docs' ``build/own``), their
    exit codes and wall times, the commit each run recorded, and the runs' folders."""
    dest.mkdir(parents=True, exist_ok=True)
    runs = sorted(p for p in (home / "runs").iterdir() if (p / "run.json").is_file())
    lines = []
    for k, (cmd, (res, s)) in enumerate(printed.items()):
        lines.append(f"{cmd}: exit {res.returncode}, {s:.0f} s wall")
        if cmd.startswith("repro "):
            stem = f"{k}-{cmd.split()[1]}"
            (dest / f"{stem}.stdout.txt").write_text(res.stdout.replace(str(out), OUT))
            (dest / f"{stem}.stderr.txt").write_text(res.stderr.replace(str(out), OUT))
    for run in runs:
        rj = json.loads((run / "run.json").read_text())
        lines.append(f"run {run.name}: {rj['status']}, commit {rj['git']['commit']}"
                     f"{' (dirty)' if rj['git'].get('dirty') else ''}")
        (dest / run.name).mkdir(exist_ok=True)
        for f in ("run.json", "summary.json", "trainings.json", "values.jsonl"):
            if (run / f).is_file():  # as recorded (the spec's temporary path and all)
                shutil.copyfile(run / f, dest / run.name / f)
    (dest / "commands.txt").write_text("\n".join(lines) + "\n")
