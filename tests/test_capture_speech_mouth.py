"""The mouth from the speech: causal, per frame, on unseen audio; silence keeps it closed."""

from __future__ import annotations

import numpy as np
import pytest

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


def test_the_compiled_sums_keep_numpys_bits(unseen_wav):
    """``live``'s mouth (``SpeechMouth(compiled=True)``: the spectrum's sums in one compiled call) gives the same
    weights to the bit as NumPy's: unseen speech, loud noise, quiet noise, silence, short frames, 30 and 5 fps."""
    from facecapges.capture import mouth_kernels

    if not mouth_kernels.checked():
        pytest.skip("this machine's NumPy sums otherwise than the compiled loops: NumPy's are used")
    rng = np.random.default_rng(0)
    speech = frames(load_audio(unseen_wav, timing.AUDIO_SR))[:400]
    noise = [rng.standard_normal(len(f)).astype(np.float32) * 10.0 ** rng.uniform(-5, 0) for f in speech[:100]]
    odd = [np.zeros(1066, np.float32), np.zeros(40, np.float32), speech[5][:300], speech[6][:64]]
    audio = speech + noise + odd + speech[:50]
    for fps in (timing.MODEL_FPS, 30.0, 5.0):
        a, b = SpeechMouth(fps), SpeechMouth(fps, compiled=True)
        for x in audio if fps == timing.MODEL_FPS else [rng.standard_normal(int(16000 / fps)).astype(np.float32)] * 30:
            np.testing.assert_array_equal(a.step(x).view(np.uint32), b.step(x).view(np.uint32))
    sums = mouth_kernels.mouth_sums  # every run length to the longest it takes
    for n in (*range(1, 300), 511, 512, 1000, 1799, 4097, 70_000):
        mag = np.abs(rng.standard_normal(n + 2))
        f = rng.uniform(0, 5000, n)
        spec = mag**2 / 1066
        got = sums(mag.copy(), 1066, 0, n, 2, n + 2, f[:n])
        want = (spec[:n].sum(), spec[2 : n + 2].sum(), (f[:n] * spec[2 : n + 2]).sum())
        assert [np.float64(v).tobytes() for v in got] == [np.float64(v).tobytes() for v in want], n


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


def test_band_slices_pick_the_masks_bins():
    """The vowel and centroid bands are taken as runs of bins made once per frame length (issue 36): the bins the
    frequency masks pick, in the same order, so every sum is the masks' sum and the weights are the same bits."""
    m = SpeechMouth()
    for n in (64, 100, 1066, 1067, 2048):
        f = np.fft.rfftfreq(n, 1.0 / m.sr)
        vowel, band, f_band = m._band_slices(n, f)
        for sl, lo, hi in ((vowel, 250.0, 1200.0), (band, 80, 5000)):
            mask = (f >= lo) & (f <= hi)
            assert np.array_equal(np.arange(len(f))[sl], np.flatnonzero(mask))
        assert f_band.tobytes() == f[(f >= 80) & (f <= 5000)].tobytes()
    rng = np.random.default_rng(3)
    x = (rng.standard_normal(16000 * 6) * np.repeat(rng.uniform(0, 0.4, 6), 16000)).astype(np.float32)
    mouth = SpeechMouth()
    for a in frames(x):  # the masks' formula, step by step, beside the mouth
        spec = np.abs(np.fft.rfft(a.astype(np.float64) * np.hanning(len(a)))) ** 2 / len(a)
        f = np.fft.rfftfreq(len(a), 1.0 / mouth.sr)
        was = (mouth.floor_db, mouth.peak_db)
        w = mouth.step(a)
        db = 10.0 * np.log10(spec[(f >= 250.0) & (f <= 1200.0)].sum() + 1e-10)
        floor = db if db < was[0] else was[0] + mouth._rise
        assert mouth.floor_db == min(floor, mouth.peak_db - 24.0) and w.dtype == np.float32
