"""A mouth that speaks without a face: jaw and lips from the speech, causally, frame by frame.

When there is no face track (the demo, ``generate``, audio-only ``live``, a face that
left the frame) the avatar would speak with a closed mouth. :class:`SpeechMouth` turns
each model frame's audio (the 1066–1067 samples the model gets, :mod:`facecapges.timing`)
into mouth blendshapes, using that frame and the past only:

1. **vowel loudness** — the frame's level (dB) in the 250–1200 Hz band, where the
   first formant of vowels lies (F1 rises as the jaw opens: "a" ≈ 750 Hz, "i"/"u" ≈
   300 Hz; fricatives put their energy higher up), placed in the top 24 dB below a
   running speech peak and at least 6 dB above a running noise floor (causal
   trackers: the floor follows quiet frames at once and rises 1.5 dB/s, the peak
   follows loud frames at once and decays 3 dB/s), so the same mapping works for a
   quiet microphone and a loud file without calibration; below a gate of 0.15 of
   that range (pauses, breaths, room noise) the jaw closes;
2. **shape** — the spectral centroid of the frame (Hann window, 80 Hz–5 kHz): dark,
   rounded vowels (low centroid: o, u) add ``mouthFunnel`` / ``mouthPucker``, bright
   sounds (high centroid: i, e, s) add ``mouthStretch``;
3. **motion** — an attack/release filter (70 % of the way per frame opening, 50 %
   closing), so syllables read as the jaw moving rather than flickering.

``jawOpen`` peaks at 0.55, about what MediaPipe measures on the shared talking-head
clip at a loud syllable (a speaking mouth is rarely wide open). The constants are
chosen once, a priori, from these physical ranges — none was fitted on an evaluation clip.
"""

from __future__ import annotations

import numpy as np

from facecapges import timing
from facecapges.arkit import ARKIT_NAMES, N_BLENDSHAPES

JAW_MAX = 0.55
GATE = 0.15
VOWEL_BAND_HZ = (250.0, 1200.0)  # where the first formant of vowels lies; it rises as the jaw opens
RANGE_DB = 24.0  # the jaw moves over the top 24 dB of the band's level
FLOOR_RISE_DB_S, PEAK_DECAY_DB_S = 1.5, 3.0
ATTACK, RELEASE = 0.7, 0.5  # share of the way to the target per frame, opening / closing
_IDX = {n: ARKIT_NAMES.index(n) for n in ARKIT_NAMES}
_NO_SHAPE = np.zeros(3)  # (never written: a frame's shape is a new array)
MOUTH_NAMES = (
    "jawOpen",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "mouthStretchLeft",
    "mouthStretchRight",
    "mouthFunnel",
    "mouthPucker",
)  # the weights it drives
_OUT_IDX = np.array([_IDX[n] for n in MOUTH_NAMES])  # where each frame's weights go, in the order step computes them


class SpeechMouth:
    """Per-frame mouth weights (52,) from that frame's audio (module docstring)."""

    def __init__(self, fps: float = timing.MODEL_FPS, sr: int = timing.AUDIO_SR, compiled: bool = False):
        """``compiled``: the sums over the spectrum in one compiled call (:mod:`.mouth_kernels`, Numba: ``live``'s
        scheduler, which loads it anyway) where they give NumPy's numbers."""
        self.fps, self.sr, self.compiled = float(fps), int(sr), compiled
        self._kernel = None
        if compiled:
            from facecapges.capture import mouth_kernels

            self._kernel = mouth_kernels.mouth_sums if mouth_kernels.checked() else None
        self.floor_db, self.peak_db = -70.0, -30.0
        self.open = 0.0
        self.shape = np.zeros(3)  # funnel, pucker, stretch
        self._rise = FLOOR_RISE_DB_S / self.fps  # dB per frame
        self._decay = PEAK_DECAY_DB_S / self.fps
        self._window: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._bands: dict[int, tuple[slice, slice, np.ndarray]] = {}

    def reset(self) -> None:
        SpeechMouth.__init__(self, self.fps, self.sr, self.compiled)

    def _sums(self, x: np.ndarray) -> tuple[float, float, float]:
        """The frame's power (Hann window) summed over the vowel band, over the centroid's band, and weighted by
        frequency over the centroid's band."""
        n = len(x)
        if n not in self._window:
            self._window[n] = (np.hanning(n), np.fft.rfftfreq(n, 1.0 / self.sr))
        win, f = self._window[n]
        vowel, band, f_band = self._band_slices(n, f)
        mag = np.abs(np.fft.rfft(x * win))
        if self._kernel is not None:
            return self._kernel(mag, n, vowel.start, vowel.stop, band.start, band.stop, f_band)
        spec = mag**2 / n
        p = spec[band]
        return spec[vowel].sum(), p.sum(), (f_band * p).sum()

    def _band_slices(self, n: int, f: np.ndarray) -> tuple[slice, slice, np.ndarray]:
        """The vowel band's and the centroid band's bins of an ``n``-sample frame as slices (the frequencies rise, so
        each band is one run of bins: the same bins, in the same order, as their masks pick), and the centroid
        band's frequencies; made once per frame length."""
        if n not in self._bands:

            def run(mask: np.ndarray) -> slice:
                i = np.flatnonzero(mask)
                return slice(int(i[0]), int(i[-1]) + 1) if len(i) else slice(0, 0)

            vowel = run((f >= VOWEL_BAND_HZ[0]) & (f <= VOWEL_BAND_HZ[1]))
            band = run((f >= 80) & (f <= 5000))
            self._bands[n] = (vowel, band, f[band].copy())
        return self._bands[n]

    def step(self, audio: np.ndarray) -> np.ndarray:
        """The mouth weights for one frame of audio (float32 samples in [-1, 1])."""
        x = np.asarray(audio, np.float64)
        target, shape = 0.0, _NO_SHAPE
        if len(x) >= 64:
            vowel_power, band_power, weighted = self._sums(x)
            db = 10.0 * np.log10(vowel_power + 1e-10)
            # causal level trackers (module docstring, step 1)
            self.floor_db = db if db < self.floor_db else self.floor_db + self._rise
            self.peak_db = db if db > self.peak_db else self.peak_db - self._decay
            self.floor_db = min(self.floor_db, self.peak_db - RANGE_DB)
            low = max(self.floor_db + 6.0, self.peak_db - RANGE_DB)
            level = (db - low) / max(self.peak_db - low, 1e-6)
            target = 0.0 if level < GATE else min((level - GATE) / (1.0 - GATE), 1.0) ** 1.3
            if target > 0:
                c = float(weighted / max(band_power, 1e-12))  # spectral centroid, Hz
                # clipped to [0, 1] as np.clip does (a NaN stays NaN)
                dark = min(max((1400.0 - c) / 900.0, 0.0), 1.0)
                bright = min(max((c - 2200.0) / 1800.0, 0.0), 1.0)
                shape = np.array([0.5 * dark, 0.3 * dark, 0.35 * bright])
        self.open += (target - self.open) * (ATTACK if target > self.open else RELEASE)
        self.shape += (shape - self.shape) * 0.5
        w = np.zeros(N_BLENDSHAPES, np.float32)
        o = self.open
        s = self.shape * o  # stretch, funnel, pucker: each its float64 product, rounded to float32 as it is stored
        w[_OUT_IDX] = (JAW_MAX * o, 0.35 * o, 0.35 * o, 0.12 * o, 0.12 * o, s[2], s[2], s[0], s[1])
        return w


def speech_frames(samples: np.ndarray, fps: float, n_frames: int, sr: int = timing.AUDIO_SR) -> list[np.ndarray]:
    """The audio chunk of each of ``n_frames`` frames (``timing.frame_sample_bounds``; empty past the end)."""
    out = []
    for k in range(n_frames):
        s, e = timing.frame_sample_bounds(k, fps, sr)
        out.append(np.asarray(samples[int(s) : int(e)], np.float32))
    return out


def speech_mouth_track(frames_audio, fps: float = timing.MODEL_FPS, sr: int = timing.AUDIO_SR) -> np.ndarray:
    """(T, 52) mouth weights for a sequence of per-frame audio chunks (causal, as live)."""
    m = SpeechMouth(fps, sr)
    return (
        np.stack([m.step(a) for a in frames_audio]).astype(np.float32)
        if len(frames_audio)
        else np.zeros((0, N_BLENDSHAPES), np.float32)
    )
