"""The rotation maths of the compiled loops (Numba), one copy: the conventions of :mod:`facecapges.rotations`.

Quaternions are ``(w, x, y, z)`` as there. Each function here is the scalar form of one of
:mod:`facecapges.rotations`' NumPy formulas, for compiled callers (the matching engine's
:mod:`facecapges.matching.kernels`): the same expressions in the same order, so the same values — to ~1 ulp where
libm's transcendental functions stand in for NumPy's own SIMD ones.

Numba is imported here: a module that only converts rotations imports :mod:`facecapges.rotations`; the compiled
callers import this one when they are built (``serve``'s server process and a command's error path never load
Numba). The machine code is cached beside the callers' files (``cache=True``; Numba re-checks only the caller's own
file: after an edit here, clear the callers' ``__pycache__`` or run ``make setup``).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def _qmul(a: np.ndarray, bw: float, bx: float, by: float, bz: float, out: np.ndarray) -> None:
    """``out ← a · (bw, bx, by, bz)``: :func:`facecapges.rotations.quaternion_multiply`'s sums."""
    aw, ax, ay, az = a[0], a[1], a[2], a[3]
    out[0] = aw * bw - ax * bx - ay * by - az * bz
    out[1] = aw * bx + ax * bw + ay * bz - az * by
    out[2] = aw * by - ax * bz + ay * bw + az * bx
    out[3] = aw * bz + ax * by - ay * bx + az * bw


@_jit
def qmul(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out ← a · b`` of one pair of quaternions (4,)."""
    _qmul(a, b[0], b[1], b[2], b[3], out)


@_jit
def qmul_conj(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out ← a · b⁻¹`` of unit quaternions (4,): :func:`qmul` with b's conjugate (no array made: it runs in the
    engine's per-row loops)."""
    _qmul(a, b[0], -b[1], -b[2], -b[3], out)


@_jit
def qlog_abs(q: np.ndarray, out: np.ndarray) -> None:
    """``out ← log(q)`` (3,) of ``q`` (4,) written with w ≥ 0: ``qlog(qabs(q))`` (:mod:`facecapges.rotations`)."""
    sign = -1.0 if q[0] < 0 else 1.0
    w, x, y, z = sign * q[0], sign * q[1], sign * q[2], sign * q[3]
    s = np.sqrt(x * x + y * y + z * z)
    angle = 2.0 * np.arctan2(s, w)
    k = angle / max(s, 1e-12)
    if not s > 1e-9:
        k = 2.0 / (w if abs(w) > 1e-12 else 1.0)
    out[0], out[1], out[2] = x * k, y * k, z * k


@_jit
def qexp(r: np.ndarray, out: np.ndarray) -> None:
    """``out ← exp(r)`` (4,) of a rotation vector (3,) (:func:`facecapges.rotations.quaternion_exp`)."""
    angle = np.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
    half = 0.5 * angle
    k = np.sin(half) / max(angle, 1e-12)
    if not angle > 1e-9:
        k = 0.5 - angle**2 / 48.0
    out[0], out[1], out[2], out[3] = np.cos(half), r[0] * k, r[1] * k, r[2] * k


_EPS = 1e-8  # :mod:`facecapges.rotations`' floor of a norm


@_jit
def quaternion_to_matrix(q: np.ndarray, out: np.ndarray) -> None:
    """``out`` (3, 3) ← the rotation of the quaternion ``q`` (4,), normalised first: the bits of
    :func:`facecapges.rotations.quaternion_to_matrix` (its norm summed left to right, its nine expressions)."""
    n = np.sqrt(((q[0] * q[0] + q[1] * q[1]) + q[2] * q[2]) + q[3] * q[3])
    if n < _EPS:  # np.maximum(n, _EPS) (a NaN stays)
        n = _EPS
    w, x, y, z = q[0] / n, q[1] / n, q[2] / n, q[3] / n
    out[0, 0] = 1 - 2 * (y * y + z * z)
    out[0, 1] = 2 * (x * y - z * w)
    out[0, 2] = 2 * (x * z + y * w)
    out[1, 0] = 2 * (x * y + z * w)
    out[1, 1] = 1 - 2 * (x * x + z * z)
    out[1, 2] = 2 * (y * z - x * w)
    out[2, 0] = 2 * (x * z - y * w)
    out[2, 1] = 2 * (y * z + x * w)
    out[2, 2] = 1 - 2 * (x * x + y * y)


def _fma_intrinsic(typingctx, a, b, c):
    """``a · b + c`` rounded once (LLVM's ``llvm.fma.f64``: the FMA instruction where the CPU has one)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        d = ir.DoubleType()
        return builder.call(builder.module.declare_intrinsic("llvm.fma", [d], ir.FunctionType(d, [d, d, d])), args)

    return sig, codegen


_fma: Any = intrinsic(_fma_intrinsic)  # called in compiled code as _fma(a, b, c)


@_jit
def matmul3(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out ← a @ b`` of 3 × 3 matrices (``out`` not ``a`` or ``b``) as NumPy's ``@`` computes it here (OpenBLAS's
    kernel): each entry from ``+0``, then ``+ a_i0 b_0j``, ``+ a_i1 b_1j`` and ``+ a_i2 b_2j``, each fused (one rounding;
    the ``+0`` makes a product's ``−0`` a ``+0``): its bits,
    held by ``tests/test_rotations_compiled.py`` (a machine whose BLAS sums otherwise would fail that test)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = _fma(a[i, 2], b[2, j], _fma(a[i, 1], b[1, j], _fma(a[i, 0], b[0, j], 0.0)))


@_jit
def _maximum(x: float, y: float) -> float:
    """``np.maximum`` of two floats: a NaN wins."""
    if np.isnan(x) or x >= y:
        return x
    return y


@_jit
def matrix_to_quaternion(m: np.ndarray, out: np.ndarray) -> None:
    """``out`` (4,) ← the unit quaternion, w ≥ 0, of the matrix ``m`` (3, 3): the bits of
    :func:`facecapges.rotations.matrix_to_quaternion` (the four candidates ``1 ± m00 ± m11 ± m22`` left to right, the
    first largest — a NaN first, as ``np.argmax`` — its four numbers, scaled, made w ≥ 0, normalised)."""
    m00, m11, m22 = m[0, 0], m[1, 1], m[2, 2]
    cw = ((1 + m00) + m11) + m22
    cx = ((1 + m00) + -m11) + -m22
    cy = ((1 + -m00) + m11) + -m22
    cz = ((1 + -m00) + -m11) + m22
    best, top = 0, cw  # np.argmax: the first largest; a NaN is taken at once
    if not np.isnan(top) and (np.isnan(cx) or cx > top):
        best, top = 1, cx
    if not np.isnan(top) and (np.isnan(cy) or cy > top):
        best, top = 2, cy
    if not np.isnan(top) and (np.isnan(cz) or cz > top):
        best, top = 3, cz
    a, b, d = m[2, 1] + -m[1, 2], m[0, 2] + -m[2, 0], m[1, 0] + -m[0, 1]
    e, f, g = m[0, 1] + m[1, 0], m[0, 2] + m[2, 0], m[1, 2] + m[2, 1]
    if best == 0:
        q0, q1, q2, q3 = cw, a, b, d
    elif best == 1:
        q0, q1, q2, q3 = a, cx, e, f
    elif best == 2:
        q0, q1, q2, q3 = b, e, cy, g
    else:
        q0, q1, q2, q3 = d, f, g, cz
    s = np.sqrt(_maximum(top, _EPS)) * 2.0
    q0, q1, q2, q3 = q0 / s, q1 / s, q2 / s, q3 / s
    if q0 < 0:
        q0, q1, q2, q3 = -q0, -q1, -q2, -q3
    n = _maximum(np.sqrt(((q0 * q0 + q1 * q1) + q2 * q2) + q3 * q3), _EPS)
    out[0], out[1], out[2], out[3] = q0 / n, q1 / n, q2 / n, q3 / n


@_jit
def rot6d_to_matrix(r6: np.ndarray, out: np.ndarray) -> None:
    """``out`` (3, 3) ← the rotation of one rot6d row ``r6`` (6,), any float dtype, in float64: the bits of
    :func:`facecapges.rotations.rot6d_to_matrix` (Gram–Schmidt, each dot product summed as NumPy's ``einsum`` does
    here: ``0 + ((x0 + x2) + x1)``, then the cross product; the columns are the two vectors and their cross)."""
    a0, a1, a2 = np.float64(r6[0]), np.float64(r6[1]), np.float64(r6[2])
    b0, b1, b2 = np.float64(r6[3]), np.float64(r6[4]), np.float64(r6[5])
    d = _maximum(np.sqrt(0.0 + ((a0 * a0 + a2 * a2) + a1 * a1)), _EPS)
    u0, u1, u2 = a0 / d, a1 / d, a2 / d  # the first column
    dot = 0.0 + ((u0 * b0 + u2 * b2) + u1 * b1)
    v0, v1, v2 = b0 - dot * u0, b1 - dot * u1, b2 - dot * u2
    d = _maximum(np.sqrt(0.0 + ((v0 * v0 + v2 * v2) + v1 * v1)), _EPS)
    w0, w1, w2 = v0 / d, v1 / d, v2 / d  # the second
    out[0, 0], out[1, 0], out[2, 0] = u0, u1, u2
    out[0, 1], out[1, 1], out[2, 1] = w0, w1, w2
    out[0, 2], out[1, 2], out[2, 2] = u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0


@_jit
def rot6d_to_quaternions(r6: np.ndarray, out: np.ndarray) -> None:
    """Rows of rot6d ``r6`` (n, 6), any float dtype → unit quaternions ``out`` (n, 4) float64, (w, x, y, z), w ≥ 0:
    ``rotations.rot6d_to_quaternion(r6.astype(np.float64))``'s numbers (:func:`rot6d_to_matrix`, then
    :func:`matrix_to_quaternion`)."""
    m = np.empty((3, 3))
    for n in range(r6.shape[0]):
        rot6d_to_matrix(r6[n], m)
        matrix_to_quaternion(m, out[n])


@_jit
def slerp(q0: np.ndarray, q1: np.ndarray, theta: float, t: float, out: np.ndarray) -> None:
    """``out`` (4,) ← the slerp ``t`` of the way from ``q0`` to ``q1`` (4,, any one order of the components), ``theta``
    the angle :func:`slerp_cosine` gives (its ``arccos``): the bits of :func:`facecapges.rotations.quaternion_slerp`
    (``quaternion_power_about``'s closed form)."""
    dot = 0.0
    for k in range(4):
        dot += q0[k] * q1[k]
    sign = -1.0 if dot < 0.0 else 1.0
    s = np.sin(theta)
    if s < 1e-6:  # nearly equal rotations: the linear blend, normalised
        a, b = 1.0 - t, t
    else:
        a, b = np.sin((1.0 - t) * theta) / s, np.sin(t * theta) / s
    for k in range(4):
        out[k] = a * q0[k] + b * (-q1[k] if sign < 0 else q1[k])
    n = np.sqrt(((out[0] * out[0] + out[1] * out[1]) + out[2] * out[2]) + out[3] * out[3])
    for k in range(4):
        out[k] = out[k] / n


@_jit
def slerp_cosine(q0: np.ndarray, q1: np.ndarray) -> float:
    """``min(|q0 · q1|, 1)`` of two quaternions (4,): the cosine whose ``np.arccos`` is :func:`slerp`'s ``theta``
    (NumPy's arccos here is its own SIMD one, not libm's: the caller takes it, to keep its bits)."""
    dot = 0.0
    for k in range(4):
        dot += q0[k] * q1[k]
    return min(abs(dot), 1.0)


@_jit
def matmul3_tn(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out ← aᵀ @ b`` of 3 × 3 matrices (``out`` not ``a`` or ``b``): NumPy's ``a.T @ b`` (OpenBLAS's kernel with
    the first matrix transposed) as :func:`matmul3` sums it, each entry ``+0`` then ``+ a_0i b_0j``, ``+ a_1i b_1j``,
    ``+ a_2i b_2j`` fused (held by ``tests/test_rotations_compiled.py``)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = _fma(a[2, i], b[2, j], _fma(a[1, i], b[1, j], _fma(a[0, i], b[0, j], 0.0)))


@_jit
def relative_quaternion(ref6: np.ndarray, r: np.ndarray, ref: np.ndarray, lq: np.ndarray, q: np.ndarray) -> float:
    """``ref`` (3, 3) ← the rotation of the rot6d row ``ref6``, ``lq`` (3, 3) ← ``refᵀ · r`` and ``q`` (4,) ← its unit
    quaternion (:func:`rot6d_to_matrix`, :func:`matmul3_tn`, :func:`matrix_to_quaternion`); returns the cosine
    ``min(|q · (1, 0, 0, 0)|, 1)`` whose ``np.arccos`` is the angle :func:`power_about_identity_rot6d` takes — the
    first steps of :func:`facecapges.rotations.quaternion_power_about` about the identity (NumPy's arccos is its
    own SIMD one, not libm's: the caller takes it, to keep its bits)."""
    rot6d_to_matrix(ref6, ref)
    matmul3_tn(ref, r, lq)
    matrix_to_quaternion(lq, q)
    dot = ((q[0] * 1.0 + q[1] * 0.0) + q[2] * 0.0) + q[3] * 0.0
    if dot < 0.0:  # np.where(dot < 0, -q, q) (w >= 0 already: never, but the formula's)
        q[0], q[1], q[2], q[3] = -q[0], -q[1], -q[2], -q[3]
    c = abs(dot)
    return 1.0 if c > 1.0 else c  # np.minimum(·, 1.0): a NaN stays


@_jit
def quaternion_to_rot6d(w0: float, x0: float, y0: float, z0: float) -> tuple:
    """The rot6d (six numbers) of the quaternion ``(w0, x0, y0, z0)``, normalised first: the bits of
    :func:`facecapges.rotations.quaternion_to_rot6d` (its norm summed left to right, at least 1e-8 with a NaN kept,
    the division, its six expressions)."""
    n = _maximum(np.sqrt(((w0 * w0 + x0 * x0) + y0 * y0) + z0 * z0), _EPS)
    w, x, y, z = w0 / n, x0 / n, y0 / n, z0 / n
    zz, xy, zw = z * z, x * y, z * w
    return (
        1.0 - 2.0 * (y * y + zz),
        2.0 * (xy + zw),
        2.0 * (x * z - y * w),
        2.0 * (xy - zw),
        1.0 - 2.0 * (x * x + zz),
        2.0 * (y * z + x * w),
    )


_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])  # (a constant of the compiled code)


@_jit
def power_about_identity_rot6d(q: np.ndarray, theta: float, power: float, out: np.ndarray) -> None:
    """Every row of ``out`` (n, 6) ← the rot6d of ``q`` (4,) raised to ``power`` about the identity, ``theta`` the
    ``np.arccos`` of :func:`relative_quaternion`'s cosine: the bits of
    ``rotations.quaternion_to_rot6d(rotations.quaternion_power_about(q, (1, 0, 0, 0), power))`` (the closed form of
    the slerp, its linear blend when ``sin θ < 1e-6``, the norm summed left to right; then the six entries),
    rounded to ``out``'s dtype as NumPy stores them."""
    o = np.empty(4)
    slerp(_IDENTITY, q, theta, power, o)  # (q · identity ≥ 0: relative_quaternion made it so)
    r0, r1, r2, r3, r4, r5 = quaternion_to_rot6d(o[0], o[1], o[2], o[3])  # (it normalises again)
    for k in range(out.shape[0]):
        out[k, 0], out[k, 1], out[k, 2], out[k, 3], out[k, 4], out[k, 5] = r0, r1, r2, r3, r4, r5


@functools.cache  # the check once a process (every scheduler, model process and replica asks)
def checked_rot6d_to_quaternions() -> Callable[[np.ndarray, np.ndarray], None]:
    """What a caller converts many rows with, ``(rot6d (n, 6), out (n, 4) float64)``: :func:`rot6d_to_quaternions`
    once it has given NumPy's bits on this machine — checked here on 4,000 rows (random rotations, any 6-vectors,
    signed zeros, tiny and near-180° ones), because NumPy's ``einsum`` sums in the order its SIMD loops take, which
    another build or CPU may change — else NumPy's own formula. (``serve``'s model process converts each tick with
    it: ~12 % of its CPU at 100–300 streams a tick in NumPy's dozens of calls over the tick's B·47 rows.)"""
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
    wide = np.empty_like(want)
    rot6d_to_quaternions(r6.astype(np.float64), wide)  # float64 rows too (live's poses): loaded here, not at a frame
    if np.array_equal(want.view(np.uint64), got.view(np.uint64)) and np.array_equal(
        want.view(np.uint64), wide.view(np.uint64)
    ):
        return rot6d_to_quaternions
    return _numpy_rot6d_to_quaternions


def _numpy_rot6d_to_quaternions(r6: np.ndarray, out: np.ndarray) -> None:
    from facecapges import rotations as rot

    out[:] = rot.rot6d_to_quaternion(np.asarray(r6, np.float64))
