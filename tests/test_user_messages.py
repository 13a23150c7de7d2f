"""Quiet surprises made loud: what a command chose, and what it will not do, is said (issue 33, item 6)."""

from __future__ import annotations

import urllib.request

import numpy as np

from conftest import shared_file
from facecapges.io.face_json import write_face_json
from runtime_helpers import cli


def test_avatar_vrma_warns_of_a_face_track_of_another_length(tmp_path):
    """A 64-s motion with an 8-s face track: converted, with a warning that says how long each is."""
    face = tmp_path / "face.json"
    write_face_json(face, np.zeros((120, 52), np.float32), 15.0)  # 8 s
    p = cli("avatar", "vrma", "--bvh", str(shared_file("data/beat/2_scott_0_1_1.bvh")), "--face", str(face),
            "--out", str(tmp_path / "m.vrma"))
    assert p.returncode == 0, p.stderr[-2000:]
    assert "warning:" in p.stderr and "8.0 s" in p.stderr and "63.8 s" in p.stderr, p.stderr
    p = cli("avatar", "vrma", "--bvh", str(shared_file("data/beat/2_scott_0_1_1.bvh")), "--out",
            str(tmp_path / "n.vrma"))
    assert p.returncode == 0 and "warning" not in p.stderr, p.stderr


def test_an_unknown_option_suggests_only_near_names():
    """`generate --max-frames` is not offered --vrma-face: it is told which commands have --max-frames; a real
    typo still gets its suggestion."""
    p = cli("generate", "--audio", "a.wav", "--out", "x.bvh", "--max-frames", "5")
    assert p.returncode == 2 and "--vrma-face" not in p.stderr, p.stderr
    assert "run" in p.stderr and "option of" in p.stderr, p.stderr
    p = cli("generate", "--audio", "a.wav", "--out", "x.bvh", "--intensty", "1")
    assert p.returncode == 2 and "--intensity" in p.stderr, p.stderr


def test_gltf_viewer_serves_every_file_its_page_asks_for():
    """The glTF viewer's page asks /vrm/layout.json which scene to draw: our server answers null (200), not 404;
    the pages name an inline icon, so browsers do not ask for /favicon.ico."""
    from facecapges.avatar.render.browser import web_dir
    from facecapges.runtime.outputs.viewer import ViewerServer

    s = ViewerServer(b"glTF", "127.0.0.1", 0).start()
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{s.bound[1]}/vrm/layout.json", timeout=10) as r:
            assert r.status == 200 and r.read() == b"null"
    finally:
        s.close()
    for page in ("viewer.html", "render.html"):
        assert '<link rel="icon" href="data:,">' in (web_dir() / page).read_text()


def test_train_on_the_shared_take_says_where_its_clip_is(beat_cache, tmp_path):
    """`train --cache … --speaker 2` as the full-BEAT docs write it, on ../shared's cache (its one take is in
    BEAT's test split): the error says where the clip is and the options that train on it."""
    p = cli("train", "--cache", str(beat_cache), "--speaker", "2", "--out", str(tmp_path / "runs" / "scott"))
    assert p.returncode == 2 and p.stderr.startswith("error:"), p.stderr
    assert "in 'test'" in p.stderr and "--split all" in p.stderr and "--holdout-from 765" in p.stderr, p.stderr
    assert not (tmp_path / "runs").exists()


def test_an_avatar_without_a_face_gets_no_empty_close_up(beat_take):
    """`run --avatar` with a humanoid GLB that has no expressions: its description says the face is none, and
    avatar.mp4 gets no face close-up (an empty one before); a VRM with expressions keeps it."""
    from facecapges.avatar.vrm.read import parse_model
    from facecapges.avatar.vrm.view import VrmDriver
    from facecapges.runtime.run import shows_face_inset
    from vrm_samples import build_sample

    bare = VrmDriver(parse_model(build_sample("glb"), "bare.glb"), beat_take.skeleton)
    assert not bare.faces.names and "face: none" in bare.describe() and not shows_face_inset(bare)
    vrm = VrmDriver(parse_model(build_sample("vrm1"), "a.vrm"), beat_take.skeleton)
    assert vrm.faces.names and shows_face_inset(vrm) and shows_face_inset(None)
