"""A VRM in the live chain and VRM Animation from the commands that make gestures:

* ``live --video F --realtime --web … --avatar SAMPLE.vrm --record DIR --vrma``: the VRM viewer
  (three-vrm in headless Chromium) draws the feed (also as an OBS browser source), the hands of the VRM 0.x sample show up on
  screen, and Ctrl-C leaves a ``motion.vrma`` as long as ``motion.bvh``, valid against the
  VRM Animation schema;
* ``generate --vrma`` (the installed default style) writes one with the face as presets;
* ``run --avatar`` renders avatar.mp4 with the VRM.
"""

from __future__ import annotations

import json
import signal
import sys
from pathlib import Path

import numpy as np
import pytest

from facecapges.avatar.vrm.glb import split_glb

sys.path.insert(0, str(Path(__file__).parent))
from runtime_helpers import check_obs_views, cli, cli_popen, obs_views, open_viewer, viewer_url
from vrm_samples import build_sample
from vrm_schemas import VRMC_VRM_ANIMATION, semantic_errors


def _vrma_ok(path: Path) -> dict:
    import jsonschema

    doc, _ = split_glb(path.read_bytes())
    jsonschema.validate(doc["extensions"]["VRMC_vrm_animation"], VRMC_VRM_ANIMATION,
                        cls=jsonschema.Draft202012Validator)
    assert semantic_errors(doc, "VRMC_vrm_animation") == []
    return doc


def _play_vrma(vrma: Path, variant: str = "vrm1") -> dict:
    """Load ``vrma`` with @pixiv/three-vrm-animation onto a sample VRM in headless Chromium."""
    from conftest import shared_file
    from facecapges.avatar.render.browser import Browser
    from facecapges.avatar.vrm.read import parse_model
    from facecapges.avatar.vrm.view import VrmDriver
    from facecapges.io.bvh import read_bvh

    skel = read_bvh(shared_file("data/beat/2_scott_0_1_1.bvh")).skeleton
    driver = VrmDriver(parse_model(build_sample(variant), variant), skel)
    page = driver.page()
    with Browser({**page.routes, "/a.vrma": vrma.read_bytes()}, page.url(160, 120), 160, 120) as b:
        b.wait_for("window.facecapges.ready")
        info = b.evaluate("window.facecapges.loadVrma('/a.vrma')")
        info["errors"] = b.evaluate("window.facecapges.errors")
        info["end"] = b.evaluate(f"window.facecapges.seekVrma({info['duration']}, ['leftHand'], "
                                 "['blink', 'EyeBlinkLeft', 'JawOpen'])")
    return info


@pytest.mark.slow
def test_live_web_shows_a_vrm_and_records_vrma(face_video, tmp_path):
    import cv2

    avatar = tmp_path / "sample.vrm"
    avatar.write_bytes(build_sample("vrm0"))
    rec = tmp_path / "rec"
    proc = cli_popen("live", "--video", str(face_video), "--realtime", "--loop", "--web", "127.0.0.1:0",
                     "--avatar", str(avatar), "--record", str(rec), "--vrma", "--max-seconds", "120")
    try:
        url = viewer_url(proc)
        state, png = open_viewer(url, lambda s: s["ready"] and s["drawn"] >= 10, 640, 480)
        assert state and state["ready"] and state["errors"] == [] and state["drawn"] >= 10, state
        assert state["metaVersion"] == "0" and state["bones"] == 22
        shot = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
        Path("/tmp/facecapges-vrm-viewer.png").write_bytes(png)
        bgr = shot.astype(int)
        red = ((bgr[..., 2] > 180) & (bgr[..., 1] < 80) & (bgr[..., 0] < 80)).sum()
        blue = ((bgr[..., 0] > 180) & (bgr[..., 1] < 80) & (bgr[..., 2] < 80)).sum()
        body = (np.abs(bgr - np.array([0xf3, 0xf0, 0xee])).sum(-1) > 60).mean()
        # the body is drawn; the red/blue hands are counted only as a note: with the default style's
        # arms hanging low they can fall below this 640-wide view's bottom edge
        assert body > 0.02, (red, blue, body)
        # as an OBS browser source: transparent, no HUD, framed from the URL, orbit with the mouse
        check_obs_views(obs_views(url), "vrm")
        proc.send_signal(signal.SIGINT)
        _out, err = proc.communicate(timeout=60)
        assert proc.returncode == 0, err[-2000:]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    from facecapges.io.bvh import read_bvh

    n = read_bvh(rec / "motion.bvh").motion.shape[0]
    doc = _vrma_ok(rec / "motion.vrma")
    times = doc["accessors"][doc["animations"][0]["samplers"][0]["input"]]
    assert times["count"] == n > 10
    assert "preset" in doc["extensions"]["VRMC_vrm_animation"]["expressions"]
    played = _play_vrma(rec / "motion.vrma", "vrm0")
    assert played["errors"] == [] and played["humanoidTracks"] == 52 and played["expressionTracks"] == 13
    assert played["duration"] == pytest.approx((n - 1) / 15, abs=1e-3)


@pytest.mark.slow
def test_generate_writes_vrma_with_the_face(unseen_wav, tmp_path):
    import soundfile as sf

    from facecapges.arkit import ARKIT_NAMES
    from facecapges.avatar.vrm.expressions import PERFECT_SYNC_NAMES
    from facecapges.io.face_json import write_face_json

    audio, sr = sf.read(unseen_wav)
    wav = tmp_path / "a.wav"
    sf.write(wav, audio[: 4 * sr], sr)
    face = tmp_path / "face.json"
    w = np.zeros((120, 52), np.float32)
    w[:, ARKIT_NAMES.index("jawOpen")] = 0.6
    write_face_json(face, w, 30.0)
    out = tmp_path / "g.bvh"
    p = cli("generate", "--audio", str(wav), "--face", str(face), "--out", str(out), "--vrma", str(tmp_path / "g.vrma"),
            "--vrma-face", "perfect-sync")
    assert p.returncode == 0, p.stderr
    doc = _vrma_ok(tmp_path / "g.vrma")
    ext = doc["extensions"]["VRMC_vrm_animation"]
    assert list(ext["expressions"]["custom"]) == list(PERFECT_SYNC_NAMES)
    played = _play_vrma(tmp_path / "g.vrma", "vrm1")  # the sample's perfect-sync clips: "JawOpen" …
    assert played["errors"] == [] and played["humanoidTracks"] == 52 and played["expressionTracks"] == 52
    assert played["end"]["expressions"]["JawOpen"] == pytest.approx(0.6, abs=1e-3)  # the face track's jaw
    p = cli("generate", "--audio", str(wav), "--out", str(tmp_path / "h.bvh"), "--vrma", str(tmp_path / "h.vrma"),
            "--vrma-face", "smiles")
    assert p.returncode == 2 and "--vrma-face" in p.stderr and not (tmp_path / "h.bvh").exists()


@pytest.mark.slow
def test_generate_vrma_without_face_has_the_speech_mouth_and_names_follow_formats(unseen_wav, tmp_path):
    """``generate --vrma`` without ``--face``: the jaw and lips from the speech, as the viewer shows them;
    ``--out x.vrma`` (a BVH under a VRMA name) and ``--vrma x.bvh`` are refused, nothing written."""
    import soundfile as sf

    audio, sr = sf.read(unseen_wav)
    wav = tmp_path / "a.wav"
    sf.write(wav, audio[: 4 * sr], sr)
    p = cli("generate", "--audio", str(wav), "--out", str(tmp_path / "g.bvh"), "--vrma", str(tmp_path / "g.vrma"))
    assert p.returncode == 0, p.stderr
    doc = _vrma_ok(tmp_path / "g.vrma")
    ext = doc["extensions"]["VRMC_vrm_animation"]
    assert {"aa", "oh"} <= set(ext["expressions"]["preset"])
    played = _play_vrma(tmp_path / "g.vrma", "vrm0")
    assert played["errors"] == [] and played["expressionTracks"] == 13
    # the mouth moves with the speech: the "aa" track's own values
    node = ext["expressions"]["preset"]["aa"]["node"]
    anim = doc["animations"][0]
    ch = next(c for c in anim["channels"] if c["target"]["node"] == node)
    acc = doc["accessors"][anim["samplers"][ch["sampler"]]["output"]]
    from facecapges.avatar.vrm.glb import split_glb as _split

    _, blob = _split((tmp_path / "g.vrma").read_bytes())
    view = doc["bufferViews"][acc["bufferView"]]
    xyz = np.frombuffer(blob, np.float32, acc["count"] * 3, view.get("byteOffset", 0) + acc.get("byteOffset", 0))
    aa = xyz.reshape(-1, 3)[:, 0]
    assert aa.max() > 0.2 and (aa < 0.05).mean() > 0.05, (aa.max(), (aa < 0.05).mean())
    for args, msg in ((("--out", str(tmp_path / "t.vrma")), "--vrma t.vrma"),
                      (("--out", str(tmp_path / "t.bvh"), "--vrma", str(tmp_path / "t.bvh2")), "end in .vrma")):
        p = cli("generate", "--audio", str(wav), *args)
        assert p.returncode == 2 and msg in p.stderr and "Traceback" not in p.stderr, p.stderr
    assert not list(tmp_path.glob("t.*"))


@pytest.mark.slow
def test_run_renders_the_vrm(face_video, tmp_path):
    import imageio_ffmpeg

    avatar = tmp_path / "sample.vrm"
    avatar.write_bytes(build_sample("vrm1"))
    out = tmp_path / "run"
    p = cli("run", str(face_video), "--out", str(out), "--avatar", str(avatar), "--max-frames", "15")
    assert p.returncode == 0, p.stderr
    frames = list(imageio_ffmpeg.read_frames(str(out / "avatar.mp4")))[1:]
    assert len(frames) == 15
    rep = json.loads((out / "report.json").read_text())
    assert rep["frames"] == 15


@pytest.mark.slow
def test_study_with_a_vrm_avatar(tmp_path, beat_bvh, beat_wav):
    """``study create --avatar SAMPLE.vrm``: the participant page shows the VRM three times and plays a clip."""
    import cv2

    from _study_media import make_clips
    from facecapges.study.build import open_study
    from facecapges.study.server import make_server, serve_in_thread
    from test_study_browser import Page

    avatar = tmp_path / "sample.vrm"
    avatar.write_bytes(build_sample("vrm0"))
    clips = make_clips(tmp_path / "src", beat_bvh, beat_wav, n_clips=1, seconds=2.0)
    p = cli("study", "create", "--clips", str(clips), "--out", str(tmp_path / "study"), "--participants", "1",
            "--avatar", str(avatar))
    assert p.returncode == 0, p.stderr
    st = open_study(tmp_path / "study")
    motion = json.loads(next((tmp_path / "study" / "media").glob("*/motion-*.json")).read_text())
    assert len(motion["bone_names"]) == 22 and len(motion["quats"]) == motion["frames"] * 22 * 4
    server = make_server(st, "127.0.0.1", 0)
    serve_in_thread(server)
    page = Page(f"http://127.0.0.1:{server.server_address[1]}/")
    try:
        page.start(st.plan.participants[0].token)  # the invitation token
        page.wait("window.study.ready && window.study.index === 0")
        page.click("play")
        page.wait("window.study.watched", timeout=30)
        assert page.js("window.study.error") is None and page.js("window.study.draws") > 5
        shot = tmp_path / "study.png"
        page.screenshot(shot)
        img = cv2.imread(str(shot)).astype(int)
        red = ((img[..., 2] > 180) & (img[..., 1] < 80) & (img[..., 0] < 80)).sum()
        blue = ((img[..., 0] > 180) & (img[..., 1] < 80) & (img[..., 2] < 80)).sum()
        assert red > 20 and blue > 20, (red, blue)
    finally:
        page.close()
        server.shutdown()
        server.server_close()
