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

import math
from dataclasses import dataclass

import numba
import numpy as np

from facecapges import timing
from facecapges.network import native

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
_LAGS_0, _LAGS_1, _VOICE_0, _VOICE_1 = _LAGS.start, _LAGS.stop, _VOICE_BINS.start, _VOICE_BINS.stop
_BAND_OF = np.where(_BANDS.any(1), np.argmax(_BANDS, 1), -1)  # each bin's band (-1: none; the bands do not overlap)
_BAND_WEIGHT = _BANDS.max(1)  # and its weight there
_LN2 = math.log(2.0)
_jit = numba.njit(cache=True, nogil=True, error_model="numpy")  # machine code cached beside this file


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
        spec = np.fft.rfft(x * _WINDOW, axis=1)  # (B, 513) complex64
        power = np.empty((B, spec.shape[1]), np.float32)
        native.power_spectrum(spec.view(np.float32).reshape(B, spec.shape[1], 2), power)
        ac = np.fft.irfft(power, axis=1)  # the windowed frame's autocorrelation
        out = SpeechFrame(
            np.empty(B, np.float32),
            np.empty(B, np.bool_),
            np.empty(B, np.bool_),
            np.empty(B, np.int64),
            np.empty(B, np.float32),
            np.empty(B, np.int64),
        )
        o = out
        track(
            np.asarray(idx, np.int64),
            a,
            power,
            ac,
            self.state,
            o.level,
            o.speaking,
            o.onset,
            o.since_onset,
            o.energy,
            o.since_voice,
        )
        return out


@_jit
def _spectrum_cues(power: np.ndarray, ac: np.ndarray, bands: np.ndarray) -> tuple[float, float, float]:
    """One frame's log band powers into ``bands`` (N_BANDS,) from its power spectrum (513,) and autocorrelation
    (1024,); → voicing, flatness and the top bins' share (module docs)."""
    bands[:] = 0.0
    for k in range(power.shape[0]):  # each bin is in one band or none: spec @ _BANDS's sums without its zeros
        if _BAND_OF[k] >= 0:
            bands[_BAND_OF[k]] += power[k] * _BAND_WEIGHT[k]
    for b in range(N_BANDS):
        bands[b] = np.log(bands[b] + np.float32(1e-10))
    peak = ac[_LAGS_0]
    for k in range(_LAGS_0 + 1, _LAGS_1):
        peak = max(peak, ac[k])
    voicing = peak / max(ac[0], np.float32(1e-20))
    total, mantissas, exponents = 0.0, 1.0, 0
    top = np.zeros(TONAL_BINS)  # the largest bins, ascending (as a full sort leaves them)
    for k in range(_VOICE_0, _VOICE_1):
        v = float(power[k]) + 1e-12
        total += v
        m, e = math.frexp(v)  # the logs' sum as one log: of the mantissas' product (≥ 2^-249), plus the exponents
        mantissas *= m
        exponents += e
        if v > top[0]:
            i = 1
            while i < TONAL_BINS and top[i] < v:
                top[i - 1] = top[i]
                i += 1
            top[i - 1] = v
    n = _VOICE_1 - _VOICE_0
    flat = np.exp((np.log(mantissas) + exponents * _LN2) / n) / (total / n)
    share = 0.0
    for v in top:
        share += v
    return voicing, flat, share / total


@_jit
def track(idx, a, power, ac, state, level, speaking, onset, since_onset, energy, since_voice) -> None:
    """The tracker's frame (module docs) for streams ``idx`` (B,): samples ``a`` (B, S), power spectra (B, 513) and
    autocorrelations (B, 1024) of the frames' last N_FFT samples (Hann); ``state`` :class:`SpeechTracker`'s arrays
    (updated); the cues into the last six (B,) arrays (:class:`SpeechFrame`). One compiled loop per stream, in the
    dtypes NumPy's formulas had (float32 levels, float64 sums): libm's log and exp and the sums in order, so the
    values equal those formulas' to ~1 ulp."""
    floor_, hang_, prev_bands, flux_hist, since_, energy_, count_, talk_, tonal_, run_, voice_ = state
    f32 = np.float32
    bands = np.empty(N_BANDS, np.float32)
    for n in range(len(idx)):
        s = idx[n]
        sq, lanes, S = 0.0, np.zeros(8), a.shape[1]
        for i in range(0, S - S % 8, 8):  # eight running sums (as NumPy's pairwise sum has): not one long chain
            for j in range(8):
                lanes[j] += float(a[n, i + j]) * float(a[n, i + j])
        for i in range(S - S % 8, S):
            sq += float(a[n, i]) * float(a[n, i])
        sq += ((lanes[0] + lanes[1]) + (lanes[2] + lanes[3])) + ((lanes[4] + lanes[5]) + (lanes[6] + lanes[7]))
        rms = np.sqrt(sq / a.shape[1] + 1e-20) if a.shape[1] else 0.0
        lv = f32(max(20.0 * np.log10(rms + 1e-12), -100.0))
        first = count_[s] == 0
        floor = lv if first else min(lv, floor_[s] + f32(FLOOR_RISE_DB))
        loud = lv > max(f32(SILENCE_DB), floor + f32(VAD_MARGIN_DB))
        voicing, flat, top = _spectrum_cues(power[n], ac[n], bands)
        tonal_sum = 0.0
        for k in range(1, TONAL_FRAMES):
            tonal_sum += tonal_[s, k]
        voice_like = (
            loud and (voicing >= f32(VOICING) or flat < FLAT_MAX) and (tonal_sum + top) / TONAL_FRAMES < TONAL_SHARE
        )
        talk = max(talk_[s] - f32(LEVEL_DECAY_DB), lv if voice_like else f32(-100.0))
        like = voice_like and lv > talk - f32(NEAR_DB)
        run = run_[s] + 1 if like else 0
        hang = HANGOVER if run >= OPEN_FRAMES else max(hang_[s] - 1, 0)
        talking = run >= OPEN_FRAMES or hang > 0
        flux = f32(0.0)
        if not np.isnan(prev_bands[s, 0]):
            for b in range(N_BANDS):
                flux += max(bands[b] - prev_bands[s, b], f32(0.0))
            flux /= f32(N_BANDS)
        valid, total = 0, f32(0.0)
        for v in flux_hist[s]:
            if not np.isnan(v):
                valid += 1
                total += v
        mean, var = 0.0, 0.0
        if valid:
            mean = total / valid
            for v in flux_hist[s]:
                if not np.isnan(v):
                    var += (v - mean) ** 2
            var /= valid
        since = min(since_[s] + 1, SINCE_CAP)
        fired = talking and flux > max(mean + ONSET_K * np.sqrt(var), MIN_FLUX) and since >= REFRACTORY
        since = 0 if fired else since
        en = lv if first else energy_[s] + f32(ENERGY_ALPHA) * (lv - energy_[s])
        floor_[s], hang_[s], prev_bands[s] = floor, hang, bands
        talk_[s], run_[s] = talk, run
        for k in range(TONAL_FRAMES - 1):
            tonal_[s, k] = tonal_[s, k + 1]
        tonal_[s, TONAL_FRAMES - 1] = top
        for k in range(FLUX_HISTORY - 1):
            flux_hist[s, k] = flux_hist[s, k + 1]
        flux_hist[s, FLUX_HISTORY - 1] = flux
        since_[s], energy_[s], count_[s] = since, en, count_[s] + 1
        voice = 0 if like else min(voice_[s] + 1, SINCE_VOICE_CAP)
        voice_[s] = voice
        level[n], speaking[n], onset[n], since_onset[n], energy[n], since_voice[n] = (
            lv,
            talking,
            fired,
            since,
            en,
            voice,
        )


def warm() -> None:
    """Load (or compile, once: ``make setup``) :func:`track`'s machine code for the types the tracker passes."""
    tr = SpeechTracker(1)
    tr.step(np.zeros(1, np.int64), np.zeros((1, N_FFT), np.float32))


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
