"""The "offline decoding" ablation (thesis 5.7, Table 5.3): a CaMN-like segment decoder.

FaceCapGes generates frame by frame in closed loop, each step seeing only the past.
This variant keeps everything else of the full model — the same audio, face and head
encoders (:mod:`facecapges.network.network`, same :class:`ModelConfig` sizes), the same
rot6d output, the same torso-then-limbs cascade and MLP heads — but replaces the
closed-loop decoder by CaMN's offline paradigm: **bidirectional** LSTMs that decode a
whole segment in one pass.

Per frame τ of a sequence of length L the fused input is (ours, after CaMN's seed-pose
input with its mask bit)::

    u_τ = [z_A,τ ; z_F,τ ; z_H,τ ; m_τ · s_τ ; m_τ]            (E + J·6 + 1)

with ``m_τ = 1`` for the first N = ``n_history`` frames, whose real poses ``s_τ`` are
given as *seed poses*, and ``m_τ = 0`` (pose slot zero) for every later frame, whose
pose is to be generated. The torso BiLSTM runs over ``u`` (forward and backward
direction, ``lstm_hidden`` units each), the limb BiLSTM over ``[u ; o_torso]``, and
the two MLP heads (2·H → ``mlp_hidden`` → rot6d) decode **every** frame. There is no
pose feedback and no state carried between calls: one call, one segment.

Consequences, on purpose: the output at frame τ depends on inputs after τ (the
backward direction) — :func:`test_offline_is_bidirectional` in the tests shows it —
so this model cannot run live; and at inference it sees a whole held-out sequence
(minutes) although it was trained on L = 34-frame segments (thesis 5.7's reading of
the FGD gap).

Encoders: the TCNs stay causal (they are the full model's encoders, unchanged); the
bidirectional context comes from the decoder. Embeddings of the seed frames at
inference are those of "no input" (zero features, the causal padding of the encoders
— exactly what the streaming generator uses before a stream starts), see
:meth:`BidirectionalDecoder.generate`.

NetworkStyle: ``save_bidirectional`` / ``load_bidirectional`` write one ``.safetensors`` with
metadata format ``facecapges-offline-1`` (the :class:`ModelConfig` and training
summary); :func:`facecapges.styles.load_style` refuses such files (not
a streaming model).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn as nn

from facecapges.errors import UserError
from facecapges.network.config import ModelConfig, model_config_from_dict
from facecapges.network.network import AudioEncoder, FaceEncoder, HeadEncoder, mlp, with_default_norms

BIDIRECTIONAL_FORMAT = "facecapges-offline-1"


class BidirectionalDecoder(nn.Module):
    """Encoders of FaceCapGes + bidirectional torso/limb LSTMs over a whole segment."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg.validate()
        H = cfg.lstm_hidden
        self.audio_enc = AudioEncoder(cfg)
        self.face_enc = FaceEncoder(cfg)
        self.head_enc = HeadEncoder(cfg)
        in_dim = cfg.fuse_dim + 1  # + the seed mask bit
        self.lstm_t = nn.LSTM(in_dim, H, cfg.lstm_layers, batch_first=True, bidirectional=True)
        self.lstm_u = nn.LSTM(in_dim + 2 * H, H, cfg.lstm_layers, batch_first=True, bidirectional=True)
        self.head_t = mlp([2 * H, cfg.mlp_hidden, cfg.n_torso * 6])
        self.head_u = mlp([2 * H, cfg.mlp_hidden, (cfg.n_joints - cfg.n_torso) * 6])
        self.drop = nn.Dropout(cfg.dropout)

    # -------------------------------------------------------------- encoding
    def encode(self, audio: torch.Tensor, face: torch.Tensor, head: torch.Tensor) -> torch.Tensor:
        """Per-frame embeddings [z_A; z_F; z_H] (B, T, E), causally (same as FaceCapGes.encode)."""
        z_a = self.audio_enc(audio)
        z_f = self.face_enc(face, z_a)
        return torch.cat([z_a, z_f, self.head_enc(head)], -1)

    def no_input_embedding(self) -> torch.Tensor:
        """Embedding (E,) of a frame before the sequence: the streaming kernel's (same encoders)."""
        from facecapges.network.batched import no_input_embedding

        return no_input_embedding(self)

    # -------------------------------------------------------------- decoding
    def decode(self, z: torch.Tensor, seed: torch.Tensor) -> torch.Tensor:
        """Embeddings (B, L, E) + seed poses (B, N, J·6) → poses of all L frames (B, L, J·6).

        Frames 0…N−1 carry the seed pose and mask 1, frames N…L−1 a zero pose and mask 0.
        """
        B, L, _ = z.shape
        n = seed.shape[1]
        if n > L:
            raise ValueError(f"{n} seed poses for a segment of {L} frames")
        s = torch.cat([seed, seed.new_zeros(B, L - n, seed.shape[2])], 1)  # (B, L, J·6)
        mask = torch.zeros(B, L, 1, dtype=z.dtype, device=z.device)
        mask[:, :n] = 1.0
        u = self.drop(torch.cat([z, s, mask], -1))  # (B, L, E + J·6 + 1)
        o_t, _ = self.lstm_t(u)  # (B, L, 2H): forward and backward directions
        o_u, _ = self.lstm_u(torch.cat([u, o_t], -1))  # (B, L, 2H)
        return torch.cat([self.head_t(o_t), self.head_u(o_u)], -1)  # every frame decoded

    def forward(self, audio: torch.Tensor, face: torch.Tensor, head: torch.Tensor, seed: torch.Tensor) -> torch.Tensor:
        return self.decode(self.encode(audio, face, head), seed)

    # ------------------------------------------------------------- inference
    @torch.inference_mode()
    def generate(self, audio: np.ndarray, face: np.ndarray, head: np.ndarray, seed: np.ndarray) -> np.ndarray:
        """A whole sequence in one pass: (T, S) audio frames, (T, 52), (T, 6), seed (N, J, 6) → (T, J, 6).

        The N seed poses are placed as the N frames *before* the sequence (their inputs
        are "no input", like the streaming generator's history before a stream starts),
        so the decoded segment is N + T frames long and its last T frames are returned.
        The sequence itself is encoded causally with zero padding, exactly as the
        streaming generator would encode it frame by frame.
        """
        self.eval()
        cfg = self.cfg
        seed = np.asarray(seed, np.float32)
        if seed.shape != (cfg.n_history, cfg.n_joints, 6):
            raise ValueError(f"seed must be ({cfg.n_history}, {cfg.n_joints}, 6), got {seed.shape}")
        a = torch.from_numpy(np.ascontiguousarray(audio, np.float32))[None]
        f = torch.from_numpy(np.ascontiguousarray(face, np.float32))[None]
        h = torch.from_numpy(np.ascontiguousarray(head, np.float32))[None]
        z = self.encode(a, f, h)  # (1, T, E)
        z0 = self.no_input_embedding().expand(1, cfg.n_history, -1)
        s = torch.from_numpy(seed.reshape(1, cfg.n_history, -1).copy())
        out = self.decode(torch.cat([z0, z], 1), s)[0, cfg.n_history :]
        return out.reshape(-1, cfg.n_joints, 6).numpy().copy()


def save_bidirectional(path: str | Path, model: BidirectionalDecoder, meta: dict) -> Path:
    """Weights + metadata (format ``facecapges-offline-1``) atomically."""
    from facecapges.network.style import save_checkpoint

    return save_checkpoint(path, model, meta, fmt=BIDIRECTIONAL_FORMAT)


def load_bidirectional(path: str | Path) -> tuple[BidirectionalDecoder, dict]:
    """An offline-decoding checkpoint (eval mode) and its metadata."""
    from facecapges.engine.files import read_weights

    p = Path(path)
    tensors, meta = read_weights(p, BIDIRECTIONAL_FORMAT, "offline-decoding checkpoint")
    model = BidirectionalDecoder(model_config_from_dict(meta["model_config"]))
    try:
        model.load_state_dict(with_default_norms(model, tensors), strict=True)
    except RuntimeError as exc:
        raise UserError(f"{p}: weights do not match the model config ({str(exc).splitlines()[0]})") from None
    return model.eval(), meta
