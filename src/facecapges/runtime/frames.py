"""The two per-frame records of the runtime: what goes into the model, what comes out.

Frame ``k`` of a stream covers stream time ``[k/fps, (k+1)/fps)`` (``fps`` = the model
rate, 15 by default, :mod:`facecapges.timing`). Its :class:`InputFrame` holds

* ``audio`` — the samples frame ``k`` owns (``timing.frame_sample_bounds``; 1066 or
  1067 at 15 fps / 16 kHz), float32 in [-1, 1];
* ``face`` — 52 ARKit weights (``facecapges.arkit.ARKIT_NAMES`` order) in [0, 1];
* ``head`` — the head rotation as rot6d (first two matrix columns, head → camera,
  identity = facing the camera; :mod:`facecapges.capture.head_pose`);

and its :class:`OutputFrame` the generated upper-body pose (47 joints,
``facecapges.skeleton.UPPER_BODY`` order) as rot6d and as local-rotation quaternions
(w, x, y, z), with the face that was shown and the per-stage compute time. With
several faces (``--faces N``) each face has its own stream and ``face_index``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class InputFrame:
    index: int
    audio: np.ndarray  # (≤ samples_per_frame,) float32
    face: np.ndarray  # (52,) float32
    head: np.ndarray  # (6,) float32 rot6d
    face_found: bool = True


@dataclass
class OutputFrame:
    index: int
    time_s: float  # start of the frame in stream time, index / fps
    pose: np.ndarray  # (47, 6) rot6d, UPPER_BODY order
    quats: np.ndarray  # (47, 4) (w, x, y, z) local rotations, UPPER_BODY order
    face: np.ndarray  # (52,) ARKit weights
    head: np.ndarray  # (6,) rot6d
    face_found: bool
    latency_ms: dict[str, float] = field(default_factory=dict)  # capture, features, model, output, total
    face_index: int = 0  # which face (avatar) of a several-face session, 0 = the first
