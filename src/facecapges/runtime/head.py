"""The avatar's head is the person's head: the captured head rotation on the avatar's neck joints.

The gesture model *gets* the captured head as an input (thesis §2.4) and also *outputs*
the neck joints (``Neck``, ``Neck1`` of the 47). What the avatar shows is chosen by
``--head``:

* ``capture`` (default of ``run`` and ``live``) — the captured head; while the face is
  lost the avatar's head goes over to the model's by the project's face-lost policy
  (:mod:`facecapges.capture.face_lost`: the last captured head held 0.5 s, then a 1 s
  smoothstep to the model's head) and comes back to the capture over 0.3 s when the face
  is found again;
* ``model`` — the model's own neck output, as generated (no capture on the head);
* ``blend`` — half-way (geodesic) between the two, with the same face-lost fallback.

Frames (the one mapping this module owns)
-----------------------------------------
The captured rotation ``R`` maps head-frame vectors to the camera frame (OpenGL: X to
the image's right, Y up, +Z towards the camera; identity = facing the camera,
:mod:`facecapges.capture.head_pose`). The avatar is built in the BVH world frame, Y up,
facing +Z, and every view of it (renderer, viewer) looks at it from +Z: the camera frame
*is* the avatar's world frame, so ``R`` is taken as the **global** rotation of the head
(the end of the Spine → … → Neck1 chain; ``Head`` itself is not driven, see
:mod:`facecapges.skeleton`). A person who turns to the image's right is shown turning to
the image's right (a side-by-side view, not a mirror). The rotation left for the neck
after the body's own chain, ``L = G(Spine3)⁻¹ · R``, is shared equally by ``Neck`` and
``Neck1`` (each ``exp(½ log L)``, so their product is exactly ``L``); joints above the
spine (Hips, Spine1–3) are at rest in the model's output, so ``G(Spine3)`` is the
``Spine`` rotation. Over VMC the same joints go out (``Neck``, and ``Neck1`` folded into
``Head``), so a receiver shows the same head.
"""

from __future__ import annotations

import functools
from types import ModuleType

import numpy as np

from facecapges import rotations as rot
from facecapges.capture.face_lost import FaceLostPolicy

HEAD_MODES = ("capture", "model", "blend")
_SPINE, _NECK, _NECK1 = 0, 1, 2  # indices in facecapges.skeleton.UPPER_BODY
_BLEND = {"capture": 1.0, "blend": 0.5, "model": 0.0}
_IDENTITY_Q = np.array([1.0, 0.0, 0.0, 0.0])


def check_head_mode(mode: str) -> str:
    from facecapges.errors import UserError

    if mode not in HEAD_MODES:
        raise UserError(f"--head must be one of {', '.join(HEAD_MODES)}, got {mode!r}")
    return mode


def avatar_head_matrix(pose: np.ndarray) -> np.ndarray:
    """Global head rotation(s) (..., 3, 3) of upper-body poses (..., 47, 6): Spine · Neck · Neck1."""
    M = rot.rot6d_to_matrix(np.asarray(pose, np.float64)[..., :3, :])
    return M[..., _SPINE, :, :] @ M[..., _NECK, :, :] @ M[..., _NECK1, :, :]


def set_head(pose: np.ndarray, R_head: np.ndarray, spine: np.ndarray | None = None) -> np.ndarray:
    """A copy of ``pose`` (47, 6) whose global head rotation is ``R_head`` (module docstring). ``spine``: the pose's
    Spine as a matrix (``rot6d_to_matrix`` of its float64 row), when the caller has it."""
    if spine is None:
        spine = rot.rot6d_to_matrix(np.asarray(pose[_SPINE], np.float64))
    L = spine.T @ np.asarray(R_head, np.float64)
    # rotation_power_about(L, None, 0.5) as rot6d: its quaternion path, rot6d taken straight from the quaternion
    # (quaternion_to_rot6d: matrix_to_rot6d(quaternion_to_matrix(·)) to the bit, in fewer calls: issue 36)
    half = rot.quaternion_to_rot6d(rot.quaternion_power_about(rot.matrix_to_quaternion(L), _IDENTITY_Q, 0.5))
    out = np.array(pose, copy=True)
    out[_NECK] = half
    out[_NECK1] = half
    return out


def _set_head_compiled(rc: ModuleType, pose: np.ndarray, R_head: np.ndarray) -> np.ndarray:
    """:func:`set_head` through :mod:`facecapges.rotations_compiled` (two compiled calls and NumPy's ``arccos``
    between them, instead of ~50 NumPy calls on one row: issue 36, the output stage's largest part)."""
    ref, lq, q, theta = np.empty((3, 3)), np.empty((3, 3)), np.empty(4), np.empty(1)
    theta[0] = rc.relative_quaternion(pose[_SPINE], R_head, ref, lq, q)
    np.arccos(theta, out=theta)  # NumPy's own (SIMD) arccos, not libm's: its bits
    out = np.array(pose, copy=True)
    rc.power_about_identity_rot6d(q, theta[0], 0.5, out[_NECK : _NECK1 + 1])
    return out


def _head_and_spine(head_rot6d: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """The captured head's and the pose's Spine's matrices (2, 3, 3) in one conversion (rot6d_to_matrix works row
    by row: the same numbers as one call each; issue 36, fewer NumPy calls a frame)."""
    rows = np.empty((2, 6))
    rows[0], rows[1] = head_rot6d, pose[_SPINE]
    return rot.rot6d_to_matrix(rows)


def _numpy_capture_head(pose: np.ndarray, head_rot6d: np.ndarray) -> np.ndarray:
    """What :class:`HeadDriver` shows in full capture with NumPy alone."""
    M = _head_and_spine(head_rot6d, pose)
    return set_head(pose, M[0], M[1])


@functools.cache  # once a process
def compiled_head() -> ModuleType | None:
    """:mod:`facecapges.rotations_compiled` when its head chain gives :func:`set_head`'s bits on this machine —
    checked here on 400 random poses and heads (float32, as ``live``'s; a third with the head on the Spine or a
    hair off it: the linear blend's branch) — else ``None`` (NumPy's own chain; a build whose ``einsum``, BLAS or
    ``sin`` sum or round otherwise than the compiled loops falls back rather than change a bit)."""
    from facecapges import rotations_compiled as rc

    rng = np.random.default_rng(0)
    n = 400  # ~30 ms a process (tests/test_runtime_head.py checks more)
    poses = rng.standard_normal((n, 47, 6)).astype(np.float32)
    heads = rot.quaternion_to_rot6d(rng.standard_normal((n, 4))).astype(np.float32)
    poses[: n // 3, _SPINE] = heads[: n // 3] + (rng.standard_normal((n // 3, 6)) * 1e-7).astype(np.float32)
    poses[: n // 6, _SPINE] = heads[: n // 6]
    R = np.empty((3, 3))
    for pose, head in zip(poses, heads):
        rc.rot6d_to_matrix(head, R)
        got, want = _set_head_compiled(rc, pose, R), _numpy_capture_head(pose, head)
        if not np.array_equal(got.view(np.uint32), want.view(np.uint32)):
            return None
    return rc


class HeadDriver:
    """Per stream: the model's pose in, the pose the avatar shows out (module docstring). ``compiled``: the full
    capture's chain through :func:`compiled_head` (Numba: ``live``'s scheduler, which loads it anyway), where it
    keeps NumPy's bits."""

    def __init__(self, mode: str = "capture", policy: FaceLostPolicy | None = None, compiled: bool = False):
        self._rc = compiled_head() if compiled else None
        self.mode = check_head_mode(mode)
        self.policy = policy or FaceLostPolicy()
        self.share = _BLEND[mode]
        self.weight = 0.0  # how much of the captured head is shown now
        self._R: np.ndarray | None = None  # last captured head while found
        self._tracking = False
        self._R_seen = False
        self._since = 0.0
        self._w_from = 0.0

    def __call__(self, pose: np.ndarray, head_rot6d: np.ndarray, found: bool, t_s: float) -> np.ndarray:
        if self.share == 0.0:
            return pose
        spine = None
        if found:
            if self._rc is not None:  # its Spine in the compiled chain below
                self._R = np.empty((3, 3))
                self._rc.rot6d_to_matrix(head_rot6d, self._R)
            else:
                M = _head_and_spine(head_rot6d, pose)
                self._R, spine = M[0], M[1]
            if not self._tracking:
                # the first face of the session is shown at once (there is no captured head to come from)
                first = self._R_seen is False
                self._tracking, self._since, self._w_from = True, t_s, 1.0 if first else self.weight
                self._R_seen = True
            k = self.policy.ease_in(t_s - self._since)
            self.weight = self._w_from + (1.0 - self._w_from) * k
        else:
            if self._tracking:
                self._tracking, self._since, self._w_from = False, t_s, self.weight
            self.weight = self._w_from * self.policy.held(t_s - self._since)
        w = self.weight * self.share
        if self._R is None or w <= 0.0:
            return pose
        if w >= 1.0:  # the captured head in full (tracking in ``capture`` mode: most frames)
            if self._rc is not None:
                return _set_head_compiled(self._rc, pose, self._R)
            return set_head(pose, self._R, spine)
        return set_head(pose, rot.rotation_power_about(self._R, avatar_head_matrix(pose), w))


def _corr(a: np.ndarray, b: np.ndarray) -> float | None:
    if len(a) < 3 or np.std(a) < 1e-9 or np.std(b) < 1e-9:
        return None
    return float(np.corrcoef(a, b)[0, 1])


def head_follow(poses: np.ndarray, heads: np.ndarray, found: np.ndarray | None = None) -> dict:
    """How closely the avatar's head follows the captured one, over the frames with a face.

    Args:
        poses: (T, 47, 6) the poses shown; heads: (T, 6) captured head rot6d; found: (T,) bool.
    Returns:
        ``{"frames", "yaw_r", "pitch_r", "yaw_range_deg": {"captured", "avatar"}, "pitch_range_deg": …,
        "mean_error_deg"}``: Pearson correlations of the ARKit-style angles
        (:func:`facecapges.rotations.head_angles`) and the mean geodesic angle between the two.
    """
    poses, heads = np.asarray(poses), np.asarray(heads)
    keep = np.ones(len(poses), bool) if found is None else np.asarray(found, bool)
    if not keep.any():
        return {"frames": 0}
    A = avatar_head_matrix(poses[keep])
    C = rot.rot6d_to_matrix(heads[keep].astype(np.float64))
    a = np.degrees(rot.head_angles(A))
    c = np.degrees(rot.head_angles(C))
    err = np.degrees(rot.geodesic_angle(A, C))

    def rng(x):
        return [round(float(x.min()), 1), round(float(x.max()), 1)]

    r = {k: _corr(a[:, i], c[:, i]) for i, k in ((0, "yaw_r"), (1, "pitch_r"))}
    return {
        "frames": int(keep.sum()),
        **{k: None if v is None else round(v, 4) for k, v in r.items()},
        "yaw_range_deg": {"captured": rng(c[:, 0]), "avatar": rng(a[:, 0])},
        "pitch_range_deg": {"captured": rng(c[:, 1]), "avatar": rng(a[:, 1])},
        "mean_error_deg": round(float(err.mean()), 2),
    }
