"""Frame-by-frame inference: the :class:`StreamingGenerator`.

One generator serves one stream of one speaker checkpoint. Each :meth:`step` takes
the current frame's inputs only — ``audio`` (the frame's ≤ 1067 samples at 16 kHz),
``face`` (52 ARKit weights), ``head`` (rot6d) — and returns the pose (47, 6) of that
frame; it never looks ahead. What it caches between steps:

* the causal encoder state: for each TCN layer its inputs of the last d_i frames
  (d_i its dilation), so a new frame costs one kernel-2 tap per layer and gives the
  same embedding as encoding the whole stream;
* the per-frame embeddings ``[z_A; z_F; z_H]`` of the last N+1 frames — each frame is
  encoded once (the naive loop re-encodes the whole window every frame);
* the history ring of the last N poses (its own predictions after warm-up, eq. 4.11);
* both LSTM states ``(h, c)``, carried across steps (thesis 4.1.4).

Cold start (thesis 4.1.1): :meth:`reset` fills the pose history with a neutral window
taken from the training data (stored in the checkpoint) and the LSTM states with
zeros; frames before the stream are "no input" (zero features, as the encoders'
causal padding). :meth:`warmup` pushes a frame whose pose is known (the warm-up
stage of 4.1.3), so a stream can start from real motion.

Its outputs equal the training-time rollout (:meth:`FaceCapGes.rollout`) on the same
inputs (tested to 1e-5). :class:`NaiveStreamingGenerator` is the straightforward
loop that re-encodes the whole window every frame — same outputs, kept only as the
benchmark's reference.
"""

from __future__ import annotations

from collections import deque

import numpy as np
import torch
import torch.nn.functional as F

from facecapges.model.network import FaceCapGes


def _as_frame_audio(audio: np.ndarray, spf: int) -> torch.Tensor:
    a = np.asarray(audio, dtype=np.float32).reshape(-1)
    if a.shape[0] > spf:
        raise ValueError(f"a frame owns at most {spf} audio samples, got {a.shape[0]}")
    if not np.isfinite(a).all():
        a = np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0)
    out = torch.zeros(spf)
    out[: a.shape[0]] = torch.from_numpy(a)
    return out


def _clean(x: np.ndarray, size: int, what: str) -> torch.Tensor:
    a = np.asarray(x, dtype=np.float32).reshape(-1)
    if a.shape[0] != size:
        raise ValueError(f"{what} must have {size} values, got {a.shape[0]}")
    return torch.from_numpy(np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0).copy())


class StreamingGenerator:
    """Causal per-frame pose generator with cached encoder state (see module docs)."""

    def __init__(self, model: FaceCapGes, neutral_window: np.ndarray):
        self.model = model.eval()
        self.cfg = model.cfg
        N = self.cfg.n_history
        neutral_window = np.asarray(neutral_window, dtype=np.float32)
        if neutral_window.shape != (N, self.cfg.n_joints, 6):
            raise ValueError(f"neutral window must be ({N}, {self.cfg.n_joints}, 6), got {neutral_window.shape}")
        self.neutral_window = neutral_window
        self._audio_layers = self._split_tcn(model.audio_enc.tcn)
        self._face_layers = self._split_tcn(model.face_enc.tcn)
        self.reset()

    # ---------------------------------------------------------------- state
    @torch.inference_mode()
    def reset(self, initial_pose: np.ndarray | None = None) -> None:
        """Start a new stream. ``initial_pose``: (47, 6), (N, 47, 6) or None (neutral)."""
        cfg, m, N, W = self.cfg, self.model, self.cfg.n_history, self.cfg.window
        if initial_pose is None:
            window = self.neutral_window
        else:
            p = np.asarray(initial_pose, dtype=np.float32)
            window = np.broadcast_to(p, (N, cfg.n_joints, 6)) if p.ndim == 2 else p
            if window.shape != (N, cfg.n_joints, 6):
                raise ValueError(f"initial pose must be (47, 6) or ({N}, 47, 6), got {p.shape}")
        self.hist = torch.from_numpy(np.ascontiguousarray(window).reshape(N, -1).copy())  # (N, J*6)
        # per TCN layer, its inputs of the last d_i frames (zeros = before the stream,
        # exactly the causal padding of the sequence encoder)
        self.q_audio = [deque([torch.zeros(1, cfg.audio_tcn_channels)] * d, maxlen=d)
                        for d in cfg.audio_tcn_dilations]
        self.q_face = [deque([torch.zeros(1, cfg.face_tcn_channels)] * d, maxlen=d) for d in cfg.face_tcn_dilations]
        self.state = m.decoder.zero_state(1)
        # embedding of a frame before the stream: the encoders over zero features
        z_a0 = m.audio_enc.from_features(torch.zeros(1, 1, cfg.audio_tcn_channels))
        z_f0 = m.face_enc.mlp(m.face_enc.tcn(torch.zeros(1, 1, cfg.face_tcn_channels), z_a0))
        e0 = torch.cat([z_a0, z_f0, m.head_enc(torch.zeros(1, 1, 6))], -1)[0, 0]
        self.emb = e0.expand(W, -1).clone()  # (N+1, E) ring of per-frame embeddings
        self.frames = 0

    # ------------------------------------------------------------- encoding
    @staticmethod
    def _split_tcn(tcn) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        """Each layer's W = [W_past | W_now] split and transposed once, for addmm."""
        C = tcn.layers[0].weight.shape[0]
        return [(lin.bias.detach()[None].clone(), lin.weight.detach()[:, C:].t().contiguous(),
                 lin.weight.detach()[:, :C].t().contiguous()) for lin in tcn.layers]

    @staticmethod
    def _tcn_step(layers, queues: list[deque], x: torch.Tensor, extra: torch.Tensor | None = None) -> torch.Tensor:
        """One new frame (1, C) through a CausalTCN using (and updating) its per-layer queues.

        Same arithmetic as :meth:`CausalTCN.layer`, with pre-split weights.
        """
        skip = None
        last = len(layers) - 1
        for i, ((b, w_now, w_past), q) in enumerate(zip(layers, queues)):
            y = torch.addmm(b, x, w_now).addmm_(q[0], w_past)
            if i == last and extra is not None:
                y += extra
            y = F.leaky_relu(y, 0.2)
            q.append(x)  # maxlen d_i: the oldest input drops out
            skip = y if skip is None else skip + y
            x = x + y
        return skip

    def _push_inputs(self, audio, face, head) -> None:
        m, cfg = self.model, self.cfg
        a = _as_frame_audio(audio, cfg.samples_per_frame)
        f = _clean(face, cfg.n_face, "face")
        h = _clean(head, 6, "head rot6d")
        feat_a = m.audio_enc.frontend(a[None, None])[0]  # (1, C): this frame only
        z_a = m.audio_enc.mlp(self._tcn_step(self._audio_layers, self.q_audio, feat_a))
        z_f = m.face_enc.mlp(self._tcn_step(self._face_layers, self.q_face, m.face_enc.inp(f[None]),
                                            m.face_enc.tcn.extra(z_a)))
        z_h = m.head_enc(h[None])
        self.emb = torch.cat([self.emb[1:], torch.cat([z_a, z_f, z_h], -1)], 0)
        self.frames += 1

    # ------------------------------------------------------------------ API
    @torch.inference_mode()
    def warmup(self, audio: np.ndarray, face: np.ndarray, head: np.ndarray, pose: np.ndarray) -> None:
        """Push one frame whose pose is known (no generation, LSTM state untouched)."""
        self._push_inputs(audio, face, head)
        p = torch.from_numpy(np.asarray(pose, dtype=np.float32).reshape(-1).copy())
        self.hist = torch.cat([self.hist[1:], p[None]], 0)

    @torch.inference_mode()
    def step(self, audio: np.ndarray, face: np.ndarray, head: np.ndarray) -> np.ndarray:
        """Generate the current frame's pose (47, 6) from this frame's inputs."""
        self._push_inputs(audio, face, head)
        pose, self.state = self.model.step(self.emb[None], self.hist[None], self.state)
        self.hist = torch.cat([self.hist[1:], pose], 0)
        return pose.reshape(self.cfg.n_joints, 6).numpy().copy()


class NaiveStreamingGenerator(StreamingGenerator):
    """Reference loop: keeps raw inputs and re-encodes the whole window every frame.

    For the window's N+1 embeddings it encodes the last 2N+1 frames of raw input
    (each window frame needs its own N-frame past) — same outputs, far more work.
    """

    @torch.inference_mode()
    def reset(self, initial_pose: np.ndarray | None = None) -> None:
        super().reset(initial_pose)
        self.raw: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = []
        self.e0 = self.emb[0].clone()

    def _push_inputs(self, audio, face, head) -> None:
        cfg, W = self.cfg, self.cfg.window
        self.raw.append((_as_frame_audio(audio, cfg.samples_per_frame), _clean(face, cfg.n_face, "face"),
                         _clean(head, 6, "head rot6d")))
        self.raw = self.raw[-(2 * cfg.n_history + 1):]  # window frames + each one's past
        a = torch.stack([r[0] for r in self.raw])[None]
        f = torch.stack([r[1] for r in self.raw])[None]
        h = torch.stack([r[2] for r in self.raw])[None]
        z = self.model.encode(a, f, h)[0][-W:]  # (≤ N+1, E)
        pad = self.e0.expand(W - z.shape[0], -1)
        self.emb = torch.cat([pad, z], 0)
        self.frames += 1
