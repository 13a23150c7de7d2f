"""The quaternions of a served tick, compiled: ``rotations.rot6d_to_quaternion`` on float64, to the bit.

``serve``'s model process turns each tick's poses (rot6d, float32) into the quaternions the ``pose`` messages
carry. NumPy's formula (:func:`facecapges.rotations.rot6d_to_matrix`, then ``matrix_to_quaternion``) runs a few
dozen calls over the tick's (B·47) rows and was ~12 % of the model process's CPU at 100–300 streams a tick; here it
is one loop over the rows doing the same operations on the same numbers in the same order — Gram–Schmidt (each
dot product summed left to right from zero, as NumPy's ``einsum`` does), the cross product, the four candidate
squares ``1 ± m00 ± m11 ± m22`` left to right, the first largest chosen, its four numbers divided by
``2·sqrt(max(·, 1e-8))``, the sign made w ≥ 0, the norm's squares summed left to right — without fused
multiply-adds (Numba's default), so every quaternion is NumPy's bit for bit (``tests/test_serve_batched.py``
compares them on random rows, degenerate ones and a tick's real poses; :func:`converter` checks them again on
this machine before the model process uses them). Imported by the model process only (the server's own process
never loads Numba); the machine code is cached beside this file (``cache=True``), loaded (or compiled) by
:func:`converter` before the model process says it is ready.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numba
import numpy as np

EPS = 1e-8  # rotations._EPS


@numba.njit(cache=True, nogil=True, inline="always")
def _maximum(x: float, y: float) -> float:
    """``np.maximum`` of two floats: a NaN wins."""
    if math.isnan(x) or x >= y:
        return x
    return y


@numba.njit(cache=True, nogil=True, error_model="numpy")
def rot6d_to_quaternions(r6: np.ndarray, out: np.ndarray) -> None:
    """Rows of rot6d ``r6`` (n, 6), any float dtype → unit quaternions ``out`` (n, 4) float64, (w, x, y, z), w ≥ 0:
    ``rotations.rot6d_to_quaternion(r6.astype(np.float64))``'s numbers (module docs)."""
    for n in range(r6.shape[0]):
        a0, a1, a2 = np.float64(r6[n, 0]), np.float64(r6[n, 1]), np.float64(r6[n, 2])
        b0, b1, b2 = np.float64(r6[n, 3]), np.float64(r6[n, 4]), np.float64(r6[n, 5])
        d = _maximum(math.sqrt(0.0 + ((a0 * a0 + a2 * a2) + a1 * a1)), EPS)
        u0, u1, u2 = a0 / d, a1 / d, a2 / d  # the first column
        dot = 0.0 + ((u0 * b0 + u2 * b2) + u1 * b1)
        v0, v1, v2 = b0 - dot * u0, b1 - dot * u1, b2 - dot * u2
        d = _maximum(math.sqrt(0.0 + ((v0 * v0 + v2 * v2) + v1 * v1)), EPS)
        w0, w1, w2 = v0 / d, v1 / d, v2 / d  # the second
        c0, c1, c2 = u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0  # the third: their cross product
        # the matrix's rows are (u0 w0 c0), (u1 w1 c1), (u2 w2 c2): m00 = u0, m11 = w1, m22 = c2
        cw = ((1.0 + u0) + w1) + c2
        cx = ((1.0 + u0) + -w1) + -c2
        cy = ((1.0 + -u0) + w1) + -c2
        cz = ((1.0 + -u0) + -w1) + c2
        best, top = 0, cw  # np.argmax: the first largest; a NaN is taken at once
        if not math.isnan(top) and (math.isnan(cx) or cx > top):
            best, top = 1, cx
        if not math.isnan(top) and (math.isnan(cy) or cy > top):
            best, top = 2, cy
        if not math.isnan(top) and (math.isnan(cz) or cz > top):
            best, top = 3, cz
        a, b, c = w2 - c1, c0 - u2, u1 - w0  # m21 − m12, m02 − m20, m10 − m01
        e, f, g = w0 + u1, c0 + u2, c1 + w2  # m01 + m10, m02 + m20, m12 + m21
        if best == 0:
            q0, q1, q2, q3 = cw, a, b, c
        elif best == 1:
            q0, q1, q2, q3 = a, cx, e, f
        elif best == 2:
            q0, q1, q2, q3 = b, e, cy, g
        else:
            q0, q1, q2, q3 = c, f, g, cz
        s = math.sqrt(_maximum(top, EPS)) * 2.0
        q0, q1, q2, q3 = q0 / s, q1 / s, q2 / s, q3 / s
        if q0 < 0:
            q0, q1, q2, q3 = -q0, -q1, -q2, -q3
        d = _maximum(math.sqrt(((q0 * q0 + q1 * q1) + q2 * q2) + q3 * q3), EPS)
        out[n, 0], out[n, 1], out[n, 2], out[n, 3] = q0 / d, q1 / d, q2 / d, q3 / d


def converter() -> Callable[[np.ndarray, np.ndarray], None]:
    """What the model process converts a tick with, ``(rot6d (n, 6), out (n, 4) float64)``: the compiled loop
    once it has given NumPy's bits on this machine — checked here on 4,000 rows (random rotations, any 6-vectors,
    signed zeros, tiny and near-180° ones), because NumPy's ``einsum`` sums in the order its SIMD loops take, which
    another build or CPU may change — else NumPy's own formula."""
    from facecapges import rotations as rot

    rng = np.random.default_rng(0)
    q = rng.standard_normal((1000, 4))
    rows = [
        rot.quaternion_to_rot6d(q / np.linalg.norm(q, axis=1, keepdims=True)),
        rng.standard_normal((1000, 6)),
        rng.choice(np.array([0.0, -0.0, 1.0, -1.0, 0.5, -0.5, 1e-9, -1e-9]), size=(1000, 6)),
        rng.standard_normal((1000, 6)) * 1e-5,
    ]
    r6 = np.concatenate(rows).astype(np.float32)
    want = rot.rot6d_to_quaternion(r6.astype(np.float64))
    got = np.empty_like(want)
    rot6d_to_quaternions(r6, got)
    if np.array_equal(want.view(np.uint64), got.view(np.uint64)):
        return rot6d_to_quaternions
    return _numpy


def _numpy(r6: np.ndarray, out: np.ndarray) -> None:
    from facecapges import rotations as rot

    out[:] = rot.rot6d_to_quaternion(np.asarray(r6, np.float64))
