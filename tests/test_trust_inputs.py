"""Issue 28, the small trust boundaries: BVH header ranges, deep YAML/JSON, secrets on disk,
Live Link subject names, ``bench`` on a broken shared folder. Each case is bounded (small files
the test writes, loopback only)."""

from __future__ import annotations

import json
import os
import socket
import stat
import time

import numpy as np
import pytest

from facecapges.errors import UserError
from facecapges.io.bvh import read_bvh
from runtime_helpers import cli

BVH = """HIERARCHY
ROOT Hips
{{
  OFFSET 0 0 0
  CHANNELS 3 Zrotation Xrotation Yrotation
  End Site
  {{
    OFFSET 0 1 0
  }}
}}
MOTION
Frames: {frames}
Frame Time: {dt}
0 0 0
1 1 1
2 2 2
"""


@pytest.mark.parametrize("frames, dt, words", [
    ("-5", "0.0666667", "at least one motion frame"),
    ("0", "0.0666667", "at least one motion frame"),
    ("3", "1e-300", "out of range"),
    ("3", "1e300", "out of range"),
    ("3", "0", "out of range"),
    ("3", "-0.1", "out of range"),
])
def test_bvh_header_values_are_range_checked(tmp_path, frames, dt, words):
    p = tmp_path / "h.bvh"
    p.write_text(BVH.format(frames=frames, dt=dt))
    with pytest.raises(UserError, match=words):
        read_bvh(p)


def test_bvh_header_in_range_reads_every_row(tmp_path):
    p = tmp_path / "h.bvh"
    p.write_text(BVH.format(frames=3, dt="0.0083333"))
    b = read_bvh(p)
    assert b.motion.shape == (3, 3) and b.fps == 120.0


def test_cli_refuses_frame_time_without_traceback(tmp_path):
    p = tmp_path / "h.bvh"
    p.write_text(BVH.format(frames=3, dt="1e-300"))
    r = cli("render", "--bvh", str(p), "--out", str(tmp_path / "o.mp4"), timeout=120)
    assert r.returncode != 0 and "Traceback" not in r.stderr and "Frame Time" in r.stderr, r.stderr[-2000:]
    assert not (tmp_path / "o.mp4").exists()


# ------------------------------------------------------------------ deep YAML / JSON
def test_deep_clips_yaml_is_a_user_error(tmp_path):
    from facecapges.study.clips import parse_clips

    p = tmp_path / "CLIPS.yaml"
    p.write_text("clips: " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(UserError, match="nested too deeply"):
        parse_clips(p)


@pytest.mark.parametrize("text", ["[" * 100_000, '{"format": ' + "[" * 100_000 + "]" * 100_000 + "}",
                                  "[1, 2]", '{"format": "facecapges-study/1", "plan": []}'])
def test_deep_or_wrong_study_json_is_a_user_error(tmp_path, text):
    from facecapges.study.build import open_study

    (tmp_path / "study.json").write_text(text)
    with pytest.raises(UserError, match="not a valid study file"):
        open_study(tmp_path)


def test_study_server_on_deep_study_json_exits_cleanly(tmp_path):
    (tmp_path / "study.json").write_text("[" * 100_000)
    r = cli("study", "serve", str(tmp_path), "--port", "0", timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr and "not a valid study file" in r.stderr, r.stderr


# ------------------------------------------------------------------ secrets on disk
def test_study_secrets_are_written_0600(tmp_path, beat_bvh, beat_wav):
    from _study_media import make_clips
    from facecapges.study.build import INVITATIONS_FILE, STUDY_FILE, create_study, ensure_tokens, open_study

    old = os.umask(0o022)
    try:
        y = make_clips(tmp_path / "src", beat_bvh, beat_wav, n_clips=2, seconds=1.0)
        create_study(y, tmp_path / "study", 2, seed=1, progress=False)
        for f in (STUDY_FILE, INVITATIONS_FILE):
            assert stat.S_IMODE((tmp_path / "study" / f).stat().st_mode) == 0o600, f
        st = open_study(tmp_path / "study")
        st.plan.participants[0].token = ""
        assert ensure_tokens(st) == 1  # rewrites study.json: still 0600
        assert stat.S_IMODE((tmp_path / "study" / STUDY_FILE).stat().st_mode) == 0o600
        assert not list((tmp_path / "study").glob("*.part"))
    finally:
        os.umask(old)


# ------------------------------------------------------------------ Live Link subject names
def test_livelink_receiver_keeps_a_bounded_set_of_subject_names():
    from facecapges.runtime.inputs.livelink import MAX_SUBJECTS, N_VALUES, LiveLinkReceiver, encode_packet

    rx = LiveLinkReceiver(port=0)
    try:
        values = np.full(N_VALUES, 0.1, np.float32)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for i in range(600):
                s.sendto(encode_packet(values, subject=f"subject-{i:04d}-" + "x" * 200), rx.address)
                if i % 50 == 49:
                    time.sleep(0.01)
        deadline = time.time() + 10
        while time.time() < deadline and rx.stats()["packets"] + rx.stats()["bad_packets"] < 600:
            time.sleep(0.05)
        assert rx.stats()["packets"] >= 500  # loopback: nearly all arrive
        assert len(rx.subjects) == MAX_SUBJECTS and rx.other_subjects >= 500 - MAX_SUBJECTS
        assert rx.latest()[1] is not None
    finally:
        rx.close()


# ------------------------------------------------------------------ bench on a broken shared folder
@pytest.mark.parametrize("layout", ["empty", "broken"])
def test_bench_on_a_bad_shared_folder_is_one_line(tmp_path, layout):
    shared = tmp_path / "shared"
    (shared / "data" / "beat").mkdir(parents=True)
    if layout == "broken":
        (shared / "data" / "beat" / "2_scott_0_1_1.bvh").write_text("HIERARCHY\nnot a bvh\n")
        (shared / "data" / "beat" / "2_scott_0_1_1.wav").write_bytes(b"RIFF\0\0\0\0WAVE")
    r = cli("bench", "--json", "--only", "data", "--shared", str(shared), timeout=300)
    assert r.returncode != 0 and "Traceback" not in r.stderr, r.stderr[-3000:]
    if layout == "empty":
        assert r.returncode == 2 and "not the shared data folder" in r.stderr
    else:
        assert "data FAILED" in r.stderr and json.loads(r.stdout)["data"]["error"]
