"""The mouth from the speech: causal, per frame, on unseen audio; silence keeps it closed."""

from __future__ import annotations

import numpy as np

from facecapges import timing
from facecapges.arkit import ARKIT_NAMES
from facecapges.capture.speech_mouth import MOUTH_NAMES, SpeechMouth, speech_frames, speech_mouth_track
from facecapges.io.audio import load_audio
from runtime_helpers import cli

JAW = ARKIT_NAMES.index("jawOpen")


def frames(x: np.ndarray) -> list[np.ndarray]:
    return speech_frames(x, timing.MODEL_FPS, int(np.ceil(len(x) / timing.AUDIO_SR * timing.MODEL_FPS - 1e-6)))


def test_jaw_follows_the_speech_on_unseen_audio(unseen_wav):
    fr = frames(load_audio(unseen_wav, timing.AUDIO_SR))
    m = speech_mouth_track(fr)
    rms = np.array([np.sqrt(np.mean(np.square(f, dtype=np.float64))) for f in fr])
    jaw = m[:, JAW]
    assert np.corrcoef(jaw, rms)[0, 1] > 0.6
    closed = (jaw < 0.05).mean()
    assert 0.05 < closed < 0.6  # it closes between phrases, and it does speak
    assert 0.1 < jaw.mean() < 0.35 and jaw.max() <= 0.55 + 1e-6
    others = np.setdiff1d(np.arange(52), [ARKIT_NAMES.index(n) for n in MOUTH_NAMES])
    assert not m[:, others].any()  # only the mouth moves
    assert np.isfinite(m).all() and m.min() >= 0 and m.max() <= 1


def test_causal_and_closed_in_silence(unseen_wav):
    fr = frames(load_audio(unseen_wav, timing.AUDIO_SR))[:200]
    a = speech_mouth_track(fr)
    changed = fr[:120] + [np.zeros_like(f) for f in fr[120:]]
    b = speech_mouth_track(changed)
    np.testing.assert_array_equal(a[:120], b[:120])  # the future does not change the past
    assert b[135:, JAW].max() < 0.01  # silence closes the mouth within a second
    m = SpeechMouth()
    assert not m.step(np.zeros(1067, np.float32)).any()
    assert not m.step(np.zeros(0, np.float32)).any()


def test_generate_writes_the_speaking_face(unseen_wav, tmp_path):
    from facecapges.io.audio import save_audio
    from facecapges.io.face_json import read_face_json

    wav = tmp_path / "unseen_10s.wav"  # its first 10 s (the whole 62 s took seconds more to generate)
    save_audio(wav, load_audio(unseen_wav, timing.AUDIO_SR)[: 10 * timing.AUDIO_SR])
    r = cli("generate", "--audio", str(wav), "--out", str(tmp_path / "g.bvh"), "--face-out", str(tmp_path / "g.json"))
    assert r.returncode == 0, r.stderr
    face = read_face_json(tmp_path / "g.json")
    jaw = face.weights[:, JAW]
    # the face covers the whole speech, and the mouth speaks
    assert face.n_frames / face.fps >= 10 - 1 / 15 and jaw.max() > 0.3 and jaw.std() > 0.05
