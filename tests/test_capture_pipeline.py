"""FaceCapture on real video (first frames only: MediaPipe costs ~15 ms a frame)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from facecapges.capture.video import open_source
from facecapges.errors import UserError
from facecapges.rotations import geodesic_angle, head_angles, matrix_to_rot6d


def _capture(**kw):
    from facecapges.capture.pipeline import FaceCapture

    try:
        return FaceCapture(**kw)
    except UserError as exc:
        if "not installed" in str(exc):
            pytest.skip(str(exc))
        raise


def _frames(path, n):
    src = open_source(str(path))
    frames = [(ts, f) for _, ts, f in src.frames(n)]
    src.close()
    return src, frames


def test_real_face_pose_matches_mediapipe_and_weights_are_valid(face_video):
    src, frames = _frames(face_video, 60)
    errs = []
    with _capture(estimator="hybrid", fps=src.fps) as cap:
        for ts, f in frames:
            r = cap.process(f, ts)
            assert r.face_found and r.face_id == 0
            assert r.weights52.shape == (52,) and r.weights52.dtype == np.float32
            assert np.all((r.weights52 >= 0) & (r.weights52 <= 1))
            assert r.head_rot6d.shape == (6,) and 0.2 < r.distance_m < 2.0
            # the head is stored once (head_R); its rot6d and angles are derived from it
            np.testing.assert_array_equal(r.head_rot6d, matrix_to_rot6d(r.head_R).astype(np.float32))
            np.testing.assert_array_equal(r.head_angles, head_angles(r.head_R).astype(np.float32))
            errs.append(math.degrees(float(geodesic_angle(r.head_R, r.mp_transform[:3, :3]))))
    assert np.median(errs) <= 3.0


def test_strong_head_turns_stay_stable(megamind_video):
    src, frames = _frames(megamind_video, 100)
    prev = None
    yaws = []
    with _capture(estimator="geometric", fps=src.fps) as cap:
        for ts, f in frames:
            r = cap.process(f, ts)
            assert np.isfinite(r.weights52).all() and np.isfinite(r.head_rot6d).all()
            if prev is not None and r.face_found and prev.face_found:
                step = math.degrees(float(geodesic_angle(r.head_R, prev.head_R)))
                assert step < 20.0  # bounded frame-to-frame change at 24 fps
                assert np.abs(r.weights52 - prev.weights52).max() <= 1.0
            yaws.append(math.degrees(r.head_angles[0]))
            prev = r
    assert max(yaws) - min(yaws) > 15  # the clip really turns


def test_face_lost_holds_then_eases_to_neutral(face_video):
    src, frames = _frames(face_video, 30)
    black = np.zeros_like(frames[0][1])
    with _capture(estimator="mediapipe", fps=src.fps, hold_ms=400, ease_ms=400) as cap:
        for ts, f in frames:
            last = cap.process(f, ts)
        t0 = frames[-1][0]
        held = cap.process(black, t0 + 200)
        assert not held.face_found and held.landmarks is None
        np.testing.assert_allclose(held.weights52, last.weights52)
        np.testing.assert_allclose(held.head_rot6d, last.head_rot6d, atol=1e-6)
        mid = cap.process(black, t0 + 800)  # lost since t0 + 200: 600 ms = hold + half the ease
        assert 0 < np.abs(mid.weights52).sum() < np.abs(last.weights52).sum()
        gone = cap.process(black, t0 + 1050)
        assert not gone.face_found and np.all(gone.weights52 == 0)
        np.testing.assert_allclose(gone.head_rot6d, [1, 0, 0, 0, 1, 0], atol=1e-6)
        back = cap.process(frames[0][1], t0 + 1100)
        assert back.face_found and back.face_id == last.face_id  # identity kept


def test_two_faces_keep_their_identities(face_video):
    src, frames = _frames(face_video, 8)
    with _capture(estimator="geometric", fps=src.fps, num_faces=2) as cap:
        ids = []
        for ts, f in frames:
            small = f[::2, ::2]
            pair = np.concatenate([small, np.ascontiguousarray(small[:, ::-1])], axis=1)
            res = [r for r in cap.process_all(pair, ts) if r.face_found]
            assert len(res) == 2
            ids.append({r.face_id: r.landmarks[:, 0].mean() < 0.5 for r in res})
        assert all(d == ids[0] for d in ids) and len(ids[0]) == 2
        assert set(cap.states) == set(ids[0])  # one estimator per face


def test_unreadable_video_and_camera_are_user_errors(tmp_path):
    bad = tmp_path / "x.mp4"
    bad.write_bytes(b"\x00" * 100)
    with pytest.raises(UserError, match="cannot be read"):
        open_source(str(bad))
    with pytest.raises(UserError, match="not found"):
        open_source(str(tmp_path / "missing.mp4"))
    with pytest.raises(UserError, match="camera 57"):
        open_source("57")


def test_primary_face_follows_a_face_that_jumped(face_video):
    """A face that jumps more than a face width gets a new identity; the primary result follows it."""
    src, frames = _frames(face_video, 8)
    with _capture(estimator="geometric", fps=src.fps) as cap:
        for k, (ts, f) in enumerate(frames):
            canvas = np.zeros((f.shape[0], 3 * f.shape[1], 3), np.uint8)
            x0 = 0 if k < 3 else 2 * f.shape[1]
            canvas[:, x0:x0 + f.shape[1]] = f
            r = cap.process(canvas, ts)
            if k < 3:
                assert r.face_found and r.face_id == 0
            elif not r.face_found:  # MediaPipe may need a frame or two to re-detect
                assert r.face_id == 0 and k < 6
        assert r.face_found and r.face_id == 1 and 0 in cap.states  # old identity still held


def test_landmarks_read_from_mediapipes_c_results_are_its_python_results(face_video):
    """The detector reads MediaPipe's C result structs (no Python object per landmark: issue 36), calls its C
    functions on this thread (not through MediaPipe's dispatcher thread) and converts every frame into one image
    of its own: the same landmarks, blendshapes and transforms, to the bit, as MediaPipe's own
    ``detect_for_video`` gives on a new image a frame."""
    from facecapges.capture.landmarks import FrameImages, LandmarkDetector
    from facecapges.capture.models import resolve_model

    src = open_source(str(face_video))
    frames = [f for _, _, f in src.frames(max_frames=20)]
    src.close()
    got = []
    for raw in (False, True):
        with LandmarkDetector(resolve_model()) as det:
            if raw:
                assert det.raw_results and det.direct is not None  # this MediaPipe has them (the pinned one does)
            else:
                det.direct, det._images = None, FrameImages(False)  # MediaPipe's dispatcher, a new image a frame
            det.raw_results = raw
            got.append([det.detect(f, int(i * 40)) for i, f in enumerate(frames)])
            assert (det._images.kept is not None) == raw  # the frames went through the detector's own image
    assert sum(len(faces) for faces in got[0]) == 20
    for public, raw in zip(*got):
        assert len(public) == len(raw)
        for a, b in zip(public, raw):
            assert a.landmarks.dtype == b.landmarks.dtype and a.landmarks.shape == b.landmarks.shape
            assert a.landmarks.tobytes() == b.landmarks.tobytes() and a.blendshapes.tobytes() == b.blendshapes.tobytes()
            assert a.transform.tobytes() == b.transform.tobytes()


def test_c_struct_fields_read_in_one_copy_or_field_by_field():
    """``_c_array``: consecutive float32 fields (a landmark's x, y, z) in one strided copy, others field by field:
    the values of the structs either way."""
    import ctypes

    from facecapges.capture.landmarks import _c_array, _c_fields

    class S(ctypes.Structure):
        _fields_ = [("a", ctypes.c_float), ("b", ctypes.c_float), ("c", ctypes.c_float), ("n", ctypes.c_void_p)]

    rows = (S * 5)(*[S(i + 0.5, -i / 3, i * 1e-3, None) for i in range(5)])
    want = np.array([[r.a, r.b, r.c] for r in rows], np.float32)
    ptr = ctypes.cast(rows, ctypes.POINTER(S))
    got = _c_array(ptr, 5, _c_fields(S, ("a", "b", "c")))
    assert got.dtype == np.float32 and got.flags.c_contiguous and got.tobytes() == want.tobytes()
    assert _c_array(ptr, 5, _c_fields(S, ("a", "c"))).tobytes() == want[:, [0, 2]].copy().tobytes()
    assert _c_array(ptr, 0, _c_fields(S, ("a", "b"))).shape == (0, 2)


def test_mediapipe_loads_in_a_fresh_interpreter():
    """``landmarks._mediapipe`` in a process that has not imported ``importlib.util`` yet (its lazy-drawing finder
    once asked itself for that module without end: a RecursionError): an image is made."""
    import subprocess
    import sys

    code = "import numpy as np\nfrom facecapges.capture.landmarks import mp_image\nmp_image(np.zeros((2, 2, 3), np.uint8))\n"
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
