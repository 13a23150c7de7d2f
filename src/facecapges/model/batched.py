"""Many live streams of one checkpoint, stepped together: :class:`BatchedStreamingGenerator`.

It is the :class:`~facecapges.model.streaming.StreamingGenerator` with every piece of
per-stream state stacked along a leading *slot* axis, so the frames of all streams
that are due at the same moment run as one batched call. Each stream owns one slot
(:meth:`open` / :meth:`close`); per slot it keeps exactly what the single-stream
generator keeps (same cold start, thesis 4.1.1):

==================  =====================  ===========================================
tensor              shape                  meaning
==================  =====================  ===========================================
``q_audio[i]``      (S, d_i, C_a)          audio TCN layer i's inputs of the last d_i frames
``q_face[i]``       (S, d_i, C_f)          same for the face TCN
``emb``             (S, N+1, E)            per-frame embeddings [z_A; z_F; z_H] of the window
``hist``            (S, N, J·6)            the last N poses (eq. 4.11)
``gx_t``, ``gx_u``  (S, N, 4H)             cached LSTM input projections of the history frames
``h_t c_t h_u c_u`` (S, H) / (L, S, H)     torso and limb LSTM states, carried (4.1.4)
==================  =====================  ===========================================

A :meth:`step` over slots ``ids`` gathers their rows, runs the audio front end, both
causal TCNs (one kernel-2 tap per layer), the head MLP and the decoder once for the
whole batch, and writes the rows back; streams that are not in ``ids`` are untouched.
Nothing mixes across the batch axis, so each stream's output equals the
single-stream generator's on the same inputs (tested to 1e-5).

Decoder. For one-layer LSTMs (the default config) the input projection of a history
frame, ``W_ih·[z_τ; s_τ] + b``, is fixed once its pose is known, so it is computed
once per frame and kept (``gx_*``); a step projects only the current frame (pose slot
zero, eq. 3.5) and the torso outputs that feed the limb LSTM, then runs the N+1-step
recurrence from the carried state. Other configs run ``FaceCapGes.step`` on the
batch (the training-time code path).

Not thread-safe by itself beyond one internal lock: callers may open/close slots
from one thread while another steps; every public method takes the lock.
"""

from __future__ import annotations

import threading
from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from facecapges.model.network import FaceCapGes
from facecapges.model.streaming import initial_window


def pack_audio(frames: Sequence[np.ndarray], samples_per_frame: int) -> np.ndarray:
    """Per-stream frame audio (each ≤ S samples) → (B, S) float32, zero padded, NaN → 0."""
    out = np.zeros((len(frames), samples_per_frame), np.float32)
    for i, a in enumerate(frames):
        a = np.asarray(a, dtype=np.float32).reshape(-1)
        if a.shape[0] > samples_per_frame:
            raise ValueError(f"a frame owns at most {samples_per_frame} audio samples, got {a.shape[0]}")
        out[i, : a.shape[0]] = a
    return np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0)


def _rows(x, n: int, what: str, batch: int) -> torch.Tensor:
    a = np.asarray(x, dtype=np.float32).reshape(batch, -1)
    if a.shape[1] != n:
        raise ValueError(f"{what} must have {n} values per stream, got {a.shape[1]}")
    return torch.from_numpy(np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0))


class _LSTMBlocks:
    """A one-layer ``nn.LSTM`` whose W_ih is cut into the blocks acting on [e; s; extra]."""

    def __init__(self, lstm: torch.nn.LSTM, e_dim: int, s_dim: int):
        w = lstm.weight_ih_l0.detach()
        self.w_e = w[:, :e_dim].t().contiguous()  # (E, 4H)
        self.w_s = w[:, e_dim:e_dim + s_dim].t().contiguous()  # (J*6, 4H)
        self.w_x = w[:, e_dim + s_dim:].t().contiguous()  # (extra, 4H); empty for the torso LSTM
        self.b = (lstm.bias_ih_l0 + lstm.bias_hh_l0).detach()[None]  # (1, 4H)
        self.w_hh_t = lstm.weight_hh_l0.detach().t().contiguous()  # (H, 4H)


@torch.jit.script
def lstm_window(gx: torch.Tensor, cur: torch.Tensor, h: torch.Tensor, c: torch.Tensor, w_hh_t: torch.Tensor,
                extra: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One-layer LSTM over a window from precomputed input gates (TorchScript: one call, no
    per-step Python dispatch).

    ``gx`` (B, N, 4H): the history frames' gates, oldest first; ``cur`` (B, 4H): the current
    frame's; ``extra`` (B, N+1, 4H) or None: gates added per step (the torso outputs'
    projection, for the limb LSTM); ``h``, ``c`` (B, H). Gate order i, f, g, o as
    ``torch.nn.LSTM``. Returns the outputs (B, N+1, H) and the final h, c.
    """
    H = h.shape[1]
    N = gx.shape[1]
    outs: list[torch.Tensor] = []
    for k in range(N + 1):
        x = gx[:, k] if k < N else cur
        if extra is not None:
            x = x + extra[:, k]
        g = torch.addmm(x, h, w_hh_t)
        s = torch.sigmoid(g)
        c = s[:, H:2 * H] * c + s[:, :H] * torch.tanh(g[:, 2 * H:3 * H])
        h = s[:, 3 * H:] * torch.tanh(c)
        outs.append(h)
    return torch.stack(outs, 1), h, c


class _ScriptedStep(torch.nn.Module):
    """The whole batched step of a one-layer-decoder model as ONE TorchScript call.

    Same arithmetic as the Python path (:meth:`BatchedStreamingGenerator._push_inputs` +
    :meth:`BatchedStreamingGenerator._decode_fast`); run as one call it needs the GIL
    once instead of for every one of its few hundred tensor operations, so a server's
    event loop and the model do not take turns waiting for each other. The rings and
    LSTM states are arguments (updated in place), the weights are shared with the model.
    """

    def __init__(self, model: FaceCapGes, audio_layers, face_layers, bt: "_LSTMBlocks", bu: "_LSTMBlocks"):
        super().__init__()
        cfg = model.cfg
        self.frontend = model.audio_enc.frontend
        self.audio_mlp = model.audio_enc.mlp
        self.face_inp = model.face_enc.inp
        self.face_extra = model.face_enc.tcn.extra
        self.face_mlp = model.face_enc.mlp
        self.head_enc = model.head_enc
        self.head_t = model.decoder.head_t
        self.head_u = model.decoder.head_u
        self.a_b = [b for b, _, _ in audio_layers]
        self.a_now = [w for _, w, _ in audio_layers]
        self.a_past = [w for _, _, w in audio_layers]
        self.a_dil = [int(d) for d in cfg.audio_tcn_dilations]
        self.f_b = [b for b, _, _ in face_layers]
        self.f_now = [w for _, w, _ in face_layers]
        self.f_past = [w for _, _, w in face_layers]
        self.f_dil = [int(d) for d in cfg.face_tcn_dilations]
        self.t_b, self.t_we, self.t_ws, self.t_whh = bt.b, bt.w_e, bt.w_s, bt.w_hh_t
        self.u_b, self.u_we, self.u_ws, self.u_wx, self.u_whh = bu.b, bu.w_e, bu.w_s, bu.w_x, bu.w_hh_t
        self.n_history = int(cfg.n_history)

    def _tcn(self, x: torch.Tensor, idx: torch.Tensor, frames: torch.Tensor, rings: list[torch.Tensor],
             b: list[torch.Tensor], w_now: list[torch.Tensor], w_past: list[torch.Tensor], dil: list[int],
             extra: torch.Tensor | None) -> torch.Tensor:
        skip = torch.zeros_like(x)
        n = len(rings)
        for i in range(n):
            rows = idx * dil[i] + torch.remainder(frames, dil[i])
            y = torch.addmm(b[i], x, w_now[i]).addmm_(rings[i].index_select(0, rows), w_past[i])
            if extra is not None and i == n - 1:
                y = y + extra
            y = F.leaky_relu(y, 0.2)
            rings[i].index_copy_(0, rows, x)
            skip = skip + y
            x = x + y
        return skip

    def forward(self, idx: torch.Tensor, frames: torch.Tensor, audio: torch.Tensor, face: torch.Tensor,
                head: torch.Tensor, q_audio: list[torch.Tensor], q_face: list[torch.Tensor], gx_t: torch.Tensor,
                gx_u: torch.Tensor, h_t: torch.Tensor, c_t: torch.Tensor, h_u: torch.Tensor, c_u: torch.Tensor,
                steps: torch.Tensor) -> torch.Tensor:
        N = self.n_history
        feat_a = self.frontend(audio.unsqueeze(1)).squeeze(1)  # (B, C)
        z_a = self.audio_mlp(self._tcn(feat_a, idx, frames, q_audio, self.a_b, self.a_now, self.a_past, self.a_dil,
                                       None))
        extra = self.face_extra(z_a) if self.face_extra is not None else None
        z_f = self.face_mlp(self._tcn(self.face_inp(face), idx, frames, q_face, self.f_b, self.f_now, self.f_past,
                                      self.f_dil, extra))
        e = torch.cat([z_a, z_f, self.head_enc(head)], -1)  # (B, E)
        hist_rows = idx.unsqueeze(1) * N + torch.remainder(frames.unsqueeze(1) + steps.unsqueeze(0), N)
        cur_t = torch.addmm(self.t_b, e, self.t_we)  # the current frame: pose slot zero (eq. 3.5)
        cur_u = torch.addmm(self.u_b, e, self.u_we)
        o_t, h, c = lstm_window(gx_t[hist_rows], cur_t, h_t.index_select(0, idx), c_t.index_select(0, idx),
                                self.t_whh, None)
        h_t.index_copy_(0, idx, h)
        c_t.index_copy_(0, idx, c)
        ox = torch.matmul(o_t, self.u_wx)
        o_u, h, c = lstm_window(gx_u[hist_rows], cur_u, h_u.index_select(0, idx), c_u.index_select(0, idx),
                                self.u_whh, ox)
        h_u.index_copy_(0, idx, h)
        c_u.index_copy_(0, idx, c)
        pose = torch.cat([self.head_t(o_t[:, -1]), self.head_u(h)], -1)
        rows = idx * N + torch.remainder(frames, N)  # frame f's pose joins the history (eq. 4.11)
        gx_t.index_copy_(0, rows, cur_t.addmm(pose, self.t_ws))
        gx_u.index_copy_(0, rows, cur_u.addmm(pose, self.u_ws))
        return pose


class BatchedStreamingGenerator:
    """Independent causal streams of one model, stepped as one batch (module docs)."""

    use_script = True  # one-layer decoders: the step as one TorchScript call (False: the Python path)

    def __init__(self, model: FaceCapGes, neutral_window: np.ndarray, capacity: int = 8):
        self.model = model.eval()
        cfg = self.cfg = model.cfg
        N = cfg.n_history
        nw = np.asarray(neutral_window, dtype=np.float32)
        if nw.shape != (N, cfg.n_joints, 6):
            raise ValueError(f"neutral window must be ({N}, {cfg.n_joints}, 6), got {nw.shape}")
        self.neutral_window = nw
        self._lock = threading.RLock()
        self._audio_layers = self._split_tcn(model.audio_enc.tcn)
        self._face_layers = self._split_tcn(model.face_enc.tcn)
        self.E = cfg.audio_dim + cfg.face_dim + cfg.head_dim
        self.fast = cfg.lstm_layers == 1
        if self.fast:
            self._bt = _LSTMBlocks(model.decoder.lstm_t, self.E, cfg.pose_dim)
            self._bu = _LSTMBlocks(model.decoder.lstm_u, self.E, cfg.pose_dim)
            self._scripted = torch.jit.script(_ScriptedStep(model, self._audio_layers, self._face_layers,
                                                            self._bt, self._bu))
            self._steps = torch.arange(-N, 0)
        with torch.inference_mode():
            m = model
            # embedding of a frame before the stream: the encoders over zero features
            z_a0 = m.audio_enc.from_features(torch.zeros(1, 1, cfg.audio_tcn_channels))
            z_f0 = m.face_enc.mlp(m.face_enc.tcn(torch.zeros(1, 1, cfg.face_tcn_channels), z_a0))
            self._e0 = torch.cat([z_a0, z_f0, m.head_enc(torch.zeros(1, 1, 6))], -1)[0, 0].clone()  # (E,)
        self.capacity = 0
        self._free: list[int] = []
        self._open: set[int] = set()
        self._alloc(max(1, capacity))

    # ------------------------------------------------------------ storage
    # Every per-frame store is a ring: slot s's frame f lives at row s·R + f mod R
    # (R = the ring length), so a step writes B rows and reads the window in time order
    # by index, instead of shifting whole windows. ``frames[s]`` counts s's frames.
    def _alloc(self, capacity: int) -> None:
        """(Re)allocate the stacked state for ``capacity`` slots, keeping existing rows."""
        cfg, N, W, H, L = self.cfg, self.cfg.n_history, self.cfg.window, self.cfg.lstm_hidden, self.cfg.lstm_layers
        old = self.capacity

        def grow(name: str, shape: tuple[int, ...], axis: int = 0, i: int | None = None,
                 dtype: torch.dtype = torch.float32) -> torch.Tensor:
            new = torch.zeros(shape, dtype=dtype)
            if old:
                prev = getattr(self, name) if i is None else getattr(self, name)[i]
                new.narrow(axis, 0, prev.shape[axis]).copy_(prev)
            return new

        # TCN layer i: ring of its inputs of the last d_i frames, (S·d_i, C)
        self.q_audio = [grow("q_audio", (capacity * d, cfg.audio_tcn_channels), i=i)
                        for i, d in enumerate(cfg.audio_tcn_dilations)]
        self.q_face = [grow("q_face", (capacity * d, cfg.face_tcn_channels), i=i)
                       for i, d in enumerate(cfg.face_tcn_dilations)]
        self.frames = grow("frames", (capacity,), dtype=torch.long)
        if self.fast:  # rings of the history frames' LSTM input projections, (S·N, 4H)
            self.gx_t = grow("gx_t", (capacity * N, 4 * H))
            self.gx_u = grow("gx_u", (capacity * N, 4 * H))
            self.h_t, self.c_t, self.h_u, self.c_u = (grow(n, (capacity, H)) for n in ("h_t", "c_t", "h_u", "c_u"))
        else:  # the model's own step: embeddings (S·W, E) and poses (S·N, J·6) rings
            self.emb = grow("emb", (capacity * W, self.E))
            self.hist = grow("hist", (capacity * N, cfg.pose_dim))
            self.h_t, self.c_t, self.h_u, self.c_u = (grow(n, (L, capacity, H), axis=1)
                                                      for n in ("h_t", "c_t", "h_u", "c_u"))
        self._free = sorted(set(self._free) | set(range(old, capacity)), reverse=True)
        self.capacity = capacity

    @staticmethod
    def _ring_rows(idx: torch.Tensor, frames: torch.Tensor, ring: int, count: int, ahead: int = 0) -> torch.Tensor:
        """Rows (B, count) of the last ``count`` entries, oldest first, of rings of length ``ring``.

        The newest entry of slot s is frame ``frames[s] - 1 + ahead``.
        """
        k = torch.arange(-count, 0) + ahead  # frame offsets relative to frames[s]
        return idx[:, None] * ring + torch.remainder(frames[:, None] + k[None], ring)

    # ---------------------------------------------------------------- slots
    @property
    def n_open(self) -> int:
        return len(self._open)

    @property
    def open_slots(self) -> frozenset[int]:
        return frozenset(self._open)

    def open(self, initial_pose: np.ndarray | None = None) -> int:
        """A new stream in cold-start state (``reset``); returns its slot id."""
        with self._lock:
            if not self._free:
                self._alloc(self.capacity * 2)
            slot = self._free.pop()
            self._open.add(slot)
            self.reset(slot, initial_pose)
            return slot

    def close(self, slot: int) -> None:
        with self._lock:
            if slot in self._open:
                self._open.discard(slot)
                self._free.append(slot)

    @torch.inference_mode()
    def reset(self, slot: int, initial_pose: np.ndarray | None = None) -> None:
        """Cold start of one stream, as ``StreamingGenerator.reset``: (47, 6), (N, 47, 6) or None."""
        cfg, N, W = self.cfg, self.cfg.n_history, self.cfg.window
        window = initial_window(initial_pose, self.neutral_window)
        with self._lock:
            if slot not in self._open:
                raise KeyError(f"slot {slot} is not open")
            hist = torch.from_numpy(np.ascontiguousarray(window).reshape(N, -1).copy())
            self.frames[slot] = 0  # ring rows: frame -N … -1 of the window sit at (f mod R)
            for q, d in zip(self.q_audio + self.q_face, cfg.audio_tcn_dilations + cfg.face_tcn_dilations):
                q[slot * d:(slot + 1) * d] = 0.0  # before the stream: the encoders' causal zeros
            order = torch.remainder(torch.arange(-N, 0), N)  # window frame j -> ring row
            if self.fast:
                e = self._e0.expand(N, -1)
                for blocks, ring in ((self._bt, self.gx_t), (self._bu, self.gx_u)):
                    ring[slot * N + order] = torch.addmm(blocks.b, e, blocks.w_e).addmm_(hist, blocks.w_s)
                for s in (self.h_t, self.c_t, self.h_u, self.c_u):
                    s[slot] = 0.0
            else:
                self.hist[slot * N + order] = hist
                self.emb[slot * W:(slot + 1) * W] = self._e0
                for s in (self.h_t, self.c_t, self.h_u, self.c_u):
                    s[:, slot] = 0.0

    # ------------------------------------------------------------- encoding
    @staticmethod
    def _split_tcn(tcn) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        C = tcn.layers[0].weight.shape[0]
        return [(lin.bias.detach()[None].clone(), lin.weight.detach()[:, C:].t().contiguous(),
                 lin.weight.detach()[:, :C].t().contiguous()) for lin in tcn.layers]

    @staticmethod
    def _tcn_step(layers, queues: list[torch.Tensor], dilations, idx: torch.Tensor, frames: torch.Tensor,
                  x: torch.Tensor, extra: torch.Tensor | None = None) -> torch.Tensor:
        """New frames (B, C) of streams ``idx`` through a CausalTCN, updating their rings.

        Layer i reads its input of d_i frames ago (ring row f mod d_i of frame f − d_i,
        the row frame f then takes over).
        """
        skip = None
        last = len(layers) - 1
        for i, ((b, w_now, w_past), q, d) in enumerate(zip(layers, queues, dilations)):
            rows = idx * d + torch.remainder(frames, d)
            y = torch.addmm(b, x, w_now).addmm_(q.index_select(0, rows), w_past)
            if i == last and extra is not None:
                y += extra
            y = F.leaky_relu(y, 0.2)
            q.index_copy_(0, rows, x)
            skip = y if skip is None else skip + y
            x = x + y
        return skip

    def _clean_inputs(self, audio, face, head, B: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(B, S) audio, (B, 52) face, (B, 6) head tensors; NaN/inf → 0 as the single-stream generator."""
        cfg = self.cfg
        if isinstance(audio, np.ndarray) and audio.ndim == 2 and audio.shape[1] == cfg.samples_per_frame:
            a = torch.from_numpy(np.nan_to_num(audio.astype(np.float32, copy=False), nan=0.0, posinf=0.0,
                                               neginf=0.0))
        else:
            a = torch.from_numpy(pack_audio(audio, cfg.samples_per_frame))
        if a.shape[0] != B:
            raise ValueError(f"audio has {a.shape[0]} rows for {B} streams")
        return a, _rows(face, cfg.n_face, "face", B), _rows(head, 6, "head rot6d", B)

    def _push_inputs(self, idx: torch.Tensor, frames: torch.Tensor, audio, face, head) -> torch.Tensor:
        """Encode this frame of every stream in ``idx``; returns the new embeddings (B, E)."""
        m, cfg = self.model, self.cfg
        a, f, h = self._clean_inputs(audio, face, head, len(idx))
        feat_a = m.audio_enc.frontend(a[:, None])[:, 0]  # (B, C): each stream's frame only
        z_a = m.audio_enc.mlp(self._tcn_step(self._audio_layers, self.q_audio, cfg.audio_tcn_dilations, idx, frames,
                                             feat_a))
        z_f = m.face_enc.mlp(self._tcn_step(self._face_layers, self.q_face, cfg.face_tcn_dilations, idx, frames,
                                            m.face_enc.inp(f), m.face_enc.tcn.extra(z_a)))
        z_h = m.head_enc(h)
        e = torch.cat([z_a, z_f, z_h], -1)  # (B, E)
        if not self.fast:
            W = cfg.window
            self.emb.index_copy_(0, idx * W + torch.remainder(frames, W), e)
        return e

    def _append_history(self, idx: torch.Tensor, frames: torch.Tensor, e: torch.Tensor, pose: torch.Tensor,
                        cur: tuple[torch.Tensor, torch.Tensor] | None = None) -> None:
        """Frame f's pose (B, J*6) joins the history of streams ``idx`` (eq. 4.11)."""
        N = self.cfg.n_history
        rows = idx * N + torch.remainder(frames, N)
        if self.fast:
            for blocks, ring, c in ((self._bt, self.gx_t, cur[0] if cur else None),
                                    (self._bu, self.gx_u, cur[1] if cur else None)):
                base = c if c is not None else torch.addmm(blocks.b, e, blocks.w_e)
                ring.index_copy_(0, rows, base.addmm(pose, blocks.w_s))
        else:
            self.hist.index_copy_(0, rows, pose)
        self.frames.index_copy_(0, idx, frames + 1)

    def _ids(self, slots: Sequence[int]) -> tuple[torch.Tensor, torch.Tensor]:
        idx = torch.as_tensor(np.asarray(slots, dtype=np.int64).reshape(-1))
        if len(set(idx.tolist())) != len(idx):
            raise ValueError("a stream can take only one frame per batched step")
        closed = [s for s in idx.tolist() if s not in self._open]
        if closed:
            raise KeyError(f"slot(s) {closed} are not open")
        return idx, self.frames.index_select(0, idx)

    # ------------------------------------------------------------------ API
    @torch.inference_mode()
    def warmup(self, slots: Sequence[int], audio, face, head, pose) -> None:
        """Push one frame with a known pose per stream (no generation, LSTM state untouched)."""
        with self._lock:
            idx, frames = self._ids(slots)
            e = self._push_inputs(idx, frames, audio, face, head)
            p = torch.from_numpy(np.asarray(pose, dtype=np.float32).reshape(len(idx), -1).copy())
            self._append_history(idx, frames, e, p)

    @torch.inference_mode()
    def step(self, slots: Sequence[int], audio, face, head) -> np.ndarray:
        """One frame for each stream in ``slots``: audio (B, ≤S) (array or list), face (B, 52),
        head (B, 6) → poses (B, 47, 6) rot6d, in the order of ``slots``."""
        with self._lock:
            idx, frames = self._ids(slots)
            if len(idx) == 0:
                return np.zeros((0, self.cfg.n_joints, 6), np.float32)
            if self.fast and self.use_script:
                a, f, h = self._clean_inputs(audio, face, head, len(idx))
                pose = self._scripted(idx, frames, a, f, h, self.q_audio, self.q_face, self.gx_t, self.gx_u,
                                      self.h_t, self.c_t, self.h_u, self.c_u, self._steps)
                self.frames.index_copy_(0, idx, frames + 1)
            else:
                e = self._push_inputs(idx, frames, audio, face, head)
                pose = self._decode_fast(idx, frames, e) if self.fast else self._decode_model(idx, frames)
            return pose.reshape(len(idx), self.cfg.n_joints, 6).numpy().copy()

    def _decode_fast(self, idx: torch.Tensor, frames: torch.Tensor, e: torch.Tensor) -> torch.Tensor:
        """Decoder.forward on each stream's window from the cached projections."""
        N, dec, bt, bu = self.cfg.n_history, self.model.decoder, self._bt, self._bu
        hist_rows = self._ring_rows(idx, frames, N, N)  # (B, N): the history frames, oldest first
        cur_t = torch.addmm(bt.b, e, bt.w_e)  # the current frame: its pose slot is zero (eq. 3.5)
        cur_u = torch.addmm(bu.b, e, bu.w_e)
        o_t, h, c = lstm_window(self.gx_t[hist_rows], cur_t, self.h_t.index_select(0, idx),
                                self.c_t.index_select(0, idx), bt.w_hh_t)  # torso (eq. 4.12)
        self.h_t.index_copy_(0, idx, h)
        self.c_t.index_copy_(0, idx, c)
        ox = torch.matmul(o_t, bu.w_x)  # torso outputs condition the limbs (eq. 4.13)
        o_u, h, c = lstm_window(self.gx_u[hist_rows], cur_u, self.h_u.index_select(0, idx),
                                self.c_u.index_select(0, idx), bu.w_hh_t, ox)
        self.h_u.index_copy_(0, idx, h)
        self.c_u.index_copy_(0, idx, c)
        pose = torch.cat([dec.head_t(o_t[:, -1]), dec.head_u(h)], -1)  # only the last step is decoded
        self._append_history(idx, frames, e, pose, (cur_t, cur_u))
        return pose

    def _decode_model(self, idx: torch.Tensor, frames: torch.Tensor) -> torch.Tensor:
        """Any decoder config: ``FaceCapGes.step`` on the gathered windows (training code path)."""
        N, W = self.cfg.n_history, self.cfg.window
        emb = self.emb[self._ring_rows(idx, frames, W, W, ahead=1)]  # (B, W, E), current frame last
        hist = self.hist[self._ring_rows(idx, frames, N, N)]  # (B, N, J*6)
        state = ((self.h_t.index_select(1, idx), self.c_t.index_select(1, idx)),
                 (self.h_u.index_select(1, idx), self.c_u.index_select(1, idx)))
        pose, ((h_t, c_t), (h_u, c_u)) = self.model.step(emb, hist, state)
        for store, v in ((self.h_t, h_t), (self.c_t, c_t), (self.h_u, h_u), (self.c_u, c_u)):
            store.index_copy_(1, idx, v)
        self._append_history(idx, frames, None, pose)
        return pose
