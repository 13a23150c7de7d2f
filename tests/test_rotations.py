"""Property tests of the rotation conventions (facecapges.rotations).

Independent reference: scipy's ``Rotation.from_euler`` with upper-case axis letters
is the intrinsic convention BVH uses, ``R = R_a(α) R_b(β) R_c(γ)``.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from facecapges import rotations as rot
from facecapges.io.bvh import read_bvh
from facecapges.skeleton import local_matrices, motion_to_euler

ORDERS = ["".join(p) for p in itertools.permutations("XYZ")]

angle = st.floats(-179.9, 179.9)
middle = st.floats(-89.0, 89.0)  # away from gimbal lock, where angles are not unique
eulers = st.tuples(angle, middle, angle).map(np.array)
vec6 = arrays(np.float64, (6,), elements=st.floats(-10, 10))


def random_matrices(n: int, seed: int) -> np.ndarray:
    return Rotation.random(n, random_state=seed).as_matrix()


@settings(max_examples=60, deadline=None)
@given(e=eulers, order=st.sampled_from(ORDERS))
def test_euler_matches_scipy_intrinsic_and_round_trips(e, order):
    m = rot.euler_to_matrix(e, order, degrees=True)
    np.testing.assert_allclose(m, Rotation.from_euler(order, e, degrees=True).as_matrix(), atol=1e-12)
    back = rot.matrix_to_euler(m, order, degrees=True)
    np.testing.assert_allclose(back, e, atol=1e-7)


@pytest.mark.parametrize("order", ORDERS)
def test_matrix_euler_matrix_for_every_order_including_gimbal_lock(order):
    mats = random_matrices(200, seed=ORDERS.index(order))
    # plus exact gimbal-lock cases: middle angle ±90°
    locked = rot.euler_to_matrix(np.array([[30.0, 90.0, 10.0], [-50.0, -90.0, 70.0]]), order, degrees=True)
    mats = np.concatenate([mats, locked])
    e = rot.matrix_to_euler(mats, order)
    assert np.all(np.abs(e[:, 1]) <= np.pi / 2 + 1e-9)
    np.testing.assert_allclose(rot.euler_to_matrix(e, order), mats, atol=1e-6)


def test_matrix_rot6d_quaternion_round_trips():
    mats = random_matrices(500, seed=1)
    r6 = rot.matrix_to_rot6d(mats)
    np.testing.assert_array_equal(r6[:, :3], mats[:, :, 0])  # first column
    np.testing.assert_array_equal(r6[:, 3:], mats[:, :, 1])  # second column
    np.testing.assert_allclose(rot.rot6d_to_matrix(r6), mats, atol=1e-12)
    q = rot.matrix_to_quaternion(mats)
    assert np.all(q[:, 0] >= 0)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-12)
    ref = Rotation.from_matrix(mats).as_quat()[:, [3, 0, 1, 2]]  # scipy is (x, y, z, w)
    ref *= np.sign(ref[:, :1] + 1e-300)
    np.testing.assert_allclose(q, ref, atol=1e-9)
    np.testing.assert_allclose(rot.quaternion_to_matrix(q), mats, atol=1e-12)
    np.testing.assert_allclose(rot.quaternion_to_matrix(-q), mats, atol=1e-12)  # q and -q: same rotation
    np.testing.assert_allclose(rot.quaternion_to_matrix(rot.rot6d_to_quaternion(r6)), mats, atol=1e-9)


def test_quaternion_of_near_180_degree_rotations():
    # the trace is ~ -1 here: the branch choice inside matrix_to_quaternion matters
    axes = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, -2, 3]], dtype=float)
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    mats = Rotation.from_rotvec(axes * (np.pi - 1e-9)).as_matrix()
    np.testing.assert_allclose(rot.quaternion_to_matrix(rot.matrix_to_quaternion(mats)), mats, atol=1e-7)


@settings(max_examples=40, deadline=None)
@given(e=arrays(np.float64, (4, 3), elements=st.floats(-180, 180)), order=st.sampled_from(ORDERS))
def test_numpy_and_torch_agree(e, order):
    t = torch.from_numpy(e)
    m_np, m_t = rot.euler_to_matrix(e, order, degrees=True), rot.euler_to_matrix(t, order, degrees=True)
    assert isinstance(m_t, torch.Tensor)
    np.testing.assert_allclose(m_t.numpy(), m_np, atol=1e-12)
    np.testing.assert_allclose(rot.matrix_to_euler(m_t, order).numpy(), rot.matrix_to_euler(m_np, order),
                               atol=1e-9)
    r6 = rot.matrix_to_rot6d(m_np)
    np.testing.assert_allclose(rot.matrix_to_rot6d(m_t).numpy(), r6, atol=1e-12)
    np.testing.assert_allclose(rot.rot6d_to_matrix(torch.from_numpy(r6)).numpy(), rot.rot6d_to_matrix(r6),
                               atol=1e-12)
    np.testing.assert_allclose(rot.matrix_to_quaternion(m_t).numpy(), rot.matrix_to_quaternion(m_np), atol=1e-9)
    q = rot.matrix_to_quaternion(m_np)
    np.testing.assert_allclose(rot.quaternion_to_matrix(torch.from_numpy(q)).numpy(), rot.quaternion_to_matrix(q),
                               atol=1e-12)
    np.testing.assert_allclose(rot.geodesic_angle(m_t, m_t.flip(0)).numpy(), rot.geodesic_angle(m_np, m_np[::-1]),
                               atol=1e-6)


def test_torch_gradients_flow_through_rot6d_to_matrix():
    x = torch.randn(8, 6, dtype=torch.float64, requires_grad=True)
    rot.rot6d_to_matrix(x).sum().backward()
    assert x.grad is not None and torch.isfinite(x.grad).all()


@settings(max_examples=100, deadline=None)
@given(v=vec6)
def test_gram_schmidt_of_any_6_vector_is_a_rotation(v):
    a, b = v[:3], v[3:]
    na = np.linalg.norm(a)
    if na < 1e-3 or np.linalg.norm(np.cross(a, b)) < 1e-3 * na * max(np.linalg.norm(b), 1e-3):
        return  # degenerate: the columns are (nearly) parallel or a vanishes
    m = rot.rot6d_to_matrix(v)
    np.testing.assert_allclose(m.T @ m, np.eye(3), atol=1e-9)
    assert np.linalg.det(m) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(m[:, 0], a / na, atol=1e-12)  # u1 keeps the first column's direction


def test_gram_schmidt_of_perturbed_rot6d_is_orthonormal_and_close():
    rng = np.random.default_rng(0)
    mats = random_matrices(300, seed=2)
    noisy = rot.matrix_to_rot6d(mats) + rng.normal(0, 0.05, (300, 6))
    m = rot.rot6d_to_matrix(noisy)
    np.testing.assert_allclose(np.swapaxes(m, -1, -2) @ m, np.broadcast_to(np.eye(3), m.shape), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(m), 1.0, atol=1e-9)
    assert rot.geodesic_angle(m, mats).max() < 0.3  # the projection stays near the clean rotation
    np.testing.assert_allclose(rot.normalize_rot6d(rot.matrix_to_rot6d(mats)), rot.matrix_to_rot6d(mats), atol=1e-12)


@settings(max_examples=50, deadline=None)
@given(theta=st.floats(-3.1, 3.1), order=st.sampled_from(ORDERS))
def test_geodesic_angle_is_the_relative_rotation_angle(theta, order):
    base = rot.euler_to_matrix(np.array([20.0, -40.0, 75.0]), order, degrees=True)
    other = base @ rot.axis_angle_matrix("Y", np.array(theta))
    assert float(rot.geodesic_angle(base, other)) == pytest.approx(abs(theta), abs=1e-6)


def test_geodesic_angle_is_accurate_at_small_angles_and_in_torch():
    R = random_matrices(5, seed=14)
    for theta in (1e-10, 1e-7, 1e-4):
        turned = R @ rot.axis_angle_matrix("Z", np.full(5, theta))
        np.testing.assert_allclose(rot.geodesic_angle(R, turned), theta, rtol=1e-5)
    A, B = random_matrices(20, seed=15), random_matrices(20, seed=16)
    np.testing.assert_allclose(rot.geodesic_angle(torch.from_numpy(A), torch.from_numpy(B)).numpy(),
                               rot.geodesic_angle(A, B), atol=1e-12)


def test_quaternion_to_unity_mirrors_x():
    q = rot.matrix_to_quaternion(random_matrices(10, seed=3))
    u = rot.quaternion_to_unity(q)
    # mirroring X: M R M with M = diag(-1, 1, 1)
    M = np.diag([-1.0, 1.0, 1.0])
    np.testing.assert_allclose(rot.quaternion_to_matrix(u), M @ rot.quaternion_to_matrix(q) @ M, atol=1e-12)


def test_bad_shapes_and_orders_raise():
    with pytest.raises(ValueError, match="Euler order"):
        rot.euler_to_matrix(np.zeros(3), "XXY")
    with pytest.raises(ValueError, match="rot6d"):
        rot.rot6d_to_matrix(np.zeros(5))
    with pytest.raises(ValueError, match="matrix"):
        rot.matrix_to_rot6d(np.zeros((3, 2)))


def test_real_right_forearm_wraps_in_euler_but_is_continuous_in_rot6d(beat_bvh):
    """The file's RightForeArm angles run past ±180° (they turn several times round);
    any converter's principal-branch Euler then jumps by ~360° while rot6d stays smooth."""
    bvh = read_bvh(beat_bvh)
    skel = bvh.skeleton
    j = skel.index("RightForeArm")
    _, euler = motion_to_euler(skel, bvh.motion)
    assert np.abs(euler[:, j]).max() > 180.0  # the stored track goes round
    mats = local_matrices(skel, euler)[:, j]
    principal = rot.matrix_to_euler(mats, skel.rotation_order(j), degrees=True)
    jumps = np.abs(np.diff(principal, axis=0)).max(axis=1)
    wraps = np.flatnonzero(jumps > 300)  # ~360° Euler jumps between neighbouring frames
    assert len(wraps) >= 3
    r6 = rot.matrix_to_rot6d(mats)
    step = np.linalg.norm(np.diff(r6, axis=0), axis=1)
    assert step[wraps].max() < 0.35  # a rot6d step of at most ~20°: no discontinuity
    assert step[wraps].max() < np.percentile(step, 99)  # smaller than the arm's fast movements
    assert np.degrees(rot.geodesic_angle(mats[wraps], mats[wraps + 1])).max() < 20.0


def test_so3_exp_log_round_trip():
    rng = np.random.default_rng(3)
    for v in list(rng.normal(size=(50, 3))) + [np.zeros(3), np.array([np.pi - 1e-6, 0, 0]), np.array([0, 1e-9, 0])]:
        R = rot.exp_so3(v)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.linalg.det(R) > 0
        assert np.allclose(rot.exp_so3(rot.log_so3(R)), R, atol=1e-5)  # ~1e-6 within 1e-6 rad of 180°


def test_rotation_between_is_the_shortest_arc():
    rng = np.random.default_rng(4)
    a, b = rng.normal(size=(200, 3)), rng.normal(size=(200, 3))
    R = rot.rotation_between(a, b)
    assert np.allclose(np.einsum("nij,nj->ni", R, a / np.linalg.norm(a, axis=1, keepdims=True)),
                       b / np.linalg.norm(b, axis=1, keepdims=True), atol=1e-9)
    assert np.allclose(R @ np.swapaxes(R, -1, -2), np.eye(3), atol=1e-9)
    # no twist: the angle turned is the angle between the vectors
    cos = (a * b).sum(1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    assert np.allclose(rot.geodesic_angle(np.eye(3), R), np.arccos(np.clip(cos, -1, 1)), atol=1e-7)
    flip = rot.rotation_between(np.array([1.0, 0, 0]), np.array([-1.0, 0, 0]))
    assert np.allclose(flip @ [1, 0, 0], [-1, 0, 0]) and np.isclose(np.linalg.det(flip), 1)
    assert np.allclose(rot.rotation_between(np.zeros(3), np.ones(3)), np.eye(3))


def _old_slerp(q0, q1, t):
    """The sin-weighted slerp formula rotations.quaternion_slerp had before it called quaternion_power_about."""
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0.0, -q1, q1)
    theta = np.arccos(np.clip(np.abs(dot), 0.0, 1.0))
    s = np.sin(theta)
    small = s < 1e-6
    safe = np.where(small, 1.0, s)
    out = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / safe) * q0 + np.where(
        small, t, np.sin(t * theta) / safe) * q1
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def test_quaternion_algebra_matches_matrices_and_scipy():
    A, B = random_matrices(300, seed=5), random_matrices(300, seed=6)
    qa, qb = rot.matrix_to_quaternion(A), rot.matrix_to_quaternion(B)
    np.testing.assert_allclose(rot.quaternion_to_matrix(rot.quaternion_multiply(qa, qb)), A @ B, atol=1e-12)
    np.testing.assert_allclose(rot.quaternion_to_matrix(rot.quaternion_invert(qa)), np.swapaxes(A, -1, -2), atol=1e-12)
    assert np.all(rot.standardize_quaternion(-qa)[:, 0] >= 0)
    rv = rot.quaternion_log(rot.standardize_quaternion(qa))
    np.testing.assert_allclose(rv, Rotation.from_matrix(A).as_rotvec(), atol=1e-9)
    np.testing.assert_allclose(np.stack([rot.log_so3(m) for m in A]), rv, atol=1e-6)  # the matrix form agrees
    np.testing.assert_allclose(rot.quaternion_to_matrix(rot.quaternion_exp(rv)), A, atol=1e-12)
    np.testing.assert_allclose(rot.quaternion_exp(np.zeros((2, 3))), [[1, 0, 0, 0]] * 2)


def test_quaternion_mean_is_scipys_mean():
    """Markley's eigenvector mean is what scipy's ``Rotation.mean`` computes (blind to sign)."""
    R = Rotation.from_rotvec(np.random.default_rng(7).normal(0, 0.4, (50, 3))) * Rotation.from_euler("y", 30, True)
    q = rot.matrix_to_quaternion(R.as_matrix()) * np.where(np.arange(50) % 3 == 0, -1.0, 1.0)[:, None]
    m = rot.quaternion_mean(q[:, None])  # (1, 4): one joint
    np.testing.assert_allclose(rot.quaternion_to_matrix(m[0]), R.mean().as_matrix(), atol=1e-9)


def test_power_about_is_the_one_slerp_and_scaling_rule():
    """quaternion_power_about against two independent forms: the sin-weighted slerp formula and the
    matrix ``A · exp(t · log(Aᵀ B))``; quaternion_slerp, rot6d_slerp and rotation_power_about are it."""
    A, B = random_matrices(200, seed=8), random_matrices(200, seed=9)
    qa, qb = rot.matrix_to_quaternion(A), rot.matrix_to_quaternion(B)
    for t in (0.0, 0.3, 1.0):
        np.testing.assert_allclose(rot.quaternion_slerp(qa, qb, t), _old_slerp(qa, qb, t), atol=1e-9)
    t = np.random.default_rng(10).uniform(-0.5, 1.5, (200, 1))  # one power per rotation, past both ends
    got = rot.rotation_power_about(B, A, t)
    want = np.stack([a @ rot.exp_so3(k * rot.log_so3(a.T @ b)) for a, b, k in zip(A, B, t[:, 0], strict=True)])
    np.testing.assert_allclose(got, want, atol=1e-6)
    np.testing.assert_allclose(rot.quaternion_to_matrix(rot.quaternion_power_about(qb, qa, t)), want, atol=1e-6)
    np.testing.assert_allclose(rot.rot6d_to_matrix(rot.rot6d_slerp(rot.matrix_to_rot6d(A), rot.matrix_to_rot6d(B), t)),
                               want, atol=1e-6)
    # about the identity: R^k is exp(k · log R)
    np.testing.assert_allclose(rot.rotation_power_about(B, None, 0.4),
                               np.stack([rot.exp_so3(0.4 * rot.log_so3(b)) for b in B]), atol=1e-6)
    # the log/exp form the motion-matching intensity had: mean · exp(g · log(mean⁻¹ q))
    rel = rot.quaternion_log(rot.standardize_quaternion(rot.quaternion_multiply(rot.quaternion_invert(qa), qb)))
    np.testing.assert_allclose(rot.quaternion_power_about(qb, qa, t),
                               rot.quaternion_multiply(qa, rot.quaternion_exp(rel * t)), atol=1e-9)
    np.testing.assert_allclose(rot.rotation_power_about(B, A, 0.0), A, atol=1e-12)
    np.testing.assert_allclose(rot.rotation_power_about(B, A, 1.0), B, atol=1e-12)


def test_nearest_rotation_and_the_two_means():
    A = random_matrices(40, seed=11)
    scaled = A * np.array([2.0, 0.5, 3.0])  # a scale per column: the rotation is still A
    np.testing.assert_allclose(rot.nearest_rotation(scaled @ np.eye(3)), rot.nearest_rotation(A), atol=1e-12)
    np.testing.assert_allclose(rot.nearest_rotation(A * 1.7), A, atol=1e-12)
    mirrored = A @ np.diag([1.0, 1.0, -1.0])  # a reflection becomes a proper rotation
    assert np.allclose(np.linalg.det(rot.nearest_rotation(mirrored)), 1.0)
    # the chordal mean of a cluster: the rotation minimising Σ ‖R − R_i‖², close to the quaternion mean
    c = Rotation.from_rotvec(np.random.default_rng(12).normal(0, 0.2, (60, 3))) * Rotation.from_euler("x", 40, True)
    m6 = rot.mean_rotation(rot.matrix_to_rot6d(c.as_matrix()))
    M = rot.rot6d_to_matrix(m6)

    def cost(R):
        return float(((c.as_matrix() - R) ** 2).sum())

    assert all(cost(M) <= cost(M @ rot.exp_so3(d)) for d in np.eye(3) * 1e-3)
    assert all(cost(M) <= cost(M @ rot.exp_so3(-d)) for d in np.eye(3) * 1e-3)
    q = rot.quaternion_mean(rot.matrix_to_quaternion(c.as_matrix())[:, None])[0]
    assert np.degrees(rot.geodesic_angle(M, rot.quaternion_to_matrix(q))) < 0.1


def test_head_angles_are_yxz_euler():
    R = rot.angles_to_matrix(0.3, -0.2, 0.1)
    np.testing.assert_allclose(R, Rotation.from_euler("YXZ", [0.3, -0.2, 0.1]).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(rot.head_angles(np.stack([R, R.T @ R])), [[0.3, -0.2, 0.1], [0, 0, 0]], atol=1e-12)


def test_rotation_between_is_the_former_avatar_shortest_rotation():
    """avatar.retarget's own shortest_rotation (Rodrigues, ``I + [v]× + [v]×² / (1 + c)``) gave the same matrices."""
    rng = np.random.default_rng(13)
    for a, b in rng.normal(size=(100, 2, 3)):
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        v = np.cross(a, b)
        vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
        np.testing.assert_allclose(rot.rotation_between(a, b), np.eye(3) + vx + vx @ vx / (1 + a @ b), atol=1e-9)


def test_continuous_quaternions_is_the_key_by_key_flip():
    q = rot.matrix_to_quaternion(Rotation.from_rotvec(np.cumsum(np.full((80, 3, 3), 0.4), 0)).as_matrix())
    q = q * np.random.default_rng(17).choice([-1.0, 1.0], (80, 3, 1))
    want = q.copy()
    for t in range(1, len(want)):  # the loop vrm.animation had
        flip = np.sum(want[t] * want[t - 1], -1) < 0
        want[t, flip] *= -1
    got = rot.continuous_quaternions(q)
    np.testing.assert_array_equal(got, want)
    assert np.all(np.sum(got[1:] * got[:-1], -1) >= 0)


def test_batched_exp_log_so3_match_scipy_and_invert():
    """exp_so3 / log_so3 on batches (…, 3) ↔ (…, 3, 3) equal scipy's rotvec conversions, small angles and near π too."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(7)
    axes = rng.normal(size=(400, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([rng.uniform(0, np.pi - 1e-3, 360), np.full(20, 1e-9), np.full(20, np.pi - 1e-6)])
    v = (axes * angles[:, None]).reshape(20, 20, 3)
    R = rot.exp_so3(v)
    np.testing.assert_allclose(R, Rotation.from_rotvec(v.reshape(-1, 3)).as_matrix().reshape(20, 20, 3, 3), atol=1e-12)
    back = rot.log_so3(R)
    assert back.shape == (20, 20, 3)
    np.testing.assert_allclose(rot.exp_so3(back), R, atol=1e-6)  # near π the sign of the axis may flip: same rotation
    ok = angles.reshape(20, 20) < np.pi - 1e-3
    np.testing.assert_allclose(back[ok], v[ok], atol=1e-9)
    assert rot.exp_so3(np.zeros(3)).tolist() == np.eye(3).tolist()


def test_twist_angle_is_the_rotation_about_the_axis():
    """A twist about x followed by a swing about y or z: twist_angle(…, "X") gives the twist back."""
    rng = np.random.default_rng(3)
    tw = rng.uniform(-3.0, 3.0, 50)
    swing = rng.uniform(-1.0, 1.0, (50, 2))
    R = rot.exp_so3(np.c_[np.zeros(50), swing]) @ rot.exp_so3(np.c_[tw, np.zeros((50, 2))])
    np.testing.assert_allclose(rot.twist_angle(R, "X"), tw, atol=1e-9)


def test_quaternion_fast_paths_keep_the_bits():
    """The engine's fast paths give the same bits as the plain formulas: ``quaternion_to_rot6d`` as
    ``matrix_to_rot6d(quaternion_to_matrix(·))``, ``quaternion_multiply`` as the component-wise Hamilton
    product summed left to right (float32 and float64, broadcast, zeros of either sign)."""
    rng = np.random.default_rng(7)
    for dtype in (np.float32, np.float64):
        q = rng.normal(size=(3, 47, 4)).astype(dtype)
        q[0, 0], q[1, 1, 1:] = 0.0, -0.0
        a, b = rot.matrix_to_rot6d(rot.quaternion_to_matrix(q)), rot.quaternion_to_rot6d(q)
        assert a.dtype == b.dtype and np.ascontiguousarray(a).tobytes() == b.tobytes()
        m = rng.normal(size=(47, 4)).astype(dtype)
        m[0, :2] = -0.0
        for other in (q, rng.normal(size=(16, 47, 4)).astype(dtype)):  # one-call form and per component
            _check_hamilton(m, other)


def _matrix_to_quaternion_reference(m: np.ndarray) -> np.ndarray:
    """The component-wise formula of ``matrix_to_quaternion`` (its torch branch's, in NumPy)."""
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    w2, x2, y2, z2 = 1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22
    r21, r12, r02, r20, r10, r01 = m[..., 2, 1], m[..., 1, 2], m[..., 0, 2], m[..., 2, 0], m[..., 1, 0], m[..., 0, 1]
    cands = np.stack([w2, x2, y2, z2], -1)
    best = np.argmax(cands, axis=-1)
    allq = np.stack(
        [
            np.stack([w2, r21 - r12, r02 - r20, r10 - r01], -1),
            np.stack([r21 - r12, x2, r01 + r10, r02 + r20], -1),
            np.stack([r02 - r20, r01 + r10, y2, r12 + r21], -1),
            np.stack([r10 - r01, r02 + r20, r12 + r21, z2], -1),
        ],
        -2,
    )
    s2 = np.take_along_axis(cands, best[..., None], axis=-1)
    q = np.take_along_axis(allq, best[..., None, None], axis=-2)[..., 0, :] / (np.sqrt(np.maximum(s2, 1e-8)) * 2.0)
    q = np.where(q[..., :1] < 0, -q, q)
    return q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), 1e-8)


def test_matrix_to_quaternion_keeps_the_bits():
    """NumPy's ``matrix_to_quaternion`` (candidates and picks in a few calls) gives the bits of the component-wise
    formula: float32 and float64, one matrix or a batch, exact zeros (rotations about one axis, the identity, a
    half turn), ties between candidates, noise off the rotation group, a NaN."""
    rng = np.random.default_rng(11)
    for k in range(300):
        n = (1, 2, 47, 55)[k % 4]
        q = rng.normal(size=(n, 4))
        q[: n // 2, rng.integers(0, 4)] = 0.0
        if k % 5 == 0:
            q[0] = (1.0, 0.0, 0.0, 0.0) if k % 2 else (0.0, 0.0, -1.0, 0.0)
        m = rot.quaternion_to_matrix(q)
        if k % 7 == 0:
            m = m + rng.normal(size=m.shape) * 1e-3
        if k % 11 == 0:
            m[-1, 1, 1] = np.nan
        for dtype in (np.float64, np.float32):
            x = m.astype(dtype)
            got, want = rot.matrix_to_quaternion(x), _matrix_to_quaternion_reference(x)
            assert got.dtype == want.dtype and got.shape == want.shape and got.tobytes() == want.tobytes()
        one = m[0]  # no leading axes
        assert rot.matrix_to_quaternion(one).tobytes() == _matrix_to_quaternion_reference(one).tobytes()


def _check_hamilton(m: np.ndarray, q: np.ndarray) -> None:
    got = rot.quaternion_multiply(m, q)
    aw, ax, ay, az = (m[..., i] for i in range(4))
    bw, bx, by, bz = (q[..., i] for i in range(4))
    want = np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        -1,
    )
    assert got.dtype == want.dtype and got.tobytes() == want.tobytes()


def test_vector_norm_keeps_numpys_bits():
    """``vector_norm`` sums fewer than 8 squares by explicit additions (left to right, as ``add.reduce`` does
    there): the bits of ``np.linalg.norm(·, axis=-1)`` for the engine's shapes, float32 and float64."""
    rng = np.random.default_rng(11)
    for dtype in (np.float32, np.float64):
        for shape in ((3,), (1, 47, 3), (300, 47, 3), (1, 47, 4), (64, 47, 4), (5, 2), (5, 7), (5, 9), (4, 1)):
            a = (rng.normal(size=shape) * 10.0 ** rng.uniform(-6, 6, size=shape)).astype(dtype)
            a.flat[0] = -0.0
            ref = np.linalg.norm(a, axis=-1)
            got = rot.vector_norm(a)
            assert got.dtype == ref.dtype and np.asarray(got).tobytes() == np.asarray(ref).tobytes(), (dtype, shape)


def test_quaternion_log_exp_and_power_of_one_rotation_do_not_depend_on_the_others():
    """The small-angle (and near-equal) branches are taken only when some entry needs them: each entry's bits are
    the same alone and among others that do or do not need them."""
    rng = np.random.default_rng(7)
    v = rng.normal(size=(64, 3))
    v[::3] *= 1e-11  # some angles below the branch's threshold
    q = rot.quaternion_exp(v)
    ref = rot.quaternion_exp(rng.normal(size=(64, 3)))
    near = ref.copy()
    near[::4] = ref[::4] + 1e-12  # some pairs nearly equal
    together = (rot.quaternion_exp(v), rot.quaternion_log(q), rot.quaternion_power_about(near, ref, 0.3))
    for i in range(len(v)):
        alone = (rot.quaternion_exp(v[i]), rot.quaternion_log(q[i]), rot.quaternion_power_about(near[i], ref[i], 0.3))
        for a, b in zip(alone, together, strict=True):
            assert np.array_equal(a, b[i])
