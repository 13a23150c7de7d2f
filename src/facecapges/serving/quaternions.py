"""The quaternions of a served tick, compiled: ``rotations.rot6d_to_quaternion`` on float64, to the bit.

``serve``'s model process turns each tick's poses (rot6d, float32) into the quaternions the ``pose`` messages
carry. NumPy's formula (:func:`facecapges.rotations.rot6d_to_matrix`, then ``matrix_to_quaternion``) runs a few
dozen calls over the tick's (B·47) rows and was ~12 % of the model process's CPU at 100–300 streams a tick;
:func:`facecapges.rotations_compiled.rot6d_to_quaternions` is one loop over the rows doing the same operations on the same numbers in the same order — Gram–Schmidt (each
dot product summed left to right from zero, as NumPy's ``einsum`` does), the cross product, the four candidate
squares ``1 ± m00 ± m11 ± m22`` left to right, the first largest chosen, its four numbers divided by
``2·sqrt(max(·, 1e-8))``, the sign made w ≥ 0, the norm's squares summed left to right — without fused
multiply-adds (Numba's default), so every quaternion is NumPy's bit for bit (``tests/test_serve_batched.py``
compares them on random rows, degenerate ones and a tick's real poses; :func:`converter` checks them again on
this machine before the model process uses them). Imported by the model process only (the server's own process
never loads Numba); the machine code is cached (``cache=True``), loaded (or compiled) by :func:`converter` before
the model process says it is ready.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from facecapges.rotations_compiled import rot6d_to_quaternions


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
