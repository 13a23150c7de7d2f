"""Metric modes as the peers compute them, on the real BEAT clip 2_scott_0_1_1."""

from __future__ import annotations

import numpy as np
import pytest
import soundfile as sf

from facecapges.evaluation import baselines as bl
from facecapges.evaluation import beat_align as ba
from facecapges.evaluation import peers
from facecapges.evaluation.l1div import l1div_temporal
from facecapges.evaluation.srgr import srgr
from facecapges.io.bvh import read_bvh
from facecapges.skeleton import UPPER_BODY, motion_to_euler, motion_to_pose, upper_body_indices

FPS = 15.0


@pytest.fixture(scope="module")
def clip(beat_bvh, beat_wav):
    b = read_bvh(beat_bvh)
    audio, sr = sf.read(beat_wav, dtype="float32")
    return b, motion_to_pose(b.skeleton, b.motion)[0], audio, sr


def test_speech_beats_merge_duplicate_onsets_the_peers_keep(clip):
    _, _, audio, sr = clip
    kept = ba.speech_beats(audio, sr, unique=False)
    merged = ba.speech_beats(audio, sr)
    assert len(kept) == 358 and len(merged) == 183
    np.testing.assert_array_equal(np.unique(kept), merged)


def test_beat_script_places_speech_beats_at_0_726_of_their_time(clip):
    _, _, audio, sr = clip
    theirs, true = peers.beat_speech_beats(audio, sr), peers.beat_speech_beats(audio, sr, true_times=True)
    assert len(theirs) == len(true) > 100
    assert len(np.unique(theirs)) < len(theirs)  # duplicates kept
    np.testing.assert_allclose(theirs, true * 16000 / 22050)
    assert abs(16000 / 22050 - 0.726) <= 5e-4


def test_beat_joint_is_what_the_channel_slice_lands_on(clip):
    b, pose, _, _ = clip
    assert UPPER_BODY[12] == peers.BEAT_JOINT == ba.BEAT_JOINT  # channels 36:39 of 141 = joint 12
    _, euler = motion_to_euler(b.skeleton, b.motion)
    flat = euler[:, upper_body_indices(b.skeleton)].reshape(len(euler), -1)  # the 141 channels CaMN sees
    vel = np.linalg.norm(np.diff(flat[:, 36:39], axis=0), axis=-1)
    from scipy.signal import argrelextrema

    expected = argrelextrema(vel, np.less, order=2)[0] / FPS
    np.testing.assert_allclose(peers.beat_motion_beats(pose, FPS), expected)


def test_modes(clip):
    _, pose, audio, sr = clip
    p, a = pose[:300], audio[: 20 * sr]
    single = ba.motion_beats(p, FPS, mode="single", joint=12)
    sets = ba.motion_beats_per_joint(p, FPS)
    np.testing.assert_array_equal(single, sets[12])
    sb = ba.speech_beats(a, sr)
    per_joint = ba.beat_align(p, a, sr, FPS, mode="per_joint")
    assert per_joint == pytest.approx(np.mean([ba.beat_align_score(sb, m) for m in sets]))
    c = ba.beat_align_control(p, a, sr, FPS, offsets_s=(4, 8), mode="per_joint")
    assert c.matched == pytest.approx(per_joint) and c.n_motion_beats == sum(len(m) for m in sets)
    assert ba.beat_align(p, a, sr, FPS, mode="union") >= ba.beat_align(p, a, sr, FPS, mode="mean")
    with pytest.raises(ValueError):
        ba.motion_beats(p, FPS, mode="single")
    with pytest.raises(ValueError):
        ba.motion_beats(p, FPS, mode="pool")


def test_l1div_beat_runs_on_euler_degrees(clip):
    b, pose, _, _ = clip
    ours = l1div_temporal(pose)
    theirs = peers.l1div_beat(pose)
    assert 7 < ours < 13
    assert 400 < theirs < 1100 and theirs > 30 * ours
    _, euler = motion_to_euler(b.skeleton, b.motion)
    flat = euler[:, upper_body_indices(b.skeleton)].reshape(len(euler), -1)
    file_l1 = np.abs(flat - flat.mean(0)).sum(1).mean()  # on the file's own Euler channels
    assert 900 < file_l1 < 1100
    assert peers.l1div_beat(bl.mean_pose_sequence([pose], 50)) == pytest.approx(0.0, abs=1e-6)


def test_srgr_beat_threshold_does_not_flatter_a_frozen_pose(clip):
    _, pose, _, _ = clip
    h = int(0.8 * len(pose))
    real, frozen = pose[h:], bl.mean_pose_sequence([pose[:h]], len(pose) - h)
    assert srgr(real, frozen).value > 0.85  # δ = 0.5 on rot6d
    assert peers.srgr_beat(real, frozen) < 0.6  # BEAT: 4° L1 on Euler
    assert peers.srgr_beat(real, real) == 1.0
    lam = np.full(len(real), 0.165)
    assert peers.srgr_beat(real, real, lam) == pytest.approx(1.0)


def test_emage_alignment(clip):
    b, pose, audio, sr = clip
    p, a = pose[:450], audio[: 30 * sr]
    pos = peers.emage_positions(b.skeleton, p)
    assert pos.shape == (450, len(peers.EMAGE_JOINTS), 3)
    score = peers.beat_align_emage(pos, a, sr, FPS)
    assert 0.3 < score < 1.0
    frozen = np.repeat(pos[:1], len(pos), 0)
    assert peers.beat_align_emage(frozen, a, sr, FPS, reference_speed=peers.emage_joint_speed(pos, FPS).mean(0)) == 0.0
    assert len(peers.emage_speech_beats(audio, sr)) == 358  # raw onsets, no backtracking
