"""How the suite compares two computations of the same result (not a test module; issue #37).

The rule (docs/testing.md, "Results that depend on the CPU"):

* **The same code path** — the same function on the same inputs, in the same process, with the same
  batch, thread count and kernel schedule — gives the same bits twice on whatever CPU it runs, so it is
  compared with ``np.array_equal`` / ``assert_array_equal`` (causality, reset, a file round trip, the same
  stream twice, resume against an uninterrupted run). Say so in a comment.
* **Two paths to the same value** — another batch size or batch composition, the native (Numba)
  against the torch schedule, the cached kernel against the naive loop, a server or another process
  against the in-process generator, DDP ranks against one process — differ by float32 rounding, and
  by how much depends on the CPU: torch's SIMD kernels (AVX2, AVX-512 or plain, chosen at start-up),
  the BLAS and convolution kernels (MKL, oneDNN, OpenBLAS pick their blocking from the CPU and the
  shape: a matrix–matrix product sums in another order than a matrix–vector one) and the thread count.
  Compare in the unit that matters, with a bound derived from float32 arithmetic below, never from
  what one machine gave.

Poses are compared as the angle between rotations (:func:`assert_rotations_close`), which treats
``q`` and ``-q`` as one rotation, ignores the length of an un-normalised rot6d (the consumers
Gram–Schmidt it) but allows a short one the larger angle its rounding makes, and names the worst frame
and joint.
"""

from __future__ import annotations

import numpy as np

from facecapges import rotations as rot

F32_EPS = float(np.finfo(np.float32).eps)  # 1.19e-7: the relative rounding of one float32 operation

# Two float32 paths to one pose. A pose comes out of ~30 float32 layers (audio and face TCNs of 12 and
# 8 layers, the fusion MLPs, two LSTMs over a 16-frame window, the head), each of dot products of up to
# ~1000 terms; summed in another order, a layer's output moves by ~√K·eps relative (rounding errors
# add like a random walk; K·eps is the worst case), so ~30·√1000·eps ≈ 1e-4 rad if each layer passes
# the error on at gain ~1, before the autoregressive history feeds it back. 0.01° (1.7e-4 rad,
# ~1500 float32 ulps of a unit vector) covers that, and anything real is far above it: a wrong slot, a
# stale LSTM state or a missed reset moves joints by degrees (issue #37 saw 0.0015° on another CPU; the
# worst here: 0.0008° between served and single-stream quaternions, 0.00023° per unit rot6d column length).
POSE_MAX_DEG = 0.01
# The same budget for any other network output, in float32 ulps of the output's scale (0.01° is ~1500 ulps of a
# unit vector): speeds in cm/s, heights in cm, embeddings, each with :func:`assert_float32_close`.
NETWORK_ULPS = 1500


def rotation_matrices(x) -> np.ndarray:
    """Rotations as float64 matrices (..., 3, 3), from quaternions (..., 4), rot6d (..., 6) or matrices."""
    a = np.asarray(x, dtype=np.float64)
    if a.shape[-2:] == (3, 3):
        return a
    if a.shape[-1] == 4:
        return rot.quaternion_to_matrix(a)
    if a.shape[-1] == 6:
        return rot.rot6d_to_matrix(a)
    raise ValueError(f"rotations must be (..., 4), (..., 6) or (..., 3, 3), got shape {a.shape}")


def rotation_angles_deg(a, b) -> np.ndarray:
    """Angle in degrees between corresponding rotations of ``a`` and ``b`` (any of the three forms)."""
    return np.degrees(rot.geodesic_angle(rotation_matrices(a), rotation_matrices(b)))


def column_length(x) -> np.ndarray:
    """How far a rotation's numbers are from degenerate, at most 1: for rot6d ``min(|a|, |b − (û·b)û|)``
    (the lengths Gram–Schmidt divides by), for a quaternion its norm, for a matrix 1."""
    a = np.asarray(x, dtype=np.float64)
    if a.shape[-2:] == (3, 3):
        return np.ones(a.shape[:-2])
    if a.shape[-1] == 4:
        return np.minimum(np.linalg.norm(a, axis=-1), 1.0)
    u, b = a[..., :3], a[..., 3:]
    nu = np.linalg.norm(u, axis=-1)
    v = b - np.einsum("...i,...i->...", u, b)[..., None] * u / np.maximum(nu, 1e-300)[..., None] ** 2
    return np.minimum(np.minimum(nu, np.linalg.norm(v, axis=-1)), 1.0)


def assert_rotations_close(actual, desired, max_deg: float = POSE_MAX_DEG, what: str = "rotations") -> None:
    """Fail unless every rotation of ``actual`` is within ``max_deg`` degrees of ``desired``'s.

    Arrays of quaternions (w, x, y, z), rot6d or matrices, same leading shape, e.g. (frames, joints, 6).
    A raw network output (rot6d) whose columns are short — a randomly initialised test model gives
    lengths down to ~1e-3 — turns the same float32 rounding of its six numbers into a proportionally
    larger angle (Gram–Schmidt divides by those lengths, :func:`column_length`): such a rotation may
    differ by ``max_deg / length``. The message names the worst index (frame, joint, …), its angle, its
    bound and how many exceed theirs.
    """
    A, D = rotation_matrices(actual), rotation_matrices(desired)
    if A.shape != D.shape:
        raise AssertionError(f"{what}: shapes differ, {A.shape[:-2]} against {D.shape[:-2]}")
    ang = np.degrees(rot.geodesic_angle(A, D))
    if ang.size == 0:
        return
    length = np.minimum(column_length(actual), column_length(desired))
    allowed = max_deg / np.maximum(length, 1e-300)
    ratio = np.where(np.isnan(ang), np.inf, ang / allowed)
    bad = ~(ratio <= 1.0)
    if bad.any():
        worst = np.unravel_index(int(np.argmax(ratio)), ang.shape)
        raise AssertionError(
            f"{what}: {int(bad.sum())} of {ang.size} rotations differ by more than {max_deg}° (per unit column "
            f"length); the worst, {float(ang[worst]):.3g}° against {float(allowed[worst]):.3g}° allowed (column "
            f"length {float(length[worst]):.3g}), at index {tuple(int(i) for i in worst)} of shape {ang.shape}"
        )


def assert_float32_close(actual, desired, scale, ulps: float, unit: str, what: str = "values") -> None:
    """Fail unless ``|actual − desired| ≤ ulps · eps32 · scale`` everywhere (a float32 rounding budget).

    ``scale`` is the magnitude the values' rounding is relative to (in ``unit``): a number, or an array that
    broadcasts against the values (e.g. one per column); ``ulps`` the number of float32 roundings the two
    paths may differ by at that scale; the caller says why in a comment.
    """
    a, d = np.asarray(actual, dtype=np.float64), np.asarray(desired, dtype=np.float64)
    if a.shape != d.shape:
        raise AssertionError(f"{what}: shapes differ, {a.shape} against {d.shape}")
    tol = np.broadcast_to(ulps * F32_EPS * np.asarray(scale, dtype=np.float64), a.shape)
    diff = np.abs(a - d)
    bad = ~(diff <= tol)  # NaN is bad
    if bad.any():
        worst = np.unravel_index(int(np.argmax(np.where(np.isnan(diff), np.inf, diff / tol))), diff.shape)
        raise AssertionError(
            f"{what}: {int(bad.sum())} of {diff.size} differ by more than their bound ({ulps:g} float32 ulps of "
            f"their scale); the worst, {float(diff[worst]):.3g} {unit} against {float(tol[worst]):.3g} {unit}, at "
            f"index {tuple(int(i) for i in worst)}"
        )
