"""Synthetic landmark sequences with known expression parameters (for tests and bench).

A "subject" is MediaPipe's canonical face (:mod:`canonical_mesh`) with random
proportions (face width/height/depth scaled by 0.9–1.1, eye corners moved ±5 %,
eyelid and lip rest gaps varied) — an unseen person, since the estimator has no per-user
calibration. Expressions are events: a channel rises over 0.2 s, holds a peak in
[0.7, 1] for 0.3–1 s and falls over 0.2 s, like the blinks, brow raises and mouth
openings of a talking face; most of the time most channels rest.

Known parameters (ARKit names) and how they move the landmarks (head frame, cm;
``w`` = the subject's inner eye-corner distance):

* ``jawOpen`` p: lower-lip landmarks down by ``0.45·w·p^(1/γ)`` (the inverse of the
  estimator's response γ = ``JAW_GAMMA``, :mod:`estimator`);
* ``eyeBlinkLeft/Right`` p: upper-lid landmarks down by ``0.9 × rest gap × p^(1/1.5)``;
* ``browOuterUpLeft/Right`` p / ``browDownLeft/Right`` p: brow landmarks up / down by
  ``0.15·w·p``; ``browInnerUp`` p: inner-brow landmarks up by ``0.15·w·p``.

The face is then posed (smooth random yaw ±25°, pitch ±15°, roll ±10°, distance
0.4–0.9 m), projected with a 63° pinhole camera (1280×720, an HD webcam) into MediaPipe's normalised landmark
format (x, y of the image, z relative depth in units of the image width) and
jittered by ``noise_px`` pixels.
"""

from __future__ import annotations

import numpy as np

from facecapges.arkit import ARKIT_NAMES, N_BLENDSHAPES
from facecapges.capture.estimator import JAW_GAMMA
from facecapges.capture.head_pose import Intrinsics
from facecapges.capture.landmarks import N_LANDMARKS
from facecapges.capture.metrics import BROW_INNER_L, BROW_INNER_R, BROW_L, BROW_R
from facecapges.rotations import angles_to_matrix
from facecapges.timing import MODEL_FPS

CHANNELS = (
    "jawOpen",
    "eyeBlinkLeft",
    "eyeBlinkRight",
    "browOuterUpLeft",
    "browOuterUpRight",
    "browDownLeft",
    "browDownRight",
    "browInnerUp",
)
LOWER_LIP = (14, 87, 317, 178, 88, 95, 402, 318, 324, 17, 84, 314, 181, 405, 91, 321, 146, 375)
UPPER_LID_L = (386, 385, 387, 388, 384, 398, 466)
UPPER_LID_R = (159, 158, 160, 161, 157, 173, 246)


def _events(T: int, fps: float, rng, rate_hz: float) -> np.ndarray:
    x = np.zeros(T)
    t = int(rng.exponential(fps / rate_hz))
    rise = max(1, int(0.2 * fps))
    while t < T:
        hold = int(rng.uniform(0.3, 1.0) * fps)
        peak = rng.uniform(0.7, 1.0)
        prof = np.concatenate([np.linspace(0, 1, rise + 1)[1:], np.ones(hold), np.linspace(1, 0, rise + 1)[1:]])
        seg = slice(t, min(T, t + len(prof)))
        x[seg] = np.maximum(x[seg], peak * prof[: seg.stop - seg.start])
        t += len(prof) + int(rng.exponential(fps / rate_hz)) + 1
    return x


def _smooth_walk(T: int, rng, amp: float, fps: float) -> np.ndarray:
    k = max(1, int(fps))
    x = np.cumsum(rng.normal(0, 1, T + 2 * k))
    x = np.convolve(x, np.ones(k) / k, mode="same")[k : k + T]
    x -= x.mean()
    return amp * x / max(np.abs(x).max(), 1e-9)


def _expressed(V: np.ndarray, w: float, p: np.ndarray, A: dict[str, int]) -> np.ndarray:
    """The face ``V`` (468, 3) with one frame's weights ``p`` (52,) applied: jaw, lids, brows (``w``: eye width)."""
    X = V.copy()
    X[list(LOWER_LIP), 1] -= 0.45 * w * p[A["jawOpen"]] ** (1 / JAW_GAMMA)
    for side, lid in (("Left", UPPER_LID_L), ("Right", UPPER_LID_R)):
        gap = (X[386, 1] - X[374, 1]) if side == "Left" else (X[159, 1] - X[145, 1])
        X[list(lid), 1] -= 0.9 * gap * p[A[f"eyeBlink{side}"]] ** (1 / 1.5)
    for side, idx in (("Left", BROW_L), ("Right", BROW_R)):
        X[list(idx), 1] += 0.15 * w * (p[A[f"browOuterUp{side}"]] - p[A[f"browDown{side}"]])
    X[list(BROW_INNER_L + BROW_INNER_R), 1] += 0.15 * w * p[A["browInnerUp"]]
    return X


def synthetic_sequence(
    canonical: np.ndarray,
    n_frames: int = 300,
    fps: float = float(MODEL_FPS),
    seed: int = 0,
    width: int = 1280,
    height: int = 720,
    noise_px: float = 0.7,
) -> dict:
    """Landmarks (T, 478, 3) normalised, true params (T, 52), true R (T, 3, 3), image size."""
    rng = np.random.default_rng(seed)
    V = np.asarray(canonical, np.float64)[:468] * rng.uniform(0.9, 1.1, 3)
    w = float(np.linalg.norm(V[133] - V[362]))
    V[[133, 362], 0] *= rng.uniform(0.95, 1.05)
    V[list(UPPER_LID_L + UPPER_LID_R), 1] += rng.uniform(0.0, 0.1) * w  # rest eyelid gap varies
    T = n_frames
    P = np.zeros((T, N_BLENDSHAPES))
    A = {n: ARKIT_NAMES.index(n) for n in CHANNELS}
    P[:, A["jawOpen"]] = _events(T, fps, rng, 0.5) ** JAW_GAMMA
    blink = _events(T, fps, rng, 0.3)
    for side in ("Left", "Right"):
        P[:, A[f"eyeBlink{side}"]] = blink**1.5
    brow = _events(T, fps, rng, 0.2) - _events(T, fps, rng, 0.15)
    P[:, A["browOuterUpLeft"]] = P[:, A["browOuterUpRight"]] = np.clip(brow, 0, 1)
    P[:, A["browDownLeft"]] = P[:, A["browDownRight"]] = np.clip(-brow, 0, 1)
    P[:, A["browInnerUp"]] = _events(T, fps, rng, 0.2)
    yaw = np.radians(_smooth_walk(T, rng, 25, fps))
    pitch = np.radians(_smooth_walk(T, rng, 15, fps))
    roll = np.radians(_smooth_walk(T, rng, 10, fps))
    dist = 65 + _smooth_walk(T, rng, 25, fps)  # cm
    K = Intrinsics.default(width, height)
    L = np.zeros((T, N_LANDMARKS, 3))
    Rs = np.zeros((T, 3, 3))
    for k in range(T):
        X = _expressed(V, w, P[k], A)
        R = angles_to_matrix(yaw[k], pitch[k], roll[k])
        Rs[k] = R
        C = X @ R.T + np.array([0.0, 0.0, -dist[k]])  # camera frame, cm
        z = -C[:, 2]
        u = C[:, 0] / z * K.fx + K.cx + rng.normal(0, noise_px, 468)
        v = -C[:, 1] / z * K.fy + K.cy + rng.normal(0, noise_px, 468)
        zc = dist[k]
        L[k, :468, 0] = u / width
        L[k, :468, 1] = v / height
        L[k, :468, 2] = -(C[:, 2] + zc) * (K.fx / zc) / width  # relative depth, MediaPipe's scale/sign
        L[k, 468:] = L[k, [468 % 468]]  # iris points unused: copy a landmark
    return {
        "landmarks": L.astype(np.float32),
        "params": P.astype(np.float32),
        "R": Rs,
        "width": width,
        "height": height,
        "fps": fps,
    }


def run_geometric(seq: dict, pose_estimator, mode: str = "geometric") -> np.ndarray:
    """The per-frame (T, 52) output of the calibration-free estimator on a synthetic sequence."""
    from facecapges.capture.estimator import ExpressionEstimator
    from facecapges.capture.metrics import compute_metrics
    from facecapges.capture.samples import sample_weight

    est = ExpressionEstimator(mode)
    out = []
    for L in seq["landmarks"]:
        pose, pts = pose_estimator.estimate(L, seq["width"], seq["height"])
        g = compute_metrics(pose_estimator.to_head_frame(pts, pose))
        est.update(g, sample_weight(pose.distance_m, pose.normal))
        out.append(est.weights())
    return np.array(out)


def synthetic_mae(seq: dict, weights: np.ndarray, skip_frames: int = 0) -> dict[str, float]:
    """MAE per known channel (and their mean) after ``skip_frames``."""
    res = {}
    for n in CHANNELS:
        j = ARKIT_NAMES.index(n)
        res[n] = float(np.abs(weights[skip_frames:, j] - seq["params"][skip_frames:, j]).mean())
    res["mean"] = float(np.mean([res[n] for n in CHANNELS]))
    return res
