"""The VMC sender's compiled frame and tick (Numba; :mod:`.vmc`, :mod:`.upsample`, issue 36).

* :func:`bone_quaternions` — a model frame's bones as sent (:meth:`.vmc.VmcMapping.local_quaternions`);
* :func:`between` — a tick between two of them: the bones' slerp and the clips' lerp
  (:meth:`.vmc.VmcSender.between`);
* :func:`pack` — every number of a frame into its datagrams (:meth:`.vmc.VmcSender._layout`'s slots).

Each is one call where the NumPy forms were tens of calls on arrays of a few dozen rows (a 30 Hz tick's cost was
their overhead, run cold right after MediaPipe's frame). Their arithmetic is :mod:`facecapges.rotations`'
(:mod:`facecapges.rotations_compiled`, the same bits: ``tests/test_rotations_compiled.py``), so a frame's datagrams
are the bytes the NumPy formulas gave. Imported when a sender is built: ``live`` loads Numba for its engine anyway;
importing :mod:`.vmc` (``live``'s option checks) does not. Cached beside this file (``cache=True``), filled by
``make setup`` (``scripts/warm-numba-caches.py``, :func:`warm`).
"""

from __future__ import annotations

import functools

import numba
import numpy as np

from facecapges import rotations_compiled as rc

# the GIL kept: a call of a few µs that released it waited up to the switch interval (5 ms) to take it back from a
# busy thread (a tick behind a model step: the steady-rate tests failed under load)
_jit = numba.njit(cache=True, error_model="numpy")


@_jit
def bone_quaternions(quats, upper_idx, n_joints, path, starts, wp_inv, wb, flip, out) -> None:
    """``out`` (bones, 4) ← the sent bones' Unity quaternions, (x, y, z, w), of a pose ``quats`` (47, 4) (w, x, y, z;
    joint ``upper_idx[i]`` of ``n_joints``, the others at rest): bone ``k``'s path product ``Q`` of the joints
    ``path[starts[k]:starts[k + 1]]``, then ``Wp⁻¹ · (X · Q · X) · Wb`` (``wp_inv[k]``, ``wb[k]``, ``flip`` X), as
    a quaternion (:mod:`.vmc`'s module docstring)."""
    mats = np.zeros((n_joints, 3, 3))
    for j in range(n_joints):
        mats[j, 0, 0] = mats[j, 1, 1] = mats[j, 2, 2] = 1.0
    for i in range(len(upper_idx)):
        rc.quaternion_to_matrix(quats[i], mats[upper_idx[i]])
    R, T, q = np.empty((3, 3)), np.empty((3, 3)), np.empty(4)
    for k in range(len(starts) - 1):
        R[:] = mats[path[starts[k]]]
        for p in range(starts[k] + 1, starts[k + 1]):  # left to right, as the NumPy steps were
            rc.matmul3(R, mats[path[p]], T)
            R[:] = T
        rc.matmul3(flip, R, T)
        rc.matmul3(T, flip, R)
        rc.matmul3(wp_inv[k], R, T)
        rc.matmul3(T, wb[k], R)
        rc.matrix_to_quaternion(R, q)
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = q[1], q[2], q[3], q[0]


@_jit
def arcs(q0, q1, out) -> None:
    """``out`` (bones,) ← each bone's :func:`facecapges.rotations_compiled.slerp_cosine` from ``q0`` to ``q1``."""
    for k in range(q0.shape[0]):
        out[k] = rc.slerp_cosine(q0[k], q1[k])


@_jit
def between(q0, q1, theta, f0, f1, w, q, f) -> None:
    """``q`` (bones, 4) ← the slerp ``w`` of the way from ``q0`` to ``q1`` (``theta``: the arcs' angles,
    ``arccos`` of :func:`arcs`), ``f`` ← ``(1 − w) · f0 + w · f1`` (the clips' weights)."""
    for k in range(q0.shape[0]):
        rc.slerp(q0[k], q1[k], theta[k], w, q[k])
    for i in range(f0.shape[0]):
        f[i] = (1.0 - w) * f0[i] + w * f1[i]


@_jit
def pack(q, face, time_s, buf, at) -> None:
    """The frame's numbers — ``q`` (bones, 4) row by row, ``face``, then ``time_s`` — each as a big-endian float32
    (rounded to nearest, ties to even: ``astype(">f4")``) into ``buf`` (uint8) at the offsets ``at``."""
    n = q.size + face.size + 1
    x = np.empty(n, np.float32)
    i = 0
    for k in range(q.shape[0]):
        for c in range(q.shape[1]):
            x[i] = q[k, c]
            i += 1
    for c in range(face.shape[0]):
        x[i] = face[c]
        i += 1
    x[i] = time_s
    bits = x.view(np.uint32)
    for i in range(n):
        b, s = bits[i], at[i]
        buf[s], buf[s + 1], buf[s + 2], buf[s + 3] = b >> 24, (b >> 16) & 255, (b >> 8) & 255, b & 255


@functools.cache
def warm() -> None:
    """Load (or, on a fresh machine, compile: ``make setup`` does it once) the machine code of every function here
    for the argument types the sender passes: when a sender is built, never on a stream's first frame."""
    ids, m, q = np.zeros(1, np.int64), np.zeros((1, 3, 3)), np.zeros((1, 4))
    bone_quaternions(q, ids, 1, ids, np.array([0, 1]), m, m, np.eye(3), q.copy())
    cos, f = np.zeros(1), np.zeros(1)
    arcs(q, q, cos)
    between(q, q, cos, f, f, 0.5, q.copy(), f.copy())
    pack(q, f, 0.0, np.zeros(64, np.uint8), np.zeros(6, np.int64))
