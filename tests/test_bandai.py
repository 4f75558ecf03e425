"""The bandai2 stand-in (prepare, cache, card), the registry, bandai2-mini and `repro data`.

Fast tests run on small Bandai-shaped folders written here; tests marked ``data`` use the real
archive, prepared once per session into their own REPRO_HOME.
"""

from __future__ import annotations

import dataclasses
import json
import os
import tarfile
import time
from pathlib import Path

import numpy as np
import pytest

from cli.main import main
from repro.data import bandai, cache
from repro.data.bandai import (BANDAI2_CARD, CM_TO_M, DatasetCard, load_bandai2,
                               prepare_bandai2)
from repro.data.bvh import Bvh, read_bvh
from repro.data.bvh_write import format_bvh
from repro.errors import ConfigError, DataError, MissingDataError

TOY_CARD = DatasetCard(name="toy", clips=None, frames=None, fps=30.0,
                       class_names=("walk", "run"), style_names=("active", "normal"), joints=5)
NAMES = ("joint_Root", "Hips", "Spine", "Head", "UpperLeg_L", "Foot_L")
PARENTS = (-1, 0, 1, 2, 1, 4)
OFFSETS = np.array([[0, 0, 0], [3, 90, 400], [0, 10, 0], [0, 30, 0], [10, -5, 0], [0, -40, 0.5]])
SIX = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")


def toy_bvh(frames: int = 6, seed: int = 0) -> Bvh:
    """A Bandai-shaped clip: dummy root, every joint with 6 channels, positions = OFFSETs."""
    rng = np.random.default_rng(seed)
    J = len(NAMES)
    motion = np.zeros((frames, J, 6))
    motion[:, :, :3] = OFFSETS
    motion[:, 0] = 0.0
    motion[:, 1, :3] = [5.0, 92.0, -3.0] + np.cumsum(rng.normal(0, 2, (frames, 3)), axis=0)
    motion[:, 1:, 3:] = rng.uniform(-60, 60, (frames, J - 1, 3))
    return Bvh(NAMES, PARENTS, OFFSETS, (SIX,) * J, (3, 5), np.zeros((2, 3)), 1 / 30,
               motion.reshape(frames, J * 6))


def write_toy(folder: Path, cells=((0, 0), (0, 1), (1, 0), (1, 1)), per_cell: int = 2,
              card: DatasetCard = TOY_CARD) -> list[Path]:
    data = folder / "data"
    data.mkdir(parents=True, exist_ok=True)
    out = []
    k = 0
    for c, s in cells:
        for i in range(per_cell):
            stem = f"dataset-2_{card.class_names[c]}_{card.style_names[s]}_{i + 1:03d}"
            (data / f"{stem}.bvh").write_text(format_bvh(toy_bvh(5 + k, seed=k)))
            (data / f"{stem}.json").write_text(json.dumps({"content": c, "style": s}))
            out.append(data / f"{stem}.bvh")
            k += 1
    return out


def cache_listing(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.name != ".lock"}


# ----------------------------------------------------------------------------- conversion
def test_prepare_folder_converts_to_metres_and_drops_dummy_root(tmp_path):
    files = write_toy(tmp_path / "src")
    res = prepare_bandai2(tmp_path / "src", card=TOY_CARD, workers=0)
    assert not res.reused and res.clips == 8
    cs = load_bandai2("toy")
    assert cs.skeleton.names == NAMES[1:] and cs.skeleton.parents == (-1, 0, 1, 0, 3)
    np.testing.assert_allclose(cs.skeleton.offsets[1:], OFFSETS[2:] * CM_TO_M)
    assert cs.fps == 30.0 and len(cs) == 8
    assert cs.label_names == ("walk", "run") and cs.style_names == ("active", "normal")
    order = sorted(p.stem for p in files)
    assert list(cs.clip_names) == order
    for i, name in enumerate(cs.clip_names):
        b = read_bvh(tmp_path / "src" / "data" / f"{name}.bvh")
        np.testing.assert_allclose(cs.clip_root(i), b.joint_channels("Hips")[:, :3] * CM_TO_M,
                                   atol=1e-6)
        np.testing.assert_allclose(cs.clip_joints(i), b.world_positions()[:, 1:] * CM_TO_M,
                                   atol=1e-6)
        q = b.local_rotations(as_quaternions=True).numpy()[:, 1:]
        np.testing.assert_allclose(cs.clip_rotations(i), q, atol=1e-6)
        parts = name.split("_")
        assert cs.label_names[cs.labels[i]] == parts[1] and cs.style_names[cs.styles[i]] == parts[2]
    assert cs.split.dtype == np.int8 and set(cs.split.tolist()) <= {0, 1}
    assert isinstance(cs.joints, np.memmap) and not cs.joints.flags.writeable
    again = prepare_bandai2(tmp_path / "src", card=TOY_CARD, workers=0)
    assert again.reused and again.fingerprint == res.fingerprint


def test_card_disagreement_fails_loudly(tmp_path):
    write_toy(tmp_path / "src")
    card = dataclasses.replace(TOY_CARD, clips=9, frames=3)
    with pytest.raises(DataError, match=r"disagrees with the toy dataset card: 8 clips \(card: 9\); "
                                        r"\d+ frames \(card: 3\)"):
        prepare_bandai2(tmp_path / "src", card=card, workers=0)
    assert cache.current_cache("toy") is None


@pytest.mark.parametrize("mutate, message", [
    ("dummy", "not an all-zero dummy"),
    ("posch", "position channels of 'Spine' move it"),
    ("offset", "OFFSETs differ"),
    ("label", "file name disagrees with its annotation"),
    ("nojson", "no annotation"),
    ("hierarchy", "hierarchy differs"),
])
def test_conversion_checks(tmp_path, mutate, message):
    files = write_toy(tmp_path / "src")
    victim = files[-1]
    b = read_bvh(victim)
    m = b.motion.copy()
    if mutate == "dummy":
        m[2, 1] = 0.5
        b = dataclasses.replace(b, motion=m)
    elif mutate == "posch":
        m[1, 12 + 1] += 0.5  # Spine Yposition
        b = dataclasses.replace(b, motion=m)
    elif mutate == "offset":
        off = b.offsets.copy()
        off[3, 1] += 0.1
        m[:, 18 + 1] += 0.1  # keep Head's position channel equal to its OFFSET
        b = dataclasses.replace(b, offsets=off, motion=m)
    elif mutate == "label":
        victim.with_suffix(".json").write_text(json.dumps({"content": 0, "style": 0}))
    elif mutate == "nojson":
        victim.with_suffix(".json").unlink()
    elif mutate == "hierarchy":
        b = dataclasses.replace(b, names=b.names[:-1] + ("Foot_X",))
    victim.write_text(format_bvh(b))
    with pytest.raises(DataError, match=message) as ei:
        prepare_bandai2(tmp_path / "src", card=TOY_CARD, workers=0)
    assert victim.name in str(ei.value) or victim.with_suffix(".json").name in str(ei.value)


def test_failed_prepare_never_removes_a_good_cache(tmp_path, monkeypatch):
    write_toy(tmp_path / "good")
    good = prepare_bandai2(tmp_path / "good", card=TOY_CARD, workers=0)
    root = cache.dataset_dir("toy")
    before = cache_listing(root)
    # 1. another source with one malformed file
    files = write_toy(tmp_path / "bad")
    text = files[2].read_text().replace("Frames: 7", "Frames: 70")
    files[2].write_text(text)
    with pytest.raises(DataError, match="truncated MOTION block"):
        prepare_bandai2(tmp_path / "bad", card=TOY_CARD, workers=0)
    assert cache_listing(root) == before
    # 2. a crash while the same cache is being rewritten (--force)
    calls = {"n": 0}
    real_save = np.save

    def failing_save(*a, **k):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError("disk full (simulated)")
        return real_save(*a, **k)

    with monkeypatch.context() as mp:
        mp.setattr(cache.np, "save", failing_save)
        with pytest.raises(OSError, match="simulated"):
            prepare_bandai2(tmp_path / "good", card=TOY_CARD, workers=0, force=True)
    assert cache_listing(root) == before
    assert not [p for p in root.iterdir() if p.name.startswith(".tmp")]
    assert load_bandai2("toy").fingerprint == good.fingerprint


def test_worker_pool_reports_a_bad_file(tmp_path, monkeypatch):
    files = write_toy(tmp_path / "src", per_cell=1)
    files[1].write_text(files[1].read_text().replace("Zrotation", "Qrotation", 1))
    monkeypatch.setattr(bandai, "POOL_MIN_FILES", 0)
    with pytest.raises(DataError) as ei:
        prepare_bandai2(tmp_path / "src", card=TOY_CARD, workers=2)
    assert files[1].name in str(ei.value) and "unknown channel name 'Qrotation'" in str(ei.value)
    assert ":5:" in str(ei.value)  # the CHANNELS line of joint_Root


def test_archive_source_reads_without_unpacking(tmp_path):
    write_toy(tmp_path / "src")
    arc = tmp_path / "toy.tar.xz"
    with tarfile.open(arc, "w:xz") as tf:
        tf.add(tmp_path / "src", arcname="dataset/toy")
    res = prepare_bandai2(arc, card=TOY_CARD, workers=0)
    from repro.keys import sha256_file

    meta = json.loads((res.path / "meta.json").read_text())
    assert meta["source_fingerprint"] == sha256_file(arc) and meta["source_kind"] == "archive"
    assert len(load_bandai2("toy")) == 8
    data = arc.read_bytes()
    arc.write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match="damaged or truncated|not a readable"):
        prepare_bandai2(arc, card=TOY_CARD, workers=0)


# ----------------------------------------------------------------------------- CLI
def test_cli_bad_bvh_one_line_exit_2(tmp_path, capsys):
    src = tmp_path / "one-bad"
    src.mkdir()
    (src / "dataset-2_walk_normal_001.bvh").write_text("HIERARCHY\nROOT joint_Root\n{\n"
                                                        "OFFSET 0 0 0\nCHANNELS 2 Xposition Bogus\n")
    rc = main(["data", "prepare", "bandai2", "--source", str(src)])
    out, err = capsys.readouterr()
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("repro: error: ")
    assert "dataset-2_walk_normal_001.bvh:5:" in err and "Traceback" not in err


def test_cli_missing_source_and_unknown_name(tmp_path, capsys):
    assert main(["data", "prepare", "bandai2", "--source", str(tmp_path / "nope.tar.xz")]) == 2
    assert main(["data", "info", "bandia2"]) == 2
    err = capsys.readouterr().err
    assert "source not found" in err and "did you mean 'bandai2'" in err


def test_registry(monkeypatch):
    from repro.data import registry

    assert {"bandai2", "bandai2-mini"} <= set(registry.dataset_names())
    assert registry.DATASETS["bandai2"].is_paper_dataset is False
    with pytest.raises(ConfigError, match="did you mean 'bandai2-mini'"):
        registry.load_clipset("bandai2-mimi")
    monkeypatch.setenv("REPRO_DATA", "/nonexistent/archive.tar.xz")
    st = registry.DATASETS["bandai2"].status()
    assert not st.prepared and "repro data prepare bandai2 --source" in st.missing
    with pytest.raises(MissingDataError, match="repro data prepare bandai2 --source"):
        registry.load_clipset("bandai2")
    assert registry.DATASETS["bandai2-mini"].status().prepared


# ----------------------------------------------------------------------------- bandai2-mini
def test_bundled_mini_is_small_credited_and_loads_fast():
    from repro.data.bundle import MINI_MAX_BYTES, bundled_dir
    from repro.data.registry import DATASETS, load_clipset

    d = bundled_dir()
    assert sum(p.stat().st_size for p in d.iterdir() if p.is_file()) <= MINI_MAX_BYTES
    notice = (d / "NOTICE").read_text()
    for needle in ("Bandai Namco Research Inc.", "CC BY-NC 4.0", "derived subset", "units",
                   "axes", "subset", "representation"):
        assert needle in notice
    cs = load_clipset("bandai2-mini")
    assert cs.fingerprint == DATASETS["bandai2-mini"].status().fingerprint
    assert len(cs) == 280 and cs.skeleton.n_joints == 21 and cs.fps == 30.0
    cells = np.zeros((10, 7, 2), int)
    np.add.at(cells, (cs.labels, cs.styles, cs.split), 1)
    assert (cells[..., 0] == 3).all() and (cells[..., 1] == 1).all()
    # joints are the forward kinematics of the stored rotations
    import roma
    import torch

    from repro.motion.skeleton import forward_kinematics

    i = 17
    R = roma.unitquat_to_rotmat(torch.from_numpy(np.asarray(cs.clip_rotations(i), np.float64)))
    fk = forward_kinematics(cs.skeleton, R, torch.from_numpy(np.asarray(cs.clip_root(i), np.float64)))
    np.testing.assert_allclose(cs.clip_joints(i), fk.numpy(), atol=1e-5)
    t0 = time.perf_counter()
    again = load_clipset("bandai2-mini")
    assert time.perf_counter() - t0 < 0.5 and again.fingerprint == cs.fingerprint


def test_build_mini_is_deterministic_and_faithful(tmp_path):
    from repro.data.bundle import build_mini, load_mini

    write_toy(tmp_path / "src", per_cell=5)
    prepare_bandai2(tmp_path / "src", card=TOY_CARD, workers=0)
    full = load_bandai2("toy")
    a = build_mini(full, tmp_path / "a", n_train=2, n_test=1)
    b = build_mini(full, tmp_path / "b", n_train=2, n_test=1)
    for f in a["files"]:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes()
    mini = load_mini(tmp_path / "a")
    assert len(mini) == a["clips"] <= 12
    idx = {n: i for i, n in enumerate(full.clip_names)}
    for i, name in enumerate(mini.clip_names):
        j = idx[name]
        assert mini.labels[i] == full.labels[j] and mini.split[i] == full.split[j]
        np.testing.assert_array_equal(mini.clip_root(i), full.clip_root(j))
        q, p = np.asarray(mini.clip_rotations(i)), np.asarray(full.clip_rotations(j))
        assert np.abs(np.abs((q * p).sum(-1)) - 1).max() < 1e-6  # same rotation (±q)
        np.testing.assert_allclose(mini.clip_joints(i), full.clip_joints(j), atol=2e-4)
    (tmp_path / "a" / "bandai2-mini.npz").write_bytes(b"garbage")
    with pytest.raises(DataError, match="sha256"):
        load_mini(tmp_path / "a")


# ----------------------------------------------------------------------------- real data
@pytest.fixture(scope="session")
def prepared_home(tmp_path_factory, bandai_archive):
    """The real archive prepared once, into a REPRO_HOME of its own."""
    home = tmp_path_factory.mktemp("bandai2-home")
    old = os.environ.get("REPRO_HOME")
    os.environ["REPRO_HOME"] = str(home)
    try:
        res = prepare_bandai2(bandai_archive, workers=2)
    finally:
        if old is None:
            os.environ.pop("REPRO_HOME", None)
        else:
            os.environ["REPRO_HOME"] = old
    return home, res


@pytest.mark.data
def test_real_counts_match_the_card(prepared_home, monkeypatch):
    home, res = prepared_home
    monkeypatch.setenv("REPRO_HOME", str(home))
    cs = load_bandai2()
    assert (len(cs), cs.n_frames, cs.n_classes, len(cs.style_names), cs.fps) == (
        2902, 384931, 10, 7, 30.0)
    assert cs.label_names == BANDAI2_CARD.class_names
    assert np.bincount(cs.labels).tolist() == [175, 236, 234, 317, 208, 209, 208, 434, 444, 437]
    assert (cs.lengths.min(), cs.lengths.max()) == (19, 466)
    assert cs.clip_names[int(np.argmin(cs.lengths))] == "dataset-2_wave-left-hand_active_011"
    assert cs.skeleton.n_joints == 21 and cs.skeleton.names[0] == "Hips"
    assert abs(float(np.median(cs.joints[:, 0, 1])) - 0.91) < 0.01  # hips height, metres
    for lab in range(10):
        for sty in range(7):
            m = (cs.labels == lab) & (cs.styles == sty)
            assert (cs.split[m] == 1).sum() == int(np.floor(0.2 * m.sum() + 0.5))


@pytest.mark.data
def test_real_info_json_and_prepare_reuse(prepared_home, monkeypatch, capsys, bandai_archive):
    home, res = prepared_home
    monkeypatch.setenv("REPRO_HOME", str(home))
    assert main(["data", "info", "bandai2", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert (info["clips"], info["frames"], info["classes"], info["styles"], info["fps"]) == (
        2902, 384931, 10, 7, 30.0)
    assert info["per_style"]["active"] == 584 and info["length_frames"]["max"] == 466
    t0 = time.perf_counter()
    assert main(["data", "prepare", "bandai2", "--source", str(bandai_archive), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["reused"] and out["fingerprint"] == res.fingerprint
    assert time.perf_counter() - t0 < 5


@pytest.mark.data
def test_real_fk_matches_bvhio(prepared_home, monkeypatch, tmp_path, bandai_archive):
    bvhio = pytest.importorskip("bvhio")
    home, _ = prepared_home
    monkeypatch.setenv("REPRO_HOME", str(home))
    cs = load_bandai2()
    index = {n: i for i, n in enumerate(cs.clip_names)}
    paths = []
    with tarfile.open(bandai_archive, "r|xz") as tf:
        for m in tf:
            if m.name.endswith(".bvh"):
                p = tmp_path / m.name.rsplit("/", 1)[-1]
                p.write_bytes(tf.extractfile(m).read())
                paths.append(p)
                if len(paths) == 24:
                    break
    worst_file = worst_cache = 0.0
    for p in paths:
        b = read_bvh(p)
        ours = b.world_positions()  # cm, joint_Root included
        root = bvhio.readAsHierarchy(str(p))
        layout = [j for j, _, _ in root.layout()]
        assert tuple(j.Name for j in layout) == b.names
        theirs = np.empty_like(ours)
        for f in range(b.n_frames):
            root.loadPose(f)
            for k, j in enumerate(layout):
                theirs[f, k] = tuple(j.PositionWorld)
        worst_file = max(worst_file, float(np.abs(ours - theirs).max()))
        cached = np.asarray(cs.clip_joints(index[p.stem]), np.float64) / CM_TO_M
        worst_cache = max(worst_cache, float(np.abs(cached - theirs[:, 1:]).max()))
    assert len(paths) >= 20
    assert worst_file < 1e-3, worst_file      # cm
    assert worst_cache < 1e-3, worst_cache    # cm


@pytest.mark.data
def test_real_bad_source_keeps_the_cache(prepared_home, monkeypatch, tmp_path, capsys):
    home, res = prepared_home
    monkeypatch.setenv("REPRO_HOME", str(home))
    src = tmp_path / "src"
    src.mkdir()
    (src / "dataset-2_run_normal_001.bvh").write_text("HIERARCHY\nROOT joint_Root\n{\n}\nMOTION\n"
                                                       "Frames: 1\nFrame Time: 0.0333333\n\n")
    assert main(["data", "prepare", "bandai2", "--source", str(src)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "dataset-2_run_normal_001.bvh:4:" in err
    assert load_bandai2().fingerprint == res.fingerprint


def test_write_cache_keeps_a_published_cache_when_not_replacing(tmp_path):
    from repro.data.cache import ARRAYS, valid_cache, write_cache

    def arrays(v):
        return {k: np.full(3, v, np.float32) for k in ARRAYS}

    meta = {"name": "x", "fps": 30.0}
    p = write_cache(tmp_path, "key", arrays(1), meta, replace=False)
    assert write_cache(tmp_path, "key", arrays(2), meta, replace=False) == p
    assert np.load(p / "root.npy")[0] == 1 and valid_cache(p)["name"] == "x"
    write_cache(tmp_path, "key", arrays(3), meta)  # replace=True (prepare --force)
    assert np.load(p / "root.npy")[0] == 3
    assert sorted(q.name for q in tmp_path.iterdir()) == ["key"]



def test_folder_source_refuses_symlinks_out_of_the_folder(tmp_path):
    """Issue 16 (part): a folder source no longer follows a .bvh symlink out of the folder;
    prepare ends with one error naming the link, already when the source is fingerprinted
    (before a cached copy could be reused)."""
    import pytest

    from repro.data.sources import source_fingerprint
    from repro.errors import DataError

    write_toy(tmp_path / "src")
    before = source_fingerprint(tmp_path / "src")
    outside = tmp_path / "elsewhere.bvh"
    outside.write_bytes(next((tmp_path / "src" / "data").glob("*.bvh")).read_bytes())
    link = tmp_path / "src" / "data" / "zz_walk_active_9.bvh"
    link.symlink_to(outside)
    with pytest.raises(DataError, match="symbolic link that leads out") as e:
        source_fingerprint(tmp_path / "src")
    assert "zz_walk_active_9.bvh" in str(e.value)
    link.unlink()
    assert source_fingerprint(tmp_path / "src") == before
    link.symlink_to(outside)
    with pytest.raises(DataError, match="symbolic link that leads out"):
        prepare_bandai2(tmp_path / "src", card=TOY_CARD, workers=0)
