"""Synchrony controls on the real takes: energy–speed r and z, wrist jerk/spread ratios, suite section."""

from __future__ import annotations

import math

import numpy as np
import pytest
import soundfile as sf

from conftest import shared_file
from facecapges.evaluation import synchrony as sy
from facecapges.io.bvh import read_bvh
from facecapges.skeleton import joint_positions, motion_to_pose


def _take(bvh_rel: str, wav_rel: str):
    b = read_bvh(shared_file(bvh_rel))
    audio, sr = sf.read(shared_file(wav_rel), dtype="float32")
    wrists = joint_positions(b.skeleton, b.motion)[:, [b.skeleton.index(n) for n in sy.WRISTS]]
    return b, wrists, audio, sr


@pytest.fixture(scope="module")
def zeggs():
    return _take("data/zeggs/067_Speech_2_x_1_0.bvh", "data/zeggs/067_Speech_2_x_1_0.wav")


@pytest.fixture(scope="module")
def beat():
    return _take("data/beat/2_scott_0_1_1.bvh", "data/beat/2_scott_0_1_1.wav")


def test_zeggs_real_motion_follows_loudness(zeggs):
    b, wrists, audio, sr = zeggs
    assert b.fps == pytest.approx(30.0)
    c = sy.energy_speed_control(wrists, audio, sr, b.fps)
    assert 0.6 < c.r < 0.75
    assert c.z > 4.0
    assert abs(c.shifted_mean) < 0.1 and len(c.offsets_s) == 30


def test_beat_speaker2_is_not_loudness_driven(beat):
    b, wrists, audio, sr = beat
    c = sy.energy_speed_control(wrists, audio, sr, b.fps)
    assert -0.2 < c.r < 0.0
    assert abs(c.z) < 2.0


def test_shifting_the_motion_destroys_the_zeggs_coupling(zeggs):
    b, wrists, audio, sr = zeggs
    moved = np.roll(wrists, int(17 * b.fps), axis=0)  # the same motion 17 s later: not this speech
    c = sy.energy_speed_control(moved, audio, sr, b.fps)
    assert abs(c.z) < 2.0 and c.r < 0.3


def test_wrist_positions_of_poses_match_bvh_fk(beat):
    b, wrists, _, _ = beat
    pose = motion_to_pose(b.skeleton, b.motion)[0]
    np.testing.assert_allclose(sy.wrist_positions(b.skeleton, pose), wrists, atol=1e-3)  # cm; float32 rot6d


def test_jerk_and_spread_ratios(beat):
    b, wrists, _, _ = beat
    real = sy.motion_stats(wrists, b.fps)
    assert real.jerk > 0 and real.spread > 1.0  # cm
    rng = np.random.default_rng(0)
    jittery = wrists + rng.normal(0, 0.5, wrists.shape)  # 5 mm of frame-to-frame noise
    assert sy.ratio(sy.wrist_jerk(jittery, b.fps), real.jerk) > 1.3
    calm = wrists.mean(0) + 0.5 * (wrists - wrists.mean(0))
    assert sy.ratio(sy.wrist_spread(calm), real.spread) == pytest.approx(0.5)
    assert sy.ratio(sy.wrist_jerk(sy.smooth(wrists, b.fps, 0.5), b.fps), real.jerk) < 0.5
    assert math.isnan(sy.ratio(1.0, 0.0))


def test_still_motion_has_no_correlation(beat):
    b, wrists, audio, sr = beat
    still = np.repeat(wrists[:1], len(wrists), 0)
    c = sy.energy_speed_control(still, audio, sr, b.fps)
    assert math.isnan(c.r) and math.isnan(c.z)
    assert sy.wrist_spread(still) == pytest.approx(0.0, abs=1e-9)


def test_energy_envelope_owns_frame_samples():
    sr, fps = 16000, 15.0
    a = np.zeros(sr * 2, np.float32)
    a[1066:2133] = 0.5  # exactly frame 1's samples: floor(16000/15) … floor(2·16000/15) − 1
    e = sy.energy_envelope(a, sr, fps)
    assert len(e) == 30
    assert e[1] == pytest.approx(0.5) and e[0] == 0.0 and e[2] == 0.0
    assert len(sy.energy_envelope(a, sr, fps, 40)) == 40


def test_suite_reports_synchrony_for_every_row(beat):
    from facecapges.evaluation import baselines as bl
    from facecapges.evaluation.suite import evaluate_paired

    b, _, audio, sr = beat
    pose = motion_to_pose(b.skeleton, b.motion)[0]
    real = pose[-300:]
    a = audio[int((len(pose) - 300) / b.fps * sr):]
    methods = {"ground truth": real, "mean pose": bl.mean_pose_sequence([pose[:-300]], 300),
               "shifted real": np.roll(real, 100, axis=0)}
    res = evaluate_paired(real, methods, a, sr, b.fps, offsets_s=(4, 8, 12), progress=False, skeleton=b.skeleton)
    sync = res["synchrony"]["methods"]
    assert sync["ground truth"]["jerk_ratio"] == pytest.approx(1.0)
    assert sync["ground truth"]["spread_ratio"] == pytest.approx(1.0)
    assert sync["mean pose"]["ES_r"] is None and sync["mean pose"]["spread_ratio"] == pytest.approx(0.0, abs=1e-6)
    assert sync["shifted real"]["spread_ratio"] == pytest.approx(1.0, rel=0.2)
    gt = res["regions"]["with_head"]["methods"]["ground truth"]
    assert gt["BA_gap_sd"] == pytest.approx(gt["BA_gap"] / gt["BA_shifted_sd"])
    peer = res["peers"]["methods"]
    assert peer["ground truth"]["SRGR_BEAT"] == 1.0 and peer["mean pose"]["L1DIV_BEAT"] == pytest.approx(0, abs=1e-6)
    assert peer["ground truth"]["L1DIV_BEAT"] > 100 and 0 < peer["ground truth"]["BA_EMAGE"] <= 1
    from facecapges.evaluation.report import markdown_table

    md = markdown_table(res)
    assert "energy–speed r" in md and "wrist jerk × real" in md and "BA (BEAT script)" in md


def test_stouffer_combines_independent_takes_as_one_test():
    from facecapges.evaluation.synchrony import stouffer_z

    assert abs(stouffer_z([2.0, 2.0, 2.0]) - 2.0 * 3**0.5) < 1e-12  # three takes at z 2: 3.46
    assert abs(stouffer_z([1.5, float("nan")]) - 1.5) < 1e-12  # a take without a figure is left out
    rng = np.random.default_rng(0)  # under the null (independent N(0,1) per take) it stays N(0,1)
    combined = [stouffer_z(rng.normal(size=5)) for _ in range(4000)]
    assert abs(np.std(combined) - 1.0) < 0.05 and abs(np.mean(combined)) < 0.05
