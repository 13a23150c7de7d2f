"""Rendering the avatar in headless Chromium: stills, MP4 with audio, contact sheet, bad input."""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest

from facecapges.arkit import ARKIT_NAMES, arkit_index
from facecapges.io.bvh import read_bvh, write_bvh
from runtime_helpers import cli

pytestmark = pytest.mark.skipif(shutil.which("chromium") is None,
                                reason="chromium not installed (scripts/setup-avatar.sh)")


@pytest.fixture(scope="module")
def glb():
    from conftest import shared_file
    from facecapges.avatar.body import default_avatar
    from facecapges.avatar.gltf import avatar_to_gltf

    skel = read_bvh(shared_file("data/beat/2_scott_0_1_1.bvh")).skeleton
    return b"".join(avatar_to_gltf(default_avatar(skel)).save_to_bytes())


@pytest.mark.slow
def test_blendshapes_show_on_the_rendered_face_on_the_right_side(glb):
    from facecapges.avatar.render.video import our_avatar, render_stills

    w = np.zeros((3, 52))
    w[1, arkit_index("eyeBlinkLeft")] = 1.0
    w[2, arkit_index("jawOpen")] = 1.0
    neutral, blink, jaw = (im.astype(float) for im in render_stills(our_avatar(glb), [None] * 3, list(w), view="face",
                                                                    width=200, height=200))
    assert neutral.std() > 20  # something is drawn
    diff_blink = np.abs(blink - neutral).sum(2)
    # the subject's left eye is on the viewer's right half of a front view
    assert diff_blink[:, 100:].sum() > 5 * diff_blink[:, :100].sum()
    diff_jaw = np.abs(jaw - neutral).sum(2)
    assert diff_jaw[110:].sum() > 5 * diff_jaw[:90].sum()  # below the nose, not the forehead


@pytest.mark.slow
def test_render_cli_writes_mp4_with_audio_and_contact_sheet(tmp_path, beat_bvh, beat_wav):
    import cv2
    import imageio_ffmpeg

    from facecapges.io.face_json import write_face_json

    full = read_bvh(beat_bvh)
    bvh = write_bvh(tmp_path / "short.bvh", full.skeleton, full.motion[:30], full.fps)
    weights = np.zeros((120, 52), np.float32)
    weights[:, arkit_index("jawOpen")] = np.linspace(0, 1, 120)
    face = write_face_json(tmp_path / "face.json", weights, 60.0)
    out, sheet = tmp_path / "out.mp4", tmp_path / "sheet.png"
    r = cli("render", "--bvh", str(bvh), "--face", str(face), "--audio", str(beat_wav), "--out", str(out),
            "--contact-sheet", str(sheet), "--size", "320x240")
    assert r.returncode == 0, r.stderr
    probe = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-i", str(out)], capture_output=True, text=True).stderr
    assert re.search(r"Video: h264.*320x240", probe) and "Audio: aac" in probe
    dur = re.search(r"Duration: (\d+):(\d+):([\d.]+)", probe)
    assert 1.8 <= float(dur.group(3)) <= 2.3  # 30 frames at 15 fps, audio cut to the video
    img = cv2.imread(str(sheet))
    assert img is not None and img.shape[1] == 8 * 240 and img.shape[0] == 7 * (240 + 22)
    # refuses to overwrite
    r = cli("render", "--bvh", str(bvh), "--out", str(out))
    assert r.returncode == 2 and "--force" in r.stderr


def test_render_rejects_a_bvh_of_another_skeleton(tmp_path):
    other = tmp_path / "other.bvh"
    other.write_text("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition "
                     "Zrotation Xrotation Yrotation\n JOINT Spine\n {\n  OFFSET 0 10 0\n  CHANNELS 3 Zrotation "
                     "Xrotation Yrotation\n  End Site\n  {\n   OFFSET 0 10 0\n  }\n }\n}\nMOTION\nFrames: 2\n"
                     "Frame Time: 0.0666667\n0 0 0 0 0 0 0 0 0\n0 0 0 0 0 0 0 0 0\n")
    r = cli("render", "--bvh", str(other), "--out", str(tmp_path / "o.mp4"))
    assert r.returncode == 2 and "not a BEAT skeleton" in r.stderr and "Traceback" not in r.stderr


def test_bvh_quaternions_refuse_a_different_joint_order(beat_bvh):
    from facecapges.avatar.render.video import bvh_quaternions
    from facecapges.errors import UserError

    b = read_bvh(beat_bvh)
    q = bvh_quaternions(b.skeleton.names, b.skeleton, b.motion[:5])
    assert q.shape == (5, 75, 4) and np.allclose(np.linalg.norm(q, axis=2), 1.0, atol=1e-5)
    with pytest.raises(UserError, match="not the avatar's"):
        bvh_quaternions(list(reversed(b.skeleton.names)), b.skeleton, b.motion[:5])
    assert len(ARKIT_NAMES) == 52
