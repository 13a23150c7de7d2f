"""Output paths, inputs checked before the work, and the messages a user reads — each case the
attack or fault itself, through the real command line (bounded: a few seconds each)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from facecapges.errors import UserError, check_output_dir, check_output_file
from runtime_helpers import cli, cli_process_sequence, refused


def read_only(folder: Path, *commands: tuple[str, ...], timeout: float = 300) -> list[subprocess.CompletedProcess]:
    """Run CLI commands with ``folder`` mounted read-only (a private mount namespace; nothing else changes),
    all in one process of their own."""
    if shutil.which("unshare") is None:
        pytest.fail("unshare (util-linux) is needed to mount a read-only file system for this test")
    mount = f"mount -t tmpfs -o ro tmpfs '{folder}' && exec \"$0\" \"$@\""
    return cli_process_sequence(*commands, launcher=("unshare", "-rm", "sh", "-c", mount), timeout=timeout)


def test_output_checks(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(UserError, match="is a file, not a folder"):
        check_output_file(tmp_path / "file" / "out.bvh")
    with pytest.raises(UserError, match="is a folder"):
        check_output_file(tmp_path, force=True)
    with pytest.raises(UserError, match="already exists"):
        check_output_file(tmp_path / "file")
    with pytest.raises(UserError, match=r"a.png: already exists \(so do b.png\)"):
        (tmp_path / "d").mkdir()
        (tmp_path / "d" / "a.png").write_text("")
        (tmp_path / "d" / "b.png").write_text("")
        check_output_dir(tmp_path / "d", ["x.json", "a.png", "b.png"])
    assert check_output_file(tmp_path / "new" / "deeper" / "o.bvh") == tmp_path / "new" / "deeper" / "o.bvh"
    assert not (tmp_path / "new").exists()  # checking creates nothing


def test_generate_refuses_bad_outputs_before_any_work(tmp_path, beat_wav):
    (tmp_path / "file").write_text("mine")
    refused(cli("generate", "--audio", str(beat_wav), "--out", str(tmp_path / "file" / "o.bvh")), "is a file")
    (tmp_path / "dir").mkdir()
    refused(cli("generate", "--audio", str(beat_wav), "--out", str(tmp_path / "dir"), "--force"), "is a folder")
    assert not list(tmp_path.glob("**/*.part"))
    ro = tmp_path / "ro"
    ro.mkdir()
    for p in read_only(ro, ("generate", "--audio", str(beat_wav), "--out", str(ro / "o.bvh")),
                       ("avatar", "build", "--out", str(ro / "a.glb")),
                       ("prepare", str(beat_wav.parent), "--out", str(ro / "cache"), "--speakers", "2")):
        refused(p, "read-only")


def test_render_checks_its_audio_first(tmp_path, beat_bvh):
    bad = tmp_path / "speech.wav"
    bad.write_bytes(b"RIFF\x24\x00\x00\x00WAVEfmt " + b"\x00" * 30)
    p = cli("render", "--bvh", str(beat_bvh), "--out", str(tmp_path / "v.mp4"), "--audio", str(bad), timeout=120)
    refused(p, "speech.wav")
    assert not (tmp_path / "v.mp4").exists()
    mp4 = tmp_path / "nosound.mp4"
    mp4.write_bytes(b"\x00\x00\x00\x18ftypmp42" + b"\x00" * 100)
    refused(cli("render", "--bvh", str(beat_bvh), "--out", str(tmp_path / "v.mp4"), "--audio", str(mp4)))


def test_eval_and_ablate_keep_every_existing_output(tmp_path):
    out = tmp_path / "ev"
    out.mkdir()
    (out / "metrics.md").write_text("my notes")  # no metrics.json: the old check let this be overwritten
    refused(cli("eval", "--cache", str(tmp_path / "nocache"), "--out", str(out)), "metrics.md: already exists",
            "--force")
    (out / "ablation.md").write_text("mine")
    refused(cli("ablate", "--cache", str(tmp_path / "nocache"), "--out", str(out)), "ablation.md")
    assert (out / "metrics.md").read_text() == "my notes" and (out / "ablation.md").read_text() == "mine"


def _face_json(path: Path, times) -> Path:
    path.write_text(json.dumps({"names": ["jawOpen"], "frames": [{"time": t, "weights": [0.2]} for t in times]}))
    return path


def test_face_json_timing_is_checked(tmp_path, beat_wav):
    from facecapges.io.face_json import read_face_json

    with pytest.raises(UserError, match="1000 s apart"):
        read_face_json(_face_json(tmp_path / "a.json", [0, 1000, 2000]))
    with pytest.raises(UserError, match="frame times must increase; frame 2"):
        read_face_json(_face_json(tmp_path / "b.json", [0, 1 / 15, 1 / 15, 3 / 15]))
    assert read_face_json(_face_json(tmp_path / "c.json", [i / 15 for i in range(30)])).fps == 15.0
    with pytest.raises(UserError, match="malformed JSON"):
        (tmp_path / "d.json").write_text("[" * 60000)
        read_face_json(tmp_path / "d.json")
    # a 2 s face track with the 64 s speech: said, not silent
    p = cli("generate", "--audio", str(beat_wav), "--face", str(tmp_path / "c.json"), "--out", str(tmp_path / "o.bvh"))
    assert p.returncode == 0, p.stderr
    assert "face track lasts 2.0 s, the audio 64.1 s" in p.stderr


def test_long_inputs_stream_in_blocks(tmp_path, beat_wav):
    import soundfile as sf

    from facecapges import timing
    from facecapges.engine.inputs import plan_inputs
    from facecapges.io.audio import load_audio

    plan = plan_inputs(beat_wav)
    blocks = list(plan.blocks(block_frames=97))  # odd block size: every boundary case of the framing
    assert max(len(a) for a, _, _ in blocks) == 97
    np.testing.assert_array_equal(np.concatenate([a for a, _, _ in blocks]),
                                  timing.frame_audio(load_audio(beat_wav), plan.n_frames))
    # 10 minutes of silence at 44.1 kHz are refused from a block-by-block level: no full decode
    with sf.SoundFile(tmp_path / "silence.wav", "w", 44100, 1, "PCM_16") as f:
        for _ in range(10):
            f.write(np.zeros(44100 * 60, np.float32))
    with pytest.raises(UserError, match="silent"):
        plan_inputs(tmp_path / "silence.wav")


def _damaged_video(tmp_path: Path) -> tuple[Path, Path]:
    import cv2

    good = tmp_path / "good.mp4"
    w = cv2.VideoWriter(str(good), cv2.VideoWriter_fourcc(*"mp4v"), 25, (160, 120))
    for i in range(120):
        f = np.full((120, 160, 3), (i * 2) % 255, np.uint8)
        cv2.putText(f, str(i), (10, 60), 0, 1, (255, 255, 255), 2)
        w.write(f)
    w.release()
    b = bytearray(good.read_bytes())
    b[int(len(b) * 0.3):int(len(b) * 0.5)] = bytes(int(len(b) * 0.5) - int(len(b) * 0.3))
    bad = tmp_path / "damaged.mp4"
    bad.write_bytes(bytes(b))
    return good, bad


def test_a_damaged_video_is_held_over_and_reported(tmp_path):
    from facecapges.capture.video import open_source

    good, bad = _damaged_video(tmp_path)
    src = open_source(bad)
    got = [i for i, _, _ in src.frames()]
    assert got == list(range(120)) and src.bad_frames > 10  # every time slot, the damaged ones held over
    src.close()
    src = open_source(good)
    assert len(list(src.frames())) == 120 and src.bad_frames == 0 and src.missing_tail == 0
    src.close()
    p = cli("capture", str(bad), "--out", str(tmp_path / "f.json"), "--estimator", "geometric")
    assert p.returncode == 0, p.stderr
    assert "could not be decoded" in p.stderr and "no face was found in any frame" in p.stderr
    assert "[mpeg4" not in p.stderr and "header damaged" not in p.stderr  # FFmpeg's own noise is off
    from facecapges.io.face_json import read_face_json

    track = read_face_json(tmp_path / "f.json")
    assert track.n_frames / track.fps == pytest.approx(4.8, abs=1 / 15)  # 120 frames at 25 fps: nothing cut


def test_camera_error_is_one_line(tmp_path):
    p = cli("capture", "7", "--out", str(tmp_path / "f.json"), "--max-frames", "3")
    refused(p, "camera 7 cannot be opened")
    assert len(p.stderr.strip().splitlines()) == 1, p.stderr  # not under ten lines of OpenCV warnings


def test_smaller_crashes_are_clear_errors(tmp_path):
    import torch
    from safetensors.torch import save_file

    from facecapges.network.style import FORMAT
    from facecapges.styles import load_style

    ck = tmp_path / "m.safetensors"

    save_file({"w": torch.zeros(1)}, str(ck), metadata={"facecapges": json.dumps({"format": FORMAT})})
    with pytest.raises(UserError, match="no 'model_config'"):
        load_style(ck)
    # a truncated cache clip
    from facecapges.data.cache import Cache

    d = tmp_path / "cache"
    (d / "clips").mkdir(parents=True)
    np.savez(d / "clips" / "c.npz", pose=np.zeros((3, 47, 6)))
    (d / "clips" / "c.npz").write_bytes((d / "clips" / "c.npz").read_bytes()[:200])
    c = Cache.__new__(Cache)
    c.path, c._by_name = d, {"c": {"name": "c", "file": "clips/c.npz"}}
    with pytest.raises(UserError, match="corrupt clip file"):
        c.load("c")
    refused(cli("live", "--livelink", "70000", "--max-seconds", "1"), "out of range")


def test_two_faces_in_view_are_said(tmp_path, face_video):
    import cv2

    cap = cv2.VideoCapture(str(face_video))
    fps = cap.get(cv2.CAP_PROP_FPS) or 25.0
    frames = []
    while len(frames) < 20:
        ok, f = cap.read()
        if not ok:
            break
        frames.append(cv2.resize(f, (f.shape[1] // 2, f.shape[0] // 2)))
    cap.release()
    two = tmp_path / "two.mp4"
    h, w = frames[0].shape[:2]
    out = cv2.VideoWriter(str(two), cv2.VideoWriter_fourcc(*"mp4v"), fps, (2 * w, h))
    for f in frames:
        out.write(np.hstack([f, f]))  # the same speaker twice, side by side
    out.release()
    p = cli("capture", str(two), "--out", str(tmp_path / "f.json"), "--estimator", "geometric")
    assert p.returncode == 0, p.stderr
    assert "more than one face was in view" in p.stderr and "the largest face was tracked" in p.stderr


def test_run_says_what_happened_in_words(tmp_path, beat_wav):
    import soundfile as sf

    _, bad = _damaged_video(tmp_path)  # no face in it; 25 fps
    a, sr = sf.read(beat_wav, dtype="float32")
    sf.write(tmp_path / "speech.wav", a[: int(4.0 * sr)], sr)
    p = cli("run", str(bad), "--audio", str(tmp_path / "speech.wav"), "--out", str(tmp_path / "o"), "--no-video",
            "--estimator", "geometric")
    assert p.returncode == 0, p.stderr
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    assert rep["frames"] == 60 and rep["stopped_by"] == "end of input"  # not "frame limit" at the normal end
    assert rep["face_found_frames"] == 0 and "no face was found in any frame" in " ".join(p.stderr.split())
    assert "video_frames_skipped" not in p.stdout and "normal frame-rate conversion" in p.stdout
