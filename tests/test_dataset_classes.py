"""Issue 28 items 3, 6, 7 and 10d: classes, class subsets and splits of a declared data set,
checked from the file names before any clip is parsed.

- a data set whose own split leaves a class without a test (or training) clip is refused by
  ``repro data prepare`` in seconds, before parsing, naming each class, its clip count and
  the fix; ``repro data check`` reports the same with per-class counts and unused classes;
- ``repro plan`` / ``repro run`` refuse a table whose protocol split (Neural Marionette's
  per-class rule) leaves a class without a test clip, by name, before any training;
- ``include`` takes a list, ``exclude`` leaves files out, a ``classes`` subset drops the
  other classes' clips (counted on the card), ``unlisted = "drop"`` drops clips the labels
  do not name (the default still refuses them);
- ``[split] by = "style"`` (and ``by = "subject"`` with ``stratify = "action"``) keeps groups
  whole and gives every action test and training clips.

The data sets are written here from one tiny valid clip (``fuzz_dataset_strategies.BVH``:
hips, two legs, a head; 30 fps) under file names that carry the labels.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fuzz_dataset_strategies import BVH
from repro.paths import repo_root
from test_dataset_spec_options import fresh_registry  # noqa: F401 (fixture)

PATTERN = r"^set_(?P<action>[a-z]+)_(?P<style>[a-z]+)_\d+$"


def write_set(folder: Path, cells: dict[tuple[str, str], int], *, extra: str = "",
              labels: str | None = None, bad: set[str] = frozenset()) -> Path:
    """``folder/takes/set_<action>_<style>_<k>.bvh`` for each (action, style) cell and a spec
    ``folder/s.toml`` (labels from the names unless ``labels`` gives a side-file section);
    the clips named in ``bad`` hold bytes that are no BVH (parsing them would fail)."""
    takes = folder / "takes"
    takes.mkdir(parents=True, exist_ok=True)
    for (action, style), n in cells.items():
        for k in range(n):
            stem = f"set_{action}_{style}_{k}"
            (takes / f"{stem}.bvh").write_bytes(b"not a bvh" if stem in bad else BVH)
    lab = labels or f"pattern = '{PATTERN}'"
    (folder / "s.toml").write_text(f'schema = 1\nname = "cls"\n[source]\npath = "takes"\n'
                                   f"[labels]\n{lab}\n{extra}")
    return folder / "s.toml"


def cli(*args: str, env: dict | None = None):
    return subprocess.run([sys.executable, "-m", "cli.main", *args], capture_output=True,
                          text=True, cwd=repo_root(),
                          env={**os.environ, "REPRO_DATASETS": "", **(env or {})}, timeout=300)


def one_line(out, *needles: str) -> str:
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 2 and len(lines) == 1, (out.returncode, out.stderr[-2000:])
    assert lines[0].startswith("repro: error: ") and "Traceback" not in out.stderr
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


def grid(actions, styles, n: int = 1) -> dict:
    return {(a, s): n for a in actions for s in styles}


# ------------------------------------------------------------------ item 3: prepare refuses
def test_prepare_refuses_a_class_without_test_clips_before_parsing(tmp_path, fresh_registry,
                                                                    _repro_home):
    """'kick' has 2 clips in one style: round(2 × 0.2) = 0 of them go to test.  Every other
    clip of the set is no BVH at all: the refusal must come from the names alone (before,
    the clips were parsed first and the class only warned about on the card)."""
    cells = {**grid(["walk", "run"], ["calm", "angry"], 5), ("kick", "calm"): 2}
    bad = {f"set_walk_calm_{k}" for k in range(5)}
    spec = write_set(tmp_path, cells, bad=bad)
    t0 = time.perf_counter()
    out = cli("data", "prepare", str(spec))
    assert time.perf_counter() - t0 < 10
    line = one_line(out, "'kick' (2 clips)", "no test clip", "s.toml",
                    '[split] by = "style"', "test_fraction to at least 0.25", "[labels] classes")
    assert "'walk'" not in line and "'run'" not in line
    out = cli("data", "check", str(spec))  # the same, without preparing, after the counts
    one_line(out, "'kick' (2 clips)", "no test clip")
    assert "per class" in out.stdout and "kick" in out.stdout


def test_a_class_left_without_training_clips_is_refused_too(tmp_path, fresh_registry,
                                                            _repro_home):
    from repro.data.dataset_prepare import prepare_dataset
    from repro.errors import DataError

    spec = write_set(tmp_path, {**grid(["walk"], ["a", "b"], 4), ("jump", "a"): 1},
                     extra="[split]\ntest_fraction = 0.5\n")
    with pytest.raises(DataError, match=r"'jump' \(1 clip\) would have no training clip.*"
                                        r"lower \[split\] test_fraction below 0.5"):
        prepare_dataset(spec)


def test_data_check_reports_counts_unused_classes_and_marionettes_split(tmp_path,
                                                                        fresh_registry):
    """`repro data check` applies the label rules to the file names: per-class counts, the
    data set's own train / test counts, Neural Marionette's per-class test counts, an unused
    class named in ``classes`` (before: found only after a full parse)."""
    cells = {**grid(["walk", "run"], ["calm", "angry", "sad", "glad", "shy"]),
             ("kick", "calm"): 1, ("kick", "sad"): 1}
    spec = write_set(tmp_path, cells, extra='classes = ["walk", "run", "kick", "fly"]\n'
                                            '[split]\nby = "style"\n')
    out = cli("data", "check", str(spec))
    one_line(out, "['fly'] have no clip")
    assert "12 clip file(s), 12 clip(s) kept" in out.stdout
    rows = {ln.split("│")[1].strip(): [c.strip() for c in ln.split("│")[2:6]]
            for ln in out.stdout.splitlines() if ln.count("│") >= 6}
    assert rows["walk"][0] == "5" and rows["kick"][0] == "2" and rows["fly"][0] == "0"
    assert int(rows["kick"][2]) >= 1 and int(rows["kick"][1]) >= 1  # by style: both sides
    assert rows["kick"][3] == "0" and rows["walk"][3] == "1"  # round(0.2·2) = 0, round(1) = 1
    assert "Neural Marionette's split" in out.stdout and "kick" in out.stdout
    (tmp_path / "s.toml").write_text((tmp_path / "s.toml").read_text().replace(', "fly"', ""))
    out = cli("data", "check", str(spec))
    assert out.returncode == 0, out.stderr
    missing = tmp_path / "nosource.toml"
    missing.write_text('schema = 1\nname = "far"\n[source]\npath = "elsewhere"\n'
                       f"[labels]\npattern = '{PATTERN}'\n")
    out = cli("data", "check", str(missing))
    assert out.returncode == 0 and "not there: labels and split not checked" in out.stdout


# ------------------------------------------------------------------ item 3: plan and run
def test_plan_and_run_refuse_a_class_too_small_for_marionettes_split(tmp_path, fresh_registry,
                                                                      _repro_home):
    """The data set's own split (whole styles) gives 'kick' (2 clips) a test clip, so it
    prepares; Neural Marionette's per-class split gives it none (round(0.2 × 2) = 0): `repro
    plan` and `repro run` say so by name, in seconds, before any training."""
    cells = {**grid(["walk", "run", "jump"], ["calm", "angry", "sad", "glad", "shy"]),
             ("kick", "calm"): 1, ("kick", "sad"): 1}
    spec = write_set(tmp_path, cells, extra='[split]\nby = "style"\n')
    assert cli("data", "prepare", str(spec)).returncode == 0
    for cmd in (("plan", "marionette/table1"), ("run", "marionette/table1", "--scale", "quick")):
        t0 = time.perf_counter()
        out = cli(*cmd, "--dataset", str(spec))
        assert time.perf_counter() - t0 < 60
        one_line(out, "marionette/table1", "Neural Marionette's per-class split",
                 "'kick' (2 clips)", "without a test clip", "at least 3 clips",
                 "[labels] classes")
    out = cli("runs", "ls")
    assert "marionette/table1" not in out.stdout  # nothing was started


def test_real_rows_name_the_missing_classes(_repro_home):
    """The message that printed "lacks classes [10, 11, ...]" names them."""
    from repro.data.registry import load_clipset
    from repro.data.splits import with_split
    from repro.errors import DataError
    from repro.eval.real import real_rows
    from repro.eval.settings import resolve_settings

    clips = load_clipset("bandai2-mini")
    split = np.asarray(clips.split).copy()
    split[np.asarray(clips.labels) == 3] = 0  # class 3 only in training
    cs = with_split(clips, split)
    with pytest.raises(DataError, match=rf"test split lacks class {clips.label_names[3]} "):
        real_rows("bandai2-mini", "quick", evaluator=object(), clipset=cs,
                  settings=resolve_settings("quick"))


# ------------------------------------------------------------------ item 6: selection
def test_include_lists_and_exclude_write_the_issues_glob_plainly(tmp_path, fresh_registry,
                                                                 _repro_home):
    """The issue's working spec needed ``dataset-1_[bdgrw][aouy][eilnsw][!c]*.bvh`` to take
    some files and leave others; a list of includes and an exclude say it plainly."""
    from repro.data.dataset_prepare import prepare_dataset
    from repro.data.dataset_spec import load_dataset_spec, role_of

    spec = write_set(tmp_path, grid(["walk", "run", "bow", "cheer"], ["a", "b", "c", "d", "e"]),
                     extra='[split]\nby = "style"\n')
    text = spec.read_text().replace(
        'path = "takes"', 'path = "takes"\ninclude = ["set_walk_*.bvh", "set_run_*.bvh", '
        '"set_bow_*.bvh"]\nexclude = "*_e_*"')
    spec.write_text(text)
    s = load_dataset_spec(spec)
    assert role_of(s, "set_walk_a_0.bvh") == "clip" and role_of(s, "SET_RUN_B_0.BVH") == "clip"
    assert role_of(s, "set_walk_e_0.bvh") is None and role_of(s, "set_cheer_a_0.bvh") is None
    res = prepare_dataset(spec)
    meta = json.loads((res.path / "meta.json").read_text())
    assert res.clips == 12 and meta["label_names"] == ["bow", "run", "walk"]
    card = meta["card"]
    assert card["excluded_files"] == 3 and card["skipped_files"]["count"] == 5  # cheer × 5
    from repro.errors import SpecError

    spec.write_text(text.replace('exclude = "*_e_*"', "exclude = []"))
    with pytest.raises(SpecError, match="at least one pattern"):
        load_dataset_spec(spec)


def test_a_class_subset_drops_the_other_classes_and_says_so(tmp_path, fresh_registry,
                                                            _repro_home):
    """``classes`` naming a subset: the other classes' clips are dropped by design (before:
    "action 'jump' is not one of the classes", on the first one), counted on the card and
    printed; their files are never parsed (they are no BVH here)."""
    cells = {**grid(["walk", "run"], ["a", "b", "c", "d", "e"]), **grid(["jump"], ["a", "b"], 2)}
    spec = write_set(tmp_path, cells, bad={f"set_jump_a_{k}" for k in range(2)},
                     extra='classes = ["walk", "run"]\n[split]\nby = "style"\n')
    out = cli("data", "prepare", str(spec))
    assert out.returncode == 0, out.stderr
    assert "cls: prepared: 10 clips" in out.stdout
    assert "4 clip(s) dropped, their class not in [labels] classes: jump 4" in out.stdout
    meta = json.loads((Path(out.stdout.split("-> ")[1].split()[0]) / "meta.json").read_text())
    assert meta["label_names"] == ["walk", "run"]
    assert meta["card"]["dropped_clips"] == {"by_class": {"jump": 4}, "count": 4}


@pytest.mark.parametrize("fmt", ["csv", "json"])
def test_unlisted_clips_are_refused_by_default_and_dropped_on_request(tmp_path, fresh_registry,
                                                                      _repro_home, fmt):
    from repro.data.dataset_prepare import prepare_dataset
    from repro.errors import DataError

    cells = grid(["walk", "run"], ["a", "b", "c", "d", "e"])
    listed = [(f"set_{a}_{s}_0", a) for (a, s) in cells if (a, s) != ("run", "e")]
    if fmt == "csv":
        (tmp_path / "l.csv").write_text("clip,action\n" + "".join(f"{c},{a}\n" for c, a in listed))
    else:
        (tmp_path / "l.json").write_text(json.dumps(dict(listed)))
    section = f'from = "{fmt}"\nfile = "l.{fmt}"'
    spec = write_set(tmp_path, cells, labels=section)
    with pytest.raises(DataError, match=r"'set_run_e_0' has no label.*unlisted = \"drop\""):
        prepare_dataset(spec)
    spec.write_text(spec.read_text().replace(section, section + '\nunlisted = "drop"'))
    res = prepare_dataset(spec)
    meta = json.loads((res.path / "meta.json").read_text())
    assert res.clips == 9 and "set_run_e_0" not in meta["clip_names"]
    assert meta["card"]["unlisted_clips"] == {"count": 1, "first": ["set_run_e_0"]}


def test_unlisted_drop_also_takes_names_the_pattern_does_not_match(tmp_path, fresh_registry,
                                                                   _repro_home):
    from repro.data.dataset_prepare import prepare_dataset
    from repro.errors import DataError

    lab = f"pattern = '{PATTERN}'"
    spec = write_set(tmp_path, grid(["walk", "run"], ["a", "b", "c", "d", "e"]), labels=lab,
                     extra='[split]\nby = "style"\n')
    (tmp_path / "takes" / "calibration.bvh").write_bytes(BVH)
    with pytest.raises(DataError, match="does not match the labels pattern.*exclude"):
        prepare_dataset(spec)
    spec.write_text(spec.read_text().replace(lab, lab + '\nunlisted = "drop"'))
    res = prepare_dataset(spec)
    assert res.clips == 10
    card = json.loads((res.path / "meta.json").read_text())["card"]
    assert card["unlisted_clips"] == {"count": 1, "first": ["calibration"]}


def test_new_fields_at_their_defaults_leave_the_key_alone(tmp_path):
    """``exclude``, ``unlisted`` and ``stratify`` are out of the key material at their
    defaults (a spec without them keeps its fingerprint), and a one-item include list is the
    pattern itself; set, each changes the key."""
    from repro.data.dataset_spec import key_material, load_dataset_spec

    base = ('schema = 1\nname = "k"\n[source]\npath = "x"\ninclude = "*.bvh"\n'
            '[labels]\npattern = "(?P<action>.*)_(?P<subject>.*)"\n')
    p = tmp_path / "k.toml"
    p.write_text(base)
    d = key_material(load_dataset_spec(p))
    assert d == {"schema": 1, "name": "k",
                 "source": {"path": "x", "format": "bvh", "include": "*.bvh", "asf": None},
                 "labels": {"from": "filename", "pattern": "(?P<action>.*)_(?P<subject>.*)",
                            "file": None, "classes": None, "styles": None},
                 "skeleton": {"up_axis": "y", "units": "cm", "length_scale": None,
                              "dummy_root": None},
                 "frames": {"fps": None, "resample_to": None},
                 "split": {"test_fraction": 0.2, "seed": 0}}
    p.write_text(base.replace('include = "*.bvh"', 'include = ["*.bvh"]'))
    assert key_material(load_dataset_spec(p)) == d
    for extra in ('[split]\nby = "subject"\nstratify = "action"\n',):
        p.write_text(base + extra)
        assert key_material(load_dataset_spec(p))["split"]["stratify"] == "action"
    p.write_text(base.replace('include = "*.bvh"', 'exclude = "*_x.bvh"')
                 + 'unlisted = "drop"\n')
    k = key_material(load_dataset_spec(p))
    assert k["source"]["exclude"] == "*_x.bvh" and k["labels"]["unlisted"] == "drop"
    from repro.errors import SpecError

    p.write_text(base + '[split]\nstratify = "action"\n')
    with pytest.raises(SpecError, match="stratify is for by"):
        load_dataset_spec(p)
    p.write_text(base + '[split]\nby = "style"\n')
    with pytest.raises(SpecError, match="style labels"):
        load_dataset_spec(p)


# ------------------------------------------------------------------ item 7: group splits
def test_one_clip_per_action_and_style_cell_splits_by_whole_styles(tmp_path, fresh_registry,
                                                                   _repro_home):
    """The issue's shape (17 actions × 15 styles, one clip per cell): the default split puts
    round(0.2) = 0 of each cell in test, 255 train / 0 test, and is refused naming the fix;
    ``by = "style"`` sends whole styles to test: every action on both sides, 51 test clips
    (3 styles), no style on both sides."""
    from repro.data.dataset_prepare import prepare_dataset
    from repro.data.dataset_registration import register_spec_path
    from repro.data.registry import load_clipset
    from repro.errors import DataError

    actions = [f"a{chr(97 + i)}" for i in range(17)]
    styles = [f"s{chr(97 + i)}" for i in range(15)]
    spec = write_set(tmp_path, grid(actions, styles))
    with pytest.raises(DataError, match=r"would have no test clip.*by = \"style\""):
        prepare_dataset(spec)
    spec.write_text(spec.read_text() + '[split]\nby = "style"\n')
    res = prepare_dataset(spec)
    clips = load_clipset(register_spec_path(str(spec)))
    split, labels = np.asarray(clips.split), np.asarray(clips.labels)
    st = np.asarray(clips.styles)
    assert (split == 1).sum() == 51 and res.clips == 255
    assert set(st[split == 1].tolist()).isdisjoint(st[split == 0].tolist())
    for c in range(17):
        assert ((labels == c) & (split == 1)).any() and ((labels == c) & (split == 0)).any()
    meta = json.loads((res.path / "meta.json").read_text())
    assert meta["split"]["method"] == "styles whole to test, every action on both sides"


def test_group_split_covers_every_action_seeded_and_refuses_the_impossible():
    from repro.data.splits import NoGroupSplit, group_split

    # five subjects; action 2 only in subjects p1 and p4, action 3 only in p0 and p2
    rows = [(a, f"p{s}") for s in range(5) for a in (0, 1)] + \
        [(2, "p1"), (2, "p4"), (3, "p0"), (3, "p2"), (3, "p2")]
    labels = np.array([a for a, _ in rows])
    groups = [g for _, g in rows]
    for seed in range(8):
        split = group_split(labels, groups, test_fraction=0.3, seed=seed)
        assert np.array_equal(split, group_split(labels, groups, test_fraction=0.3, seed=seed))
        g = np.array(groups)
        assert set(g[split == 1]).isdisjoint(g[split == 0])
        for a in range(4):
            assert ((labels == a) & (split == 1)).any() and ((labels == a) & (split == 0)).any()
    assert len({group_split(labels, groups, seed=k).tobytes() for k in range(8)}) > 1
    with pytest.raises(NoGroupSplit) as e:  # action 4's clips all lie in subject p3
        group_split(np.append(labels, [4, 4]), groups + ["p3", "p3"])
    assert e.value.actions == [4] and e.value.single == [4]


def test_subject_split_stratified_by_action_on_request(tmp_path, fresh_registry, _repro_home):
    """``by = "subject"`` alone keeps the earlier seeded fill (which may leave an action
    without a test clip: refused, with the fix ``stratify = "action"``); with it, every
    action is on both sides and no subject is on both."""
    from repro.data.dataset_prepare import prepare_dataset
    from repro.data.dataset_registration import register_spec_path
    from repro.data.registry import load_clipset
    from repro.errors import DataError

    pattern = r"^set_(?P<action>[a-z]+)_(?P<subject>[a-z]+)_\d+$"
    # 'kick' is performed only by subjects 'pa' and 'pb'
    cells = {**grid(["walk", "run"], ["pa", "pb", "pc", "pd", "pe", "pf"], 2),
             ("kick", "pa"): 2, ("kick", "pb"): 2}
    problems = []
    for seed in range(6):
        spec = write_set(tmp_path, cells, labels=f"pattern = '{pattern}'",
                         extra=f'[split]\nby = "subject"\nseed = {seed}\n')
        try:
            prepare_dataset(spec)
        except DataError as e:
            problems.append(str(e))
    assert any("'kick' (4 clips) would have no test clip" in p
               and 'stratify = "action"' in p for p in problems), problems
    spec = write_set(tmp_path, cells, labels=f"pattern = '{pattern}'",
                     extra='[split]\nby = "subject"\nstratify = "action"\n')
    res = prepare_dataset(spec)
    clips = load_clipset(register_spec_path(str(spec)))
    meta = json.loads((res.path / "meta.json").read_text())
    subj = np.array(meta["clip_subjects"])
    split, labels = np.asarray(clips.split), np.asarray(clips.labels)
    assert set(subj[split == 1]).isdisjoint(subj[split == 0])
    for c in range(3):
        assert ((labels == c) & (split == 1)).any() and ((labels == c) & (split == 0)).any()
