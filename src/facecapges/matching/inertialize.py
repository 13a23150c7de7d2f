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

import numpy as np

from facecapges.rotations import quaternion_exp as qexp
from facecapges.rotations import quaternion_invert as qconj
from facecapges.rotations import quaternion_log as qlog
from facecapges.rotations import quaternion_mean as quaternion_mean
from facecapges.rotations import quaternion_multiply as qmul
from facecapges.rotations import quaternion_power_about
from facecapges.rotations import standardize_quaternion as qabs

LN2 = float(np.log(2.0))


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


def qpow_about(q: np.ndarray, mean: np.ndarray, g: np.ndarray | float) -> np.ndarray:
    """``mean · (mean⁻¹ · q)^g``: rotations ``q`` (B, …, 4) scaled by ``g`` (a float or one per leading
    entry, (B,)) about ``mean`` (g = 1: unchanged) — :func:`facecapges.rotations.quaternion_power_about`."""
    g = np.asarray(g, np.float64)
    g = g.reshape(g.shape + (1,) * (q.ndim - g.ndim))
    return quaternion_power_about(q, mean, g).astype(q.dtype, copy=False)
