"""Head pose (Procrustes, lifting, smoothing) and the geometric metrics."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facecapges.capture import head_pose as hp
from facecapges.capture.metrics import METRIC_NAMES, compute_metrics
from facecapges.errors import UserError
from facecapges.rotations import angles_to_matrix, geodesic_angle, head_angles, rot6d_to_matrix


@pytest.fixture(scope="module")
def mesh():
    from facecapges.capture.canonical_mesh import load_canonical_mesh
    from facecapges.capture.models import resolve_model

    try:
        return load_canonical_mesh(resolve_model())
    except UserError as exc:
        pytest.skip(str(exc))


angles = st.floats(-1.2, 1.2)


@settings(max_examples=30, deadline=None)
@given(angles, angles, angles, st.floats(0.2, 5.0))
def test_procrustes_recovers_a_similarity(a, b, c, s):
    rng = np.random.default_rng(0)
    src = rng.normal(size=(30, 3))
    R = angles_to_matrix(a, b, c)
    t = np.array([1.0, -2.0, 3.0])
    s2, R2, t2 = hp.procrustes(src, s * src @ R.T + t, rng.uniform(0.5, 1, 30))
    assert math.isclose(s2, s, rel_tol=1e-9)
    np.testing.assert_allclose(R2, R, atol=1e-9)
    np.testing.assert_allclose(t2, t, atol=1e-8)


def _procrustes_reference(src, dst, weights, with_scale):
    """:func:`procrustes` as written before :class:`SourceFit` (both sides computed every call)."""
    w = np.ones(len(src)) if weights is None else np.asarray(weights, np.float64)
    w = w / w.sum()
    mu_s, mu_d = w @ src, w @ dst
    a, b = src - mu_s, dst - mu_d
    u, sig, vt = np.linalg.svd((b * w[:, None]).T @ a)
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    D = np.array([1.0, 1.0, d])
    R = (u * D) @ vt
    s = float((sig * D).sum() / max(float(w @ (a * a).sum(axis=1)), 1e-12)) if with_scale else 1.0
    return s, R, mu_d - s * R @ mu_s


@pytest.mark.parametrize("with_scale", [True, False])
@pytest.mark.parametrize("weighted", [True, False])
def test_procrustes_with_a_source_fit_keeps_the_bits(with_scale, weighted):
    """A :class:`SourceFit` made once (the head pose's canonical basis) gives the same bits as the fit computed
    whole each call, with or without it, with or without weights and scale."""
    rng = np.random.default_rng(3)
    src = rng.normal(size=(40, 3))
    w = rng.uniform(0.2, 1.0, 40) if weighted else None
    fit = hp.SourceFit.of(src, w, with_scale)
    for _ in range(20):
        dst = rng.uniform(0.5, 2.0) * src @ angles_to_matrix(*rng.uniform(-1, 1, 3)).T + rng.normal(size=(40, 3))
        ref = _procrustes_reference(src, dst, w, with_scale)
        for got in (hp.procrustes(src, dst, w, with_scale), hp.procrustes(None, dst, with_scale=with_scale, fit=fit)):
            assert got[0] == ref[0] and got[1].tobytes() == ref[1].tobytes() and got[2].tobytes() == ref[2].tobytes()


def test_head_angles_round_trip_and_signs():
    R = angles_to_matrix(0.3, -0.2, 0.1)
    np.testing.assert_allclose(head_angles(R), [0.3, -0.2, 0.1], atol=1e-12)
    # yaw > 0 turns the face normal (+Z) towards +X (the image's right)
    assert angles_to_matrix(0.3, 0, 0)[0, 2] > 0
    # pitch > 0 tilts the face down: normal gets −Y; roll > 0 turns X towards +Y
    assert angles_to_matrix(0, 0.3, 0)[1, 2] < 0
    assert angles_to_matrix(0, 0, 0.3)[1, 0] > 0


def _project(V, R, dist_cm, W=1280, H=720):
    K = hp.Intrinsics.default(W, H)
    C = V @ R.T + [0, 0, -dist_cm]
    z = -C[:, 2]
    L = np.zeros((478, 3))
    L[:468, 0] = (C[:, 0] / z * K.fx + K.cx) / W
    L[:468, 1] = (-C[:, 1] / z * K.fy + K.cy) / H
    L[:468, 2] = -(C[:, 2] + dist_cm) * (K.fx / dist_cm) / W
    return L


@pytest.mark.parametrize("ypr", [(0, 0, 0), (0.4, 0, 0), (0, -0.3, 0.2), (-0.45, 0.25, -0.15)])
def test_pose_from_projected_canonical_face(mesh, ypr):
    est = hp.HeadPoseEstimator(mesh.vertices, mesh.procrustes_ids, mesh.procrustes_weights)
    R = angles_to_matrix(*ypr)
    pose, pts = est.estimate(_project(mesh.vertices, R, 60.0), 1280, 720)
    assert math.degrees(float(geodesic_angle(pose.R, R))) < 0.5
    assert abs(pose.distance_m - 0.60) < 0.02
    np.testing.assert_allclose(rot6d_to_matrix(pose.rot6d.astype(np.float64)), pose.R, atol=1e-6)
    # metrics of the posed face equal those of the canonical face (pose removed, scale normalised)
    np.testing.assert_allclose(compute_metrics(est.to_head_frame(pts, pose)), compute_metrics(mesh.vertices), atol=2e-3)


@settings(max_examples=20, deadline=None)
@given(angles, angles, angles, st.floats(0.1, 10.0))
def test_metrics_invariant_to_similarity(mesh, a, b, c, s):
    R = angles_to_matrix(a, b, c)
    P = mesh.vertices
    np.testing.assert_allclose(compute_metrics((s * P @ R.T) @ R), compute_metrics(P) * 1.0, atol=1e-9)


def test_metrics_respond_to_their_landmarks(mesh):
    P = mesh.vertices.copy()
    base = compute_metrics(P)
    P[[14, 87, 317], 1] -= 1.0  # lower lip down
    P[[386, 385, 387], 1] -= 0.3  # left upper lid down
    g = compute_metrics(P)
    d = dict(zip(METRIC_NAMES, g - base))
    assert d["lip_gap"] > 0.2 and d["eyelid_L"] < -0.05 and abs(d["eyelid_R"]) < 1e-12
    assert abs(d["brow_height_L"]) < 1e-12


def test_smoother_has_no_lag_on_a_ramp_and_reduces_jitter():
    sm = hp.PoseSmoother(window=5)
    rng = np.random.default_rng(0)
    errs_raw, errs_s, lag = [], [], []
    for k in range(60):
        yaw = 0.01 * k  # constant angular velocity
        R_true = angles_to_matrix(yaw, 0, 0)
        noisy = angles_to_matrix(yaw + rng.normal(0, 0.01), rng.normal(0, 0.01), 0)
        out = sm(hp.HeadPose(noisy, np.zeros(3)))
        if k >= 5:
            errs_raw.append(float(geodesic_angle(noisy, R_true)))
            errs_s.append(float(geodesic_angle(out.R, R_true)))
            lag.append(yaw - head_angles(out.R)[0])
    assert np.mean(errs_s) < 0.85 * np.mean(errs_raw)
    assert abs(np.mean(lag)) < 0.01 * 0.5  # well under one frame (0.01 rad per frame)
    # a jump beyond reset_deg is followed at once
    out = sm(hp.HeadPose(angles_to_matrix(1.5, 0, 0), np.zeros(3)))
    assert abs(head_angles(out.R)[0] - 1.5) < 1e-9


def test_the_fits_determinant_sign_is_lapacks():
    """procrustes' reflection test (the sign of det(U Vᵀ), ±1 to rounding) by cofactors is LAPACK's sign (issue 36)."""
    rng = np.random.default_rng(4)
    for _ in range(300):
        u, _, vt = np.linalg.svd(rng.normal(size=(3, 3)) * 10.0 ** rng.integers(-6, 6))
        m = u @ vt
        assert hp._det_sign(m) == np.sign(np.linalg.det(m)) and abs(hp._det_sign(m)) == 1.0
    assert hp._det_sign(np.diag([1.0, 1.0, 0.0])) == 1.0  # 0 counts as no reflection, as before
    assert math.isnan(hp._det_sign(np.full((3, 3), np.nan)))


def test_lifted_points_keep_the_stacked_formulas_bits(mesh):
    """landmarks_to_camera writes its columns in place: the numbers of the np.stack formulas (issue 36)."""
    rng = np.random.default_rng(6)
    est = hp.HeadPoseEstimator(mesh.vertices, mesh.procrustes_ids, mesh.procrustes_weights)
    for w, h in ((512, 512), (640, 480)):
        lm = np.column_stack([rng.uniform(0.3, 0.7, 478), rng.uniform(0.3, 0.7, 478), rng.normal(0, 0.05, 478)])
        lm[::9, 2] = 0.0  # signed zeros
        got = hp.landmarks_to_camera(lm.astype(np.float32), w, h, est.canonical, est.weights, est.ids)
        x = np.asarray(lm.astype(np.float32)[:468], np.float64)
        px, py = x[:, 0] * w, x[:, 1] * h
        ortho = np.stack([px, -py, -x[:, 2] * w], axis=1)
        s, _, t = hp.procrustes(est.canonical[est.ids], ortho[est.ids], est.weights)
        K = hp.Intrinsics.default(w, h)
        z = K.fx / s - (ortho[:, 2] - t[2]) / s
        want = np.stack([(px - K.cx) * z / K.fx, -(py - K.cy) * z / K.fy, -z], axis=1)
        assert got.tobytes() == want.tobytes()


def _smoothed_one_log_at_a_time(poses, window: int, reset_deg: float) -> list[np.ndarray]:
    """PoseSmoother as it was before issue 36 (the jump and the window each their own log_so3 call)."""
    from collections import deque

    from facecapges.rotations import exp_so3, log_so3

    Rs: deque = deque(maxlen=window)
    ts: deque = deque(maxlen=window)
    coef = {m: hp.PoseSmoother._endpoint_weights(m) for m in range(1, window + 1)}
    out = []
    for R_new, t_new in poses:
        if Rs and hp._norm(log_so3(Rs[-1].T @ R_new)) > math.radians(reset_deg):
            Rs.clear()
            ts.clear()
        Rs.append(R_new.copy())
        ts.append(t_new.copy())
        c = coef[len(Rs)]
        out.append(np.concatenate([(R_new @ exp_so3(c @ log_so3(R_new.T @ np.stack(Rs)))).ravel(), c @ np.stack(ts)]))
    return out


@pytest.mark.parametrize("window", [1, 2, 5])
def test_smoother_keeps_the_bits_of_one_log_call_at_a_time(window):
    """The smoother's one log_so3 call a frame (the jump and the window together) makes the numbers the two calls
    made, resets included (issue 36)."""
    rng = np.random.default_rng(window)
    poses, yaw = [], 0.0
    for k in range(80):
        yaw += 0.6 if k % 17 == 16 else 0.02  # a jump past reset_deg now and then
        R = angles_to_matrix(yaw + rng.normal(0, 0.01), rng.normal(0, 0.02), rng.normal(0, 0.01))
        poses.append((R, rng.normal(size=3) * 10.0))
    sm = hp.PoseSmoother(window=window, reset_deg=20.0)
    got = [np.concatenate([p.R.ravel(), p.t]) for p in (sm(hp.HeadPose(R, t)) for R, t in poses)]
    want = _smoothed_one_log_at_a_time(poses, window, 20.0)
    assert np.array_equal(np.array(got).view(np.int64), np.array(want).view(np.int64))


def test_metrics_means_and_norms_keep_numpys_bits():
    """``metrics._mean`` and the norms it uses are ``mean(axis=-1)`` and ``np.linalg.norm(axis=-1)``'s own arithmetic:
    the same bits on one frame's points and on batches (issue 36)."""
    from facecapges.capture import metrics as M
    from facecapges.rotations import vector_norm

    rng = np.random.default_rng(3)
    for shape in [(2,), (3,), (4,), (6,), (9,), (5, 4), (2, 3, 7)]:
        x = rng.normal(size=shape) * 10.0
        assert M._mean(x).tobytes() == x.mean(axis=-1).tobytes()
    for shape in [(3,), (8, 3), (2, 4, 3)]:
        v = rng.normal(size=shape)
        assert vector_norm(v).tobytes() == np.linalg.norm(v, axis=-1).tobytes()
