"""Causal speech cues of the matching engine: speaking or pause, onsets, loudness — per frame.

Each 15 fps frame owns ≤ 1067 samples (16 kHz). :class:`SpeechTracker` reads only the current
frame's samples and its own running state, for B independent streams at once (one stream is
B = 1), so the database's annotations (the take's own audio through the same tracker, frame by
frame) and the live engine agree by construction.

Per frame and stream:

* ``level`` — the frame's RMS in dBFS (floor −100).
* ``speaking`` — a VAD that decides on speech, not on level (issue #38: a muted mic, room tone,
  keyboard clicks, music and a far voice are pauses). A frame is *speech-like* when all hold:

  - **loud over the noise floor**: the level above ``max(SILENCE_DB, floor + VAD_MARGIN_DB)``; the
    noise floor follows the quietest frames (drops at once, rises ≤ ``FLOOR_RISE_DB`` a frame);
  - **near the talker's level**: above the running speech level − ``NEAR_DB`` (the speech level
    jumps up to a louder speech-like frame and sinks by ``LEVEL_DECAY_DB`` a frame: a voice 25 dB
    below the talker's — someone across the room — is not the talker);
  - **voice-like spectrum** (of the frame's last 1024 samples, Hann, 100 Hz – 4 kHz): periodic
    (normalised autocorrelation peak at a lag of 2.5–14 ms — a pitch of 70–400 Hz — at least
    ``VOICING``) or a steep spectrum (flatness below ``FLAT_MAX``); clicks and noise are flat and
    aperiodic;
  - **not a steady tone**: the strongest ``TONAL_BINS`` bins hold less than ``TONAL_SHARE`` of the
    band's power on average over the last ``TONAL_FRAMES`` frames (a few partials held over notes:
    music; speech's harmonics and formants move every frame).

  Speech opens after ``OPEN_FRAMES`` speech-like frames in a row and stays open ``HANGOVER``
  frames after the last one (short gaps between words stay speech). Measured on the conversation
  clips (:mod:`facecapges.evaluation.conversation`) by ``scripts/conversation_report.py``.
* ``since_voice`` — frames since the last speech-like frame (0 on one; capped at ``SINCE_VOICE_CAP``): how
  long the voice has been gone, before the hangover decides it is a pause (the idle layer,
  :mod:`facecapges.matching.idle`).
* ``onset`` — spectral flux: the frame's last 1024 samples (Hann) in ``N_BANDS`` log-spaced
  bands 80 Hz – 8 kHz, log power; the flux is the mean positive rise of the bands against the
  previous frame. An onset fires while speaking when the flux exceeds the mean + ``ONSET_K`` sd
  of the flux over the last ``FLUX_HISTORY`` frames (and ``MIN_FLUX``), at most once every
  ``REFRACTORY`` frames.
* ``since_onset`` — frames since the last onset (capped at ``SINCE_CAP``).
* ``energy`` — the level smoothed over ~0.3 s (exponential), for the loudness class.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facecapges import timing
from facecapges.network.mel import irfft, rfft

SILENCE_DB = -50.0
VAD_MARGIN_DB = 20.0
FLOOR_RISE_DB = 0.05
HANGOVER = 6
NEAR_DB = 20.0
LEVEL_DECAY_DB = 0.02
VOICING = 0.3
FLAT_MAX = 0.03
TONAL_BINS = 12
TONAL_SHARE = 0.98
TONAL_FRAMES = 4
OPEN_FRAMES = 1
N_FFT = 1024
N_BANDS = 8
FLUX_HISTORY = 23  # ~1.5 s
ONSET_K = 1.0
MIN_FLUX = 0.5
REFRACTORY = 3
SINCE_CAP = 30
SINCE_VOICE_CAP = 10**6
ENERGY_ALPHA = 0.2


def _band_matrix(sr: int = timing.AUDIO_SR) -> np.ndarray:
    freqs = np.fft.rfftfreq(N_FFT, 1.0 / sr)
    edges = np.geomspace(80.0, 8000.0, N_BANDS + 1)
    m = np.zeros((len(freqs), N_BANDS), np.float32)
    for b in range(N_BANDS):
        m[(freqs >= edges[b]) & (freqs < edges[b + 1]), b] = 1.0
    return m / np.maximum(m.sum(0, keepdims=True), 1.0)


_BANDS = _band_matrix()
_WINDOW = np.hanning(N_FFT).astype(np.float32)
_FREQS = np.fft.rfftfreq(N_FFT, 1.0 / timing.AUDIO_SR)
_VOICE_BAND = (_FREQS >= 100.0) & (_FREQS < 4000.0)
_VOICE_BINS = slice(int(np.argmax(_VOICE_BAND)), len(_VOICE_BAND) - int(np.argmax(_VOICE_BAND[::-1])))  # as a slice
_LAGS = slice(timing.AUDIO_SR // 400, timing.AUDIO_SR // 70 + 1)  # pitch 400 … 70 Hz
LAGS_0, LAGS_1, VOICE_0, VOICE_1 = _LAGS.start, _LAGS.stop, _VOICE_BINS.start, _VOICE_BINS.stop
BAND_OF = np.where(_BANDS.any(1), np.argmax(_BANDS, 1), -1)  # each bin's band (-1: none; the bands do not overlap)
BAND_WEIGHT = _BANDS.max(1)  # and its weight there


@dataclass
class SpeechFrame:
    """The cues of one frame for B streams (module docs)."""

    level: np.ndarray  # (B,) dBFS
    speaking: np.ndarray  # (B,) bool
    onset: np.ndarray  # (B,) bool
    since_onset: np.ndarray  # (B,) int
    energy: np.ndarray  # (B,) smoothed dBFS
    since_voice: np.ndarray  # (B,) int: frames since the last speech-like frame


class SpeechTracker:
    """Causal speaking/onset/loudness state of ``capacity`` streams (module docs)."""

    def __init__(self, capacity: int = 1):
        from facecapges.matching import kernels  # Numba: loaded when a tracker is built, not with this module
        from facecapges.network import native

        self._track, self._power = kernels.track, native.power_spectrum
        self.capacity = 0
        self._alloc(capacity)

    def _alloc(self, capacity: int) -> None:
        old = self.capacity

        def grow(name: str, shape: tuple, fill: float, dtype=np.float32) -> np.ndarray:
            new = np.full((capacity, *shape), fill, dtype)
            if old:
                new[:old] = getattr(self, name)
            return new

        self.floor = grow("floor", (), 0.0)
        self.hang = grow("hang", (), 0, np.int64)
        self.prev_bands = grow("prev_bands", (N_BANDS,), np.nan)
        self.flux_hist = grow("flux_hist", (FLUX_HISTORY,), np.nan)
        self.since = grow("since", (), SINCE_CAP, np.int64)
        self.energy = grow("energy", (), -100.0)
        self.count = grow("count", (), 0, np.int64)
        self.talk_level = grow("talk_level", (), -100.0)
        self.tonal = grow("tonal", (TONAL_FRAMES,), 0.0)
        self.run = grow("run", (), 0, np.int64)
        self.since_voice = grow("since_voice", (), SINCE_VOICE_CAP, np.int64)
        self.capacity = capacity
        self.state = (  # what the compiled frame (track) reads and updates, in its order
            self.floor,
            self.hang,
            self.prev_bands,
            self.flux_hist,
            self.since,
            self.energy,
            self.count,
            self.talk_level,
            self.tonal,
            self.run,
            self.since_voice,
        )

    def ensure(self, capacity: int) -> None:
        if capacity > self.capacity:
            self._alloc(capacity)

    def reset(self, slot: int) -> None:
        self.floor[slot], self.hang[slot], self.since[slot] = 0.0, 0, SINCE_CAP
        self.prev_bands[slot], self.flux_hist[slot] = np.nan, np.nan
        self.energy[slot], self.count[slot] = -100.0, 0
        self.talk_level[slot], self.tonal[slot], self.run[slot] = -100.0, 0.0, 0
        self.since_voice[slot] = SINCE_VOICE_CAP

    def step(self, idx: np.ndarray, audio: np.ndarray) -> SpeechFrame:
        """One frame of streams ``idx`` (B,) from their samples (B, ≤1067) → :class:`SpeechFrame`."""
        a = np.ascontiguousarray(np.asarray(audio, np.float32).reshape(len(idx), -1))
        B = len(a)
        if a.shape[1] >= N_FFT:  # the frame's last N_FFT samples
            x = a[:, a.shape[1] - N_FFT :]
        else:  # zeros before a short frame's samples
            x = np.zeros((B, N_FFT), np.float32)
            if a.shape[1]:
                x[:, N_FFT - a.shape[1] :] = a
        spec = rfft(x * _WINDOW)  # (B, 513) complex64: np.fft.rfft's bits (network.mel.rfft)
        power = np.empty((B, spec.shape[1]), np.float32)
        self._power(spec.view(np.float32).reshape(B, spec.shape[1], 2), power)
        ac = irfft(power)  # the windowed frame's autocorrelation (np.fft.irfft's bits)
        out = SpeechFrame(
            np.empty(B, np.float32),
            np.empty(B, np.bool_),
            np.empty(B, np.bool_),
            np.empty(B, np.int64),
            np.empty(B, np.float32),
            np.empty(B, np.int64),
        )
        self._track(
            np.asarray(idx, np.int64),
            a,
            power,
            ac,
            self.state,
            out.level,
            out.speaking,
            out.onset,
            out.since_onset,
            out.energy,
            out.since_voice,
        )
        return out


def speech_track(audio: np.ndarray, n_frames: int) -> SpeechFrame:
    """The tracker run over a whole take's audio, frame by frame: every field (n_frames,)."""
    tr = SpeechTracker(1)
    spf = timing.samples_per_frame()
    idx = np.zeros(1, np.int64)
    a = np.asarray(audio, np.float32)
    rows = []
    for t in range(n_frames):
        chunk = a[t * spf : (t + 1) * spf]
        rows.append(tr.step(idx, chunk[None] if len(chunk) else np.zeros((1, 0), np.float32)))
    return SpeechFrame(*(np.concatenate([getattr(r, k) for r in rows]) for k in SpeechFrame.__dataclass_fields__))
