"""A recording's inputs, planned frame by frame at an engine's rate (the one generation loop that
consumes them: :mod:`facecapges.engine.generate`).

:func:`prepare_inputs` turns files into per-frame model inputs at the engine's
rate (audio framed, face JSON resampled causally, head rotation aligned; a loaded style plans
them at its own rate: :meth:`GestureEngine.plan_inputs <facecapges.engine.contract.GestureEngine.plan_inputs>`).
A recording gives ``ceil(duration·fps)`` frames.

Long recordings: :func:`plan_inputs` checks the files (the silence check reads the
audio block by block) and :meth:`StreamedInputs.blocks` hands out the audio frames a
block at a time, so :func:`generate_blocks` and a block-wise writer (``generate``
writes the BVH with :class:`facecapges.io.bvh.BvhWriter`) keep memory flat in the
input's length; only the face and head tracks (232 bytes per frame) are held whole.

Missing modalities: without a face track the face is neutral (all weights 0); without
a head track the head is at rest (identity rotation). A face track shorter than the
audio holds its last frame; a longer one is cut.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facecapges import timing
from facecapges.arkit import N_BLENDSHAPES
from facecapges.errors import file_error
from facecapges.rotations import identity_rot6d

BLOCK_FRAMES = 900  # frames per block when a recording is streamed (1 min at 15 fps)


def finite(a: np.ndarray) -> np.ndarray:
    """``a`` with NaN and ±inf set to 0 (as ``np.nan_to_num(..., nan=0, posinf=0, neginf=0)``, cheaper on small
    arrays); ``a`` itself when it is all finite (callers read it, never write it)."""
    if np.isfinite(a).all():  # the usual case: no copy
        return a
    return np.where(np.isfinite(a), a, a.dtype.type(0))


def pack_audio(frames, samples_per_frame: int) -> np.ndarray:
    """Per-stream frame audio (a sequence of arrays of ≤ S samples each) → (B, S) float32, zero padded, NaN → 0."""
    out = np.zeros((len(frames), samples_per_frame), np.float32)
    for i, a in enumerate(frames):
        a = np.asarray(a, dtype=np.float32).reshape(-1)
        if a.shape[0] > samples_per_frame:
            raise ValueError(f"a frame owns at most {samples_per_frame} audio samples, got {a.shape[0]}")
        out[i, : a.shape[0]] = a
    return finite(out)


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


@dataclass
class StreamedInputs:
    """Inputs of a long recording, read block by block: face and head for every frame
    (small: 232 bytes per frame) and the audio frames only while :meth:`blocks` runs."""

    audio_path: Path
    n_frames: int
    face: np.ndarray  # (T, 52)
    head: np.ndarray  # (T, 6)
    fps: float
    sr: int
    notes: list[str]

    def blocks(self, block_frames: int = BLOCK_FRAMES):
        """(audio (n, samples_per_frame), face (n, 52), head (n, 6)) for consecutive frames."""
        from facecapges.io.audio import audio_blocks

        spf = timing.samples_per_frame(self.fps, self.sr)
        stream = audio_blocks(self.audio_path, self.sr)
        buf, offset, k = np.zeros(0, np.float32), 0, 0  # buf[0] is sample `offset` of the file
        while k < self.n_frames:
            kb = min(self.n_frames, k + block_frames)
            starts, ends = timing.frame_sample_bounds(np.arange(k, kb), self.fps, self.sr)
            while offset + len(buf) < ends[-1]:
                more = next(stream, None)
                if more is None:
                    break
                buf = np.concatenate([buf, more])
            audio = np.zeros((kb - k, spf), np.float32)  # frames past the end of the audio are silent
            for row, (a, b) in enumerate(zip(starts - offset, ends - offset)):
                chunk = buf[a:b]
                audio[row, : len(chunk)] = chunk
            buf, offset = buf[starts[-1] - offset :], int(starts[-1])
            yield audio, self.face[k:kb], self.head[k:kb]
            k = kb


def plan_inputs(
    audio_path: str | Path,
    face_path: str | Path | None = None,
    head_path: str | Path | None = None,
    fps: float = timing.MODEL_FPS,
    sr: int = timing.AUDIO_SR,
) -> StreamedInputs:
    """Check the input files and read everything but the audio (module docstring); memory flat in length."""
    from facecapges.io.audio import SILENCE_DB, audio_level

    notes: list[str] = []
    audio_s, level_db = audio_level(audio_path)  # block by block: 1 h of silence is refused in flat memory
    if audio_s * sr < timing.samples_per_frame(fps, sr) - 1:
        raise file_error(
            audio_path,
            f"audio is shorter than one frame ({audio_s * sr:.0f} samples at {sr} Hz, one frame is {sr / fps:.0f})",
        )
    if level_db < SILENCE_DB:
        raise file_error(audio_path, "audio is silent (below -50 dBFS): there is no speech to gesture to")
    T = timing.n_frames_for(audio_s, fps)

    face = np.zeros((T, N_BLENDSHAPES), np.float32)
    head = np.broadcast_to(identity_rot6d(), (T, 6)).copy()
    if face_path is not None:
        from facecapges.io.face_json import read_face_json

        track = read_face_json(face_path)
        if track.unknown_names:
            notes.append(f"{face_path}: ignored unknown blendshape names: {', '.join(track.unknown_names)}")
        if track.n_frames == 0:
            raise file_error(face_path, "face track has no frames")
        face_s = track.n_frames / track.fps
        if abs(face_s - audio_s) > max(0.5, 0.05 * audio_s):
            notes.append(
                f"{face_path}: the face track lasts {face_s:.1f} s, the audio {audio_s:.1f} s; "
                + ("its last frame is held" if face_s < audio_s else "it is cut")
                + " (are they the same take?)"
            )
        face = _fit(timing.resample(track.weights, track.fps, fps), T).astype(np.float32)
        if track.head_rot6d is not None and head_path is None:
            head = _fit(timing.resample(track.head_rot6d, track.fps, fps), T).astype(np.float32)
    if head_path is not None:
        p = Path(head_path)
        if not p.is_file():
            raise file_error(p, "head rotation file not found")
        try:
            h = np.load(p)
        except Exception:  # noqa: BLE001  numpy raises many types for a bad file; all mean unreadable
            raise file_error(p, "not a readable .npy array") from None
        if h.ndim != 2 or h.shape[1] != 6 or len(h) == 0:
            raise file_error(p, f"head rotation must be (T, 6) rot6d at {fps:g} fps, got {h.shape}")
        if not np.isfinite(h).all():
            raise file_error(p, "head rotation contains NaN or infinite values")
        head = _fit(h.astype(np.float32), T)
    return StreamedInputs(Path(audio_path), T, face, head, fps, sr, notes)


def prepare_inputs(
    audio_path: str | Path,
    face_path: str | Path | None = None,
    head_path: str | Path | None = None,
    fps: float = timing.MODEL_FPS,
    sr: int = timing.AUDIO_SR,
) -> FrameInputs:
    """Every frame's inputs in memory (:func:`plan_inputs` + all its blocks at once)."""
    plan = plan_inputs(audio_path, face_path, head_path, fps, sr)
    audio = (
        np.concatenate([a for a, _, _ in plan.blocks()])
        if plan.n_frames
        else np.zeros((0, timing.samples_per_frame(fps, sr)), np.float32)
    )
    return FrameInputs(audio=audio, face=plan.face, head=plan.head, fps=fps, notes=plan.notes)
