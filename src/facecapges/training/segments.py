"""Training data: the clips a run learns from, cut into segments and gathered into batches (thesis 4.1).

* :class:`ClipArrays` — one recording's inputs and targets at the model rate;
  :func:`load_clips` reads them from the prepared cache, :func:`clip_head` cuts a clip's start.
* :class:`SegmentSet` — every clip cut into L = 34-frame segments with stride 10 (eq. 4.1),
  each frame's encoder input its own causal window (N frames further back, zero before a
  clip's start, as the streaming generator sees a stream start); ``gather`` batches them.
* :func:`holdout_frames` / :func:`segment_sets` — the training segments (frames before each
  clip's hold-out frame) and the held-out ones; :func:`hold_head_still` — head dropout on a batch.

The trainer (:mod:`facecapges.training.train`) uses them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from facecapges.data.cache import FrameArrays
from facecapges.errors import UserError
from facecapges.network.config import ModelConfig, TrainConfig
from facecapges.rotations import identity_rot6d
from facecapges.timing import frame_audio, frame_sample_bounds
from facecapges.training.masking import mirrored


@dataclass
class ClipArrays(FrameArrays):
    """One recording's model inputs and targets at the model rate (:class:`FrameArrays`: name, pose,
    head, face, audio) and which joints have real motion."""

    mask: np.ndarray | None = None  # (47,) or (T, 47) bool: joints with real motion (None: all)


def load_clips(cache_path: Path, speaker: int, split: str):
    """The prepared cache at ``cache_path`` and the :class:`ClipArrays` of ``speaker``'s ``split`` clips."""
    from facecapges.data.cache import Cache

    cache = Cache(cache_path)
    clips = []
    for e in cache.select(speaker, split):
        a = cache.load(e["name"])
        clips.append(
            ClipArrays(name=e["name"], pose=a["pose"], head=a["head"], face=a["face"], audio=a["audio"], mask=a["mask"])
        )
    return cache, clips


def clip_head(c: ClipArrays, n_frames: int, fps: float, sr: int) -> ClipArrays:
    """The first ``n_frames`` of a clip (audio cut at the first sample frame ``n_frames`` would own)."""
    S = int(frame_sample_bounds(n_frames, fps, sr)[0])
    mask = c.mask if c.mask is None or np.ndim(c.mask) == 1 else c.mask[:n_frames]
    return ClipArrays(c.name, c.pose[:n_frames], c.head[:n_frames], c.face[:n_frames], c.audio[:S], mask)


class SegmentSet:
    """All clips concatenated (each preceded by N zero frames) + segment start indices.

    ``gather(idx)`` returns batched tensors for segments ``idx``: inputs of
    N + L frames (each segment frame's causal window) and the L poses.
    """

    def __init__(
        self,
        clips: list[ClipArrays],
        cfg: ModelConfig,
        clip_len: int,
        stride: int,
        frame_range: tuple[int, int | None] | list[tuple[int, int | None]] = (0, None),
    ):
        N = cfg.n_history
        self.N, self.L = N, clip_len

        def pad(x: np.ndarray) -> np.ndarray:  # N zero frames ahead of the clip: the first window's history
            return np.concatenate([np.zeros((N,) + x.shape[1:], np.float32), x.astype(np.float32)])

        audio, face, head, pose, starts, mask = [], [], [], [], [], []
        offset = 0
        ranges = frame_range if isinstance(frame_range, list) else [frame_range] * len(clips)
        for c, (lo, hi) in zip(clips, ranges):
            T = len(c.pose)
            hi = T if hi is None else min(hi, T)
            a = frame_audio(c.audio, T, cfg.fps, cfg.sr)
            audio.append(pad(a))
            face.append(pad(c.face))
            head.append(pad(c.head))
            pose.append(pad(c.pose.reshape(T, -1)))
            m = np.ones(c.pose.shape[1], bool) if c.mask is None else np.asarray(c.mask, bool)
            mask.append(pad(np.broadcast_to(m, (T, c.pose.shape[1]))))
            for s in range(lo, hi - clip_len + 1, stride):
                starts.append(offset + N + s)  # index of the segment's first frame
            offset += T + N
        if not starts:
            raise UserError(f"no {clip_len}-frame segment fits in the selected frames of {len(clips)} clip(s)")
        self.audio = np.concatenate(audio)
        self.face = np.concatenate(face)
        self.head = np.concatenate(head)
        self.pose = np.concatenate(pose)
        self.mask = np.concatenate(mask)  # (frames, 47) float32, 1 = joint present
        self.starts = np.array(starts)

    def __len__(self) -> int:
        return len(self.starts)

    def gather(self, idx: np.ndarray) -> dict[str, torch.Tensor]:
        s = self.starts[idx]
        win = s[:, None] + np.arange(-self.N, self.L)[None]  # (B, N + L)
        seg = s[:, None] + np.arange(self.L)[None]
        return {
            "audio": torch.from_numpy(self.audio[win]),
            "face": torch.from_numpy(self.face[win]),
            "head": torch.from_numpy(self.head[win]),
            "pose": torch.from_numpy(self.pose[seg]),
            "mask": torch.from_numpy(self.mask[seg]),
        }


def hold_head_still(head: torch.Tensor, p: float) -> torch.Tensor:
    """``TrainConfig.head_dropout``: each segment's head input (B, N + L, 6), with chance
    ``p``, set in place to the identity rotation — "facing the camera" in the model's
    camera frame (:mod:`facecapges.capture.head_pose`), what a still head or an audio
    file without a head track gives the style at run time. Drawn from torch's generator,
    which ``train_epoch`` seeds per epoch (a resumed run draws the same segments)."""
    held = torch.rand(head.shape[0]) < p
    if bool(held.any()):
        head[held] = torch.from_numpy(identity_rot6d()).to(head)
    return head


def holdout_frames(clips: list[ClipArrays], tcfg: TrainConfig) -> list[int | None]:
    """Per clip, its first held-out frame (None: no hold-out) — ``holdout_fraction`` or ``holdout_from``."""
    if tcfg.holdout_fraction:
        return [int(math.floor(len(c.pose) * (1.0 - tcfg.holdout_fraction))) for c in clips]
    return [tcfg.holdout_from] * len(clips)


def segment_sets(clips: list[ClipArrays], mcfg: ModelConfig, tcfg: TrainConfig) -> tuple[SegmentSet, SegmentSet | None]:
    """Training segments (frames < each clip's hold-out frame) and held-out ones (frames ≥ it, or None)."""
    F_ = holdout_frames(clips, tcfg)
    train_ranges = [(0, f) for f in F_]
    train_clips = clips
    if getattr(tcfg, "mirror", False):
        train_clips, train_ranges = clips + [mirrored(c) for c in clips], train_ranges * 2
    train_set = SegmentSet(train_clips, mcfg, tcfg.clip_len, tcfg.stride, train_ranges)
    held_set = None
    if any(f is not None for f in F_):
        try:
            held_set = SegmentSet(
                clips,
                mcfg,
                tcfg.clip_len,
                tcfg.stride,
                [(len(c.pose) if f is None else f, None) for c, f in zip(clips, F_)],
            )
        except UserError:  # too few held-out frames for one segment
            held_set = None
    return train_set, held_set
