"""A mouth that speaks without a face: jaw and lips from the speech, causally, frame by frame.

When there is no face track (the demo, ``generate``, audio-only ``live``, a face that
left the frame) the avatar would speak with a closed mouth. :class:`SpeechMouth` turns
each model frame's audio (the 1066–1067 samples the model gets, :mod:`facecapges.timing`)
into mouth blendshapes, using that frame and the past only:

1. **loudness** — the frame's RMS level in dB, placed between a running noise floor
   and a running speech peak (both causal trackers: the floor follows quiet frames at
   once and rises 1.5 dB/s, the peak follows loud frames at once and decays 3 dB/s),
   so the same mapping works for a quiet microphone and a loud file without
   calibration. ``openness = ((level − floor) / (peak − floor))`` clamped to [0, 1],
   zero below a gate of 0.2 (breaths and room noise do not move the jaw);
2. **shape** — the spectral centroid of the frame (Hann window, 80 Hz–5 kHz): dark,
   rounded vowels (low centroid: o, u) add ``mouthFunnel`` / ``mouthPucker``, bright
   sounds (high centroid: i, e, s) add ``mouthStretch``;
3. **motion** — an attack/release filter (opens within ~2 frames, closes within ~4),
   so syllables read as the jaw moving rather than flickering.

``jawOpen`` peaks at 0.55, about what MediaPipe measures on the shared talking-head
clip at a loud syllable (a speaking mouth is rarely wide open). The constants are
chosen once, a priori, from these physical ranges — none was fitted on an evaluation clip.
"""

from __future__ import annotations

import numpy as np

from facecapges import timing
from facecapges.arkit import ARKIT_NAMES, N_BLENDSHAPES

JAW_MAX = 0.55
GATE = 0.2
_IDX = {n: ARKIT_NAMES.index(n) for n in ARKIT_NAMES}
MOUTH_NAMES = ("jawOpen", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft", "mouthUpperUpRight",
               "mouthStretchLeft", "mouthStretchRight", "mouthFunnel", "mouthPucker")  # the weights it drives


class SpeechMouth:
    """Per-frame mouth weights (52,) from that frame's audio (module docstring)."""

    def __init__(self, fps: float = timing.MODEL_FPS, sr: int = timing.AUDIO_SR):
        self.fps, self.sr = float(fps), int(sr)
        self.floor_db, self.peak_db = -55.0, -25.0
        self.open = 0.0
        self.shape = np.zeros(3)  # funnel, pucker, stretch
        self._rise = 1.5 / self.fps  # dB per frame
        self._decay = 3.0 / self.fps

    def reset(self) -> None:
        self.__init__(self.fps, self.sr)

    def _centroid(self, x: np.ndarray) -> float:
        spec = np.abs(np.fft.rfft(x * np.hanning(len(x)))) ** 2
        f = np.fft.rfftfreq(len(x), 1.0 / self.sr)
        band = (f >= 80) & (f <= 5000)
        p = spec[band]
        return float((f[band] * p).sum() / max(p.sum(), 1e-12))

    def step(self, audio: np.ndarray) -> np.ndarray:
        """The mouth weights for one frame of audio (float32 samples in [-1, 1])."""
        x = np.asarray(audio, np.float64)
        rms = float(np.sqrt(np.mean(x * x))) if len(x) else 0.0
        db = 20.0 * np.log10(rms + 1e-6)
        # causal level trackers (module docstring, step 1)
        self.floor_db = db if db < self.floor_db else self.floor_db + self._rise
        self.peak_db = db if db > self.peak_db else self.peak_db - self._decay
        self.floor_db = min(self.floor_db, self.peak_db - 20.0)
        self.peak_db = max(self.peak_db, self.floor_db + 20.0)
        level = (db - self.floor_db) / (self.peak_db - self.floor_db)
        target = 0.0 if level < GATE else min((level - GATE) / (1.0 - GATE), 1.0)
        self.open += (target - self.open) * (0.65 if target > self.open else 0.4)
        shape = np.zeros(3)
        if target > 0 and len(x) >= 64:
            c = self._centroid(x)
            dark = float(np.clip((1400.0 - c) / 900.0, 0.0, 1.0))
            bright = float(np.clip((c - 2200.0) / 1800.0, 0.0, 1.0))
            shape = np.array([0.5 * dark, 0.3 * dark, 0.35 * bright])
        self.shape += (shape - self.shape) * 0.5
        w = np.zeros(N_BLENDSHAPES, np.float32)
        o = self.open
        w[_IDX["jawOpen"]] = JAW_MAX * o
        for side in ("Left", "Right"):
            w[_IDX[f"mouthLowerDown{side}"]] = 0.35 * o
            w[_IDX[f"mouthUpperUp{side}"]] = 0.12 * o
            w[_IDX[f"mouthStretch{side}"]] = self.shape[2] * o
        w[_IDX["mouthFunnel"]] = self.shape[0] * o
        w[_IDX["mouthPucker"]] = self.shape[1] * o
        return w


def speech_mouth_track(frames_audio, fps: float = timing.MODEL_FPS, sr: int = timing.AUDIO_SR) -> np.ndarray:
    """(T, 52) mouth weights for a sequence of per-frame audio chunks (causal, as live)."""
    m = SpeechMouth(fps, sr)
    return np.stack([m.step(a) for a in frames_audio]).astype(np.float32) if len(frames_audio) else \
        np.zeros((0, N_BLENDSHAPES), np.float32)
