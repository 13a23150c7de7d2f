"""The model process's compiled quaternions (``serving/quaternions.py``): NumPy's ``rot6d_to_quaternion`` on
float64, bit for bit, on every kind of row a tick can hold."""

from __future__ import annotations

import numpy as np
import pytest

from facecapges import rotations as rot

quaternions = pytest.importorskip("facecapges.serving.quaternions")


def same_bits(r6: np.ndarray) -> None:
    want = rot.rot6d_to_quaternion(np.asarray(r6, np.float64)).reshape(-1, 4)
    got = np.empty_like(want)
    quaternions.rot6d_to_quaternions(np.ascontiguousarray(r6).reshape(-1, 6), got)
    differ = ~((want.view(np.uint64) == got.view(np.uint64)) | (np.isnan(want) & np.isnan(got))).all(axis=1)
    assert not differ.any(), (np.flatnonzero(differ)[:5], want[differ][:3], got[differ][:3])


@pytest.mark.parametrize("B", [1, 7, 100, 300])
def test_a_ticks_poses(B):
    """A tick's layout (B, 47, 6) float32, as the engines return it, from random rotations."""
    q = np.random.default_rng(B).standard_normal((B, 47, 4))
    same_bits(rot.quaternion_to_rot6d(q / np.linalg.norm(q, axis=-1, keepdims=True)).astype(np.float32))


def test_any_rows_signed_zeros_tiny_and_half_turns():
    rng = np.random.default_rng(0)
    same_bits(rng.standard_normal((50_000, 6)).astype(np.float32))
    same_bits(rng.choice(np.array([0.0, -0.0, 1.0, -1.0, 0.5, -0.5, 1e-9, -1e-9], np.float32), size=(50_000, 6)))
    same_bits((rng.standard_normal((20_000, 6)) * 1e-5).astype(np.float32))
    angle = rng.uniform(np.pi - 1e-3, np.pi, 20_000)  # near 180°: the largest candidate changes
    axis = rng.standard_normal((20_000, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    q = np.concatenate([np.cos(angle / 2)[:, None], np.sin(angle / 2)[:, None] * axis], 1)
    same_bits(rot.quaternion_to_rot6d(q).astype(np.float32))
    with np.errstate(invalid="ignore"):
        same_bits(np.array([[np.nan, 0, 0, 0, 1, 0], [np.inf, 0, 0, 0, 1, 0], [0, 0, 0, 0, 0, 0]], np.float32))


def test_the_model_process_uses_the_compiled_loop_here():
    """:func:`converter` checks the loop against NumPy on this machine and keeps it (else NumPy's own)."""
    assert quaternions.converter() is quaternions.rot6d_to_quaternions
