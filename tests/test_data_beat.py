"""BEAT clip names, the split rule, clip discovery, semantic .txt and emotion .csv readers."""

from __future__ import annotations

import numpy as np
import pytest

from facecapges.data import beat
from facecapges.errors import UserError


def test_parse_clip_name():
    c = beat.parse_clip_name("2_scott_0_1_1")
    assert (c.speaker, c.performer, c.type, c.start, c.end) == (2, "scott", 0, 1, 1)
    assert c.kind == "speech" and c.clip_number == 1 and c.stem == "2_scott_0_1_1"
    conv = beat.parse_clip_name("10_kieks_1_12_12")
    assert conv.kind == "conversation" and conv.speaker == 10 and conv.clip_number == 12
    assert beat.parse_clip_name("2_scott_0_1") is None
    assert beat.parse_clip_name("bvh_mean") is None
    assert beat.parse_clip_name("scott_2_0_1_1") is None


def split(name: str) -> str:
    return beat.split_of(beat.parse_clip_name(name))


def test_split_rule():
    test_speech = list(range(1, 9)) + [65, 73, 81, 87, 95, 103, 111]
    val_speech = list(range(57, 65)) + [72, 80, 86, 94, 102, 110, 118]
    for n in range(1, 119):
        expected = "test" if n in test_speech else "val" if n in val_speech else "train"
        assert split(f"4_lawrence_0_{n}_{n}") == expected, n
    assert split("2_scott_1_1_1") == "test"
    assert split("2_scott_1_12_12") == "val"
    for n in (2, 3, 8, 11, 13):
        assert split(f"2_scott_1_{n}_{n}") == "train"
    assert split("2_scott_0_1_1") == "test"  # the shared sample is a test clip
    assert split("2_scott_0_9_9") == "train" and split("2_scott_0_56_56") == "train"


def test_emotion_from_clip_number():
    def emo(n):
        return beat.emotion_from_clip_number(beat.parse_clip_name(f"2_scott_0_{n}_{n}"))

    assert [emo(n) for n in (1, 64, 65, 72, 73, 81, 87, 95, 103, 111, 118)] == [0, 0, 1, 1, 2, 3, 4, 5, 6, 7, 7]
    assert beat.emotion_from_clip_number(beat.parse_clip_name("2_scott_1_1_1")) is None
    # every single test/val speech clip past 64 is the first/last clip of an emotion block
    starts = {lo for lo, _ in beat.SPEECH_EMOTION_BLOCKS[1:]}
    ends = {hi for _, hi in beat.SPEECH_EMOTION_BLOCKS[1:]}
    assert set(beat.TEST_SPEECH) - set(range(1, 9)) == starts
    assert set(beat.VAL_SPEECH) - set(range(57, 65)) == ends


def test_find_clips_groups_files_recursively(tmp_path):
    for rel in ["2/2_scott_0_1_1.bvh", "2/2_scott_0_1_1.wav", "2/sem/2_scott_0_1_1.txt",
                "4/4_lawrence_1_3_3.wav", "4/4_lawrence_1_3_3.json", "notes.txt", "2/2_scott_0_1_1.png"]:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("x")
    clips = beat.find_clips(tmp_path)
    assert [c.name for c in clips] == ["2_scott_0_1_1", "4_lawrence_1_3_3"]
    assert set(clips[0].files) == {"bvh", "wav", "txt"} and set(clips[1].files) == {"wav", "json"}
    (tmp_path / "copy").mkdir()
    (tmp_path / "copy" / "2_scott_0_1_1.bvh").write_text("x")
    with pytest.raises(UserError, match="two bvh files"):
        beat.find_clips(tmp_path)


def test_find_clips_errors(tmp_path):
    with pytest.raises(UserError, match="not found"):
        beat.find_clips(tmp_path / "nope")
    with pytest.raises(UserError, match="no BEAT files"):
        beat.require_beat_clips(tmp_path)


# ------------------------------------------------------------------- semantic
def test_semantic_max_of_overlapping_segments(tmp_path):
    p = tmp_path / "s.txt"
    p.write_text("\n".join([
        "name\tstart\tend\tduration\tscore\tkeywords",  # header line
        "beat_align\t0.0\t1.0\t1.0\t0.1\tso",
        "deictic_r\t0.5\t0.8\t0.3\t0.7\tthis one",
        "metaphoric\t2.0\t2.2\t0.2\t0.4\tidea\tmore words",
        "",
    ]))
    s = beat.read_semantic(p, n_frames=45, fps=15)
    assert s.shape == (45,) and s.dtype == np.float32
    t = np.arange(45) / 15
    expected = np.where((t >= 0.5) & (t <= 0.8), 0.7, np.where(t <= 1.0, 0.1, 0.0))
    expected = np.where((t >= 2.0) & (t <= 2.2 + 1e-9), 0.4, expected)
    np.testing.assert_allclose(s, expected, atol=1e-6)


def test_semantic_errors(tmp_path):
    p = tmp_path / "bad.txt"
    p.write_text("a\t0.0\t1.0\t1.0\t0.5\tok\nb\tzero\t1\t1\t0.5\tk\n")
    with pytest.raises(UserError, match=r"bad\.txt.*line 2"):
        beat.read_semantic(p, 10, 15)
    p.write_text("a\t2.0\t1.0\t-1\t0.5\tk\n")
    with pytest.raises(UserError, match="bad segment"):
        beat.read_semantic(p, 10, 15)
    p.write_text("")
    assert np.all(beat.read_semantic(p, 10, 15) == 0)


# -------------------------------------------------------------------- emotion
@pytest.mark.parametrize("content, expected", [
    ("3\n", [3] * 6),
    ("emotion\nanger\n", [2] * 6),
    ("time,label\n0.0,0\n0.2,5\n", [0, 0, 0, 5, 5, 5]),
    ("0.1;1\n0.3;fear\n", [1, 1, 1, 1, 1, 6]),
    ("label\n1\n2\n7\n", [1, 2, 7, 7, 7, 7]),
    ("1\n2\n3\n4\n5\n6\n7\n0\n", [1, 2, 3, 4, 5, 6]),
])
def test_emotion_layouts(tmp_path, content, expected):
    p = tmp_path / "e.csv"
    p.write_text(content)
    e = beat.read_emotion(p, n_frames=6, fps=15)
    assert e.dtype == np.int16
    assert e.tolist() == expected


@pytest.mark.parametrize("content, message", [
    ("", "empty"),
    ("9\n", "not an integer 0-7"),
    ("bliss\n", "unknown emotion"),
    ("0.5,1\n0.1,2\n", "increasing"),
    ("1,2,3\n", "columns"),
])
def test_emotion_errors(tmp_path, content, message):
    p = tmp_path / "bad.csv"
    p.write_text(content)
    with pytest.raises(UserError, match=f"bad.csv.*{message}"):
        beat.read_emotion(p, 6, 15)
