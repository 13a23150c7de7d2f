"""Our face.json against BEAT's own loader, written here from BEAT's published data loader (PantoMatrix/BEAT).

BEAT's loader (``dataloaders/beat.py``, cache generation) reads a face JSON like this: it takes the frame
step from ``frames[10]`` and ``frames[20]``: ``ceil(1 / ((t20 - t10) / 10)) // pose_fps``, keeps the
``weights`` of every frame whose index is a multiple of it (60 fps → 15 fps), stacks them and later
normalises them with the dataset's 51-channel face mean/std; clip lengths are ``frames // pose_fps``
seconds. ``beat_loader`` below does exactly that, independently of our reader.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from facecapges import rotations as rot
from facecapges import timing
from facecapges.arkit import ARKIT_NAMES, BEAT_NAMES
from facecapges.io.face_json import read_face_json, write_face_json

POSE_FPS = 15


def beat_loader(path, pose_fps: int = POSE_FPS) -> np.ndarray:
    with open(path) as f:
        data = json.load(f)
    factor = math.ceil(1 / ((data["frames"][20]["time"] - data["frames"][10]["time"]) / 10)) // pose_fps
    return np.array([fr["weights"] for j, fr in enumerate(data["frames"]) if j % factor == 0])


def beat_normalise(facial: np.ndarray) -> np.ndarray:
    from conftest import shared_file

    mean = np.load(shared_file("data/beat/stats/face_mean.npy"))
    std = np.load(shared_file("data/beat/stats/face_std.npy"))
    assert mean.shape == (51,)
    return (facial - mean) / std  # a (T, 52) array fails here: operands could not be broadcast


def talking_face(T: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(T) / POSE_FPS
    w = np.clip(0.3 + 0.25 * np.sin(2 * np.pi * (0.5 + rng.uniform(0, 2, 52)) * t[:, None] + rng.uniform(0, 6, 52)), 0, 1)
    w[:, ARKIT_NAMES.index("tongueOut")] = 0.7  # only the full layout keeps it
    return w.astype(np.float32)


def test_default_is_beats_layout_and_beats_loader_gets_our_frames_back(tmp_path):
    w = talking_face(120)  # 8 s at the model rate
    heads = rot.matrix_to_rot6d(rot.euler_to_matrix(np.stack([np.linspace(0, 0.5, 120), np.zeros(120),
                                                              np.zeros(120)], -1), "YXZ"))
    path = write_face_json(tmp_path / "face.json", w, 15.0, heads)
    doc = json.loads(path.read_text())
    assert doc["names"] == list(BEAT_NAMES) and len(doc["names"]) == 51 and "tongueOut" not in doc["names"]
    assert len(doc["frames"]) == 480 and doc["frames"][1]["time"] == pytest.approx(1 / 60, abs=1e-6)
    facial = beat_loader(path)
    assert facial.shape == (120, 51)  # 8 s stay 8 s
    assert facial.shape[0] // POSE_FPS == 8
    np.testing.assert_allclose(facial, w[:, :51], atol=1e-6)  # every 4th frame is our frame, unchanged
    assert np.isfinite(beat_normalise(facial)).all()
    # in between: linear weights, slerped head
    mid = np.array(doc["frames"][2]["weights"])
    np.testing.assert_allclose(mid, (w[0, :51] + w[1, :51]) / 2, atol=1e-6)
    yaw = [float(rot.matrix_to_euler(rot.rot6d_to_matrix(np.array(doc["frames"][j]["head_rot6d"])), "YXZ")[0])
           for j in range(5)]
    np.testing.assert_allclose(yaw, np.linspace(0, 0.5 / 119, 5), atol=1e-6)


def test_full_layout_keeps_52_at_the_model_rate(tmp_path):
    w = talking_face(60)
    path = write_face_json(tmp_path / "full.json", w, 15.0, layout="full")
    doc = json.loads(path.read_text())
    assert doc["names"] == list(ARKIT_NAMES) and len(doc["frames"]) == 60 and doc["fps"] == 15
    facial = beat_loader(path)  # BEAT's loader reads it (step 1) but it is not BEAT's layout:
    assert facial.shape == (60, 52)
    with pytest.raises(ValueError):
        beat_normalise(facial)


def test_training_input_reading_takes_both_layouts(tmp_path):
    """What data/prepare.py and generate do: read_face_json, then resample to the model rate."""
    w = talking_face(90)
    for layout in ("beat", "full"):
        tr = read_face_json(write_face_json(tmp_path / f"{layout}.json", w, 15.0, layout=layout))
        back = timing.resample(tr.weights, tr.fps, 15.0)
        assert tr.fps == (60 if layout == "beat" else 15) and back.shape == (90, 52)
        np.testing.assert_allclose(back[:, :51], w[:, :51], atol=1e-6)
        assert back[:, 51].max() == (pytest.approx(0.7) if layout == "full" else 0.0)


def test_recorders_of_run_and_live_write_beats_layout(tmp_path):
    from facecapges.runtime.frames import OutputFrame
    from facecapges.runtime.outputs.recorders import FaceJsonRecorder

    w = talking_face(45)
    rec = FaceJsonRecorder(tmp_path / "face.json", 15.0)
    for k in range(45):
        q = np.tile([1.0, 0, 0, 0], (47, 1))
        rec.write(OutputFrame(k, k / 15, np.zeros((47, 6)), q, w[k], rot.identity_rot6d(), True, {}))
    rec.close()
    facial = beat_loader(tmp_path / "face.json")
    assert facial.shape == (45, 51) and np.isfinite(beat_normalise(facial)).all()


def test_capture_command_writes_beats_layout(face_video, tmp_path):
    from runtime_helpers import cli

    out = tmp_path / "cap.json"
    r = cli("capture", str(face_video), "--out", str(out), "--max-frames", "30")
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads(out.read_text())
    assert len(doc["names"]) == 51 and len(doc["frames"]) == 120
    assert all(f["face_found"] is True and len(f["head_rot6d"]) == 6 for f in doc["frames"])
    facial = beat_loader(out)
    assert facial.shape == (30, 51) and facial.shape[0] // POSE_FPS == 2
    assert np.isfinite(beat_normalise(facial)).all() and facial.max() > 0.1


def test_unknown_layout_is_one_clear_error(face_video, tmp_path):
    from runtime_helpers import cli

    for args in (["capture", str(face_video), "--out", str(tmp_path / "a.json")],
                 ["run", str(face_video), "--out", str(tmp_path / "r")],
                 ["live", "--video", str(face_video), "--max-seconds", "1"]):
        r = cli(*args, "--face-json", "beat52")
        assert r.returncode == 2 and "--face-json beat52" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "a.json").exists() and not (tmp_path / "r").exists()


def test_the_face_recorder_keeps_a_second_in_memory_not_the_session(tmp_path):
    """A long ``live --record`` (issue #38's soak grew 0.46 MB a minute): 10 minutes of frames through the face
    recorder leave under 0.1 MB held in memory (the recorder before, lists of every frame's arrays: 2.2 MB here, where
    the frames are views of one array; 5.3 MB — 0.43 MB a minute — with a new array a frame, as live passes), and the
    JSON written at close holds every frame, weights and head."""
    import tracemalloc

    from facecapges.runtime.frames import OutputFrame
    from facecapges.runtime.outputs.recorders import FaceJsonRecorder

    n, fps = 9000, 15.0
    rng = np.random.default_rng(0)
    w = rng.random((n, 52)).astype(np.float32)
    quat = rng.normal(size=(n, 4))
    head = rot.quaternion_to_rot6d(quat / np.linalg.norm(quat, axis=1, keepdims=True)).astype(np.float32)
    pose, q = np.zeros((47, 6), np.float32), np.tile(np.float32([1, 0, 0, 0]), (47, 1))
    rec = FaceJsonRecorder(tmp_path / "face.json", fps, layout="full")
    tracemalloc.start()
    try:
        for k in range(60):  # the first frames allocate once (the temporary file, its buffer)
            rec.write(OutputFrame(k, k / fps, pose, q, w[k], head[k], True, {}))
        before = tracemalloc.get_traced_memory()[0]
        for k in range(60, n):
            rec.write(OutputFrame(k, k / fps, pose, q, w[k], head[k], True, {}))
        held = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert held < 100_000, f"{held / 1e6:.2f} MB held after {n} frames"
    rec.close()
    tr = read_face_json(tmp_path / "face.json")
    assert tr.weights.shape == (n, 52) and tr.fps == fps
    np.testing.assert_allclose(tr.weights, w, atol=1e-5)
    doc = json.loads((tmp_path / "face.json").read_text())
    np.testing.assert_allclose(np.array([f["head_rot6d"] for f in doc["frames"]]), head, atol=1e-5)
