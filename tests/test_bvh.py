"""BVH reader/writer: hierarchy and channel handling, round trips, and malformed input."""

from __future__ import annotations


import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import repro.data.bvh as bvh_mod
from repro.data.bvh import MAX_DEPTH, Bvh, parse_bvh, read_bvh
from repro.data.bvh_write import bvh_from_motion, format_bvh
from repro.data.bvh_write import save_bvh as write_bvh
from repro.errors import DataError

# A hierarchy exercising: a root with rotations before positions, per-joint channel orders,
# position channels on a non-root joint, a joint without channels, End Sites, a joint with a
# space in its name, and a joint with only one rotation channel.
MIXED = """HIERARCHY
ROOT Hips
{
  OFFSET 1.0 90.0 -2.0
  CHANNELS 6 Yrotation Xposition Yposition Zposition Xrotation Zrotation
  JOINT Spine
  {
    OFFSET 0.0 10.0 0.0
    CHANNELS 3 Xrotation Yrotation Zrotation
    JOINT Head Top
    {
      OFFSET 0.0 30.0 1.5
      CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
      End Site
      {
        OFFSET 0.0 12.0 0.0
      }
    }
  }
  JOINT Leg
  {
    OFFSET 10.0 -5.0 0.0
    JOINT Knee
    {
      OFFSET 0.0 -40.0 0.0
      CHANNELS 1 Zrotation
      End Site
      {
        OFFSET 0.0 -40.0 0.0
      }
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.0333333
"""
N_CH = 6 + 3 + 6 + 0 + 1


def mixed_text(motion: np.ndarray | None = None) -> str:
    if motion is None:
        motion = np.random.default_rng(0).uniform(-90, 90, size=(3, N_CH))
    return MIXED + "\n".join(" ".join(f"{v:.6f}" for v in row) for row in motion) + "\n"


def bad(text: str, tmp_path, name: str = "bad.bvh") -> DataError:
    p = tmp_path / name
    p.write_text(text)
    with pytest.raises(DataError) as ei:
        read_bvh(p)
    e = ei.value
    assert e.file == str(p), e
    assert str(p) in str(e)
    return e


# ----------------------------------------------------------------------------- structure
def test_hierarchy_channels_and_end_sites():
    b = parse_bvh(mixed_text())
    assert b.names == ("Hips", "Spine", "Head Top", "Leg", "Knee")
    assert b.parents == (-1, 0, 1, 0, 3)
    assert b.channels[0] == ("Yrotation", "Xposition", "Yposition", "Zposition", "Xrotation",
                             "Zrotation")
    assert b.channels[3] == ()
    assert b.rotation_orders() == ("YXZ", "XYZ", "ZYX", "", "Z")
    assert b.end_parents == (2, 4)
    np.testing.assert_allclose(b.end_offsets, [[0, 12, 0], [0, -40, 0]])
    assert b.n_frames == 3 and b.n_channels == N_CH
    assert b.fps == pytest.approx(30.0, abs=1e-3)


def test_rotations_compose_intrinsically_in_channel_order():
    rng = np.random.default_rng(1)
    motion = rng.uniform(-170, 170, size=(3, N_CH))
    b = parse_bvh(mixed_text(motion))
    R = b.local_rotations().numpy()
    # Independent reference: scipy, uppercase = intrinsic, angles in channel order.
    hips = motion[:, [0, 4, 5]]
    spine = motion[:, 6:9]
    head = motion[:, [12, 13, 14]]
    np.testing.assert_allclose(R[:, 0], Rotation.from_euler("YXZ", hips, degrees=True).as_matrix(),
                               atol=1e-10)
    np.testing.assert_allclose(R[:, 1], Rotation.from_euler("XYZ", spine, degrees=True).as_matrix(),
                               atol=1e-10)
    np.testing.assert_allclose(R[:, 2], Rotation.from_euler("ZYX", head, degrees=True).as_matrix(),
                               atol=1e-10)
    np.testing.assert_allclose(R[:, 3], np.broadcast_to(np.eye(3), (3, 3, 3)))
    # Zrotation Xrotation Yrotation means R = Rz @ Rx @ Ry (column vectors).
    z, x, y = np.radians([30.0, -50.0, 70.0])
    Rz = np.array([[np.cos(z), -np.sin(z), 0], [np.sin(z), np.cos(z), 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, np.cos(x), -np.sin(x)], [0, np.sin(x), np.cos(x)]])
    Ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    one = parse_bvh("HIERARCHY\nROOT A\n{\nOFFSET 0 0 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n"
                    "End Site\n{\nOFFSET 0 1 0\n}\n}\nMOTION\nFrames: 1\nFrame Time: 0.1\n30 -50 70\n")
    np.testing.assert_allclose(one.local_rotations().numpy()[0, 0], Rz @ Rx @ Ry, atol=1e-12)
    q = one.local_rotations(as_quaternions=True).numpy()[0, 0]
    np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), Rz @ Rx @ Ry, atol=1e-12)


def test_position_channels_replace_offsets_on_any_joint():
    motion = np.zeros((3, N_CH))
    motion[:, 1:4] = [[5, 80, 7], [6, 81, 8], [7, 82, 9]]      # root position
    motion[:, 9:12] = [[0, 25, 0], [1, 26, 0], [2, 27, 0]]     # Head Top position channels
    motion[1, 6] = 90.0                                        # Spine Xrotation, frame 1
    b = parse_bvh(mixed_text(motion))
    P = b.world_positions()
    np.testing.assert_allclose(P[:, 0], motion[:, 1:4])                     # root = channels
    np.testing.assert_allclose(P[0, 1], motion[0, 1:4] + [0, 10, 0])        # offset kept
    np.testing.assert_allclose(P[0, 2], P[0, 1] + [0, 25, 0], atol=1e-9)    # replaced, not added
    # frame 1: Spine rotated +90° about X maps +Y to +Z
    np.testing.assert_allclose(P[1, 2], P[1, 1] + [1, 0, 26], atol=1e-9)
    np.testing.assert_allclose(P[0, 4], P[0, 0] + [10, -45, 0], atol=1e-9)  # channel-less Leg


# ----------------------------------------------------------------------------- round trips
def test_read_write_read_is_exact(tmp_path):
    rng = np.random.default_rng(2)
    motion = rng.uniform(-179, 179, size=(3, N_CH))
    p = tmp_path / "in.bvh"
    p.write_text(mixed_text(motion))
    a = read_bvh(p)
    write_bvh(a, tmp_path / "out.bvh")
    b = read_bvh(tmp_path / "out.bvh")
    assert (b.names, b.parents, b.channels, b.end_parents) == (a.names, a.parents, a.channels,
                                                               a.end_parents)
    assert np.abs(b.motion - a.motion).max() < 1e-4
    assert np.abs(b.offsets - a.offsets).max() < 1e-4
    assert np.abs(b.end_offsets - a.end_offsets).max() < 1e-4
    assert b.frame_time == pytest.approx(a.frame_time, rel=1e-6)
    assert np.abs(b.world_positions() - a.world_positions()).max() < 1e-3
    assert format_bvh(b) == format_bvh(a)  # a second pass changes nothing


def test_bvh_from_motion_round_trip(tmp_path):
    from repro.motion.skeleton import Skeleton, forward_kinematics

    skel = Skeleton(("root", "a", "b", "c"), (-1, 0, 1, 0),
                    np.array([[0, 0, 0], [0, 0.3, 0], [0.2, 0, 0.1], [-0.1, -0.4, 0]]))
    R = Rotation.random(5 * 4, random_state=3).as_matrix().reshape(5, 4, 3, 3)
    root = np.random.default_rng(3).normal(size=(5, 3))
    b = bvh_from_motion(skel, R, root, fps=30.0, order="ZXY")
    write_bvh(b, tmp_path / "gen.bvh")
    back = read_bvh(tmp_path / "gen.bvh")
    assert back.end_parents == (2, 3)
    np.testing.assert_allclose(back.local_rotations().numpy(), R, atol=1e-6)
    expected = forward_kinematics(skel, R, root) * 100.0
    np.testing.assert_allclose(back.world_positions(), expected, atol=1e-4)
    np.testing.assert_allclose(back.world_positions(scale=0.01), expected / 100, atol=1e-6)


def test_deep_but_legal_nesting_reads_and_writes(tmp_path):
    depth = MAX_DEPTH - 2
    text = _chain(depth)
    b = parse_bvh(text, "deep.bvh")
    assert b.n_joints == depth
    assert parse_bvh(format_bvh(b)).parents == b.parents


def _chain(n: int, frames: int = 1) -> str:
    lines = ["HIERARCHY"]
    for i in range(n):
        lines += [("ROOT" if i == 0 else "JOINT") + f" j{i}", "{", "OFFSET 0 1 0",
                  "CHANNELS 1 Zrotation"]
    lines += ["End Site", "{", "OFFSET 0 1 0", "}"] + ["}"] * n
    lines += ["MOTION", f"Frames: {frames}", "Frame Time: 0.0333333"]
    lines += [" ".join(["1.0"] * n)] * frames
    return "\n".join(lines) + "\n"


def test_crlf_and_tabs_are_accepted():
    text = mixed_text().replace("  ", "\t").replace("\n", "\r\n")
    b = parse_bvh(text)
    assert b.n_frames == 3 and b.names[2] == "Head Top"


def test_cr_only_line_ends_read_like_lf():
    """Issue 16 (part): classic-Mac CR-only files used to end in "unexpected 'MOTION' after
    the hierarchy"; they now parse exactly like the LF file."""
    lf = parse_bvh(mixed_text())
    cr = parse_bvh(mixed_text().replace("\n", "\r"))
    assert cr.names == lf.names and cr.n_frames == lf.n_frames
    np.testing.assert_array_equal(cr.motion, lf.motion)


# ----------------------------------------------------------------------------- malformed
def _lines(text: str) -> list[str]:
    return text.split("\n")


def _line_of(text: str, needle: str, nth: int = 0) -> int:
    hits = [i + 1 for i, ln in enumerate(_lines(text)) if needle in ln]
    return hits[nth]


def test_truncated_motion_block(tmp_path):
    text = mixed_text()
    cut = "\n".join(_lines(text)[:-2]) + "\n"  # drop the last frame line
    e = bad(cut, tmp_path)
    assert "truncated MOTION block" in e.problem and "Frames: 3" in e.problem
    assert "only 2" in e.problem
    # cut in the middle of a line: the last frame has too few values
    lines = _lines(text)
    lines[-2] = " ".join(lines[-2].split()[:-2])
    e = bad("\n".join(lines)[:-1], tmp_path)  # no final newline either
    assert f"frame 3 has {N_CH - 2} values" in e.problem and e.line == len(lines) - 1


def test_wrong_channel_count(tmp_path):
    text = mixed_text()
    lines = _lines(text)
    n = len(lines)
    lines[n - 3] = lines[n - 3] + " 1.5"  # frame 2 gets one value too many
    e = bad("\n".join(lines), tmp_path)
    assert e.line == n - 2 and f"has {N_CH + 1} values" in e.problem and f"{N_CH} channels" in e.problem
    # compensating errors (one short line, one long line) keep the total but are still caught
    lines = _lines(text)
    lines[n - 4] = lines[n - 4].rsplit(" ", 1)[0]
    lines[n - 3] = lines[n - 3] + " 1.5"
    e = bad("\n".join(lines), tmp_path)
    assert e.line == n - 3 and "frame 1 has" in e.problem


def test_non_numeric_and_non_finite_values(tmp_path):
    text = mixed_text()
    lines = _lines(text)
    n = len(lines)
    lines[n - 2] = lines[n - 2].replace(" ", " abc ", 1)
    lines[n - 2] = " ".join(lines[n - 2].split()[:N_CH])
    e = bad("\n".join(lines), tmp_path)
    assert e.line == n - 1 and "'abc' is not a number" in e.problem
    lines = _lines(text)
    parts = lines[n - 4].split()
    parts[3] = "nan"
    lines[n - 4] = " ".join(parts)
    e = bad("\n".join(lines), tmp_path)
    assert e.line == n - 3 and "not finite" in e.problem
    e = bad(text.replace("OFFSET 0.0 10.0 0.0", "OFFSET 0.0 ten 0.0"), tmp_path)
    assert e.line == _line_of(text, "OFFSET 0.0 10.0 0.0") and "not a number" in e.problem


def test_unknown_channel_name(tmp_path):
    text = mixed_text().replace("CHANNELS 3 Xrotation Yrotation Zrotation",
                                "CHANNELS 3 Xrotation Wrotation Zrotation")
    e = bad(text, tmp_path)
    assert "unknown channel name 'Wrotation'" in e.problem and "'Spine'" in e.problem
    assert e.line == _line_of(text, "Wrotation")


@pytest.mark.parametrize("old, new, problem, line_of", [
    ("Frames: 3", "Frames: 0", "at least one frame", "Frames:"),
    ("Frames: 3", "Frames: three", "not an integer", None),
    ("Frame Time: 0.0333333", "Frame Time: -1", "positive", "Frame Time:"),
], ids=["zero-frames", "frames-not-a-number", "negative-frame-time"])
def test_bad_header(tmp_path, old, new, problem, line_of):
    text = mixed_text()
    e = bad(text.replace(old, new), tmp_path)
    assert problem in e.problem
    assert line_of is None or e.line == _line_of(text, line_of)


def test_no_motion_block(tmp_path):
    text = mixed_text()
    e = bad(text.split("MOTION")[0], tmp_path)
    assert "no MOTION block" in e.problem and e.line == _line_of(text, "MOTION")


def test_deeply_nested_braces_are_refused_without_recursion(tmp_path):
    e = bad(_chain(MAX_DEPTH + 50), tmp_path)
    assert f"deeper than {MAX_DEPTH}" in e.problem
    # a pathological run of bare braces
    e = bad("HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\n" + "{\n" * 100_000 + "MOTION\n", tmp_path)
    assert "unexpected '{'" in e.problem and e.line == 5


def test_huge_frames_claim_fails_without_allocating(tmp_path):
    text = mixed_text().replace("Frames: 3", "Frames: 2147483647")
    e = bad(text, tmp_path)  # over bvh.MAX_FRAMES: refused from the header alone
    assert "over the 10,000,000 frames" in e.problem and "2147483647" in e.problem
    assert e.line == _line_of(text, "Frames:")
    text = mixed_text().replace("Frames: 3", "Frames: 9999999")
    e = bad(text, tmp_path)  # under it: the lines that follow are counted before reading
    assert "truncated MOTION block" in e.problem and "9999999" in e.problem


def test_more_frames_than_declared(tmp_path):
    lines = _lines(mixed_text())
    lines.insert(-1, lines[-2])
    e = bad("\n".join(lines), tmp_path)
    assert "more frame lines than Frames: 3" in e.problem


def test_hierarchy_errors_name_the_line(tmp_path):
    text = mixed_text()
    e = bad(text.replace("JOINT Leg", "JOINT Spine"), tmp_path)
    assert "used twice" in e.problem and e.line == _line_of(text, "JOINT Leg")
    e = bad(text.replace("CHANNELS 1 Zrotation", "CHANNELS 9 Zrotation"), tmp_path)
    assert "declares 9 channels" in e.problem
    unbalanced = text.replace("MOTION", "}\nMOTION")
    e = bad(unbalanced, tmp_path)
    assert "after the hierarchy" in e.problem
    e = bad(text.replace("ROOT Hips", "ROOT Hips\n{\nOFFSET 0 0 0\n}\nROOT Other", 1), tmp_path)
    assert "after the hierarchy" in e.problem or "more than one ROOT" in e.problem
    e = bad(text.replace("JOINT Knee\n    {", "JOINT Knee"), tmp_path)
    assert "expected '{', found 'OFFSET'" in e.problem and e.line == _line_of(text, "JOINT Knee") + 1
    e = bad("not a bvh file\n", tmp_path)
    assert "not a BVH file" in e.problem and e.line == 1


def test_missing_file_is_a_data_error(tmp_path):
    with pytest.raises(DataError, match="file not found"):
        read_bvh(tmp_path / "nope.bvh")


def test_bvh_validates_its_arrays():
    with pytest.raises(ValueError):
        Bvh(("a",), (-1,), np.zeros((1, 3)), (("Zrotation",),), (), np.zeros((0, 3)), 0.1,
            np.zeros((2, 2)))


# ----------------------------------------------------------------------------- hierarchy memo
def test_a_seen_hierarchy_is_reused_without_sharing_arrays():
    """A HIERARCHY block parsed before is not parsed again; each Bvh still owns its arrays."""
    bvh_mod._HIERARCHIES.clear()
    first = parse_bvh(mixed_text())
    assert len(bvh_mod._HIERARCHIES) == 1
    motion = np.random.default_rng(1).uniform(-90, 90, size=(3, N_CH))
    second = parse_bvh(mixed_text(motion).encode(), "second.bvh")
    assert len(bvh_mod._HIERARCHIES) == 1  # a hit: the same block
    assert (second.names, second.parents, second.channels, second.end_parents) == \
        (first.names, first.parents, first.channels, first.end_parents)
    assert second.offsets.tobytes() == first.offsets.tobytes()
    np.testing.assert_allclose(second.motion, motion, atol=5e-7)
    second.offsets[0, 0] = 123.0  # the caller's copy: neither the memo nor `first` changes
    third = parse_bvh(mixed_text())
    assert third.offsets[0, 0] == first.offsets[0, 0] == 1.0
    assert third.motion.tobytes() == first.motion.tobytes()


def test_errors_after_a_seen_hierarchy_name_the_file_and_line(tmp_path):
    """A MOTION error in a file whose hierarchy was seen before names that file and the same
    line as when its hierarchy is parsed afresh."""
    text = mixed_text()
    lines = _lines(text)
    n = len(lines)
    lines[n - 2] = lines[n - 2].replace(" ", " abc ", 1)
    lines[n - 2] = " ".join(lines[n - 2].split()[:N_CH])
    broken = "\n".join(lines)
    bvh_mod._HIERARCHIES.clear()
    cold = bad(broken, tmp_path, "cold.bvh")
    parse_bvh(text)  # remembers the hierarchy
    warm = bad(broken, tmp_path, "warm.bvh")
    assert warm.file.endswith("warm.bvh")
    assert (warm.line, warm.problem) == (cold.line, cold.problem)
    assert warm.line == n - 1
    assert "'abc' is not a number" in warm.problem


def test_hierarchy_memo_is_bounded(monkeypatch):
    bvh_mod._HIERARCHIES.clear()
    monkeypatch.setattr(bvh_mod, "_HIERARCHIES_MAX", 4)
    for k in range(7):  # seven different blocks (the root OFFSET differs)
        parse_bvh(mixed_text().replace("OFFSET 1.0 90.0 -2.0", f"OFFSET 1.0 90.0 {k}.5"))
    assert len(bvh_mod._HIERARCHIES) == 4
    assert all(b"-2.0" not in key for key in bvh_mod._HIERARCHIES)
    assert any(b"6.5" in key for key in bvh_mod._HIERARCHIES)  # the newest is kept
    bvh_mod._HIERARCHIES.clear()
    monkeypatch.setattr(bvh_mod, "_HIERARCHY_KEY_MAX", 100)  # a block longer than this
    b = parse_bvh(mixed_text())
    assert b.n_joints == 5 and not bvh_mod._HIERARCHIES
