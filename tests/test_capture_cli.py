"""``facecapges capture`` / ``capture-eval`` end to end, and their error paths."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from facecapges.arkit import ARKIT_NAMES
from facecapges.commands.cli import app
from facecapges.errors import UserError
from runtime_helpers import cli

runner = CliRunner()


def _invoke(args):
    res = runner.invoke(app, args)
    if isinstance(res.exception, UserError) and "not installed" in str(res.exception):
        pytest.skip(str(res.exception))
    return res


def test_capture_writes_face_json_and_overlay(face_video, tmp_path):
    out, ov = tmp_path / "face.json", tmp_path / "ov.mp4"
    res = _invoke(["capture", str(face_video), "--out", str(out), "--fps", "15", "--estimator", "hybrid",
                   "--overlay", str(ov), "--max-frames", "20", "--face-json", "full"])
    assert res.exit_code == 0, res.output + repr(res.exception)
    doc = json.loads(out.read_text())
    assert doc["names"] == list(ARKIT_NAMES) and doc["fps"] == 15
    frames = doc["frames"]
    assert len(frames) == 20
    np.testing.assert_allclose([f["time"] for f in frames], np.arange(20) / 15, atol=1e-6)
    for f in frames:
        assert len(f["weights"]) == 52 and len(f["head_rot6d"]) == 6
        assert f["face_found"] is True and 0.2 < f["distance_m"] < 2
        assert all(0 <= x <= 1 for x in f["weights"])
    assert ov.stat().st_size > 1000
    import cv2

    c = cv2.VideoCapture(str(ov))
    assert int(c.get(cv2.CAP_PROP_FRAME_COUNT)) == 20
    c.release()
    # refuses to overwrite without --force
    res = _invoke(["capture", str(face_video), "--out", str(out), "--max-frames", "2"])
    assert isinstance(res.exception, UserError) and "--force" in str(res.exception)


def test_capture_eval_writes_report_and_plot(face_video, tmp_path):
    res = _invoke(["capture-eval", str(face_video), "--out", str(tmp_path), "--max-frames", "75"])
    assert res.exit_code == 0, res.output + repr(res.exception)
    rep = json.loads((tmp_path / "capture_eval.json").read_text())
    assert rep["frames"] == 75 and rep["frames_evaluated"] == 25
    assert set(rep["channels"]) >= {"jawOpen", "eyeBlinkLeft", "eyeBlinkRight"}
    assert rep["head_pose"]["median_deg"] <= 3.0
    assert (tmp_path / "tracks.png").stat().st_size > 10000
    assert "jawOpen" in res.output


def _run_cli(*args):
    return cli(*args, timeout=120)


def test_errors_exit_nonzero_with_one_clear_line(tmp_path, face_video):
    bad = tmp_path / "broken.mp4"
    bad.write_bytes(b"garbage" * 10)
    p = _run_cli("capture", str(bad), "--out", str(tmp_path / "o.json"))
    assert p.returncode == 2 and "cannot be read as a video" in p.stderr and "Traceback" not in p.stderr
    p = _run_cli("capture", "57", "--out", str(tmp_path / "o.json"))
    assert p.returncode == 2 and "camera 57 cannot be opened" in p.stderr
    p = _run_cli("capture", str(face_video), "--out", str(tmp_path / "o.json"), "--model", str(tmp_path / "none.task"))
    assert p.returncode == 2 and "none.task: face landmarker model not found" in p.stderr and "Traceback" not in p.stderr
    p = _run_cli("capture", str(bad), "--out", str(tmp_path / "o.json"), "--estimator", "magic")
    assert p.returncode == 2 and "--estimator" in p.stderr


def test_capture_with_depth_frames(face_video, tmp_path):
    """RGB-D wiring: depth frames rendered from the canonical mesh drive the head pose."""
    import math

    from facecapges.capture.canonical_mesh import load_canonical_mesh
    from facecapges.capture.depth import render_depth
    from facecapges.capture.head_pose import Intrinsics
    from facecapges.capture.models import resolve_model
    from facecapges.rotations import angles_to_matrix, geodesic_angle, rot6d_to_matrix

    try:
        mesh = load_canonical_mesh(resolve_model())
    except UserError as exc:
        pytest.skip(str(exc))
    K = Intrinsics(200.0, 200.0, 80.0, 60.0)
    ddir = tmp_path / "depth"
    ddir.mkdir()
    truth = []
    for k in range(4):
        R = angles_to_matrix(math.radians(5 * k), 0.0, 0.0)
        truth.append(R)
        D = render_depth(mesh.vertices / 100 @ R.T + [0, 0, -0.6], mesh.triangles, K, 160, 120, background_mm=1500)
        np.save(ddir / f"{k:04d}.npy", D)
    (tmp_path / "K.json").write_text(json.dumps({"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy}))
    out = tmp_path / "face.json"
    res = _invoke(["capture", str(face_video), "--out", str(out), "--fps", "25", "--depth", str(ddir),
                   "--intrinsics", str(tmp_path / "K.json"), "--max-frames", "4", "--face-json", "full"])
    assert res.exit_code == 0, res.output + repr(res.exception)
    frames = json.loads(out.read_text())["frames"]
    assert len(frames) == 4
    for f, R in zip(frames, truth):
        Rf = rot6d_to_matrix(np.array(f["head_rot6d"]))
        assert math.degrees(float(geodesic_angle(Rf, R))) < 3.0
        assert abs(f["distance_m"] - 0.6) < 0.05
