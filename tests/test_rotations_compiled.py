"""The compiled rotation helpers (:mod:`facecapges.rotations_compiled`) give the bits of :mod:`facecapges.rotations`'
NumPy formulas (the VMC sender's frames and ticks are built from them: tests/test_runtime_vmc.py holds those)."""

from __future__ import annotations

import numpy as np
import pytest

from facecapges import rotations as rot

rc = pytest.importorskip("facecapges.rotations_compiled")


def _quaternions(rng: np.random.Generator, n: int) -> np.ndarray:
    """Random rotations and the awkward ones: the identity, half turns about each axis, exact zeros, a non-unit one."""
    q = rng.standard_normal((n, 4))
    q[: n // 4] *= rng.uniform(0.5, 2.0, (n // 4, 1))  # not unit: normalised first
    special = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [-1, 0, 0, 0], [0.5, 0.5, 0.5, 0.5],
               [np.sqrt(0.5), 0, -np.sqrt(0.5), 0], [1e-9, 0, 0, 0], [0, 0, 0, 0]]  # fmt: skip
    return np.concatenate([np.asarray(special, np.float64), q])


def test_quaternion_matrix_conversions_are_the_numpy_bits():
    rng = np.random.default_rng(3)
    q = _quaternions(rng, 4000)
    want = rot.quaternion_to_matrix(q)
    got = np.empty_like(want)
    for i in range(len(q)):
        rc.quaternion_to_matrix(q[i], got[i])
    np.testing.assert_array_equal(got.view(np.int64), want.view(np.int64))  # the bits (zeros' signs too)
    mats = np.concatenate([want, rng.standard_normal((2000, 3, 3)), np.eye(3)[None], -np.eye(3)[None]])
    want_q = rot.matrix_to_quaternion(mats)
    got_q = np.empty_like(want_q)
    for i in range(len(mats)):
        rc.matrix_to_quaternion(mats[i], got_q[i])
    np.testing.assert_array_equal(got_q.view(np.int64), want_q.view(np.int64))


def test_matmul3_is_numpys_matmul():
    """NumPy's ``@`` of stacked 3 × 3 matrices, in the shapes the VMC mapping used it: (n, 3, 3) @ (n, 3, 3) and a
    (3, 3) on either side; random entries and rotations with exact zeros and signed ones (Unity's X flip)."""
    rng = np.random.default_rng(4)
    a = np.concatenate([rng.standard_normal((500, 3, 3)), rot.quaternion_to_matrix(_quaternions(rng, 500))])
    b = np.concatenate([rng.standard_normal((500, 3, 3)), rot.quaternion_to_matrix(_quaternions(rng, 500))])
    b = b[: len(a)]
    flip = np.diag([-1.0, 1.0, 1.0])
    for want, left, right in ((a @ b, a, b), (flip @ a, [flip] * len(a), a), (a @ flip, a, [flip] * len(a))):
        got = np.empty_like(want)
        for i in range(len(want)):
            rc.matmul3(np.asarray(left[i]), np.asarray(right[i]), got[i])
        np.testing.assert_array_equal(got.view(np.int64), want.view(np.int64))


def test_matmul3_tn_is_numpys_transposed_matmul():
    """``a.T @ b`` (the head driver's ``spineᵀ · R``): random entries and rotations."""
    rng = np.random.default_rng(6)
    a = np.concatenate([rng.standard_normal((500, 3, 3)), rot.quaternion_to_matrix(_quaternions(rng, 500))])
    b = np.concatenate([rng.standard_normal((500, 3, 3)), rot.quaternion_to_matrix(_quaternions(rng, 500))])
    got = np.empty((3, 3))
    for i in range(len(a)):
        rc.matmul3_tn(a[i], b[i], got)
        np.testing.assert_array_equal(got.view(np.int64), (a[i].T @ b[i]).view(np.int64))


def test_slerp_is_quaternion_slerp():
    """The slerp of every pair (opposite hemispheres, nearly equal, equal, any order of the components) at
    fractions in and beyond [0, 1]: :func:`facecapges.rotations.quaternion_slerp`'s bits, ``theta`` from NumPy's
    ``arccos`` of :func:`slerp_cosine`."""
    rng = np.random.default_rng(5)
    q0 = rot.quaternion_to_matrix(_quaternions(rng, 3000))
    q0 = rot.matrix_to_quaternion(q0)
    q1 = np.concatenate([q0[:500] + 1e-8 * rng.standard_normal((500, 4)), q0[500:1000], -q0[1000:1500],
                         rot.matrix_to_quaternion(rot.quaternion_to_matrix(rng.standard_normal((len(q0) - 1500, 4))))])  # fmt: skip
    q1 = q1 / np.linalg.norm(q1, axis=-1, keepdims=True)
    for t in (0.0, 1.0, 0.25, 0.5, *rng.uniform(-0.5, 1.5, 5)):
        want = rot.quaternion_slerp(q0, q1, t)
        theta = np.arccos(np.array([rc.slerp_cosine(a, b) for a, b in zip(q0, q1)]))
        got = np.empty_like(want)
        for i in range(len(q0)):
            rc.slerp(q0[i], q1[i], theta[i], t, got[i])
        np.testing.assert_array_equal(got.view(np.int64), want.view(np.int64))


def same_quaternion_bits(r6: np.ndarray) -> None:
    want = rot.rot6d_to_quaternion(np.asarray(r6, np.float64)).reshape(-1, 4)
    got = np.empty_like(want)
    rc.rot6d_to_quaternions(np.ascontiguousarray(r6).reshape(-1, 6), got)
    differ = ~((want.view(np.uint64) == got.view(np.uint64)) | (np.isnan(want) & np.isnan(got))).all(axis=1)
    assert not differ.any(), (np.flatnonzero(differ)[:5], want[differ][:3], got[differ][:3])


@pytest.mark.parametrize("B", [1, 7, 100, 300])
def test_rot6d_rows_of_a_ticks_poses(B):
    """A tick's layout (B, 47, 6) float32, as the engines return it, from random rotations."""
    q = np.random.default_rng(B).standard_normal((B, 47, 4))
    same_quaternion_bits(rot.quaternion_to_rot6d(q / np.linalg.norm(q, axis=-1, keepdims=True)).astype(np.float32))


def test_rot6d_rows_any_signed_zeros_tiny_and_half_turns():
    rng = np.random.default_rng(0)
    same_quaternion_bits(rng.standard_normal((50_000, 6)).astype(np.float32))
    same_quaternion_bits(rng.choice(np.array([0.0, -0.0, 1.0, -1.0, 0.5, -0.5, 1e-9, -1e-9], np.float32), size=(50_000, 6)))
    same_quaternion_bits((rng.standard_normal((20_000, 6)) * 1e-5).astype(np.float32))
    angle = rng.uniform(np.pi - 1e-3, np.pi, 20_000)  # near 180°: the largest candidate changes
    axis = rng.standard_normal((20_000, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    q = np.concatenate([np.cos(angle / 2)[:, None], np.sin(angle / 2)[:, None] * axis], 1)
    same_quaternion_bits(rot.quaternion_to_rot6d(q).astype(np.float32))
    with np.errstate(invalid="ignore"):
        same_quaternion_bits(np.array([[np.nan, 0, 0, 0, 1, 0], [np.inf, 0, 0, 0, 1, 0], [0, 0, 0, 0, 0, 0]], np.float32))


def test_the_checked_conversion_is_the_compiled_loop_here():
    """:func:`checked_rot6d_to_quaternions` checks the loop against NumPy on this machine and keeps it (else NumPy's
    own): here it is the loop (serve's model process converts a tick with it)."""
    assert rc.checked_rot6d_to_quaternions() is rc.rot6d_to_quaternions
