"""CLIPS.yaml checks and ``study create`` on material cut from the real BEAT clip; bad input → one clear line."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest
import yaml

from _study_media import SYSTEMS, make_clips
from facecapges.errors import UserError
from facecapges.io.bvh import read_bvh, write_bvh
from facecapges.io.face_json import read_face_json
from facecapges.rotations import quaternion_to_matrix
from facecapges.skeleton import local_matrices, motion_to_euler
from facecapges.study.build import create_study, open_study
from facecapges.study.clips import load_clips
from runtime_helpers import cli


def run(*args):
    return cli(*map(str, args))


def one_line_error(res: subprocess.CompletedProcess, *fragments: str) -> str:
    assert res.returncode == 2, res.stdout + res.stderr
    assert "Traceback" not in res.stderr + res.stdout
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    for f in fragments:
        assert f in lines[0], (f, lines[0])
    return lines[0]


@pytest.fixture
def clips_yaml(tmp_path, beat_bvh, beat_wav):
    return make_clips(tmp_path / "src", beat_bvh, beat_wav, n_clips=2, seconds=2.0)


def edit(path, fn):
    doc = yaml.safe_load(path.read_text())
    fn(doc)
    path.write_text(yaml.safe_dump(doc, sort_keys=False))


def test_load_clips_reads_everything(clips_yaml):
    cs, motions, faces = load_clips(clips_yaml)
    assert cs.systems == list(SYSTEMS) and cs.clip_ids == ["clip1", "clip2"] and cs.fps == 15
    assert all(abs(c.duration - 2.0) < 1e-9 for c in cs.clips)
    assert motions["clip1"]["shift_4s"].n_frames == 30
    assert faces["clip2"].fps == 30


def test_create_writes_playable_poses(tmp_path, clips_yaml, beat_bvh):
    summary = create_study(clips_yaml, tmp_path / "study", 4, seed=1, progress=False)
    assert summary["participants"] == 4 and summary["balance"]["serial_position_spread"] == 0
    st = open_study(tmp_path / "study")
    assert (st.dir / "avatar.glb").stat().st_size > 100_000
    doc = json.loads((st.dir / "media" / "clip2" / "motion-shift_9s.json").read_text())
    src = read_bvh(clips_yaml.parent / "media" / "clip2-shift_9s.bvh")
    assert doc["frames"] == 30 and doc["joint_names"] == list(src.skeleton.names)
    q = np.asarray(doc["quats"]).reshape(30, len(src.skeleton.names), 4)
    # the quaternions are the BVH's local rotations (w, x, y, z)
    _, euler = motion_to_euler(src.skeleton, src.motion)
    want = local_matrices(src.skeleton, euler)
    assert np.abs(quaternion_to_matrix(q) - want).max() < 2e-3
    face = json.loads((st.dir / "media" / "clip1" / "face.json").read_text())
    track = read_face_json(clips_yaml.parent / "media" / "clip1.json")
    w = np.asarray(face["weights"]).reshape(30, 52)
    assert np.abs(w - track.weights[::2]).max() < 1e-3  # 30 fps face track played at 15 fps
    import soundfile as sf

    info = sf.info(str(st.dir / "media" / "clip1" / "audio.wav"))
    assert info.samplerate == 16000 and info.frames == 32000


def test_missing_bvh_for_a_clip_and_system(clips_yaml):
    edit(clips_yaml, lambda d: d["clips"][1]["bvh"].pop("shift_4s"))
    with pytest.raises(UserError, match=r"clip 'clip2' has no BVH for system 'shift_4s'"):
        load_clips(clips_yaml)


def test_missing_bvh_file(clips_yaml):
    (clips_yaml.parent / "media" / "clip1-shift_9s.bvh").unlink()
    with pytest.raises(UserError, match=r"BVH of clip 'clip1', system 'shift_9s' not found"):
        load_clips(clips_yaml)


def test_unknown_system(clips_yaml):
    edit(clips_yaml, lambda d: d["clips"][0]["bvh"].update(extra=d["clips"][0]["bvh"]["shift_4s"]))
    with pytest.raises(UserError, match=r"clip 'clip1' has a BVH for system 'extra'"):
        load_clips(clips_yaml)


@pytest.mark.parametrize("cut,ok", [(1, True), (2, False), (-2, False)])
def test_clips_of_different_lengths(clips_yaml, cut, ok):
    p = clips_yaml.parent / "media" / "clip2-shift_4s.bvh"
    b = read_bvh(p)
    motion = b.motion[:-cut] if cut > 0 else np.concatenate([b.motion, b.motion[:-cut]])
    write_bvh(p, b.skeleton, motion, b.fps)
    if ok:
        load_clips(clips_yaml)  # within one frame
        return
    with pytest.raises(UserError, match=r"clip 'clip2', system 'shift_4s'.*must be as long as its audio"):
        load_clips(clips_yaml)


def test_bvh_at_another_rate_is_checked_at_its_own_rate(clips_yaml, tmp_path):
    p = clips_yaml.parent / "media" / "clip1-ground_truth.bvh"
    b = read_bvh(p)
    write_bvh(p, b.skeleton, np.repeat(b.motion, 2, axis=0), 30.0)  # same 2 s at 30 fps
    load_clips(clips_yaml)
    create_study(clips_yaml, tmp_path / "study", 2, progress=False)
    doc = json.loads((tmp_path / "study" / "media" / "clip1" / "motion-ground_truth.json").read_text())
    assert doc["frames"] == 30
    write_bvh(p, b.skeleton, b.motion, 30.0)  # now 1 s at 30 fps: too short
    with pytest.raises(UserError, match="clip 'clip1', system 'ground_truth'"):
        load_clips(clips_yaml)


def test_face_track_of_another_length(clips_yaml):
    p = clips_yaml.parent / "media" / "clip1.json"
    doc = json.loads(p.read_text())
    doc["frames"] = doc["frames"][:45]
    p.write_text(json.dumps(doc))
    with pytest.raises(UserError, match=r"clip 'clip1': the face track .* lasts 1.500 s but the audio 2.000 s"):
        load_clips(clips_yaml)


def test_other_skeleton(clips_yaml):
    p = clips_yaml.parent / "media" / "clip2-ground_truth.bvh"
    p.write_text("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xrotation Yrotation Zrotation\n End Site\n {\n"
                 "  OFFSET 0 1 0\n }\n}\nMOTION\nFrames: 30\nFrame Time: 0.0666667\n" + "0 0 0\n" * 30)
    with pytest.raises(UserError, match=r"clip 'clip2', system 'ground_truth'.*not a BEAT skeleton"):
        load_clips(clips_yaml)


def test_cli_bad_inputs(tmp_path, clips_yaml):
    bad = tmp_path / "bad.yaml"
    bad.write_text("clips: [\n")
    one_line_error(run("study", "create", "--clips", bad, "--out", tmp_path / "s"), "bad.yaml", "malformed YAML")
    bad.write_text("systems: [a]\nclips: [{id: x, audio: a.wav, bvh: {a: a.bvh}}]\n")
    one_line_error(run("study", "create", "--clips", bad, "--out", tmp_path / "s"), "at least two systems")
    one_line_error(run("study", "create", "--clips", tmp_path / "nope.yaml", "--out", tmp_path / "s"),
                   "nope.yaml", "not found")
    edit(clips_yaml, lambda d: d["clips"][0]["bvh"].pop("ground_truth"))
    one_line_error(run("study", "create", "--clips", clips_yaml, "--out", tmp_path / "s"),
                   "clip 'clip1' has no BVH for system 'ground_truth'")
    one_line_error(run("study", "serve", tmp_path / "s"), "not a study folder")
    one_line_error(run("study", "analyze", tmp_path / "s", "--out", tmp_path / "r"), "not a study folder")


def test_cli_create_refuses_to_overwrite(tmp_path, clips_yaml):
    out = tmp_path / "study"
    res = run("study", "create", "--clips", clips_yaml, "--out", out, "--participants", "3", "--seed", "5")
    assert res.returncode == 0, res.stderr
    assert "2 clips × 3 systems" in res.stdout and "3 participants" in res.stdout
    one_line_error(run("study", "create", "--clips", clips_yaml, "--out", out), "already exists", "--force")
    create_study(clips_yaml, out, 2, force=True, progress=False)  # --force, in process (saves a torch import)
    assert len(open_study(out).plan.participants) == 2
    (out / "responses" / "P01.json").write_text('{"participant": "P01", "history": []}')
    one_line_error(run("study", "create", "--clips", clips_yaml, "--out", out, "--force"),
                   "answers of 1 participant")
    one_line_error(run("study", "analyze", out, "--out", tmp_path / "r"), "no answers yet")
