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
* both LSTM states ``(h, c)``, carried across steps (thesis 4.1.4);
* the LSTMs' input projections of each history frame: the fused input of frame τ
  (``[z; s_τ]``) no longer changes once its pose is known, so ``W_ih·fuse_τ`` is
  computed once per frame; each step projects only the current frame (pose slot 0)
  and the torso outputs fed to the limb LSTM, then runs the 17-step recurrence
  (``lstm_window``, TorchScript) from the carried state.

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


@torch.jit.script
def lstm_window(gx: torch.Tensor, h: torch.Tensor, c: torch.Tensor, w_hh_t: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A one-layer LSTM over a window whose input projections ``gx`` (W, 4H) are given.

    Same gates as ``torch.nn.LSTM`` (order i, f, g, o); ``h``, ``c``: (1, H). Returns the
    outputs (W, H) and the final state.
    """
    H = h.shape[1]
    outs: list[torch.Tensor] = []
    for k in range(gx.shape[0]):
        g = torch.addmm(gx[k:k + 1], h, w_hh_t)
        s = torch.sigmoid(g)
        c = torch.addcmul(s[:, H:2 * H] * c, s[:, :H], torch.tanh(g[:, 2 * H:3 * H]))
        h = s[:, 3 * H:] * torch.tanh(c)
        outs.append(h)
    return torch.cat(outs), h, c


class _ProjectedLSTM:
    """An ``nn.LSTM`` (one layer) split for per-frame caching of input projections.

    The input of window frame τ is ``[e_τ; s_τ; extra_τ]``; ``W_ih`` is cut into the
    blocks acting on each part, so ``W_e e_τ + W_s s_τ + b`` can be computed once per
    frame and kept, and only ``extra`` (the torso outputs, for the limb LSTM) is
    projected every step.
    """

    def __init__(self, lstm: torch.nn.LSTM, e_dim: int, s_dim: int):
        w = lstm.weight_ih_l0.detach()
        self.w_e = w[:, :e_dim].t().contiguous()
        self.w_s = w[:, e_dim:e_dim + s_dim].t().contiguous()
        self.w_x = w[:, e_dim + s_dim:].t().contiguous()  # (extra, 4H), may be empty
        self.b = (lstm.bias_ih_l0 + lstm.bias_hh_l0).detach()[None]
        self.w_hh_t = lstm.weight_hh_l0.detach().t().contiguous()


def initial_window(initial_pose: np.ndarray | None, neutral_window: np.ndarray) -> np.ndarray:
    """The N-frame pose history a stream starts from: (47, 6) repeated, (N, 47, 6), or the neutral window."""
    if initial_pose is None:
        return neutral_window
    N, J = neutral_window.shape[:2]
    p = np.asarray(initial_pose, dtype=np.float32)
    window = np.broadcast_to(p, (N, J, 6)) if p.ndim == 2 else p
    if window.shape != (N, J, 6):
        raise ValueError(f"initial pose must be ({J}, 6) or ({N}, {J}, 6), got {p.shape}")
    return window


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

    fast_decoder = True  # cache the LSTMs' per-frame input projections (one-layer decoders)

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
        dec, E = model.decoder, self.cfg.audio_dim + self.cfg.face_dim + self.cfg.head_dim
        self._fast = self.fast_decoder and self.cfg.lstm_layers == 1
        if self._fast:
            self._pt = _ProjectedLSTM(dec.lstm_t, E, self.cfg.pose_dim)
            self._pu = _ProjectedLSTM(dec.lstm_u, E, self.cfg.pose_dim)
        self.reset()

    # ---------------------------------------------------------------- state
    @torch.inference_mode()
    def reset(self, initial_pose: np.ndarray | None = None) -> None:
        """Start a new stream. ``initial_pose``: (47, 6), (N, 47, 6) or None (neutral)."""
        cfg, m, N, W = self.cfg, self.model, self.cfg.n_history, self.cfg.window
        window = initial_window(initial_pose, self.neutral_window)
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
        if self._fast:  # rings of W_e e_τ + W_s s_τ + b for the N history frames
            self.gx_t = self._project(self._pt, self.emb[:N], self.hist)
            self.gx_u = self._project(self._pu, self.emb[:N], self.hist)

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
        p = torch.from_numpy(np.asarray(pose, dtype=np.float32).reshape(1, -1).copy())
        self._append_history(p)

    @torch.inference_mode()
    def step(self, audio: np.ndarray, face: np.ndarray, head: np.ndarray) -> np.ndarray:
        """Generate the current frame's pose (47, 6) from this frame's inputs."""
        self._push_inputs(audio, face, head)
        if self._fast:
            pose, cur = self._decode_cached()
            self._append_history(pose, cur)
        else:
            pose, self.state = self.model.step(self.emb[None], self.hist[None], self.state)
            self._append_history(pose)
        return pose.reshape(self.cfg.n_joints, 6).numpy().copy()

    # -------------------------------------------------------------- decoding
    @staticmethod
    def _project(pl: _ProjectedLSTM, emb: torch.Tensor, pose: torch.Tensor | None) -> torch.Tensor:
        g = torch.addmm(pl.b, emb, pl.w_e)
        return g if pose is None else g.addmm_(pose, pl.w_s)

    def _append_history(self, pose: torch.Tensor, cur: tuple[torch.Tensor, torch.Tensor] | None = None) -> None:
        """Frame t's pose joins the history (eq. 4.11) — as its cached projections.

        ``cur``: the frame's projections without pose (``W_e e_t + b``) if the decoder
        already made them; the pose term is added to them in place.
        """
        if not self._fast:
            self.hist = torch.cat([self.hist[1:], pose], 0)
            return
        if cur is None:
            e = self.emb[-1:]
            cur = (self._project(self._pt, e, None), self._project(self._pu, e, None))
        self.gx_t = torch.cat([self.gx_t[1:], cur[0].addmm_(pose, self._pt.w_s)], 0)
        self.gx_u = torch.cat([self.gx_u[1:], cur[1].addmm_(pose, self._pu.w_s)], 0)

    def _decode_cached(self) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        """Decoder.forward on the window, from cached projections (same arithmetic).

        Returns the pose (1, J*6) and the current frame's pose-free projections.
        """
        dec, e = self.model.decoder, self.emb[-1:]
        (h_t, c_t), (h_u, c_u) = self.state
        cur_t, cur_u = self._project(self._pt, e, None), self._project(self._pu, e, None)  # s_t = 0 (eq. 3.5)
        o_t, h_t, c_t = lstm_window(torch.cat([self.gx_t, cur_t], 0), h_t[0], c_t[0], self._pt.w_hh_t)
        gx_u = torch.cat([self.gx_u, cur_u], 0).addmm_(o_t, self._pu.w_x)
        o_u, h_u, c_u = lstm_window(gx_u, h_u[0], c_u[0], self._pu.w_hh_t)
        self.state = ((h_t[None], c_t[None]), (h_u[None], c_u[None]))
        return torch.cat([dec.head_t(o_t[-1:]), dec.head_u(o_u[-1:])], -1), (cur_t, cur_u)


class NaiveStreamingGenerator(StreamingGenerator):
    """Reference loop: keeps raw inputs and re-encodes the whole window every frame.

    Its decoder is the model's own ``step`` (``nn.LSTM`` over the fused window), with no
    cached projections.

    For the window's N+1 embeddings it encodes the last 2N+1 frames of raw input
    (each window frame needs its own N-frame past) — same outputs, far more work.
    """

    fast_decoder = False

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
