"""Realism controls of issue #25 §3 (transitions, repetition, silence, real-vs-generated) on real BEAT motion."""

from __future__ import annotations

import numpy as np
import pytest

from facecapges import rotations as rot
from facecapges.evaluation import realism as R
from tolerances import assert_rotations_close

FPS = 15


@pytest.fixture(scope="module")
def take(beat_take):
    """The real take 2_scott_0_1_1: rot6d poses (957, 47, 6) and its skeleton."""
    from facecapges.skeleton import motion_to_pose

    b = beat_take
    return motion_to_pose(b.skeleton, b.motion)[0].astype(np.float64), b.skeleton


def test_transitions_real_take_and_hard_cuts(take):
    pose, _ = take
    train = pose[:766]
    own = R.transitions(train, train, FPS)
    assert own.count <= 2 and own.threshold > 0  # 0.1 % of its own frames at most
    clean = R.transitions(pose[766:], train, FPS)
    assert clean.per_minute <= 5.0
    starts = [700, 50, 400, 200, 600, 120]
    cuts = np.concatenate([train[s : s + 20] for s in starts])  # a hard cut every 20 frames
    res = R.transitions(cuts, train, FPS)
    near = {f // 20 for f in res.frames if f % 20 in (19, 0)}  # frames around each of the 5 cuts
    assert len(near) >= 4 and res.count > clean.count
    assert res.per_minute == pytest.approx(res.count / (len(cuts) / FPS / 60))
    assert set(res.top_joints) & {"RightArm", "RightForeArm", "RightHand", "LeftArm", "LeftForeArm", "LeftHand"}
    assert R.joint_acceleration(pose[:10], FPS, per_joint=True).shape == (10, 47)


def test_repetition_of_a_crude_replay(take):
    pose, _ = take
    db = pose[:766]
    replay = np.concatenate([db[100:250], db[400:500], db[100:250]])
    res = R.repetition(replay, db, FPS)
    assert res.copied_share == 1.0 and res.longest_copy_s == pytest.approx(150 / FPS)
    assert res.database_share_used == pytest.approx(250 / 766)
    assert res.returns == 1  # the second play of frames 100–249 starts 6.7 s after the first ended
    assert res.returns_per_minute == pytest.approx(1 / (400 / FPS / 60))
    far = np.concatenate([db[100:250], db[400:720], db[100:250]])  # 21 s of other motion in between
    assert R.repetition(far, db, FPS).returns == 0
    rng = np.random.default_rng(0)
    blended = rot.normalize_rot6d(replay + rng.normal(0, 0.2 * res.tolerance / np.sqrt(6), replay.shape))
    assert R.repetition(blended, db, FPS).longest_copy_s > 5.0  # near a clip still counts as copied
    held_out = R.repetition(pose[766:], db, FPS)  # the real motion of later seconds is no copy
    assert held_out.copied_share < 0.05 and held_out.longest_copy_s < 0.5 and held_out.returns == 0
    two = R.repetition(replay, [db[:300], db[300:766]], FPS)  # a database of two clips: same runs
    assert two.longest_copy_s == pytest.approx(150 / FPS) and two.database_frames == 766


def test_silence_ratio_on_synthetic_speech():
    sr, n = 16000, 300  # 20 s: speech 0–10 s, a pause 10–20 s
    rng = np.random.default_rng(0)
    audio = np.zeros(n * sr // FPS, np.float32)
    audio[: 10 * sr] = 0.1 * rng.standard_normal(10 * sr)
    audio[10 * sr :] = 1e-4 * rng.standard_normal(len(audio) - 10 * sr)
    speech = R.speech_frames(audio, sr, FPS, n)
    assert speech[:150].all() and not speech[150 + round(0.3 * FPS) :].any()  # 0.3 s hangover
    t = np.arange(n) / FPS
    amp = np.where(t < 10, 10.0, 2.0)
    wrists = np.stack([np.stack([amp * np.sin(2 * t), np.zeros(n), np.zeros(n)], -1)] * 2, 1)  # (T, 2, 3)
    res = R.silence_ratio(wrists, audio, sr, FPS)
    assert res.ratio == pytest.approx(0.2, abs=0.03) and res.pause_s == pytest.approx((150 - round(0.3 * FPS)) / FPS)
    frozen = R.silence_ratio(np.where(t[:, None, None] < 10, wrists, wrists[150]), audio, sr, FPS)
    assert frozen.ratio < 1e-9
    still = R.silence_ratio(np.repeat(wrists[:1], n, 0), audio, sr, FPS)  # a motion that never moves
    assert np.isnan(still.ratio) and still.speech_s > 0


def test_silence_ratio_on_the_real_take(take, beat_audio):

    pose, skel = take
    res = R.silence_ratio(pose, beat_audio, 16000, FPS, skel)
    assert res.pause_s > 1.0 and res.speech_s > 30.0 and 0.2 < res.ratio < 1.5
    with pytest.raises(ValueError, match="skeleton"):
        R.silence_ratio(pose, beat_audio, 16000, FPS)


def test_real_vs_generated_separates_a_jittered_mean_pose(take):
    pose, skel = take
    rng = np.random.default_rng(0)
    fake = rot.normalize_rot6d(pose.mean(0) + rng.normal(0, 0.02, pose.shape))
    res = R.real_vs_generated(pose, fake, FPS, skel, seed=0)
    assert res.accuracy >= 0.95 and len(res.fold_accuracy) == 5 and res.n_windows > 20


def test_real_vs_generated_is_chance_on_interleavings_of_one_take(take):
    pose, skel = take
    chunks = [pose[i : i + 45] for i in range(0, len(pose) - 44, 45)]  # 3-s chunks
    accs = []
    for seed in range(3):
        side = np.random.default_rng(seed).permutation(len(chunks)) % 2
        a = [c for c, s in zip(chunks, side) if s == 0]
        b = [c for c, s in zip(chunks, side) if s == 1]
        accs.append(R.real_vs_real_control(a, b, FPS, skel, seed=seed).accuracy)
    assert 0.3 < np.mean(accs) < 0.7, accs


def test_control_on_the_two_halves_of_the_take(take):
    pose, skel = take
    half = len(pose) // 2
    res = R.real_vs_real_control(pose[:half], pose[half:], FPS, skel)
    assert 0.4 < res.accuracy < 0.9 and np.isfinite(res.sd)  # his halves differ a little (arms higher in one)
    assert np.isnan(R.real_vs_generated(pose[:40], pose[40:80], FPS, skel).accuracy)  # too short for 2 folds


def test_eval_generation_runs_through_the_checkpoints_own_stream(take, beat_audio):
    """``generate_poses`` from a history uses ``ckpt.streaming()`` + ``reset(initial_pose)``: the same poses
    as the network's streaming generator built on that window by hand (the path it replaced)."""
    from facecapges import timing
    from facecapges.engine.generate import generate_poses
    from facecapges.engine.inputs import FrameInputs
    from facecapges.evaluation.run import engine_database, history_frames
    from facecapges.network.streaming import NetworkStream
    from facecapges.styles import load_style

    pose, _ = take
    ckpt = load_style(style="beat2-scott-demo")
    n = 30
    audio = beat_audio[: timing.frame_sample_bounds(n, FPS)[0]]
    head = np.broadcast_to(rot.identity_rot6d(), (n, 6)).copy()
    inputs = FrameInputs(
        audio=timing.frame_audio(audio, n, FPS), face=np.zeros((n, 52), np.float32), head=head, fps=FPS, notes=[]
    )
    window = pose[200 : 200 + history_frames(ckpt)].astype(np.float32)
    got, _ = generate_poses(ckpt, inputs, progress=False, history=window)
    by_hand = NetworkStream(ckpt.model, window)
    want = np.stack([by_hand.step(inputs.audio[t], inputs.face[t], inputs.head[t]) for t in range(n)])
    # the same kernel, but generate_poses sets its own thread count: float32 rounding, 0.01° (tolerances.py)
    assert_rotations_close(got, want, what="generate_poses against the generator by hand")
    cold, _ = generate_poses(ckpt, inputs, progress=False)
    np.testing.assert_array_equal(cold, generate_poses(ckpt, inputs, False, ckpt.neutral_window)[0])  # same path
    assert np.abs(cold - got).max() > 1e-3  # the start window is really used
    assert ckpt.display_name == "FaceCapGes (beat2-scott-demo)" and ckpt.database_poses() is None
    db, source = engine_database(ckpt, [pose[:766]])
    assert db is not None and len(db[0]) == 766 and "training frames" in source
    assert engine_database(ckpt, [])[0] is None


def test_realism_section_and_its_table(take, beat_audio):
    from facecapges.evaluation.report import realism_lines

    pose, skel = take
    audio = beat_audio
    real, train = pose[766:], pose[:766]
    s0 = 766 * 16000 // FPS
    methods = {"ground truth": [real], "frozen": [np.repeat(real[:1], len(real), 0)], "replay": [train[:191]]}
    kw = dict(sr=16000, fps=FPS, skeleton=skel, real_heldout=[real], reference=[train], database=[train])
    sec = R.realism_section(methods, [audio[s0:]], **kw, database_source="training", no_classifier=["ground truth"])
    rows = sec["methods"]
    assert rows["replay"]["longest_copy_s"] == pytest.approx(191 / FPS) and rows["frozen"]["classifier"] >= 0.9
    assert sec["control"]["classifier"] is None  # no other real motion given: no control
    md = "\n".join(realism_lines({"realism": sec, "regions": {}, "synchrony": None}))
    assert "| — (no pause ≥ 0.5 s) |" in md  # the held-out 12.7 s have no pause that long
    assert "no control" in md and "| transitions a minute | ≤ 1 | 0.00 ✓ | 0.00 ✓ |" in md
    sec = R.realism_section(methods, [audio[s0:]], **kw, database_source="training", control_reference=[train])
    assert 0.0 <= sec["control"]["classifier"] <= 1.0 and sec["control"]["classifier_windows"] > 0
    assert "its control (held-out real vs" in "\n".join(realism_lines({"realism": sec}))


def test_classifier_averages_balanced_subsamples(take):
    """With more windows on one side, one balanced subsample is luck: the figure averages DRAWS of them."""
    pose, skel = take
    short, long_ = pose[:240], pose[240:]  # 16 s against 48 s: the longer side is subsampled in every block
    one = [R.real_vs_real_control(short, long_, FPS, skel, seed=s, draws=1).accuracy for s in range(4)]
    many = [R.real_vs_real_control(short, long_, FPS, skel, seed=s) for s in range(4)]
    assert all(m.draws == R.DRAWS and m.draw_sd > 0 for m in many)
    assert np.ptp([m.accuracy for m in many]) < np.ptp(one)
    equal = R.real_vs_real_control(pose[:300], pose[300:600], FPS, skel)  # as many windows a block: one draw
    assert equal.draws == 1 and equal.draw_sd == 0.0
