"""``capture-body``: the solver on landmarks made from known BEAT motion, the models, the CLI on a
rendered video of the avatar driven by his real motion (truth known), and its error paths (issue 32)."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from facecapges.capture.body_solve import MP_TO_BVH, BodyLandmarks, solve
from facecapges.commands.cli import app
from facecapges.errors import UserError
from facecapges.evaluation.body_capture import compare
from facecapges.skeleton import joint_positions, pose_to_motion

runner = CliRunner()

# MediaPipe hand landmark k ← BEAT joint (the wrist, then each finger root to tip)
HAND_JOINTS = ["Hand"] + [f"Hand{f}{k}" for f in ("Thumb", "Index", "Middle", "Ring", "Pinky") for k in (1, 2, 3, 4)]


def _synthetic_landmarks(skel, motion) -> BodyLandmarks:
    """What a perfect landmarker would report for this motion (camera axes, metres)."""
    P = joint_positions(skel, motion) / 100.0  # cm → m
    T = len(P)

    def at(name):
        return P[:, skel.index(name)]

    pose = np.zeros((T, 33, 3))
    for side, (sh, el, wr, pk, ix, hp) in {
        "Left": (11, 13, 15, 17, 19, 23),
        "Right": (12, 14, 16, 18, 20, 24),
    }.items():
        pose[:, sh], pose[:, el], pose[:, wr] = at(f"{side}Arm"), at(f"{side}ForeArm"), at(f"{side}Hand")
        pose[:, pk], pose[:, ix], pose[:, hp] = at(f"{side}HandPinky1"), at(f"{side}HandIndex1"), at(f"{side}UpLeg")
    head = at("Head")
    pose[:, 0] = head + [0, 0.05, 0.1]  # nose, ears: a rigid head at rest orientation
    pose[:, 7], pose[:, 8] = head + [0.07, 0.05, 0], head + [-0.07, 0.05, 0]
    hands = np.stack([np.stack([at(f"{s}{j}") for j in HAND_JOINTS], 1) for s in ("Right", "Left")], 1)
    to_mp = MP_TO_BVH.T  # the axis change is its own inverse
    return BodyLandmarks(
        pose=pose @ to_mp, visibility=np.ones((T, 33)), hands=hands @ to_mp, hand_score=np.ones((T, 2)), fps=15.0
    )


def test_solver_recovers_arm_directions_from_perfect_landmarks(beat_take):
    skel, motion = beat_take.skeleton, beat_take.motion[::4][:120]
    lm = _synthetic_landmarks(skel, motion)
    res = solve(skel, lm, smooth=False, depth_completion=False, hand_weight=0.0)
    assert res.pose.shape == (len(motion), 47, 6) and np.isfinite(res.pose).all()
    m = compare(skel, motion, pose_to_motion(skel, res.pose))
    # only the clavicles (kept at rest) and the spine's pivot separate the result from the truth
    assert m["median_deg"] < 6 and m["p90_deg"] < 12, m
    assert 0.85 < m["wrist_spread_ratio"] < 1.15, m
    # the head (ears and nose facing +Z, level) comes out facing forward: Spine · Neck · Neck1 ≈ identity
    from facecapges import rotations as rot
    from facecapges.skeleton import pose_head_rot6d

    head = rot.rot6d_to_matrix(pose_head_rot6d(skel, res.pose).astype(np.float64))
    assert np.degrees(np.linalg.norm(rot.log_so3(head), axis=-1)).max() < 2
    # the fingers follow the hand landmarks: fingertip directions in the hand's frame match
    P_t = joint_positions(skel, motion)
    P_c = joint_positions(skel, pose_to_motion(skel, res.pose))
    for tip, base in (("RightHandIndex4", "RightHandIndex1"), ("LeftHandMiddle4", "LeftHandMiddle1")):
        a = P_t[:, skel.index(tip)] - P_t[:, skel.index(base)]
        b = P_c[:, skel.index(tip)] - P_c[:, skel.index(base)]
        cos = (a * b).sum(-1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
        assert np.median(np.degrees(np.arccos(np.clip(cos, -1, 1)))) < 15
    # the default solve (the hand's direction blended into the forearm's, smoothing) stays close on
    # perfect landmarks: the blend costs what the wrist bends (a few degrees), nothing more (unsmoothed:
    # these frames are 4 apart)
    m = compare(skel, motion, pose_to_motion(skel, solve(skel, lm, smooth=False).pose))
    assert m["median_deg"] < 9 and m["p90_deg"] < 18, m


def test_the_torso_lean_is_blended_with_beats_population_prior(beat_take):
    """The lean towards the camera, which a frontal camera barely sees, is the landmarker's blended with the
    mean Spine pitch of BEAT's 4-speaker training set (its share by the two measured reliabilities); the
    turn and the roll stay the landmarker's."""
    from conftest import shared_file
    from facecapges import rotations as rot
    from facecapges.capture import body_solve as bs
    from facecapges.skeleton import UPPER_BODY

    mean = np.load(shared_file("data/beat/stats/bvh_mean.npy"))
    std = np.load(shared_file("data/beat/stats/bvh_std.npy"))
    k = 3 * UPPER_BODY.index("Spine")  # channels X, Y, Z: X is the pitch
    assert abs(bs.LEAN_PRIOR_DEG - mean[k]) < 0.05 and abs(bs.LEAN_PRIOR_SD_DEG - std[k]) < 0.05
    assert 0.15 < bs.LEAN_WEIGHT < 0.3
    skel, motion = beat_take.skeleton, beat_take.motion[:30]
    lm = _synthetic_landmarks(skel, motion)

    def spine_angles(**kw):  # the solved Spine's intrinsic X, Y, Z angles (degrees), one row a frame
        pose = solve(skel, lm, smooth=False, **kw).pose[:, UPPER_BODY.index("Spine")].astype(np.float64)
        return np.degrees(rot.matrix_to_euler(rot.rot6d_to_matrix(pose), "XYZ"))

    blended, seen = spine_angles(), spine_angles(lean_weight=1.0)
    want = bs.LEAN_WEIGHT * seen[:, 0] + (1 - bs.LEAN_WEIGHT) * bs.LEAN_PRIOR_DEG
    assert np.abs(blended[:, 0] - want).max() < 0.1, (blended[:, 0], want)
    assert np.abs(blended[:, 1:] - seen[:, 1:]).max() < 0.1  # turn and roll as seen


def test_arm_bones_take_their_image_plane_direction_from_the_image_landmarks(beat_take):
    """capture-body turns each arm bone's image-plane part to the image landmarks' direction (the world
    landmarks flatten the picture's perspective unevenly), keeping its length and depth."""
    from facecapges.capture.body_solve import ELBOW, SHOULDER, WRIST, image_directions

    skel, motion = beat_take.skeleton, beat_take.motion[:40]
    lm = _synthetic_landmarks(skel, motion)
    size = (640, 480)
    image = np.concatenate([lm.pose[..., :2] / size + 0.5, lm.pose[..., 2:]], axis=-1)  # an orthographic picture
    assert np.allclose(image_directions(lm.pose, image, size), lm.pose)
    bent = lm.pose.copy()  # the world landmarks' wrists off in the image plane, the picture right
    for side in ("Right", "Left"):
        bent[:, WRIST[side], :2] += np.array([0.06, -0.04])
    fixed = image_directions(bent, image, size)
    for side in ("Right", "Left"):
        for i, j in ((SHOULDER[side], ELBOW[side]), (ELBOW[side], WRIST[side])):
            d_true, d_fix, d_bent = (x[:, j] - x[:, i] for x in (lm.pose, fixed, bent))
            assert np.allclose(np.linalg.norm(d_fix, axis=-1), np.linalg.norm(d_bent, axis=-1))  # length kept
            assert np.allclose(d_fix[:, 2], d_bent[:, 2])  # depth kept
            u = d_true[:, :2] / np.linalg.norm(d_true[:, :2], axis=-1, keepdims=True)
            v = d_fix[:, :2] / np.linalg.norm(d_fix[:, :2], axis=-1, keepdims=True)
            assert (u * v).sum(-1).min() > 0.9999  # the picture's direction
    m_bent, m_fix = (
        compare(
            skel,
            motion,
            pose_to_motion(
                skel,
                solve(skel, marks, smooth=False, depth_completion=False, hand_weight=0.0).pose,
            ),
        )
        for marks in (
            BodyLandmarks(bent, lm.visibility, lm.hands, lm.hand_score, 15.0),
            BodyLandmarks(bent, lm.visibility, lm.hands, lm.hand_score, 15.0, image, size),
        )
    )
    assert m_fix["per_bone_median_deg"]["Right forearm"] < m_bent["per_bone_median_deg"]["Right forearm"] - 3, (
        m_fix,
        m_bent,
    )


def test_a_lost_hand_eases_to_rest_and_back(beat_take):
    skel, motion = beat_take.skeleton, beat_take.motion[:90]
    lm = _synthetic_landmarks(skel, motion)
    lm.hand_score[30:60, 0] = 0.0  # the right hand leaves the frame for 2 s
    lm.hands[30:60, 0] = np.nan
    res = solve(skel, lm, smooth=False)
    from facecapges.skeleton import UPPER_BODY

    k = UPPER_BODY.index("RightHandIndex2")
    assert res.confidence[40, k] == 0 and res.confidence[20, k] == 1
    step = np.abs(np.diff(res.pose[:, k], axis=0)).max(axis=1)
    assert step.max() < 0.5  # no jump: the fingers ease out and back in
    rest = solve(skel, lm, smooth=False).pose[45, k]  # deep in the gap: at rest
    assert np.allclose(rest, res.pose[45, k])


def test_models_are_built_reproducibly_with_the_pinned_hashes():
    from facecapges.capture import body_models as bm

    try:
        for name in (bm.POSE_TASK, bm.HAND_TASK):
            bm.model_path(name)  # verifies the sha256
    except UserError as exc:
        pytest.skip(str(exc))


def test_capture_body_errors(tmp_path):
    res = runner.invoke(app, ["capture-body", str(tmp_path / "none.mp4"), "--out", str(tmp_path / "x.bvh")])
    assert res.exit_code != 0 and "video not found" in str(res.exception)
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"not a video at all")
    res = runner.invoke(app, ["capture-body", str(bad), "--out", str(tmp_path / "x.bvh")])
    assert res.exit_code != 0 and isinstance(res.exception, (UserError, SystemExit))
    out = tmp_path / "x.bvh"
    out.write_text("keep")
    res = runner.invoke(app, ["capture-body", str(bad), "--out", str(out)])
    assert res.exit_code != 0 and out.read_text() == "keep"


def test_a_video_with_nothing_usable_is_refused_before_anything_is_written(tmp_path):
    """A face close-up (HDTF: no arm in any frame) is refused with the reason, and no BVH is left behind."""
    from conftest import shared_file

    video = shared_file("data/face/WDA_KatieHill_000.mp4")
    out = tmp_path / "x.bvh"
    res = runner.invoke(app, ["capture-body", str(video), "--out", str(out), "--max-frames", "20"])
    assert res.exit_code != 0 and isinstance(res.exception, UserError)
    assert "nothing usable" in str(res.exception)
    assert not out.exists()


@pytest.mark.slow
def test_capture_body_recovers_his_real_motion_from_a_rendered_video(beat_bvh, beat_wav, tmp_path):
    """Render the avatar with the held-out last 20 % of his real motion (13 s) and speech, capture it back, compare.
    The speech makes it test_live_body.py's video, rendered once per session (conftest's render cache)."""
    from facecapges.capture.body_models import POSE_TASK, model_path
    from facecapges.evaluation.body_capture import measure

    try:
        model_path(POSE_TASK)
    except UserError as exc:
        pytest.skip(str(exc))
    m = measure(beat_bvh, tmp_path, wav=beat_wav)
    assert m["frames"] == 191 and (tmp_path / "captured.bvh").is_file()
    # measured 10.8° / 22.6° (docs/capture-body.md): the target (median ≤ 12°, p90 ≤ 30°). The solver
    # before the torso's lean prior and the landmarker's own upper-arm depth gave 14.0° / 33.3°, forearms
    # 21.3° / 22.1°, camera frame 13.1° / 24.2° (and before that 15.9° / 37°).
    assert m["median_deg"] < 12 and m["p90_deg"] < 30, m
    forearms = [v for k, v in m["per_bone_median_deg"].items() if "forearm" in k]
    assert np.mean(forearms) < 19, m
    assert 0.8 < m["wrist_spread_ratio"] < 1.3, m
    assert m["camera"]["median_deg"] < 13 and m["camera"]["p90_deg"] < 25, m


def test_styles_build_video_errors(tmp_path):
    """--video: a missing file or a video without a soundtrack is one error before any capture."""
    res = runner.invoke(app, ["styles", "build", "x", "--video", str(tmp_path / "none.mp4")])
    assert res.exit_code != 0 and "not found" in str(res.exception)
    res = runner.invoke(app, ["styles", "build", "x"])
    assert res.exit_code != 0 and "--video VIDEO" in str(res.exception)


def test_nothing_usable_is_refused_and_out_of_view_arms_warned():
    from facecapges.capture.body import check_usable

    with pytest.raises(UserError, match="nothing usable"):
        check_usable("v.mp4", {"pose_found": 0.1, "arm_confidence": 0.9})
    assert "out of view" in check_usable("v.mp4", {"pose_found": 1.0, "arm_confidence": 0.3})
    assert check_usable("v.mp4", {"pose_found": 1.0, "arm_confidence": 0.9}) is None


def test_a_video_style_card_says_where_the_motion_came_from_and_how_well_it_was_seen():
    """styles build --video: the model card names the video, the shares of frames with the person and the hands
    found and each driven joint's mean confidence (from capture-body's summary)."""
    from facecapges.capture.body import CARD_JOINTS, seen_report
    from facecapges.matching.build import model_card
    from facecapges.skeleton import UPPER_BODY

    conf = [0.9] * len(UPPER_BODY)
    conf[UPPER_BODY.index("LeftForeArm")] = 0.31
    summary = {"frames": 450, "pose_found": 1.0, "hands_found": [0.8, 0.55], "both_hands_found": 0.5}
    seen = seen_report("me talking.mp4", {**summary, "joint_confidence": conf})
    assert seen["video"] == "me talking.mp4" and seen["both_hands_found"] == 0.5
    assert set(CARD_JOINTS) <= set(seen["joint_confidence"]) and seen["joint_confidence"]["LeftForeArm"] == 0.31
    take = {"name": "me", "source": "me talking.mp4.capture-body.bvh", "frames_used": [0, 360], "held_out": [360, 450]}
    meta = {"takes": [{**take, "captured_from": seen}], "licence": "the user's own", "attribution": "x"}
    card = model_card("mine", meta, 720, 0.2)
    row = next(line for line in card.splitlines() if line.startswith("| me | me talking.mp4 |"))
    assert "| 450 | 100% | 80% | 55% | 50% |" in row and "| 0.31 |" in row, row
    assert "LeftForeArm" in card and "capture-body" in card
    # a take from motion capture gets no such section
    assert "captured from video" not in model_card("mocap", {**meta, "takes": [take]}, 720, 0.2).lower()


def test_a_video_styles_motion_is_smoothed_of_capture_jitter_and_keeps_the_arms(beat_take):
    """styles build --video puts the captured motion in a style's database as it is replayed: landmark jitter
    (noise on a perfect landmarker's points) pops by the pop rule (his 99.9th-percentile acceleration) in the
    plain solve; smooth_for_style brings every joint under its acceleration limit, the pops to his rate, and
    costs the arm directions nothing."""
    from facecapges import rotations as rot
    from facecapges.capture.body_solve import ACCEL_LIMIT, smooth_for_style
    from facecapges.evaluation import realism as rz
    from facecapges.skeleton import motion_to_pose

    skel, motion = beat_take.skeleton, beat_take.motion[:450]
    real = motion_to_pose(skel, motion)[0]
    lm = _synthetic_landmarks(skel, motion)
    rng = np.random.default_rng(0)
    lm.pose[:] += rng.normal(0.0, 0.01, lm.pose.shape)  # 1 cm of landmark jitter, 4 mm on the hands
    lm.hands[:] += rng.normal(0.0, 0.004, lm.hands.shape)
    raw = solve(skel, lm).pose
    smooth = smooth_for_style(raw, 15.0)
    assert smooth.shape == raw.shape and np.isfinite(smooth).all()
    pops = [rz.transitions(p, [real], 15.0).per_minute for p in (raw, smooth, real)]
    assert pops[0] > 50 and pops[1] <= max(2.0, pops[2]), pops
    assert rot.angular_acceleration(smooth, 15.0).max() <= ACCEL_LIMIT * 1.05
    m_raw, m = (compare(skel, motion, pose_to_motion(skel, p)) for p in (raw, smooth))
    assert m["median_deg"] <= m_raw["median_deg"] + 0.5 and m["p90_deg"] <= m_raw["p90_deg"] + 0.5, (m_raw, m)


def test_styles_build_video_puts_the_smoothed_capture_in_the_take(beat_take, tmp_path, monkeypatch):
    """The --video path of styles build captures with for_style: the BVH its database is built from is under
    the acceleration limit (the landmarker fed a jittery perfect landmarker's points instead of a video's)."""
    import facecapges.capture.body as body
    import facecapges.io.audio as audio
    from facecapges import rotations as rot
    from facecapges.capture.body_solve import ACCEL_LIMIT
    from facecapges.commands.styles import _video_takes
    from facecapges.io.bvh import read_bvh
    from facecapges.skeleton import motion_to_pose

    skel, motion = beat_take.skeleton, beat_take.motion[:150]
    lm = _synthetic_landmarks(skel, motion)
    rng = np.random.default_rng(1)
    lm.pose[:] += rng.normal(0.0, 0.01, lm.pose.shape)
    lm.hands[:] += rng.normal(0.0, 0.004, lm.hands.shape)
    summary = {"frames": len(motion), "pose_found": 1.0, "hands_found": [1.0, 1.0], "both_hands_found": 1.0}
    monkeypatch.setattr(body, "collect_landmarks", lambda *a, **k: (lm, dict(summary)))
    monkeypatch.setattr(audio, "check_audio", lambda v: None)
    (tmp_path / "w").mkdir()
    pairs, _ = _video_takes([tmp_path / "me.mp4"], tmp_path / "w")
    b = read_bvh(pairs[0][0])
    captured = motion_to_pose(b.skeleton, b.motion)[0]
    assert rot.angular_acceleration(captured, 15.0).max() <= ACCEL_LIMIT * 1.05
    plain = rot.angular_acceleration(solve(skel, lm).pose, 15.0).max()
    assert plain > 1.5 * ACCEL_LIMIT  # the jitter is there before the smoothing (seeded: 201 rad/s²)


def test_the_render_cache_key_changes_with_anything_that_changes_the_video(tmp_path):
    """conftest's render cache (docs/testing.md) must never hand back a stale video: the key follows the input
    files' bytes (motion, frame range, fps, speech) and the options, not the paths the files are written at."""
    from facecapges.evaluation.body_capture import _render_key

    a, b, c = tmp_path / "a" / "truth.bvh", tmp_path / "b" / "truth.bvh", tmp_path / "truth.wav"
    for p, text in ((a, "MOTION 0.1\n"), (b, "MOTION 0.2\n"), (c, "RIFF")):
        p.parent.mkdir(exist_ok=True)
        p.write_text(text)
    args = ["render", "--bvh", str(a), "--out", str(tmp_path / "a.mp4"), "--force"]
    key = _render_key([a], args)
    same = tmp_path / "elsewhere.bvh"
    same.write_bytes(a.read_bytes())
    assert _render_key([same], ["render", "--bvh", str(same), "--out", "/x/y.mp4", "--force"]) == key
    assert _render_key([b], args) != key  # one digit of motion
    assert _render_key([a, c], [*args, "--audio", str(c)]) != key  # the speech (and the mouth it moves)
    assert _render_key([a], [*args, "--size", "320x240"]) != key


def test_body_landmarkers_called_directly_give_mediapipes_own_results(beat_bvh, beat_wav, tmp_path):
    """``BodyLandmarker`` calls the pose and hand landmarkers' C functions on its own thread and converts every frame
    into one kept image (as the face landmarker does, issue 36): the same landmarks, visibilities and hand scores,
    to the bit, as MediaPipe's own ``detect_for_video`` through its dispatcher on a new image a frame."""
    from facecapges.capture.body import BodyLandmarker
    from facecapges.capture.body_models import POSE_TASK, model_path
    from facecapges.capture.landmarks import FrameImages
    from facecapges.capture.video import open_source
    from facecapges.evaluation.body_capture import render_truth

    try:
        model_path(POSE_TASK)
    except UserError as exc:
        pytest.skip(str(exc))
    _, _, video, _ = render_truth(beat_bvh, tmp_path, wav=beat_wav)  # test_live_body.py's video (render cache)
    src = open_source(str(video))
    frames = [f for _, _, f in src.frames(max_frames=30)]
    src.close()
    got = []
    for direct in (False, True):
        with BodyLandmarker() as lm:
            if direct:
                assert lm._direct_pose is not None and lm._direct_hand is not None and lm._images.keep
            else:
                lm._direct_pose = lm._direct_hand = None  # MediaPipe's dispatcher, and a new image a frame
                lm._images = FrameImages(False)
            got.append([lm.detect(f, int(i * 1000 / 15)) for i, f in enumerate(frames)])
            assert (lm._images.kept is not None) == direct
    assert sum(d["pose"] is not None for d in got[0]) >= 25 and sum(len(d["hands"]) for d in got[0]) >= 10
    for a, b in zip(*got):
        for k in ("pose", "visibility", "pose_image"):
            assert (a[k] is None) == (b[k] is None) and (a[k] is None or a[k].tobytes() == b[k].tobytes())
        assert len(a["hands"]) == len(b["hands"])
        for (wa, ia, sa), (wb, ib, sb) in zip(a["hands"], b["hands"]):
            assert wa.tobytes() == wb.tobytes() and ia.tobytes() == ib.tobytes() and sa == sb
