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

**Streaming** (:class:`BatchedPredictor`, :class:`PredictorStream`) runs without torch (:class:`SpeechKernel`:
the weights read from the style file; the TCNs as shift registers, all layers of every stream in one call of the
streaming kernel's compiled :func:`~facecapges.network.native.tcn_taps`; each run of linear layers in one call of
:func:`~facecapges.matching.kernels.dense_chain`; the Mel features of :mod:`facecapges.network.mel`): a matching style's ``live`` and ``serve``
do not load torch (~85 MB of libraries) but do load Numba (~70 MB), whose machine code ``make setup`` caches and
:func:`~facecapges.matching.kernels.warm` loads when a kernel is built (docs/performance.md, "Engine step, third pass"). Its outputs equal the
torch network's over the whole sequence to float32 rounding (``test_matching_predictor``). The network itself (a
torch module, :class:`~facecapges.matching.predictor_training.SpeechReader`) lives with its training in
:mod:`facecapges.matching.predictor_training`, with :func:`~facecapges.matching.predictor_training.predict`
(whole recordings: the figures), so this module never imports it.

How the sizes were chosen, and the validation and held-out figures: docs/matching.md.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from facecapges.engine.inputs import finite, pack_audio
from facecapges.engine.slots import Slots
from facecapges.matching.targets import TARGET_NAMES
from facecapges.network.config import ModelConfig

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


# --------------------------------------------------------------------------- the network's sizes
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


def weight_shapes(cfg: ModelConfig, hidden: int) -> dict[str, tuple[int, ...]]:
    """Every tensor of the speech reader's state (``SpeechReader.state_dict()``) and its shape."""
    ca, cf, e = cfg.audio_tcn_channels, cfg.face_tcn_channels, cfg.audio_dim + cfg.face_dim + cfg.head_dim
    out: dict[str, tuple[int, ...]] = {}

    def linear(name: str, n_in: int, n_out: int, bias: bool = True, standardized: bool = False) -> None:
        out[f"{name}.weight"] = (n_out, n_in)
        if bias:
            out[f"{name}.bias"] = (n_out,)
        if standardized:
            out[f"{name}.in_mean"] = out[f"{name}.in_scale"] = (n_in,)

    if cfg.audio_repr == "raw":
        c1, c2, c3 = cfg.audio_frontend_channels
        out["audio_enc.frontend.in_mean"] = out["audio_enc.frontend.in_scale"] = (1,)
        length = cfg.samples_per_frame
        for i, (cin, cout, k, st) in enumerate(((1, c1, 15, 5), (c1, c2, 9, 4), (c2, c3, 9, 4))):
            out[f"audio_enc.frontend.convs.{i}.weight"], out[f"audio_enc.frontend.convs.{i}.bias"] = (
                (cout, cin, k),
                (cout,),
            )
            length = (length - k) // st + 1
        out["audio_enc.frontend.collapse.weight"], out["audio_enc.frontend.collapse.bias"] = (ca, c3, length), (ca,)
    else:
        from facecapges.network.mel import FEATURE_DIM

        c = cfg.audio_frontend_channels[-1]
        linear("audio_enc.frontend.proj", FEATURE_DIM, c, standardized=True)
        linear("audio_enc.frontend.out", c, ca)
    for i in range(len(cfg.audio_tcn_dilations)):
        linear(f"audio_enc.tcn.layers.{i}", 2 * ca, ca)
    linear("audio_enc.mlp.0", ca, cfg.audio_dim)
    linear("audio_enc.mlp.2", cfg.audio_dim, cfg.audio_dim)
    linear("face_enc.inp", cfg.n_face, cf, standardized=True)
    for i in range(len(cfg.face_tcn_dilations)):
        linear(f"face_enc.tcn.layers.{i}", 2 * cf, cf)
    linear("face_enc.tcn.extra", cfg.audio_dim, cf, bias=False)
    linear("face_enc.mlp.0", cf, 2 * cfg.face_dim)
    linear("face_enc.mlp.2", 2 * cfg.face_dim, cfg.face_dim)
    if cfg.head_dim:
        linear("head_enc.fc1", 6, cfg.head_hidden, standardized=True)
        linear("head_enc.fc2", cfg.head_hidden, cfg.head_dim)
    linear("out.0", e, hidden)
    linear("out.2", hidden, hidden)
    linear("out.4", hidden, K + 1)
    return out


# --------------------------------------------------------------------------- the kernel
LEAK = np.float32(0.2)  # the leaky-ReLU slope (also the compiled dense_chain's: matching.kernels)
_ACTIVATION = {"": 0, "leaky": 1, "relu": 2}


def _leaky(y: np.ndarray) -> np.ndarray:
    """``leaky_relu(y, 0.2)``: the same bits (y > 0: y; else 0.2·y, which is then the larger)."""
    return np.maximum(y, LEAK * y)


class _Chain:
    """Linear layers in a row (optionally over a standardised input, folded in as ``affine_chain`` does:
    ``W((x − m)·s) + b = (W·diag(s)) x + (b − W(m·s))``), their weights transposed once into one buffer, run
    by :func:`facecapges.matching.kernels.dense_chain` in one call."""

    def __init__(self, w: dict[str, np.ndarray], layers: Sequence[tuple[str, str]]):
        parts, table, at = [], [], 0
        for name, act in layers:
            W, b = w[f"{name}.weight"], w.get(f"{name}.bias")
            b = np.zeros(W.shape[0], np.float32) if b is None else b
            if f"{name}.in_mean" in w:
                m, s = w[f"{name}.in_mean"], w[f"{name}.in_scale"]
                b = b - W @ (m * s)
                W = W * s
            w_t = np.ascontiguousarray(W.T, np.float32)
            parts += [w_t.reshape(-1), np.asarray(b, np.float32)]
            table.append((at, at + w_t.size, w_t.shape[0], w_t.shape[1], _ACTIVATION[act]))
            at += w_t.size + len(b)
        self.buf = np.ascontiguousarray(np.concatenate(parts), np.float32)
        self.table = np.array(table, np.int64)
        self.n_out = int(self.table[-1, 3])
        from facecapges.matching import kernels  # Numba: loaded when a kernel is built, not with this module

        self._run = kernels.dense_chain

    def __call__(self, x: np.ndarray, out: np.ndarray | None = None, col: int = 0) -> np.ndarray:
        """Rows ``x`` (B, n_in) float32 → (B, n_out), or into ``out``'s columns from ``col``."""
        if out is None:
            out = np.empty((len(x), self.n_out), np.float32)
        self._run(np.ascontiguousarray(x, np.float32), self.buf, self.table, out, col)  # one compiled variant
        return out


class _Taps:
    """A CausalTCN one new frame at a time (the torch schedule of ``network.batched.TCNTaps``): layer i
    reads its input d_i frames ago from a shift register ``reg`` (S, R, L, C), newest first; the layers of
    every stream in one call of :func:`facecapges.network.native.tcn_taps`."""

    def __init__(self, w: dict[str, np.ndarray], name: str, dilations: Sequence[int]):
        L = len(dilations)
        W = np.stack([w[f"{name}.layers.{i}.weight"] for i in range(L)])  # (L, C, 2C) = [past | now]
        C = W.shape[1]
        self.R, self.L, self.C = max(dilations), L, C
        self.w_past = np.ascontiguousarray(W[:, :, :C].transpose(0, 2, 1), np.float32)  # (L, C, C), on the right
        self.w_now = np.ascontiguousarray(W[:, :, C:].transpose(0, 2, 1), np.float32)
        self.b = np.ascontiguousarray(np.stack([w[f"{name}.layers.{i}.bias"] for i in range(L)]), np.float32)
        self.rows = np.array([d - 1 for d in dilations], np.int64)
        self.no_extra = np.zeros((0, C), np.float32)
        from facecapges.network import native  # Numba: loaded when a kernel is built, not with this module

        self._taps = native.tcn_taps

    def register(self, capacity: int) -> np.ndarray:
        return np.zeros((capacity, self.R, self.L, self.C), np.float32)

    def step(self, reg: np.ndarray, idx: np.ndarray, x: np.ndarray, extra: np.ndarray | None = None) -> np.ndarray:
        """New frames (B, C) of the streams in slots ``idx`` → the TCN's skip sum (B, C); shifts ``reg``."""
        skip = np.empty_like(x)
        extra = self.no_extra if extra is None else extra
        self._taps(reg, idx, np.ascontiguousarray(x), self.w_past, self.w_now, self.b, self.rows, extra, skip)
        return skip


class SpeechKernel:
    """The speech reader's inference (module docs): per frame of B streams, audio (B, S), face (B, 52),
    camera-frame head (B, 6) → the network's raw outputs (B, K + 1); the TCN registers are the caller's."""

    def __init__(self, cfg: ModelConfig, hidden: int, w: dict[str, np.ndarray]):
        self.cfg = cfg
        from facecapges.matching import kernels

        kernels.warm()  # the compiled loops' machine code now, not on a stream's first frame
        if cfg.audio_repr == "raw":
            self.mel = None
            p = "audio_enc.frontend"
            self.raw_gain = (w[f"{p}.in_mean"].astype(np.float32), w[f"{p}.in_scale"].astype(np.float32))
            self.convs = [(w[f"{p}.convs.{i}.weight"], w[f"{p}.convs.{i}.bias"], s) for i, s in enumerate((5, 4, 4))]
            self.collapse = (w[f"{p}.collapse.weight"], w[f"{p}.collapse.bias"], 1)
        else:
            from facecapges.network.mel import MelFeatures

            self.mel = MelFeatures(cfg.sr, cfg.samples_per_frame)
            self.front = _Chain(w, (("audio_enc.frontend.proj", "leaky"), ("audio_enc.frontend.out", "")))
        self.audio_tcn = _Taps(w, "audio_enc.tcn", cfg.audio_tcn_dilations)
        self.face_tcn = _Taps(w, "face_enc.tcn", cfg.face_tcn_dilations)
        self.audio_mlp = _Chain(w, (("audio_enc.mlp.0", "leaky"), ("audio_enc.mlp.2", "")))
        self.face_inp = _Chain(w, (("face_enc.inp", ""),))
        self.face_extra = _Chain(w, (("face_enc.tcn.extra", ""),))
        self.face_mlp = _Chain(w, (("face_enc.mlp.0", "leaky"), ("face_enc.mlp.2", "")))
        self.head = _Chain(w, (("head_enc.fc1", "relu"), ("head_enc.fc2", ""))) if cfg.head_dim else None
        self.out = _Chain(w, (("out.0", "leaky"), ("out.2", "leaky"), ("out.4", "")))
        self.width = cfg.audio_dim + cfg.face_dim + cfg.head_dim

    def _raw_frontend(self, a: np.ndarray) -> np.ndarray:
        """``AudioFrontend``: strided convolutions over each frame's samples (B, S) → (B, C)."""
        x = ((a - self.raw_gain[0]) * self.raw_gain[1])[:, None]  # (B, 1, S)
        for i, (W, b, stride) in enumerate((*self.convs, self.collapse)):
            win = np.lib.stride_tricks.sliding_window_view(x, W.shape[2], axis=2)[:, :, ::stride]  # (B, Cin, L, k)
            x = np.einsum("bclk,ock->bol", win, W, optimize=True) + b[:, None]
            if i < len(self.convs):
                x = _leaky(x)
        return np.ascontiguousarray(x[:, :, 0], np.float32)

    def step(self, regs: tuple[np.ndarray, np.ndarray], idx: np.ndarray, a: np.ndarray, f: np.ndarray, h: np.ndarray):
        """One frame of the streams in slots ``idx`` (registers ``regs`` = audio, face) → raw outputs (B, K + 1)."""
        idx = np.asarray(idx, np.int64)
        feat = self.front(self.mel(a)) if self.mel is not None else self._raw_frontend(a)
        z = np.empty((len(idx), self.width), np.float32)  # [z_A; z_F; z_H]
        z_a = self.audio_mlp(self.audio_tcn.step(regs[0], idx, feat), z, 0)[:, : self.audio_mlp.n_out]
        extra = self.face_extra(np.ascontiguousarray(z_a))
        self.face_mlp(self.face_tcn.step(regs[1], idx, self.face_inp(f), extra), z, self.audio_mlp.n_out)
        if self.head is not None:
            self.head(h, z, self.audio_mlp.n_out + self.face_mlp.n_out)
        return self.out(z)


# --------------------------------------------------------------------------- data
def camera_head(head: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """A take's skeleton-frame head rotations (T, 6) → the model's camera frame (reference = facing it)."""
    from facecapges.capture.head_pose import skeleton_head_to_camera

    return skeleton_head_to_camera(head, reference)


# --------------------------------------------------------------------------- the trained predictor
class Predictor:
    """A trained speech reader: its weights (NumPy, float32: the style file's ``predictor.*`` tensors) and
    ``config`` (JSON: sizes, target normalisation, head reference)."""

    def __init__(self, weights: dict[str, Any], config: dict[str, Any]):
        known = {f.name for f in fields(ModelConfig)}
        mc: dict[str, Any] = {
            k: tuple(v) if isinstance(v, list) else v for k, v in config["model"].items() if k in known
        }
        self.cfg = ModelConfig(**mc).validate()
        self.hidden = int(config["settings"]["hidden"])
        w = {k: np.ascontiguousarray(np.asarray(v, np.float32)) for k, v in weights.items()}
        shapes = weight_shapes(self.cfg, self.hidden)
        missing, unexpected = sorted(set(shapes) - set(w)), sorted(set(w) - set(shapes))
        if missing or unexpected:
            raise ValueError(f"speech predictor weights: missing {missing[:3]}, unexpected {unexpected[:3]}")
        for k, shape in shapes.items():
            if w[k].shape != shape:
                raise ValueError(f"speech predictor weight {k} is {w[k].shape}, expected {shape}")
        self.weights = w
        self.config = config
        self.mean = np.asarray(config["target_mean"], np.float32)
        self.sd = np.asarray(config["target_sd"], np.float32)

    @functools.cached_property
    def kernel(self) -> SpeechKernel:
        """The inference kernel, built on first use (what only loads a style — ``serve``'s server process — never
        loads its compiled loops)."""
        return SpeechKernel(self.cfg, self.hidden, self.weights)

    def state_dict(self) -> dict[str, np.ndarray]:
        return {k: v.copy() for k, v in self.weights.items()}

    @classmethod
    def from_state(cls, config: dict[str, Any], tensors: dict[str, Any]) -> Predictor:
        """From a style file's ``predictor.*`` tensors (NumPy arrays or torch tensors) and its JSON config."""
        if config.get("format") != FORMAT or int(config.get("version", 0)) > VERSION:
            raise ValueError(f"not a speech predictor of version ≤ {VERSION}: {config.get('format')!r}")
        return cls(tensors, config)

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

    def stream(self) -> PredictorStream:
        return PredictorStream(self)

    def batched(self, capacity: int = 8) -> BatchedPredictor:
        return BatchedPredictor(self, capacity)


class BatchedPredictor:
    """Independent causal streams of one predictor, stepped as one batch (slots as the generator's kernel)."""

    def __init__(self, predictor: Predictor, capacity: int = 8):
        self.predictor = predictor
        self._kernel = predictor.kernel
        self._lock = threading.RLock()
        self._regs = (self._kernel.audio_tcn.register(0), self._kernel.face_tcn.register(0))
        self._spf = predictor.cfg.samples_per_frame
        self._n_face = predictor.cfg.n_face
        self.slots = Slots()
        self._grow(max(1, capacity))

    @property
    def capacity(self) -> int:
        return len(self._regs[0])

    @property
    def samples_per_frame(self) -> int:
        return self._spf

    def _grow(self, capacity: int) -> None:
        """(Re)allocate the TCN registers for ``capacity`` slots, keeping existing rows."""
        old = self.capacity
        k = self._kernel
        regs = (k.audio_tcn.register(capacity), k.face_tcn.register(capacity))
        for new, cur in zip(regs, self._regs, strict=True):
            new[:old] = cur
        self._regs = regs
        self.slots.grown(capacity)

    def open(self) -> int:
        """A new stream (before its first frame: the encoders' causal zeros); returns its slot."""
        with self._lock:
            slot = self.slots.take(self._grow)
            self._reset(slot)
            return slot

    def close(self, slot: int) -> None:
        with self._lock:
            self.slots.release(slot)

    def _reset(self, slot: int) -> None:
        for r in self._regs:
            r[slot] = 0.0

    def reset(self, slot: int) -> None:
        with self._lock:
            self.slots.require(slot)
            self._reset(slot)

    def step(self, slots: Sequence[int], audio, face, head) -> np.ndarray:
        """One frame per stream: audio (B, ≤ 1067), face (B, 52), camera-frame head (B, 6) → (B, K + 1)."""
        with self._lock:
            ids = self.slots.check(slots)
            if not ids:
                return np.zeros((0, K + 1), np.float32)
            B = len(ids)
            if isinstance(audio, np.ndarray) and audio.ndim == 2 and audio.shape[1] == self._spf:
                a = finite(audio.astype(np.float32, copy=False))
            else:
                a = pack_audio(audio, self._spf)
            if a.shape[0] != B:
                raise ValueError(f"audio has {a.shape[0]} rows for {B} streams")
            f = _rows(face, self._n_face, "face", B)
            h = _rows(head, 6, "head rot6d", B)
            return self.step_checked(np.asarray(ids, np.intp), a, f, h)

    def step_checked(self, idx: np.ndarray, a: np.ndarray, f: np.ndarray, h: np.ndarray) -> np.ndarray:
        """:meth:`step` for a caller that owns the slots ``idx`` (B,) intp and has checked its inputs: audio
        (B, samples per frame), face (B, 52), head (B, 6), all float32 and finite (the matcher's own)."""
        with self._lock:
            return self.predictor.outputs(self._kernel.step(self._regs, idx, a, f, h))


def _rows(x, n: int, what: str, batch: int) -> np.ndarray:
    a = np.asarray(x, dtype=np.float32).reshape(batch, -1)
    if a.shape[1] != n:
        raise ValueError(f"{what} must have {n} values per stream, got {a.shape[1]}")
    return finite(a)


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
