"""The streaming kernel: many live streams of one checkpoint, stepped together.

:class:`BatchedStreamingGenerator` is the one implementation of causal frame-by-frame
inference. Each stream owns one *slot* (:meth:`open` / :meth:`close`); a :meth:`step`
over some slots runs their current frames as one batched call.
:class:`~facecapges.model.streaming.StreamingGenerator` is a one-slot use of it, and
:class:`~facecapges.model.streaming.NaiveStreamingGenerator` (the training code path,
re-encoding every window) is its test oracle.

Per slot it keeps (cold start as thesis 4.1.1: the neutral window as history, zero
LSTM states, "no input" — zero features — before the stream):

==================  =====================  ===========================================
tensor              shape                  meaning
==================  =====================  ===========================================
``x_audio``         (S, R_a, L_a, C_a)     ring of the audio TCN's layer inputs of the
                                           last R_a = max(d_i) frames (row f mod R_a)
``x_face``          (S, R_f, L_f, C_f)     same for the face TCN
``gx_t``, ``gx_u``  (S, N, 4H)             ring of the history frames' LSTM input
                                           projections ``W_ih·[z_τ; s_τ] + b``
``hc``              (S, 2, 2H)             [h_t | h_u], [c_t | c_u]: torso and limb
                                           LSTM states, carried across steps (4.1.4)
``frames``          (S,)                   frames pushed so far
==================  =====================  ===========================================

The kernel of one step, stage by stage (each stage is a ``torch.profiler`` scope named
``facecapges::<stage>``, so ``bench`` reads the stage timings from a profile of the
real step, not from a copy of it):

* ``input_prep`` — samples / weights → (B, S), (B, 52), (B, 6) tensors, NaN → 0;
* ``audio_frontend`` — :meth:`audio_features`, the model's per-frame audio front end
  over this frame's samples only (a separate call, so another front end slots in);
* ``audio_tcn`` / ``face_encoder`` — one :func:`tcn_tap` per TCN layer: layer i reads
  its input of d_i frames ago from the ring (kernel 2, causal), so a new frame costs
  one tap per layer and gives the same embedding as encoding the whole stream;
* ``head_encoder`` — the head MLP;
* ``decoder`` — both LSTMs over the N+1 window. The input projection of a history
  frame is fixed once its pose is known, so it is computed once per frame and kept
  (``gx_*``); a step projects only the current frame (pose slot zero, eq. 3.5) and the
  torso outputs that feed the limb LSTM (eq. 4.13), runs both N+1-step recurrences
  (:class:`Cascade`) from the carried state, decodes the last step with the MLP
  heads, and writes the new frame's projections into the history ring (eq. 4.11).

Decoders with more than one LSTM layer run ``FaceCapGes.step`` on the gathered
windows instead (the training code path; rings of embeddings and poses).

Nothing mixes across the batch axis: each stream's output equals the naive
re-windowed loop's on the same inputs (tested to 1e-5), and a one-slot generator gives
the same poses as a slot of a batch.

What replaced TorchScript (``torch.jit.script`` is deprecated in torch 2.13): measured
on this 2-core machine, default checkpoint, one thread, the candidates interleaved in
one run; CPU ms per step (``time.thread_time``, so the other helpers' load — average
16–22 during the run — inflates all alike, ~3× a quiet machine's figures):

=====================================  =========  =========  ===============================
kernel                                 B = 1      B = 64     start-up
=====================================  =========  =========  ===============================
TorchScript (the old step)             2.47       19.7       ~1 s (scripting)
eager, this module (before lockstep)   3.20       22.6       none
torch.compile (inductor) of the step   2.42       18.4       191 s (B = 1), 210 s (B = 64)
                                                             cold, per batch shape; 5.5 s
                                                             from a warm on-disk cache
torch.export, the LSTM window only     1.74       —          18.6 s to export
  (same window in eager: 1.08)
=====================================  =========  =========  ===============================

Chosen: **eager**. torch.compile runs no faster than TorchScript did and needs minutes
of compilation for every checkpoint shape and batch size on first use — every
``run``, ``live``, test and ``serve`` start would pay it on a fresh machine;
``torch.export``'s program, run from Python, is slower than the eager code it records
(and AOT-compiling it costs what inductor costs). What eager loses (1.3× CPU at one
stream) is won back where it matters: the two LSTMs run in lockstep for small batches
(:class:`Cascade`: 1.53 vs 1.67 ms for the decoder at B = 1, same run), Euler
conversion moved to one vectorised pass (:func:`facecapges.rotations.matrix_to_euler`),
and ``serve`` — which needed TorchScript's single GIL-free call so its event loop and
the model would not wait for each other — runs this kernel in a process of its own
(:mod:`facecapges.serving.model_process`).

Where the rest of the CPU's peak goes (the step's 12 MFLOP reach a few % of the
~100 GFLOP/s single-thread matmul peak, ``bench``'s ``fraction_of_peak``): the step is
~360 small tensor operations, each a few µs of dispatch and allocation whatever its
size (per-op overhead, most of the time at B = 1); its products are matrix–vector
products (B = 1) that read every weight once per use — ~9 MB of weights per frame
(the LSTMs' W_hh 17 times each) streamed from L2/L3, so they run at memory speed, not
at the FMA units' peak; the audio front end's small strided convolutions are far
from GEMM efficiency. Batching (``serve``) turns the products into matrix–matrix ones
and spreads the per-op overhead over the streams.

Thread safety: every public method takes one internal lock, so one thread may
open/close slots while another steps.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch.autograd.profiler import record_function

from facecapges.model.network import FaceCapGes

STAGES = ("input_prep", "audio_frontend", "audio_tcn", "face_encoder", "head_encoder", "decoder")
_NO_SCOPE = contextlib.nullcontext()


stage_listener: Callable[[str], contextlib.AbstractContextManager] | None = (
    None  # a function stage name → context manager, set by the benchmark to count FLOPs per stage
)


def stage(name: str):
    """The profiler scope ``facecapges::<name>`` while a profiler records, else nothing (≈ free)."""
    if stage_listener is not None:
        return stage_listener(name)
    return record_function("facecapges::" + name) if torch.autograd.profiler._is_profiler_enabled else _NO_SCOPE


# ------------------------------------------------------------------ inputs
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


def pack_audio(frames: Sequence[np.ndarray], samples_per_frame: int) -> np.ndarray:
    """Per-stream frame audio (each ≤ S samples) → (B, S) float32, zero padded, NaN → 0."""
    out = np.zeros((len(frames), samples_per_frame), np.float32)
    for i, a in enumerate(frames):
        a = np.asarray(a, dtype=np.float32).reshape(-1)
        if a.shape[0] > samples_per_frame:
            raise ValueError(f"a frame owns at most {samples_per_frame} audio samples, got {a.shape[0]}")
        out[i, : a.shape[0]] = a
    return np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0, copy=False)


def _rows(x, n: int, what: str, batch: int) -> torch.Tensor:
    a = np.asarray(x, dtype=np.float32).reshape(batch, -1)
    if a.shape[1] != n:
        raise ValueError(f"{what} must have {n} values per stream, got {a.shape[1]}")
    return torch.from_numpy(np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0))


def no_input_embedding(model) -> torch.Tensor:
    """Embedding (E,) of a frame before the stream starts: the encoders over zero features.

    Exactly the causal zero padding of the sequence encoders, so a stream's first frames
    see the same past as a whole clip encoded at once. ``model``: anything with the
    FaceCapGes encoders (``audio_enc``, ``face_enc``, ``head_enc``).
    """
    cfg = model.cfg
    z_a = model.audio_enc.from_features(torch.zeros(1, 1, cfg.audio_tcn_channels))
    z_f = model.face_enc.mlp(model.face_enc.tcn(torch.zeros(1, 1, cfg.face_tcn_channels), z_a))
    return torch.cat([z_a, z_f, model.head_enc(torch.zeros(1, 1, 6))], -1)[0, 0]


# ------------------------------------------------------------------ the kernel's pieces
def tcn_tap(
    x_now: torch.Tensor,
    x_past: torch.Tensor,
    b: torch.Tensor,
    w_now: torch.Tensor,
    w_past: torch.Tensor,
    extra: torch.Tensor | None = None,
) -> torch.Tensor:
    """One frame through one causal TCN layer: ``act(W [x_{t-d}; x_t] + b (+ extra))``.

    The arithmetic of :meth:`~facecapges.model.network.CausalTCN.layer` with its weight
    split into the blocks acting on the past and the current tap (``w_past``, ``w_now``,
    transposed, (C, C) each); ``x_now``, ``x_past`` (B, C).
    """
    y = torch.addmm(b, x_now, w_now).addmm_(x_past, w_past)
    if extra is not None:
        y += extra
    return F.leaky_relu(y, 0.2)


def split_tcn(tcn) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
    """Each layer's (b, W_now^T, W_past^T) of a CausalTCN, split once for :func:`tcn_tap`."""
    C = tcn.layers[0].weight.shape[0]
    return [
        (
            lin.bias.detach()[None].clone(),
            lin.weight.detach()[:, C:].t().contiguous(),
            lin.weight.detach()[:, :C].t().contiguous(),
        )
        for lin in tcn.layers
    ]


def lstm_window(
    gx: torch.Tensor, h: torch.Tensor, c: torch.Tensor, w_hh_t: torch.Tensor
) -> tuple[list[torch.Tensor], torch.Tensor]:
    """A one-layer LSTM over a window whose input gates ``gx`` (B, W, 4H) are given.

    Gates as ``torch.nn.LSTM`` (order i, f, g, o); ``h``, ``c`` (B, H) the carried state,
    ``w_hh_t`` (H, 4H). Returns the W outputs (B, H) each (the last is the final h) and
    the final c.
    """
    H = h.shape[1]
    outs = []
    for x in gx.unbind(1):
        g = torch.addmm(x, h, w_hh_t)
        i, f, _, o = g.sigmoid().chunk(4, 1)
        c = torch.addcmul(f * c, i, g[:, 2 * H : 3 * H].tanh())
        h = o * c.tanh()
        outs.append(h)
    return outs, c


class Cascade:
    """The torso LSTM and the limb LSTM it conditions (eq. 4.12–4.13) over one window.

    :meth:`run` takes the input gates of each window step, ``gx_t``, ``gx_u`` (B, W, 4H),
    without the limb's torso-output term, and the carried states ``h``, ``c`` (B, 2H) as
    ``[torso | limb]``; it returns the final ``h``, ``c``. Two schedules of the same
    recurrence (same gates as ``torch.nn.LSTM``, order i, f, g, o), chosen by batch size:

    * **lockstep** (B ≤ :attr:`LOCKSTEP_MAX_BATCH`): iteration m runs torso step m and
      limb step m − 1 as one cell — the limb's input at step m − 1 is the torso output
      h_t,m−1, exactly the torso half of the state iteration m starts from, so one
      ``[h_t | h_u] @ w`` (2H × 8H, gate columns interleaved ``[i_t i_u f_t f_u …]``)
      gives both cells' recurrent gates and the limb's torso term: W + 1 cells of ~9
      ops instead of 2W. Fewer ops win when the per-op overhead dominates (one stream);
    * **sequential** (larger batches): the torso over the whole window, its outputs'
      projection as one GEMM, then the limb — fewer multiply–adds (no zero block, W_x
      read once), which wins once the products dominate.

    Measured (CPU ms per kernel step, same run): lockstep vs sequential 1.53 vs 1.67 at
    B = 1, 28.5 vs 22.6 at B = 64 (load 19, so ~3× a quiet machine's figures).
    """

    LOCKSTEP_MAX_BATCH = 4

    def __init__(self, lstm_t: torch.nn.LSTM, lstm_u: torch.nn.LSTM):
        H = self.H = lstm_t.hidden_size
        self.w_t = lstm_t.get_parameter("weight_hh_l0").detach().t().contiguous()  # (H, 4H)
        self.w_x = lstm_u.get_parameter("weight_ih_l0").detach()[:, -H:].t().contiguous()  # limb input = [e; s; o_t]
        self.w_u = lstm_u.get_parameter("weight_hh_l0").detach().t().contiguous()
        top = torch.stack([self.w_t.reshape(H, 4, H), self.w_x.reshape(H, 4, H)], 2)
        bottom = torch.stack([torch.zeros(H, 4, H), self.w_u.reshape(H, 4, H)], 2)
        self.w = torch.cat([top, bottom], 0).reshape(2 * H, 8 * H).contiguous()

    def run(
        self, gx_t: torch.Tensor, gx_u: torch.Tensor, h: torch.Tensor, c: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        B, W, _ = gx_t.shape
        H = self.H
        if B > self.LOCKSTEP_MAX_BATCH:
            o_t, c_t = lstm_window(gx_t, h[:, :H], c[:, :H], self.w_t)
            o_u, c_u = lstm_window(gx_u + torch.matmul(torch.stack(o_t, 1), self.w_x), h[:, H:], c[:, H:], self.w_u)
            return torch.cat([o_t[-1], o_u[-1]], 1), torch.cat([c_t, c_u], 1)
        z = gx_t.new_zeros(B, 1, 4, H)
        gx = torch.stack([torch.cat([gx_t.view(B, W, 4, H), z], 1), torch.cat([z, gx_u.view(B, W, 4, H)], 1)], 3)
        h_u, c_u = h[:, H:], c[:, H:]
        for m, x in enumerate(gx.view(B, W + 1, 8 * H).unbind(1)):
            g = torch.addmm(x, h, self.w)
            i, f, _, o = g.sigmoid().chunk(4, 1)
            c = torch.addcmul(f * c, i, g[:, 4 * H : 6 * H].tanh())
            h = o * c.tanh()
            if m == 0:  # there is no limb step −1: the limb state stays as carried
                h, c = torch.cat([h[:, :H], h_u], 1), torch.cat([c[:, :H], c_u], 1)
            elif m == W - 1:  # the torso's last step
                h_t, c_t = h[:, :H], c[:, :H]
        return torch.cat([h_t, h[:, H:]], 1), torch.cat([c_t, c[:, H:]], 1)


class _LSTMBlocks:
    """A one-layer ``nn.LSTM``'s W_ih blocks acting on the embedding and the pose of [e; s; extra]."""

    def __init__(self, lstm: torch.nn.LSTM, e_dim: int, s_dim: int):
        w = lstm.get_parameter("weight_ih_l0").detach()
        self.w_e = w[:, :e_dim].t().contiguous()  # (E, 4H)
        self.w_s = w[:, e_dim : e_dim + s_dim].t().contiguous()  # (J*6, 4H)
        self.b = (lstm.get_parameter("bias_ih_l0") + lstm.get_parameter("bias_hh_l0")).detach()[None]  # (1, 4H)


class BatchedStreamingGenerator:
    """Independent causal streams of one model, stepped as one batch (module docs)."""

    def __init__(self, model: FaceCapGes, neutral_window: np.ndarray, capacity: int = 8):
        self.model = model.eval()
        cfg = self.cfg = model.cfg
        N = cfg.n_history
        nw = np.asarray(neutral_window, dtype=np.float32)
        if nw.shape != (N, cfg.n_joints, 6):
            raise ValueError(f"neutral window must be ({N}, {cfg.n_joints}, 6), got {nw.shape}")
        self.neutral_window = nw
        self._lock = threading.RLock()
        self._audio_layers = split_tcn(model.audio_enc.tcn)
        self._face_layers = split_tcn(model.face_enc.tcn)
        self._d_audio = torch.tensor(cfg.audio_tcn_dilations)
        self._d_face = torch.tensor(cfg.face_tcn_dilations)
        self.E = cfg.audio_dim + cfg.face_dim + cfg.head_dim
        self.fast = cfg.lstm_layers == 1
        if self.fast:
            self._bt = _LSTMBlocks(model.decoder.lstm_t, self.E, cfg.pose_dim)
            self._bu = _LSTMBlocks(model.decoder.lstm_u, self.E, cfg.pose_dim)
            self._cascade = Cascade(model.decoder.lstm_t, model.decoder.lstm_u)
        self._hist_offsets = torch.arange(-N, 0)
        with torch.inference_mode():
            self._e0 = no_input_embedding(model).clone()  # (E,)
        self.capacity = 0
        self._free: list[int] = []
        self._open: set[int] = set()
        self._alloc(max(1, capacity))

    # ------------------------------------------------------------ storage
    # Every per-frame store is a ring: slot s's frame f lives at row f mod R (R = the
    # ring length), so a step writes one row per stream and reads by index in time
    # order instead of shifting whole windows. ``frames[s]`` counts s's frames.
    def _alloc(self, capacity: int) -> None:
        """(Re)allocate the stacked state for ``capacity`` slots, keeping existing rows."""
        cfg, N, W, H, L = self.cfg, self.cfg.n_history, self.cfg.window, self.cfg.lstm_hidden, self.cfg.lstm_layers
        old = self.capacity

        def grow(name: str, shape: tuple[int, ...], axis: int = 0, dtype: torch.dtype = torch.float32):
            new = torch.zeros(shape, dtype=dtype)
            if old:
                prev = getattr(self, name)
                new.narrow(axis, 0, prev.shape[axis]).copy_(prev)
            return new

        self.x_audio = grow(
            "x_audio", (capacity, max(cfg.audio_tcn_dilations), len(cfg.audio_tcn_dilations), cfg.audio_tcn_channels)
        )
        self.x_face = grow(
            "x_face", (capacity, max(cfg.face_tcn_dilations), len(cfg.face_tcn_dilations), cfg.face_tcn_channels)
        )
        self.frames = grow("frames", (capacity,), dtype=torch.long)
        if self.fast:
            self.gx_t = grow("gx_t", (capacity, N, 4 * H))
            self.gx_u = grow("gx_u", (capacity, N, 4 * H))
            self.hc = grow("hc", (capacity, 2, 2 * H))  # [h_t | h_u], [c_t | c_u]
        else:  # the model's own step: rings of embeddings and poses, (L, S, H) states
            self.emb = grow("emb", (capacity, W, self.E))
            self.hist = grow("hist", (capacity, N, cfg.pose_dim))
            self.state = grow("state", (4, L, capacity, H), axis=2)
        self._free = sorted(set(self._free) | set(range(old, capacity)), reverse=True)
        self.capacity = capacity

    # ---------------------------------------------------------------- slots
    @property
    def n_open(self) -> int:
        return len(self._open)

    @property
    def open_slots(self) -> frozenset[int]:
        return frozenset(self._open)

    def open(self, initial_pose: np.ndarray | None = None) -> int:
        """A new stream in cold-start state (:meth:`reset`); returns its slot id."""
        with self._lock:
            if not self._free:
                self._alloc(self.capacity * 2)
            slot = self._free.pop()
            self._open.add(slot)
            try:
                self.reset(slot, initial_pose)
            except Exception:
                self.close(slot)
                raise
            return slot

    def close(self, slot: int) -> None:
        with self._lock:
            if slot in self._open:
                self._open.discard(slot)
                self._free.append(slot)

    @torch.inference_mode()
    def reset(self, slot: int, initial_pose: np.ndarray | None = None) -> None:
        """Cold start of one stream. ``initial_pose``: (47, 6), (N, 47, 6) or None (the neutral window)."""
        N = self.cfg.n_history
        window = initial_window(initial_pose, self.neutral_window)
        with self._lock:
            if slot not in self._open:
                raise KeyError(f"slot {slot} is not open")
            hist = torch.from_numpy(np.ascontiguousarray(window).reshape(N, -1).copy())
            self.frames[slot] = 0  # history frame -N + j sits at ring row j (= (-N + j) mod N)
            self.x_audio[slot] = 0.0  # before the stream: the encoders' causal zeros
            self.x_face[slot] = 0.0
            if self.fast:
                e = self._e0.expand(N, -1)
                for blocks, ring in ((self._bt, self.gx_t), (self._bu, self.gx_u)):
                    ring[slot] = torch.addmm(blocks.b, e, blocks.w_e).addmm_(hist, blocks.w_s)
                self.hc[slot] = 0.0
            else:
                self.hist[slot] = hist
                self.emb[slot] = self._e0
                self.state[:, :, slot] = 0.0

    # ------------------------------------------------------------- the kernel
    def audio_features(self, audio: torch.Tensor) -> torch.Tensor:
        """The audio front end of one frame per stream: (B, S) samples → (B, C) TCN input."""
        return self.model.audio_enc.frontend(audio[:, None])[:, 0]

    def _clean_inputs(self, audio, face, head, B: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(B, S) audio, (B, 52) face, (B, 6) head tensors; NaN/inf → 0."""
        cfg = self.cfg
        if isinstance(audio, np.ndarray) and audio.ndim == 2 and audio.shape[1] == cfg.samples_per_frame:
            a = torch.from_numpy(np.nan_to_num(audio.astype(np.float32, copy=False), nan=0.0, posinf=0.0, neginf=0.0))
        else:
            a = torch.from_numpy(pack_audio(audio, cfg.samples_per_frame))
        if a.shape[0] != B:
            raise ValueError(f"audio has {a.shape[0]} rows for {B} streams")
        return a, _rows(face, cfg.n_face, "face", B), _rows(head, 6, "head rot6d", B)

    @staticmethod
    def _tcn(
        layers,
        ring: torch.Tensor,
        dil: torch.Tensor,
        idx: torch.Tensor,
        frames: torch.Tensor,
        x: torch.Tensor,
        extra: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """New frames (B, C) of streams ``idx`` through a CausalTCN; updates its ring, returns the skip sum."""
        R, L = ring.shape[1], ring.shape[2]
        past = ring[idx[:, None], torch.remainder(frames[:, None] - dil, R), torch.arange(L)].unbind(1)
        xs, ys = [], []
        for i, (b, w_now, w_past) in enumerate(layers):
            xs.append(x)
            y = tcn_tap(x, past[i], b, w_now, w_past, extra if i == L - 1 else None)
            ys.append(y)
            x = x + y
        ring[idx, torch.remainder(frames, R)] = torch.stack(xs, 1)
        return torch.stack(ys).sum(0)

    def _encode(
        self, idx: torch.Tensor, frames: torch.Tensor, a: torch.Tensor, f: torch.Tensor, h: torch.Tensor
    ) -> torch.Tensor:
        """This frame of every stream in ``idx`` → its embedding [z_A; z_F; z_H] (B, E)."""
        m = self.model
        with stage("audio_frontend"):
            feat = self.audio_features(a)
        with stage("audio_tcn"):
            z_a = m.audio_enc.mlp(self._tcn(self._audio_layers, self.x_audio, self._d_audio, idx, frames, feat))
        with stage("face_encoder"):
            extra = m.face_enc.tcn.extra(z_a) if m.face_enc.tcn.extra is not None else None
            z_f = m.face_enc.mlp(
                self._tcn(self._face_layers, self.x_face, self._d_face, idx, frames, m.face_enc.inp(f), extra)
            )
        with stage("head_encoder"):
            z_h = m.head_enc(h)
        return torch.cat([z_a, z_f, z_h], -1)

    def _decode(self, idx: torch.Tensor, frames: torch.Tensor, e: torch.Tensor) -> torch.Tensor:
        """Both LSTMs over each stream's window from the cached projections → pose (B, J*6)."""
        N, dec, bt, bu = self.cfg.n_history, self.model.decoder, self._bt, self._bu
        rows = torch.remainder(frames[:, None] + self._hist_offsets, N)  # (B, N): history, oldest first
        cur_t = torch.addmm(bt.b, e, bt.w_e)  # the current frame: its pose slot is zero (eq. 3.5)
        cur_u = torch.addmm(bu.b, e, bu.w_e)
        hc = self.hc[idx]  # (B, 2, 2H)
        gx_t = torch.cat([self.gx_t[idx[:, None], rows], cur_t[:, None]], 1)  # (B, N+1, 4H)
        gx_u = torch.cat([self.gx_u[idx[:, None], rows], cur_u[:, None]], 1)
        h, c = self._cascade.run(gx_t, gx_u, hc[:, 0], hc[:, 1])  # eq. 4.12-4.13
        self.hc[idx] = torch.stack([h, c], 1)
        H = self.cfg.lstm_hidden
        pose = torch.cat([dec.head_t(h[:, :H]), dec.head_u(h[:, H:])], -1)  # only the last step is decoded
        self._push_pose(idx, frames, e, pose, (cur_t, cur_u))
        return pose

    def _decode_model(self, idx: torch.Tensor, frames: torch.Tensor, e: torch.Tensor) -> torch.Tensor:
        """Any decoder config: ``FaceCapGes.step`` on the gathered windows (training code path)."""
        N, W = self.cfg.n_history, self.cfg.window
        self.emb[idx, torch.remainder(frames, W)] = e
        emb = self.emb[idx[:, None], torch.remainder(frames[:, None] + torch.arange(-N, 1), W)]  # (B, W, E)
        hist = self.hist[idx[:, None], torch.remainder(frames[:, None] + self._hist_offsets, N)]  # (B, N, J*6)
        st = self.state[:, :, idx]
        pose, ((h_t, c_t), (h_u, c_u)) = self.model.step(emb, hist, ((st[0], st[1]), (st[2], st[3])))
        self.state[:, :, idx] = torch.stack([h_t, c_t, h_u, c_u])
        self._push_pose(idx, frames, e, pose)
        return pose

    def _push_pose(
        self,
        idx: torch.Tensor,
        frames: torch.Tensor,
        e: torch.Tensor | None,
        pose: torch.Tensor,
        cur: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> None:
        """Frame f's pose (B, J*6) joins the history of streams ``idx`` (eq. 4.11).

        One-layer decoders keep it as the frame's LSTM input projections (``cur``: its
        pose-free part ``W_e e + b`` if already made).
        """
        row = torch.remainder(frames, self.cfg.n_history)
        if self.fast:
            for blocks, ring, c in (
                (self._bt, self.gx_t, cur[0] if cur else None),
                (self._bu, self.gx_u, cur[1] if cur else None),
            ):
                if c is None:
                    assert e is not None  # without ``cur`` the embedding makes the pose-free part
                    c = torch.addmm(blocks.b, e, blocks.w_e)
                ring[idx, row] = c.addmm(pose, blocks.w_s)
        else:
            self.hist[idx, row] = pose
        self.frames[idx] = frames + 1

    def _ids(self, slots: Sequence[int]) -> tuple[torch.Tensor, torch.Tensor]:
        ids = [int(s) for s in (slots if isinstance(slots, (list, tuple)) else np.asarray(slots).reshape(-1))]
        if len(set(ids)) != len(ids):
            raise ValueError("a stream can take only one frame per batched step")
        closed = [s for s in ids if s not in self._open]
        if closed:
            raise KeyError(f"slot(s) {closed} are not open")
        idx = torch.tensor(ids, dtype=torch.long)
        return idx, self.frames[idx]

    # ------------------------------------------------------------------ API
    @torch.inference_mode()
    def warmup(self, slots: Sequence[int], audio, face, head, pose) -> None:
        """Push one frame with a known pose per stream (no generation, LSTM state untouched)."""
        with self._lock:
            idx, frames = self._ids(slots)
            a, f, h = self._clean_inputs(audio, face, head, len(idx))
            e = self._encode(idx, frames, a, f, h)
            p = torch.from_numpy(np.asarray(pose, dtype=np.float32).reshape(len(idx), -1).copy())
            if not self.fast:
                self.emb[idx, torch.remainder(frames, self.cfg.window)] = e
            self._push_pose(idx, frames, e, p)

    @torch.inference_mode()
    def step(self, slots: Sequence[int], audio, face, head) -> np.ndarray:
        """One frame for each stream in ``slots``: audio (B, ≤S) (array or list), face (B, 52),
        head (B, 6) → poses (B, 47, 6) rot6d, in the order of ``slots``."""
        with self._lock:
            idx, frames = self._ids(slots)
            B = len(idx)
            if B == 0:
                return np.zeros((0, self.cfg.n_joints, 6), np.float32)
            with stage("input_prep"):
                a, f, h = self._clean_inputs(audio, face, head, B)
            e = self._encode(idx, frames, a, f, h)
            with stage("decoder"):
                pose = self._decode(idx, frames, e) if self.fast else self._decode_model(idx, frames, e)
            return pose.reshape(B, self.cfg.n_joints, 6).numpy()
