"""``facecapges prepare`` / ``export`` through the real command line: the stated figures and bad input."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from facecapges.io.bvh import read_bvh, write_bvh
from facecapges.skeleton import joint_positions
from runtime_helpers import cli


def run(*args: str):
    return cli(*map(str, args))


def assert_one_line_error(res: subprocess.CompletedProcess, *fragments: str) -> None:
    assert res.returncode != 0
    assert "Traceback" not in res.stderr and "Traceback" not in res.stdout
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith("error: ")
    for f in fragments:
        assert f in lines[0], (f, lines[0])


@pytest.fixture
def beat_tree(tmp_path, beat_bvh, beat_wav):
    """A BEAT folder with the real sample linked in (shared data is never copied)."""
    root = tmp_path / "beat"
    root.mkdir()
    (root / beat_bvh.name).symlink_to(beat_bvh)
    (root / beat_wav.name).symlink_to(beat_wav)
    return root


def test_prepare_and_export_shared_sample(tmp_path, beat_bvh):
    root = beat_bvh.parent
    res = run("prepare", root, "--out", tmp_path / "c", "--speakers", "2", "--quiet")
    assert res.returncode == 0, res.stderr
    # the folder's other speech clips (no .bvh) are counted, however many there are
    n_audio_only = sum(1 for w in root.glob("2_*.wav") if not w.with_suffix(".bvh").exists())
    assert n_audio_only >= 1
    assert f"1 clip, 957 frames, 63.8 s, {n_audio_only} audio only" in res.stdout
    res = run("export", tmp_path / "c", "--clip", "2_scott_0_1_1", "--out", tmp_path / "e.bvh")
    assert res.returncode == 0, res.stderr
    a, b = read_bvh(beat_bvh), read_bvh(tmp_path / "e.bvh")
    assert b.fps == 15 and b.skeleton.n_joints == 75
    assert "Frame Time: 0.0666667" in (tmp_path / "e.bvh").read_text()[:20000]
    err = np.abs(joint_positions(b.skeleton, b.motion) - joint_positions(a.skeleton, a.motion)).max()
    assert err < 0.01  # cm
    # export refuses to overwrite, and names what is wrong
    assert_one_line_error(run("export", tmp_path / "c", "--clip", "2_scott_0_1_1", "--out", tmp_path / "e.bvh"),
                          "e.bvh", "--force")
    assert_one_line_error(run("export", tmp_path / "c", "--clip", "9_nobody_0_1_1", "--out", tmp_path / "x.bvh"),
                          "no clip '9_nobody_0_1_1'")
    assert_one_line_error(run("export", tmp_path / "nocache", "--clip", "2_scott_0_1_1", "--out", tmp_path / "x.bvh"),
                          "nocache", "cache folder not found")


def test_missing_folder(tmp_path):
    assert_one_line_error(run("prepare", tmp_path / "nowhere", "--out", tmp_path / "c"), "nowhere", "not found")


def test_empty_folder(tmp_path):
    (tmp_path / "empty").mkdir()
    assert_one_line_error(run("prepare", tmp_path / "empty", "--out", tmp_path / "c"), "empty", "no BEAT files")


def test_truncated_bvh(tmp_path, beat_bvh, beat_wav):
    root = tmp_path / "beat"
    root.mkdir()
    text = beat_bvh.read_text()
    (root / beat_bvh.name).write_text(text[: int(len(text) * 0.6)])
    (root / beat_wav.name).symlink_to(beat_wav)
    assert_one_line_error(run("prepare", root, "--out", tmp_path / "c"), "2_scott_0_1_1.bvh", "truncated BVH")
    assert not (tmp_path / "c").exists()


def test_truncated_wav(tmp_path, beat_bvh, beat_wav):
    root = tmp_path / "beat"
    root.mkdir()
    (root / beat_bvh.name).symlink_to(beat_bvh)
    data = beat_wav.read_bytes()
    (root / beat_wav.name).write_bytes(data[: len(data) // 2])
    assert_one_line_error(run("prepare", root, "--out", tmp_path / "c"), "2_scott_0_1_1.wav", "truncated WAV")


def test_malformed_face_json(tmp_path, beat_tree):
    (beat_tree / "2_scott_0_1_1.json").write_text('{"names": ["jawOpen"], "frames": [{"time": 0, ')
    assert_one_line_error(run("prepare", beat_tree, "--out", tmp_path / "c"), "2_scott_0_1_1.json", "malformed JSON")


def test_wrong_skeleton(tmp_path, beat_bvh, beat_wav):
    root = tmp_path / "beat"
    root.mkdir()
    bvh = read_bvh(beat_bvh)
    path = write_bvh(root / beat_bvh.name, bvh.skeleton, bvh.motion[:20], bvh.fps)
    path.write_text(path.read_text().replace("JOINT RightHand\n", "JOINT RightPalm\n"))
    (root / beat_wav.name).symlink_to(beat_wav)
    assert_one_line_error(run("prepare", root, "--out", tmp_path / "c"), "2_scott_0_1_1.bvh", "wrong skeleton",
                          "RightHand")


def test_existing_cache_needs_force(tmp_path, beat_tree):
    assert run("prepare", beat_tree, "--out", tmp_path / "c", "--quiet").returncode == 0
    assert_one_line_error(run("prepare", beat_tree, "--out", tmp_path / "c"), "already exists", "--force")
    res = run("prepare", beat_tree, "--out", tmp_path / "c", "--force", "--quiet")
    assert res.returncode == 0, res.stderr


def test_bad_speakers_option(tmp_path, beat_tree):
    assert_one_line_error(run("prepare", beat_tree, "--out", tmp_path / "c", "--speakers", "two"), "--speakers")
    assert_one_line_error(run("prepare", beat_tree, "--out", tmp_path / "c", "--speakers", "4"), "speaker(s) [4]")
