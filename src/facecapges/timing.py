"""Frame rate, audio rate and how frames own audio samples — defined once.

* The model rate is ``MODEL_FPS`` = 15 frames/s (configurable per checkpoint); audio
  is mono float32 at ``AUDIO_SR`` = 16 000 Hz.
* Frame ``i`` (time ``i / fps`` s) owns audio samples
  ``floor(i·sr/fps) … floor((i+1)·sr/fps) − 1``: 1066 or 1067 samples at 15 fps
  (:func:`frame_sample_bounds`). The model sees each frame's samples zero-padded on
  the right to ``samples_per_frame(fps, sr) = ceil(sr/fps)`` = 1067.
* Resampling follows BEAT: an integer ratio keeps every k-th frame (120→15 keeps
  every 8th, 60→15 every 4th, starting at frame 0); any other ratio takes the
  nearest source frame at or before each target time (never a future one).
* A sequence of ``D`` seconds has ``ceil(D·fps)`` frames (:func:`n_frames_for`).
"""

from __future__ import annotations

import math

import numpy as np

MODEL_FPS = 15
AUDIO_SR = 16_000


def samples_per_frame(fps: float = MODEL_FPS, sr: int = AUDIO_SR) -> int:
    """Largest number of samples a frame owns (1067 at 15 fps, 16 kHz)."""
    return math.ceil(sr / fps)


def frame_sample_bounds(i: int | np.ndarray, fps: float = MODEL_FPS, sr: int = AUDIO_SR):
    """Start (inclusive) and end (exclusive) sample index of frame ``i``."""
    i = np.asarray(i)
    start = np.floor(i * sr / fps).astype(np.int64)
    end = np.floor((i + 1) * sr / fps).astype(np.int64)
    return start, end


def audio_samples(n_frames: int, fps: float = MODEL_FPS, sr: int = AUDIO_SR) -> int:
    """Samples ``n_frames`` frames own (:func:`frame_sample_bounds`): floor(T·sr/fps), tolerant to float noise."""
    return int(math.floor(n_frames * sr / fps + 1e-6))


def n_frames_for(duration_s: float, fps: float = MODEL_FPS) -> int:
    """Frames covering ``duration_s`` seconds: ceil(duration·fps), tolerant to float noise."""
    return int(math.ceil(duration_s * fps - 1e-6))


def frame_audio(
    audio: np.ndarray, n_frames: int | None = None, fps: float = MODEL_FPS, sr: int = AUDIO_SR
) -> np.ndarray:
    """Cut mono audio (S,) into per-frame chunks (T, samples_per_frame), zero-padded.

    ``n_frames`` defaults to ``n_frames_for(len(audio)/sr)``; frames past the end of
    the audio are silent.
    """
    audio = np.asarray(audio, dtype=np.float32)
    if n_frames is None:
        n_frames = n_frames_for(len(audio) / sr, fps)
    spf = samples_per_frame(fps, sr)
    out = np.zeros((n_frames, spf), np.float32)
    starts, ends = frame_sample_bounds(np.arange(n_frames), fps, sr)
    for t, (s, e) in enumerate(zip(starts, ends)):
        chunk = audio[s : min(e, len(audio))]
        out[t, : len(chunk)] = chunk
    return out


def resample_indices(n_src: int, src_fps: float, dst_fps: float = MODEL_FPS) -> np.ndarray:
    """Source frame index for each target frame (causal: never a later source frame)."""
    if src_fps <= 0 or dst_fps <= 0:
        raise ValueError(f"frame rates must be positive, got {src_fps} and {dst_fps}")
    ratio = src_fps / dst_fps
    if abs(ratio - round(ratio)) < 1e-6 and round(ratio) >= 1:
        return np.arange(0, n_src, int(round(ratio)))
    n_dst = n_frames_for(n_src / src_fps, dst_fps)
    idx = np.floor(np.arange(n_dst) * ratio + 1e-9).astype(np.int64)
    return np.clip(idx, 0, n_src - 1)


def resample(frames: np.ndarray, src_fps: float, dst_fps: float = MODEL_FPS) -> np.ndarray:
    """Resample a (T, ...) sequence from ``src_fps`` to ``dst_fps`` by :func:`resample_indices`."""
    return frames[resample_indices(len(frames), src_fps, dst_fps)]


#: Motion and its speech may differ by this many model frames without a word; beyond it a warning, and
#: beyond ``MISMATCH_REFUSE_SHARE`` of the motion's length a refusal (issue #34: a 5-s wav padded to 63.8 s of
#: motion, or a take declaring 1000 fps, taught a style silence).
MISMATCH_WARN_FRAMES = 5
MISMATCH_REFUSE_SHARE = 0.10


def length_mismatch(n_frames: int, fps: float, speech_s: float) -> tuple[str, bool] | None:
    """How motion of ``n_frames`` at ``fps`` and speech of ``speech_s`` seconds disagree: None when within
    :data:`MISMATCH_WARN_FRAMES`, else (the problem in words, whether it is beyond
    :data:`MISMATCH_REFUSE_SHARE` of the motion and so must be refused)."""
    motion_s = n_frames / fps
    diff = speech_s - motion_s
    if abs(diff) * fps <= MISMATCH_WARN_FRAMES:
        return None
    effect = "its end is cut" if diff > 0 else f"{-diff:.1f} s of silence are added"
    text = f"the speech lasts {speech_s:.1f} s and the motion {motion_s:.1f} s ({effect})"
    return text, abs(diff) > MISMATCH_REFUSE_SHARE * motion_s
