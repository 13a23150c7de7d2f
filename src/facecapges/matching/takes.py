"""Paired takes (motion + speech) as the matching engine reads them, at the model rate.

A :class:`Take` is one recording of a speaker: the upper-body pose (rot6d, 15 fps), the speech
(16 kHz), the face (ARKit weights, zeros where the take has none), the head rotation and the
skeleton the pose belongs to. Frames from ``train_until`` on are the take's held-out 20 %: the
database, the predictor and every choice use only frames before it.

Loaders:

* :func:`load_bvh_take` — a BVH of the BEAT skeleton at any rate (resampled to 15 fps by BEAT's
  rule, :func:`facecapges.timing.resample`), or of another skeleton (ZEGGS, a user's mocap):
  retargeted onto a BEAT ``target`` skeleton with :mod:`facecapges.data.retarget`.
* :func:`load_take` — dispatches on the motion file's suffix (``.bvh``; ``.npz`` BEAT2 when
  :mod:`facecapges.data.beat2` is present).
* :func:`mirror_take` — the left/right mirror image (:mod:`facecapges.data.mirror`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from facecapges import timing
from facecapges.arkit import N_BLENDSHAPES
from facecapges.data.cache import FrameArrays, holdout_frame
from facecapges.errors import UserError, file_error
from facecapges.skeleton import UPPER_BODY, Skeleton, motion_to_pose, pose_head_rot6d


@dataclass
class Take(FrameArrays):
    """One paired take at the model rate (module docs): :class:`FrameArrays` (name; pose, head, face
    float32; audio float32 of S = floor(T · 16000 / 15) samples) and what the engine needs besides."""

    skeleton: Skeleton
    train_until: int  # frames >= this are the held-out 20 %: never used
    mirrored: bool = False
    source: str = ""  # the motion file it came from (for the model card)
    licence: str = ""
    notes: tuple[str, ...] = ()  # warnings about the files (e.g. speech a little longer than the motion)


def fit_audio(audio: np.ndarray, T: int, fps: float = timing.MODEL_FPS, sr: int = timing.AUDIO_SR) -> np.ndarray:
    """Audio cut or zero-padded to the samples of ``T`` frames."""
    S = timing.audio_samples(T, fps, sr)
    out = np.zeros(S, np.float32)
    n = min(S, len(audio))
    out[:n] = audio[:n]
    return out


def make_take(
    name: str,
    pose: np.ndarray,
    audio: np.ndarray,
    skeleton: Skeleton,
    face: np.ndarray | None = None,
    head: np.ndarray | None = None,
    **extra,
) -> Take:
    """A :class:`Take` from its arrays (audio fitted to the pose's length, train_until = floor(0.8 T))."""
    pose = np.asarray(pose, np.float32)
    T = len(pose)
    if T < 30:
        raise UserError(f"{name}: {T} frames at {timing.MODEL_FPS} fps is too short for a take (2 s at least)")
    face = np.zeros((T, N_BLENDSHAPES), np.float32) if face is None else np.asarray(face, np.float32)
    head = pose_head_rot6d(skeleton, pose) if head is None else np.asarray(head, np.float32)
    return Take(
        name=name,
        pose=pose,
        audio=fit_audio(np.asarray(audio, np.float32), T),
        face=face,
        head=head.astype(np.float32),
        skeleton=skeleton,
        train_until=holdout_frame(T),
        **extra,
    )


def speech_notes(motion_path: Path, wav_path: Path, n_frames: int, audio: np.ndarray) -> tuple[str, ...]:
    """() when the speech matches the motion's length, a warning when it is a few frames off; a UserError
    beyond :data:`facecapges.timing.MISMATCH_REFUSE_SHARE` (:func:`facecapges.timing.length_mismatch`)."""
    mismatch = timing.length_mismatch(n_frames, timing.MODEL_FPS, len(audio) / timing.AUDIO_SR)
    if mismatch is None:
        return ()
    text, refuse = mismatch
    if refuse:
        raise file_error(
            wav_path,
            f"does not match {motion_path.name}: {text}; more than "
            f"{timing.MISMATCH_REFUSE_SHARE:.0%} apart (wrong file or wrong frame rate?)",
        )
    return (f"{wav_path.name}: {text}",)


def load_bvh_take(bvh_path: str | Path, wav_path: str | Path, target: Skeleton | None = None) -> Take:
    """A BVH take + its speech; a non-BEAT skeleton is retargeted onto ``target`` (module docs)."""
    from facecapges.io.audio import load_audio
    from facecapges.io.bvh import read_bvh

    bvh_path, wav_path = Path(bvh_path), Path(wav_path)
    bvh = read_bvh(bvh_path)
    audio = load_audio(wav_path)
    if not bvh.skeleton.missing(UPPER_BODY):
        motion = timing.resample(bvh.motion, bvh.fps, timing.MODEL_FPS)
        pose, head = motion_to_pose(bvh.skeleton, motion)
        notes = speech_notes(bvh_path, wav_path, len(pose), audio)
        return make_take(
            bvh_path.stem, pose, audio, bvh.skeleton, head=head, source=str(bvh_path), licence="", notes=notes
        )
    if target is None:
        raise file_error(bvh_path, "not a BEAT skeleton, and no BEAT skeleton was given to retarget it onto")
    from facecapges.data.retarget import retarget_bvh

    r = retarget_bvh(bvh_path, target, fps=timing.MODEL_FPS)
    notes = speech_notes(bvh_path, wav_path, len(r.pose), audio)
    return make_take(bvh_path.stem, r.pose, audio, target, source=str(bvh_path), licence=r.licence, notes=notes)


def load_take(motion_path: str | Path, wav_path: str | Path, target: Skeleton | None = None) -> Take:
    """A take from a motion file (``.bvh``; ``.npz`` BEAT2) and its ``.wav`` (clear errors otherwise)."""
    from facecapges.io.audio import check_audio

    motion_path, wav_path = Path(motion_path), Path(wav_path)
    if not motion_path.is_file():
        raise file_error(motion_path, "motion file not found")
    check_audio(wav_path)
    suffix = motion_path.suffix.lower()
    if suffix == ".bvh":
        return load_bvh_take(motion_path, wav_path, target)
    if suffix == ".npz":
        return load_beat2_take(motion_path, wav_path, target)
    raise file_error(motion_path, "unknown motion format (expected a .bvh or a BEAT2 .npz)")


def load_beat2_take(npz_path: Path, wav_path: Path, target: Skeleton | None) -> Take:
    """A BEAT2 SMPL-X take (:mod:`facecapges.data.beat2`: BEAT upper body + jawOpen face) on ``target``.

    ``target`` is the BEAT skeleton the poses belong to (BEAT2 has none of its own): a BEAT BVH's
    or a style's (:func:`facecapges.styles.load_skeleton`).
    """
    from facecapges.data import beat2
    from facecapges.io.audio import load_audio

    if target is None:
        raise file_error(npz_path, "a BEAT2 take needs a BEAT skeleton to put its poses on")
    pose, face = beat2.load_beat2_take(npz_path, fps=timing.MODEL_FPS)
    audio = load_audio(wav_path)
    notes = speech_notes(npz_path, wav_path, len(pose), audio)
    return make_take(
        npz_path.stem, pose, audio, target, face=face, source=str(npz_path), licence="CC BY-NC 4.0", notes=notes
    )


def mirror_take(take: Take) -> Take:
    """The take's left/right mirror image (pose, head and face; the same audio)."""
    return replace(take, **take.mirror_arrays(), mirrored=not take.mirrored)
