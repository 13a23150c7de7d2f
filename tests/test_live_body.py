"""``live --body``: the causal solve, the arms' inertialized hand-over (no pop), the option end to end on a
rendered video of the avatar driven by his real motion, and its bad inputs (issue 32)."""

from __future__ import annotations

import numpy as np
import pytest

from facecapges import rotations as rot
from facecapges.capture.body_solve import StreamSolver, solve
from facecapges.evaluation import realism as rz
from facecapges.evaluation.body_capture import compare
from facecapges.runtime.body import HALFLIFE_S, ArmHandover, arm_joints
from facecapges.skeleton import UPPER_BODY, motion_to_pose, pose_to_motion
from runtime_helpers import cli
from test_capture_body import _synthetic_landmarks


def _stream(skel, lm, upto=None):
    s = StreamSolver(skel, lm.fps)
    n = lm.n_frames if upto is None else upto
    out = [s.step(lm.pose[t], lm.visibility[t], list(lm.hands[t]), lm.hand_score[t]) for t in range(n)]
    return np.stack([q for q, _ in out]), np.stack([c for _, c in out])


def test_stream_solver_is_causal_and_close_to_the_offline_solve(beat_take):
    skel, motion = beat_take.skeleton, beat_take.motion[:150]
    lm = _synthetic_landmarks(skel, motion)
    q, conf = _stream(skel, lm)
    assert conf.min() == 1.0
    pose = rot.matrix_to_rot6d(rot.quaternion_to_matrix(q)).astype(np.float32)
    live = compare(skel, motion, pose_to_motion(skel, pose))
    offline = compare(skel, motion, pose_to_motion(skel, solve(skel, lm).pose))
    # the One-Euro filter lags a little where the zero-phase Gaussian does not: a few degrees more (with the
    # torso's lean prior: live 7.2°, offline 3.7°; before it 8.8° and 6.9°, so the absolute bound is tightened)
    assert live["median_deg"] < offline["median_deg"] + 3.5 and live["median_deg"] < 8, (live, offline)
    # causal: what comes after frame 60 does not change frames 0..59
    lm2 = _synthetic_landmarks(skel, motion)
    lm2.pose[60:] = lm2.pose[60:][::-1]
    lm2.hands[60:] = np.nan
    lm2.hand_score[60:] = 0
    q2, _ = _stream(skel, lm2)
    assert np.allclose(q2[:60], q[:60]) and not np.allclose(q2[60:70], q[60:70])


def _his_pose(beat_take):
    return motion_to_pose(beat_take.skeleton, beat_take.motion)[0]  # 15 fps


def test_arms_hand_over_both_ways_inertialized_without_a_pop(beat_take):
    """The engine plays one stretch of his motion, the 'body' another; the right arm is seen, lost, seen again."""
    pose = _his_pose(beat_take)
    engine, body = pose[:150], pose[300:450]
    threshold = rz.transition_threshold([pose[: int(0.8 * len(pose))]], 15.0)  # his training frames
    seen_r = np.r_[np.ones(50), np.zeros(50), np.ones(50)].astype(bool)
    to_q = rot.rot6d_to_quaternion
    h = ArmHandover(15.0)
    out = np.stack(
        [
            h.step(to_q(engine[t].astype(np.float64)), to_q(body[t].astype(np.float64)), [seen_r[t], True], False)
            for t in range(150)
        ]
    )
    out6 = rot.matrix_to_rot6d(rot.quaternion_to_matrix(out)).astype(np.float32)
    R, L = arm_joints("Right"), arm_joints("Left")
    assert [e[1:] for e in h.events] == [("Right", "body"), ("Left", "body"), ("Right", "gestures"), ("Right", "body")]
    # away from the hand-overs each arm is its source's; the spine and head are always the engine's
    others = np.setdiff1d(np.arange(len(UPPER_BODY)), np.r_[R, L])
    assert np.allclose(out6[:, others], engine[:, others], atol=1e-5)
    settle = int(6 * HALFLIFE_S * 15)
    ang = lambda a, b: np.degrees(rot.geodesic_angle(rot.rot6d_to_matrix(a), rot.rot6d_to_matrix(b)))  # noqa: E731
    assert ang(out6[40, R], body[40, R]).max() < 2 and ang(out6[50 + settle, R], engine[50 + settle, R]).max() < 2
    assert ang(out6[149, R], body[149, R]).max() < 2 and ang(out6[149, L], body[149, L]).max() < 2
    # no pop at the hand-overs: the whole-body acceleration stays below his real motion's 99.9th percentile
    acc = rz.joint_acceleration(out6, 15.0)
    for frame, _, _ in h.events:
        assert acc[max(frame - 1, 1) : frame + 8].max() < threshold, (frame, acc[frame - 1 : frame + 8], threshold)
    # … where switching without the blend would pop (so the check can fail)
    hard = engine.copy()
    hard[:, L] = body[:, L]
    for t in np.flatnonzero(seen_r):
        hard[t, R] = body[t, R]
    assert rz.joint_acceleration(hard, 15.0)[[49, 50, 51, 99, 100, 101]].max() > threshold
    # --gestures: the engine's arms exactly
    g = ArmHandover(15.0)
    eq = [
        g.step(to_q(engine[t].astype(np.float64)), to_q(body[t].astype(np.float64)), [True, True], True)
        for t in range(20)
    ]
    assert np.allclose(np.abs((np.stack(eq) * to_q(engine[:20].astype(np.float64))).sum(-1)), 1.0, atol=1e-6)
    assert not g.events


def test_body_option_errors(tmp_path, beat_wav):
    r = cli("live", "--gestures", "--video", str(tmp_path / "x.mp4"), "--record", str(tmp_path / "r"))
    assert r.returncode == 2 and "--gestures" in r.stderr and "Traceback" not in r.stderr
    r = cli("live", "--body", "--livelink", "0", "--audio", str(beat_wav), "--record", str(tmp_path / "r"))
    assert r.returncode == 2 and "--body needs a camera or a video" in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def _models_or_skip():
    from facecapges.capture.body_models import HAND_TASK, POSE_TASK, model_path
    from facecapges.errors import UserError

    try:
        model_path(POSE_TASK), model_path(HAND_TASK)
    except UserError as exc:
        pytest.skip(str(exc))


@pytest.mark.slow
def test_live_body_with_no_body_in_view_warns_and_runs(tmp_path, beat_wav):
    """A video in which no person is ever seen: live runs to the end on the engine's gestures and says so."""
    import imageio_ffmpeg

    _models_or_skip()
    video = tmp_path / "wall.mp4"
    w = imageio_ffmpeg.write_frames(str(video), (320, 240), fps=15, codec="libx264", macro_block_size=1)
    w.send(None)
    rng = np.random.default_rng(0)
    for _ in range(45):
        w.send(np.full((240, 320, 3), 120, np.uint8) + rng.integers(0, 8, (240, 320, 3), dtype=np.uint8))
    w.close()
    rec = tmp_path / "rec"
    r = cli(
        "live", "--video", str(video), "--audio", str(beat_wav), "--body", "--record", str(rec), "--max-seconds", "3"
    )
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    assert "no person's body was seen in any of the" in r.stderr
    import json

    rep = json.loads((rec / "report.json").read_text())
    assert rep["body"]["person_found"] == 0 and rep["body"]["handovers"] == {"Right": 0, "Left": 0}
    assert rep["frames"] == 45


@pytest.mark.slow
def test_live_body_follows_his_real_motion_and_hands_over_when_the_hands_leave(beat_bvh, beat_wav, tmp_path):
    """The held-out end of 1_1 rendered with his speech, fed to ``live --body``; then the same video with the
    right arm and both hands leaving the frame (docs/capture-body.md has the figures)."""
    from facecapges.evaluation.live_body import measure_live

    _models_or_skip()
    def in_process(*args):  # `live` in this process (cli): what the subprocess ran, without its start-up
        r = cli(*args)
        return r.returncode, r.stderr

    m = measure_live(beat_bvh, beat_wav, tmp_path, runner=in_process)
    plain, leave = m["plain"], m["leave"]
    # capture-body (offline, zero-phase) on this video: 10.8° / 23.5°; live (causal) measured 11.7° / 27.2° (before
    # the torso's lean prior and the landmarker's own upper-arm depth: 14.2° / 34.4°, which fails here)
    assert plain["all_frames"]["median_deg"] < 13.5 and plain["all_frames"]["p90_deg"] < 31, plain
    assert plain["on_body_share"] > 0.8, plain  # settled on the body after the start-up hand-over's 1.5 s
    assert 0.7 < plain["all_frames"]["wrist_spread_ratio"] < 1.3, plain
    # the hands leave: the right arm goes to the gestures and back, then both; no pop at any hand-over
    sides_to = {(h["side"], h["to"]) for h in leave["handover"]["handovers"]}
    assert {("Right", "gestures"), ("Right", "body"), ("Left", "gestures"), ("Left", "body")} <= sides_to, leave
    assert leave["handover"]["pops_at_handovers"] == 0, leave["handover"]
    assert plain["handover"]["pops_at_handovers"] == 0, plain["handover"]
    assert leave["both_arms_on_body"]["median_deg"] < 15, leave  # measured 8.8° (before: 11.2°)
