"""Rotation conventions for the whole project, stated once, and every rotation helper.

Every function here is pure and, unless its docstring says "numpy only", batched over
leading dimensions and works on both ``numpy.ndarray`` and ``torch.Tensor`` (the output has
the input's type). Conversions (Euler, rot6d, quaternions, rotation vectors, ARKit-style head
angles), the quaternion algebra, averages (:func:`mean_rotation`, :func:`quaternion_mean`) and
the one rule for scaling or interpolating a rotation about another,
:func:`quaternion_power_about` (slerp, the intensity dial, the face-lost ease), live here only.

Conventions
-----------
* **Matrices act on column vectors**: ``v_world = R @ v_local``. A child's global
  rotation is ``G_child = G_parent @ R_child`` (thesis eq. 2.2).
* **rot6d** is the *first two columns* of the rotation matrix, concatenated:
  ``r6 = [R[:, 0]; R[:, 1]] = (R00, R10, R20, R01, R11, R21)`` (thesis 2.3). It is
  turned back into a matrix by Gram–Schmidt (eq. 2.6–2.9): ``u1 = a/|a|``,
  ``u2 = normalise(b - (u1·b) u1)``, ``u3 = u1 × u2``, ``R = [u1 u2 u3]``.
  Note that pytorch3d's ``matrix_to_rotation_6d`` takes the first two *rows*; ours
  is the transpose of that choice.
* **Euler angles** are BVH's: degrees in files (:func:`euler_to_matrix` takes
  ``degrees=True`` for them), radians inside ARKit-style head angles. The order is a
  string of axis letters as the BVH ``CHANNELS`` line declares them, e.g. ``"XYZ"``
  for ``Xrotation Yrotation Zrotation``; the rotation is intrinsic in that order,
  ``R = R_X(a0) @ R_Y(a1) @ R_Z(a2)``, which is how BVH, Blender and three.js's
  BVHLoader read the channels.
* **Quaternions** are ``(w, x, y, z)``, real part first, unit norm, and
  :func:`matrix_to_quaternion` returns the one with ``w >= 0``.
* **Handedness**: BEAT BVH, three.js and glTF are right-handed, Y up, +Z towards the
  viewer, centimetres in BVH and metres in glTF. ARKit's face anchor is right-handed
  too (Y up, +Z out of the face). Unity / VMC is left-handed (Y up, +Z forward):
  :func:`quaternion_to_unity` converts a right-handed quaternion by mirroring the X
  axis, ``(w, x, y, z) -> (w, x, -y, -z)`` (positions: ``x -> -x``).
"""

from __future__ import annotations

import functools
import math
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

Array = Any  # numpy.ndarray or torch.Tensor

_EPS = 1e-8
_CROSS_I, _CROSS_J = np.array([1, 2, 0]), np.array([2, 0, 1])  # _cross's index arrays, made once


# --------------------------------------------------------------------------- helpers
def _is_torch(x: Array) -> bool:
    """A torch tensor? (torch is never imported here: a tensor means it is loaded; NumPy callers stay light.)"""
    t = sys.modules.get("torch")
    return t is not None and isinstance(x, t.Tensor)


def _torch() -> Any:
    """The torch module, for a function given a tensor (so already imported)."""
    return sys.modules["torch"]


def _check_last(x: Array, shape: tuple[int, ...], what: str) -> None:
    if tuple(x.shape[-len(shape) :]) != shape:
        raise ValueError(f"{what} must have shape (..., {', '.join(map(str, shape))}), got {tuple(x.shape)}")


def _stack(items: list[Array], axis: int, like: Array) -> Array:
    return _torch().stack(items, dim=axis) if _is_torch(like) else np.stack(items, axis=axis)


def _cross(a: Array, b: Array) -> Array:
    if _is_torch(a):
        return _torch().linalg.cross(a, b, dim=-1)
    i, j = _CROSS_I, _CROSS_J  # np.cross is slow on small arrays (take: a[..., i] without fancy indexing's setup)
    return a.take(i, axis=-1) * b.take(j, axis=-1) - a.take(j, axis=-1) * b.take(i, axis=-1)


def _norm(a: Array) -> Array:
    if _is_torch(a):
        return _torch().linalg.norm(a, dim=-1, keepdim=True)
    return vector_norm(a, keepdims=True)


def vector_norm(a: np.ndarray, keepdims: bool = False) -> np.ndarray:
    """``np.linalg.norm(a, axis=-1)``'s own arithmetic (``sqrt(add.reduce(a·a))``, the same bits) without
    its argument handling: on the engine's (1, 47, k) arrays that was most of its cost."""
    a = np.asarray(a)
    if not issubclass(a.dtype.type, np.inexact):
        a = a.astype(float)
    sq = a * a
    k = sq.shape[-1] if sq.ndim else 0
    if 2 <= k < 8:  # add.reduce sums fewer than 8 numbers left to right: the same sums, 5x faster on (300, 47, 3)
        s = sq[..., 0] + sq[..., 1]
        for i in range(2, k):
            s += sq[..., i]
    else:
        s = np.add.reduce(sq, axis=-1)
    n = np.sqrt(s)
    return n[..., None] if keepdims else n


def _maximum(a: Array, value: float) -> Array:
    return _torch().clamp(a, min=value) if _is_torch(a) else np.maximum(a, value)


def _sqrt(a: Array) -> Array:
    return _torch().sqrt(a) if _is_torch(a) else np.sqrt(a)


# ---------------------------------------------------------------- axis and Euler
def axis_angle_matrix(axis: str, angle: Array) -> Array:
    """Rotation matrices about one principal axis ``"X"``, ``"Y"`` or ``"Z"``.

    ``angle`` in radians, shape (...); returns (..., 3, 3).
    """
    lib = _torch() if _is_torch(angle) else np
    c, s = lib.cos(angle), lib.sin(angle)
    one, zero = lib.ones_like(angle), lib.zeros_like(angle)
    if axis == "X":
        rows = (one, zero, zero, zero, c, -s, zero, s, c)
    elif axis == "Y":
        rows = (c, zero, s, zero, one, zero, -s, zero, c)
    elif axis == "Z":
        rows = (c, -s, zero, s, c, zero, zero, zero, one)
    else:
        raise ValueError(f"axis must be one of X, Y, Z, got {axis!r}")
    flat = _stack(list(rows), -1, angle)
    return flat.reshape(tuple(angle.shape) + (3, 3))


def _check_order(order: str) -> str:
    order = order.upper()
    if len(order) != 3 or set(order) != {"X", "Y", "Z"}:
        raise ValueError(f"Euler order must be a permutation of 'XYZ', got {order!r}")
    return order


def euler_to_matrix(euler: Array, order: str, degrees: bool = False) -> Array:
    """Euler angles (..., 3), applied intrinsically in ``order`` → matrices (..., 3, 3).

    ``euler[..., i]`` is the angle about axis ``order[i]``; the result is
    ``R_order[0] @ R_order[1] @ R_order[2]``. BVH channels are in degrees: pass
    ``degrees=True``.
    """
    order = _check_order(order)
    _check_last(euler, (3,), "euler")
    if degrees:
        euler = euler * (math.pi / 180.0)
    mats = [axis_angle_matrix(order[i], euler[..., i]) for i in range(3)]
    return mats[0] @ mats[1] @ mats[2]


def matrix_to_euler(matrix: Array, order: str | Sequence[str], degrees: bool = False) -> Array:
    """Inverse of :func:`euler_to_matrix` (principal branch, middle angle in [-90°, 90°]).

    ``order``: one order for every matrix, or a sequence of orders, one per entry of
    the matrices' third-last axis (e.g. each joint of a skeleton in its own BVH order:
    ``matrix`` (..., J, 3, 3) with J orders) — one vectorised pass either way.

    Near gimbal lock the first angle is set from the remaining freedom; the matrix
    the angles give back is still the input matrix.
    """
    _check_last(matrix, (3, 3), "matrix")
    lib = _torch() if _is_torch(matrix) else np
    # one order: ints and a float sign; one order per matrix: index and sign arrays (NumPy or torch)
    i: Any
    j: Any
    k: Any
    sign: Any
    rows: Any
    if isinstance(order, str):
        i, j, k = ("XYZ".index(a) for a in _check_order(order))
        sign = 1.0 if (j - i) % 3 == 1 else -1.0  # even permutations (XYZ, YZX, ZXY) give +1
        ii, ij, ik, jk, kk, kj, jj = (
            matrix[..., r, c] for r, c in ((i, i), (i, j), (i, k), (j, k), (k, k), (k, j), (j, j))
        )
    else:
        rows, cols, sign = _orders_index(tuple(order))
        if matrix.ndim < 3 or matrix.shape[-3] != len(rows):
            raise ValueError(f"{len(rows)} Euler orders for matrices of shape {tuple(matrix.shape)}")
        if _is_torch(matrix):
            flat = matrix.reshape(tuple(matrix.shape[:-2]) + (9,))
            rows, cols = _torch().as_tensor(rows, device=matrix.device), _torch().as_tensor(cols, device=matrix.device)
            sign = _torch().as_tensor(sign, dtype=matrix.dtype, device=matrix.device)
            v = flat[..., rows, cols]  # (..., J, 7): the seven entries used, each joint's own
        else:  # the same entries by one np.take over each matrix set's J·9 numbers, then as below
            take, signs = _orders_take(tuple(order))
            return _euler_from_entries(
                np.take(matrix.reshape(tuple(matrix.shape[:-3]) + (-1,)), take, axis=-1), signs, degrees
            )
        ii, ij, ik, jk, kk, kj, jj = (v[..., n] for n in range(7))
    # For R = R_i(a) R_j(b) R_k(c): R[i, k] = sign * sin(b)
    sb = lib.clip(sign * ik, -1.0, 1.0)
    b = lib.arcsin(sb)
    a = lib.arctan2(-sign * jk, kk)
    c = lib.arctan2(-sign * ij, ii)
    # gimbal lock: cos(b) ~ 0, put everything in a
    cb = lib.sqrt(ii**2 + ij**2)
    locked = cb < 1e-6
    if bool(locked.any()):
        a_locked = lib.arctan2(sign * kj, jj)
        a = lib.where(locked, a_locked, a)
        c = lib.where(locked, lib.zeros_like(c), c)
    out = _stack([a, b, c], -1, matrix)
    if degrees:
        out = out * (180.0 / math.pi)
    return out


def head_angles(R: Array) -> Array:
    """ARKit-style head angles (yaw, pitch, roll) in radians (…, 3) of head → camera rotations (…, 3, 3).

    ``R = R_Y(yaw) @ R_X(pitch) @ R_Z(roll)`` (:func:`matrix_to_euler` with order ``"YXZ"``): yaw > 0
    turns the face towards the image's right, pitch > 0 tilts it down, roll > 0 tilts it
    counter-clockwise as the camera sees it (:mod:`facecapges.capture.head_pose` has the frames).
    """
    if not _is_torch(R):
        R = np.asarray(R, np.float64)
    return matrix_to_euler(R, "YXZ")


def angles_to_matrix(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """The head → camera rotation (3, 3) of ARKit-style angles in radians: the inverse of :func:`head_angles`."""
    return euler_to_matrix(np.array([yaw, pitch, roll], np.float64), "YXZ")


def _euler_from_entries(v: np.ndarray, signs: np.ndarray, degrees: bool) -> np.ndarray:
    """:func:`matrix_to_euler`'s angles from each matrix's entries (..., J, 7) = R[j,k], R[i,j],
    R[k,k], R[i,i], R[i,k], R[k,j], R[j,j] and their signs (J, 7) (:func:`_orders_take`): the
    same formulas in fewer NumPy calls (the per-frame BVH conversion of a stream runs it on 47 joints)."""
    s = v * signs
    ac = np.arctan2(s[..., 0:2], s[..., 2:4])  # a, c: atan2(-sign R[j,k], R[k,k]), atan2(-sign R[i,j], R[i,i])
    out = np.empty(v.shape[:-1] + (3,))
    out[..., 1] = np.arcsin(np.clip(s[..., 4], -1.0, 1.0))
    locked = np.hypot(v[..., 3], v[..., 1]) < 1e-6  # gimbal lock: cos(b) ~ 0, put everything in a
    if locked.any():
        ac[..., 0] = np.where(locked, np.arctan2(s[..., 5], s[..., 6]), ac[..., 0])
        ac[..., 1] = np.where(locked, 0.0, ac[..., 1])
    out[..., ::2] = ac
    if degrees:
        out *= 180.0 / math.pi
    return out


@functools.lru_cache(maxsize=64)
def _orders_take(orders: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Per order: the flat indices into its matrix's 9 entries, offset by 9 per joint, of R[j,k],
    R[i,j], R[k,k], R[i,i], R[i,k], R[k,j], R[j,j] (J, 7), and the signs they take (J, 7)
    (−sign, −sign, 1, 1, sign, sign, 1) — for :func:`_euler_from_entries`."""
    rows, cols, sign = _orders_index(orders)
    one = np.ones_like(sign)
    signs = np.stack([-sign, -sign, one, one, sign, sign, one], -1)
    return (rows * 9 + cols)[:, [3, 1, 4, 0, 2, 5, 6]], signs


@functools.lru_cache(maxsize=64)
def _orders_index(orders: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per order: row numbers (J, 1), the flat indices of R[i,i], R[i,j], R[i,k], R[j,k],
    R[k,k], R[k,j], R[j,j] (J, 7), and the permutation's sign (J,) — for :func:`matrix_to_euler`."""
    ijk = np.array([["XYZ".index(a) for a in _check_order(o)] for o in orders], np.int64).reshape(-1, 3)
    i, j, k = ijk.T
    cols = np.stack([3 * r + c for r, c in ((i, i), (i, j), (i, k), (j, k), (k, k), (k, j), (j, j))], 1)
    return np.arange(len(ijk))[:, None], cols, np.where((j - i) % 3 == 1, 1.0, -1.0)


# ------------------------------------------------------------------------- rot6d
def matrix_to_rot6d(matrix: Array) -> Array:
    """Matrices (..., 3, 3) → rot6d (..., 6): first column then second column."""
    _check_last(matrix, (3, 3), "matrix")
    cols = [matrix[..., :, 0], matrix[..., :, 1]]
    return _torch().cat(cols, dim=-1) if _is_torch(matrix) else np.concatenate(cols, axis=-1)


def rot6d_to_matrix(rot6d: Array) -> Array:
    """rot6d (..., 6) → rotation matrices (..., 3, 3) by Gram–Schmidt (eq. 2.6–2.9).

    Works for any non-degenerate 6-vector (network outputs need not be orthonormal).
    """
    _check_last(rot6d, (6,), "rot6d")
    a, b = rot6d[..., :3], rot6d[..., 3:]
    if not _is_torch(rot6d):  # the same steps in fewer NumPy calls (one frame of a stream: 47 small rows)
        u1 = a / np.maximum(np.sqrt(np.einsum("...i,...i->...", a, a))[..., None], _EPS)
        v2 = b - np.einsum("...i,...i->...", u1, b)[..., None] * u1
        m = np.empty(u1.shape + (3,), u1.dtype)  # the columns written in place (np.stack's work, fewer calls)
        np.divide(v2, np.maximum(np.sqrt(np.einsum("...i,...i->...", v2, v2))[..., None], _EPS), out=m[..., 1])
        m[..., 0] = u1
        u2, i, j = m[..., 1], _CROSS_I, _CROSS_J
        np.subtract(u1.take(i, -1) * u2.take(j, -1), u1.take(j, -1) * u2.take(i, -1), out=m[..., 2])  # _cross
        return m
    u1 = a / _maximum(_norm(a), _EPS)
    dot = (u1 * b).sum(-1, keepdims=True) if not _is_torch(b) else (u1 * b).sum(-1, keepdim=True)
    v2 = b - dot * u1
    u2 = v2 / _maximum(_norm(v2), _EPS)
    u3 = _cross(u1, u2)
    return _stack([u1, u2, u3], -1, rot6d)


def normalize_rot6d(rot6d: Array) -> Array:
    """Project any 6-vector onto the valid rot6d manifold (orthonormal columns)."""
    return matrix_to_rot6d(rot6d_to_matrix(rot6d))


def angular_acceleration(rot6d: np.ndarray, fps: float) -> np.ndarray:
    """Angular acceleration of each rotation of a sequence rot6d (T, ..., 6) along time: (T, ...).

    ``‖R_{t+1} − 2R_t + R_{t−1}‖_F · fps² / √2`` (rad/s² for small steps); the first and last frame
    (no second difference) are 0. The one formula behind the pop rule (``evaluation.realism``) and
    the captured-motion limiter (``capture.body_solve.smooth_for_style``)."""
    R = rot6d_to_matrix(np.asarray(rot6d, dtype=np.float64))
    acc = np.zeros(R.shape[:-2])
    if len(R) >= 3:
        d2 = R[2:] - 2.0 * R[1:-1] + R[:-2]
        acc[1:-1] = np.sqrt((d2**2).sum((-1, -2))) * fps**2 / np.sqrt(2.0)
    return acc


def euler_to_rot6d(euler: Array, order: str, degrees: bool = False) -> Array:
    """Euler angles (..., 3) → rot6d (..., 6)."""
    return matrix_to_rot6d(euler_to_matrix(euler, order, degrees))


def rot6d_to_euler(rot6d: Array, order: str, degrees: bool = False) -> Array:
    """rot6d (..., 6) → Euler angles (..., 3) in ``order``."""
    return matrix_to_euler(rot6d_to_matrix(rot6d), order, degrees)


def identity_rot6d(shape: tuple[int, ...] = ()) -> np.ndarray:
    """The rest rotation as rot6d, float32, shape ``shape + (6,)``."""
    return np.broadcast_to(np.array([1, 0, 0, 0, 1, 0], np.float32), tuple(shape) + (6,)).copy()


# -------------------------------------------------------------------- quaternion
def matrix_to_quaternion(matrix: Array) -> Array:
    """Matrices (..., 3, 3) → unit quaternions (..., 4) as (w, x, y, z), w ≥ 0."""
    _check_last(matrix, (3, 3), "matrix")
    m = matrix
    if not _is_torch(m):
        return _matrix_to_quaternion_np(np.asarray(m))
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    # four candidate |components|, all computed, best-conditioned one picked
    w2 = 1 + m00 + m11 + m22
    x2 = 1 + m00 - m11 - m22
    y2 = 1 - m00 + m11 - m22
    z2 = 1 - m00 - m11 + m22
    cands = _stack([w2, x2, y2, z2], -1, matrix)
    best = cands.argmax(-1) if _is_torch(m) else np.argmax(cands, axis=-1)
    r21, r12 = m[..., 2, 1], m[..., 1, 2]
    r02, r20 = m[..., 0, 2], m[..., 2, 0]
    r10, r01 = m[..., 1, 0], m[..., 0, 1]

    def from_(s2: Array, comps: list[Array]) -> Array:
        # the chosen component is sqrt(s2)/2; the others follow from off-diagonals
        s = _sqrt(_maximum(s2, _EPS)) * 2.0
        return _stack([c / s for c in comps], -1, matrix)

    qw = from_(w2, [w2, r21 - r12, r02 - r20, r10 - r01])
    qx = from_(x2, [r21 - r12, x2, r01 + r10, r02 + r20])
    qy = from_(y2, [r02 - r20, r01 + r10, y2, r12 + r21])
    qz = from_(z2, [r10 - r01, r02 + r20, r12 + r21, z2])
    allq = _stack([qw, qx, qy, qz], -2, matrix)  # (..., 4 candidates, 4)
    q: Any  # a torch tensor or a NumPy array, as the input
    if _is_torch(m):
        q = _torch().gather(allq, -2, best[..., None, None].expand(*best.shape, 1, 4)).squeeze(-2)
        q = _torch().where(q[..., :1] < 0, -q, q)
    else:
        q = np.take_along_axis(allq, best[..., None, None], axis=-2)[..., 0, :]
        q = np.where(q[..., :1] < 0, -q, q)
    return q / _maximum(_norm(q), _EPS)


# _matrix_to_quaternion_np's constants: the signs of the diagonal in w², x², y², z²; the off-diagonal pairs
# (flat indices) whose differences / sums a b c / d e f are; each candidate row's four of [w² x² y² z² a b c d e f]
_DIAG_SIGNS = np.array([[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]])
_OFF_I, _OFF_J = np.array([7, 2, 3, 1, 2, 5]), np.array([5, 6, 1, 3, 6, 7])
_OFF_SIGNS = np.array([-1.0, -1.0, -1.0, 1.0, 1.0, 1.0])
_CAND_ROWS = np.array([[0, 4, 5, 6], [4, 1, 7, 8], [5, 7, 2, 9], [6, 8, 9, 3]])
_DIAG = np.array([0, 4, 8])  # the diagonal's flat indices
_SIGNS_OF = {np.dtype(t).char: (_DIAG_SIGNS.astype(t), _OFF_SIGNS.astype(t)) for t in (np.float64, np.float32)}


def _matrix_to_quaternion_np(m: np.ndarray) -> np.ndarray:
    """:func:`matrix_to_quaternion` for NumPy in fewer calls (one frame of a stream is a few dozen
    small matrices, where the calls are the cost): the four candidates' squares ``1 ± m00 ± m11 ± m22``
    (left to right; ``x − y`` is ``x + (−y)``) and the off-diagonal sums and differences each in one call,
    the chosen candidate's four numbers picked by one index, then scaled — the same operations on the same
    numbers, so the same result (``test_rotations``: the bits of the component-wise formula)."""
    lead = m.shape[:-2]
    flat = m.reshape(-1, 9)
    signs = _SIGNS_OF.get(m.dtype.char) or (_DIAG_SIGNS.astype(m.dtype), _OFF_SIGNS.astype(m.dtype))
    t = flat.take(_DIAG, axis=1)[:, None] * signs[0]  # ±m00 ±m11 ±m22 (exact, m's dtype)
    values = np.empty((len(flat), 10), np.result_type(1, t))  # [w² x² y² z² a b c d e f], written in place
    cands = values[:, :4]  # (n, 4): w² x² y² z²
    np.add(1 + t[..., 0] + t[..., 1], t[..., 2], out=cands)
    np.add(flat.take(_OFF_I, axis=1), flat.take(_OFF_J, axis=1) * signs[1], out=values[:, 4:])  # a b c d e f
    best = np.argmax(cands, axis=-1)
    rows = np.arange(len(flat))
    q = values[rows[:, None], _CAND_ROWS[best]]
    q = q / (np.sqrt(np.maximum(cands[rows, best][:, None], _EPS)) * 2.0)
    q = np.where(q[..., :1] < 0, -q, q)
    q = q / np.maximum(vector_norm(q, keepdims=True), _EPS)
    return q.reshape(lead + (4,))


def quaternion_to_matrix(quat: Array) -> Array:
    """Quaternions (..., 4) as (w, x, y, z) → matrices (..., 3, 3). Normalises first."""
    _check_last(quat, (4,), "quaternion")
    q = quat / _maximum(_norm(quat), _EPS)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [
        1 - 2 * (y * y + z * z),
        2 * (x * y - z * w),
        2 * (x * z + y * w),
        2 * (x * y + z * w),
        1 - 2 * (x * x + z * z),
        2 * (y * z - x * w),
        2 * (x * z - y * w),
        2 * (y * z + x * w),
        1 - 2 * (x * x + y * y),
    ]
    return _stack(rows, -1, quat).reshape(tuple(quat.shape[:-1]) + (3, 3))


def quaternion_to_rot6d(quat: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) as (w, x, y, z) → rot6d (..., 6); numpy only. Normalises first.

    ``matrix_to_rot6d(quaternion_to_matrix(quat))`` to the bit (the same expressions for the six entries
    rot6d keeps), without the third column and the intermediate matrices: the matching engine's last step.
    """
    _check_last(quat, (4,), "quaternion")
    q = quat / np.maximum(vector_norm(quat, keepdims=True), _EPS)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(q.shape[:-1] + (6,), q.dtype)
    zz, xy, zw = z * z, x * y, z * w  # each used twice
    out[..., 0] = 1 - 2 * (y * y + zz)
    out[..., 1] = 2 * (xy + zw)
    out[..., 2] = 2 * (x * z - y * w)
    out[..., 3] = 2 * (xy - zw)
    out[..., 4] = 1 - 2 * (x * x + zz)
    out[..., 5] = 2 * (y * z + x * w)
    return out


def rot6d_to_quaternion(rot6d: Array) -> Array:
    """rot6d (..., 6) → quaternion (..., 4), (w, x, y, z)."""
    return matrix_to_quaternion(rot6d_to_matrix(rot6d))


def quaternion_to_unity(quat: Array) -> Array:
    """Right-handed Y-up quaternion (w, x, y, z) → Unity's left-handed frame (X mirrored).

    Returns (w, x, y, z) in Unity's axes; Unity/VMC messages list it as (x, y, z, w).
    """
    _check_last(quat, (4,), "quaternion")
    sign = np.array([1.0, 1.0, -1.0, -1.0], dtype=np.float64)
    if _is_torch(quat):
        return quat * _torch().as_tensor(sign, dtype=quat.dtype, device=quat.device)
    return quat * sign.astype(np.asarray(quat).dtype)


def geodesic_angle(r1: Array, r2: Array) -> Array:
    """Angle in radians between rotation matrices (..., 3, 3), in [0, π].

    ``atan2(sin θ, cos θ)`` of ``R = r1ᵀ r2``, with ``2 sin θ = |vee(R − Rᵀ)|`` and ``2 cos θ = tr R − 1``:
    accurate at small angles too (the arccos of the trace alone keeps only ~1e-8 rad there).
    """
    lib = _torch() if _is_torch(r1) else np
    rel = r1.transpose(-1, -2) @ r2 if _is_torch(r1) else np.swapaxes(r1, -1, -2) @ r2
    vee = _stack(
        [rel[..., 2, 1] - rel[..., 1, 2], rel[..., 0, 2] - rel[..., 2, 0], rel[..., 1, 0] - rel[..., 0, 1]], -1, rel
    )
    cos = (rel[..., 0, 0] + rel[..., 1, 1] + rel[..., 2, 2] - 1.0) / 2.0
    return lib.arctan2(_norm(vee)[..., 0] / 2.0, cos)


# ------------------------------------------------------------- quaternion algebra
# the Hamilton product's terms: component k's m-th term is a_i b_j at [k, m] = 4 i + j, with its sign
_QMUL_TERMS = np.array([[0, 5, 10, 15], [1, 4, 11, 14], [2, 7, 8, 13], [3, 6, 9, 12]])
_QMUL_SIGNS = np.array([[1, -1, -1, -1], [1, 1, 1, -1], [1, -1, 1, 1], [1, 1, -1, 1]], np.float64)
_QMUL_A, _QMUL_B = _QMUL_TERMS // 4, _QMUL_TERMS % 4  # the a and b component of each term
_QMUL_SIGNS_OF = {np.dtype(t).char: _QMUL_SIGNS.astype(t) for t in (np.float64, np.float32)}
_QMUL_SMALL = 4 * 47 * 4  # up to this many numbers the one-call form is the faster (4 poses: 26 against 34 µs)


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a · b`` of quaternions (…, 4), (w, x, y, z), broadcast; numpy only.

    The rotation of ``a · b`` is ``quaternion_to_matrix(a) @ quaternion_to_matrix(b)`` (``b`` first).
    """
    a, b = np.asarray(a), np.asarray(b)
    # both paths give the same bits: the size picks the faster (the larger operand's, without broadcast_shapes)
    if max(a.size, b.size) > _QMUL_SMALL:  # many quaternions: per component (the gather below costs more there)
        shape = np.broadcast_shapes(a.shape, b.shape)
        aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
        bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
        out = np.empty(shape, np.result_type(a, b))  # fewer calls than moveaxis + stack
        out[..., 0] = aw * bw - ax * bx - ay * by - az * bz
        out[..., 1] = aw * bx + ax * bw + ay * bz - az * by
        out[..., 2] = aw * by - ax * bz + ay * bw + az * bx
        out[..., 3] = aw * bz + ax * by - ay * bx + az * bw
        return out
    # few (one stream's 47 joints): all 16 products in one call, each term's sign applied exactly (x − y is
    # x + (−y) in IEEE arithmetic), three additions left to right: the same bits in a few calls instead of ~36
    # (each factor gathered into place, then add.reduce, which sums 4 numbers left to right: 5 calls)
    terms = a[..., _QMUL_A] * b[..., _QMUL_B]  # (…, 4 components, 4 terms): a_i b_j
    sign = _QMUL_SIGNS_OF.get(terms.dtype.char)
    terms *= _QMUL_SIGNS.astype(terms.dtype) if sign is None else sign
    return np.add.reduce(terms, axis=-1)


def quaternion_invert(q: np.ndarray) -> np.ndarray:
    """The inverse rotations of unit quaternions (…, 4): the conjugates (w, −x, −y, −z); numpy only."""
    conj = _CONJ_OF.get(q.dtype.char) if isinstance(q, np.ndarray) else None
    return q * (np.array([1.0, -1.0, -1.0, -1.0], q.dtype) if conj is None else conj)


_CONJ_OF = {np.dtype(t).char: np.array([1.0, -1.0, -1.0, -1.0], t) for t in (np.float64, np.float32)}


def standardize_quaternion(q: np.ndarray) -> np.ndarray:
    """The same rotations (…, 4) written with w ≥ 0 (the short way round); numpy only."""
    return np.where(q[..., :1] < 0, -q, q)


def quaternion_log(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (…, 4) → rotation vectors (…, 3) (angle · axis, radians); numpy only.

    The angle is in [0, 2π); it is at most π for a quaternion with w ≥ 0
    (:func:`standardize_quaternion`). The quaternion form of :func:`log_so3`, batched.
    """
    w = q[..., 0]
    v = q[..., 1:]
    s = vector_norm(v)
    angle = 2.0 * np.arctan2(s, w)
    k = angle / np.maximum(s, 1e-12)
    big = s > 1e-9
    if not big.all():  # (else every angle is far from 0: the limit below is not needed, the same numbers)
        k = np.where(big, k, 2.0 / np.where(np.abs(w) > 1e-12, w, 1.0))
    return v * k[..., None]


def quaternion_exp(r: np.ndarray) -> np.ndarray:
    """Rotation vectors (…, 3) (angle · axis, radians) → unit quaternions (…, 4); numpy only.

    The inverse of :func:`quaternion_log`; the quaternion form of :func:`exp_so3`, batched.
    """
    r = np.asarray(r)
    angle = vector_norm(r)
    half = 0.5 * angle
    k = np.sin(half) / np.maximum(angle, 1e-12)
    big = angle > 1e-9
    if not big.all():  # (else the small-angle series below is not needed: the same numbers)
        k = np.where(big, k, 0.5 - angle**2 / 48.0)
    out = np.empty(angle.shape + (4,), np.result_type(half, r))
    np.cos(half, out=out[..., 0])
    np.multiply(r, k[..., None], out=out[..., 1:])
    return out


def continuous_quaternions(q: np.ndarray) -> np.ndarray:
    """A sequence of quaternions (T, …, 4) with each key's sign chosen so that consecutive keys have a
    non-negative dot product (the first key kept): the same rotations, and a linear or slerp
    interpolation between keys (glTF ``LINEAR``) takes the short way; numpy only."""
    q = np.asarray(q)
    if len(q) < 2:
        return q.copy()
    step = np.where(np.sum(q[1:] * q[:-1], axis=-1) < 0, -1.0, 1.0)  # flip relative to the previous key
    sign = np.concatenate([np.ones_like(step[:1]), np.cumprod(step, axis=0)])
    return q * sign[..., None].astype(q.dtype)


# --------------------------------------------------------------------- averaging
def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation matrix (…, 3, 3) nearest (Frobenius) to each 3×3 matrix ``M`` (…, 3, 3); numpy only.

    ``U diag(1, 1, d) Vᵀ`` from the SVD ``M = U Σ Vᵀ``, ``d = sign det(U Vᵀ)`` (a reflection is
    turned into the nearest proper rotation). Strips a scale or shear from a transform's 3×3 block.
    """
    u, _, vt = np.linalg.svd(np.asarray(M, np.float64))
    d = np.sign(np.linalg.det(u @ vt))
    d = np.where(d == 0, 1.0, d)
    return (u * np.stack([np.ones_like(d), np.ones_like(d), d], -1)[..., None, :]) @ vt


def mean_rotation_matrix(R: np.ndarray) -> np.ndarray:
    """The chordal L2 mean (3, 3) of rotation matrices (…, 3, 3): their average projected onto SO(3)
    (:func:`nearest_rotation`); numpy only. (:func:`quaternion_mean` is the quaternion form.)"""
    return nearest_rotation(np.asarray(R, np.float64).reshape(-1, 3, 3).mean(0))


def mean_rotation(rot6d: np.ndarray) -> np.ndarray:
    """The chordal L2 mean (6,) of rotations given as rot6d (…, 6) (:func:`mean_rotation_matrix`)."""
    return matrix_to_rot6d(mean_rotation_matrix(rot6d_to_matrix(np.asarray(rot6d, np.float64).reshape(-1, 6))))


def quaternion_mean(q: np.ndarray) -> np.ndarray:
    """Per-joint mean rotation of samples (N, J, 4) → (J, 4), w ≥ 0; numpy only.

    The principal eigenvector of ``Σ q qᵀ`` (Markley et al. 2007): the quaternion chordal
    L2 mean, blind to each sample's sign. (:func:`mean_rotation` is the matrix chordal mean.)
    """
    M = np.einsum("nji,njk->jik", q, q)
    _, vec = np.linalg.eigh(M)
    return standardize_quaternion(vec[..., -1])


# --------------------------------------------------------------- SO(3) exp / log
def log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation matrices (…, 3, 3) → rotation vectors (…, 3): axis × angle, radians (0 … π).

    The angle is ``atan2(|v|/2, (tr R − 1)/2)`` with ``v`` the skew part, accurate at small angles; within
    1e-4 rad of π, where ``v`` vanishes, the axis comes from the diagonal (its sign from ``v``)."""
    R = np.asarray(R, np.float64)
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    sn = np.linalg.norm(v, axis=-1) / 2
    ang = np.arctan2(sn, (np.trace(R, axis1=-2, axis2=-1) - 1) / 2)
    out = v * np.where(sn > 1e-12, ang / np.maximum(2 * sn, 1e-300), 0.5)[..., None]
    near_pi = np.pi - ang < 1e-4
    if np.any(near_pi):
        axis = np.sqrt(np.maximum((np.diagonal(R, axis1=-2, axis2=-1) + 1) / 2, 0)) * (np.sign(v) + (v == 0))
        axis = axis / np.maximum(np.linalg.norm(axis, axis=-1, keepdims=True), 1e-12) * ang[..., None]
        out = np.where(near_pi[..., None], axis, out)
    return out


def exp_so3(v: np.ndarray) -> np.ndarray:
    """Rotation vectors (…, 3) (axis × angle, radians) → rotation matrices (…, 3, 3) (Rodrigues). One vector (3,)
    takes the same arithmetic without the stacking (the capture's pose smoother, once a frame: issue 36)."""
    v = np.asarray(v, np.float64)
    if v.shape == (3,):
        a = np.sqrt(np.add.reduce(v * v))  # np.linalg.norm(v)
        kx, ky, kz = (v / np.maximum(a, 1e-300)).tolist()
        K1 = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
        return np.eye(3) + np.sin(a) * K1 + (1 - np.cos(a)) * (K1 @ K1)
    ang = np.linalg.norm(v, axis=-1)[..., None, None]
    k = v / np.maximum(ang[..., 0], 1e-300)
    zero = np.zeros_like(k[..., 0])
    K = np.stack(
        [
            np.stack([zero, -k[..., 2], k[..., 1]], -1),
            np.stack([k[..., 2], zero, -k[..., 0]], -1),
            np.stack([-k[..., 1], k[..., 0], zero], -1),
        ],
        -2,
    )
    return np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * (K @ K)


def twist_angle(R: np.ndarray, axis: str = "X") -> np.ndarray:
    """Twist (radians, −π … π) of rotations (…, 3, 3) about the local ``axis`` (swing-twist decomposition)."""
    q = matrix_to_quaternion(R)
    return (2.0 * np.arctan2(q[..., 1 + "XYZ".index(axis)], q[..., 0]) + np.pi) % (2 * np.pi) - np.pi


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The shortest-arc rotation (..., 3, 3) taking direction ``a`` (..., 3) onto ``b`` (..., 3).

    ``R @ a/|a| = b/|b|`` and ``R`` turns about ``a × b`` only (no twist about either
    vector). Opposite vectors turn 180° about an axis perpendicular to ``a``; a zero
    vector gives the identity. numpy only.
    """
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    na, nb = np.linalg.norm(a, axis=-1, keepdims=True), np.linalg.norm(b, axis=-1, keepdims=True)
    degenerate = ((na < _EPS) | (nb < _EPS))[..., 0]
    a = a / np.maximum(na, _EPS)
    b = b / np.maximum(nb, _EPS)
    v = np.cross(a, b)
    c = (a * b).sum(-1)
    vx = np.zeros(a.shape[:-1] + (3, 3))
    vx[..., 0, 1], vx[..., 0, 2], vx[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    vx[..., 1, 0], vx[..., 2, 0], vx[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    opposite = c < -1.0 + 1e-9
    k = 1.0 / np.maximum(1.0 + c, 1e-9)
    R = np.eye(3) + vx + (vx @ vx) * k[..., None, None]
    if np.any(opposite):
        # any axis perpendicular to a: cross with the least-aligned principal axis
        helper = np.eye(3)[np.argmin(np.abs(a), axis=-1)]
        axis = np.cross(a, helper)
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        flip = 2.0 * axis[..., :, None] * axis[..., None, :] - np.eye(3)  # 180° about axis
        R = np.where(opposite[..., None, None], flip, R)
    return np.where(degenerate[..., None, None], np.eye(3), R)


# ----------------------------------------------- powers of a rotation about another
def quaternion_power_about(q: np.ndarray, ref: np.ndarray, power) -> np.ndarray:
    """``ref · (ref⁻¹ · q)^power``: rotations ``q`` (…, 4) raised to ``power`` about ``ref`` (…, 4); numpy only.

    The project's one rule for scaling a rotation about another and for interpolating between
    two: the rotation from ``ref`` to ``q`` is taken the short way round and its angle multiplied by
    ``power`` about the same axis. ``power = 0`` gives ``ref``, ``1`` gives ``q`` (up to sign),
    0 … 1 is the slerp from ``ref`` to ``q``, above 1 goes on past ``q`` along the same arc (a motion
    amplified about ``ref``: the intensity dial) and below 0 turns away from ``q``.

    ``power`` is a float or an array broadcastable to (…, 1) (one per quaternion). Quaternions are
    (w, x, y, z), unit (to float precision); the result is unit, float64, on ``ref``'s side
    (``ref · result ≥ 0`` for powers in [0, 1]). Callers: :func:`quaternion_slerp`,
    :func:`rot6d_slerp` (the model's intensity, :func:`facecapges.engine.intensity.scale_pose`),
    :func:`rotation_power_about` (matrices: the face-lost ease), the motion-matching intensity
    (:func:`facecapges.matching.inertialize.qpow_about`).
    """
    q = np.asarray(q, np.float64)
    ref = np.asarray(ref, np.float64)
    _check_last(q, (4,), "quaternion")
    _check_last(ref, (4,), "quaternion")
    # the geodesic through ref and q, in the closed form of the slerp (valid for any power):
    # (sin((1 − p)θ) · ref + sin(pθ) · q) / sin θ, θ the angle between ref and ±q (the nearer one)
    dot = np.add.reduce(ref * q, axis=-1, keepdims=True)  # np.sum's own reduction
    q = np.where(dot < 0.0, -q, q)
    theta = np.arccos(np.minimum(np.abs(dot), 1.0))  # np.clip(·, 0, 1) of a number ≥ 0
    s = np.sin(theta)
    small = s < 1e-6  # nearly equal rotations: the linear blend, normalised
    p = np.asarray(power, np.float64)
    if small.any():
        safe = np.where(small, 1.0, s)
        a = np.where(small, 1.0 - p, np.sin((1.0 - p) * theta) / safe)
        b = np.where(small, p, np.sin(p * theta) / safe)
    else:  # the same numbers without the linear blend's branch
        a, b = np.sin((1.0 - p) * theta) / s, np.sin(p * theta) / s
    out = a * ref + b * q
    return out / vector_norm(out, keepdims=True)  # np.linalg.norm's own arithmetic


def rotation_power_about(R: np.ndarray, ref: np.ndarray | None, power) -> np.ndarray:
    """``ref · (refᵀ · R)^power`` for rotation matrices (…, 3, 3) (``ref=None``: the identity, ``R^power``).

    :func:`quaternion_power_about` on matrices; numpy only, float64. ``power`` is a float or an array
    broadcastable to the matrices' leading shape + (1,). ``power = 0`` gives ``ref``,
    ``1`` gives ``R``, 0 … 1 the geodesic from ``ref`` to ``R`` (e.g. the face-lost ease of
    :mod:`facecapges.capture.face_lost`: ``rotation_power_about(R, None, k)`` eases ``R`` towards the
    identity, ``rotation_power_about(B, A, k)`` goes ``k`` of the way from ``A`` to ``B``).
    """
    R = np.asarray(R, np.float64)
    if ref is not None:
        ref = np.asarray(ref, np.float64)
        R = np.swapaxes(ref, -1, -2) @ R  # the rotation relative to ref, raised about the identity
    q = quaternion_power_about(matrix_to_quaternion(R), np.array([1.0, 0.0, 0.0, 0.0]), power)
    return quaternion_to_matrix(q) if ref is None else ref @ quaternion_to_matrix(q)


def quaternion_slerp(q0: np.ndarray, q1: np.ndarray, t) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (..., 4), (w, x, y, z); numpy only.

    ``t`` is a float or an array broadcastable to (..., 1) (one fraction per quaternion).
    Takes the shorter arc; ``t = 0`` gives ``q0``, ``t = 1`` gives ``q1`` (up to sign), and
    ``t > 1`` goes on past ``q1``. It is :func:`quaternion_power_about` ``(q1, q0, t)``.
    """
    return quaternion_power_about(q1, q0, t)


def rot6d_slerp(r0: np.ndarray, r1: np.ndarray, t) -> np.ndarray:
    """Per rotation, the slerp from ``r0`` to ``r1`` (both rot6d (..., 6)) at fraction ``t``; numpy only.

    ``t`` is a float or an array broadcastable to (..., 1). ``t = 0`` gives ``r0``, ``t = 1``
    gives ``r1``, and ``t > 1`` goes on past ``r1`` along the same arc (a motion amplified about
    ``r0``); the result is rot6d (..., 6) float64. :func:`quaternion_power_about` ``(r1, r0, t)``.
    """
    q0 = rot6d_to_quaternion(np.asarray(r0, np.float64))
    q1 = rot6d_to_quaternion(np.asarray(r1, np.float64))
    return matrix_to_rot6d(quaternion_to_matrix(quaternion_power_about(q1, q0, t)))
