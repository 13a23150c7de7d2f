"""The FaceCapGes network (thesis ch. 3), top to bottom.

Per frame τ the encoders give ``z_A`` (128), ``z_F`` (32) and ``z_H`` (12); the decoder
sees the window τ = t−N … t of fused vectors ``[z_A; z_F; z_H; s_τ]`` (eq. 3.6) where
``s_τ`` is the pose of frame τ for τ ≤ t−1 and zeros at τ = t (eq. 3.5), runs the torso
LSTM and the upper-limb LSTM conditioned on it (eq. 3.8, 4.12–4.13), and decodes only
the last window step with two MLP heads (eq. 3.9–3.11).

Causality and caching. Both TCNs are causal with kernel 2 and dilations summing to N,
so an embedding at frame τ depends on inputs τ−N … τ only — exactly "the encoder
applied to that frame's own causal window" of eq. 3.2. Encoding a whole clip with
causal (left zero) padding therefore gives, at every frame, the same embedding as the
windowed encoder; the streaming generator computes each frame's embedding once and
caches it. In the face TCN's 8th layer the audio embedding enters through a kernel-1
path (the current frame's ``z_A`` only), so joining it does not widen the window.

Input normalisation. Each input enters the network through a layer that first
standardises it, ``(x − in_mean) · in_scale`` (:class:`StandardizedLinear`, buffers
saved in the checkpoint): the face weights and the head rotation per channel, the
Mel features per channel, the raw samples by one gain. The trainer sets them from the
training frames (:func:`set_input_statistics`); a modality training never saw gets
``in_scale = 0``, so the model ignores it at run time exactly as it did in training
(no face in training → the live face cannot change the output). Fresh models and
checkpoints written before these buffers existed have the identity (mean 0, scale 1).

Shapes: B batch, T frames, S = samples per frame (1067), J = 47 joints.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from facecapges.network.audio_features import AudioFeatures
from facecapges.network.config import ModelConfig

LSTMState = tuple[torch.Tensor, torch.Tensor]
NORM_BUFFERS = ("in_mean", "in_scale")


class StandardizedLinear(nn.Linear):
    """``Linear((x − in_mean) · in_scale)``: a linear layer over a standardised input."""

    in_mean: torch.Tensor  # buffers (in_features,)
    in_scale: torch.Tensor

    def __init__(self, in_features: int, out_features: int, bias: bool = True):
        super().__init__(in_features, out_features, bias)
        self.register_buffer("in_mean", torch.zeros(in_features))
        self.register_buffer("in_scale", torch.ones(in_features))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return super().forward((x - self.in_mean) * self.in_scale)


class AudioFrontend(nn.Module):
    """One frame's raw samples (S,) → one vector, by strided convolutions (per frame).

    The samples are first multiplied by the gain ``in_scale`` (1 / the RMS of the
    training audio; ``in_mean`` is 0: audio has no offset).
    """

    in_mean: torch.Tensor  # buffers (1,)
    in_scale: torch.Tensor

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.register_buffer("in_mean", torch.zeros(1))
        self.register_buffer("in_scale", torch.ones(1))
        c1, c2, c3 = cfg.audio_frontend_channels
        self.convs = nn.ModuleList(
            [
                nn.Conv1d(1, c1, 15, stride=5),
                nn.Conv1d(c1, c2, 9, stride=4),
                nn.Conv1d(c2, c3, 9, stride=4),
            ]
        )
        length = cfg.samples_per_frame
        for conv in self.convs:
            assert isinstance(conv, nn.Conv1d)
            length = (length - conv.kernel_size[0]) // conv.stride[0] + 1
        self.collapse = nn.Conv1d(c3, cfg.audio_tcn_channels, length)  # remaining length -> 1

    def forward(self, audio: torch.Tensor) -> torch.Tensor:  # (B, T, S) -> (B, T, C)
        B, T, S = audio.shape
        x = ((audio - self.in_mean) * self.in_scale).reshape(B * T, 1, S)
        for conv in self.convs:
            x = F.leaky_relu(conv(x), 0.2)
        x = self.collapse(x)  # (B*T, C, 1)
        return x.reshape(B, T, -1)


class MelFrontend(nn.Module):
    """One frame's samples (S,) → log-Mel/energy/F0 features (43) → one vector (per frame).

    ``features`` is :class:`facecapges.network.audio_features.AudioFeatures`; the features
    are standardised (``proj``'s buffers) and mapped by a two-layer MLP to the TCN width.
    """

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.features = AudioFeatures(cfg.sr, cfg.samples_per_frame)
        c = cfg.audio_frontend_channels[-1]
        self.proj = StandardizedLinear(self.features.dim, c)
        self.out = nn.Linear(c, cfg.audio_tcn_channels)

    def forward(self, audio: torch.Tensor) -> torch.Tensor:  # (B, T, S) -> (B, T, C)
        return self.out(F.leaky_relu(self.proj(self.features(audio)), 0.2))


class CausalTCN(nn.Module):
    """Causal temporal conv net: kernel-2 dilated convs with residual + skip connections.

    Layer i computes ``y_t = act(W_i [x_{t-d_i}; x_t] + b_i)`` (a kernel-2 causal
    convolution with dilation ``d_i``, written as one linear map over the two taps;
    ``x_{t-d} = 0`` before the sequence start), then ``x ← x + y`` (residual) and adds
    ``y`` to the skip sum it returns. ``extra_dim`` > 0 joins an extra per-frame input
    at the last layer through a kernel-1 projection (the face encoder's audio
    embedding at layer 8). Tensors are (B, T, C).
    """

    def __init__(self, channels: int, dilations: tuple[int, ...], extra_dim: int = 0):
        super().__init__()
        self.dilations = tuple(dilations)
        self.layers = nn.ModuleList([nn.Linear(2 * channels, channels) for _ in dilations])
        self.extra = nn.Linear(extra_dim, channels, bias=False) if extra_dim else None

    def layer(
        self, i: int, x_past: torch.Tensor, x_now: torch.Tensor, extra: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Layer ``i``'s activation from its input d_i frames ago and now (…, C) each."""
        y = self.layers[i](torch.cat([x_past, x_now], -1))
        if i == len(self.layers) - 1 and self.extra is not None:
            y = y + self.extra(extra)
        return F.leaky_relu(y, 0.2)

    def forward(self, x: torch.Tensor, extra: torch.Tensor | None = None) -> torch.Tensor:
        skip = torch.zeros_like(x)
        for i, d in enumerate(self.dilations):
            past = F.pad(x, (0, 0, d, 0))[:, : x.shape[1]]  # x shifted d frames later, zeros first
            y = self.layer(i, past, x, extra)
            skip = skip + y
            x = x + y
        return skip


def mlp(dims: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(dims) - 1):
        layers.append(nn.Linear(dims[i], dims[i + 1]))
        if i < len(dims) - 2:
            layers.append(nn.LeakyReLU(0.2))
    return nn.Sequential(*layers)


class AudioEncoder(nn.Module):
    """E_A: frontend → 12-layer causal TCN with skips → 2-layer MLP → z_A (128)."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.frontend = AudioFrontend(cfg) if cfg.audio_repr == "raw" else MelFrontend(cfg)
        self.tcn = CausalTCN(cfg.audio_tcn_channels, cfg.audio_tcn_dilations)
        self.mlp = mlp([cfg.audio_tcn_channels, cfg.audio_dim, cfg.audio_dim])

    def from_features(self, feats: torch.Tensor) -> torch.Tensor:  # (B, T, C) -> (B, T, 128)
        return self.mlp(self.tcn(feats))

    def forward(self, audio: torch.Tensor) -> torch.Tensor:  # (B, T, S) -> (B, T, 128)
        return self.from_features(self.frontend(audio))


class FaceEncoder(nn.Module):
    """E_F: 8-layer causal TCN over 52 weights, z_A joined at layer 8, MLP → z_F (32)."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.inp = StandardizedLinear(cfg.n_face, cfg.face_tcn_channels)
        self.tcn = CausalTCN(cfg.face_tcn_channels, cfg.face_tcn_dilations, extra_dim=cfg.audio_dim)
        self.mlp = mlp([cfg.face_tcn_channels, cfg.face_dim * 2, cfg.face_dim])

    def forward(self, face: torch.Tensor, z_audio: torch.Tensor) -> torch.Tensor:
        # face (B, T, 52), z_audio (B, T, 128) -> (B, T, 32)
        return self.mlp(self.tcn(self.inp(face), z_audio))


class HeadEncoder(nn.Module):
    """E_H (eq. 3.12–3.13): per-frame 6 → 36 (ReLU) → 12.

    ``head_dim = 0`` is the "without head pose" ablation (thesis 5.7): no head
    encoder, z_H is empty and the head rotation never reaches the network.
    """

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.dim = cfg.head_dim
        if self.dim:
            self.fc1 = StandardizedLinear(6, cfg.head_hidden)
            self.fc2 = nn.Linear(cfg.head_hidden, cfg.head_dim)

    def forward(self, head: torch.Tensor) -> torch.Tensor:  # (B, T, 6) -> (B, T, 12)
        if not self.dim:
            return head.new_zeros(head.shape[:-1] + (0,))
        return self.fc2(F.relu(self.fc1(head)))


class Decoder(nn.Module):
    """Torso LSTM then upper-limb LSTM over the N+1 window; last step → rot6d heads."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        H = cfg.lstm_hidden
        self.cfg = cfg
        self.lstm_t = nn.LSTM(cfg.fuse_dim, H, cfg.lstm_layers, batch_first=True)
        self.lstm_u = nn.LSTM(cfg.fuse_dim + H, H, cfg.lstm_layers, batch_first=True)
        self.head_t = mlp([H, cfg.mlp_hidden, cfg.n_torso * 6])
        self.head_u = mlp([H, cfg.mlp_hidden, (cfg.n_joints - cfg.n_torso) * 6])
        self.drop = nn.Dropout(cfg.dropout)

    def zero_state(self, batch: int, device=None) -> tuple[LSTMState, LSTMState]:
        shape = (self.cfg.lstm_layers, batch, self.cfg.lstm_hidden)
        z = torch.zeros(shape, device=device)
        return (z, z.clone()), (z.clone(), z.clone())

    def forward(
        self, fuse: torch.Tensor, state: tuple[LSTMState, LSTMState]
    ) -> tuple[torch.Tensor, tuple[LSTMState, LSTMState]]:
        # fuse (B, N+1, D) -> pose (B, J*6) of the window's last frame, new states
        fuse = self.drop(fuse)
        o_t, st_t = self.lstm_t(fuse, state[0])  # (B, N+1, H)   eq. 4.12
        o_u, st_u = self.lstm_u(torch.cat([fuse, o_t], -1), state[1])  # eq. 4.13
        v_t = self.head_t(o_t[:, -1])  # only the last step is decoded (eq. 3.9-3.10)
        v_u = self.head_u(o_u[:, -1])
        return torch.cat([v_t, v_u], -1), (st_t, st_u)  # eq. 3.11


class FaceCapGes(nn.Module):
    """The generator: encoders + fusion + cascaded decoders."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg.validate()
        self.audio_enc = AudioEncoder(cfg)
        self.face_enc = FaceEncoder(cfg)
        self.head_enc = HeadEncoder(cfg)
        self.decoder = Decoder(cfg)

    # ---------------------------------------------------------------- encoding
    def encode(self, audio: torch.Tensor, face: torch.Tensor, head: torch.Tensor) -> torch.Tensor:
        """Per-frame embeddings [z_A; z_F; z_H] (B, T, 172) of whole sequences, causally."""
        z_a = self.audio_enc(audio)
        z_f = self.face_enc(face, z_a)
        z_h = self.head_enc(head)
        return torch.cat([z_a, z_f, z_h], -1)

    # ---------------------------------------------------------------- decoding
    def fuse_window(self, z_win: torch.Tensor, hist: torch.Tensor) -> torch.Tensor:
        """Window embeddings (B, N+1, E) + history poses (B, N, J*6) → fused (B, N+1, D).

        The current frame's pose slot is the zero placeholder of eq. 3.5.
        """
        s = torch.cat([hist, hist.new_zeros(hist.shape[0], 1, hist.shape[2])], 1)
        return torch.cat([z_win, s], -1)

    def step(self, z_win: torch.Tensor, hist: torch.Tensor, state) -> tuple[torch.Tensor, tuple]:
        """One generation step: (B, N+1, E), (B, N, J*6), state → pose (B, J*6), state."""
        return self.decoder(self.fuse_window(z_win, hist), state)

    def rollout(self, z: torch.Tensor, warmup: torch.Tensor, state=None) -> torch.Tensor:
        """Closed-loop autoregressive rollout (thesis 4.1.2), batched over clips.

        ``z``: embeddings (B, N+M, E) of a segment; ``warmup``: its first N poses
        (B, N, J*6). Each of the M steps writes its prediction back into the history the
        next step sees; the LSTM state starts at zero (4.1.4) and is carried.
        Returns the M generated poses (B, M, J*6).
        """
        N = self.cfg.n_history
        B, L, _ = z.shape
        if state is None:
            state = self.decoder.zero_state(B, z.device)
        hist = warmup
        outs = []
        for m in range(L - N):
            pose, state = self.step(z[:, m : m + N + 1], hist[:, -N:], state)
            outs.append(pose)
            hist = torch.cat([hist[:, 1:], pose[:, None]], 1)
        return torch.stack(outs, 1)


class SegmentDiscriminator(nn.Module):
    """Dis (eq. 4.21): M generated frames (B, M, J*6) → logit that they are real.

    (ours) Input is the pose and its velocity; two strided temporal convs and a linear
    layer. Only generated frames are judged, never the warm-up (thesis 4.3.1).
    """

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        C = cfg.disc_channels
        self.net = nn.Sequential(
            nn.Conv1d(cfg.pose_dim * 2, C, 3, padding=1),
            nn.LeakyReLU(0.2),
            nn.Conv1d(C, C, 3, stride=2, padding=1),
            nn.LeakyReLU(0.2),
            nn.Conv1d(C, C, 3, stride=2, padding=1),
            nn.LeakyReLU(0.2),
        )
        self.out = nn.Linear(C, 1)

    def forward(self, seq: torch.Tensor) -> torch.Tensor:  # (B, M, D) -> (B,)
        vel = torch.cat([torch.zeros_like(seq[:, :1]), seq[:, 1:] - seq[:, :-1]], 1)
        h = self.net(torch.cat([seq, vel], -1).transpose(1, 2))
        return self.out(h.mean(-1)).squeeze(-1)


def input_norm_layers(model: Any) -> dict[str, Any]:  # model: FaceCapGes-like (duck-typed, below)
    """The standardising layer of each input of a FaceCapGes-like model (audio, face, head).

    A model with its own ``input_norm_layers()`` method (e.g. the CaMN baseline) names them itself.
    """
    if hasattr(model, "input_norm_layers"):
        return model.input_norm_layers()
    fe = model.audio_enc.frontend
    layers = {"audio": fe if isinstance(fe, AudioFrontend) else fe.proj, "face": model.face_enc.inp}
    if model.head_enc.dim:
        layers["head"] = model.head_enc.fc1
    return layers


@torch.no_grad()
def set_input_statistics(
    model: nn.Module, stats: Mapping[str, tuple[torch.Tensor | np.ndarray, torch.Tensor | np.ndarray]]
) -> None:
    """Set ``in_mean``/``in_scale`` of the inputs named in ``stats`` ({name: (mean, scale)})."""
    layers = input_norm_layers(model)
    for name, (mean, scale) in stats.items():
        if name in layers:
            layers[name].in_mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
            layers[name].in_scale.copy_(torch.as_tensor(scale, dtype=torch.float32))


def input_standardisation(
    head: np.ndarray, face: np.ndarray, audio: np.ndarray, audio_repr: str, n_face: int
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The ``{input: (in_mean, in_scale)}`` of :func:`set_input_statistics` from training frames — the one rule
    the thesis trainer (:func:`facecapges.training.train.input_statistics`) and the matching style's speech
    predictor (:mod:`facecapges.matching.predictor_training`) both use.

    ``head`` (T, 6) in the model's camera frame, ``face`` (T, 52), ``audio``: the raw samples (any shape) when
    ``audio_repr`` is "raw", else the Mel features (T, 43).

    * head: per channel mean and one scale, 1 / RMS deviation over the six channels (rot6d channels near ±1
      barely move; a scale per channel would magnify them);
    * face: per channel mean and 1 / max(sd, 0.01); when no frame has a face (all zero) the scale is 0: the
      model never saw faces, so faces never reach it;
    * audio: raw samples by 1 / RMS; Mel features per channel, 1 / max(sd, 1e-3).
    """
    head = np.asarray(head, np.float64)
    face = np.asarray(face, np.float64)
    h_mean = head.mean(0)
    h_scale = 1.0 / max(float(np.sqrt(((head - h_mean) ** 2).sum(1).mean() / 6)), 1e-3)
    stats = {"head": (h_mean, np.full(6, h_scale))}
    if len(face) and np.abs(face).max() > 0:
        stats["face"] = (face.mean(0), 1.0 / np.maximum(face.std(0), 0.01))
    else:
        stats["face"] = (np.zeros(n_face), np.zeros(n_face))
    a = np.asarray(audio, np.float64)
    if audio_repr == "raw":
        stats["audio"] = (np.zeros(1), np.ones(1) / max(float(np.sqrt(np.mean(a**2))), 1e-4))
    else:
        stats["audio"] = (a.mean(0), 1.0 / np.maximum(a.std(0), 1e-3))
    return stats


def with_default_norms(model: nn.Module, tensors: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """``tensors`` plus identity normalisation buffers where a checkpoint predates them."""
    own = model.state_dict()
    missing = {k: own[k] for k in own if k not in tensors and k.rsplit(".", 1)[-1] in NORM_BUFFERS}
    return {**tensors, **missing}
