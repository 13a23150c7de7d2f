"""The gesture intensity dial, shared by both engines: its range and how a pose is scaled by it.

``intensity`` 0 … 1 … 1.3 (:data:`MIN_INTENSITY`, :data:`MAX_INTENSITY`): 1 plays the motion as the
engine makes it, 0 the style's rest, above 1 larger than recorded. The thesis network's generators
(:class:`~facecapges.network.batched.BatchedNetworkStreams` and the one-stream
:class:`~facecapges.network.streaming.NetworkStream`) scale their output poses by it about the
style's rest pose (:func:`scale_pose`); their own pose history stays unscaled, so the dial changes
what is shown, never what the network is fed back. The motion-matching engine plays idle motion at 0
and scales the same way above its idle pose (see :mod:`facecapges.matching`).
"""

from __future__ import annotations

import math

import numpy as np

from facecapges import rotations as rot
from facecapges.errors import UserError

MIN_INTENSITY = 0.0
MAX_INTENSITY = 1.3


def check_intensity(value: float, what: str = "--intensity") -> float:
    """``value`` as a float in [MIN_INTENSITY, MAX_INTENSITY], or a :class:`UserError` naming it."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise UserError(f"{what} must be a number from {MIN_INTENSITY:g} to {MAX_INTENSITY:g}, got {value!r}") from None
    if not (math.isfinite(v) and MIN_INTENSITY <= v <= MAX_INTENSITY):
        raise UserError(f"{what} must be from {MIN_INTENSITY:g} (rest) to {MAX_INTENSITY:g}, got {value!r}")
    return v


def rest_pose(window: np.ndarray) -> np.ndarray:
    """The rest pose (47, 6) of a pose window (N, 47, 6): its per-joint mean rotation, re-orthonormalised."""
    return rot.normalize_rot6d(np.asarray(window, np.float64).mean(axis=0)).astype(np.float32)


def scale_pose(pose: np.ndarray, rest: np.ndarray, gain) -> np.ndarray:
    """Poses (..., 47, 6) scaled about ``rest`` (47, 6): per joint the slerp rest → pose at ``gain``.

    ``gain`` is a float or an array broadcastable to the poses' leading shape + (1, 1) (one per pose).
    """
    g = np.asarray(gain, np.float64)
    if g.ndim:
        g = g.reshape(g.shape + (1, 1))
    return rot.rot6d_slerp(np.broadcast_to(rest, pose.shape), pose, g).astype(np.float32)
