"""The avatar's head is the person's head: on both real talking-head clips, in the files and over VMC."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest

from facecapges import rotations as rot
from facecapges.capture.face_lost import FaceLostPolicy
from facecapges.io.face_json import read_face_json
from facecapges.rotations import angles_to_matrix, head_angles
from facecapges.runtime.head import HeadDriver, avatar_head_matrix, head_follow, set_head
from runtime_helpers import checkpoint, cli

MEGAMIND_FRAMES = 168  # the clip's 11.3 s at 15 fps (it has no audio: a BEAT clip is the speech)


def run_head(tmp_path, video, head, audio=None, frames=None, track=None) -> dict:
    from facecapges.runtime.run import run_video

    rep = run_video(video, tmp_path / head, checkpoint(), audio=audio, max_frames=frames, progress=False,
                    videos=False, head=head, face_track=track)
    return rep["head_follow"]


@pytest.mark.parametrize("clip", ["katie", "megamind"])
def test_avatar_head_follows_the_captured_head(tmp_path, clip, face_video, megamind_video, unseen_wav):
    video, audio, frames = (face_video, None, None) if clip == "katie" else (megamind_video, unseen_wav,
                                                                            MEGAMIND_FRAMES)
    from facecapges.runtime.session import FaceTrack

    # the face is captured once, end to end, by the first run; the other two head modes replay its track (the
    # same capture results, frame by frame: runtime/session.py) instead of capturing the same face again
    track = FaceTrack()
    got = run_head(tmp_path, video, "capture", audio, frames, track)
    assert got["frames"] > 100
    assert got["yaw_r"] >= 0.9 and got["pitch_r"] >= 0.9, got
    assert got["mean_error_deg"] < 3.0
    # the model's own neck (it gets the head as an input) follows the person less closely (the measure can fail)
    old = run_head(tmp_path, video, "model", audio, frames, track)
    assert old["mean_error_deg"] > got["mean_error_deg"] + 2.0, old
    half = run_head(tmp_path, video, "blend", audio, frames, track)
    assert old["mean_error_deg"] > half["mean_error_deg"] > got["mean_error_deg"]


def test_a_replayed_face_track_drives_the_avatar_as_a_new_capture_does(tmp_path, face_video):
    """``run_video``'s ``face_track`` (what the test above shares between its three runs): a run replaying the track
    writes the same motion and face files, byte for byte, as a run that captures the face itself; a run asking for
    frames the track does not have (more of them) fails instead of guessing."""
    from facecapges.runtime.run import run_video
    from facecapges.runtime.session import FaceTrack

    track = FaceTrack()

    def run(name, **kw):
        run_video(face_video, tmp_path / name, checkpoint(), max_frames=20, progress=False, videos=False,
                  head="model", **kw)
        return [(tmp_path / name / f).read_bytes() for f in ("motion.bvh", "face.json")]

    run("capture", face_track=track)
    assert len(track.frames) >= 20
    assert run("replay", face_track=track) == run("again")
    with pytest.raises(ValueError, match="face track has no frame"):
        run_video(face_video, tmp_path / "longer", checkpoint(), max_frames=40, progress=False, videos=False,
                  face_track=track)


def test_set_head_puts_the_rotation_on_the_neck_chain():
    rng = np.random.default_rng(0)
    pose = rot.matrix_to_rot6d(rot.euler_to_matrix(rng.uniform(-0.4, 0.4, (47, 3)), "XYZ")).astype(np.float64)
    R = angles_to_matrix(0.4, -0.3, 0.1)
    out = set_head(pose, R)
    np.testing.assert_allclose(avatar_head_matrix(out), R, atol=1e-9)
    np.testing.assert_array_equal(out[0], pose[0])  # the spine is the model's
    np.testing.assert_array_equal(out[3:], pose[3:])  # and so are the arms
    np.testing.assert_allclose(out[1], out[2])  # the neck's share is split evenly


def test_face_lost_falls_back_to_the_model_head_and_comes_back_smoothly():
    pol = FaceLostPolicy()
    drv = HeadDriver("capture", pol)
    model_pose = np.tile(rot.identity_rot6d(), (47, 1)).astype(np.float64)
    cap = rot.matrix_to_rot6d(angles_to_matrix(0.5, 0.3, 0.0))
    fps, yaws = 15.0, []
    for k in range(90):
        t = k / fps
        found = not (15 <= k < 60)  # the face is away for 3 s
        yaws.append(head_angles(avatar_head_matrix(drv(model_pose, cap, found, t)))[0])
    yaws = np.degrees(yaws)
    assert yaws[0] == pytest.approx(np.degrees(0.5), abs=1e-6)  # the first face is shown at once
    held = [k for k in range(15, 60) if (k - 15) / fps <= pol.hold_s]
    np.testing.assert_allclose(yaws[held], np.degrees(0.5), atol=1e-6)  # held 0.5 s
    gone = [k for k in range(15, 60) if (k - 15) / fps >= pol.gone_s]
    np.testing.assert_allclose(yaws[gone], 0.0, atol=1e-6)  # then the model's head
    assert yaws[-1] == pytest.approx(np.degrees(0.5), abs=1e-6)  # the capture again
    assert np.abs(np.diff(yaws)).max() < 10.0  # eased both ways: no jump (the full swing is 28.6°)
    assert np.abs(np.diff(yaws[58:66])).max() > 1.0  # and it does come back within 0.3 s
    # model mode leaves the model's head alone
    assert HeadDriver("model")(model_pose, cap, True, 0.0) is model_pose


def test_the_compiled_head_chain_keeps_numpys_bits():
    """``HeadDriver(compiled=True)`` (``live``'s scheduler) shows the same poses to the bit as NumPy's chain: 3,000
    frames of random poses and heads (float32, as ``live``'s), a third of them with the head on the Spine or a hair
    off it (the slerp's linear branch), the face found, lost (held, easing) and found again."""
    from facecapges.runtime import head

    rc = head.compiled_head()
    if rc is None:
        pytest.skip("this machine's NumPy sums or rounds otherwise than the compiled chain: NumPy's is used")
    rng = np.random.default_rng(7)
    n = 3000
    poses = rng.standard_normal((n, 47, 6)).astype(np.float32)
    heads = rot.quaternion_to_rot6d(rng.standard_normal((n, 4))).astype(np.float32)
    poses[: n // 3, 0] = heads[: n // 3] + (rng.standard_normal((n // 3, 6)) * 1e-7).astype(np.float32)
    poses[: n // 6, 0] = heads[: n // 6]
    R = np.empty((3, 3))
    for pose, h in zip(poses, heads):  # the chain alone, on every kind of pair
        rc.rot6d_to_matrix(h, R)
        got = head._set_head_compiled(rc, pose, R)
        np.testing.assert_array_equal(got.view(np.uint32), head._numpy_capture_head(pose, h).view(np.uint32))
    fast, slow = HeadDriver("capture", compiled=True), HeadDriver("capture")
    order = rng.permutation(n)
    for k, i in enumerate(order[:600]):  # a session: found, lost for 2 s (held, eased), found again
        found = not (100 <= k < 130 or 300 <= k < 400)
        a, b = fast(poses[i], heads[i], found, k / 15.0), slow(poses[i], heads[i], found, k / 15.0)
        np.testing.assert_array_equal(a.view(np.uint32), b.view(np.uint32))


def test_head_follow_measures_disagreement():
    T = 60
    yaw = 0.4 * np.sin(np.arange(T) / 6)
    heads = np.stack([rot.matrix_to_rot6d(angles_to_matrix(y, 0.2 * np.cos(k / 5), 0)) for k, y in enumerate(yaw)])
    still = np.tile(rot.identity_rot6d(), (T, 47, 1))
    shown = np.stack([set_head(still[k], rot.rot6d_to_matrix(heads[k].astype(np.float64))) for k in range(T)])
    assert head_follow(shown, heads)["yaw_r"] == pytest.approx(1.0)
    assert head_follow(still, heads)["mean_error_deg"] > 5  # a still head does not follow


def model_rate_heads(path) -> np.ndarray:
    """The recorded head rot6d at the model's 15 fps (face JSON is BEAT's 60 fps: every 4th frame is exact)."""
    f = read_face_json(path)
    return f.head_rot6d[::int(round(f.fps / 15))]


def _vmc_heads(port_holder, got, stop):
    from pythonosc.dispatcher import Dispatcher
    from pythonosc.osc_server import BlockingOSCUDPServer

    current: dict[str, np.ndarray] = {}

    def on_bone(address, name, *v):
        current[name] = np.array([v[6], v[3], -v[4], -v[5]])  # Unity (x, y, z, w) → right-handed (w, x, y, z)

    def on_time(address, t):
        got[int(round(float(t) * 15))] = dict(current)

    disp = Dispatcher()
    disp.map("/VMC/Ext/Bone/Pos", on_bone)
    disp.map("/VMC/Ext/T", on_time)
    server = BlockingOSCUDPServer(("127.0.0.1", 0), disp)
    server.timeout = 0.2
    port_holder.append(server.server_address[1])
    while not stop.is_set():
        server.handle_request()
    server.server_close()


def test_vmc_receiver_sees_the_captured_head(tmp_path, face_video):
    """``live`` over VMC: a receiver chaining the bones it gets shows the person's yaw and pitch."""
    got: dict[int, dict] = {}
    port, stop = [], threading.Event()
    th = threading.Thread(target=_vmc_heads, args=(port, got, stop), daemon=True)
    th.start()
    while not port:
        time.sleep(0.01)
    rec = tmp_path / "rec"
    r = cli("live", "--video", str(face_video), "--vmc", f"127.0.0.1:{port[0]}", "--record", str(rec),
            "--face-json", "full")  # face.json at the model rate: frame k is VMC frame k
    time.sleep(0.5)
    stop.set()
    th.join(5)
    assert r.returncode == 0, r.stderr
    captured = model_rate_heads(rec / "face.json")
    chain = ("Hips", "Spine", "Chest", "UpperChest", "Neck", "Head")
    frames = sorted(k for k, bones in got.items() if all(b in bones for b in chain) and k < len(captured))
    assert len(frames) > 0.9 * len(captured)
    vmc, cam = [], []
    for k in frames:
        G = np.eye(3)
        for b in chain:
            G = G @ rot.quaternion_to_matrix(got[k][b])
        vmc.append(np.degrees(head_angles(G)))
        cam.append(np.degrees(head_angles(rot.rot6d_to_matrix(captured[k].astype(np.float64)))))
    vmc, cam = np.array(vmc), np.array(cam)
    r_yaw, r_pitch = (np.corrcoef(vmc[:, i], cam[:, i])[0, 1] for i in (0, 1))
    assert r_yaw >= 0.9 and r_pitch >= 0.9, (r_yaw, r_pitch)
    report = json.loads((rec / "report.json").read_text())
    assert report["frames"] >= len(captured)


@pytest.mark.slow
def test_the_video_shows_the_head(tmp_path, face_video):
    """MediaPipe, run on the face close-up of the rendered avatar.mp4, sees the person's yaw and pitch."""
    import cv2

    from facecapges.capture.pipeline import FaceCapture
    from facecapges.runtime.run import run_video

    out = tmp_path / "run"
    run_video(face_video, out, checkpoint(), max_frames=75, progress=False, head="capture")
    captured = model_rate_heads(out / "face.json")
    v = cv2.VideoCapture(str(out / "avatar.mp4"))
    W, H = int(v.get(cv2.CAP_PROP_FRAME_WIDTH)), int(v.get(cv2.CAP_PROP_FRAME_HEIGHT))
    ih = round(H / 3)  # the inset: a third of the height, 4:3, top-right (web/avatar_scene.js)
    iw, m = round(ih * 4 / 3), round(H / 60) + 2
    seen, cam = [], []
    with FaceCapture(estimator="mediapipe", fps=15) as cap:
        k = 0
        while True:
            ok, img = v.read()
            if not ok:
                break
            crop = cv2.resize(img[m:m + ih, W - iw - m:W - m], (3 * iw, 3 * ih), interpolation=cv2.INTER_CUBIC)
            r = cap.process(crop, k * 1000 / 15)
            if r.face_found and k < len(captured):
                seen.append(np.degrees(head_angles(r.head_R)))
                cam.append(np.degrees(head_angles(rot.rot6d_to_matrix(captured[k].astype(np.float64)))))
            k += 1
    v.release()
    seen, cam = np.array(seen), np.array(cam)
    assert len(seen) > 0.9 * len(captured)
    r_yaw, r_pitch = (np.corrcoef(seen[:, i], cam[:, i])[0, 1] for i in (0, 1))
    assert r_yaw >= 0.9 and r_pitch >= 0.9, (r_yaw, r_pitch)
