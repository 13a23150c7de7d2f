"""``prepare`` on the real BEAT sample (and on small BEAT trees the tests build), the cache API, export."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from facecapges.data.cache import Cache
from facecapges.data.prepare import prepare, summary_rows
from facecapges.errors import UserError
from facecapges.io.audio import load_audio
from facecapges.io.bvh import read_bvh, write_bvh
from facecapges.skeleton import N_JOINTS, joint_positions, motion_to_pose, pose_to_motion

CLIP = "2_scott_0_1_1"


@pytest.fixture(scope="module")
def sample_cache(tmp_path_factory):
    from conftest import shared_file

    root = shared_file("data/beat/2_scott_0_1_1.bvh").parent
    out = tmp_path_factory.mktemp("cache") / "c"
    index = prepare(root, out, speakers=[2], progress=False)
    return out, index


@pytest.fixture(scope="module")
def sample_bvh():
    from conftest import shared_file

    return read_bvh(shared_file("data/beat/2_scott_0_1_1.bvh"))


def link_clip(dst_dir, name, bvh=None, wav=None):
    """Symlink shared files into a tmp BEAT tree under a new clip name (shared data is never copied)."""
    dst_dir.mkdir(parents=True, exist_ok=True)
    if bvh is not None:
        (dst_dir / f"{name}.bvh").symlink_to(bvh)
    if wav is not None:
        (dst_dir / f"{name}.wav").symlink_to(wav)


def test_sample_summary(sample_cache):
    _, index = sample_cache
    assert [c["name"] for c in index["clips"]] == [CLIP]
    c = index["clips"][0]
    assert (c["speaker"], c["split"], c["n_frames"]) == (2, "test", 957)
    assert c["duration_s"] == pytest.approx(63.8)
    assert not (c["has_face"] or c["has_semantic"] or c["has_emotion"])
    assert summary_rows(index)[-1] == ("total", "", 1, 957, pytest.approx(63.8))
    # every speech clip of the folder without motion is listed, however many the folder holds
    root = Path(index["source"])
    audio_only = sorted(w.stem for w in root.glob("2_*.wav") if not w.with_suffix(".bvh").exists())
    assert "2_scott_0_2_2" in audio_only
    assert [(s["name"], s["reason"]) for s in index["skipped"]] == [(n, "audio only") for n in audio_only]


def test_cache_arrays(sample_cache, sample_bvh, beat_wav):
    out, _ = sample_cache
    cache = Cache(out)
    assert len(cache) == 1 and cache.fps == 15 and cache.sr == 16000 and cache.speakers == [2]
    assert [c["name"] for c in cache.clips(speaker=2, split="test")] == [CLIP]
    assert cache.clips(split="train") == [] and cache.clips(speaker=4) == []
    d = cache.load(CLIP)
    pose, head = motion_to_pose(sample_bvh.skeleton, sample_bvh.motion)
    assert d["pose"].shape == (957, N_JOINTS, 6) and d["pose"].dtype == np.float32
    np.testing.assert_array_equal(d["pose"], pose)
    np.testing.assert_array_equal(d["head"], head)
    assert d["face"].shape == (957, 52) and not d["face"].any() and d["face_present"] is False
    assert d["semantic"].shape == (957,) and d["semantic_present"] is False
    assert d["emotion"].shape == (957,) and d["emotion"].dtype == np.int16 and d["emotion_present"] is False
    S = math.floor(957 * 16000 / 15)
    assert d["audio"].shape == (S,) and d["audio"].dtype == np.float32
    np.testing.assert_array_equal(d["audio"], load_audio(beat_wav)[:S])  # the true samples, cut at T
    # the skeleton header is complete: the full 75-joint hierarchy
    skel = cache.skeleton(CLIP)
    assert skel.is_same_tree(sample_bvh.skeleton) and skel.channels == sample_bvh.skeleton.channels
    np.testing.assert_allclose(skel.offsets, sample_bvh.skeleton.offsets)
    assert skel.end_sites.keys() == sample_bvh.skeleton.end_sites.keys()


def test_stats(sample_cache):
    out, index = sample_cache
    cache = Cache(out)
    d = cache.load(CLIP)
    s = cache.stats(2)
    # the only clip is a test clip: the statistics fall back to all clips and say so
    assert "no train clip" in index["stats"]["2"]["source"]
    np.testing.assert_allclose(s["pose_mean"], d["pose"].mean(0), atol=1e-5)
    np.testing.assert_allclose(s["pose_std"], np.maximum(d["pose"].std(0), 1e-3), atol=1e-4)
    np.testing.assert_allclose(s["head_mean"], d["head"].mean(0), atol=1e-5)
    assert np.all(s["face_mean"] == 0) and np.all(s["face_std"] == 1)  # no face data at all
    assert set(cache.stats(None)) == set(s)
    with pytest.raises(UserError, match="no statistics for speaker 4"):
        cache.stats(4)


def test_export_matches_original_positions(sample_cache, sample_bvh, tmp_path):
    out, _ = sample_cache
    cache = Cache(out)
    skel = cache.skeleton(CLIP)
    path = write_bvh(tmp_path / "e.bvh", skel, pose_to_motion(skel, cache.load(CLIP)["pose"]), cache.fps)
    again = read_bvh(path)
    assert again.fps == 15 and again.n_frames == 957 and again.skeleton.n_joints == 75
    err = np.abs(joint_positions(again.skeleton, again.motion) - joint_positions(sample_bvh.skeleton, sample_bvh.motion))
    assert err.max() < 0.01  # centimetres


def test_120fps_bvh_prepares_to_the_same_15fps_pose(tmp_path, sample_bvh, beat_wav):
    n = 120
    motion15 = sample_bvh.motion[:n]
    motion120 = np.repeat(motion15, 8, axis=0)  # each 15 fps frame held for 8 frames at 120 fps
    root = tmp_path / "beat"
    root.mkdir()
    path = write_bvh(root / "2_scott_0_9_9.bvh", sample_bvh.skeleton, motion120, 120.0)
    text = path.read_text().replace("Frame Time: 0.0083333", "Frame Time: 0.008333")
    path.write_text(text)
    assert read_bvh(path).fps == 120.0
    import soundfile as sf

    audio, sr = sf.read(beat_wav, dtype="float32")  # the speech of the 8 s of motion (issue 34: 64 s is refused)
    sf.write(root / "2_scott_0_9_9.wav", audio[: n * sr // 15], sr)
    index = prepare(root, tmp_path / "c", progress=False)
    c = index["clips"][0]
    assert c["n_frames"] == n and c["split"] == "train" and c["source_fps"] == 120.0
    d = Cache(tmp_path / "c").load("2_scott_0_9_9")
    pose, head = motion_to_pose(sample_bvh.skeleton, motion15)
    np.testing.assert_allclose(d["pose"], pose, atol=1e-6)
    np.testing.assert_allclose(d["head"], head, atol=1e-6)
    assert len(d["audio"]) == math.floor(n * 16000 / 15)


def test_side_files_are_resampled_to_the_motion_frames(tmp_path, beat_bvh, beat_wav):
    root = tmp_path / "beat"
    link_clip(root, "2_scott_0_10_10", beat_bvh, beat_wav)  # a train clip
    link_clip(root, "2_scott_0_60_60", beat_bvh, beat_wav)  # a val clip
    n60 = 400  # fewer face frames than motion frames × 4: the face is padded with its last frame
    names = ["jawOpen", "eyeBlinkLeft"]
    frames = [{"time": round(k / 60, 6), "weights": [k / 1000, 0.5]} for k in range(n60)]
    (root / "2_scott_0_10_10.json").write_text(json.dumps({"names": names, "frames": frames}))
    (root / "2_scott_0_10_10.txt").write_text("beat\t1.0\t2.0\t1.0\t0.9\tword\n")
    (root / "2_scott_0_10_10.csv").write_text("time,label\n0,0\n30,happiness\n")
    index = prepare(root, tmp_path / "c", fps=15, progress=False)
    cache = Cache(tmp_path / "c")
    assert [c["split"] for c in cache.clips()] == ["train", "val"]
    d = cache.load("2_scott_0_10_10")
    assert d["face_present"] and d["semantic_present"] and d["emotion_present"]
    jaw = d["face"][:, 24]  # ARKIT_NAMES index of jawOpen
    np.testing.assert_allclose(jaw[:100], np.arange(100) * 4 / 1000, atol=1e-6)  # 60 → 15: every 4th frame
    np.testing.assert_allclose(jaw[100:], (n60 - 4) / 1000, atol=1e-6)
    assert np.all(d["face"][:, 8] == 0.5)  # eyeBlinkLeft
    t = np.arange(957) / 15
    np.testing.assert_allclose(d["semantic"], np.where((t >= 1.0) & (t <= 2.0), 0.9, 0.0), atol=1e-6)
    np.testing.assert_array_equal(d["emotion"], np.where(t >= 30, 1, 0))
    v = cache.load("2_scott_0_60_60")
    assert not v["face_present"] and not v["face"].any()
    # stats of speaker 2 use only its train clip: the face statistics come from the train clip's face
    s = cache.stats(2)
    assert index["stats"]["2"]["source"] == "train clips of speaker 2"
    np.testing.assert_allclose(s["face_mean"], d["face"].mean(0), atol=1e-5)
    np.testing.assert_allclose(s["pose_mean"], d["pose"].mean(0), atol=1e-5)


def test_prepare_errors(tmp_path, beat_bvh, beat_wav, sample_bvh):
    with pytest.raises(UserError, match="no BEAT files"):
        prepare(tmp_path, tmp_path / "c", progress=False)
    root = tmp_path / "beat"
    link_clip(root, "2_scott_0_10_10", beat_bvh, beat_wav)
    with pytest.raises(UserError, match=r"no clips of speaker\(s\) \[4\]"):
        prepare(root, tmp_path / "c", speakers=[4], progress=False)
    prepare(root, tmp_path / "c", progress=False)
    with pytest.raises(UserError, match="already exists; pass --force"):
        prepare(root, tmp_path / "c", progress=False)
    prepare(root, tmp_path / "c", force=True, progress=False)  # replaced
    assert Cache(tmp_path / "c").clips()[0]["name"] == "2_scott_0_10_10"
    other = tmp_path / "mine"
    other.mkdir()
    (other / "precious.txt").write_text("keep me")
    with pytest.raises(UserError, match="not a facecapges cache"):
        prepare(root, other, force=True, progress=False)
    assert (other / "precious.txt").read_text() == "keep me"
    # a second performer whose skeleton lacks a joint
    skel = sample_bvh.skeleton
    bad = root / "4_lawrence_0_10_10.bvh"
    write_bvh(bad, skel, sample_bvh.motion[:30], 15)
    bad.write_text(bad.read_text().replace("JOINT RightHand\n", "JOINT RightPaw\n"))
    link_clip(root, "4_lawrence_0_10_10", wav=beat_wav)
    with pytest.raises(UserError, match=r"4_lawrence_0_10_10\.bvh: wrong skeleton: missing 1 .*RightHand"):
        prepare(root, tmp_path / "c2", progress=False)
    assert not (tmp_path / "c2").exists() and not list(tmp_path.glob(".c2.part"))


def test_cache_errors(tmp_path, sample_cache):
    with pytest.raises(UserError, match="cache folder not found"):
        Cache(tmp_path / "none")
    with pytest.raises(UserError, match="not a facecapges cache"):
        Cache(tmp_path)
    with pytest.raises(UserError, match="no clip 'nope'"):
        Cache(sample_cache[0]).load("nope")
