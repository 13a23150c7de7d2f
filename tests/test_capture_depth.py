"""RGB-D head pose: K-means foreground, point cloud, ICP on depth rendered from the canonical mesh."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from facecapges.capture import depth as dp
from facecapges.capture.head_pose import Intrinsics
from facecapges.errors import UserError
from facecapges.rotations import angles_to_matrix, geodesic_angle

K = Intrinsics(200.0, 200.0, 80.0, 60.0)


@pytest.fixture(scope="module")
def mesh():
    from facecapges.capture.canonical_mesh import load_canonical_mesh
    from facecapges.capture.models import resolve_model

    try:
        return load_canonical_mesh(resolve_model())
    except UserError as exc:
        pytest.skip(str(exc))


def test_icp_svd_step_recovers_a_rigid_motion(mesh):
    V = mesh.vertices / 100
    R = angles_to_matrix(0.1, -0.05, 0.03)
    t = np.array([0.01, -0.005, 0.02])
    R2, t2, rms = dp.icp(V @ R.T + t, V)
    assert math.degrees(float(geodesic_angle(R2, R))) < 0.01 and np.allclose(t2, t, atol=1e-5) and rms < 1e-6


def test_tracking_rendered_depth_under_known_motion(mesh, tmp_path):
    V = mesh.vertices / 100
    tracker = dp.DepthHeadTracker(V, K)
    for k in range(5):
        R = angles_to_matrix(math.radians(4 * k), math.radians(-3 * k), math.radians(k))
        t = np.array([0.01 * k, -0.005 * k, -0.6 - 0.01 * k])
        D = dp.render_depth(V @ R.T + t, mesh.triangles, K, 160, 120, background_mm=1500)
        if k == 0:
            fg = dp.foreground_mask(D)
            assert 0 < fg.sum() < (D < 1000).sum() + 1 and not fg[D >= 1500].any()  # wall is background
            path = tmp_path / "d.png"
            import cv2

            cv2.imwrite(str(path), D.astype(np.uint16))
            np.testing.assert_allclose(dp.read_depth(path), np.round(D), atol=1)
        pose = tracker.update(D)
        assert math.degrees(float(geodesic_angle(pose.R, R))) < 2.0, k
        assert np.linalg.norm(pose.t / 100 - t) < 0.01


def test_depth_inputs_are_checked(tmp_path):
    with pytest.raises(UserError, match="together"):
        dp.check_depth_inputs(tmp_path, None)
    with pytest.raises(UserError, match="no depth frames"):
        dp.list_depth_frames(tmp_path)
    k = tmp_path / "K.json"
    k.write_text(json.dumps({"fx": 1}))
    with pytest.raises(UserError, match="intrinsics"):
        dp.load_intrinsics(k)
    k.write_text(json.dumps({"K": [[500, 0, 320], [0, 501, 240], [0, 0, 1]]}))
    assert dp.load_intrinsics(k) == Intrinsics(500, 501, 320, 240)
    bad = tmp_path / "x.png"
    import cv2

    cv2.imwrite(str(bad), np.zeros((4, 4), np.uint8))
    with pytest.raises(UserError, match="16-bit"):
        dp.read_depth(bad)
