"""The face capture's compiled steps (:mod:`facecapges.capture.kernels`) give the NumPy path's bits: the check a
process makes once, on more seeds; and a whole face's capture, compiled and not, frame for frame."""

from __future__ import annotations

import numpy as np
import pytest

from facecapges import rotations as rot
from facecapges.capture import kernels
from facecapges.capture.canonical_mesh import load_canonical_mesh
from facecapges.capture.estimator import N_UNITS, ExpressionEstimator
from facecapges.capture.head_pose import HeadPose, HeadPoseEstimator, PoseSmoother, landmarks_to_camera
from facecapges.capture.metrics import compute_metrics
from facecapges.capture.models import resolve_model
from facecapges.capture.samples import sample_weight
from facecapges.capture.synthetic import synthetic_sequence


def test_the_check_passes_here():
    assert kernels.compiled() is kernels


@pytest.mark.parametrize("seed", range(1, 13))
def test_the_check_on_more_seeds(seed):
    assert kernels.checked(seed)


def test_signed_zeros_in_a_range_scan():
    """A one-directional node on one −0.0 sample: NumPy's sum starts from +0.0, so the node is +0.0."""
    est = ExpressionEstimator("geometric", capacity=4, compiled=False)
    values, weights = est.samples.values, est.samples.weights
    values[:, :4] = [-0.38, -0.109, -0.0, 0.09]
    weights[:, :4] = [0.0024, 0.041, 0.89, 0.92]
    est.samples.size = 4
    nodes = est.nodes.copy()
    assert kernels.estimate_ranges(values, weights, 4, np.arange(N_UNITS), est.two_dir, est.min_span, nodes)
    est.update_ranges(compiled=False)
    np.testing.assert_array_equal(nodes.view(np.uint64), est.nodes.view(np.uint64))


def test_not_finite_samples_take_the_numpy_path():
    est = ExpressionEstimator("geometric", capacity=4)
    assert est.samples.kernels is kernels
    g = np.full(N_UNITS, 0.1)
    g[3] = np.nan
    est.samples.insert(g, 0.5)  # the cold start's insert takes any metrics
    assert est.samples.size == 1 and np.isnan(est.samples.values[3, 0])
    assert not kernels.estimate_ranges(
        est.samples.values, est.samples.weights, 1, np.arange(N_UNITS), est.two_dir, est.min_span, est.nodes.copy()
    )
    est.update_ranges()  # the NumPy path: the same nodes as without the kernels
    ref = ExpressionEstimator("geometric", capacity=4, compiled=False)
    ref.samples.insert(g, 0.5)
    ref.update_ranges(compiled=False)
    np.testing.assert_array_equal(est.nodes, ref.nodes)


def test_a_synthetic_face_frame_for_frame():
    """Camera points, metrics, sample set, ranges, activations and weights of a synthetic face, compiled and not."""
    mesh = load_canonical_mesh(resolve_model(None))
    seq = synthetic_sequence(mesh.vertices, n_frames=150, seed=3)
    pe = HeadPoseEstimator(mesh.vertices, mesh.procrustes_ids, mesh.procrustes_weights)
    fast, slow = ExpressionEstimator("hybrid"), ExpressionEstimator("hybrid", compiled=False)
    rng = np.random.default_rng(3)
    for lm in seq["landmarks"]:
        args = (lm, seq["width"], seq["height"], pe.canonical, pe.weights, pe.ids, None, pe.fit)
        pts = landmarks_to_camera(*args)
        np.testing.assert_array_equal(pts.view(np.uint64), landmarks_to_camera(*args, compiled=False).view(np.uint64))
        pose, _ = pe.estimate(lm, seq["width"], seq["height"])
        P = pe.to_head_frame(pts, pose)
        g, g_ref = compute_metrics(P), compute_metrics(P, compiled=False)
        np.testing.assert_array_equal(g.view(np.uint64), g_ref.view(np.uint64))
        omega, normal = sample_weight(pose.distance_m, pose.normal), pose.normal
        np.testing.assert_array_equal(fast.update(g, omega, normal), slow.update(g, omega, normal))
        mp = rng.uniform(0, 1, 52).astype(np.float32)
        np.testing.assert_array_equal(
            fast.weights(mp).view(np.uint32), slow.weights(mp, compiled=False).view(np.uint32)
        )
    np.testing.assert_array_equal(fast.nodes, slow.nodes)
    np.testing.assert_array_equal(fast.samples.values, slow.samples.values)


def test_the_smoother_keeps_log_so3_bits():
    rng = np.random.default_rng(5)
    sm = PoseSmoother(5)
    for _ in range(60):
        R = rot.exp_so3(rng.standard_normal(3) * 0.3)
        out = sm(HeadPose(R, rng.standard_normal(3), 1.0))
        assert np.isfinite(out.R).all()
    M = rot.exp_so3(rng.standard_normal((50, 3)) * 10.0 ** rng.uniform(-8, 0.4, (50, 1)))
    v, sn, c = np.empty((50, 3)), np.empty(50), np.empty(50)
    kernels.skew_parts(M, v, sn, c)
    assert kernels.scale_skew(v, sn, np.arctan2(sn, c))
    np.testing.assert_array_equal(v.view(np.uint64), rot.log_so3(M).view(np.uint64))
