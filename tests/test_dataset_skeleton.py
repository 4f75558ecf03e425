"""Declared data sets, issue 28's skeleton items: one ASF per subject (a pattern: each AMC takes
the nearest ASF), a single ASF applied across subjects refused, AMC clips whose bones do not
fit their ASF refused by bone; the skeleton tolerance and errors naming the joint, the
difference and every file; a dummy root that moves folded into the hips (world positions
unchanged); strips coloured by the declared hips' naming.  The data are written by the tests.
"""

from __future__ import annotations

import io
import json
import tarfile

import numpy as np
import pytest

from repro.data.dataset_prepare import prepare_dataset
from repro.errors import DataError, SpecError


from test_dataset_spec_options import fresh_registry  # noqa: F401 (fixture)


def _clipset(spec):
    from repro.data.dataset_registration import register_spec_path
    from repro.data.registry import load_clipset

    return load_clipset(register_spec_path(str(spec)))


def _rows(clips, name):
    i = clips.clip_names.index(name)
    return slice(int(clips.starts[i]), int(clips.starts[i] + clips.lengths[i]))


# ------------------------------------------------------------------------------ BVH writing
def bvh_text(joints, motion: np.ndarray, frame_time: float = 1 / 30) -> str:
    """A BVH file: ``joints`` = (name, parent index, offset, channels) in depth-first order
    (a joint without children gets an End Site), ``motion`` (T, channels)."""
    kids = {j: [k for k, jt in enumerate(joints) if jt[1] == j] for j in range(len(joints))}
    out = ["HIERARCHY"]

    def emit(j: int, depth: int) -> None:
        name, parent, off, chans = joints[j]
        pad = "  " * depth
        out.append(f"{pad}{'ROOT' if parent < 0 else 'JOINT'} {name}")
        out.append(pad + "{")
        out.append(f"{pad}  OFFSET {off[0]!r} {off[1]!r} {off[2]!r}")
        out.append(f"{pad}  CHANNELS {len(chans)} {' '.join(chans)}")
        for k in kids[j]:
            emit(k, depth + 1)
        if not kids[j]:
            out.extend([f"{pad}  End Site", pad + "  {", f"{pad}    OFFSET 0.0 -5.0 0.0",
                        pad + "  }"])
        out.append(pad + "}")

    emit(0, 0)
    out += ["MOTION", f"Frames: {len(motion)}", f"Frame Time: {frame_time!r}"]
    out += [" ".join(repr(float(v)) for v in row) for row in motion]
    return "\n".join(out) + "\n"


POS = ("Xposition", "Yposition", "Zposition")
ROT = ("Zrotation", "Xrotation", "Yrotation")
#: a small body in centimetres; the harness finds its hips (LeftUpLeg / RightUpLeg) and Head
BODY = [("Hips", -1, (0.0, 0.0, 0.0), POS + ROT),
        ("LeftUpLeg", 0, (10.0, -5.0, 0.0), ROT), ("LeftLeg", 1, (0.0, -40.0, 0.0), ROT),
        ("RightUpLeg", 0, (-10.0, -5.0, 0.0), ROT), ("RightLeg", 3, (0.0, -40.0, 0.0), ROT),
        ("Spine", 0, (0.0, 20.0, 0.0), ROT), ("Head", 5, (0.0, 30.0, 0.0), ROT)]


def _body_motion(seed: int, T: int = 24) -> np.ndarray:
    """(T, channels) of BODY: a walk forward with small joint swings, in cm and degrees."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) / 30.0
    cols = [2 * np.sin(3 * t), 90 + 2 * np.sin(6 * t), 60 * t]
    for _ in range(len(BODY) * 3):
        cols.append(15 * np.sin(2 * np.pi * rng.uniform(0.5, 1.5) * t + rng.uniform(0, 6)))
    return np.stack(cols, 1)


def _bvh_folder(folder, n: int = 8, offsets=None) -> list[str]:
    """``n`` clips walk_00, run_01, ... (half each); ``offsets(k)`` edits clip k's BODY."""
    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for k in range(n):
        body = [list(j) for j in BODY]
        if offsets is not None:
            offsets(k, body)
        name = f"{'walk' if k % 2 == 0 else 'run'}_{k:02d}"
        (folder / f"{name}.bvh").write_text(bvh_text([tuple(j) for j in body], _body_motion(k)))
        names.append(name)
    return names


BVH_SPEC = """schema = 1
name = "skel"
[source]
path = "clips"
[labels]
pattern = '^(?P<action>[a-z]+)_\\d+$'
[skeleton]
units = "cm"
{skeleton}
[split]
test_fraction = 0.25
"""


# ------------------------------------------------------------------------------- tolerance
def _shift(files: set[int], joint: str, dy: float):
    def edit(k, body):
        if k in files:
            j = next(i for i, b in enumerate(body) if b[0] == joint)
            x, y, z = body[j][2]
            body[j][2] = (x, y + dy, z)
    return edit


def _refused(tmp_path, edit) -> tuple:
    """(spec, message) of 12 clips edited by ``edit`` and refused by a spec without
    ``offset_tolerance``."""
    _bvh_folder(tmp_path / "clips", 12, edit)
    spec = tmp_path / "skel.toml"
    spec.write_text(BVH_SPEC.format(skeleton=""))
    with pytest.raises(DataError) as ei:
        prepare_dataset(spec)
    return spec, str(ei.value)


def test_offsets_that_differ_name_the_joint_the_size_and_every_file(tmp_path, fresh_registry):
    # the reference is the first file in the source's order: run_01.bvh (k = 1)
    spec, msg = _refused(tmp_path, _shift({3, 6, 9, 10}, "LeftLeg", -0.04))
    assert "OFFSETs of 4 of 12 files differ from the reference run_01.bvh's (the first in " \
        "the source)" in msg
    assert "joint 'LeftLeg' by 0.04 cm in" in msg and "offset_tolerance = 1e-05 m" in msg
    for f in ("run_03.bvh", "walk_06.bvh", "run_09.bvh", "walk_10.bvh"):
        assert f in msg
    assert "raise offset_tolerance" in msg and "\n" not in msg and "odd one" not in msg

    # within a wider tolerance: prepared, every clip on the reference's bones, the card says so
    spec.write_text(BVH_SPEC.format(skeleton="offset_tolerance = 0.001"))
    res = prepare_dataset(spec)
    card = json.loads((res.path / "meta.json").read_text())["card"]
    assert any("OFFSETs of 4 file(s) differ from the reference run_01.bvh's by up to 0.04 cm "
               "(joint 'LeftLeg'), within [skeleton] offset_tolerance = 0.001 m" in w
               for w in card["warnings"]), card["warnings"]
    clips = _clipset(spec)
    leg = clips.skeleton.index("LeftLeg")
    assert np.allclose(clips.skeleton.offsets[leg], [0.0, -0.40, 0.0])  # the reference's


def test_every_differing_file_is_counted_the_list_is_capped(tmp_path, fresh_registry):
    # 11 files differ from the reference run_01.bvh (k = 1): two joints, 0.5 to 1.5 cm and
    # 2 cm; ten names, then "and 1 more"
    def edit(k, body):
        if k != 1:
            j = 2 if k < 11 else 6
            x, y, z = body[j][2]
            body[j][2] = (x, y + (0.5 + 0.1 * k if j == 2 else 2.0), z)
    _, msg = _refused(tmp_path, edit)
    assert "OFFSETs of 11 of 12 files" in msg
    assert "joint 'Head' by 2 cm in run_11.bvh; joint 'LeftLeg' by 0.5 cm to 1.5 cm in " \
        "walk_10.bvh, " in msg  # the largest first
    assert "the reference agrees with no other file: is it the odd one?" in msg
    assert msg.count(".bvh") == 11  # the reference and ten files named ...
    assert "and 1 more" in msg      # ... the eleventh counted


def test_the_new_skeleton_fields_keep_old_keys_and_enter_new_ones(tmp_path):
    from repro.data.dataset_spec import key_material, load_dataset_spec

    spec = tmp_path / "skel.toml"
    spec.write_text(BVH_SPEC.format(skeleton=""))
    d = key_material(load_dataset_spec(spec))
    assert "offset_tolerance" not in d["skeleton"] and "fold_dummy_root" not in d["skeleton"]
    spec.write_text(BVH_SPEC.format(skeleton="offset_tolerance = 0.001\n"
                                    'dummy_root = "r"\nfold_dummy_root = true'))
    d = key_material(load_dataset_spec(spec))
    assert d["skeleton"]["offset_tolerance"] == 0.001 and d["skeleton"]["fold_dummy_root"]
    spec.write_text(BVH_SPEC.format(skeleton="fold_dummy_root = true"))
    with pytest.raises(SpecError, match="fold_dummy_root needs dummy_root"):
        load_dataset_spec(spec)
    spec.write_text(BVH_SPEC.format(skeleton="offset_tolerance = 0"))
    with pytest.raises(SpecError, match="offset_tolerance"):
        load_dataset_spec(spec)


#: fingerprints of specs that use none of issue 28's skeleton fields, prepared by the code
#: before them (commit 7e64fc0): a BVH folder and an ASF/AMC folder with one ``asf`` file
OLD_FINGERPRINTS = {
    "bvh": "f4a8e0695ed8ba3bb9d1d183b7f840f82282badf64aeadc912708ce889767126",
    "asf": "f0fab103bc0dd789915567b867487a2274e78778ed9bd2bc1cc391b1dce99c9b",
}


def test_specs_without_the_new_fields_keep_their_fingerprints(tmp_path, fresh_registry):
    _bvh_folder(tmp_path / "clips", 8)
    spec = tmp_path / "skel.toml"
    spec.write_text(BVH_SPEC.format(skeleton=""))
    assert prepare_dataset(spec).fingerprint == OLD_FINGERPRINTS["bvh"]
    _subjects(tmp_path / "cmu", subjects=("s01",))
    spec = tmp_path / "cmu.toml"
    spec.write_text(CMU_SPEC.format(asf="s01/s01.asf", extra=""))
    assert prepare_dataset(spec).fingerprint == OLD_FINGERPRINTS["asf"]


# ------------------------------------------------------------------------------ dummy root
#: BODY under a dummy root that carries the motion (the loop clips of issue 28)
DUMMY = [("joint_Root", -1, (0.0, 0.0, 0.0), POS + ROT)] + [
    (n, p + 1, off, ch) for n, p, off, ch in BODY]


def _dummy_motion(seed: int, T: int = 24) -> np.ndarray:
    """The dummy walks and turns (yaw 40°/s, a few degrees of tilt); the hips sway in place at
    90 cm, far from their OFFSET (0, 0, 0)."""
    t = np.arange(T) / 30.0
    dummy = np.stack([30 * t, 1 + 0 * t, 80 * t, 4 * np.sin(5 * t), 3 * np.cos(4 * t),
                      40 * t + 10 * seed], 1)
    return np.concatenate([dummy, _body_motion(seed, T)], 1)


def _dummy_folder(folder, n: int = 8) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for k in range(n):
        name = f"{'walk' if k % 2 == 0 else 'run'}_{k:02d}"
        (folder / f"{name}.bvh").write_text(bvh_text(DUMMY, _dummy_motion(k)))


def test_a_moving_dummy_root_is_folded_into_the_hips(tmp_path, fresh_registry):
    from repro.data.bvh import read_bvh

    _dummy_folder(tmp_path / "clips")
    spec = tmp_path / "skel.toml"
    spec.write_text(BVH_SPEC.format(skeleton=""))
    with pytest.raises(DataError, match=r"position channels of 'Hips' move it 9\d(\.\d+)? units .*"
                       r"dummy_root = 'joint_Root' and fold_dummy_root = true"):
        prepare_dataset(spec)
    spec.write_text(BVH_SPEC.format(skeleton='dummy_root = "joint_Root"'))
    with pytest.raises(DataError, match=r"dummy root 'joint_Root' is not all zero .* fold it "
                       r"into 'Hips': \[skeleton\] fold_dummy_root = true"):
        prepare_dataset(spec)
    spec.write_text(BVH_SPEC.format(skeleton='dummy_root = "joint_Root"\nfold_dummy_root = true'))
    prepare_dataset(spec)
    clips = _clipset(spec)
    assert clips.skeleton.names == tuple(n for n, *_ in BODY)
    for name in ("walk_00", "run_05"):
        want = read_bvh(tmp_path / "clips" / f"{name}.bvh").world_positions(0.01)[:, 1:]
        got = np.asarray(clips.joints[_rows(clips, name)], np.float64)
        assert np.abs(got - want).max() < 2e-6  # stored as float32 (metres, up to 2 m)


def test_folding_keeps_every_world_position_in_float64():
    """:func:`fold_dummy_root` composes the dummy's transform into its child: forward
    kinematics before (with the dummy) and after (without) agree to 1e-9 m."""
    from repro.data.bvh import parse_bvh
    from repro.data.dataset_skeleton import fold_dummy_root
    from repro.motion.rotations import quat_to_matrix
    from repro.motion.skeleton import Skeleton, forward_kinematics

    b = parse_bvh(bvh_text(DUMMY, _dummy_motion(3)), "x.bvh")
    before = b.world_positions(0.01)
    q, t = fold_dummy_root(np.asarray(b.local_rotations(as_quaternions=True), np.float64),
                           b.local_translations() * 0.01)
    sk = Skeleton(b.names[1:], [p - 1 for p in b.parents[1:]], b.offsets[1:] * 0.01)
    after = forward_kinematics(sk, quat_to_matrix(q), t[:, 0], offsets=t)
    after = np.asarray(after, np.float64)
    assert np.abs(after - before[:, 1:]).max() < 1e-9
    assert np.abs(before[:, 1] - before[0, 1]).max() > 0.3  # the body did move


# ------------------------------------------------------------------------- ASF per subject
CMU_SPEC = """schema = 1
name = "cmu"
[source]
path = "cmu"
format = "asf_amc"
asf = "{asf}"
[labels]
pattern = '^s\\d+_\\d+_(?P<action>[ab])$'
[skeleton]
units = "inch"
hips = ["lfemur", "rfemur"]
{extra}
[frames]
fps = 120.0
[split]
test_fraction = 0.25
"""
ORDER = "TX TY TZ RX RY RZ"


def _asf_for(subject: str) -> str:
    """The test ASF (tests/test_asf_amc.py); subject s02's thighs 5 % longer and one axis
    turned, so that pairing its clips with s01's skeleton would change their rotations."""
    from test_asf_amc import write_asf

    text = write_asf(root_order=ORDER, length_unit=0.45)
    if subject == "s02":
        text = text.replace("length 7.0", "length 7.35").replace(
            "axis 10.0 -5.0 30.0 ZYX", "axis 25.0 -5.0 30.0 ZYX")
    assert subject != "s02" or "7.35" in text and "25.0 -5.0" in text
    return text


def _subjects(folder, subjects=("s01", "s02"), *, amc_edit=None) -> dict[str, str]:
    """CMU's layout: ``<subject>/<subject>.asf`` beside ``<subject>/<subject>_<k>_<a|b>.amc``;
    returns clip -> AMC text."""
    from test_asf_amc import make_motion, write_amc

    texts = {}
    for i, s in enumerate(subjects):
        (folder / s).mkdir(parents=True, exist_ok=True)
        (folder / s / f"{s}.asf").write_text(_asf_for(s))
        for k in range(4):
            clip = f"{s}_{k:02d}_{'ab'[k % 2]}"
            text = write_amc(make_motion(ORDER, seed=10 * i + k), ORDER)
            if amc_edit is not None and s == subjects[-1]:
                text = amc_edit(text)
            (folder / s / f"{clip}.amc").write_text(text)
            texts[clip] = text
    return texts


def test_one_asf_applied_across_subjects_is_refused(tmp_path, fresh_registry):
    _subjects(tmp_path / "cmu")
    spec = tmp_path / "cmu.toml"
    spec.write_text(CMU_SPEC.format(asf="s01/s01.asf", extra=""))
    with pytest.raises(DataError, match=r"asf = 's01/s01.asf' is applied to every clip, but 1 "
                       r"folder\(s\) of clips hold their own ASF \(s02/s02_00_a.amc beside "
                       r"s02/s02.asf\); one ASF per subject: write asf = \"\*.asf\""):
        prepare_dataset(spec)


def _subject_bytes(src, layout: str):
    """The source as written (a folder), or the same files in a .tar.gz."""
    if layout == "folder":
        return "cmu"
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tf:
        for p in sorted(src.rglob("*")):
            if p.is_file():
                tf.add(p, arcname=p.relative_to(src).as_posix())
    (src.parent / "cmu.tar.gz").write_bytes(buf.getvalue())
    return "cmu.tar.gz"


@pytest.mark.parametrize("layout", ["folder", "archive"])
def test_each_amc_takes_its_own_subjects_asf(tmp_path, fresh_registry, layout):
    from repro.data.asf_amc import parse_amc, parse_asf, to_skeleton_motion
    from repro.motion.rotations import quat_to_matrix
    from repro.motion.skeleton import forward_kinematics

    texts = _subjects(tmp_path / "cmu")
    path = _subject_bytes(tmp_path / "cmu", layout)
    spec = tmp_path / "cmu.toml"
    spec.write_text(CMU_SPEC.format(asf="*.asf", extra="").replace('"cmu"\nformat',
                                                                    f'"{path}"\nformat'))
    # the thighs differ by 5 %: refused with the joint, the size, the files and their ASF
    with pytest.raises(DataError) as ei:
        prepare_dataset(spec)
    msg = str(ei.value)
    assert "OFFSETs of 4 of 8 files differ from the reference s01/s01_00_a.amc (ASF " \
        "s01/s01.asf)'s (the first in the source)" in msg
    assert "joint 'ltibia' by 1.86 cm in s02/s02_00_a.amc (ASF s02/s02.asf)" in msg, msg
    spec.write_text(CMU_SPEC.format(asf="*.asf", extra="offset_tolerance = 0.05").replace(
        '"cmu"\nformat', f'"{path}"\nformat'))
    res = prepare_dataset(spec)
    card = json.loads((res.path / "meta.json").read_text())["card"]
    assert any("reference s01/s01_00_a.amc (ASF s01/s01.asf)'s by up to 1.86 cm" in w
               for w in card["warnings"]), card["warnings"]
    clips = _clipset(spec)
    name = "s02_01_b"
    rows = _rows(clips, name)
    got = quat_to_matrix(np.asarray(clips.rotations[rows], np.float64))
    want = {}
    for s in ("s01", "s02"):
        asf = parse_asf(_asf_for(s), f"{s}.asf")
        want[s] = to_skeleton_motion(asf, parse_amc(texts[name], "x.amc", asf),
                                     length_scale=0.0254 / 0.45)
    assert np.abs(np.asarray(got) - want["s02"][2]).max() < 1e-5   # its own subject's ASF
    assert np.abs(np.asarray(got) - want["s01"][2]).max() > 0.05   # not subject 1's
    # posed on the reference's bones: FK of its rotations and root on the data set's skeleton
    joints = forward_kinematics(clips.skeleton, want["s02"][2], want["s02"][1])
    assert np.abs(np.asarray(clips.joints[rows]) - np.asarray(joints)).max() < 1e-5


def test_amc_bones_that_do_not_fit_their_asf_are_named(tmp_path, fresh_registry):
    from repro.data.asf_amc import parse_amc, parse_asf

    texts = _subjects(tmp_path / "cmu", amc_edit=lambda t: t.replace("\nlclav ", "\nlclavicle ")
                      .replace("\nhead ", "\nskull "))
    spec = tmp_path / "cmu.toml"
    spec.write_text(CMU_SPEC.format(asf="*.asf", extra="offset_tolerance = 0.05"))
    with pytest.raises(DataError) as ei:
        prepare_dataset(spec)
    e = ei.value
    assert str(e.file).endswith("s02/s02_00_a.amc")
    assert "its bones do not fit the ASF" in str(e) and "s02.asf" in str(e)
    assert "unknown bones 'skull', 'lclavicle' (not in the ASF)" in str(e)
    assert "frame 1 gives no values for bones 'head', 'lclav'" in str(e)
    asf = parse_asf(_asf_for("s01"), "s01.asf")
    with pytest.raises(DataError, match=r"unknown bone 'skull'") as ei:
        parse_amc(texts["s02_00_a"].replace("lclavicle", "lclav"), "one.amc", asf)
    assert ei.value.line == texts["s02_00_a"].split("\n").index(
        next(ln for ln in texts["s02_00_a"].split("\n") if ln.startswith("skull "))) + 1


def test_the_nearest_asf_rule():
    from repro.data.dataset_asf import SkeletonFiles
    from repro.data.dataset_spec import DatasetSpec

    spec = DatasetSpec.model_validate({"schema": 1, "name": "x", "source": {
        "path": "p", "format": "asf_amc", "asf": "*.asf"}})
    files = {p: (b"", p) for p in ("all/01.asf", "all/02.asf", "all/010.asf", "sub/03/03.asf",
                                   "top.asf", "two/a.asf", "two/b.asf")}
    sf = SkeletonFiles(spec, files, [])
    assert sf.asf_for("all/01_01.amc") == "all/01.asf"          # the stem's prefix
    assert sf.asf_for("all/010_01.amc") == "all/010.asf"        # the longest prefix
    assert sf.asf_for("sub/03/03_01.amc") == "sub/03/03.asf"    # its own folder
    assert sf.asf_for("sub/03/deep/x.amc") == "sub/03/03.asf"   # the nearest above
    assert sf.asf_for("other/x.amc") == "top.asf"
    with pytest.raises(DataError, match=r"'two' holds 2 ASFs matching '\*.asf' \(two/a.asf, "
                       "two/b.asf\\)") as ei:
        sf.asf_for("two/c_01.amc")
    assert ei.value.file == "two/c_01.amc"
    with pytest.raises(DataError, match="no ASF matching"):
        SkeletonFiles(spec, {"a/x.asf": (b"", "")}, []).asf_for("b/y.amc")


# -------------------------------------------------------------------------- strip colours
CMU_NAMES = ("root", "lhipjoint", "lfemur", "ltibia", "rhipjoint", "rfemur", "rtibia",
             "lowerback", "thorax", "head", "lclavicle", "lhumerus", "rclavicle", "rhumerus")


def test_strip_sides_follow_the_declared_hips_naming():
    from repro.render.strips import side_of, skeleton_sides

    assert {side_of(n) for n in CMU_NAMES} == {2}  # names alone: no side found
    sides = dict(zip(CMU_NAMES, skeleton_sides(CMU_NAMES, ("lfemur", "rfemur"))))
    assert [n for n, s in sides.items() if s == 0] == ["lhipjoint", "lfemur", "ltibia",
                                                       "lclavicle", "lhumerus"]
    assert [n for n, s in sides.items() if s == 1] == ["rhipjoint", "rfemur", "rtibia",
                                                       "rclavicle", "rhumerus"]
    assert skeleton_sides(("Hips", "Leg.L", "Leg.R", "Arm.L", "Arm.R", "Head"),
                          ("Leg.L", "Leg.R")) == [2, 0, 1, 0, 1, 2]
    assert skeleton_sides(("a", "UpperLeg_L"), None) == [2, 0]


def test_strips_draw_cmu_sides_in_the_side_colours():
    from repro.render import Panel, render_strip
    from repro.render.strips import LEFT_RGB, RIGHT_RGB, skeleton_sides

    names = ("root", "lfemur", "ltibia", "rfemur", "rtibia", "thorax", "head")
    parents = (-1, 0, 1, 0, 3, 0, 5)
    rest = np.array([[0, 1, 0], [0.1, 0.9, 0.3], [0.1, 0.5, 0.3], [-0.1, 0.9, -0.3],
                     [-0.1, 0.5, -0.3], [0, 1.4, 0], [0, 1.7, 0]], float)
    panel = Panel("cmu", np.repeat(rest[None], 4, 0))

    def count(img, rgb):
        return int((np.abs(img.rgba[..., :3].astype(int) - rgb).sum(-1) == 0).sum())

    plain = render_strip([panel], parents, names, key_frames=2)
    sided = render_strip([panel], parents, names, key_frames=2,
                         sides=skeleton_sides(names, ("lfemur", "rfemur")))
    assert count(plain, LEFT_RGB) == 0 and count(plain, RIGHT_RGB) == 0
    assert count(sided, LEFT_RGB) > 20 and count(sided, RIGHT_RGB) > 20
    with pytest.raises(ValueError, match="sides"):
        render_strip([panel], parents, names, sides=[0, 1])


def test_a_runs_strips_take_the_sides_of_its_skeletons_hips(tmp_path, monkeypatch):
    """``write_strips`` colours a skeleton with declared hips (a CMU spec's) by their naming."""
    from types import SimpleNamespace

    from PIL import Image

    from repro.motion.skeleton import Skeleton
    from repro.render import Panel
    from repro.render.strips import LEFT_RGB
    from repro.report import strip_sets

    names = ("root", "lfemur", "ltibia", "rfemur", "rtibia", "thorax", "head")
    parents = (-1, 0, 1, 0, 3, 0, 5)
    rest = np.array([[0, 1, 0], [0.1, 0.9, 0.3], [0.1, 0.5, 0.3], [-0.1, 0.9, -0.3],
                     [-0.1, 0.5, -0.3], [0, 1.4, 0], [0, 1.7, 0]], float)
    sk = Skeleton(names, parents, np.zeros((7, 3)), ("lfemur", "rfemur"))
    strip = strip_sets.Strip("s", "t", [Panel("cmu", np.repeat(rest[None], 4, 0))], [0, 3],
                             {"band": 0})
    monkeypatch.setattr(strip_sets, "table_strips", lambda rs, **kw: ([strip], []))
    rs = SimpleNamespace(bands=[SimpleNamespace(items=SimpleNamespace(skeleton=sk))],
                         spec=SimpleNamespace(id="marionette/table1"), run_id="r")
    strip_sets.write_strips(rs, tmp_path, formats=("png",))
    rgb = np.asarray(Image.open(tmp_path / "s.png").convert("RGB"), int)
    assert (np.abs(rgb - LEFT_RGB).sum(-1) == 0).sum() > 20
