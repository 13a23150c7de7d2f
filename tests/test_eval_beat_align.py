"""BeatAlign: hand-computed scores, known offsets end to end, the shifted-audio control on the real clip."""

from __future__ import annotations

import math

import numpy as np
import pytest
import soundfile as sf

from facecapges import rotations as rot
from facecapges.evaluation import beat_align as ba
from facecapges.evaluation.regions import select
from facecapges.io.bvh import read_bvh
from facecapges.skeleton import motion_to_pose

SR, FPS = 16000, 15.0


def test_score_hand_computed():
    # Δt = 0.3 s and 0 s → (e^{-0.5} + 1) / 2
    assert ba.beat_align_score([1.0, 2.0], [1.3, 2.0, 5.0]) == pytest.approx((math.exp(-0.5) + 1) / 2)
    # one motion beat, nearest is used for both speech beats
    assert ba.beat_align_score([0.0, 0.6], [0.3]) == pytest.approx(math.exp(-0.5))
    assert ba.beat_align_score([1.0], []) == 0.0
    assert math.isnan(ba.beat_align_score([], [1.0]))
    assert ba.beat_align_score([1.0], [1.0], sigma_s=0.1) == 1.0


def _clicks(times_s, dur_s):
    rng = np.random.default_rng(0)
    y = np.zeros(int(dur_s * SR), np.float32)
    for t in times_s:
        s = int(t * SR)
        y[s:s + 1600] = rng.normal(0, 0.5, 1600) * np.hanning(3200)[1600:]  # sharp attack, 0.1 s decay
    return y


def _motion_with_minima(frames, n_frames, n_joints=5):
    """Poses (n, J, 6): joint 0 turns about Z at 0.05 rad/frame except slow steps at ``frames``."""
    step = np.full(n_frames - 1, 0.05)
    step[list(frames)] = 0.01
    angle = np.concatenate([[0.0], np.cumsum(step)])
    R = rot.axis_angle_matrix("Z", angle)
    pose = np.tile(rot.identity_rot6d((1, n_joints)), (n_frames, 1, 1)).astype(np.float64)
    pose[:, 0] = rot.matrix_to_rot6d(R)
    return pose


def test_motion_beats_are_the_speed_minima_at_frame_midpoints():
    frames = [10, 25, 40]
    pose = _motion_with_minima(frames, 60)
    speed = ba.joint_angular_speed(pose, FPS)
    assert speed.shape == (59, 5)
    assert speed[0, 0] == pytest.approx(0.05 * FPS) and speed[10, 0] == pytest.approx(0.01 * FPS)
    np.testing.assert_allclose(ba.motion_beats(pose, FPS), (np.array(frames) + 0.5) / FPS)
    assert len(ba.motion_beats(np.repeat(pose[:1], 30, 0), FPS)) == 0  # still motion has no beat


def test_speech_beats_find_clicks_just_before_them():
    times = [0.5, 1.3, 2.2, 3.0, 4.1]
    sb = ba.speech_beats(_clicks(times, 5.0), SR)
    assert len(sb) == len(times)
    d = np.array(times) - sb
    assert np.all(d >= -0.04) and np.all(d < 0.15)  # backtracked to where the RMS starts rising


@pytest.mark.parametrize("offset_s", [0.0, 0.2, 0.4])
def test_known_offset_gives_known_beat_align(offset_s):
    click_times = [1.0, 2.6, 4.0, 5.5, 7.1]
    audio = _clicks(click_times, 9.0)
    sb = ba.speech_beats(audio, SR)
    # motion minima placed offset_s after each detected speech beat (rounded to the frame grid)
    frames = [int(round((t + offset_s) * FPS - 0.5)) for t in sb]
    pose = _motion_with_minima(frames, int(9.0 * FPS))
    dt = np.abs((np.array(frames) + 0.5) / FPS - sb)
    expect = np.mean(np.exp(-dt ** 2 / (2 * 0.3 ** 2)))
    assert ba.beat_align(pose, audio, SR, FPS) == pytest.approx(expect, abs=1e-9)
    assert expect == pytest.approx(math.exp(-offset_s ** 2 / 0.18), abs=0.03)


def test_control_with_synthetic_sync_has_a_large_gap():
    click_times = np.arange(0.7, 20, 1.37)
    audio = _clicks(click_times, 20.0)
    sb = ba.speech_beats(audio, SR)
    frames = sorted({int(round(t * FPS - 0.5)) for t in sb})
    pose = _motion_with_minima(frames, int(20 * FPS))
    c = ba.beat_align_control(pose, audio, SR, FPS, offsets_s=[2.5, 5.3, 9.1, 13.7, 33.3])
    assert c.matched > 0.95 and c.gap > 0.2
    assert len(c.shifted) == 5 and c.shifted_mean == pytest.approx(np.mean(c.shifted))


def test_control_skips_offsets_that_are_no_shift():
    pose = _motion_with_minima([5, 20], 60)  # 4 s
    audio = _clicks([1.0, 2.0], 4.0)
    c = ba.beat_align_control(pose, audio, SR, FPS, offsets_s=[2.0, 4.0, 8.2, 6.0])
    assert c.offsets_s == [2.0, 6.0]  # 4.0 ≡ 0 and 8.2 ≡ 0.2 s are not shifts


def test_real_clip_matched_vs_shifted(beat_bvh, beat_wav):
    bvh = read_bvh(beat_bvh)
    pose = select(motion_to_pose(bvh.skeleton, bvh.motion)[0], "with_head")
    audio, sr = sf.read(beat_wav, dtype="float32")
    c = ba.beat_align_control(pose, audio, sr, bvh.fps, offsets_s=range(2, 61, 4))
    print(f"real clip BeatAlign matched {c.matched:.4f}, shifted {c.shifted_mean:.4f} ± {c.shifted_sd:.4f}, "
          f"gap {c.gap:.4f} ({c.n_speech_beats} speech, {c.n_motion_beats} motion beats)")
    assert 0.7 < c.matched < 1.0 and np.isfinite(c.shifted_sd)
    assert c.n_speech_beats > 100 and c.n_motion_beats > 50
    assert c.gap > 0  # matched audio beats shifted audio, if only by a little
