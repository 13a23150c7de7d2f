"""The shipped default style and `facecapges demo` (what `make demo` runs)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from facecapges.demo import demo_speech
from facecapges.model.checkpoint import DEFAULT_STYLE, list_styles, load_checkpoint
from runtime_helpers import cli, cli_process


def test_default_style_is_installed_and_complete():
    assert DEFAULT_STYLE in list_styles()
    ck = load_checkpoint()
    assert ck.path.stat().st_size <= 20 * 1024 * 1024
    assert ck.skeleton.n_joints == 75 and not ck.skeleton.missing()
    assert ck.neutral_window.shape == (16, 47, 6)
    assert ck.meta["speaker"] == 2 and ck.meta["epochs_trained"] >= 1
    card = ck.path.with_suffix(".md")
    assert card.is_file() and "held" in card.read_text().lower()


def test_default_style_streams_like_its_training_rollout(beat_audio, beat_take, default_checkpoint):
    """The shipped model, on the real clip: streaming == training-time rollout."""
    import torch

    from facecapges.skeleton import motion_to_pose
    from facecapges.timing import frame_audio

    ck = default_checkpoint
    b = beat_take
    pose, head = motion_to_pose(b.skeleton, b.motion)
    T, N = 80, 16
    s = 770  # a held-out stretch
    audio = frame_audio(beat_audio, s + T)[s:]
    face = np.zeros((T, 52), np.float32)
    with torch.no_grad():
        z = ck.model.encode(torch.from_numpy(audio)[None], torch.from_numpy(face)[None],
                            torch.from_numpy(head[s:s + T])[None])
        ref = ck.model.rollout(z, torch.from_numpy(pose[s:s + N].reshape(1, N, -1)))[0].numpy()
    g = ck.streaming()
    for t in range(N):
        g.warmup(audio[t], face[t], head[s + t], pose[s + t])
    out = np.stack([g.step(audio[t], face[t], head[s + t]) for t in range(N, T)])
    np.testing.assert_allclose(out.reshape(T - N, -1), ref, atol=1e-5)


@pytest.mark.slow
def test_demo_writes_bvh_and_video(tmp_path):
    """``make demo`` end to end through the installed ``facecapges`` script (the console entry point)."""
    out = tmp_path / "out"
    script = Path(sys.executable).parent / "facecapges"
    assert script.is_file(), f"{script}: the console script is missing (make setup)"
    p = cli_process("demo", "--out", str(out), launcher=(str(script),), timeout=900)
    assert p.returncode == 0, p.stderr
    summary = json.loads(p.stdout[: p.stdout.rindex("}") + 1])
    info = sf.info(str(demo_speech()))
    assert summary["frames"] == math.ceil(info.frames / info.samplerate * 15 - 1e-6)
    from facecapges.io.bvh import read_bvh

    bvh = read_bvh(out / "demo.bvh")
    assert bvh.n_frames == summary["frames"]
    arms = bvh.motion[:, 3:].std(0)
    assert arms.max() > 1.0  # degrees: the avatar actually gestures
    import imageio_ffmpeg

    for video in ("demo.mp4", "demo_avatar.mp4"):
        probe = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-i", str(out / video)], capture_output=True, text=True)
        assert "Video: h264" in probe.stderr and "Audio:" in probe.stderr, video
    # a second run never overwrites without asking
    p2 = cli("demo", "--out", str(out), timeout=300)
    assert p2.returncode != 0 and "--force" in p2.stderr and "Traceback" not in p2.stderr
