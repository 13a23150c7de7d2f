"""Sample set (eq. 4–7), range estimation (eq. 8–9) and the calibration-free estimator."""

from __future__ import annotations

import math

import numpy as np
import pytest

from facecapges.arkit import ARKIT_NAMES
from facecapges.capture import ranges, samples
from facecapges.capture.estimator import GEOMETRIC_MASK, N_UNITS, UNITS, ExpressionEstimator, units_to_arkit
from facecapges.capture.metrics import METRIC_NAMES
from facecapges.errors import UserError


def test_sample_weight_formula():
    assert samples.sample_weight(0.5, np.array([0, 0, 1.0])) == pytest.approx(1.0)
    assert samples.sample_weight(1.0, np.array([0, 0, 1.0])) == pytest.approx(0.9)  # 1 − 0.5·0.2
    n = np.array([math.sin(math.radians(60)), 0, math.cos(math.radians(60))])
    assert samples.sample_weight(0.5, n) == pytest.approx(math.sqrt(0.5))
    assert samples.sample_weight(0.5, np.array([0, 0, -1.0])) == 0.0  # facing away


@pytest.mark.parametrize("omega", [0.4, 0.6, 0.9, 0.99])
def test_compensation_samples_satisfy_the_density_ratio(omega):
    d = samples.compensation_delta(omega)
    sigma = -math.log(omega)
    f = lambda x: math.exp(-x * x / (2 * sigma * sigma))  # noqa: E731 (Gaussian density up to a constant)
    assert omega / ((1 - omega) / 2) == pytest.approx(f(0) / f(d), rel=1e-9)
    assert math.isnan(samples.compensation_delta(0.3)) and samples.compensation_delta(1.0) == 0.0


def test_sample_set_drops_merges_and_stays_bounded():
    s = samples.SampleSet(2, capacity=4, scales=np.array([1.0, 2.0]))
    assert not s.add(np.array([0.0, 0.0]), 0.2)  # ω < 1/3: dropped
    assert s.size == 0 and s.n_dropped == 1
    assert s.add(np.array([1.0, 1.0]), 1.0) and s.size == 1  # ω = 1: no compensation samples
    assert s.add(np.array([5.0, 5.0]), 0.8) and s.size == 4  # + two compensation samples
    d = samples.compensation_delta(0.8)
    np.testing.assert_allclose(sorted(s.values[1, :4]), sorted([1.0, 5.0, 5 + 2 * d, 5 - 2 * d]))
    np.testing.assert_allclose(s.weights[0, :4].sum(), 1.0 + 0.8 + 0.2)
    # full: a new sample merges with its nearest neighbour (eq. 6–7)
    s.insert(np.array([1.5, 1.5]), 1.0)
    assert s.size == 4
    v, w = s.unit(0)
    assert v[0] == pytest.approx((1.0 * 1 + 1.5 * 1) / 2) and w[0] == pytest.approx(2.0)


def test_scan_end_skips_isolated_outliers():
    v = np.concatenate([[-5.0], np.linspace(0, 1, 40)])
    w = np.ones_like(v)
    lo = ranges.scan_end(v, w)
    assert 0 <= lo < 0.1  # the lone −5 sample is not the node
    lo2, hi = ranges.one_directional_range(v, w)
    assert lo2 == lo and 0.9 < hi <= 1.0


def test_two_directional_nodes_on_three_groups():
    rng = np.random.default_rng(0)
    v = np.sort(np.concatenate([rng.normal(-1, 0.02, 5), rng.normal(0, 0.02, 30), rng.normal(1, 0.02, 5)]))
    g0, g1, g2 = ranges.two_directional_range(v, np.ones_like(v))
    assert abs(g0 + 1) < 0.05 and abs(g1) < 0.05 and abs(g2 - 1) < 0.05
    assert ranges.merge_to_three(np.array([2.0]), np.array([1.0])) == (2.0, 2.0, 2.0)
    # eq. 8 and 9
    assert ranges.one_directional_weight(1.5, 1.0, 3.0) == 0.25
    np.testing.assert_allclose(ranges.two_directional_weight([-1, -0.5, 0, 0.5, 2], -1, 0, 1), [-1, -0.5, 0, 0.5, 2])


def test_cold_start_reads_the_first_frame_as_rest_and_output_is_bounded():
    est = ExpressionEstimator("geometric")
    g = np.array([0.1, 1.7, 0.0, 0.7, 0.7, 0.26, 0.26, 1.1, 1.1, 0.6, 0.0, 0.0, 0.8])
    a = est.update(g, 0.95)
    np.testing.assert_allclose(a, 0.0, atol=1e-9)
    assert np.all(est.weights() == 0)
    # an open mouth on frame 2 is measured against the prior span at once
    g2 = g.copy()
    for m in ("lip_gap", "jaw_drop"):  # the lower lip down
        u = METRIC_NAMES.index(m)
        g2[u] += UNITS[u].min_span
    est.update(g2, 0.95)
    w = est.weights()
    assert w[ARKIT_NAMES.index("jawOpen")] > 0.3
    assert np.all((w >= 0) & (w <= 1))
    assert np.isfinite(est.activations).all()


def test_modes():
    mp = np.linspace(0, 1, 52).astype(np.float32)
    g = np.full(N_UNITS, 0.5)
    with pytest.raises(ValueError):
        ExpressionEstimator("learned")
    e = ExpressionEstimator("mediapipe")
    e.update(g, 1.0)
    np.testing.assert_allclose(e.weights(mp), mp)
    for mode in ("geometric", "hybrid"):
        e = ExpressionEstimator(mode)
        e.update(g, 1.0)
        w = e.weights(mp)
        other = ~GEOMETRIC_MASK
        np.testing.assert_allclose(w[other], mp[other] if mode == "hybrid" else 0)
    # units → ARKit: exaggerated values are clipped
    a = np.zeros(N_UNITS)
    a[METRIC_NAMES.index("jaw_drop")] = 3.0
    assert units_to_arkit(a)[ARKIT_NAMES.index("jawOpen")] == 1.0


def test_weighted_median_is_the_cumsum_and_searchsorted_one():
    """The weighted median over Python floats picks what ``np.cumsum`` and ``np.searchsorted`` pick (issue 36),
    zero weights and ties included."""
    rng = np.random.default_rng(2)
    for n in (1, 2, 3, 8, 32, 33):
        for _ in range(50):
            v = np.sort(rng.normal(size=n))
            w = rng.choice([0.0, 0.1, 1 / 3, 0.5, 1.0], size=n) if n > 1 else np.array([0.7])
            w[rng.integers(0, n)] = 1.0
            c = np.cumsum(w)
            want = float(v[min(int(np.searchsorted(c, 0.5 * c[-1])), n - 1)])
            assert ranges.weighted_median(v, w) == want


def _units_to_arkit_channel_by_channel(a: np.ndarray) -> np.ndarray:
    """units_to_arkit as it was before issue 36: the module docstring's table, one expression per channel."""
    from facecapges.capture import estimator as E

    U, A = {u.metric: i for i, u in enumerate(UNITS)}, {n: i for i, n in enumerate(ARKIT_NAMES)}
    pos, neg = np.clip(a, 0.0, 1.0), np.clip(-a, 0.0, 1.0)
    out = np.zeros(a.shape[:-1] + (len(ARKIT_NAMES),))
    out[..., A["jawOpen"]] = pos[..., U["jaw_drop"]] ** E.JAW_GAMMA
    lips, narrow, wide = pos[..., U["lip_gap"]], neg[..., U["mouth_width"]], pos[..., U["mouth_width"]]
    out[..., A["mouthPucker"]] = narrow * (1.0 - lips)
    out[..., A["mouthFunnel"]] = narrow * lips
    lift = 0.5 * (pos[..., U["mouth_corner_L"]] + pos[..., U["mouth_corner_R"]])
    for side in ("Left", "Right"):
        s = side[0]
        out[..., A[f"mouthSmile{side}"]] = (1.0 - E.SMILE_CORNER) * wide + E.SMILE_CORNER * lift
        out[..., A[f"mouthFrown{side}"]] = neg[..., U[f"mouth_corner_{s}"]]
        out[..., A[f"mouthStretch{side}"]] = wide * (1.0 - pos[..., U[f"mouth_corner_{s}"]])
        out[..., A[f"browOuterUp{side}"]] = pos[..., U[f"brow_height_{s}"]]
        out[..., A[f"browDown{side}"]] = neg[..., U[f"brow_height_{s}"]]
        out[..., A[f"eyeBlink{side}"]] = neg[..., U[f"eyelid_{s}"]] ** E.BLINK_GAMMA
        out[..., A[f"eyeWide{side}"]] = pos[..., U[f"eyelid_{s}"]]
        out[..., A[f"noseSneer{side}"]] = neg[..., U[f"nose_{s}"]]
    out[..., A["jawLeft"]] = pos[..., U["lip_offset"]]
    out[..., A["jawRight"]] = neg[..., U["lip_offset"]]
    out[..., A["browInnerUp"]] = pos[..., U["brow_inner"]]
    return np.clip(out, 0.0, 1.0)


def test_units_to_arkit_by_groups_keeps_the_channel_by_channel_bits():
    """units_to_arkit's groups (one NumPy call each) make the numbers of one expression per channel, signed zeros
    and NaN included, on one frame and on batches (issue 36)."""
    rng = np.random.default_rng(5)
    for shape in [(N_UNITS,), (7, N_UNITS), (2, 3, N_UNITS)]:
        for scale in (0.3, 1.0, 3.0):
            a = rng.normal(size=shape) * scale
            a.flat[::5] = 0.0
            a.flat[1::7] = -0.0
            a.flat[3::11] = np.nan
            got, want = units_to_arkit(a), _units_to_arkit_channel_by_channel(a)
            assert got.shape == want.shape and got.tobytes() == want.tobytes()


def test_synthetic_sequences_recover_known_parameters():
    from facecapges.capture.canonical_mesh import load_canonical_mesh
    from facecapges.capture.head_pose import HeadPoseEstimator
    from facecapges.capture.models import resolve_model
    from facecapges.capture.synthetic import run_geometric, synthetic_mae, synthetic_sequence

    try:
        mesh = load_canonical_mesh(resolve_model())
    except UserError as exc:
        pytest.skip(str(exc))
    pe = HeadPoseEstimator(mesh.vertices, mesh.procrustes_ids, mesh.procrustes_weights)
    for seed in (0, 1):
        seq = synthetic_sequence(mesh.vertices, 300, seed=seed)
        mae = synthetic_mae(seq, run_geometric(seq, pe), skip_frames=30)
        assert mae["mean"] <= 0.1, mae
        assert mae["jawOpen"] <= 0.1 and mae["eyeBlinkLeft"] <= 0.1, mae


def test_a_toothy_smile_does_not_open_the_jaw_and_smiles_symmetrically():
    """The upper lip lifted off the teeth (a toothy smile: lip gap up, jaw shut) leaves jawOpen at 0; the lower lip
    dropped by as much opens it. A smile's corner lift counts on both sides alike (issue 33)."""
    from facecapges.capture.canonical_mesh import load_canonical_mesh
    from facecapges.capture.metrics import MOUTH_CORNER_L, compute_metrics, eye_corner_distance
    from facecapges.capture.models import resolve_model
    from facecapges.capture.synthetic import LOWER_LIP

    try:
        V = load_canonical_mesh(resolve_model()).vertices
    except UserError as exc:
        pytest.skip(str(exc))
    w = float(eye_corner_distance(V))
    upper_lip = (13, 82, 312, 0, 37, 267)
    jaw = ARKIT_NAMES.index("jawOpen")

    def face(lower=0.0, upper=0.0, corner_l=0.0):
        P = V.copy()
        P[list(LOWER_LIP), 1] -= lower * w
        P[list(upper_lip), 1] += upper * w
        P[MOUTH_CORNER_L, 1] += corner_l * w
        return compute_metrics(P)

    est = ExpressionEstimator("geometric")
    rng = np.random.default_rng(0)
    for _ in range(120):  # talking: the jaw at rest most of the time, open now and then
        est.update(face(lower=max(0.0, rng.normal(0.0, 0.2))), 1.0)
    est.update(face(lower=0.3), 1.0)
    opened = est.weights()[jaw]
    est.update(face(upper=0.3), 1.0)
    smile = est.weights()
    assert opened > 0.3 and smile[jaw] < 0.05, (opened, smile[jaw])
    est.update(face(corner_l=0.06), 1.0)
    w2 = est.weights()
    left, right = w2[ARKIT_NAMES.index("mouthSmileLeft")], w2[ARKIT_NAMES.index("mouthSmileRight")]
    assert left > 0.05 and left == pytest.approx(right)


def test_the_lips_stretch_does_not_read_as_the_jaw():
    """Widening the mouth draws the lower lip down over the teeth with the jaw where it was: ``jaw_drop`` reads the
    lower lip's height at a given mouth width, so a widening that lowers the lip by ``JAW_STRETCH`` per unit of width
    leaves it unchanged, while the same lip drop at the rest width reads as the jaw (issue 33)."""
    from facecapges.capture.canonical_mesh import load_canonical_mesh
    from facecapges.capture.metrics import (
        JAW_STRETCH,
        MOUTH_CORNER_L,
        MOUTH_CORNER_R,
        compute_metrics,
        eye_corner_distance,
    )
    from facecapges.capture.models import resolve_model
    from facecapges.capture.synthetic import LOWER_LIP

    try:
        V = load_canonical_mesh(resolve_model()).vertices
    except UserError as exc:
        pytest.skip(str(exc))
    w = float(eye_corner_distance(V))
    jd, mw = METRIC_NAMES.index("jaw_drop"), METRIC_NAMES.index("mouth_width")
    rest = compute_metrics(V)
    wide = V.copy()
    wide[MOUTH_CORNER_L, 0] += 0.15 * w
    wide[MOUTH_CORNER_R, 0] -= 0.15 * w
    widened = compute_metrics(wide)[mw] - rest[mw]
    assert widened == pytest.approx(0.3, abs=0.01)
    wide[list(LOWER_LIP), 1] -= JAW_STRETCH * widened * w
    assert compute_metrics(wide)[jd] == pytest.approx(rest[jd], abs=1e-6)
    dropped = V.copy()
    dropped[list(LOWER_LIP), 1] -= JAW_STRETCH * widened * w
    assert compute_metrics(dropped)[jd] - rest[jd] == pytest.approx(JAW_STRETCH * widened, abs=1e-6)


def test_a_head_turn_does_not_shift_the_jaw_sideways():
    """The lip offset that follows the head's yaw (landmark depth error on real video) is taken out once the yaw has
    varied; a sideways jaw at a steady head still reads (issue 33: a lopsided mouth whenever she looked aside)."""
    u = METRIC_NAMES.index("lip_offset")
    left, right = ARKIT_NAMES.index("jawLeft"), ARKIT_NAMES.index("jawRight")
    g0 = np.array([0.1, 1.7, 0.0, 0.7, 0.7, 0.26, 0.26, 1.1, 1.1, 0.6, 0.0, 0.0, 0.6])
    rng = np.random.default_rng(0)

    def run(with_yaw: bool) -> tuple[float, ExpressionEstimator]:
        est = ExpressionEstimator("geometric")
        worst = 0.0
        for k in range(300):  # 12 s at 25 fps: the head turns ±20° every 4 s, the jaw stays put
            yaw = math.radians(20.0) * math.sin(2 * math.pi * k / 100)
            g = g0 + rng.normal(0.0, 0.003, g0.shape)
            g[u] += 0.15 * math.sin(yaw)  # the leak: 0.05 eye-corner distances at 20°
            est.update(g, 1.0, normal=np.array([math.sin(yaw), 0.0, math.cos(yaw)]) if with_yaw else None)
            if k >= 100:
                w = est.weights()
                worst = max(worst, float(w[left]), float(w[right]))
        return worst, est

    leaked, _ = run(False)
    worst, est = run(True)
    assert leaked > 0.3 and worst < 0.1, (leaked, worst)
    g = g0.copy()
    g[u] += 0.08  # the lower lip shifted to the subject's left with the head straight
    est.update(g, 1.0, normal=np.array([0.0, 0.0, 1.0]))
    assert est.weights()[left] > 0.5
