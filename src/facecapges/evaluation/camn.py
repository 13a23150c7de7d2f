"""The CaMN baseline (BEAT, Liu et al. ECCV 2022; thesis 5.2.1, Tables 5.2/5.3) — our own implementation.

CaMN ("Cascaded Motion Network") decodes a whole segment offline: per-modality
encoders, a cascade of fusion MLPs, then a **bidirectional** body LSTM and a
bidirectional hands LSTM conditioned on the body output. We build it from the paper's
description, with the same inputs FaceCapGes gets and nothing more: per-frame raw
16 kHz audio, the 52 face weights and the head rotation (CaMN's text, speaker and
emotion branches have no counterpart here, so they are left out; the head branch is
ours, added so the comparison has equal information).

Per frame τ of a segment (B batch, T frames, S = 1067 samples per frame):

* **audio** (CaMN's wave encoder): each frame's samples → strided 1-D convolutions
  with BatchNorm and LeakyReLU (1→32→64→128 channels, strides 5·6·6, then averaged to
  one vector), followed by two *non-causal* residual temporal convolutions over the
  frames (kernel 3) → ``a_τ`` (128). CaMN runs one strided stack over the whole
  waveform and pads the result to the frame count; we stride within each frame so
  frame τ's feature is exactly frame τ's audio.
* **face** (CaMN's facial encoder): the weights standardised per channel (training
  statistics; scale 0 for a face-less training set), then residual temporal conv
  blocks with BatchNorm (52→16, kernel 7; 16→16, 16→32, kernel 3) → ``f_τ`` (32).
* **head** (ours): standardised rot6d → one temporal conv block (6→16, kernel 3).
* **fusion cascade** (CaMN): ``â = MLP(a)`` (128 → H/2 → 128), ``f̂ = MLP([â; f])``
  (160 → H/2 → 32), each layer LeakyReLU(0.1).
* **seed poses** (CaMN's ``pre_seq``): the first ``n_seed`` frames carry their real
  pose (rot6d, J·6) and a mask bit 1, the other frames zeros and 0.
* **decoder** (CaMN): ``u = [seed; mask; â; f̂; h]``; body BiLSTM (``layers`` = 4,
  ``hidden`` = 256, dropout 0.3 between layers) whose two directions are **summed**,
  an MLP (H → H/2 → torso) to the 3 torso joints; hands BiLSTM over ``[u; torso]``,
  summed, MLP to the 44 limb joints. Output: rot6d of all 47 joints for every frame.

Sizes are CaMN's (BEAT's config: hidden 256, 4 layers, audio 128, face 32, dropout
0.3). It is trained by the project's trainer with the same recipe as FaceCapGes
(:func:`build_camn_trainer` gives the trainer a :class:`facecapges.training.train.Variant`
made of :func:`build_camn`, :func:`camn_batch`, :func:`camn_heads` and :func:`save_camn`):
L = 34-frame segments with the first N = 16 real poses as seed (CaMN's own setting is
4; we give it what the FaceCapGes warm-up sees), losses on the 18 frames after.
Evaluation decodes a whole held-out sequence in one pass from the same N-frame
history the streaming models start from, placed before the sequence with zero inputs
(:meth:`CaMN.generate`), exactly as the offline-decoding ablation is run.

**DiffSHEG** (thesis 5.2.1) is not provided: it conditions a diffusion model jointly
generating expression and gesture on HuBERT speech features, i.e. on a large
self-supervised speech model pretrained on hundreds of hours of audio. No HuBERT weights
come with anything the project installs and nothing may be downloaded at run time (no
model hub); a speech model trained here on one minute of speech would not be HuBERT,
and DiffSHEG without it would not be DiffSHEG. Its rows in Tables 5.2/5.3 are therefore
not reproduced.

NetworkStyle: one ``.safetensors``, metadata format ``facecapges-camn-1``
(:func:`save_camn` / :func:`load_camn`), holding the :class:`ModelConfig` (for the
shared sizes: joints, face channels, N, rates) and the :class:`CaMNConfig`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from facecapges.errors import UserError, file_error
from facecapges.network.config import ModelConfig, model_config_from_dict

CAMN_FORMAT = "facecapges-camn-1"


@dataclass(frozen=True)
class CaMNConfig:
    """CaMN's own sizes (BEAT's ``camn_beat_4english_15_141`` config and defaults)."""

    hidden: int = 256
    layers: int = 4
    audio_f: int = 128
    facial_f: int = 32
    head_f: int = 16  # (ours) CaMN has no head input
    dropout: float = 0.3


class _Standardize(nn.Module):
    """``(x − in_mean) · in_scale`` per channel, buffers set from the training frames."""

    in_mean: torch.Tensor  # buffers (dim,)
    in_scale: torch.Tensor

    def __init__(self, dim: int):
        super().__init__()
        self.register_buffer("in_mean", torch.zeros(dim))
        self.register_buffer("in_scale", torch.ones(dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.in_mean) * self.in_scale


class _TemporalBlock(nn.Module):
    """Residual non-causal block over frames: conv–BN–LReLU–conv–BN (+ projected input), LReLU. (B, C, T)."""

    def __init__(self, c_in: int, c_out: int, kernel: int):
        super().__init__()
        pad = kernel // 2
        self.conv1 = nn.Conv1d(c_in, c_out, kernel, padding=pad)
        self.bn1 = nn.BatchNorm1d(c_out)
        self.conv2 = nn.Conv1d(c_out, c_out, 3, padding=1)
        self.bn2 = nn.BatchNorm1d(c_out)
        self.skip = (
            None if c_in == c_out else nn.Sequential(nn.Conv1d(c_in, c_out, kernel, padding=pad), nn.BatchNorm1d(c_out))
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.bn2(self.conv2(F.leaky_relu(self.bn1(self.conv1(x)), 0.2)))
        return F.leaky_relu(y + (x if self.skip is None else self.skip(x)), 0.2)


class _WaveEncoder(nn.Module):
    """Per-frame raw samples (B, T, S) → (B, T, audio_f): strided convs per frame, then temporal blocks."""

    def __init__(self, audio_f: int):
        super().__init__()
        self.gain = _Standardize(1)
        layers: list[nn.Module] = []
        for c_in, c_out, stride in ((1, 32, 5), (32, 64, 6), (64, audio_f, 6)):
            layers += [nn.Conv1d(c_in, c_out, 15, stride=stride), nn.BatchNorm1d(c_out), nn.LeakyReLU(0.2)]
        self.frame = nn.Sequential(*layers)
        self.temporal = nn.Sequential(_TemporalBlock(audio_f, audio_f, 3), _TemporalBlock(audio_f, audio_f, 3))

    def forward(self, audio: torch.Tensor) -> torch.Tensor:
        B, T, S = audio.shape
        x = self.frame(self.gain(audio.reshape(B * T, 1, S)))  # (B·T, C, S')
        x = x.mean(-1).reshape(B, T, -1).transpose(1, 2)  # (B, C, T)
        return self.temporal(x).transpose(1, 2)


def _fusion(d_in: int, hidden: int, d_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(d_in, hidden), nn.LeakyReLU(0.1), nn.Linear(hidden, d_out), nn.LeakyReLU(0.1))


def _out_head(hidden: int, d_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(hidden, hidden // 2), nn.LeakyReLU(0.1), nn.Linear(hidden // 2, d_out))


class CaMN(nn.Module):
    """CaMN on audio + face + head → rot6d of the 47 upper-body joints (module docs)."""

    def __init__(self, cfg: ModelConfig, camn: CaMNConfig | None = None):
        super().__init__()
        self.cfg = cfg.validate()
        self.camn = c = camn or CaMNConfig()
        H = c.hidden
        self.audio_enc = _WaveEncoder(c.audio_f)
        self.face_norm = _Standardize(cfg.n_face)
        self.face_enc = nn.Sequential(
            _TemporalBlock(cfg.n_face, c.facial_f // 2, 7),
            _TemporalBlock(c.facial_f // 2, c.facial_f // 2, 3),
            _TemporalBlock(c.facial_f // 2, c.facial_f, 3),
        )
        self.head_norm = _Standardize(6)
        self.head_enc = _TemporalBlock(6, c.head_f, 3)
        self.audio_fusion = _fusion(c.audio_f, H // 2, c.audio_f)
        self.facial_fusion = _fusion(c.audio_f + c.facial_f, H // 2, c.facial_f)
        in_dim = cfg.pose_dim + 1 + c.audio_f + c.facial_f + c.head_f
        n_torso, n_limb = cfg.n_torso * 6, (cfg.n_joints - cfg.n_torso) * 6
        self.lstm_body = nn.LSTM(in_dim, H, c.layers, batch_first=True, bidirectional=True, dropout=c.dropout)
        self.lstm_hands = nn.LSTM(
            in_dim + n_torso, H, c.layers, batch_first=True, bidirectional=True, dropout=c.dropout
        )
        self.head_t = _out_head(H, n_torso)
        self.head_u = _out_head(H, n_limb)

    def input_norm_layers(self) -> dict[str, nn.Module]:
        """The standardising modules of each input ({name: module with in_mean/in_scale}).

        Audio is always raw samples here (CaMN's input); its one gain takes the
        trainer's statistic only when the shared config's audio is raw too (with Mel
        features the statistic is per feature; BatchNorm then sets the scale).
        """
        layers: dict[str, nn.Module] = {"face": self.face_norm, "head": self.head_norm}
        if self.cfg.audio_repr == "raw":
            layers["audio"] = self.audio_enc.gain
        return layers

    def features(self, audio: torch.Tensor, face: torch.Tensor, head: torch.Tensor) -> torch.Tensor:
        """Fused per-frame features [â; f̂; h] (B, T, F), non-causal over the segment."""
        a = self.audio_enc(audio)
        f = self.face_enc(self.face_norm(face).transpose(1, 2)).transpose(1, 2)
        h = self.head_enc(self.head_norm(head).transpose(1, 2)).transpose(1, 2)
        a = self.audio_fusion(a)
        f = self.facial_fusion(torch.cat([a, f], -1))
        return torch.cat([a, f, h], -1)

    def forward(self, audio: torch.Tensor, face: torch.Tensor, head: torch.Tensor, seed: torch.Tensor) -> torch.Tensor:
        """Inputs of T frames + seed poses (B, n, J·6) of the first n frames → poses (B, T, J·6)."""
        x = self.features(audio, face, head)
        B, T, _ = x.shape
        n = seed.shape[1]
        if n > T:
            raise ValueError(f"{n} seed poses for a segment of {T} frames")
        s = torch.cat([seed, seed.new_zeros(B, T - n, seed.shape[2])], 1)
        mask = x.new_zeros(B, T, 1)
        mask[:, :n] = 1.0
        u = torch.cat([s, mask, x], -1)
        H = self.camn.hidden
        o, _ = self.lstm_body(u)
        torso = self.head_t(o[..., :H] + o[..., H:])  # the two directions summed, as CaMN
        o, _ = self.lstm_hands(torch.cat([u, torso], -1))
        limbs = self.head_u(o[..., :H] + o[..., H:])
        return torch.cat([torso, limbs], -1)

    @torch.inference_mode()
    def generate(self, audio: np.ndarray, face: np.ndarray, head: np.ndarray, seed: np.ndarray) -> np.ndarray:
        """A whole sequence in one pass: (T, S), (T, 52), (T, 6), seed (N, J, 6) → (T, J, 6).

        The seed poses are the N frames *before* the sequence, with zero inputs (as the
        offline-decoding ablation and the streaming generator's history are seeded).
        """
        self.eval()
        cfg = self.cfg
        seed = np.asarray(seed, np.float32)
        n = len(seed)
        if seed.ndim != 3 or seed.shape[1:] != (cfg.n_joints, 6) or n < 1:
            raise ValueError(f"seed must be (n ≥ 1, {cfg.n_joints}, 6), got {seed.shape}")

        def pad(x, width):
            x = np.ascontiguousarray(x, np.float32)
            return torch.from_numpy(np.concatenate([np.zeros((n, width), np.float32), x]))[None]

        out = self(
            pad(audio, cfg.samples_per_frame),
            pad(face, cfg.n_face),
            pad(head, 6),
            torch.from_numpy(seed.reshape(1, n, -1).copy()),
        )[0, n:]
        return out.reshape(-1, cfg.n_joints, 6).numpy().copy()


# ------------------------------------------------------------------ training pieces
def build_camn(cfg: ModelConfig) -> CaMN:
    """A fresh CaMN for the trainer (CaMN's own sizes)."""
    return CaMN(cfg)


def camn_batch(model: CaMN, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """Generated and real poses (B, M, J·6) of a batch of segments (``SegmentSet.gather``).

    The segment's L frames are decoded in one pass from their own inputs (the N frames
    of causal context the batch carries in front are not used: CaMN's encoders see the
    segment), seeded by its first N real poses; the M frames after the seed are scored.
    """
    N = model.cfg.n_history
    out = model(batch["audio"][:, N:], batch["face"][:, N:], batch["head"][:, N:], batch["pose"][:, :N])
    return out[:, N:], batch["pose"][:, N:]


def camn_heads(model: CaMN) -> tuple[nn.Sequential, nn.Sequential]:
    """The (torso, limbs) output MLPs, which the trainer starts at the training mean pose."""
    return model.head_t, model.head_u


def _variant():
    from facecapges.training.train import Variant

    return Variant(
        name="camn",
        build=build_camn,
        forward=camn_batch,
        output_heads=camn_heads,
        export=save_camn,
        meta={"variant": "CaMN"},
    )


def build_camn_trainer(clips, out: Path, model_over: dict, train_over: dict, meta: dict):
    """A new trainer of the project's one training loop for CaMN (same override dicts as ``build_trainer``)."""
    from facecapges.training.train import build_trainer

    return build_trainer(clips, out, model_over, train_over, meta, resume=False, variant=_variant())


def save_camn(path: str | Path, model: CaMN, meta: dict) -> Path:
    """Weights + metadata (format ``facecapges-camn-1``, with the CaMN sizes) atomically."""
    from facecapges.network.style import save_checkpoint

    return save_checkpoint(path, model, dict(meta, camn_config=asdict(model.camn)), fmt=CAMN_FORMAT)


def load_camn(path: str | Path) -> tuple[CaMN, dict]:
    """A CaMN checkpoint (eval mode) and its metadata; clear errors for other files."""
    from facecapges.engine.files import read_weights

    p = Path(path)
    tensors, meta = read_weights(p, CAMN_FORMAT, "CaMN checkpoint")
    try:
        camn_cfg = CaMNConfig(**meta.get("camn_config", {}))
    except TypeError as exc:
        raise file_error(p, f"bad CaMN sizes in the metadata ({exc})") from None
    model = CaMN(model_config_from_dict(meta["model_config"]), camn_cfg)
    try:
        model.load_state_dict(tensors, strict=True)
    except RuntimeError as exc:
        raise UserError(f"{p}: weights do not match the CaMN config ({str(exc).splitlines()[0]})") from None
    return model.eval(), meta
