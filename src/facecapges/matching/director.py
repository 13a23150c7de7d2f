"""The thesis network beside the matcher: its generated wrist direction as a query term (issue #25).

The network (:class:`~facecapges.network.network.FaceCapGes`, trained on the style's own training frames by
:func:`facecapges.training.director.train_director`) runs causally on the same per-frame inputs as the
matcher (audio, face, camera-frame head) through the streaming kernel
(:class:`~facecapges.network.batched.BatchedNetworkStreams`). Its output pose is not played; what the
engine reads from it each frame is the **direction each wrist moves**:

* query (:meth:`BatchedDirector.step`): per wrist, the unit vector of the network's wrist displacement
  over the last :data:`SPAN` frames, ``p_t − p_{t−SPAN}``, in the chest frame
  (:func:`facecapges.matching.targets.arm_positions`), 6 values (right, left);
* database (:func:`database_directions`): the same of each row's real motion over its next :data:`SPAN`
  frames, ``p_{r+SPAN} − p_r`` — what the clip would play from that row on.

Why the velocity's direction and not the offset from a rest/mean pose: the network trained on a minute
moves little, but when it moves follows the speech (its BeatAlign gap is the engine's best); a direction
throws the amplitude away and keeps the timing and the sense (up on a stroke, down on a retraction),
while an offset from the mean is mostly where the network's mean pose sits. A displacement shorter than
:data:`MIN_MOVE` (units of the skeleton: cm) has no direction and gives the zero vector, whose squared
distance to every unit vector is 1: no preference. The engine adds
``direction_weight · Σ_wrists |d_query − d_row|²`` to every row's cost
(:class:`~facecapges.matching.matcher.MatchingConfig`).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

import numpy as np
import torch

from facecapges.matching.targets import arm_positions
from facecapges.skeleton import Skeleton

SPAN = 2  # frames (133 ms at 15 fps)
MIN_MOVE = 0.05  # skeleton units (cm for BEAT) moved over SPAN frames below which a wrist has no direction
FORMAT = "facecapges-director-1"


def unit_directions(disp: np.ndarray) -> np.ndarray:
    """Wrist displacements (…, 2, 3) → unit directions (…, 6); zero where a wrist moved < :data:`MIN_MOVE`."""
    n = np.linalg.norm(disp, axis=-1, keepdims=True)
    d = np.where(n >= MIN_MOVE, disp / np.maximum(n, 1e-9), 0.0)
    return d.reshape(d.shape[:-2] + (6,)).astype(np.float32)


def database_directions(skel: Skeleton, pose: np.ndarray, segment: np.ndarray) -> np.ndarray:
    """(N, 6) per database row: the unit direction of each wrist over the row's next :data:`SPAN` frames."""
    out = np.zeros((len(pose), 6), np.float32)
    for s in np.unique(segment):
        rows = np.flatnonzero(segment == s)
        wr = arm_positions(skel, pose[rows])[:, :2]
        disp = np.zeros_like(wr)
        disp[:-SPAN] = wr[SPAN:] - wr[:-SPAN]
        disp[-SPAN:] = disp[-SPAN - 1] if len(rows) > SPAN else 0.0
        out[rows] = unit_directions(disp)
    return out


class Director:
    """A trained thesis network and what it needs to stream (neutral window); see the module docs."""

    def __init__(self, model, meta: dict, skeleton: Skeleton):
        self.model = model.eval()
        self.meta = dict(meta)
        self.skeleton = skeleton

    @property
    def config(self) -> dict:
        from facecapges.network.config import to_dict

        return dict(self.meta, format=FORMAT, model_config=to_dict(self.model.cfg))

    def state_dict(self) -> dict[str, torch.Tensor]:
        return {k: v.detach().float().contiguous() for k, v in self.model.state_dict().items()}

    @classmethod
    def from_state(cls, config: dict, tensors: dict[str, torch.Tensor], skeleton: Skeleton) -> Director:
        from facecapges.network.config import model_config_from_dict
        from facecapges.network.network import FaceCapGes, with_default_norms

        if config.get("format") != FORMAT:
            raise ValueError(f"not a matching style's network ({config.get('format')!r})")
        model = FaceCapGes(model_config_from_dict(config["model_config"]))
        model.load_state_dict(with_default_norms(model, {k: v.float() for k, v in tensors.items()}), strict=True)
        return cls(model, {k: v for k, v in config.items() if k not in ("format", "model_config")}, skeleton)

    def batched(self, capacity: int = 8) -> BatchedDirector:
        return BatchedDirector(self, capacity)


class BatchedDirector:
    """Independent causal streams of the network; :meth:`step` gives each one's wrist directions (B, 6)."""

    def __init__(self, director: Director, capacity: int = 8):
        from facecapges.network.batched import BatchedNetworkStreams

        self.director = director
        self._lock = threading.RLock()
        neutral = np.asarray(director.meta["neutral_window"], np.float32)
        self.kernel = BatchedNetworkStreams(director.model, neutral, capacity=max(1, capacity))
        self._wrists: dict[int, list[np.ndarray]] = {}

    def open(self) -> int:
        with self._lock:
            slot = self.kernel.open()
            self._wrists[slot] = []
            return slot

    def close(self, slot: int) -> None:
        with self._lock:
            self.kernel.close(slot)
            self._wrists.pop(slot, None)

    def reset(self, slot: int) -> None:
        with self._lock:
            self.kernel.reset(slot)
            self._wrists[slot] = []

    def step(self, slots: Sequence[int], audio, face, head) -> np.ndarray:
        """One frame per stream (the matcher's inputs) → the network's wrist directions (B, 6)."""
        with self._lock:
            ids = [int(s) for s in slots]
            pose = self.kernel.step(ids, audio, face, head)  # (B, 47, 6)
            wr = arm_positions(self.director.skeleton, np.asarray(pose, np.float64))[:, :2]  # (B, 2, 3)
            out = np.zeros((len(ids), 6), np.float32)
            for k, s in enumerate(ids):
                hist = self._wrists[s]
                hist.append(wr[k])
                if len(hist) > SPAN + 1:
                    del hist[0]
                if len(hist) == SPAN + 1:
                    out[k] = unit_directions(hist[-1] - hist[0])
            return out
