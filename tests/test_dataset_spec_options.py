"""Declared data sets, the options added after the first cut (issue 16): hip joints named in the
spec (CMU's skeleton), an ASF inside an archive, subject labels and a subject-disjoint split,
case-insensitive ``include``, and a card that counts what the source held but was not read.
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import tarfile

import numpy as np
import pytest

from repro.paths import repo_root


@pytest.fixture
def fresh_registry(monkeypatch):
    from repro.data import registry

    monkeypatch.setenv("REPRO_DATASETS", "")
    registry.reset()
    yield
    registry.reset()


def _cmu_archive(tmp_path, *, subjects=("s1", "s2", "s3", "s4")):
    """A .tar.gz with a CMU-like ASF (``lhip`` / ``rhip`` both leave the root, as CMU's
    ``lhipjoint`` / ``rhipjoint``), AMC clips named ``<subject>_<n>``, a README the pattern
    does not take, and a labels CSV with a subject column (one row naming no clip)."""
    from test_asf_amc import make_motion, write_amc, write_asf

    order = "TX TY TZ RX RY RZ"
    members = {"data/body.asf": write_asf(root_order=order, length_unit=0.45),
               "data/README.txt": "not a clip\n"}
    rows = ["clip,action,subject"]
    k = 0
    for s in subjects:
        for action in ("jump", "kick"):
            for _ in range(2):
                stem = f"{s}_{k:02d}"
                members[f"data/{stem}.AMC" if k == 0 else f"data/{stem}.amc"] = write_amc(
                    make_motion(order, seed=k), order)
                rows.append(f"{stem},{action},{s}")
                k += 1
    rows.append("ghost_99,jump,s1")
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tf:
        for name, text in members.items():
            data = text.encode()
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tf.addfile(info, io.BytesIO(data))
    (tmp_path / "cmu.tar.gz").write_bytes(buf.getvalue())
    (tmp_path / "labels.csv").write_text("\n".join(rows) + "\n")
    return k


SPEC = """schema = 1
name = "cmuarch"
[source]
path = "cmu.tar.gz"
format = "asf_amc"
asf = "data/body.asf"
include = "data/*.amc"
[labels]
from = "csv"
file = "labels.csv"
[skeleton]
units = "inch"
{skeleton}
[frames]
fps = 120.0
[split]
test_fraction = 0.25
by = "subject"
"""


def test_cmu_hips_named_in_the_spec_asf_in_an_archive_subject_split(tmp_path, fresh_registry,
                                                                    _repro_home):
    from repro.data.dataset_prepare import prepare_dataset
    from repro.data.dataset_registration import register_spec_path
    from repro.data.registry import load_clipset
    from repro.errors import DataError
    from repro.motion.heading import body_frame

    n = _cmu_archive(tmp_path)
    spec = tmp_path / "cmuarch.toml"
    spec.write_text(SPEC.format(skeleton=""))
    with pytest.raises(DataError, match=r"\[skeleton\] hips"):  # both hips start at the root
        prepare_dataset(spec)
    spec.write_text(SPEC.format(skeleton='hips = ["lfemur", "nosuch"]'))
    with pytest.raises(DataError, match="'nosuch'"):
        prepare_dataset(spec)
    spec.write_text(SPEC.format(skeleton='hips = ["lfemur", "rfemur"]'))
    res = prepare_dataset(spec)
    assert res.clips == n  # the upper-case .AMC too: include is case-insensitive
    clips = load_clipset(register_spec_path(str(spec)))
    assert clips.skeleton.hips == ("lfemur", "rfemur")
    assert body_frame(clips.skeleton).joints[:2] == ("lfemur", "rfemur")
    meta = json.loads((res.path / "meta.json").read_text())
    subj = np.array(meta["clip_subjects"])
    split = np.asarray(clips.split)
    assert set(subj[split == 1]).isdisjoint(subj[split == 0])  # no subject on both sides
    assert (split == 1).sum() >= round(0.25 * n) and (split == 0).any()
    card = meta["card"]
    assert card["subjects"] == 4
    assert card["skipped_files"] == {"count": 1, "first": ["data/README.txt"]}
    assert card["unused_label_rows"] == {"count": 1, "first": ["ghost_99"]}
    assert card["per_class"]["jump"]["seconds_total"] > 0


def test_subject_split_needs_subjects(tmp_path, fresh_registry, _repro_home):
    from repro.data.dataset_prepare import prepare_dataset
    from repro.data.dataset_spec import load_dataset_spec
    from repro.errors import DataError, SpecError

    _cmu_archive(tmp_path, subjects=("s1",))
    spec = tmp_path / "one.toml"
    spec.write_text(SPEC.format(skeleton='hips = ["lfemur", "rfemur"]'))
    with pytest.raises(DataError, match="at least two subjects"):
        prepare_dataset(spec)
    spec.write_text(SPEC.format(skeleton="").replace('from = "csv"\nfile = "labels.csv"',
                                                     "from = \"filename\"\npattern = "
                                                     "'(?P<action>.*)'"))
    with pytest.raises(SpecError, match="subject labels"):
        load_dataset_spec(spec)


def test_subject_split_is_seeded_and_disjoint():
    from repro.data.splits import subject_split

    subjects = [f"p{i % 7}" for i in range(70)]
    a = subject_split(subjects, test_fraction=0.3, seed=4)
    assert np.array_equal(a, subject_split(subjects, test_fraction=0.3, seed=4))
    s = np.array(subjects)
    assert set(s[a == 1]).isdisjoint(s[a == 0]) and 21 <= (a == 1).sum() < 70
    assert any(not np.array_equal(a, subject_split(subjects, test_fraction=0.3, seed=k))
               for k in range(5, 10))
    with pytest.raises(ValueError, match="two subjects"):
        subject_split(["a"] * 5)


def test_new_fields_at_their_defaults_leave_the_key_alone(tmp_path):
    """A spec written before hips / up_joint / split.by existed keeps its fingerprint."""
    from repro.data.dataset_spec import key_material, load_dataset_spec

    base = 'schema = 1\nname = "k"\n[source]\npath = "x"\n[labels]\npattern = "(?P<action>.*)"\n'
    p = tmp_path / "k.toml"
    p.write_text(base)
    d = key_material(load_dataset_spec(p))
    assert "hips" not in d["skeleton"] and "up_joint" not in d["skeleton"]
    assert "by" not in d["split"] and "description" not in d
    p.write_text(base + '[skeleton]\nhips = ["a", "b"]\n[split]\nby = "clip"\n')
    d2 = key_material(load_dataset_spec(p))
    assert d2["skeleton"]["hips"] == ["a", "b"] and "by" not in d2["split"]
    p.write_text(base + '[skeleton]\nhips = ["a", "a"]\n')
    from repro.errors import SpecError

    with pytest.raises(SpecError, match="two different joints"):
        load_dataset_spec(p)


def test_skeleton_body_joints_round_trip_and_key():
    from repro.motion.skeleton import Skeleton

    off = np.zeros((3, 3))
    off[1, 0], off[2, 0] = 0.1, -0.1
    a = Skeleton(("r", "a", "b"), (-1, 0, 0), off)
    b = Skeleton(("r", "a", "b"), (-1, 0, 0), off, ("a", "b"))
    assert "hips" not in a.to_dict() and a.fingerprint() != b.fingerprint() and a != b
    assert Skeleton.from_dict(b.to_dict()) == b
    with pytest.raises(ValueError, match="'z'"):
        Skeleton(("r", "a", "b"), (-1, 0, 0), off, ("a", "z"))


def test_prepare_prints_the_card(tmp_path, fresh_registry, _repro_home):
    """`repro data prepare SPEC` prints per-class durations and what was not read."""
    _cmu_archive(tmp_path)
    spec = tmp_path / "cmuarch.toml"
    spec.write_text(SPEC.format(skeleton='hips = ["lfemur", "rfemur"]'))
    out = subprocess.run([sys.executable, "-m", "cli.main", "data", "prepare", str(spec)],
                         capture_output=True, text=True, cwd=repo_root(),
                         env={**os.environ, "REPRO_DATASETS": ""})
    assert out.returncode == 0, out.stderr
    assert "per class" in out.stdout and "total s" in out.stdout
    assert "subjects: 4" in out.stdout
    assert "1 file(s) in the source matched no pattern: data/README.txt" in out.stdout
    assert "1 label row(s) name no clip of the source: ghost_99" in out.stdout


def test_cli_refuses_a_link_out_of_a_folder_source(tmp_path, fresh_registry, _repro_home):
    """A clip file that is a symbolic link leading out of the source folder: one line naming
    it, exit 2, and the data set prepared before stays."""
    from test_asf_amc import make_motion, write_amc, write_asf

    order = "TX TY TZ RX RY RZ"
    src = tmp_path / "src"
    src.mkdir()
    (src / "body.asf").write_text(write_asf(root_order=order))
    for k in range(4):
        (src / f"s{k % 2}_{k}_{'ab'[k // 2]}.amc").write_text(
            write_amc(make_motion(order, seed=k), order))
    spec = tmp_path / "linked.toml"
    spec.write_text('schema = 1\nname = "linked"\n[source]\npath = "src"\nformat = "asf_amc"\n'
                    'asf = "body.asf"\n[labels]\npattern = \'_(?P<action>[ab])$\'\n'
                    '[skeleton]\nhips = ["lfemur", "rfemur"]\n[split]\ntest_fraction = 0.5\n')
    env = {**os.environ, "REPRO_DATASETS": ""}

    def prepare():
        return subprocess.run([sys.executable, "-m", "cli.main", "data", "prepare", str(spec),
                               "--json"], capture_output=True, text=True, cwd=repo_root(),
                              env=env)

    first = prepare()
    assert first.returncode == 0, first.stderr
    kept = json.loads(first.stdout)["path"]
    outside = tmp_path / "elsewhere.amc"
    outside.write_text(write_amc(make_motion(order, seed=9), order))
    (src / "s1_9_a.amc").symlink_to(outside)
    out = prepare()
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
    assert "s1_9_a.amc" in out.stderr and "symbolic link" in out.stderr
    assert os.path.isdir(kept) and os.path.isfile(os.path.join(kept, "meta.json"))


def test_expect_pins_the_facts_of_a_declared_data_set(tmp_path, fresh_registry, _repro_home):
    from repro.data.dataset_prepare import prepare_dataset
    from repro.errors import DataError

    n = _cmu_archive(tmp_path)
    spec = tmp_path / "cmuarch.toml"
    spec.write_text(SPEC.format(skeleton='hips = ["lfemur", "rfemur"]')
                    + "[expect]\nclips = 99\njoints = 4\n")
    with pytest.raises(DataError, match=rf"{n} clips \(\[expect\] clips = 99\); \d+ joints"):
        prepare_dataset(spec)


def test_the_built_in_bandai2_is_declared_by_its_shipped_spec(tmp_path):
    """bandai2's facts (names, fps, counts, words, split) live in repro/data/bundled/bandai2.toml,
    valid under the same schema; a copy of it elsewhere may not take the built-in's name."""
    import shutil

    from repro.data.bandai import BANDAI2_CARD, BANDAI2_SPEC
    from repro.data.dataset_spec import builtin_spec_path

    path = builtin_spec_path("bandai2")
    out = subprocess.run([sys.executable, "-m", "cli.main", "data", "check", str(path)],
                         capture_output=True, text=True, cwd=repo_root())
    assert out.returncode == 0, out.stderr
    assert BANDAI2_CARD.clips == 2902 and BANDAI2_CARD.frames == 384931
    assert BANDAI2_CARD.joints == 21 and BANDAI2_CARD.fps == 30.0
    assert BANDAI2_CARD.class_names[0] == "walk" and len(BANDAI2_CARD.style_names) == 7
    assert (BANDAI2_SPEC.split.test_fraction, BANDAI2_SPEC.split.seed) == (0.2, 0)
    shutil.copy(path, tmp_path / "mine.toml")
    out = subprocess.run([sys.executable, "-m", "cli.main", "data", "check",
                          str(tmp_path / "mine.toml")], capture_output=True, text=True,
                         cwd=repo_root())
    assert out.returncode == 2 and "built-in" in out.stderr


@pytest.mark.data
def test_the_built_in_fingerprint_is_unchanged_by_its_declaration(bandai_archive):
    """Moving bandai2's facts into its shipped spec kept every prepared copy and job key: the
    fingerprint of the archive is the one prepared before the move (main 4b3830a)."""
    from repro.data.bandai import BANDAI2_CARD, dataset_fingerprint, split_config
    from repro.data.sources import source_fingerprint

    assert dataset_fingerprint(source_fingerprint(bandai_archive), BANDAI2_CARD,
                               split_config()) == \
        "9cb30349044010c9fa7a668e34fe51846cc9758f875d87981d897c2954357e53"


def _amc_folder(tmp_path, name="src", n=4):
    from test_asf_amc import make_motion, write_amc, write_asf

    order = "TX TY TZ RX RY RZ"
    src = tmp_path / name
    src.mkdir()
    (src / "Body.ASF").write_text(write_asf(root_order=order))
    for k in range(n):
        (src / f"s{k % 2}_{k}_{'ab'[k * 2 // n]}.amc").write_text(
            write_amc(make_motion(order, seed=k), order))
    return src


FOLDER_SPEC = ('schema = 1\nname = "fold"\n[source]\npath = "{path}"\nformat = "asf_amc"\n'
               'asf = "{asf}"\n[labels]\npattern = \'_(?P<action>[ab])$\'\n'
               '[skeleton]\nhips = ["lfemur", "rfemur"]\n{extra}[split]\ntest_fraction = 0.5\n')


def test_the_key_follows_only_the_files_read(tmp_path, fresh_registry, _repro_home):
    """A folder's other files, the spec kept inside its source, its words and [expect] leave
    the fingerprint alone; the ASF (matched case-insensitively) and the clips do not."""
    from repro.data.dataset_prepare import prepare_dataset
    from repro.data.dataset_registration import register_spec_path
    from repro.data.registry import get_entry

    src = _amc_folder(tmp_path)
    spec = src / "fold.toml"  # the spec inside its own source folder
    spec.write_text(FOLDER_SPEC.format(path=".", asf="body.asf", extra=""))
    a = prepare_dataset(spec)
    card = json.loads((a.path / "meta.json").read_text())["card"]
    assert card["skipped_files"]["count"] == 0  # the spec itself is no skipped file
    (src / "notes.txt").write_text("x")
    spec.write_text('description = "words"\n' + FOLDER_SPEC.format(
        path=".", asf="body.asf", extra="") + "[expect]\nclips = 4\n")
    b = prepare_dataset(spec)
    assert b.fingerprint == a.fingerprint and b.reused
    name = register_spec_path(str(spec))
    assert get_entry(name).status().prepared
    (src / "Body.ASF").write_text((src / "Body.ASF").read_text().replace("length 1", "length 2"))
    assert prepare_dataset(spec).fingerprint != a.fingerprint


def test_bad_paths_and_postures_are_refused(tmp_path, fresh_registry, _repro_home):
    from repro.data.dataset_prepare import prepare_dataset
    from repro.data.dataset_spec import load_dataset_spec
    from repro.errors import DataError, SpecError

    _amc_folder(tmp_path)
    spec = tmp_path / "fold.toml"
    for asf in ("../src/Body.ASF", "/etc/passwd"):
        spec.write_text(FOLDER_SPEC.format(path="src", asf=asf, extra=""))
        with pytest.raises(SpecError, match="inside the source"):
            load_dataset_spec(spec)
    spec.write_text(FOLDER_SPEC.format(path="src", asf="body.asf", extra='up_joint = "ltibia"\n'))
    with pytest.raises(DataError, match="in a leg"):
        prepare_dataset(spec)
    spec.write_text(FOLDER_SPEC.format(path="src", asf="body.asf", extra='up_axis = "z"\n'))
    with pytest.raises(DataError, match="not \\+y"):  # a y-up body turned as if z-up lies down
        prepare_dataset(spec)
    spec.write_text(FOLDER_SPEC.format(path="src", asf="body.asf", extra="")
                    + "[expect]\nclips = 4\n")
    prepare_dataset(spec)
    spec.write_text(FOLDER_SPEC.format(path="src", asf="body.asf", extra="")
                    + "[expect]\nclips = 5\n")
    with pytest.raises(DataError, match=r"4 clips \(\[expect\] clips = 5\)"):
        prepare_dataset(spec)  # checked on the reused copy too


@pytest.mark.parametrize("fmt,text,problem", [
    ("json", '{"s0_0_a": null}', "action must be a non-empty name"),
    ("json", '{"s0_0_a": {"style": "x"}}', "action must be a non-empty name"),
    ("json", '{"a":' * 100_000 + "1" + "}" * 100_000, "not JSON"),
    ("json", '{"s0_0_a": "st\\u0000omp"}', "control characters"),
    ("csv", "clip,action\ns0_0_a\n", "action must be a non-empty name"),
    ("csv", "clip,action\n,a\n", "the clip name"),
    ("csv", "clip,action\ns0_0_a," + "x" * 200_000 + "\n", "not a readable CSV"),
])
def test_broken_label_files_are_one_error(tmp_path, fresh_registry, _repro_home, fmt, text,
                                          problem):
    from repro.data.dataset_prepare import prepare_dataset
    from repro.errors import DataError

    _amc_folder(tmp_path)
    (tmp_path / f"labels.{fmt}").write_text(text)
    spec = tmp_path / "fold.toml"
    spec.write_text(FOLDER_SPEC.format(path="src", asf="body.asf", extra="").replace(
        "pattern = '_(?P<action>[ab])$'", f'from = "{fmt}"\nfile = "labels.{fmt}"'))
    with pytest.raises(DataError, match=problem) as e:
        prepare_dataset(spec)
    assert len(str(e.value)) < 600


def test_force_with_an_unknown_kind_is_refused(tmp_path):
    out = subprocess.run([sys.executable, "-m", "cli.main", "run", "marionette/table1",
                          "--force", "trian"], capture_output=True, text=True, cwd=repo_root(),
                         env={**os.environ, "REPRO_HOME": str(tmp_path)})
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert "--force trian: no job of this run" in out.stderr and "train" in out.stderr


def test_a_damaged_declared_copy_names_its_own_prepare_command(tmp_path, fresh_registry,
                                                               _repro_home):
    from repro.data.dataset_prepare import prepare_dataset
    from repro.data.dataset_registration import register_spec_path
    from repro.data.registry import load_clipset
    from repro.errors import DataError

    _amc_folder(tmp_path)
    spec = tmp_path / "fold.toml"
    spec.write_text(FOLDER_SPEC.format(path="src", asf="body.asf", extra=""))
    res = prepare_dataset(spec)
    name = register_spec_path(str(spec))
    (res.path / "joints.npy").write_bytes(b"\x93NUMPY broken")
    with pytest.raises(DataError, match=r"run: repro data prepare \S*fold.toml --force"):
        load_clipset(name)


def test_the_lab_example_is_the_bundled_motion_in_another_skeleton(tmp_path, fresh_registry,
                                                                   _repro_home):
    """docs/examples/lab_example.py (the README's walk-through) re-expresses bandai2-mini: once
    prepared by its spec alone, its joints are the mini's (toes aside), in metres, y up."""
    import importlib.util

    from repro.data.dataset_prepare import prepare_dataset
    from repro.data.dataset_registration import register_spec_path
    from repro.data.registry import load_clipset

    path = repo_root() / "docs" / "examples" / "lab_example.py"
    mod_spec = importlib.util.spec_from_file_location("lab_example", path)
    lab = importlib.util.module_from_spec(mod_spec)
    mod_spec.loader.exec_module(lab)
    spec = lab.write_lab_example(tmp_path / "lab")
    prepare_dataset(spec)
    got = load_clipset(register_spec_path(str(spec)))
    mini = load_clipset("bandai2-mini")
    assert got.skeleton.names == tuple(lab.RENAME.values()) and len(got) == len(mini)
    assert got.skeleton.hips == ("femur.L", "femur.R")
    idx = [mini.skeleton.names.index(n) for n in lab.RENAME]
    for i in (0, 57, 279):
        j = got.clip_names.index(f"take_{i + 1:04d}")
        assert got.label_names[got.labels[j]] == mini.label_names[mini.labels[i]]
        a = np.asarray(got.joints[got.starts[j]:got.starts[j] + got.lengths[j]])
        b = np.asarray(mini.joints[mini.starts[i]:mini.starts[i] + mini.lengths[i]])[:, idx]
        assert np.abs(a - b).max() < 1e-4  # metres: 6-decimal mm text, float32 storage
