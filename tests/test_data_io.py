"""Audio loading and BEAT face JSON reading/writing."""

from __future__ import annotations

import json

import numpy as np
import pytest
import soundfile as sf

from facecapges.arkit import ARKIT_NAMES, BEAT_NAMES
from facecapges.errors import UserError
from facecapges.io.audio import is_silent, load_audio, rms_db, save_audio
from facecapges.io.face_json import read_face_json, write_face_json


# ---------------------------------------------------------------------- audio
def test_load_real_wav(beat_wav):
    audio = load_audio(beat_wav)
    info = sf.info(str(beat_wav))
    assert audio.dtype == np.float32 and audio.ndim == 1
    assert len(audio) == info.frames and info.samplerate == 16000
    assert 64.0 < len(audio) / 16000 < 64.2
    assert not is_silent(audio)


def test_load_pcm16_wav(unseen_wav):
    audio = load_audio(unseen_wav)
    assert len(audio) == 62 * 16000 and np.abs(audio).max() <= 1.0


def test_resample_stereo_44k_keeps_pitch_and_length(tmp_path):
    sr = 44100
    t = np.arange(2 * sr) / sr
    left = 0.5 * np.sin(2 * np.pi * 440.0 * t)
    right = 0.3 * np.sin(2 * np.pi * 440.0 * t)
    sf.write(tmp_path / "st.wav", np.stack([left, right], 1).astype(np.float32), sr)
    audio = load_audio(tmp_path / "st.wav")
    assert len(audio) == 32000
    spec = np.abs(np.fft.rfft(audio[4000:-4000]))
    freq = np.fft.rfftfreq(len(audio) - 8000, 1 / 16000)[spec.argmax()]
    assert abs(freq - 440.0) < 1.0
    # mean of the channels: amplitude 0.4
    assert np.abs(audio[4000:-4000]).max() == pytest.approx(0.4, abs=0.01)


def test_video_audio_track(face_video):
    audio = load_audio(face_video)
    assert audio.dtype == np.float32
    assert abs(len(audio) / 16000 - 8.0) < 0.1
    assert not is_silent(audio)


def test_save_load_round_trip_and_silence(tmp_path):
    x = (0.25 * np.sin(np.linspace(0, 200, 16000))).astype(np.float32)
    save_audio(tmp_path / "a.wav", x)
    y = load_audio(tmp_path / "a.wav")
    np.testing.assert_allclose(y, x, atol=1 / 32767 + 1e-6)
    assert is_silent(np.zeros(1000, np.float32)) and rms_db(np.zeros(10)) == float("-inf")
    assert is_silent(np.full(1000, 1e-4, np.float32)) and not is_silent(x)


def test_audio_errors_name_the_file(tmp_path, beat_wav):
    data = beat_wav.read_bytes()
    (tmp_path / "cut.wav").write_bytes(data[: len(data) // 3])
    with pytest.raises(UserError, match=r"cut\.wav.*truncated"):
        load_audio(tmp_path / "cut.wav")
    (tmp_path / "head.wav").write_bytes(data[:30])
    with pytest.raises(UserError, match=r"head\.wav.*truncated"):
        load_audio(tmp_path / "head.wav")
    (tmp_path / "empty.wav").write_bytes(b"")
    with pytest.raises(UserError, match=r"empty\.wav.*empty"):
        load_audio(tmp_path / "empty.wav")
    (tmp_path / "junk.wav").write_bytes(b"this is not audio at all" * 10)
    with pytest.raises(UserError, match=r"junk\.wav.*not a readable audio"):
        load_audio(tmp_path / "junk.wav")
    sf.write(tmp_path / "zero.wav", np.zeros(0, np.float32), 16000)
    with pytest.raises(UserError, match=r"zero\.wav.*no samples"):
        load_audio(tmp_path / "zero.wav")
    with pytest.raises(UserError, match=r"nothing\.wav.*not found"):
        load_audio(tmp_path / "nothing.wav")
    (tmp_path / "fake.mp4").write_bytes(b"\x00" * 100)
    with pytest.raises(UserError, match=r"fake\.mp4"):
        load_audio(tmp_path / "fake.mp4")


# ------------------------------------------------------------------ face JSON
def beat_face_doc(n: int, fps: float = 60.0, names=BEAT_NAMES) -> dict:
    rng = np.random.default_rng(0)
    w = rng.uniform(0, 1, (n, len(names))).round(4)
    return {"names": list(names), "frames": [{"time": i / fps, "weights": w[i].tolist()} for i in range(n)]}


def test_read_beat_face_json(tmp_path):
    doc = beat_face_doc(30)
    (tmp_path / "f.json").write_text(json.dumps(doc))
    face = read_face_json(tmp_path / "f.json")
    assert face.weights.shape == (30, 52) and face.weights.dtype == np.float32
    assert face.fps == 60.0 and face.unknown_names == [] and face.head_rot6d is None
    np.testing.assert_allclose(face.weights[:, :51], [f["weights"] for f in doc["frames"]], atol=1e-6)
    assert np.all(face.weights[:, ARKIT_NAMES.index("tongueOut")] == 0)


def test_names_are_reordered_and_unknown_reported(tmp_path):
    names = ["jawOpen", "EyeBlinkLeft", "sparkle"]
    doc = {"names": names, "frames": [{"time": i / 30, "weights": [0.5, 0.25, 0.9]} for i in range(4)]}
    (tmp_path / "f.json").write_text(json.dumps(doc))
    face = read_face_json(tmp_path / "f.json")
    assert face.fps == 30.0 and face.unknown_names == ["sparkle"]
    assert np.all(face.weights[:, ARKIT_NAMES.index("jawOpen")] == 0.5)
    assert np.all(face.weights[:, ARKIT_NAMES.index("eyeBlinkLeft")] == 0.25)
    assert face.weights.sum() == pytest.approx(4 * 0.75)


def test_fps_falls_back_to_60_without_times(tmp_path):
    doc = beat_face_doc(5)
    for f in doc["frames"]:
        del f["time"]
    (tmp_path / "f.json").write_text(json.dumps(doc))
    assert read_face_json(tmp_path / "f.json").fps == 60.0


def test_write_read_round_trip_with_head(tmp_path):
    rng = np.random.default_rng(1)
    w = rng.uniform(0, 1, (12, 52)).astype(np.float32)
    from scipy.spatial.transform import Rotation

    from facecapges.rotations import matrix_to_rot6d

    head = matrix_to_rot6d(Rotation.random(12, random_state=0).as_matrix()).astype(np.float32)
    write_face_json(tmp_path / "o.json", w, 15.0, head_rot6d=head, layout="full")
    doc = json.loads((tmp_path / "o.json").read_text())
    assert doc["names"] == list(ARKIT_NAMES) and len(doc["frames"]) == 12
    face = read_face_json(tmp_path / "o.json")
    assert face.fps == 15.0
    np.testing.assert_allclose(face.weights, w, atol=1e-6)
    np.testing.assert_allclose(face.head_rot6d, head, atol=1e-6)
    write_face_json(tmp_path / "n.json", w, 60.0)
    assert read_face_json(tmp_path / "n.json").head_rot6d is None
    with pytest.raises(ValueError):
        write_face_json(tmp_path / "bad.json", w[:, :51], 60.0)


@pytest.mark.parametrize("content, message", [
    ('{"names": ["jawOpen"], "frames": [{"time": 0, "weights": [0.1]}', "malformed JSON"),
    ('{"names": ["jawOpen"], "frames": [{"time": 0, "weights": [NaN]}]}', "NaN"),
    ('{"names": ["jawOpen"], "frames": [{"time": 0, "weights": [0.1, 0.2]}]}', "frame 0 has 2 weights"),
    ('{"names": ["jawOpen"], "frames": []}', "no frames"),
    ('[1, 2, 3]', "'names' list"),
    ('{"names": ["jawOpen"], "frames": [{"weights": ["x"]}]}', "numbers"),
])
def test_bad_face_json(tmp_path, content, message):
    (tmp_path / "bad.json").write_text(content)
    with pytest.raises(UserError, match=f"bad.json.*{message}"):
        read_face_json(tmp_path / "bad.json")
