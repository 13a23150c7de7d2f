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

import numba
import numpy as np

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def qmul(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out ← a · b`` of one pair of quaternions (4,): :func:`facecapges.rotations.quaternion_multiply`'s sums."""
    aw, ax, ay, az, bw, bx, by, bz = a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3]
    out[0] = aw * bw - ax * bx - ay * by - az * bz
    out[1] = aw * bx + ax * bw + ay * bz - az * by
    out[2] = aw * by - ax * bz + ay * bw + az * bx
    out[3] = aw * bz + ax * by - ay * bx + az * bw


@_jit
def qmul_conj(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out ← a · b⁻¹`` of unit quaternions (4,) (b's conjugate, then :func:`qmul`)."""
    c = np.empty(4)
    c[0], c[1], c[2], c[3] = b[0], -b[1], -b[2], -b[3]
    qmul(a, c, out)


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
