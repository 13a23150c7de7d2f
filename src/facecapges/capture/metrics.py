"""The calibration-free geometric metrics of the paper (3.2.1), on MediaPipe landmarks.

Every metric is measured on the landmarks in the **head frame** (after the rigid head
pose is removed, :meth:`head_pose.HeadPoseEstimator.to_head_frame`: X to the subject's
left, Y up, +Z out of the face) and divided by the inner eye-corner distance ``w``
(``g' = g / w``, paper 3.2.1), so neither head rotation nor distance to the camera nor
face size changes it. "Height" is a difference along head Y, "width"/"offset" along X.

MediaPipe landmark indices used (478-point FaceMesh topology; L/R = subject's side):

=====================  =========================================================  ====
metric                 definition                                                 kind
=====================  =========================================================  ====
eye_corner_dist (w)    ‖p133 − p362‖ (R / L inner eye corners)                    norm
lip_gap                upper − lower inner lip height, mean of pairs              one
                       (13, 14), (82, 87), (312, 317)
mouth_width            ‖p61 − p291‖ (R / L mouth corners)                         two
lip_offset             x(17) − x(0): lower lip centre vs upper lip centre         two
brow_height_L / _R     mean y of brow (L 334, 296, 282, 295 / R 105, 66, 52, 65)  two
                       − mean y of the eye corners (L 362, 263 / R 133, 33)
eyelid_L / _R          upper − lower lid height, mean of pairs                    one
                       L (386, 374), (385, 380), (387, 373)
                       R (159, 145), (158, 153), (160, 144)
nose_L / _R            y(inner eye corner) − y(nostril wing): L 362 − 294,        one
                       R 133 − 64
brow_inner             mean of L y(336, 285) and R y(107, 55)                     two
                       − mean y of the inner eye corners (133, 362)
mouth_corner_L / _R    y(corner) − mean y(13, 14): L 291, R 61                    two
jaw_drop               y(2) − mean y(14, 87, 317) − β · mouth_width: the lower    one
                       inner lip below the base of the nose (subnasale), less
                       the part that follows the lips' stretch (β = 0.1, below)
=====================  =========================================================  ====

The first nine rows are the paper's set (mouth: lip height gap, mouth width, lip
horizontal offset; eyes: brow-to-eye height L/R, eyelid gap L/R, inner eye-corner
distance; nose: nostril-to-inner-eye-corner height L/R). The paper leaves
"上下嘴唇水平距离" (upper/lower lip horizontal distance) open; it is read here as the
sideways offset of the lower lip under the upper lip (it moves with jawLeft/Right).
``brow_inner``, ``mouth_corner_L/R`` and ``jaw_drop`` are additions of this project: the
paper's units cannot tell an inner brow raise from an outer one, a smile from a grin, nor
an open jaw from lips parted over the teeth (a toothy smile widens the lip gap with the jaw
shut), and the ARKit channels browInnerUp, mouthSmile/Frown and jawOpen need that.

The lower lip is not fixed to the jaw: stretching the lips sideways (a smile, "ee") draws
it down over the lower teeth, rounding them ("oo", a pucker) pushes it up and forward,
with the jaw where it was. Measured: the residual of the lower lip's height against a
straight-line fit on MediaPipe's jawOpen follows the mouth width (r 0.59 on the HDTF clip,
0.52 on Megamind). ``jaw_drop`` therefore subtracts ``JAW_STRETCH · mouth_width`` (both per
eye-corner distance): the lower lip's height at a given mouth width, on both sides of the
rest width (a correction for widening only did not help). Its one constant, β = 0.1, was
chosen from {0, 0.05, 0.1, 0.15, 0.2} on one set of videos and checked on another
(docs/face-capture.md; the choosing set's r peaks at 0.1 and falls off slowly either side).
"""

from __future__ import annotations

import functools

import numpy as np

from facecapges.rotations import vector_norm

INNER_EYE_R, INNER_EYE_L = 133, 362
OUTER_EYE_R, OUTER_EYE_L = 33, 263

LIP_PAIRS = ((13, 14), (82, 87), (312, 317))
MOUTH_CORNER_R, MOUTH_CORNER_L = 61, 291
UPPER_LIP_CENTER, LOWER_LIP_CENTER = 0, 17
SUBNASALE = 2
JAW_STRETCH = 0.1  # lower-lip drop per unit of mouth width that is the lips' stretch, not the jaw
BROW_L = (334, 296, 282, 295)
BROW_R = (105, 66, 52, 65)
BROW_INNER_L = (336, 285)
BROW_INNER_R = (107, 55)
EYELID_PAIRS_L = ((386, 374), (385, 380), (387, 373))
EYELID_PAIRS_R = ((159, 145), (158, 153), (160, 144))
NOSTRIL_L, NOSTRIL_R = 294, 64

#: metric names, the order of :func:`compute_metrics`'s output
METRIC_NAMES: tuple[str, ...] = (
    "lip_gap",
    "mouth_width",
    "lip_offset",
    "brow_height_L",
    "brow_height_R",
    "eyelid_L",
    "eyelid_R",
    "nose_L",
    "nose_R",
    "brow_inner",
    "mouth_corner_L",
    "mouth_corner_R",
    "jaw_drop",
)


def _pairs_index(pairs) -> tuple[np.ndarray, np.ndarray]:
    """The upper and lower landmarks of ``pairs`` as index arrays (made once, not on every frame)."""
    return np.array([a for a, _ in pairs]), np.array([b for _, b in pairs])


_PAIRS = {pairs: _pairs_index(pairs) for pairs in (LIP_PAIRS, EYELID_PAIRS_L, EYELID_PAIRS_R)}
_EYES_L = np.array([INNER_EYE_L, OUTER_EYE_L])
_EYES_R = np.array([INNER_EYE_R, OUTER_EYE_R])
_BROW_L, _BROW_R = np.array(BROW_L), np.array(BROW_R)
_BROW_INNER = np.array(BROW_INNER_L + BROW_INNER_R)
_LOWER_LIP = np.array([b for _, b in LIP_PAIRS])


@functools.cache
def _kernels():
    from facecapges.capture import kernels

    return kernels.compiled()


def _mean(x: np.ndarray) -> np.ndarray:
    """``x.mean(axis=-1)`` of float64 ``x``: its own arithmetic (the sum by ``add.reduce``, divided by the count),
    the same bits, without its Python layers (a dozen means a frame, issue 36)."""
    return np.add.reduce(x, axis=-1) / x.shape[-1]


def _pairs_height(P: np.ndarray, pairs) -> np.ndarray:
    up, lo = _PAIRS.get(pairs) or _pairs_index(pairs)
    return _mean(P[..., up, 1] - P[..., lo, 1])


def eye_corner_distance(P: np.ndarray) -> np.ndarray:
    """Inner eye-corner distance ``w`` of head-frame points (..., N, 3)."""
    return vector_norm(P[..., INNER_EYE_R, :] - P[..., INNER_EYE_L, :])


def compute_metrics(P: np.ndarray, compiled: bool = True) -> np.ndarray:
    """Head-frame landmarks (..., N ≥ 468, 3) → metrics (..., 13) in :data:`METRIC_NAMES` order.

    One face's (N, 3) float64 points in one compiled call where :mod:`facecapges.capture.kernels` keeps these
    bits on this machine and ``compiled`` (a live frame's, issue 36); else the NumPy below."""
    P = np.asarray(P, np.float64)
    k = _kernels() if compiled and P.ndim == 2 and P.flags.c_contiguous else None
    if k is not None:
        g = np.empty(13)
        k.metrics(P, g)
        return g
    w = np.maximum(eye_corner_distance(P), 1e-9)
    y = P[..., 1]
    eyes_L = _mean(y[..., _EYES_L])
    eyes_R = _mean(y[..., _EYES_R])
    lip_mid = 0.5 * (y[..., 13] + y[..., 14])
    mouth_width = vector_norm(P[..., MOUTH_CORNER_L, :] - P[..., MOUTH_CORNER_R, :])
    # the 13 metrics written into one array (what np.stack(…, axis=-1) of them makes, in fewer calls)
    g = np.empty((*w.shape, 13))
    g[..., 0] = _pairs_height(P, LIP_PAIRS)
    g[..., 1] = mouth_width
    g[..., 2] = P[..., LOWER_LIP_CENTER, 0] - P[..., UPPER_LIP_CENTER, 0]
    g[..., 3] = _mean(y[..., _BROW_L]) - eyes_L
    g[..., 4] = _mean(y[..., _BROW_R]) - eyes_R
    g[..., 5] = _pairs_height(P, EYELID_PAIRS_L)
    g[..., 6] = _pairs_height(P, EYELID_PAIRS_R)
    g[..., 7] = y[..., INNER_EYE_L] - y[..., NOSTRIL_L]
    g[..., 8] = y[..., INNER_EYE_R] - y[..., NOSTRIL_R]
    g[..., 9] = _mean(y[..., _BROW_INNER]) - 0.5 * (y[..., INNER_EYE_L] + y[..., INNER_EYE_R])
    g[..., 10] = y[..., MOUTH_CORNER_L] - lip_mid
    g[..., 11] = y[..., MOUTH_CORNER_R] - lip_mid
    g[..., 12] = y[..., SUBNASALE] - _mean(y[..., _LOWER_LIP]) - JAW_STRETCH * mouth_width
    return g / w[..., None]
