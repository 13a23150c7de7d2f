"""Side-by-side skeleton MP4 from poses, with audio."""

from __future__ import annotations

import subprocess

import imageio_ffmpeg
import numpy as np
import pytest

from facecapges.avatar.render.skeleton_video import drawn_bones, pose_positions, render_skeleton_video
from facecapges.skeleton import joint_positions, motion_to_pose, pose_to_motion


def _probe(path):
    out = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path)],
                         capture_output=True, text=True)
    return out.stderr


def test_positions_match_bvh_fk(beat_take):
    bvh = beat_take
    pose = motion_to_pose(bvh.skeleton, bvh.motion[:20])[0]
    ours = pose_positions(bvh.skeleton, pose)
    ref = joint_positions(bvh.skeleton, pose_to_motion(bvh.skeleton, pose))
    np.testing.assert_allclose(ours, ref, atol=1e-3)  # cm
    names = {bvh.skeleton.names[j] for _, j, _ in drawn_bones(bvh.skeleton)}
    assert "RightHandIndex3" in names and "HeadEnd" in names and "RightUpLeg" not in names


def test_two_panels_with_audio(beat_take, beat_wav, tmp_path):
    bvh = beat_take
    pose = motion_to_pose(bvh.skeleton, bvh.motion[:45])[0]
    out = render_skeleton_video([pose, pose[::-1]], ["real", "generated"], bvh.skeleton, tmp_path / "v.mp4",
                                fps=15, wav=beat_wav, panel_size=(320, 360))
    info = _probe(out)
    assert "Video: h264" in info and "640x360" in info and "Audio: aac" in info
    # decode frame 10 and check both panels hold a drawn figure (dark pixels) on a light background
    raw = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-loglevel", "error", "-i", str(out), "-vf",
                          "select=eq(n\\,10)", "-frames:v", "1", "-f", "rawvideo", "-pix_fmt", "gray", "-"],
                         capture_output=True, check=True).stdout
    img = np.frombuffer(raw, np.uint8).reshape(360, 640)
    for panel in (img[60:, :320], img[60:, 320:]):
        assert (panel < 160).sum() > 200 and np.median(panel) > 230


def test_no_audio_and_bad_arguments(beat_take, tmp_path):
    bvh = beat_take
    pose = motion_to_pose(bvh.skeleton, bvh.motion[:10])[0]
    out = render_skeleton_video([pose], ["only"], bvh.skeleton, tmp_path / "a" / "v.mp4")
    info = _probe(out)
    assert "Video: h264" in info and "Audio" not in info
    with pytest.raises(ValueError):
        render_skeleton_video([pose], [], bvh.skeleton, tmp_path / "x.mp4")
    with pytest.raises(ValueError):
        pose_positions(bvh.skeleton, pose[:, :40])
