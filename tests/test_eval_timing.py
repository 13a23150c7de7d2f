"""evaluation.timing: onset → wrist-peak lag and the event-related rise, each against random times."""

from __future__ import annotations

import numpy as np
import pytest

from facecapges.evaluation import timing as et

FPS = 15.0


def _speed_with_strokes(n: int, events: np.ndarray, lag: int, rng: np.random.Generator) -> np.ndarray:
    """A wrist-speed curve: noise plus a 5-frame bump peaking ``lag`` frames after each event."""
    s = 5.0 + rng.normal(0, 0.5, n)
    bump = np.array([0.3, 0.7, 1.0, 0.7, 0.3]) * 20.0
    for e in events:
        c = e + lag
        for k, b in enumerate(bump):
            if 0 <= c - 2 + k < n:
                s[c - 2 + k] += b
    return s


def _events(n: int, rng: np.random.Generator, gap=(15, 40)) -> np.ndarray:
    t, out = 10, []
    while t < n - 20:
        out.append(t)
        t += int(rng.integers(*gap))
    return np.array(out)


@pytest.mark.parametrize("lag", [2, 4, 6])
def test_known_lag_is_found_and_beats_chance(lag):
    rng = np.random.default_rng(lag)
    n = 3000
    ev = _events(n, rng)
    speed = _speed_with_strokes(n, ev, lag, rng)
    fig = et.onset_lag([speed], [ev], FPS, seed=1)
    assert fig.value == pytest.approx(lag / FPS, abs=0.5 / FPS)
    assert fig.median == pytest.approx(lag / FPS, abs=0.5 / FPS)
    assert fig.chance > fig.value + 0.1  # random times wait longer for the next peak
    assert fig.z < -5 and fig.p < 0.01
    rise = et.onset_rise([speed], [ev], FPS, window_s=(lag + 3) / FPS, seed=1)
    assert rise.value > 0 and rise.z > 5 and rise.p < 0.01


def test_unrelated_onsets_score_chance():
    rng = np.random.default_rng(7)
    n = 4000
    strokes = _events(n, rng)
    speed = _speed_with_strokes(n, strokes, 3, rng)
    zs_lag, zs_rise = [], []
    for k in range(6):  # onsets that know nothing of the strokes
        ev = np.sort(np.random.default_rng(100 + k).choice(np.arange(20, n - 20), 120, replace=False))
        zs_lag.append(et.onset_lag([speed], [ev], FPS, seed=k).z)
        zs_rise.append(et.onset_rise([speed], [ev], FPS, seed=k).z)
    assert abs(np.median(zs_lag)) < 1.5 and abs(np.median(zs_rise)) < 1.5
    assert max(abs(z) for z in zs_lag + zs_rise) < 3.5


def test_clips_pool_without_crossing_borders():
    rng = np.random.default_rng(3)
    a_ev, b_ev = _events(800, rng), _events(900, rng)
    a, b = _speed_with_strokes(800, a_ev, 4, rng), _speed_with_strokes(900, b_ev, 4, rng)
    fig = et.onset_lag([a, b], [a_ev, b_ev], FPS)
    assert fig.value == pytest.approx(4 / FPS, abs=0.5 / FPS)
    assert fig.n_events == len(a_ev) + len(b_ev)
    # an onset in the last frame of clip a finds no peak in clip b
    assert et.onset_lag([a, b], [np.array([799]), np.array([], int)], FPS).n_events == 0


def test_still_motion_has_no_peaks():
    assert len(et.speed_peaks(np.zeros(100))) == 0
    fig = et.onset_lag([np.zeros(100)], [np.array([10, 50])], FPS)
    assert fig.n_events == 0 and np.isnan(fig.value)


def test_speech_onsets_come_from_the_speech_tracker():
    from conftest import shared_file
    from facecapges.io.audio import load_audio
    from facecapges.matching.speech import speech_track

    sr, n = 16000, 60
    speech = load_audio(shared_file("data/beat/2_scott_0_4_4.wav"))
    voiced = speech[5 * sr : 5 * sr + sr // 2]  # half a second of his speech (white noise is not speech to the VAD)
    audio = np.zeros(sr * 4, np.float32)
    for s in (0.5, 1.7, 2.9):  # three bursts of speech after silence
        i = int(s * sr)
        audio[i : i + len(voiced)] = voiced
    on = et.speech_onsets(audio, sr, FPS, n)
    assert np.array_equal(on, np.flatnonzero(speech_track(audio, n).onset))
    assert len(on) >= 3
    with pytest.raises(ValueError):
        et.speech_onsets(audio, 22050, FPS, n)
