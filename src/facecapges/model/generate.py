"""Gestures for a whole recording, through the same per-frame path as live use.

:func:`prepare_inputs` turns files into per-frame model inputs at the checkpoint's
rate (audio framed, face JSON resampled causally, head rotation aligned) and
:func:`generate_poses` runs the :class:`~facecapges.model.streaming.StreamingGenerator`
frame by frame from a cold start. The result has ``ceil(duration·fps)`` frames.

Missing modalities: without a face track the face is neutral (all weights 0); without
a head track the head is at rest (identity rotation). A face track shorter than the
audio holds its last frame; a longer one is cut.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facecapges import timing
from facecapges.arkit import N_BLENDSHAPES
from facecapges.errors import UserError, file_error
from facecapges.rotations import identity_rot6d


@dataclass
class FrameInputs:
    """Per-frame inputs at the model rate: audio chunks, face weights, head rot6d."""

    audio: np.ndarray  # (T, samples_per_frame)
    face: np.ndarray  # (T, 52)
    head: np.ndarray  # (T, 6)
    fps: float
    notes: list[str]

    @property
    def n_frames(self) -> int:
        return int(self.audio.shape[0])


def _fit(x: np.ndarray, T: int) -> np.ndarray:
    if len(x) >= T:
        return x[:T]
    return np.concatenate([x, np.repeat(x[-1:], T - len(x), 0)])


def prepare_inputs(audio_path: str | Path, face_path: str | Path | None = None, head_path: str | Path | None = None,
                   fps: float = timing.MODEL_FPS, sr: int = timing.AUDIO_SR) -> FrameInputs:
    from facecapges.io.audio import is_silent, load_audio

    notes: list[str] = []
    audio = load_audio(audio_path, sr)
    if len(audio) < timing.samples_per_frame(fps, sr) - 1:
        raise file_error(audio_path, f"audio is shorter than one frame ({len(audio)} samples at {sr} Hz, "
                                     f"one frame is {sr / fps:.0f})")
    if is_silent(audio):
        raise file_error(audio_path, "audio is silent (below -50 dBFS): there is no speech to gesture to")
    T = timing.n_frames_for(len(audio) / sr, fps)
    frames = timing.frame_audio(audio, T, fps, sr)

    face = np.zeros((T, N_BLENDSHAPES), np.float32)
    head = np.broadcast_to(identity_rot6d(), (T, 6)).copy()
    if face_path is not None:
        from facecapges.io.face_json import read_face_json

        track = read_face_json(face_path)
        if track.unknown_names:
            notes.append(f"{face_path}: ignored unknown blendshape names: {', '.join(track.unknown_names)}")
        if track.n_frames == 0:
            raise file_error(face_path, "face track has no frames")
        face_s, audio_s = track.n_frames / track.fps, len(audio) / sr
        if abs(face_s - audio_s) > max(0.5, 0.05 * audio_s):
            notes.append(f"{face_path}: the face track lasts {face_s:.1f} s, the audio {audio_s:.1f} s; "
                         + ("its last frame is held" if face_s < audio_s else "it is cut") + " (are they the same take?)")
        face = _fit(timing.resample(track.weights, track.fps, fps), T).astype(np.float32)
        if track.head_rot6d is not None and head_path is None:
            head = _fit(timing.resample(track.head_rot6d, track.fps, fps), T).astype(np.float32)
    if head_path is not None:
        p = Path(head_path)
        if not p.is_file():
            raise file_error(p, "head rotation file not found")
        try:
            h = np.load(p)
        except Exception:
            raise file_error(p, "not a readable .npy array") from None
        if h.ndim != 2 or h.shape[1] != 6 or len(h) == 0:
            raise file_error(p, f"head rotation must be (T, 6) rot6d at {fps:g} fps, got {h.shape}")
        if not np.isfinite(h).all():
            raise file_error(p, "head rotation contains NaN or infinite values")
        head = _fit(h.astype(np.float32), T)
    return FrameInputs(audio=frames, face=face, head=head, fps=fps, notes=notes)


def generate_poses(checkpoint, inputs: FrameInputs, progress: bool = True) -> tuple[np.ndarray, float]:
    """Run the streaming generator over every frame: poses (T, 47, 6), ms per frame."""
    if abs(inputs.fps - checkpoint.fps) > 1e-6:
        raise UserError(f"inputs are at {inputs.fps} fps, the checkpoint runs at {checkpoint.fps} fps")
    import torch

    gen = checkpoint.streaming()
    T = inputs.n_frames
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # one small step at a time: more threads only spin
    out = np.empty((T, 47, 6), np.float32)
    t0 = time.perf_counter()
    if progress:
        from rich.progress import track

        it = track(range(T), description="generating", transient=True)
    else:
        it = range(T)
    try:
        for t in it:
            out[t] = gen.step(inputs.audio[t], inputs.face[t], inputs.head[t])
    finally:
        torch.set_num_threads(threads)
    ms = (time.perf_counter() - t0) * 1000 / max(T, 1)
    if not np.isfinite(out).all():  # never emit NaN: this would be a model bug
        raise UserError("the model produced non-finite poses; the checkpoint is unusable")
    return out, ms
