"""Comparison strips (repro.render.strips) and their OpenEXR copies (repro.render.exr).

The motions are synthetic (a 19-joint stick skeleton with ``_L``/``_R`` names, walking, jumping
and waving made of sines), so no data files are needed.

Golden images: ``tests/golden/strip_single.png`` (3 single-action panels) and
``tests/golden/strip_multi.png`` (2 panels, 3 action segments, transition windows, top view)
are compared by SSIM (RGB composited over white, ``data_range=255``): the score is the lowest
of the whole image's SSIM and every cell's, and must be at least :data:`SSIM_THRESHOLD`.
After an intended change of the drawing, regenerate them with::

    REPRO_UPDATE_GOLDEN=1 .venv/bin/python -m pytest tests/test_render_strips.py

(the golden tests then rewrite the files instead of comparing) and look at them before
committing.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from skimage.metrics import structural_similarity

from repro.render import (
    Panel,
    Segment,
    key_frame_indices,
    read_exr,
    render_strip,
    save_png,
)
from repro.render.exr import srgb_to_linear, write_exr
from repro.render.strips import LEFT_RGB, RIGHT_RGB, SEGMENT_PALETTE, side_of

SSIM_THRESHOLD = 0.97
GOLDEN = Path(__file__).parent / "golden"
UPDATE = os.environ.get("REPRO_UPDATE_GOLDEN") == "1"

NAMES = ["pelvis", "spine", "chest", "neck", "head",
         "hip_L", "knee_L", "ankle_L", "toe_L", "hip_R", "knee_R", "ankle_R", "toe_R",
         "shoulder_L", "elbow_L", "wrist_L", "shoulder_R", "elbow_R", "wrist_R"]
PARENTS = [-1, 0, 1, 2, 3, 0, 5, 6, 7, 0, 9, 10, 11, 2, 13, 14, 2, 16, 17]
HEAD, TOE_L = 4, 8


def _limb(start, lengths, angles):
    """Points of a chain hanging from ``start``, each link at ``angle`` from straight down
    (positive: towards +z)."""
    pts, p = [], start
    for length, a in zip(lengths, angles):
        p = p + length * np.stack([np.zeros_like(a), -np.cos(a), np.sin(a)], -1)
        pts.append(p)
    return pts


def motion(kind: str = "walk", T: int = 40, phase: float = 0.0, speed: float = 1.2,
           drift: float = 0.0, fps: float = 20.0) -> np.ndarray:
    """(T, 19, 3) synthetic motion along +z: "walk", "jump" (legs still, root up) or "wave"
    (walk, left arm raised and waving); ``drift`` sways the root along x."""
    t = np.arange(T) / fps
    ph = 2 * np.pi * t + phase
    J = np.zeros((T, len(NAMES), 3))
    lift = 0.25 * np.clip(np.sin(np.pi * t / (T / fps)), 0, None) if kind == "jump" else 0.0
    pel = np.stack([drift * np.sin(t), 0.95 + 0.02 * np.cos(2 * ph) + lift, speed * t], -1)
    J[:, 0] = pel
    for j, h in zip(range(1, 5), (0.2, 0.4, 0.55, 0.72)):
        J[:, j] = pel + [0, h, 0]
    swing = 0.4 * np.sin(ph) * (kind != "jump")
    for side, s, leg, arm in ((1, swing, 5, 13), (-1, -swing, 9, 16)):
        hip = pel + [0.1 * side, -0.05, 0]
        bend = 0.3 * (1 - np.cos(ph + (0 if side > 0 else np.pi))) / 2
        knee, ankle = _limb(hip, (0.45, 0.43), (s, s - bend))
        J[:, leg:leg + 4] = np.stack([hip, knee, ankle, ankle + [0, -0.04, 0.12]], 1)
        sh = J[:, 2] + [0.18 * side, 0.05, 0]
        a = -0.35 * np.sin(ph) * side
        if kind == "wave" and side > 0:
            a = np.pi - 0.4 + 0.3 * np.sin(3 * ph)
        J[:, arm:arm + 3] = np.stack([sh, *_limb(sh, (0.28, 0.25), (a, a + 0.3))], 1)
    return J.astype(np.float32)


def single_panels(changed: bool = False) -> list[Panel]:
    return [Panel("Real (test clip)", motion("walk"), tag="walk"),
            Panel("MarioNet", motion("jump" if changed else "walk", phase=0.8, speed=1.0),
                  tag="walk"),
            Panel("Baseline", motion("walk", phase=2.0, speed=0.6), tag="walk")]


SEGMENTS = [Segment(0, 20, "walk"), Segment(20, 40, "jump", transition=(16, 20)),
            Segment(40, 60, "wave", transition=(36, 40))]


def multi_panels() -> list[Panel]:
    def chain(speed, drift):
        parts = [motion("walk", 20, speed=speed, drift=drift),
                 motion("jump", 20, speed=0.4 * speed, drift=drift),
                 motion("wave", 20, speed=speed, drift=drift)]
        for i in (1, 2):              # continue where the previous action ended
            parts[i][..., [0, 2]] += parts[i - 1][-1, 0, [0, 2]] - parts[i][0, 0, [0, 2]]
        return np.concatenate(parts)

    return [Panel("Real (test-set actions)", chain(1.2, 0.4), tag="walk > jump > wave",
                  segments=SEGMENTS, frame_offset=-4),
            Panel("MultiAct", chain(1.0, -0.3), segments=SEGMENTS, frame_offset=-4)]


def render_single(changed: bool = False):
    return render_strip(single_panels(changed), PARENTS, NAMES, title="Table 1 | item 3: walk")


def render_multi():
    return render_strip(multi_panels(), PARENTS, NAMES, top_view=True,
                        title="Table 3 | test sequence 0: walk > jump > wave")


def pixel_of(img, panel, column, point, root_z):
    """(row, col) of a world point in a cell, by the documented projection."""
    x0, y0, x1, _ = img.boxes[(panel, column)]
    ppm = img.pixels_per_metre
    return (int(np.rint(y0 + img.ground_offset - point[1] * ppm)),
            int(np.rint((x0 + x1) / 2 - (point[2] - root_z) * ppm)))


def on_white(rgba: np.ndarray) -> np.ndarray:
    a = rgba[..., 3:4].astype(np.float64) / 255.0
    return rgba[..., :3] * a + 255.0 * (1.0 - a)


def similarity(img, golden_rgba: np.ndarray) -> float:
    """Lowest SSIM of the whole image and of each cell (so one changed row shows)."""
    a, b = on_white(img.rgba), on_white(golden_rgba)
    if a.shape != b.shape:
        return 0.0
    scores = [structural_similarity(a, b, channel_axis=2, data_range=255)]
    for x0, y0, x1, y1 in img.boxes.values():
        scores.append(structural_similarity(a[y0:y1, x0:x1], b[y0:y1, x0:x1], channel_axis=2,
                                            data_range=255))
    return float(min(scores))


def check_golden(img, name: str) -> None:
    path = GOLDEN / name
    if UPDATE:
        path.parent.mkdir(parents=True, exist_ok=True)
        save_png(img, path)
        return
    assert path.exists(), f"{path} missing; create it with REPRO_UPDATE_GOLDEN=1"
    golden = np.asarray(Image.open(path).convert("RGBA"))
    assert golden.shape == img.rgba.shape, \
        f"size {img.rgba.shape} != golden {golden.shape}; REPRO_UPDATE_GOLDEN=1 if intended"
    score = similarity(img, golden)
    assert score >= SSIM_THRESHOLD, f"{name}: SSIM {score:.4f} < {SSIM_THRESHOLD}"


# --- basics ----------------------------------------------------------------------------------

def test_shapes_dtypes_and_background():
    img = render_single()
    H, W = img.depth.shape
    assert img.rgba.shape == (H, W, 4) and img.rgba.dtype == np.uint8
    assert img.depth.dtype == np.float32 and img.joint_index.dtype == np.uint32
    assert img.frames == key_frame_indices(40, 8)
    assert len(img.boxes) == 3 * 8
    assert img.rgba[H - 1, W - 1, 3] == 0 and np.isinf(img.depth[H - 1, W - 1])
    assert img.joint_index[H - 1, W - 1] == 0
    drawn = img.joint_index > 0
    assert drawn.any() and np.all(np.isfinite(img.depth[drawn])) and np.all(img.depth[drawn] > 0)
    assert np.all(img.rgba[..., 3][drawn] > 0)
    assert set(np.unique(img.joint_index)) <= set(range(len(NAMES) + 1))


def test_deterministic_bytes(tmp_path):
    a, b = render_multi(), render_multi()
    for x, y in ((a.rgba, b.rgba), (a.depth, b.depth), (a.joint_index, b.joint_index)):
        assert x.tobytes() == y.tobytes()
    save_png(a, tmp_path / "a.png")
    save_png(b, tmp_path / "b.png")
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "b.png"]


@pytest.mark.parametrize("near", [1, 2])
def test_nearer_joint_wins_all_buffers(near):
    """Two joints at the same (y, z), one at x = +0.3, one at x = -0.3: the nearer (larger x)
    owns the pixel in colour, depth and joint index."""
    J = np.zeros((1, 3, 3), np.float32)
    J[0, 0] = (0, 1.0, 0)
    J[0, 1] = (0.3 if near == 1 else -0.3, 0.5, 0.1)
    J[0, 2] = (-0.3 if near == 1 else 0.3, 0.5, 0.1)
    img = render_strip([Panel("x", J)], [-1, 0, 0], ["root", "a_L", "b_R"])
    r, c = pixel_of(img, 0, 0, J[0, 1], 0.0)
    assert img.joint_index[r, c] == near + 1
    assert img.depth[r, c] == pytest.approx(1.0, abs=1e-5)     # x_cam = 0.3 + 1
    want = LEFT_RGB if near == 1 else RIGHT_RGB
    assert np.abs(img.rgba[r, c, :3].astype(int) - want).max() <= 2


def test_joint_index_and_depth_at_disc_centres():
    panels = single_panels()
    img = render_strip(panels, PARENTS, NAMES)
    x_cam = max(float(p.joints[img.frames, :, 0].max()) for p in panels) + 1.0
    for k, f in enumerate(img.frames[:3]):
        P = panels[1].joints[f]
        for j in (HEAD, TOE_L):
            r, c = pixel_of(img, 1, k, P[j], P[0, 2])
            assert img.joint_index[r, c] == j + 1
            assert img.depth[r, c] == pytest.approx(x_cam - P[j, 0], abs=1e-4)


def test_side_colours_from_names():
    assert [side_of(n) for n in ("UpperLeg_L", "L_knee", "LeftHand", "left_hip", "HandLeft",
                                 "Arm_R", "RightFoot", "right_knee", "Spine", "Head")] \
        == [0, 0, 0, 0, 0, 1, 1, 1, 2, 2]


# --- key frames and errors ---------------------------------------------------------------------

def test_key_frame_indices():
    k = key_frame_indices(100, 8)
    assert len(k) == 8 and k[0] == 0 and k[-1] == 99 and k == sorted(set(k))
    assert key_frame_indices(3, 8) == [0, 1, 2]
    assert key_frame_indices(1, 8) == [0]
    assert key_frame_indices(100, 8, include=[50, 0, 57]) == sorted(set(k) | {50, 57})
    assert key_frame_indices(10, 0, include=[4]) == [4]
    with pytest.raises(ValueError, match="out of range"):
        key_frame_indices(10, 4, include=[10])
    with pytest.raises(ValueError):
        key_frame_indices(0, 4)


def test_default_frames_include_junctions():
    img = render_multi()
    assert {20, 40} <= set(img.frames) and img.frames[0] == 0 and img.frames[-1] == 59
    assert img.frames == key_frame_indices(60, 8, include=[20, 40])


def test_shape_and_frame_errors():
    good = motion()
    with pytest.raises(ValueError, match=r"\(T, J, 3\)"):
        render_strip([Panel("a", good[:, :, :2])], PARENTS, NAMES)
    with pytest.raises(ValueError, match=r"\(T, J, 3\)"):
        render_strip([Panel("a", good[0])], PARENTS, NAMES)
    with pytest.raises(ValueError, match="skeleton has 18"):
        render_strip([Panel("a", good)], PARENTS[:-1], NAMES[:-1])
    with pytest.raises(ValueError, match="names"):
        render_strip([Panel("a", good)], PARENTS, NAMES[:-1])
    with pytest.raises(ValueError, match="frame 40 is out of range"):
        render_strip([Panel("a", good)], PARENTS, NAMES, frames=[0, 40])
    with pytest.raises(ValueError, match="out of range"):
        render_strip([Panel("a", good), Panel("b", good[:10])], PARENTS, NAMES, frames=[12])
    bad = good.copy()
    bad[3, 2, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        render_strip([Panel("a", bad)], PARENTS, NAMES)


# --- multi-action marks ------------------------------------------------------------------------

def _close(px, rgb, tol=3):
    return np.all(np.abs(px[..., :3].astype(int) - rgb) <= tol, axis=-1) & (px[..., 3] == 255)


def test_multi_action_marks():
    img = render_multi()
    for panel in (0, 1):
        for k, f in enumerate(img.frames):
            x0, y0, x1, y1 = img.boxes[(panel, k)]
            seg = next(i for i, s in enumerate(SEGMENTS) if s.start <= f < s.stop)
            bar = img.rgba[y1 + 3:y1 + 7, x0 + 4:x1 - 4]
            assert _close(bar, SEGMENT_PALETTE[seg]).all(), (panel, k, f)
            left_edge = img.rgba[y0 + 30:y1 - 30, x0:x0 + 2]
            junction = f in (20, 40)
            assert bool(_close(left_edge, (20, 20, 20)).all()) == junction, (k, f)
            win = [i for i, s in enumerate(SEGMENTS) if s.transition
                   and s.transition[0] <= f < s.transition[1]]
            top = img.rgba[y0, x0 + 10:x1 - 10]
            if win:
                assert _close(top, SEGMENT_PALETTE[win[0]]).sum() >= 10, (k, f)
            else:
                assert not _close(top, SEGMENT_PALETTE[1]).any()
    # top view: a key-frame dot in each segment colour in the last column
    x0, y0, x1, y1 = img.boxes[(0, len(img.frames))]
    tv = img.rgba[y0:y1, x0:x1]
    for rgb in SEGMENT_PALETTE[:3]:
        assert _close(tv, rgb, tol=2).any()


# --- OpenEXR ----------------------------------------------------------------------------------

def test_exr_round_trip(tmp_path):
    img = render_multi()
    path = write_exr(img, tmp_path / "strip.exr")
    write_exr(render_multi(), tmp_path / "again.exr")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["again.exr", "strip.exr"]
    assert path.read_bytes() == (tmp_path / "again.exr").read_bytes()
    ch = read_exr(path)
    assert set(ch) == {"R", "G", "B", "A", "Z", "JointIndex"}
    for c in "RGBA":
        assert ch[c].dtype == np.float16 and ch[c].shape == img.depth.shape
    assert ch["Z"].dtype == np.float32 and ch["JointIndex"].dtype == np.uint32
    np.testing.assert_array_equal(ch["JointIndex"], img.joint_index)
    np.testing.assert_array_equal(ch["Z"], img.depth)
    H, W = img.depth.shape
    assert ch["A"][H - 1, W - 1] == 0 and ch["JointIndex"][H - 1, W - 1] == 0
    assert np.isinf(ch["Z"][H - 1, W - 1])
    P = multi_panels()[0].joints[img.frames[2]]
    r, c = pixel_of(img, 0, 2, P[HEAD], P[0, 2])
    assert ch["JointIndex"][r, c] == HEAD + 1
    assert ch["Z"][r, c] == pytest.approx(img.depth[r, c]) and 0 < ch["Z"][r, c] < 10
    save_png(img, tmp_path / "strip.png")
    png = np.asarray(Image.open(tmp_path / "strip.png")).astype(np.float64) / 255.0
    premult = srgb_to_linear(png[..., :3]) * png[..., 3:4]
    exr_rgb = np.stack([ch[c].astype(np.float64) for c in "RGB"], -1)
    np.testing.assert_allclose(exr_rgb, premult, atol=1e-3)
    np.testing.assert_allclose(ch["A"].astype(np.float64), png[..., 3], atol=1e-3)


# --- golden images -----------------------------------------------------------------------------

def test_golden_single_action():
    check_golden(render_single(), "strip_single.png")


def test_golden_multi_action():
    check_golden(render_multi(), "strip_multi.png")


@pytest.mark.skipif(UPDATE, reason="golden files are being rewritten")
def test_changed_drawing_fails_golden():
    golden = np.asarray(Image.open(GOLDEN / "strip_single.png").convert("RGBA"))
    img = render_single(changed=True)
    assert img.rgba.shape == golden.shape
    assert similarity(img, golden) < SSIM_THRESHOLD
