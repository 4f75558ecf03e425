"""Issue 29, items 2 and 5: unbounded numbers and non-finite data in a data-set or table spec.

A ``[frames] resample_to`` of 1e6 or 1e9, 240 fps on a long clip, a 1,000,000-frame BVH, a
clip of many joints without channels and too many frames in all are refused from the clips'
headers, before their frames are parsed (one line naming the file or option, exit 2, under
1 GiB of address space and a timeout); a resampling that leaves a clip one frame is refused;
a root position of 1e300 (finite in float64, infinite in float32) is refused naming the clip
and nothing is published; the posture check fails on NaN; ``write_cache`` refuses non-finite
arrays; a table spec's ``version`` and protocol ``fps`` are bounded.  The BVH files are written
by repeating one frame line, so a 37 MB file takes a fraction of a second.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fuzz_dataset_strategies import HIPS_AND_LEGS
from repro.errors import DataError, SpecError
from repro.paths import repo_root

#: a five-joint skeleton whose hips and head the harness finds by name
HEAD = HIPS_AND_LEGS + """  JOINT Spine
  {
    OFFSET 0 20 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT Head
    {
      OFFSET 0 30 0
      CHANNELS 3 Zrotation Xrotation Yrotation
      End Site
      {
        OFFSET 0 10 0
      }
    }
  }
%s}
MOTION
"""
ROW = "0 90 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0\n"


def write_set(folder: Path, frames: int, *, clips: int = 2, fps: float = 30.0, row: str = ROW,
              frames_toml: str = "", extra_joints: int = 0, name: str = "numbers") -> Path:
    """``clips`` BVH files of ``frames`` copies of ``row`` under ``folder/src`` and a spec
    labelling them all 'walk'; ``extra_joints`` channel-less joints hang off the root."""
    src = folder / "src"
    src.mkdir(parents=True, exist_ok=True)
    extra = "".join(f" JOINT x{k}\n {{\n  OFFSET 0 1 0\n }}\n" for k in range(extra_joints))
    head = (HEAD % extra + f"Frames: {frames}\nFrame Time: {1 / fps:.7f}\n").encode()
    body = row.encode() * frames
    for k in range(clips):
        (src / f"walk_{k}.bvh").write_bytes(head + body)
    spec = folder / "spec.toml"
    spec.write_text(f'schema = 1\nname = "{name}"\n[source]\npath = "src"\n[labels]\n'
                    "from = \"filename\"\npattern = '^(?P<action>[a-z]+)_\\d+$'\n[split]\n"
                    f"test_fraction = 0.5\n{frames_toml}\n")
    return spec


def run_limited(args: list[str], home: Path, timeout: float = 60.0):
    """``repro ARGS`` in a subprocess under RLIMIT_AS = 1 GiB (stdout, stderr, exit code)."""
    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))

    return subprocess.run([sys.executable, "-m", "cli.main", *args], capture_output=True,
                          text=True, cwd=repo_root(), timeout=timeout, preexec_fn=limit,
                          env={**os.environ, "REPRO_HOME": str(home), "REPRO_DATASETS": ""})


def assert_one_line(out, *needles: str) -> str:
    assert out.returncode == 2, (out.returncode, out.stderr[-2000:])
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("repro: error: "), out.stderr[-2000:]
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


def nothing_published(home: Path, name: str = "numbers") -> bool:
    root = home / "datasets" / name
    return not root.exists() or not [p for p in root.iterdir() if not p.name.startswith(".")]


@pytest.fixture
def home(tmp_path, monkeypatch):
    h = tmp_path / "home"
    monkeypatch.setenv("REPRO_HOME", str(h))
    monkeypatch.setenv("REPRO_DATASETS", "")
    return h


# ------------------------------------------------------------------------ [frames] bounds
@pytest.mark.parametrize("value", ["1e6", "1e9", "1e-9", "0.5", "1001"])
def test_resample_to_out_of_range_is_refused_by_the_spec(tmp_path, value):
    from repro.data.dataset_spec import load_dataset_spec

    spec = write_set(tmp_path, 10, frames_toml=f"[frames]\nresample_to = {value}")
    with pytest.raises(SpecError, match="resample_to"):
        load_dataset_spec(spec)


def test_frames_fps_is_bounded(tmp_path):
    from repro.data.dataset_spec import load_dataset_spec

    for bad in ("1e308", "-30", "0"):
        with pytest.raises(SpecError, match="frames.fps"):
            load_dataset_spec(write_set(tmp_path, 10, frames_toml=f"[frames]\nfps = {bad}"))
    load_dataset_spec(write_set(tmp_path, 10, frames_toml="[frames]\nfps = 120\nresample_to = 1000"))


def test_cli_resample_to_1e6_one_line(tmp_path):
    spec = write_set(tmp_path, 100, frames_toml="[frames]\nresample_to = 1e6")
    out = run_limited(["data", "prepare", str(spec)], tmp_path / "home")
    assert_one_line(out, "resample_to")
    assert nothing_published(tmp_path / "home")


# ------------------------------------------------------------------------ frames per clip
def test_cli_upsampling_past_the_clip_cap_is_refused_from_the_header(tmp_path):
    """240 fps from 30 multiplies 30,000 frames by 8: over MAX_CLIP_FRAMES, refused before
    the frames are parsed (the old code built the 240,000 frames: GBs)."""
    spec = write_set(tmp_path, 30_000, frames_toml="[frames]\nresample_to = 240")
    out = run_limited(["data", "prepare", str(spec)], tmp_path / "home")
    line = assert_one_line(out, "walk_0.bvh", "239,993 frames after resampling to 240 fps",
                           "MAX_CLIP_FRAMES")
    assert "resample_to" in line
    assert nothing_published(tmp_path / "home")


def test_cli_37_mb_clip_of_a_million_frames_is_refused_from_its_header(tmp_path):
    """The issue's 37 MB, 1,000,000-frame BVH took 2 GB to prepare."""
    # walk_1 stays a short clip of the class, so the split check (a class needs a training and
    # a test clip, checked from file names first) passes and the header check is what refuses
    write_set(tmp_path, 10, clips=2)
    spec = write_set(tmp_path, 1_000_000, clips=1)
    assert (tmp_path / "src" / "walk_0.bvh").stat().st_size > 37_000_000
    out = run_limited(["data", "prepare", str(spec)], tmp_path / "home")
    assert_one_line(out, "walk_0.bvh", "1,000,000 frames", "MAX_CLIP_FRAMES")
    assert nothing_published(tmp_path / "home")


def test_joints_without_channels_count_towards_the_clip_cap(home, tmp_path):
    """400 joints that cost no byte per frame in the file still cost memory per frame."""
    from repro.data.dataset_prepare import prepare_dataset

    spec = write_set(tmp_path, 15_000, extra_joints=400)  # 405 × 15,000 = 6.1 M frame-joints
    with pytest.raises(DataError, match="MAX_CLIP_JOINT_FRAMES") as e:
        prepare_dataset(spec)
    assert "walk_0.bvh" in str(e.value) and "405 joints" in str(e.value)
    assert "[limits] max_clip_joint_frames" in str(e.value)  # the way round is named


def test_total_frames_are_capped(home, tmp_path):
    """Counted over the clips as they stream; here the cap is the spec's own ``[limits]`` (the
    cost of this test is loading torch for the first clip, nothing more)."""
    from repro.data.dataset_prepare import prepare_dataset

    spec = write_set(tmp_path, 100, clips=3, frames_toml="[limits]\nmax_total_frames = 150")
    with pytest.raises(DataError, match="200 frames .*the spec's \\[limits\\] max_total_frames"
                       ) as e:
        prepare_dataset(spec)
    assert "walk_1.bvh" in str(e.value)  # the clip that crossed the cap is named
    assert nothing_published(home)


def test_a_cap_names_itself_and_the_way_round():
    from repro.data import prepare_caps

    budget = prepare_caps.FrameBudget(None, None)
    for k in range(10):  # 10 clips of 200,000 frames × 25 joints: 50 million frame-joints
        budget.check(f"{k}.bvh", 200_000, 120.0, 25)
    with pytest.raises(DataError) as e:
        budget.check("b.bvh", 1_000, 120.0, 25)
    assert "b.bvh: the clips read up to this one hold 50,025,000 frame-joints" in str(e.value)
    assert ("prepare_caps.MAX_TOTAL_JOINT_FRAMES; raise it for this data set with [limits] "
            "max_total_joint_frames in the spec" in str(e.value))
    for cap, key, args in (("MAX_CLIP_FRAMES", "max_clip_frames", (300_000, 120.0, 1)),
                           ("MAX_CLIP_JOINT_FRAMES", "max_clip_joint_frames", (150_000, 120.0, 50))):
        with pytest.raises(DataError) as e:
            prepare_caps.FrameBudget(None, None).check("c.bvh", *args)
        assert f"prepare_caps.{cap}; raise it" in str(e.value) and f"[limits] {key}" in str(e.value)


def test_caps_admit_long_clips_and_a_cmu_sized_set():
    """The first caps refused a 31-joint clip of 4.5 min at 120 fps and all of CMU (9 h at
    120 fps, 31 joints) resampled to 30 fps; both are within the caps now."""
    from repro.data import prepare_caps

    prepare_caps.FrameBudget(None, None).check("long.bvh", 25 * 60 * 120, 120.0, 31)
    budget = prepare_caps.FrameBudget(30.0, None)
    for k in range(2_000):  # 2,000 clips of 16.5 s: 9.2 h at 120 fps
        budget.check(f"{k}.amc", 1_980, 120.0, 31)
    assert budget.frames == 2_000 * 495 and budget.joint_frames == 2_000 * 495 * 31


def test_limits_raise_a_cap_for_one_data_set(home, tmp_path, monkeypatch):
    from repro.data import prepare_caps
    from repro.data.dataset_prepare import prepare_dataset

    monkeypatch.setattr(prepare_caps, "MAX_CLIP_JOINT_FRAMES", 100)  # 5 joints × 30 frames
    with pytest.raises(DataError, match="MAX_CLIP_JOINT_FRAMES"):
        prepare_dataset(write_set(tmp_path, 30))
    res = prepare_dataset(write_set(tmp_path, 30, frames_toml="[limits]\n"
                                    "max_clip_joint_frames = 150"))
    assert (res.clips, res.frames) == (2, 60)


@pytest.mark.parametrize("value", ["0", "-1", "1e6", "true", '"10"', "10000000001"])
def test_limits_are_validated(tmp_path, value):
    from repro.data.dataset_spec import load_dataset_spec

    with pytest.raises(SpecError, match="limits"):
        load_dataset_spec(write_set(tmp_path, 10, frames_toml=f"[limits]\nmax_clip_frames = {value}"))
    with pytest.raises(SpecError, match="limits"):
        load_dataset_spec(write_set(tmp_path, 10, frames_toml="[limits]\nmax_frames = 10"))


def test_limits_stay_out_of_the_fingerprint(tmp_path):
    """Caps refuse data, they never change its bytes: a spec keeps its key with [limits]."""
    from repro.data.dataset_registration import spec_key
    from repro.data.dataset_spec import key_material, load_dataset_spec

    plain = write_set(tmp_path / "a", 10)
    lifted = write_set(tmp_path / "b", 10, frames_toml="[limits]\nmax_clip_frames = 9000000\n"
                       "max_total_joint_frames = 2000000000")
    a, b = load_dataset_spec(plain), load_dataset_spec(lifted)
    assert b.limits.max_clip_frames == 9_000_000
    assert key_material(a) == key_material(b) and "limits" not in key_material(b)
    assert spec_key(a, plain) != "" and spec_key(a, plain) == spec_key(b, plain)


def test_sliced_conversion_equals_whole_conversion_bitwise(monkeypatch):
    """A long clip is converted in slices (rotations, resampling, forward kinematics): with
    the threshold lowered, a small clip's slices give the whole clip's bytes."""
    import torch

    from repro.data import prepare_caps
    from repro.data.bvh import Bvh, parse_bvh
    from repro.motion.skeleton import Skeleton

    rng = np.random.default_rng(3)
    rows = rng.uniform(-170, 170, (97, 18))
    rows[:, :3] = rng.uniform(-50, 50, (97, 3))
    text = HEAD % "" + "Frames: 97\nFrame Time: 0.0333333\n" + "".join(
        " ".join(f"{v:.6f}" for v in r) + "\n" for r in rows)
    b = parse_bvh(text.encode(), "x.bvh")
    skel = Skeleton(b.names, b.parents, np.asarray(b.offsets) / 100)

    def run():
        q = np.asarray(b.local_rotations(as_quaternions=True), np.float64)
        qr, rr = prepare_caps.resample_clip(q, rows[:, :3] / 100, 30.0, 47.0)
        j = prepare_caps.joints_f32(skel, qr.astype(np.float32), rr.astype(np.float32))
        return q, qr, rr, j

    whole = run()
    calls = {"rot": 0}
    real = Bvh.local_rotations

    def counting(self, *a, **k):
        calls["rot"] += 1
        return real(self, *a, **k)

    monkeypatch.setattr(Bvh, "local_rotations", counting)
    monkeypatch.setattr(prepare_caps, "CHUNK_ABOVE", 40)  # 97 × 5 = 485 frame-joints: sliced
    monkeypatch.setattr(prepare_caps, "CHUNK", 35)        # slices of 7 frames
    sliced = run()
    assert calls["rot"] == 1 + 14  # the call, then one per slice of 7 frames
    for w, s in zip(whole, sliced):
        assert w.dtype == s.dtype and w.shape == s.shape
        assert w.tobytes() == s.tobytes()
    assert isinstance(whole[0], np.ndarray) and not torch.is_tensor(whole[1])


def test_resampling_that_leaves_one_frame_is_refused(home, tmp_path):
    from repro.data.dataset_prepare import prepare_dataset

    spec = write_set(tmp_path, 20, frames_toml="[frames]\nresample_to = 1")
    with pytest.raises(DataError, match="leaves 1 frame") as e:
        prepare_dataset(spec)
    assert "walk_0.bvh" in str(e.value)


def test_resampling_within_the_caps_still_prepares(home, tmp_path):
    from repro.data.dataset_prepare import prepare_dataset

    res = prepare_dataset(write_set(tmp_path, 31, frames_toml="[frames]\nresample_to = 60"))
    assert (res.clips, res.frames) == (2, 2 * 61)


def test_amc_frames_are_capped_as_they_are_read(monkeypatch):
    from test_asf_amc import ASF, AMC

    from repro.data import asf_amc, prepare_caps

    monkeypatch.setattr(prepare_caps, "MAX_CLIP_FRAMES", 3)
    asf = asf_amc.parse_asf(ASF, "s.asf")
    budget = prepare_caps.FrameBudget(None, None)
    seen = []

    def check(n):
        seen.append(n)
        budget.check("walk.amc", n, 120.0, len(asf.order), count=False)

    with pytest.raises(DataError, match="walk.amc: 4 frames; .*MAX_CLIP_FRAMES"):
        asf_amc.parse_amc(AMC, "walk.amc", asf, frame_check=check)
    assert seen == [1, 2, 3, 4]  # refused as frame 4 begins, not after the whole file
    # and prepare passes its budget to the AMC reader
    from repro.data.dataset_skeleton import convert_amc
    from repro.data.dataset_spec import SkeletonSpec

    with pytest.raises(DataError, match="walk.amc: 4 frames; .*MAX_CLIP_FRAMES"):
        convert_amc("walk.amc", AMC, asf, SkeletonSpec(), None,
                     prepare_caps.FrameBudget(None, None))


def test_amc_lines_are_not_held_as_one_list(tmp_path):
    """40 MiB of empty lines: the reader held a 40-million-item list (400 MB) before saying
    "no frames" (and 60 MiB took 14 s); it now reads line by line (a process capped at
    384 MiB of address space)."""
    from test_asf_amc import ASF

    (tmp_path / "s.asf").write_text(ASF)
    code = ("import sys\nfrom repro.data import asf_amc\nfrom repro.errors import DataError\n"
            f"asf = asf_amc.read_asf({str(tmp_path / 's.asf')!r})\n"
            "try:\n    asf_amc.parse_amc(b'\\n' * (40 << 20), 'x.amc', asf)\n"
            "except DataError as e:\n    print(e)\n")

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (384 << 20, 384 << 20))

    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=repo_root(), timeout=60, preexec_fn=limit)
    assert out.returncode == 0 and "x.amc:41943040: no frames" in out.stdout, out.stderr[-1500:]


def test_resampled_frames_is_frame_positions_count():
    from repro.data.timebase import resampled_frames
    from repro.motion.resample import frame_positions

    for n, src, dst in [(1, 30, 240), (2, 30, 1), (31, 30, 60), (1000, 120, 30), (999, 30, 29.97),
                        (7, 29.97, 30), (100_000, 30, 240)]:
        assert resampled_frames(n, src, dst) == len(frame_positions(n, src, dst)), (n, src, dst)


# ------------------------------------------------------------------------ non-finite data
def test_cli_root_of_1e300_is_refused_naming_the_clip(tmp_path):
    """1e300 cm is finite in float64 and infinite in float32: the old code published 30,000
    inf values in root.npy with exit 0."""
    spec = write_set(tmp_path, 300, row="1e300 90 0" + " 0" * 15 + "\n")
    out = run_limited(["data", "prepare", str(spec)], tmp_path / "home")
    assert_one_line(out, "walk_0.bvh", "non-finite", "root")
    assert nothing_published(tmp_path / "home")


def test_positions_beyond_any_capture_volume_are_refused(home, tmp_path):
    from repro.data.dataset_prepare import prepare_dataset

    spec = write_set(tmp_path, 30, row="1e30 90 0" + " 0" * 15 + "\n")
    with pytest.raises(DataError, match="MAX_POSITION_M") as e:
        prepare_dataset(spec)
    assert "walk_0.bvh" in str(e.value)
    assert nothing_published(home)


def test_posture_check_fails_on_nan():
    from repro.data.dataset_prepare import _body, _posture_checks
    from repro.motion.skeleton import Skeleton

    skel = Skeleton(("Hips", "LeftUpLeg", "RightUpLeg", "Spine", "Head"), (-1, 0, 0, 0, 3),
                    np.array([[0, 0, 0], [.1, 0, 0], [-.1, 0, 0], [0, .2, 0], [0, .3, 0.]]))
    body = _body(skel, Path("spec.toml"))
    good = np.zeros((4, 5, 3), np.float32)
    good[:, 1, 0], good[:, 2, 0], good[:, 3, 1], good[:, 4, 1] = .1, -.1, .2, .5
    assert _posture_checks(skel, body, [good], 30.0, Path("spec.toml")) == []
    bad = good.copy()
    bad[2, 4] = np.nan
    with pytest.raises(DataError, match="up direction"):
        _posture_checks(skel, body, [bad], 30.0, Path("spec.toml"))


def test_write_cache_refuses_non_finite_arrays(tmp_path):
    from repro.data.cache import ARRAYS, write_cache

    arrays = {k: np.zeros(3, np.int64) for k in ARRAYS}
    arrays.update(starts=np.array([0, 2, 4]), lengths=np.array([2, 2, 2]),
                  rotations=np.zeros((6, 2, 4), np.float32), root=np.zeros((6, 3), np.float32),
                  joints=np.zeros((6, 2, 3), np.float32))
    arrays["joints"][5, 1, 2] = np.inf
    with pytest.raises(DataError, match="clip 'c': non-finite values in joints .frame 2"):
        write_cache(tmp_path, "fp", arrays, {"clip_names": ["a", "b", "c"]})
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------ table specs
def _table(tmp_path: Path, version: str = "1", fps: str = "30") -> Path:
    text = (repo_root() / "tables" / "marionette" / "table1.toml").read_text()
    lines = [f"version = {version}" if ln.startswith("version = ") else
             f"fps = {fps}" if ln.startswith("fps = ") else ln for ln in text.splitlines()]
    out = tmp_path / "marionette" / "table1.toml"
    out.parent.mkdir(exist_ok=True)
    out.write_text("\n".join(lines) + "\n")
    return out


@pytest.mark.parametrize("version, fps, where", [
    ("100000000000000000000000", "30", "version"), ("0", "30", "version"),
    ("1", "-30", "protocol_params"), ("1", "1e308", "protocol_params"), ("1", "0", "protocol_params"),
    ("1", "true", "protocol_params")])
def test_table_spec_version_and_protocol_fps_are_bounded(tmp_path, version, fps, where):
    from repro.specs.load import load_spec

    with pytest.raises(SpecError) as e:
        load_spec(_table(tmp_path, version, fps))
    assert where in str(e.value)


def test_table_spec_in_range_still_loads(tmp_path):
    from repro.specs.load import load_spec

    assert load_spec(_table(tmp_path, "1000000", "1000")).version == 1_000_000


def test_scale_profiles_are_bounded_too(tmp_path):
    from repro.errors import ConfigError
    from repro.specs.scales import load_scales

    text = (repo_root() / "tables" / "scales.toml").read_text()
    ver = [ln for ln in text.splitlines() if ln.startswith("version = ")][0]
    bad = tmp_path / "scales.toml"
    bad.write_text(text.replace(ver, "version = 100000000000000000000000", 1))
    with pytest.raises((SpecError, ConfigError), match="version"):
        load_scales(bad)
