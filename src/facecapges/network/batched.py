"""The streaming kernel: many live streams of one checkpoint, stepped together.

:class:`BatchedNetworkStreams` is the one implementation of causal frame-by-frame
inference. Each stream owns one *slot* (:meth:`open` / :meth:`close`); a :meth:`step`
over some slots runs their current frames as one batched call.
:class:`~facecapges.network.streaming.NetworkStream` is a one-slot use of it, and
:class:`~facecapges.network.streaming.NaiveNetworkStream` (the training code path,
re-encoding every window) is its test oracle.

Per slot it keeps (cold start as thesis 4.1.1: the neutral window as history, zero
LSTM states, "no input" — zero features — before the stream; the encoders' registers
in its :class:`BatchedEncoders`, the encoder stage alone; the motion-matching engine's speech
reader runs the same encoders in NumPy instead, :mod:`facecapges.matching.predictor`):

==================  =====================  ===========================================
tensor              shape                  meaning
==================  =====================  ===========================================
``x_audio``         (S, R_a, L_a, C_a)     shift register of the audio TCN's layer
                                           inputs of the last R_a = max(d_i) frames,
                                           newest first (:class:`TCNTaps`)
``x_face``          (S, R_f, L_f, C_f)     same for the face TCN
``gx``              (S, N, 8H)             the history frames' LSTM input projections
                                           ``W_ih·[z_τ; s_τ] + b``, torso | limb,
                                           oldest first
``hc``              (S, 2, 2H)             [h_t | h_u], [c_t | c_u]: torso and limb
                                           LSTM states, carried across steps (4.1.4)
``frames``          (S,)                   frames pushed so far
==================  =====================  ===========================================

A step reads each of its slots' rows with one gather and writes them back shifted
by one frame (``index_select`` / ``index_copy_``), so every stream's past sits at the
same rows whatever its frame count and no ring index is computed per step.

The kernel of one step, stage by stage (each stage is a ``torch.profiler`` scope named
``facecapges::<stage>``, so ``bench`` reads the stage timings from a profile of the
real step, not from a copy of it):

* ``input_prep`` — samples / weights → (B, S), (B, 52), (B, 6) tensors, NaN → 0;
* ``audio_frontend`` — :meth:`audio_features`, the model's per-frame audio front end
  over this frame's samples only (a separate call, so another front end slots in);
* ``audio_tcn`` / ``face_encoder`` — :meth:`TCNTaps.step`: layer i reads its input of
  d_i frames ago from the shift register (kernel 2, causal), so a new frame costs one
  tap per layer and gives the same embedding as encoding the whole stream;
* ``head_encoder`` — the head MLP;
* ``decoder`` — both LSTMs over the N+1 window. The input projection of a history
  frame is fixed once its pose is known, so it is computed once per frame and kept
  (``gx``); a step projects only the current frame (pose slot zero, eq. 3.5) and the
  torso outputs that feed the limb LSTM (eq. 4.13), runs both N+1-step recurrences
  (:class:`Cascade`) from the carried state, decodes the last step with the MLP
  heads, and shifts the new frame's projections into the history (eq. 4.11).

The encoders' and heads' small layers run as :func:`affine_chain` calls (weights
transposed once, input standardisation folded in) rather than as module calls, whose
dispatch costs more than the arithmetic of a 32-wide layer.

Decoders with more than one LSTM layer run ``FaceCapGes.step`` on the gathered
windows instead (the training code path; rings of embeddings and poses).

Nothing mixes across the batch axis: each stream's output equals the naive
re-windowed loop's on the same inputs (tested to 1e-5), and a one-slot generator gives
the same poses as a slot of a batch.

Why eager with native small-batch loops and not TorchScript, ``torch.compile`` or ``torch.export``:
each was measured against it (docs/performance.md, "The streaming kernel": the tables, the commits
and the loads they were measured at). ``torch.compile`` needs minutes of compilation per checkpoint
shape and batch size on a fresh machine and ran no faster; ``torch.export``'s program is slower from
Python than the eager code it records. So the kernel is eager, with the per-operation cost cut
instead (shift registers, one ``baddbmm`` for the TCNs' past taps, :func:`affine_chain`, one product
for both LSTMs' projections), and for small batches the TCN taps, the LSTM cascade and the Mel front
end's work between its FFTs each run as one loop compiled by Numba (:mod:`facecapges.network.native`;
:class:`TCNTaps`, :class:`Cascade` and :data:`BatchedNetworkStreams.MEL_NATIVE_MAX_BATCH` hold the
measured batch-size splits; above them the torch schedules run). At one stream the step is bound by
per-call overhead and memory, not arithmetic; batching (``serve``) turns the products into
matrix–matrix ones and spreads the per-call overhead over the streams.

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

from facecapges.engine.inputs import finite, pack_audio
from facecapges.engine.intensity import check_intensity, rest_pose, scale_pose
from facecapges.engine.slots import SlotOwner, Slots
from facecapges.network import native
from facecapges.network.network import FaceCapGes, MelFrontend

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


def _finite(a: np.ndarray) -> np.ndarray:
    """:func:`facecapges.engine.inputs.finite` as a new C-contiguous array (torch shares its memory)."""
    out = finite(a)
    return np.array(out, copy=True, order="C") if out is a else out


def _rows(x, n: int, what: str, batch: int) -> torch.Tensor:
    a = np.asarray(x, dtype=np.float32).reshape(batch, -1)
    if a.shape[1] != n:
        raise ValueError(f"{what} must have {n} values per stream, got {a.shape[1]}")
    return torch.from_numpy(_finite(a))


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


def affine_chain(module: torch.nn.Module | Sequence[torch.nn.Module]) -> Callable[[torch.Tensor], torch.Tensor]:
    """``module`` (a Linear, StandardizedLinear, (Leaky)ReLU or a sequence of them) as
    plain ``addmm`` / activation calls on weights transposed once: the same function of
    (B, in) rows without a module call per layer (~2 µs each, more than a small layer's
    arithmetic). A StandardizedLinear's standardisation is folded into its weights,
    ``W((x − m)·s) + b = (W·diag(s)) x + (b − W(m·s))``. Other modules are called as they are.
    """
    from facecapges.network.network import StandardizedLinear

    def affine(w_t: torch.Tensor, b_row: torch.Tensor) -> Callable[[torch.Tensor], torch.Tensor]:
        return lambda x: torch.addmm(b_row, x, w_t)

    def leaky(slope: float) -> Callable[[torch.Tensor], torch.Tensor]:
        return lambda x: F.leaky_relu(x, slope)

    steps: list[Callable[[torch.Tensor], torch.Tensor]] = []
    mods = list(module) if isinstance(module, (torch.nn.Sequential, list, tuple)) else [module]
    for mod in mods:
        if isinstance(mod, torch.nn.Linear) and type(mod) in (torch.nn.Linear, StandardizedLinear):
            w = mod.weight.detach()
            b = mod.bias.detach() if mod.bias is not None else torch.zeros(w.shape[0])
            if isinstance(mod, StandardizedLinear):
                b = b - w @ (mod.in_mean * mod.in_scale)
                w = w * mod.in_scale
            steps.append(affine(w.t().contiguous(), b[None].clone()))
        elif isinstance(mod, torch.nn.LeakyReLU):
            steps.append(leaky(mod.negative_slope))
        elif isinstance(mod, torch.nn.ReLU):
            steps.append(torch.relu)
        else:
            assert isinstance(mod, torch.nn.Module)
            steps.append(mod)
    if len(steps) == 1:
        return steps[0]

    def run(x: torch.Tensor) -> torch.Tensor:
        for f in steps:
            x = f(x)
        return x

    return run


class TCNTaps:
    """A CausalTCN split for one new frame at a time: the taps of :meth:`CausalTCN.layer`.

    Layer i computes ``act(W_i [x_{t-d_i}; x_t] + b_i (+ extra))``, its weight split into
    the blocks acting on the past tap and on the current one. The past inputs live in a
    *shift register* ``reg`` (S, R, L, C) per slot: ``reg[s, r, i]`` is layer i's input
    r + 1 frames ago (R = max d_i, newest first), so the past tap of layer i is always
    row d_i − 1 — a fixed gather, the same for every stream whatever its frame count.
    Two schedules of the same step, chosen by batch size:

    * **native** (B ≤ :attr:`NATIVE_MAX_BATCH`): :func:`facecapges.network.native.tcn_taps`,
      all layers of every stream and the register shift as one compiled loop — at one
      stream a layer is a (C × C) product of a few hundred multiply–adds, less than one
      torch call's dispatch;
    * **torch**: the past taps of all layers are known before the frame starts, so they
      go through their blocks as one batched product (``baddbmm``); the current taps run
      layer by layer as (B × C)·(C × C) products.

    The batch-size split is measured (docs/performance.md, "Small-batch splits").
    """

    NATIVE_MAX_BATCH = 64

    def __init__(self, tcn):
        w = torch.stack([lin.weight.detach() for lin in tcn.layers])  # (L, C, 2C) = [past | now]
        L, C = w.shape[0], w.shape[1]
        self.R, self.L, self.C = max(tcn.dilations), L, C
        self.past_rows = torch.tensor([(d - 1) * L + i for i, d in enumerate(tcn.dilations)])  # into (R·L, C)
        self.w_past = w[:, :, :C].transpose(1, 2).contiguous()  # (L, C, C), acting on the right of x
        self.w_now = [w[i, :, C:].t().contiguous() for i in range(L)]
        self.b = torch.stack([lin.bias.detach() for lin in tcn.layers])[:, None]  # (L, 1, C)
        self.native_max_batch = self.NATIVE_MAX_BATCH  # 0: always torch (``bench`` counts its FLOPs)
        # the same weights for native.tcn_taps: past and current blocks, biases, each past tap's register row
        self._w_past, self._w_now = self.w_past.numpy().copy(), torch.stack(self.w_now).numpy().copy()
        self._b, self._rows = self.b[:, 0].numpy().copy(), np.array([d - 1 for d in tcn.dilations], np.int64)
        self._no_extra = np.zeros((0, C), np.float32)

    def register(self, capacity: int) -> torch.Tensor:
        """Zero shift registers (the causal zeros before a stream) for ``capacity`` slots."""
        return torch.zeros(capacity, self.R, self.L, self.C)

    def step(self, reg: torch.Tensor, idx: torch.Tensor, x: torch.Tensor, extra: torch.Tensor | None = None):
        """New frames (B, C) of the streams in slots ``idx`` → the TCN's skip sum (B, C); shifts ``reg``."""
        B = x.shape[0]
        if x.shape[0] <= self.native_max_batch:  # small batches: one native call (class docs)
            skip = np.empty((B, self.C), np.float32)
            ex = extra.numpy() if extra is not None else self._no_extra
            native.tcn_taps(
                reg.numpy(), idx.numpy(), x.numpy(), self._w_past, self._w_now, self._b, self._rows, ex, skip
            )
            return torch.from_numpy(skip)
        held = reg.index_select(0, idx)  # (B, R, L, C)
        past = held.view(B, self.R * self.L, self.C).index_select(1, self.past_rows).transpose(0, 1)  # (L, B, C)
        pre = torch.baddbmm(self.b, past, self.w_past).unbind(0)  # each layer's b + W_past x_{t-d}
        x0, xs = x, []
        for i, w_now in enumerate(self.w_now):
            xs.append(x)
            y = torch.addmm(pre[i], x, w_now)
            if extra is not None and i == self.L - 1:
                y += extra
            x = x + F.leaky_relu(y, 0.2)  # residual; x − x0 is the sum of the layers' outputs (the skips)
        reg.index_copy_(0, idx, torch.cat([torch.stack(xs, 1)[:, None], held[:, :-1]], 1))
        return x - x0


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

    :meth:`run` takes the input gates of each window step, ``gx`` (B, W, 8H) as
    ``[torso | limb]``, the limb's without its torso-output term, and the carried states
    ``hc`` (B, 2, 2H) = ``[[h_t | h_u], [c_t | c_u]]``; it returns the final ones. Two schedules of the same
    recurrence (same gates as ``torch.nn.LSTM``, order i, f, g, o), chosen by batch size:

    * **lockstep, native** (B ≤ :attr:`NATIVE_MAX_BATCH`): :func:`facecapges.network.native.cascade`,
      one compiled loop; iteration m runs torso step m and limb step m − 1 — the limb's
      input at step m − 1 is the torso output h_t,m−1, exactly the torso state iteration
      m starts from, so one ``h_t @ [W_hh,t | W_x]`` (H × 8H) gives the torso's recurrent
      gates and the limb's torso term, and ``h_u @ W_hh,u`` the rest. At one stream each
      cell is a matrix–vector product and element-wise work on 4H numbers, where a NumPy
      call costs ~0.5 µs and a torch call 1–3 µs of dispatch;
    * **sequential** (larger batches, torch): the torso over the whole window, its
      outputs' projection as one GEMM, then the limb — the same multiply–adds as
      matrix–matrix products, which win once the products dominate.

    The batch-size split is measured (docs/performance.md, "Small-batch splits").
    """

    NATIVE_MAX_BATCH = 16

    def __init__(self, lstm_t: torch.nn.LSTM, lstm_u: torch.nn.LSTM):
        self.native_max_batch = self.NATIVE_MAX_BATCH  # 0: always torch (``bench`` counts its FLOPs)
        H = self.H = lstm_t.hidden_size
        self.w_t = lstm_t.get_parameter("weight_hh_l0").detach().t().contiguous()  # (H, 4H)
        self.w_x = lstm_u.get_parameter("weight_ih_l0").detach()[:, -H:].t().contiguous()  # limb input = [e; s; o_t]
        self.w_u = lstm_u.get_parameter("weight_hh_l0").detach().t().contiguous()
        self._w_top = torch.cat([self.w_t, self.w_x], 1).numpy().copy()  # (H, 8H): h_t's weights, for native.cascade
        self._w_u = self.w_u.numpy().copy()

    def run(self, gx: torch.Tensor, hc: torch.Tensor) -> torch.Tensor:
        """Input gates ``gx`` (B, W, 8H) = [torso | limb] per window step, carried ``hc`` (B, 2, 2H)
        = [[h_t | h_u], [c_t | c_u]] → the final ``hc``."""
        B, H = gx.shape[0], self.H
        if gx.shape[0] <= self.native_max_batch:
            out = np.empty((B, 2, 2 * H), np.float32)
            native.cascade(gx.numpy(), hc.numpy(), self._w_top, self._w_u, out)
            return torch.from_numpy(out)
        h, c = hc[:, 0], hc[:, 1]
        o_t, c_t = lstm_window(gx[..., : 4 * H], h[:, :H], c[:, :H], self.w_t)
        gx_u = gx[..., 4 * H :] + torch.matmul(torch.stack(o_t, 1), self.w_x)
        o_u, c_u = lstm_window(gx_u, h[:, H:], c[:, H:], self.w_u)
        return torch.stack([torch.cat([o_t[-1], o_u[-1]], 1), torch.cat([c_t, c_u], 1)], 1)


class _LSTMBlocks:
    """Both one-layer LSTMs' W_ih blocks acting on the embedding and the pose of [e; s; extra],
    side by side ``[torso | limb]`` (4H + 4H gate columns), and their summed biases."""

    def __init__(self, lstms: Sequence[torch.nn.LSTM], e_dim: int, s_dim: int):
        w = [lstm.get_parameter("weight_ih_l0").detach() for lstm in lstms]
        self.w_e = torch.cat([x[:, :e_dim] for x in w]).t().contiguous()  # (E, 8H)
        self.w_s = torch.cat([x[:, e_dim : e_dim + s_dim] for x in w]).t().contiguous()  # (J*6, 8H)
        self.b = torch.cat(
            [(lstm.get_parameter("bias_ih_l0") + lstm.get_parameter("bias_hh_l0")).detach() for lstm in lstms]
        )[None]  # (1, 8H)


class BatchedEncoders:
    """The kernel's encoder stage alone: per-frame audio, face and head of many streams → their
    embeddings [z_A; z_F; z_H] (B, E), causally, one frame per step (module docs, stages
    ``audio_frontend`` … ``head_encoder``).

    ``model``: anything with the FaceCapGes encoders (``cfg``, ``audio_enc``, ``face_enc``,
    ``head_enc``) — the generator's network (the motion-matching engine's speech reader runs the same encoders
    in NumPy: :class:`facecapges.matching.predictor.SpeechKernel`). Keeps the TCNs' shift registers ``x_audio``,
    ``x_face`` per slot; slot bookkeeping and locking are the caller's.
    """

    # the Mel front end's native schedule (AudioFeatures.forward_native) up to this batch; µs per
    # call, default checkpoint, one thread, same run, load ~2.7: torch 195 vs native 57 at B = 1,
    # 326 vs 202 at B = 16, 721 vs 647 at B = 64, 2674 vs 2493 at B = 240 (the FFTs are the same
    # calls) — but above 64 whole batched steps with either are within the machine's noise, so
    # large batches keep the torch schedules throughout (TCN and LSTM cascade as well)
    MEL_NATIVE_MAX_BATCH = 64
    x_audio: torch.Tensor  # (slots, R_a, L_a, C_a): the audio TCN's shift registers
    x_face: torch.Tensor  # (slots, R_f, L_f, C_f)

    def __init__(self, model, capacity: int = 8):
        self.model, cfg = model, model.cfg
        self.cfg = cfg
        native.warm()  # the small-batch schedules' machine code, before the first frame
        self.mel_native_max_batch = self.MEL_NATIVE_MAX_BATCH  # 0: always torch (``bench`` counts its FLOPs)
        self._audio_tcn = TCNTaps(model.audio_enc.tcn)
        self._face_tcn = TCNTaps(model.face_enc.tcn)
        fe = model.face_enc
        self._audio_mlp, self._face_inp, self._face_mlp = (
            affine_chain(x) for x in (model.audio_enc.mlp, fe.inp, fe.mlp)
        )
        self._face_extra = affine_chain(fe.tcn.extra) if fe.tcn.extra is not None else None
        he = model.head_enc  # HeadEncoder.forward: fc2(relu(fc1(head))), or nothing without head pose
        front = model.audio_enc.frontend  # MelFrontend.forward: out(leaky_relu(proj(features(samples))))
        self._mel_mlp = (
            affine_chain([front.proj, torch.nn.LeakyReLU(0.2), front.out]) if isinstance(front, MelFrontend) else None
        )
        self._head_enc = affine_chain([he.fc1, torch.nn.ReLU(), he.fc2]) if he.dim else he
        self.E = cfg.audio_dim + cfg.face_dim + cfg.head_dim
        self.capacity = 0
        self.alloc(max(1, capacity))

    def alloc(self, capacity: int) -> None:
        """(Re)allocate the shift registers for ``capacity`` slots, keeping existing rows."""
        old, xa, xf = self.capacity, self._audio_tcn.register(capacity), self._face_tcn.register(capacity)
        if old:
            xa[:old], xf[:old] = self.x_audio, self.x_face
        self.x_audio, self.x_face, self.capacity = xa, xf, capacity

    def reset(self, slot: int) -> None:
        """Slot ``slot`` back to before its stream: the encoders' causal zeros."""
        self.x_audio[slot] = 0.0
        self.x_face[slot] = 0.0

    def torch_schedules_only(self) -> None:
        """Every encoder stage in its torch schedule whatever the batch size."""
        self.mel_native_max_batch = 0
        self._audio_tcn.native_max_batch = self._face_tcn.native_max_batch = 0

    def audio_features(self, audio: torch.Tensor) -> torch.Tensor:
        """The audio front end of one frame per stream: (B, S) samples → (B, C) TCN input."""
        front = self.model.audio_enc.frontend
        if isinstance(front, MelFrontend) and self._mel_mlp is not None:
            if audio.shape[0] <= self.mel_native_max_batch:  # the small-batch schedule (AudioFeatures docs)
                return self._mel_mlp(front.features.forward_native(audio))
            return self._mel_mlp(front.features(audio))
        return front(audio[:, None])[:, 0]

    def clean_inputs(self, audio, face, head, B: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(B, S) audio, (B, 52) face, (B, 6) head tensors; NaN/inf → 0."""
        cfg = self.cfg
        if isinstance(audio, np.ndarray) and audio.ndim == 2 and audio.shape[1] == cfg.samples_per_frame:
            a = torch.from_numpy(_finite(audio.astype(np.float32, copy=False)))
        else:
            a = torch.from_numpy(pack_audio(audio, cfg.samples_per_frame))
        if a.shape[0] != B:
            raise ValueError(f"audio has {a.shape[0]} rows for {B} streams")
        return a, _rows(face, cfg.n_face, "face", B), _rows(head, 6, "head rot6d", B)

    def encode(self, idx: torch.Tensor, a: torch.Tensor, f: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        """This frame of every stream in ``idx`` → its embedding [z_A; z_F; z_H] (B, E); shifts the registers."""
        with stage("audio_frontend"):
            feat = self.audio_features(a)
        with stage("audio_tcn"):
            z_a = self._audio_mlp(self._audio_tcn.step(self.x_audio, idx, feat))
        with stage("face_encoder"):
            extra = self._face_extra(z_a) if self._face_extra is not None else None
            z_f = self._face_mlp(self._face_tcn.step(self.x_face, idx, self._face_inp(f), extra))
        with stage("head_encoder"):
            z_h = self._head_enc(h)
        return torch.cat([z_a, z_f, z_h], -1)


class BatchedNetworkStreams(SlotOwner):
    """Independent causal streams of one model, stepped as one batch (module docs)."""

    MEL_NATIVE_MAX_BATCH = BatchedEncoders.MEL_NATIVE_MAX_BATCH

    def __init__(self, model: FaceCapGes, neutral_window: np.ndarray, capacity: int = 8):
        self.model = model.eval()
        cfg = self.cfg = model.cfg
        N = cfg.n_history
        nw = np.asarray(neutral_window, dtype=np.float32)
        if nw.shape != (N, cfg.n_joints, 6):
            raise ValueError(f"neutral window must be ({N}, {cfg.n_joints}, 6), got {nw.shape}")
        self.neutral_window = nw
        self.rest = rest_pose(nw)  # what the intensity dial scales about (facecapges.engine.intensity)
        self._lock = threading.RLock()
        self.encoders = BatchedEncoders(model, 1)  # audio, face, head → [z_A; z_F; z_H] (stages up to the decoder)
        dec = model.decoder
        self._head_t, self._head_u = affine_chain(dec.head_t), affine_chain(dec.head_u)
        self.E = self.encoders.E
        self.fast = cfg.lstm_layers == 1
        if self.fast:
            self._blocks = _LSTMBlocks((model.decoder.lstm_t, model.decoder.lstm_u), self.E, cfg.pose_dim)
            self._cascade = Cascade(model.decoder.lstm_t, model.decoder.lstm_u)
        self._hist_offsets = torch.arange(-N, 0)
        with torch.inference_mode():
            self._e0 = no_input_embedding(model).clone()  # (E,)
        self.capacity = 0
        self.slots = Slots()
        self._alloc(max(1, capacity))

    # ------------------------------------------------------------ storage
    # The TCNs' past inputs and the decoder's history are shift registers (newest last
    # for the history, oldest first): a step reads a slot's rows in one gather and writes
    # them back shifted by one frame. The multi-layer path keeps rings: slot s's frame f
    # at row f mod R. ``frames[s]`` counts s's frames.
    def _alloc(self, capacity: int) -> None:
        """(Re)allocate the stacked state for ``capacity`` slots, keeping existing rows."""
        cfg, N, W, H, L = self.cfg, self.cfg.n_history, self.cfg.window, self.cfg.lstm_hidden, self.cfg.lstm_layers
        old = self.capacity

        def grow(name: str, new: torch.Tensor, axis: int = 0):
            if old:
                prev = getattr(self, name)
                new.narrow(axis, 0, prev.shape[axis]).copy_(prev)
            return new

        self.encoders.alloc(capacity)
        frames = np.zeros(capacity, np.int64)  # a NumPy counter: no torch call per step to read or bump it
        if old:
            frames[:old] = self.frames
        self.frames: np.ndarray = frames
        gain = np.ones(capacity)  # each slot's intensity (set_intensity)
        if old:
            gain[:old] = self.intensity
        self.intensity: np.ndarray = gain
        if self.fast:
            self.gx = grow("gx", torch.zeros(capacity, N, 8 * H))  # history frames' [torso | limb] input gates
            self.hc = grow("hc", torch.zeros(capacity, 2, 2 * H))  # [h_t | h_u], [c_t | c_u]
        else:  # the model's own step: rings of embeddings and poses, (L, S, H) states
            self.emb = grow("emb", torch.zeros(capacity, W, self.E))
            self.hist = grow("hist", torch.zeros(capacity, N, cfg.pose_dim))
            self.state = grow("state", torch.zeros(4, L, capacity, H), axis=2)
        self.slots.grown(capacity)
        self.capacity = capacity

    # ---------------------------------------------------------------- slots
    def _opened(self, slot: int) -> None:
        self.intensity[slot] = 1.0

    def close(self, slot: int) -> None:
        with self._lock:
            self.slots.release(slot)

    @torch.inference_mode()
    def reset(self, slot: int, initial_pose: np.ndarray | None = None) -> None:
        """Cold start of one stream. ``initial_pose``: (47, 6), (N, 47, 6) or None (the neutral window)."""
        N = self.cfg.n_history
        window = initial_window(initial_pose, self.neutral_window)
        with self._lock:
            self.slots.require(slot)
            hist = torch.from_numpy(np.ascontiguousarray(window).reshape(N, -1).copy())
            self.frames[slot] = 0  # history frame -N + j sits at ring row j (= (-N + j) mod N)
            self.encoders.reset(slot)  # before the stream: the encoders' causal zeros
            if self.fast:
                bl = self._blocks
                self.gx[slot] = torch.addmm(bl.b, self._e0.expand(N, -1), bl.w_e).addmm_(hist, bl.w_s)
                self.hc[slot] = 0.0
            else:
                self.hist[slot] = hist
                self.emb[slot] = self._e0
                self.state[:, :, slot] = 0.0

    # ------------------------------------------------------------- the kernel
    @property
    def mel_native_max_batch(self) -> int:
        """The Mel front end's native schedule up to this batch (:class:`BatchedEncoders`)."""
        return self.encoders.mel_native_max_batch

    @mel_native_max_batch.setter
    def mel_native_max_batch(self, value: int) -> None:
        self.encoders.mel_native_max_batch = value

    def audio_features(self, audio: torch.Tensor) -> torch.Tensor:
        """The audio front end of one frame per stream: (B, S) samples → (B, C) TCN input."""
        return self.encoders.audio_features(audio)

    def _decode(self, idx: torch.Tensor, e: torch.Tensor) -> torch.Tensor:
        """Both LSTMs over each stream's window from the cached projections → pose (B, J*6)."""
        bl, H = self._blocks, self.cfg.lstm_hidden
        cur = torch.addmm(bl.b, e, bl.w_e)  # the current frame: its pose slot is zero (eq. 3.5)
        held = self.gx.index_select(0, idx)  # (B, N, 8H): the history, oldest first
        gx = torch.cat([held, cur[:, None]], 1)  # (B, N+1, 8H)
        hc = self._cascade.run(gx, self.hc.index_select(0, idx))  # eq. 4.12-4.13, (B, 2, 2H)
        self.hc.index_copy_(0, idx, hc)
        h = hc[:, 0]
        pose = torch.cat([self._head_t(h[:, :H]), self._head_u(h[:, H:])], -1)  # only the last step is decoded
        # the frame joins the history with its pose (eq. 4.11): the oldest frame leaves
        self.gx.index_copy_(0, idx, torch.cat([held[:, 1:], torch.addmm(cur, pose, bl.w_s)[:, None]], 1))
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
        self.hist[idx, torch.remainder(frames, N)] = pose
        return pose

    def _ids(self, slots: Sequence[int]) -> tuple[torch.Tensor, list[int]]:
        ids = self.slots.check(slots if isinstance(slots, (list, tuple)) else np.asarray(slots).reshape(-1))
        return torch.tensor(ids, dtype=torch.long), ids

    def torch_schedules_only(self) -> None:
        """Run every stage in its torch schedule whatever the batch size (the native
        small-batch loops off): the arithmetic ``bench``'s FLOP counter can see, and the
        second schedule the tests compare with the naive loop."""
        self.encoders.torch_schedules_only()
        if self.fast:
            self._cascade.native_max_batch = 0

    # ------------------------------------------------------------------ API
    @torch.inference_mode()
    def warmup(self, slots: Sequence[int], audio, face, head, pose) -> None:
        """Push one frame with a known pose per stream (no generation, LSTM state untouched)."""
        with self._lock:
            idx, ids = self._ids(slots)
            a, f, h = self.encoders.clean_inputs(audio, face, head, len(idx))
            e = self.encoders.encode(idx, a, f, h)
            p = torch.from_numpy(np.asarray(pose, dtype=np.float32).reshape(len(idx), -1).copy())
            if self.fast:
                bl = self._blocks
                new = torch.addmm(bl.b, e, bl.w_e).addmm_(p, bl.w_s)
                self.gx.index_copy_(0, idx, torch.cat([self.gx.index_select(0, idx)[:, 1:], new[:, None]], 1))
            else:
                N, W, frames = self.cfg.n_history, self.cfg.window, torch.from_numpy(self.frames[ids])
                self.emb[idx, torch.remainder(frames, W)] = e
                self.hist[idx, torch.remainder(frames, N)] = p
            self.frames[ids] += 1

    @torch.inference_mode()
    def step(self, slots: Sequence[int], audio, face, head) -> np.ndarray:
        """One frame for each stream in ``slots``: audio (B, ≤S) (array or list), face (B, 52),
        head (B, 6) → poses (B, 47, 6) rot6d, in the order of ``slots``."""
        with self._lock:
            idx, ids = self._ids(slots)
            B = len(idx)
            if B == 0:
                return np.zeros((0, self.cfg.n_joints, 6), np.float32)
            with stage("input_prep"):
                a, f, h = self.encoders.clean_inputs(audio, face, head, B)
            e = self.encoders.encode(idx, a, f, h)
            with stage("decoder"):
                if self.fast:
                    pose = self._decode(idx, e)
                else:
                    pose = self._decode_model(idx, torch.from_numpy(self.frames[ids]), e)
            self.frames[ids] += 1
            out = pose.reshape(B, self.cfg.n_joints, 6).numpy()
            gain = self.intensity[ids]
            dial = np.flatnonzero(gain != 1.0)
            if len(dial):  # shown poses only: the history above keeps the unscaled ones
                out[dial] = scale_pose(out[dial], self.rest, gain[dial])
            return out

    def set_intensity(self, slot: int, value: float) -> None:
        """The intensity dial of one stream (:mod:`facecapges.engine.intensity`), from its next step on."""
        v = check_intensity(value)
        with self._lock:
            self.slots.require(slot)
            self.intensity[slot] = v
