"""The suite's rule for comparing two computations of one result (tests/tolerances.py, issue #37): the
rotation check passes float32 rounding and fails on what a wrong slot or a stale state does."""

from __future__ import annotations

import numpy as np
import pytest

from facecapges import rotations as rot
from facecapges.skeleton import motion_to_pose
from tolerances import POSE_MAX_DEG, assert_float32_close, assert_rotations_close, rotation_angles_deg


@pytest.fixture(scope="module")
def poses(beat_take) -> np.ndarray:
    """Real motion: 120 frames (8 s at 15 fps) of the BEAT sample as rot6d (120, 47, 6)."""
    return motion_to_pose(beat_take.skeleton, beat_take.motion)[0][300:420]


def _turned(pose: np.ndarray, deg: float, seed: int = 0) -> np.ndarray:
    """``pose`` with every rotation turned by ``deg`` degrees about a random axis."""
    axes = np.random.default_rng(seed).normal(size=pose.shape[:-1] + (3,))
    axes *= np.radians(deg) / np.linalg.norm(axes, axis=-1, keepdims=True)
    R = rot.rot6d_to_matrix(pose.astype(np.float64)) @ rot.exp_so3(axes)
    return rot.matrix_to_rot6d(R)


def test_float32_rounding_passes(poses):
    assert_rotations_close(poses.astype(np.float32), poses.astype(np.float64))
    # one float32 ulp on every number of every joint, and a scaled (un-normalised) rot6d: the same rotations
    bumped = np.nextafter(poses.astype(np.float32), np.float32(np.inf))
    assert_rotations_close(bumped, poses)
    assert_rotations_close(3.0 * poses, poses)
    assert_rotations_close(_turned(poses, 0.2 * POSE_MAX_DEG), poses)


def test_q_and_minus_q_are_one_rotation(poses):
    q = rot.rot6d_to_quaternion(poses.astype(np.float64))
    flip = np.where(np.arange(poses.shape[1]) % 2 == 0, 1.0, -1.0)[None, :, None]
    assert_rotations_close(q * flip, q)
    assert_rotations_close(q * flip, poses)  # and forms mix: quaternions against rot6d …
    assert_rotations_close(rot.quaternion_to_matrix(q), poses)  # … or matrices


def test_a_real_divergence_fails(poses):
    """Negative controls: a 0.1° turn, a stream one frame late (a stale state), two slots swapped, a NaN."""
    with pytest.raises(AssertionError, match=r"differ by more than 0.01°.*at index \("):
        assert_rotations_close(_turned(poses, 0.1), poses)
    late = np.concatenate([poses[:1], poses[:-1]])
    with pytest.raises(AssertionError, match="differ by more than"):
        assert_rotations_close(late, poses)
    a, b = poses[:60], poses[60:]
    with pytest.raises(AssertionError, match="differ by more than"):
        assert_rotations_close(np.stack([b, a]), np.stack([a, b]))
    one_joint = poses.copy()
    one_joint[17, 30] = _turned(poses[17, 30], 0.05)
    with pytest.raises(AssertionError, match=r"1 of 5640 .* at index \(17, 30\)"):
        assert_rotations_close(one_joint, poses)
    nan = poses.copy()
    nan[5, 3, 0] = np.nan
    with pytest.raises(AssertionError, match=r"at index \(5, 3\)"):
        assert_rotations_close(nan, poses)
    with pytest.raises(AssertionError, match="shapes differ"):
        assert_rotations_close(poses[:-1], poses)


def test_short_columns_allow_their_larger_angle(poses):
    """A raw output whose first column is 0.01 long: rounding of its numbers turns it 100× more (Gram–Schmidt
    divides by the length), so it may differ by 1°; a unit one next to it still may not."""
    p = poses[:2, :2].astype(np.float64).copy()
    p[..., :3] *= 0.01
    turned = _turned(p, 0.5)
    turned[..., :3] *= 0.01 / np.linalg.norm(turned[..., :3], axis=-1, keepdims=True)
    assert rotation_angles_deg(turned, p).min() > 0.4
    assert_rotations_close(turned, p)
    unit = poses[:2, :2].astype(np.float64)
    with pytest.raises(AssertionError, match="column length 1"):
        assert_rotations_close(np.concatenate([turned, _turned(unit, 0.5)]), np.concatenate([p, unit]))


def test_float32_budget():
    x = np.linspace(-50, 50, 101)
    assert_float32_close(x.astype(np.float32), x, scale=50, ulps=1, unit="cm")
    with pytest.raises(AssertionError, match=r"1 of 101 differ by more than .* cm .* index \(7,\)"):
        y = x.copy()
        y[7] += 1e-4
        assert_float32_close(y, x, scale=50, ulps=4, unit="cm")
    # one scale per column: a probability next to speeds of 50 cm/s keeps its own, tighter bound
    v = np.stack([x, np.linspace(0, 1, 101)], -1)
    w = v.copy()
    w[3, 1] += 1e-3  # 0.1 % of a probability: 84 float32 ulps of 50, 8400 of 1
    assert_float32_close(w[:, 0], v[:, 0], scale=50, ulps=1500, unit="cm/s")
    with pytest.raises(AssertionError, match=r"against 0.000179 cm/s or 1, at index \(3, 1\)"):
        assert_float32_close(w, v, scale=np.abs(v).max(0), ulps=1500, unit="cm/s or 1")
