"""``facecapges run`` end to end on the real talking-head clip (cut short with --max-frames)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from facecapges.io.bvh import read_bvh
from facecapges.io.face_json import read_face_json
from runtime_helpers import cli

N = 30  # 2 s of the 8 s clip keeps the test short; the full clip is run by the benchmark


@pytest.fixture(scope="module")
def run_dir(face_video, tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "out"
    r = cli("run", str(face_video), "--out", str(out), "--max-frames", str(N))
    assert r.returncode == 0, r.stderr[-2000:]
    (out.parent / "stdout.txt").write_text(r.stdout)
    return out


def probe(path):
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    n = sum(1 for _ in reader)
    return meta, n


@pytest.mark.slow
def test_outputs_written(run_dir):
    for name in ("motion.bvh", "face.json", "avatar.mp4", "side_by_side.mp4", "report.json"):
        assert (run_dir / name).stat().st_size > 0, name
    bvh = read_bvh(run_dir / "motion.bvh")
    assert bvh.motion.shape[0] == N and bvh.fps == 15 and bvh.skeleton.n_joints == 75
    assert np.isfinite(bvh.motion).all() and np.ptp(bvh.motion, axis=0).max() > 0.5  # it moves
    face = read_face_json(run_dir / "face.json")
    assert face.n_frames == 4 * N and face.fps == 60 and face.head_rot6d is not None  # BEAT's layout
    assert face.weights.max() > 0.1  # a talking face: the jaw and the eyes move


@pytest.mark.slow
def test_run_says_its_avatar_face_mode_and_files(run_dir):
    """What `run` used and wrote is on its output, not only in report.json."""
    said = (run_dir.parent / "stdout.txt").read_text()
    assert "avatar: ours" in said and "face capture: hybrid estimator" in said, said
    for name in ("motion.bvh", "face.json", "avatar.mp4", "side_by_side.mp4", "report.json"):
        assert f"wrote {run_dir / name}" in said, said
    report = json.loads((run_dir / "report.json").read_text())
    assert report["avatar"].startswith("ours") and report["face_inset"] is True


def test_videos(run_dir):
    meta, n = probe(run_dir / "avatar.mp4")
    assert n == N and meta["fps"] == pytest.approx(15) and meta["audio_codec"]
    meta2, n2 = probe(run_dir / "side_by_side.mp4")
    assert n2 == N and meta2["size"][0] > meta2["size"][1] > 0 and meta2["audio_codec"]


@pytest.mark.slow
def test_report(run_dir):
    rep = json.loads((run_dir / "report.json").read_text())
    assert rep["frames"] == N
    for stage in ("capture", "features", "model", "output", "total"):
        assert rep["latency_ms"][stage]["p50"] > 0 and rep["latency_ms"][stage]["p99"] >= rep["latency_ms"][stage]["p50"]
    assert set(rep["events"]) >= {"face_lost_frames", "input_frames_reused", "audio_underruns", "late_frames"}
    assert rep["events"]["face_lost_frames"] == 0  # the face is in view the whole clip
    assert rep["events"]["video_frames_skipped"] > 0  # 25 fps source at the 15 fps model rate


@pytest.mark.slow
def test_refuses_to_overwrite(run_dir, face_video):
    r = cli("run", str(face_video), "--out", str(run_dir), "--max-frames", "2", "--no-video")
    assert r.returncode == 2 and "already exists" in r.stderr and "Traceback" not in r.stderr


def test_bad_inputs(tmp_path, face_video):
    r = cli("run", str(tmp_path / "nope.mp4"), "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "nope.mp4" in r.stderr and "Traceback" not in r.stderr
    silent = tmp_path / "silent.mp4"
    import subprocess

    import imageio_ffmpeg

    subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-loglevel", "error", "-i", str(face_video), "-t", "1", "-an",
                    "-c:v", "copy", str(silent)], check=True)
    r = cli("run", str(silent), "--out", str(tmp_path / "o2"))
    assert r.returncode == 2 and "silent.mp4" in r.stderr and "--audio" in r.stderr
    r = cli("run", str(face_video), "--out", str(tmp_path / "o3"), "--style", "no-such-style")
    assert r.returncode == 2 and "no-such-style" in r.stderr
