"""Frame-by-frame inference of one stream: the :class:`NetworkStream`.

One generator serves one stream of one speaker checkpoint. Each :meth:`step` takes
the current frame's inputs only — ``audio`` (the frame's ≤ 1067 samples at 16 kHz),
``face`` (52 ARKit weights), ``head`` (rot6d) — and returns the pose (47, 6) of that
frame; it never looks ahead.

It is a one-slot use of the streaming kernel,
:class:`~facecapges.network.batched.BatchedNetworkStreams` (whose docs list what is
cached between steps: the causal encoders' per-layer inputs, the history frames' LSTM
input projections, both LSTM states), so one stream and a slot of a served batch run
the same code and give the same poses.

Cold start (thesis 4.1.1): :meth:`reset` fills the pose history with a neutral window
taken from the training data (stored in the checkpoint) and the LSTM states with
zeros; frames before the stream are "no input" (zero features, as the encoders'
causal padding). :meth:`warmup` pushes a frame whose pose is known (the warm-up
stage of 4.1.3), so a stream can start from real motion.

:class:`NaiveNetworkStream` is the straightforward loop on the training code
path (:meth:`FaceCapGes.encode` over the window's raw inputs, :meth:`FaceCapGes.step`)
that re-encodes the whole window every frame — same outputs, kept as the test oracle
and as the benchmark's reference. Both equal the training-time rollout
(:meth:`FaceCapGes.rollout`) on the same inputs (tested to 1e-5).
"""

from __future__ import annotations

import numpy as np
import torch

from facecapges.network.batched import BatchedNetworkStreams, initial_window, no_input_embedding
from facecapges.network.network import FaceCapGes

__all__ = ["NaiveNetworkStream", "NetworkStream", "initial_window"]


class NetworkStream:
    """Causal per-frame pose generator of one stream (module docs)."""

    def __init__(self, model: FaceCapGes, neutral_window: np.ndarray):
        self.kernel = BatchedNetworkStreams(model, neutral_window, capacity=1)
        self.model, self.cfg = self.kernel.model, self.kernel.cfg
        self.neutral_window = self.kernel.neutral_window
        self._slot = [self.kernel.open()]

    @property
    def frames(self) -> int:
        """Frames pushed since the last :meth:`reset`."""
        return int(self.kernel.frames[self._slot[0]])

    def reset(self, initial_pose: np.ndarray | None = None) -> None:
        """Start a new stream. ``initial_pose``: (47, 6), (N, 47, 6) or None (neutral)."""
        self.kernel.reset(self._slot[0], initial_pose)

    @property
    def intensity(self) -> float:
        """The intensity dial, 0 (rest) … 1 (as generated) … 1.3 (:mod:`facecapges.engine.intensity`)."""
        return float(self.kernel.intensity[self._slot[0]])

    @intensity.setter
    def intensity(self, value: float) -> None:
        self.kernel.set_intensity(self._slot[0], value)

    def warmup(self, audio: np.ndarray, face: np.ndarray, head: np.ndarray, pose: np.ndarray) -> None:
        """Push one frame whose pose is known (no generation, LSTM state untouched)."""
        self.kernel.warmup(self._slot, [audio], face, head, pose)

    def step(self, audio: np.ndarray, face: np.ndarray, head: np.ndarray) -> np.ndarray:
        """Generate the current frame's pose (47, 6) from this frame's inputs."""
        return self.kernel.step(self._slot, [audio], face, head)[0]


def _frame_audio(audio: np.ndarray, spf: int) -> torch.Tensor:
    a = np.asarray(audio, dtype=np.float32).reshape(-1)
    if a.shape[0] > spf:
        raise ValueError(f"a frame owns at most {spf} audio samples, got {a.shape[0]}")
    out = torch.zeros(spf)
    out[: a.shape[0]] = torch.from_numpy(np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0))
    return out


def _clean(x: np.ndarray, size: int, what: str) -> torch.Tensor:
    a = np.asarray(x, dtype=np.float32).reshape(-1)
    if a.shape[0] != size:
        raise ValueError(f"{what} must have {size} values, got {a.shape[0]}")
    return torch.from_numpy(np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0).copy())


class NaiveNetworkStream:
    """Reference loop: keeps raw inputs and re-encodes the whole window every frame.

    For the window's N+1 embeddings it encodes the last 2N+1 frames of raw input with
    :meth:`FaceCapGes.encode` (each window frame needs its own N-frame past); its
    decoder is the model's own :meth:`FaceCapGes.step` (``nn.LSTM`` over the fused
    window). No caching: same outputs as :class:`NetworkStream`, far more work.
    """

    def __init__(self, model: FaceCapGes, neutral_window: np.ndarray):
        self.model = model.eval()
        self.cfg = model.cfg
        N = self.cfg.n_history
        neutral_window = np.asarray(neutral_window, dtype=np.float32)
        if neutral_window.shape != (N, self.cfg.n_joints, 6):
            raise ValueError(f"neutral window must be ({N}, {self.cfg.n_joints}, 6), got {neutral_window.shape}")
        self.neutral_window = neutral_window
        with torch.inference_mode():
            self.e0 = no_input_embedding(model)
        self.reset()

    @torch.inference_mode()
    def reset(self, initial_pose: np.ndarray | None = None) -> None:
        N = self.cfg.n_history
        window = initial_window(initial_pose, self.neutral_window)
        self.hist = torch.from_numpy(np.ascontiguousarray(window).reshape(N, -1).copy())  # (N, J*6)
        self.state = self.model.decoder.zero_state(1)
        self.raw: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = []
        self.frames = 0

    def _window(self, audio, face, head) -> torch.Tensor:
        """Push the frame's raw inputs; the window's N+1 embeddings (N+1, E), encoded afresh."""
        cfg, W = self.cfg, self.cfg.window
        self.raw.append(
            (
                _frame_audio(audio, cfg.samples_per_frame),
                _clean(face, cfg.n_face, "face"),
                _clean(head, 6, "head rot6d"),
            )
        )
        self.raw = self.raw[-(2 * cfg.n_history + 1) :]  # window frames + each one's past
        a, f, h = (torch.stack([r[i] for r in self.raw])[None] for i in range(3))
        z = self.model.encode(a, f, h)[0][-W:]  # (≤ N+1, E)
        self.frames += 1
        return torch.cat([self.e0.expand(W - z.shape[0], -1), z], 0)

    @torch.inference_mode()
    def warmup(self, audio: np.ndarray, face: np.ndarray, head: np.ndarray, pose: np.ndarray) -> None:
        self._window(audio, face, head)
        p = torch.from_numpy(np.asarray(pose, dtype=np.float32).reshape(1, -1).copy())
        self.hist = torch.cat([self.hist[1:], p], 0)

    @torch.inference_mode()
    def step(self, audio: np.ndarray, face: np.ndarray, head: np.ndarray) -> np.ndarray:
        emb = self._window(audio, face, head)
        pose, self.state = self.model.step(emb[None], self.hist[None], self.state)
        self.hist = torch.cat([self.hist[1:], pose], 0)
        return pose.reshape(self.cfg.n_joints, 6).numpy().copy()
