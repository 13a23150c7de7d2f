"""The speech reader of the motion-matching engine: the near future of the arms, from the last second of speech.

Each frame it estimates, causally, what the database is searched by (:mod:`facecapges.matching.targets`):
the mean wrist speed and wrist height over the next 0.3 s and 0.6 s (:data:`TARGET_NAMES`, in the
targets' own units), and the probability that the speaker is speaking now.

**Network** (:class:`SpeechReader`). The thesis's causal encoders from :mod:`facecapges.network.network`
— :class:`~facecapges.network.network.AudioEncoder` (Mel or raw front end, 12-layer kernel-2 TCN),
:class:`~facecapges.network.network.FaceEncoder` (8-layer TCN, the audio embedding joined at layer 8)
and :class:`~facecapges.network.network.HeadEncoder` (6 → 36 → 12) — built from a
:class:`~facecapges.network.config.ModelConfig` with the thesis's dilations (receptive field 17
frames, 1.1 s) and the same or smaller widths (:class:`PredictorSettings`), then a small MLP
``[z_A; z_F; z_H] → K + 1`` (the K normalised targets and the speaking logit). Trained from
scratch on the style's own takes: never initialised from a shipped style.

**Training** and its figures: :mod:`facecapges.matching.predictor_training`.

**Inputs at run time**: per frame ≤ 1067 samples of 16 kHz audio, the 52 ARKit weights (zeros: no
face) and the head rotation as rot6d in the model's camera frame (identity: facing the camera, the
speaker's mean head rotation in the takes; :meth:`Predictor.camera_head` maps a take's skeleton
head into it, as the thesis trainer does).

**Speaking labels** (:func:`speaking_frames`): the engine's energy VAD with hangover
(:mod:`facecapges.matching.speech`, the one the database annotates with) over the take's own audio.

**Streaming** (:class:`BatchedPredictor`, :class:`PredictorStream`) runs the encoders through the
generator's kernel (:class:`facecapges.network.batched.BatchedEncoders`: TCN shift registers, native
small-batch loops), so a frame costs one tap per TCN layer; its outputs equal the network's
over the whole sequence (tested).

How the sizes were chosen, and the validation and held-out figures: docs/matching.md.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from facecapges import timing
from facecapges.engine.slots import Slots
from facecapges.matching.targets import TARGET_NAMES
from facecapges.network.audio_features import FEATURE_DIM, AudioFeatures
from facecapges.network.config import ModelConfig
from facecapges.network.network import (
    AudioEncoder,
    FaceEncoder,
    HeadEncoder,
    MelFrontend,
    mlp,
)

K = len(TARGET_NAMES)
OUTPUT_NAMES: tuple[str, ...] = (*TARGET_NAMES, "speaking")
FORMAT = "facecapges-speech-predictor"
VERSION = 1


# --------------------------------------------------------------------------- speaking labels
def speaking_frames(audio: np.ndarray, n_frames: int) -> np.ndarray:
    """(T,) bool: the engine's own VAD (:func:`facecapges.matching.speech.speech_track`) over the audio —
    the speaking state the database annotates its frames with, so the probability predicted here
    means what the database's ``speaking`` feature means."""
    from facecapges.matching.speech import speech_track

    return np.asarray(speech_track(audio, n_frames).speaking, bool)


# --------------------------------------------------------------------------- the network
@dataclass(frozen=True)
class PredictorSettings:
    """Sizes and training settings (ours; the widths the thesis's ModelConfig or smaller)."""

    audio_repr: str = "mel"  # "mel" or "raw" (ModelConfig.audio_repr)
    audio_tcn_channels: int = 32  # the thesis config: 64
    audio_dim: int = 32  # 128
    face_tcn_channels: int = 32  # 32
    face_dim: int = 8  # 32
    head_dim: int = 12  # 12
    hidden: int = 32  # the output MLP's hidden width
    dropout: float = 0.1  # on the embeddings [z_A; z_F; z_H] before the output MLP, training only
    segment: int = 48  # training segment (frames); the first 16 only warm the TCNs up
    batch: int = 32
    steps: int = 800  # at most; early stopping usually ends before
    lr: float = 2e-3
    weight_decay: float = 1e-4
    face_dropout: float = 0.5
    head_dropout: float = 0.5
    eval_every: int = 25
    patience: int = 8  # evaluations without a better validation loss
    speaking_weight: float = 0.5

    def model_config(self) -> ModelConfig:
        return ModelConfig(
            audio_repr=self.audio_repr,
            audio_tcn_channels=self.audio_tcn_channels,
            audio_dim=self.audio_dim,
            face_tcn_channels=self.face_tcn_channels,
            face_dim=self.face_dim,
            head_dim=self.head_dim,
        ).validate()


class SpeechReader(nn.Module):
    """The thesis's causal encoders + an MLP: per frame (audio, face, head) → K + 1 outputs (module docs)."""

    def __init__(self, cfg: ModelConfig, hidden: int, dropout: float = 0.0):
        super().__init__()
        self.cfg = cfg.validate()
        self.dropout = float(dropout)
        self.audio_enc = AudioEncoder(cfg)
        self.face_enc = FaceEncoder(cfg)
        self.head_enc = HeadEncoder(cfg)
        self.out = mlp([cfg.audio_dim + cfg.face_dim + cfg.head_dim, hidden, hidden, K + 1])

    def audio_input(self, audio: torch.Tensor) -> torch.Tensor:
        """(B, T, S) samples, or (B, T, 43) precomputed Mel features → (B, T, C) the audio TCN's input."""
        front = self.audio_enc.frontend
        if isinstance(front, MelFrontend) and audio.shape[-1] == FEATURE_DIM:
            return front.out(F.leaky_relu(front.proj(audio), 0.2))  # MelFrontend.forward past its features
        return front(audio)

    def forward(self, audio: torch.Tensor, face: torch.Tensor, head: torch.Tensor) -> torch.Tensor:
        """Whole sequences, causally: audio (B, T, S | 43), face (B, T, 52), head (B, T, 6) → (B, T, K + 1)."""
        z_a = self.audio_enc.from_features(self.audio_input(audio))
        z = torch.cat([z_a, self.face_enc(face, z_a), self.head_enc(head)], -1)
        return self.out(F.dropout(z, self.dropout, self.training))


# --------------------------------------------------------------------------- data
def camera_head(head: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """A take's skeleton-frame head rotations (T, 6) → the model's camera frame (reference = facing it)."""
    from facecapges.capture.head_pose import skeleton_head_to_camera

    return skeleton_head_to_camera(head, reference)


def audio_frames(audio: np.ndarray, n_frames: int, cfg: ModelConfig) -> np.ndarray:
    """The network's audio input of ``n_frames`` frames: samples (T, 1067), or Mel features (T, 43)."""
    frames = timing.frame_audio(audio, n_frames, cfg.fps, cfg.sr)
    if cfg.audio_repr == "raw":
        return frames
    with torch.no_grad():
        return AudioFeatures(cfg.sr, cfg.samples_per_frame)(torch.from_numpy(frames)).numpy()


# --------------------------------------------------------------------------- the trained predictor
class Predictor:
    """A trained speech reader: its network, and ``config`` (JSON: sizes, target normalisation, head reference)."""

    def __init__(self, net: SpeechReader, config: dict[str, Any]):
        self.net = net.eval()
        self.config = config
        self.mean = np.asarray(config["target_mean"], np.float32)
        self.sd = np.asarray(config["target_sd"], np.float32)

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {k: v.detach().clone() for k, v in self.net.state_dict().items()}

    @classmethod
    def from_state(cls, config: dict[str, Any], tensors: dict[str, torch.Tensor]) -> Predictor:
        if config.get("format") != FORMAT or int(config.get("version", 0)) > VERSION:
            raise ValueError(f"not a speech predictor of version ≤ {VERSION}: {config.get('format')!r}")
        known = {f.name for f in fields(ModelConfig)}
        mc: dict[str, Any] = {
            k: tuple(v) if isinstance(v, list) else v for k, v in config["model"].items() if k in known
        }
        net = SpeechReader(ModelConfig(**mc), int(config["settings"]["hidden"]))
        net.load_state_dict(tensors)
        return cls(net, config)

    @property
    def output_names(self) -> tuple[str, ...]:
        return OUTPUT_NAMES

    def camera_head(self, head: np.ndarray) -> np.ndarray:
        """Skeleton-frame head rotations (…, 6) of a take → the camera frame the predictor reads."""
        return camera_head(head, np.asarray(self.config["head_reference"], np.float64))

    def outputs(self, raw: np.ndarray) -> np.ndarray:
        """Network outputs (…, K + 1) → targets in their units and the speaking probability."""
        out = np.empty(raw.shape, np.float32)
        out[..., :K] = raw[..., :K] * self.sd + self.mean
        out[..., K] = 1.0 / (1.0 + np.exp(-np.clip(raw[..., K], -60.0, 60.0)))
        return out

    @torch.no_grad()
    def predict(self, audio: np.ndarray, face: np.ndarray, head: np.ndarray) -> np.ndarray:
        """A whole recording at once: audio (S,), face (T, 52), camera-frame head (T, 6) → (T, K + 1).

        The network over the sequence (causal padding): the same values as stepping a stream.
        """
        cfg, T = self.net.cfg, len(face)
        a = torch.from_numpy(audio_frames(np.asarray(audio, np.float32), T, cfg))[None]
        f = torch.from_numpy(np.asarray(face, np.float32))[None]
        h = torch.from_numpy(np.array(head, np.float32))[None]
        return self.outputs(self.net(a, f, h)[0].numpy())

    def stream(self) -> PredictorStream:
        return PredictorStream(self)

    def batched(self, capacity: int = 8) -> BatchedPredictor:
        return BatchedPredictor(self, capacity)


class BatchedPredictor:
    """Independent causal streams of one predictor, stepped as one batch (slots as the generator's kernel)."""

    def __init__(self, predictor: Predictor, capacity: int = 8):
        from facecapges.network.batched import BatchedEncoders, affine_chain

        self.predictor = predictor
        self._lock = threading.RLock()
        self._enc = BatchedEncoders(predictor.net, max(1, capacity))
        self._out = affine_chain(predictor.net.out)
        self.slots = Slots()
        self.slots.grown(self._enc.capacity)

    @property
    def capacity(self) -> int:
        return self._enc.capacity

    def _grow(self, capacity: int) -> None:
        self._enc.alloc(capacity)
        self.slots.grown(capacity)

    def open(self) -> int:
        """A new stream (before its first frame: the encoders' causal zeros); returns its slot."""
        with self._lock:
            slot = self.slots.take(self._grow)
            self._enc.reset(slot)
            return slot

    def close(self, slot: int) -> None:
        with self._lock:
            self.slots.release(slot)

    def reset(self, slot: int) -> None:
        with self._lock:
            self.slots.require(slot)
            self._enc.reset(slot)

    @torch.inference_mode()
    def step(self, slots: Sequence[int], audio, face, head) -> np.ndarray:
        """One frame per stream: audio (B, ≤ 1067), face (B, 52), camera-frame head (B, 6) → (B, K + 1)."""
        with self._lock:
            ids = self.slots.check(slots)
            if not ids:
                return np.zeros((0, K + 1), np.float32)
            a, f, h = self._enc.clean_inputs(audio, face, head, len(ids))
            e = self._enc.encode(torch.tensor(ids, dtype=torch.long), a, f, h)
            return self.predictor.outputs(self._out(e).numpy())


class PredictorStream:
    """One causal stream: :meth:`step` per model frame (a one-slot :class:`BatchedPredictor`)."""

    def __init__(self, predictor: Predictor):
        self._batch = BatchedPredictor(predictor, 1)
        self._slot = self._batch.open()

    def step(self, audio_chunk: np.ndarray, face: np.ndarray, head: np.ndarray) -> np.ndarray:
        """This frame's audio (≤ 1067 samples), face (52,), camera-frame head (6,) → (K + 1,) float32."""
        return self._batch.step([self._slot], [audio_chunk], face, head)[0]

    def reset(self) -> None:
        self._batch.reset(self._slot)
