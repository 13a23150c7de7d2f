"""Inertialization of rotations: a clip switch leaves an offset that decays, so no pose snaps.

Quaternions are (w, x, y, z) (the project's convention, :mod:`facecapges.rotations`), arrays
(…, 4); rotation vectors (angle · axis, radians) are (…, 3). Per joint, the played rotation is
``exp(x) · q_clip`` where ``x`` is the offset's rotation vector and ``v`` its angular velocity.

At a switch from a source frame (what would have played next: rotation ``s``, velocity ``v_s``)
to a destination frame (``d``, ``v_d``) the offset takes up the jump (Bollo's inertialization as
in Holden's Motion-Matching reference, ``inertialize_pose_transition``):
``x ← log(exp(x) · s · d⁻¹)``, ``v ← v + v_s − v_d``. Each frame both decay with a critically
damped spring of half-life ``h`` (:func:`decay_spring`), so the output keeps its rotation and
angular velocity across the switch and reaches the new clip within a few half-lives.

The quaternion algebra is :mod:`facecapges.rotations`' (``quaternion_multiply`` …), imported here
under the short names the formulas above use (``qmul``, ``qconj``, ``qabs``, ``qlog``, ``qexp``).
"""

from __future__ import annotations

import numba
import numpy as np

from facecapges.rotations import quaternion_exp as qexp
from facecapges.rotations import quaternion_invert as qconj
from facecapges.rotations import quaternion_log as qlog
from facecapges.rotations import quaternion_mean as quaternion_mean
from facecapges.rotations import quaternion_multiply as qmul
from facecapges.rotations import quaternion_power_about
from facecapges.rotations import standardize_quaternion as qabs

LN2 = float(np.log(2.0))
_jit = numba.njit(cache=True, nogil=True, error_model="numpy")  # machine code cached beside this file


def angular_velocity(q: np.ndarray, fps: float) -> np.ndarray:
    """Forward-difference angular velocity (T, …, 3) rad/s of a rotation sequence (T, …, 4); last repeats."""
    v = np.zeros(q.shape[:-1] + (3,), q.dtype)
    if len(q) > 1:
        v[:-1] = qlog(qabs(qmul(q[1:], qconj(q[:-1])))) * fps
        v[-1] = v[-2]
    return v


def decay_spring(
    x: np.ndarray, v: np.ndarray, halflife: float | np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """One step of a critically damped spring towards 0 (exact): offsets x and velocities v (``halflife``:
    one value, or an array broadcasting against them — one per stream)."""
    y = 2.0 * LN2 / np.maximum(halflife, 1e-5)  # half the damping 4·ln2/h
    j1 = v + x * y
    e = np.exp(-y * dt)
    return e * (x + j1 * dt), e * (v - j1 * y * dt)


def transition(
    x: np.ndarray, v: np.ndarray, src_q: np.ndarray, src_v: np.ndarray, dst_q: np.ndarray, dst_v: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The offset (x, v) after switching from ``src`` to ``dst`` (module docs)."""
    q = qabs(qmul(qexp(x), qmul(src_q, qconj(dst_q))))
    return qlog(q), v + src_v - dst_v


@_jit
def _qmul(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out ← a · b`` of one pair of quaternions (4,): :func:`facecapges.rotations.quaternion_multiply`'s sums."""
    aw, ax, ay, az, bw, bx, by, bz = a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3]
    out[0] = aw * bw - ax * bx - ay * by - az * bz
    out[1] = aw * bx + ax * bw + ay * bz - az * by
    out[2] = aw * by - ax * bz + ay * bw + az * bx
    out[3] = aw * bz + ax * by - ay * bx + az * bw


@_jit
def _qmul_conj(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out ← a · b⁻¹`` of unit quaternions (4,) (b's conjugate, then :func:`_qmul`)."""
    c = np.empty(4)
    c[0], c[1], c[2], c[3] = b[0], -b[1], -b[2], -b[3]
    _qmul(a, c, out)


@_jit
def _qlog_abs(q: np.ndarray, out: np.ndarray) -> None:
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
def _qexp(r: np.ndarray, out: np.ndarray) -> None:
    """``out ← exp(r)`` (4,) of a rotation vector (3,) (:func:`facecapges.rotations.quaternion_exp`)."""
    angle = np.sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2])
    half = 0.5 * angle
    k = np.sin(half) / max(angle, 1e-12)
    if not angle > 1e-9:
        k = 0.5 - angle**2 / 48.0
    out[0], out[1], out[2], out[3] = np.cos(half), r[0] * k, r[1] * k, r[2] * k


@_jit
def step_offsets(
    slots: np.ndarray,
    x: np.ndarray,
    v: np.ndarray,
    halflife: np.ndarray,
    base: np.ndarray,
    prev: np.ndarray,
    cap: float,
    fps: float,
    shift: bool,
    out: np.ndarray,
) -> None:
    """One frame of inertialized streams: the shown poses ``out`` (n, J, 4) = exp(x) · ``base`` (n, J, 4) after the
    offsets ``x`` and velocities ``v`` (S, J, 3) of ``slots`` (n,) decay one frame (:func:`decay_spring`, half-life
    ``halflife[slot]``); then, unless ``cap`` < 0 (no cap), the whole-body angular acceleration against the last two poses shown
    (``prev[slot, 1]``, the last, and ``prev[slot, 0]``; (S, 2, J, 4)) stays below ``cap`` (rad/s², root sum of
    squares over the joints): a larger step is shortened along itself and the offset takes up the difference
    (``x ← log(shown · base⁻¹)``: the clip continues from the limited pose). ``shift``: ``prev[slot]`` ← (its last,
    the pose shown now). The matcher's blend and the idle layer's (:mod:`facecapges.matching.idle`) in one compiled
    loop: libm's exp, sin, cos and atan2 where NumPy has its own, and the acceleration's sum in order, so the values
    equal the NumPy formulas' to ~1 ulp, not bit for bit."""
    dt = 1.0 / fps
    J = x.shape[1]
    pred, t, d, e = np.empty(4), np.empty(4), np.empty((J, 3)), np.empty(4)
    for n in range(len(slots)):
        s = slots[n]
        y = 2.0 * LN2 / max(halflife[s], 1e-5)  # half the damping 4·ln2/h
        decay = np.exp(-y * dt)
        for j in range(J):
            for c in range(3):
                xj, vj = x[s, j, c], v[s, j, c]
                j1 = vj + xj * y
                x[s, j, c] = decay * (xj + j1 * dt)
                v[s, j, c] = decay * (vj - j1 * y * dt)
            _qexp(x[s, j], e)
            _qmul(e, base[n, j], out[n, j])
        if cap >= 0:
            total = 0.0
            for j in range(J):
                _qmul_conj(prev[s, 1, j], prev[s, 0, j], t)
                _qmul(t, prev[s, 1, j], pred)  # constant angular velocity
                _qmul_conj(out[n, j], pred, t)
                _qlog_abs(t, d[j])  # acceleration · dt²
                total += d[j, 0] * d[j, 0] + d[j, 1] * d[j, 1] + d[j, 2] * d[j, 2]
            total = np.sqrt(total) * fps**2
            if total > cap:
                for j in range(J):
                    for c in range(3):
                        d[j, c] *= cap / total
                    _qmul_conj(prev[s, 1, j], prev[s, 0, j], t)
                    _qmul(t, prev[s, 1, j], pred)
                    _qexp(d[j], e)
                    _qmul(e, pred, out[n, j])
                    _qmul_conj(out[n, j], base[n, j], t)
                    _qlog_abs(t, x[s, j])
        if shift:
            prev[s, 0] = prev[s, 1]
            prev[s, 1] = out[n]


@_jit
def dial(slots: np.ndarray, q: np.ndarray, mean: np.ndarray, slow: np.ndarray, beta: float, gain: np.ndarray) -> None:
    """The matcher's intensity dial on poses ``q`` (n, J, 4) of streams ``slots`` (n,), in place: each joint's
    deviation ``d = log(m⁻¹ q)`` from the style's idle mean ``mean`` (J, 4), its smoothing ``slow`` (S, J, 3) ←
    ``slow + beta · (d − slow)``, and where ``gain`` (n,) is not 1 (beyond 1e-9) ``q ← m · exp(d + (gain − 1) ·
    slow)`` (:mod:`facecapges.matching.matcher`, step 6). ``beta`` = 1 with ``slow`` zero and ``gain`` 1 sets the
    smoothing to the deviation itself (a stream's restart)."""
    t, inv, d = np.empty(4), np.empty((mean.shape[0], 4)), np.empty(3)
    for j in range(mean.shape[0]):
        inv[j, 0], inv[j, 1], inv[j, 2], inv[j, 3] = mean[j, 0], -mean[j, 1], -mean[j, 2], -mean[j, 3]
    for n in range(len(slots)):
        s, g = slots[n], gain[n]
        for j in range(mean.shape[0]):
            _qmul(inv[j], q[n, j], t)
            _qlog_abs(t, d)
            for c in range(3):
                slow[s, j, c] = slow[s, j, c] + beta * (d[c] - slow[s, j, c])
            if abs(g - 1.0) > 1e-9:
                for c in range(3):
                    d[c] = d[c] + (g - 1.0) * slow[s, j, c]
                _qexp(d, t)
                _qmul(mean[j], t, q[n, j])


def warm() -> None:
    """Load (or compile, once: ``make setup``) the machine code of :func:`step_offsets` and :func:`dial` for the
    types their callers pass."""
    ids, one, z3, z4 = np.zeros(1, np.int64), np.ones(1), np.zeros((1, 1, 3)), np.zeros((1, 1, 4))
    step_offsets(ids, z3, z3.copy(), one, z4, np.zeros((1, 2, 1, 4)), 1.0, 15.0, True, z4.copy())
    dial(ids, z4.copy(), z4[0].copy(), z3.copy(), 0.5, one)


def qpow_about(q: np.ndarray, mean: np.ndarray, g: np.ndarray | float) -> np.ndarray:
    """``mean · (mean⁻¹ · q)^g``: rotations ``q`` (B, …, 4) scaled by ``g`` (a float or one per leading
    entry, (B,)) about ``mean`` (g = 1: unchanged) — :func:`facecapges.rotations.quaternion_power_about`."""
    g = np.asarray(g, np.float64)
    g = g.reshape(g.shape + (1,) * (q.ndim - g.ndim))
    return quaternion_power_about(q, mean, g).astype(q.dtype, copy=False)
