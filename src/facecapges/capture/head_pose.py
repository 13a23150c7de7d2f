"""Head pose from 3D landmarks: rigid alignment to the canonical face mesh.

Conventions
-----------
* **Camera frame** = OpenGL's (the frame of MediaPipe's facial transformation matrix):
  X to the image's right, Y up, +Z from the scene towards the camera. Units: cm inside
  this module, metres in ``distance_m``.
* **Head frame** = the canonical mesh's: X to the subject's left, Y up, +Z out of the
  face (see :mod:`canonical_mesh`).
* ``R`` maps head-frame vectors to camera-frame vectors; a face looking straight into
  the camera has ``R = I``. This is ARKit's face-anchor rotation relative to the camera
  and the rotation part of MediaPipe's facial transformation matrix. ``head_rot6d`` is
  ``matrix_to_rot6d(R)`` (first two columns, :mod:`facecapges.rotations`).
* **ARKit-style angles** ``(yaw, pitch, roll)`` in radians, with
  ``R = R_Y(yaw) @ R_X(pitch) @ R_Z(roll)``: yaw > 0 turns the face towards the image's
  right (the subject's left), pitch > 0 tilts it down (right-hand rule about X), roll > 0
  tilts it counter-clockwise
  as seen by the camera.
* **The gesture model's head input** is this camera-frame ``R`` (identity = facing the
  camera), whatever the source. Live capture (webcam, ARKit, Live Link) is already in
  it. A rotation from a motion-capture skeleton (BEAT/ZEGGS: the global rotation of
  the head chain, :func:`facecapges.skeleton.head_rot6d`, Y up, the body facing +Z —
  the same axes as the camera frame of a camera in front of the speaker) is mapped
  into it by :func:`skeleton_head_to_camera`: ``R = R_skel · R_refᵀ``, where
  ``R_ref`` (:func:`facecapges.rotations.mean_rotation`) is the speaker's mean head rotation over the
  training frames — the speaker's average head orientation stands for "facing the
  camera". A head turn of the speaker about the vertical axis is then the same turn of
  a user in front of the camera. The trainer stores ``R_ref`` in the checkpoint
  (``head_reference_rot6d``); evaluation maps held-out skeleton heads with it.

Landmarks → metric points (:func:`landmarks_to_camera`): MediaPipe's normalised
landmarks are a scaled-orthographic view. They are lifted to the camera frame with a
pinhole camera (focal length from the intrinsics, or — like MediaPipe's geometry
pipeline — a 63° vertical field of view when unknown): a first similarity fit to the
canonical mesh gives the scale, hence the head's depth ``z = f / s``; each landmark is
then unprojected along its own ray at that depth plus its relative depth. A second,
rigid fit on those points gives ``R`` and ``t``. Both fits are weighted Kabsch /
Umeyama alignments (:func:`procrustes`) on MediaPipe's own Procrustes landmark basis
(the stable points listed in the model bundle), so expression barely moves the pose.

Smoothing (paper 3.1.1 asks for window smoothing of the jitter):
:class:`PoseSmoother` fits a straight line, per component, to the last ``window`` poses
(rotation as a rotation vector relative to the newest raw pose, translation in cm) and
takes the line's value *at the newest frame*. That is a causal window smoother whose
lag is zero for constant-velocity motion (and under one frame for accelerating motion),
unlike a moving average, which lags by ``(window − 1) / 2`` frames. A jump larger than
``reset_deg`` restarts the window, so real fast turns are not smeared.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from dataclasses import dataclass
from types import ModuleType

import numpy as np

from facecapges import rotations as rot

DEFAULT_VFOV_DEG = 63.0  # MediaPipe's geometry pipeline default


@dataclass(frozen=True)
class SourceFit:
    """The source side of :func:`procrustes`, worked out once for a source that does not change between fits (the
    canonical mesh's Procrustes basis, fitted twice a frame): the points, the normalised weights, their weighted
    mean, the centred points and (``with_scale``) their weighted variance. A fit given it computes only the
    destination's side, with the same bits as computing both each time."""

    src: np.ndarray  # (N, 3)
    w: np.ndarray  # (N,) weights / their sum
    mu: np.ndarray  # (3,) w @ src
    a: np.ndarray  # (N, 3) src - mu
    var: float | None  # w @ |a|², when the fit has a scale

    @classmethod
    def of(cls, src: np.ndarray, weights: np.ndarray | None = None, with_scale: bool = True) -> SourceFit:
        w = np.ones(len(src)) if weights is None else np.asarray(weights, np.float64)
        w = w / w.sum()
        mu = w @ src
        a = src - mu
        return cls(src, w, mu, a, float(w @ (a * a).sum(axis=1)) if with_scale else None)


def procrustes(
    src: np.ndarray | None,
    dst: np.ndarray,
    weights: np.ndarray | None = None,
    with_scale: bool = True,
    fit: SourceFit | None = None,
) -> tuple[float, np.ndarray, np.ndarray]:
    """Weighted similarity alignment ``dst ≈ s · R @ src + t`` (Umeyama 1991).

    Args:
        src, dst: (N, 3) corresponding points.
        weights: (N,) non-negative, or None for equal weights.
        with_scale: fit ``s``; else ``s = 1`` (rigid Kabsch).
        fit: ``SourceFit.of(src, weights, with_scale)`` made beforehand (``src`` and ``weights`` are then
            not used): the same result, without redoing the source's side.
    Returns:
        ``(s, R (3, 3), t (3,))`` with ``det R = +1``.
    """
    if fit is None:
        assert src is not None
        fit = SourceFit.of(src, weights, with_scale)
    w = fit.w
    mu_d = w @ dst
    b = dst - mu_d
    cov = (b * w[:, None]).T @ fit.a  # (3, 3) = Σ w b aᵀ
    u, sig, vt = _svd(cov)
    D = np.array([1.0, 1.0, _det_sign(u @ vt)])
    R = (u * D) @ vt
    if with_scale:
        var_s = fit.var if fit.var is not None else float(w @ (fit.a * fit.a).sum(axis=1))
        s = float((sig * D).sum() / max(var_s, 1e-12))
    else:
        s = 1.0
    t = mu_d - s * R @ fit.mu
    return s, R, t


_SVD_F = getattr(getattr(np.linalg, "_umath_linalg", None), "svd_f", None)  # np.linalg.svd's own gufunc


def _svd(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``np.linalg.svd(a)`` of a finite float64 (3, 3): its gufunc (LAPACK's ``dgesdd``, the same bits) called
    without its argument handling, half its cost (twice a frame: issue 36). Anything else — a NaN or an infinity, where
    it raises LinAlgError — goes through ``np.linalg.svd`` itself."""
    if _SVD_F is None or not math.isfinite(np.add.reduce(a, axis=None)):
        return np.linalg.svd(a)
    return _SVD_F(a, signature="d->ddd")


def _det_sign(m: np.ndarray) -> float:
    """``np.sign(np.linalg.det(m))`` of an orthogonal 3×3 ``m`` (0 counted as +1, NaN kept): its determinant is
    ±1 to rounding, so the cofactor expansion has the same sign as LAPACK's LU; in Python's floats, without
    ``det``'s argument handling (twice a frame: issue 36)."""
    (a, b, c), (d, e, f), (g, h, i) = m.tolist()
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    return 1.0 if det >= 0.0 else -1.0 if det < 0.0 else det


def _norm(x: np.ndarray):
    """``np.linalg.norm(x)`` of a float vector: its own arithmetic (the square root of ``x · x``, in ``x``'s dtype),
    without its argument handling (twice a frame: issue 36)."""
    x = np.asarray(x).ravel()
    return np.sqrt(x.dot(x))


def _log_so3(M: np.ndarray) -> np.ndarray:
    """:func:`facecapges.rotations.log_so3` of float64 rotations (m, 3, 3), in two compiled calls around NumPy's own
    ``arctan2`` where :mod:`facecapges.capture.kernels` keeps its bits (issue 36), else (and within 1e-4 rad of π)
    its own."""
    k = _kernels()
    if k is None:
        return rot.log_so3(M)
    v, sn, c = np.empty((len(M), 3)), np.empty(len(M)), np.empty(len(M))
    k.skew_parts(M, v, sn, c)
    return v if k.scale_skew(v, sn, np.arctan2(sn, c)) else rot.log_so3(M)


def focal_from_vfov(height_px: float, vfov_deg: float = DEFAULT_VFOV_DEG) -> float:
    """Pinhole focal length in pixels for an image ``height_px`` tall."""
    return 0.5 * height_px / math.tan(math.radians(vfov_deg) / 2)


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels (image x right, y down)."""

    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def default(cls, width: int, height: int, vfov_deg: float = DEFAULT_VFOV_DEG) -> Intrinsics:
        f = focal_from_vfov(height, vfov_deg)
        return cls(f, f, width / 2.0, height / 2.0)


def landmarks_to_camera(
    landmarks: np.ndarray,
    width: int,
    height: int,
    canonical: np.ndarray,
    weights: np.ndarray,
    ids: np.ndarray,
    K: Intrinsics | None = None,
    fit: SourceFit | None = None,
    compiled: bool | ModuleType = True,
) -> np.ndarray:
    """Normalised MediaPipe landmarks (N ≥ 468, 3) → camera-frame points (468, 3) in cm.

    See the module docstring. ``canonical`` (468, 3) cm, ``ids``/``weights`` the fit basis; ``fit``:
    ``SourceFit.of(canonical[ids], weights)``, made once (:class:`HeadPoseEstimator` does). The points before and
    after the fit in one compiled call each where :mod:`facecapges.capture.kernels` keeps these bits on this machine
    and ``compiled`` (issue 36; or ``compiled`` is that module, unchecked: its own check), else the NumPy below."""
    K = K or Intrinsics.default(width, height)
    fit = fit or SourceFit.of(canonical[ids], weights)
    k = _kernels() if compiled is True else compiled or None
    if k is not None:
        ortho, out = np.empty((468, 3)), np.empty((468, 3))
        k.ortho_points(landmarks, int(width), int(height), ortho)
        s, _, t = procrustes(None, ortho[ids], fit=fit)
        k.lift_points(ortho, s, float(t[2]), float(K.fx), float(K.fy), float(K.cx), float(K.cy), out)
        return out
    lm = np.asarray(landmarks[:468], np.float64)
    px = lm[:, 0] * width
    py = lm[:, 1] * height
    # scaled-orthographic points in pixels, camera axes (Y up, Z towards the camera); columns written in place (what
    # np.stack(…, axis=1) makes, without its Python layers: issue 36)
    ortho = np.empty((len(lm), 3))
    ortho[:, 0] = px
    np.negative(py, out=ortho[:, 1])
    np.multiply(lm[:, 2], -width, out=ortho[:, 2])
    s, _, t = procrustes(None, ortho[ids], fit=fit)
    depth = K.fx / s  # cm from the camera to the fitted head origin
    rel = ortho[:, 2] - t[2]  # pixels, + towards the camera
    z = depth - rel / s  # cm, distance along the optical axis
    out = np.empty((len(lm), 3))
    out[:, 0] = (px - K.cx) * z / K.fx
    out[:, 1] = -(py - K.cy) * z / K.fy
    np.negative(z, out=out[:, 2])
    return out


@functools.cache
def _kernels():
    from facecapges.capture import kernels

    return kernels.compiled()


@dataclass
class HeadPose:
    """One head pose: ``R`` head→camera (3, 3), ``t`` (3,) cm, camera frame (module docstring)."""

    R: np.ndarray
    t: np.ndarray
    scale: float = 1.0

    @property
    def rot6d(self) -> np.ndarray:
        return rot.matrix_to_rot6d(self.R).astype(np.float32)

    @property
    def angles(self) -> np.ndarray:
        """(yaw, pitch, roll) radians, ``R = R_Y(yaw) R_X(pitch) R_Z(roll)``."""
        return rot.head_angles(self.R)

    @property
    def distance_m(self) -> float:
        """Distance from the camera centre to the head origin, metres.

        ``|t| / scale``: the lifted points are only known up to the assumption that the
        face has the canonical mesh's size, and a fitted scale ≠ 1 means the lifting
        depth was off by that factor.
        """
        return float(_norm(self.t) / max(self.scale, 1e-9) / 100.0)

    @property
    def normal(self) -> np.ndarray:
        """The face's unit normal in camera coordinates (``R @ +Z``)."""
        return self.R[:, 2].copy()


class HeadPoseEstimator:
    """Landmarks → :class:`HeadPose` by alignment to the canonical mesh (module docstring)."""

    def __init__(self, canonical_vertices: np.ndarray, basis_ids: np.ndarray, basis_weights: np.ndarray):
        self.canonical = np.asarray(canonical_vertices, np.float64)
        self.ids = np.asarray(basis_ids)
        self.weights = np.asarray(basis_weights, np.float64)
        self.fit = SourceFit.of(self.canonical[self.ids], self.weights)  # both fits' source: the same every frame

    def estimate(
        self, landmarks: np.ndarray, width: int, height: int, K: Intrinsics | None = None
    ) -> tuple[HeadPose, np.ndarray]:
        """Pose and the camera-frame points (468, 3) cm of one face."""
        pts = landmarks_to_camera(landmarks, width, height, self.canonical, self.weights, self.ids, K, self.fit)
        s, R, t = procrustes(None, pts[self.ids], fit=self.fit)
        return HeadPose(R, t, s), pts

    def to_head_frame(self, pts: np.ndarray, pose: HeadPose) -> np.ndarray:
        """Camera-frame points → head frame (canonical orientation and scale, cm)."""
        return ((pts - pose.t) @ pose.R) / pose.scale


class PoseSmoother:
    """Causal local-linear window smoother for poses (module docstring).

    Args:
        window: number of frames in the fit (1 = no smoothing).
        reset_deg: a frame-to-frame rotation jump above this restarts the window.
    """

    def __init__(self, window: int = 5, reset_deg: float = 20.0):
        self.window = max(1, int(window))
        self.reset = math.radians(reset_deg)
        self._R: deque = deque(maxlen=self.window)
        self._t: deque = deque(maxlen=self.window)
        n = self.window
        # least-squares line through x = -(n-1)..0, evaluated at 0: fixed weights per length
        self._coef = {m: self._endpoint_weights(m) for m in range(1, n + 1)}

    @staticmethod
    def _endpoint_weights(m: int) -> np.ndarray:
        if m == 1:
            return np.ones(1)
        x = np.arange(-(m - 1), 1, dtype=np.float64)
        A = np.stack([np.ones(m), x], axis=1)
        return np.linalg.pinv(A)[0]  # intercept row: value at x = 0

    def reset_state(self) -> None:
        self._R.clear()
        self._t.clear()

    def __call__(self, pose: HeadPose) -> HeadPose:
        ref = pose.R
        rv = None  # (m, 3) the window's rotations relative to the newest
        if self._R:
            # the jump from the last pose and the window's rotations relative to the newest (as if the window goes on)
            # in one log_so3 call: it works matrix by matrix, so the same numbers as a call each (issue 36)
            kept = list(self._R)[max(0, len(self._R) - self.window + 1) :]
            logs = _log_so3(np.concatenate([(self._R[-1].T @ ref)[None], ref.T @ np.stack([*kept, ref])]))
            if _norm(logs[0]) > self.reset:
                self.reset_state()
            else:
                rv = logs[1:]
        if rv is None:  # a new window: the newest pose alone
            rv = _log_so3(ref.T @ np.stack([ref]))
        self._R.append(ref.copy())
        self._t.append(np.asarray(pose.t, np.float64).copy())
        c = self._coef[len(self._R)]
        R = ref @ rot.exp_so3(c @ rv)
        t = c @ np.stack(self._t)
        return HeadPose(R, t, pose.scale)


def skeleton_head_to_camera(head_rot6d: np.ndarray, reference_rot6d: np.ndarray) -> np.ndarray:
    """Skeleton-frame head rotations (…, 6) → the model's camera frame: ``R_skel · R_refᵀ`` (module docs)."""
    R = rot.rot6d_to_matrix(np.asarray(head_rot6d, np.float64))
    ref = rot.rot6d_to_matrix(np.asarray(reference_rot6d, np.float64))
    return rot.matrix_to_rot6d(R @ np.swapaxes(ref, -1, -2)).astype(np.float32)
