"""Seconds -> frames: the one conversion (repro.data.timebase), its rules and edge cases."""

import math

import numpy as np
import pytest

from repro.data.timebase import (effective_fps, frames_to_seconds, seconds_to_frame,
                                 segment_frames, subsample_step)


def test_time_zero_is_frame_zero_for_every_rule_and_rate():
    for fps in (30, 60, 100, 120, 150, 250, 59.94):
        for rule in ("trunc", "floor", "round", "ceil"):
            assert seconds_to_frame(0.0, fps, rule) == 0


def test_default_rule_is_multiact_int_truncation():
    # MultiAct: int(start_t * mocap_framerate)
    for t, fps in [(1.999, 120), (0.5, 250), (3.834, 120), (2.0, 150), (0.0167, 60)]:
        assert seconds_to_frame(t, fps) == int(t * fps)
    assert seconds_to_frame(1.999, 120) == 239
    assert seconds_to_frame(0.999, 250) == 249


def test_float_artefacts_trunc_versus_tolerant_floor():
    assert 0.29 * 100 < 29  # binary floating point
    assert seconds_to_frame(0.29, 100, "trunc") == 28   # what the reference code does
    assert seconds_to_frame(0.29, 100, "floor") == 29   # tolerant of the artefact
    assert seconds_to_frame(0.2951, 100, "floor") == 29
    assert seconds_to_frame(0.291, 100, "ceil") == 30
    assert seconds_to_frame(0.29, 100, "ceil") == 29


def test_round_is_half_up_not_bankers():
    assert seconds_to_frame(0.5, 1, "round") == 1
    assert seconds_to_frame(2.5, 1, "round") == 3   # Python's round(2.5) would give 2
    assert seconds_to_frame(2.49, 1, "round") == 2


def test_segment_end_at_clip_end_is_clamped():
    # A 3.83 s clip at 120 Hz has 460 frames; BABEL labels often end at 3.834 s.
    n = 460
    assert segment_frames(3.0, 3.834, 120, n_frames=n) == (360, 460)
    assert segment_frames(0.0, 3.83, 120, n_frames=n) == (0, 459)
    assert segment_frames(4.0, 5.0, 120, n_frames=n) == (460, 460)   # empty, past the end
    assert segment_frames(1.0, 2.0, 120) == (120, 240)


def test_abutting_segments_stay_abutting_at_150_and_250_hz():
    rng = np.random.default_rng(0)
    for fps in (150.0, 250.0, 120.0, 59.94):
        for _ in range(200):
            a, b, c = np.sort(rng.uniform(0, 30, size=3))
            s1 = segment_frames(a, b, fps)
            s2 = segment_frames(b, c, fps)
            assert s1[1] == s2[0]
            assert s1[0] <= s1[1] <= s2[1]


def test_150_and_250_hz_sources():
    assert segment_frames(0.1, 0.2, 150) == (15, 30)
    assert segment_frames(0.1, 0.2, 250) == (25, 50)
    assert 0.82 * 150 < 123
    assert seconds_to_frame(0.82, 150) == 122  # 122.99999... truncated, as int() does
    assert seconds_to_frame(0.82, 150, "floor") == 123


def test_multiact_subsampling_step():
    assert subsample_step(120) == 6
    assert subsample_step(60) == 3
    assert subsample_step(100) == 5
    assert subsample_step(150) == 7
    assert subsample_step(250) == 12
    assert subsample_step(59.94) == 3      # round(59.94) = 60
    assert subsample_step(10) == 1         # never below 1
    assert math.isclose(effective_fps(150), 150 / 7)    # 21.43, not 20
    assert math.isclose(effective_fps(250), 250 / 12)   # 20.83
    assert effective_fps(120) == 20.0


def test_inverse_and_refusals():
    assert frames_to_seconds(240, 120) == 2.0
    with pytest.raises(ValueError):
        seconds_to_frame(-0.1, 30)
    with pytest.raises(ValueError):
        seconds_to_frame(float("nan"), 30)
    with pytest.raises(ValueError):
        seconds_to_frame(1.0, 0)
    with pytest.raises(ValueError):
        seconds_to_frame(1.0, 30, "nearest")
    with pytest.raises(ValueError):
        segment_frames(2.0, 1.0, 30)
