"""The face capture's per-frame steps after MediaPipe that compile without changing a bit (Numba), one call each
where NumPy made a dozen calls on a few numbers or Python looped over ~30 samples a unit (issue 36): the landmarks'
points before and after the head's first fit (:func:`facecapges.capture.head_pose.landmarks_to_camera`), the pose
smoother's rotation logs around NumPy's own ``arctan2``, a face's geometric metrics
(:func:`facecapges.capture.metrics.compute_metrics` of one face), a frame's merges into the bounded sample set
(:meth:`facecapges.capture.samples.SampleSet.insert`), its units' nodes
(:meth:`facecapges.capture.estimator.ExpressionEstimator.update_ranges`: :mod:`facecapges.capture.ranges`' scans
and merges), the units' activations and the 52 ARKit weights around NumPy's own powers.

Every number is the NumPy/Python path's: the same operations on the same float64s in the same order (a mean of
fewer than 8 numbers is NumPy's ``add.reduce``, left to right, and a longer sum its pairwise summation,
:func:`facecapges.capture.mouth_kernels.pairwise_sum`, both from NumPy's identity +0.0; a sample set's sort is a
stable one, as ``argsort(kind="stable")``; ``np.clip`` keeps NaN and −0.0; Python's ``min``/``max`` keep their
first argument on a tie). No transcendental function, SVD nor BLAS call is here: NumPy's (SVML, OpenBLAS) could
round otherwise than compiled code, so they stay NumPy's between the calls. Finite samples only: :func:`insert`
and :func:`estimate_ranges` return False, untouched, when a value or weight they read is not finite, and the
caller takes the NumPy path. :func:`checked` holds every kernel against its NumPy path on this machine once a
process (:func:`compiled`, ~55 ms), else the NumPy path is used throughout. Imported lazily: a process that
never captures a face does not load Numba here.
"""

from __future__ import annotations

import functools
import sys
from types import ModuleType

import numba
import numpy as np

from facecapges.capture import metrics as m
from facecapges.capture.estimator import SMILE_CORNER
from facecapges.capture.mouth_kernels import pairwise_sum
from facecapges.capture.ranges import K_PCT, L_PCT, M_PCT

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")
_LOWER_LIP = tuple(b for _, b in m.LIP_PAIRS)
_BROW_INNER = m.BROW_INNER_L + m.BROW_INNER_R


@_jit
def _sum(a: np.ndarray, lo: int, n: int) -> float:
    """``a[lo : lo + n].sum()`` of float64: NumPy's reduction adds the pairwise sum to its identity, +0.0 (a sum of
    −0.0s is +0.0)."""
    return 0.0 + pairwise_sum(a, lo, n)


@_jit
def ortho_points(lm: np.ndarray, width: int, height: int, ortho: np.ndarray) -> None:
    """``ortho`` (n, 3) ← :func:`facecapges.capture.head_pose.landmarks_to_camera`'s scaled-orthographic points of
    the first n landmarks ``lm`` (in pixels, camera axes: ``x·width``, ``−(y·height)``, ``z·−width``)."""
    for i in range(len(ortho)):
        ortho[i, 0] = np.float64(lm[i, 0]) * width
        ortho[i, 1] = -(np.float64(lm[i, 1]) * height)
        ortho[i, 2] = np.float64(lm[i, 2]) * -width


@_jit
def lift_points(
    ortho: np.ndarray, s: float, t_z: float, fx: float, fy: float, cx: float, cy: float, out: np.ndarray
) -> None:
    """``out`` ← :func:`facecapges.capture.head_pose.landmarks_to_camera`'s camera-frame points (cm) of
    :func:`ortho_points`' ``ortho`` after the similarity fit's scale ``s`` and depth offset ``t_z``: each point at the
    head's depth ``fx / s`` plus its own, along its ray."""
    depth = fx / s
    for i in range(len(ortho)):
        px, py = ortho[i, 0], -ortho[i, 1]
        z = depth - (ortho[i, 2] - t_z) / s
        out[i, 0] = (px - cx) * z / fx
        out[i, 1] = -(py - cy) * z / fy
        out[i, 2] = -z


@_jit
def _norm3(P: np.ndarray, a: int, b: int) -> float:
    """``vector_norm(P[a] - P[b])``: the squares summed left to right, the square root."""
    dx, dy, dz = P[a, 0] - P[b, 0], P[a, 1] - P[b, 1], P[a, 2] - P[b, 2]
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@_jit
def _mean_y(P: np.ndarray, idx: tuple) -> float:
    """``P[idx, 1].mean()`` of fewer than 8 rows: the sum left to right (to +0.0, NumPy's identity), divided by the
    count."""
    s = P[idx[0], 1]
    for i in idx[1:]:
        s += P[i, 1]
    return (0.0 + s) / len(idx)


@_jit
def _pairs_height(P: np.ndarray, pairs: tuple) -> float:
    """``_pairs_height``: the mean of the pairs' height differences, summed as :func:`_mean_y`."""
    s = P[pairs[0][0], 1] - P[pairs[0][1], 1]
    for a, b in pairs[1:]:
        s += P[a, 1] - P[b, 1]
    return (0.0 + s) / len(pairs)


@_jit
def metrics(P: np.ndarray, g: np.ndarray) -> None:
    """``g`` (13,) ← :func:`facecapges.capture.metrics.compute_metrics` of one face's head-frame points (N, 3)."""
    w = _norm3(P, m.INNER_EYE_R, m.INNER_EYE_L)
    if w < 1e-9:  # np.maximum(w, 1e-9) (NaN kept)
        w = 1e-9
    eyes_l = (P[m.INNER_EYE_L, 1] + P[m.OUTER_EYE_L, 1]) / 2
    eyes_r = (P[m.INNER_EYE_R, 1] + P[m.OUTER_EYE_R, 1]) / 2
    lip_mid = 0.5 * (P[13, 1] + P[14, 1])
    mouth_width = _norm3(P, m.MOUTH_CORNER_L, m.MOUTH_CORNER_R)
    g[0] = _pairs_height(P, m.LIP_PAIRS)
    g[1] = mouth_width
    g[2] = P[m.LOWER_LIP_CENTER, 0] - P[m.UPPER_LIP_CENTER, 0]
    g[3] = _mean_y(P, m.BROW_L) - eyes_l
    g[4] = _mean_y(P, m.BROW_R) - eyes_r
    g[5] = _pairs_height(P, m.EYELID_PAIRS_L)
    g[6] = _pairs_height(P, m.EYELID_PAIRS_R)
    g[7] = P[m.INNER_EYE_L, 1] - P[m.NOSTRIL_L, 1]
    g[8] = P[m.INNER_EYE_R, 1] - P[m.NOSTRIL_R, 1]
    g[9] = _mean_y(P, _BROW_INNER) - 0.5 * (P[m.INNER_EYE_L, 1] + P[m.INNER_EYE_R, 1])
    g[10] = P[m.MOUTH_CORNER_L, 1] - lip_mid
    g[11] = P[m.MOUTH_CORNER_R, 1] - lip_mid
    g[12] = P[m.SUBNASALE, 1] - _mean_y(P, _LOWER_LIP) - m.JAW_STRETCH * mouth_width
    for i in range(13):
        g[i] = g[i] / w


@_jit
def insert(values: np.ndarray, weights: np.ndarray, size: int, v: np.ndarray, w: float) -> bool:
    """:meth:`SampleSet.insert` of one sample a unit ``v`` (U,) of weight ``w`` into ``values``/``weights``
    (U, capacity) holding ``size`` samples (the caller counts the new one when ``size < capacity``); False, nothing
    changed, when a number read is not finite."""
    n_units, cap = values.shape
    if not np.isfinite(w):
        return False
    for u in range(n_units):
        if not np.isfinite(v[u]):
            return False
    if size < cap:
        for u in range(n_units):
            values[u, size] = v[u]
            weights[u, size] = w
        return True
    for u in range(n_units):
        for k in range(cap):
            if not (np.isfinite(values[u, k]) and np.isfinite(weights[u, k])):
                return False
    for u in range(n_units):
        j, best = 0, abs(values[u, 0] - v[u])  # the nearest neighbour: the first smallest distance (argmin)
        for k in range(1, cap):
            d = abs(values[u, k] - v[u])
            if d < best:
                j, best = k, d
        w2 = weights[u, j]
        values[u, j] = (v[u] * w + values[u, j] * w2) / (w + w2)
        weights[u, j] = w + w2
    return True


@_jit
def _scan_end(v: np.ndarray, w: np.ndarray) -> float:
    """:func:`facecapges.capture.ranges.scan_end` of sorted contiguous ``v``, ``w`` (its default l, k, m)."""
    n = len(v)
    if n == 1:
        return v[0]
    width = abs(v[n - 1] - v[0])
    total = _sum(w, 0, n)
    gap_limit = width * L_PCT / 100.0
    k_w, m_w = total * K_PCT / 100.0, total * M_PCT / 100.0
    start, stop = 0, n - 1
    count = scanned = 0.0
    for i in range(n - 1):
        count += w[i]
        scanned += w[i]
        if count >= k_w or scanned >= m_w:
            stop = i
            break
        if abs(v[i + 1] - v[i]) > gap_limit:
            start = i + 1
            count = 0.0
    if stop < start:
        return v[start]
    m = stop + 1 - start
    prod = np.empty(m)
    for i in range(m):
        prod[i] = v[start + i] * w[start + i]
    return _sum(prod, 0, m) / _sum(w, start, m)


@_jit
def _merge_outer(v0: np.ndarray, w0: np.ndarray) -> tuple[float, float]:
    """(g_min, g_max) of :func:`facecapges.capture.ranges.merge_to_three`: its merges of the first smallest gap,
    the two gaps beside a merged pair recomputed, on arrays (a deletion shifts the rest left)."""
    n = len(v0)
    if n < 3:  # cold start: (a, a, a) of one sample, (a, b, b) of two
        return v0[0], v0[n - 1]
    v, w = v0.copy(), w0.copy()
    gaps = np.empty(n - 1)
    for k in range(n - 1):
        gaps[k] = v[k + 1] - v[k]
    while n > 3:
        i, g = 0, gaps[0]
        for k in range(1, n - 1):
            if gaps[k] < g:
                i, g = k, gaps[k]
        j = i + 1
        wi, wj = w[i], w[j]
        ws = wi + wj
        vi = (v[i] * wi + v[j] * wj) / ws
        v[i], w[i] = vi, ws
        for k in range(j, n - 1):
            v[k], w[k] = v[k + 1], w[k + 1]
        for k in range(i, n - 2):
            gaps[k] = gaps[k + 1]
        n -= 1
        if i > 0:
            gaps[i - 1] = vi - v[i - 1]
        if j < n:
            gaps[i] = v[j] - vi
    return v[0], v[2]


@_jit
def _weighted_median(v: np.ndarray, w: np.ndarray) -> float:
    """:func:`facecapges.capture.ranges.weighted_median`: the running sums left to right, the first reaching half."""
    n = len(v)
    c = np.empty(n)
    acc = w[0]
    c[0] = acc
    for k in range(1, n):
        acc = acc + w[k]
        c[k] = acc
    half = 0.5 * c[n - 1]
    i = 0
    while i < n and c[i] < half:
        i += 1
    return v[min(i, n - 1)]


@_jit
def _min(a: float, b: float) -> float:
    return b if b < a else a  # Python's min(a, b)


@_jit
def _max(a: float, b: float) -> float:
    return b if b > a else a  # Python's max(a, b)


@_jit
def estimate_ranges(
    values: np.ndarray,
    weights: np.ndarray,
    size: int,
    units: np.ndarray,
    two_dir: np.ndarray,
    min_span: np.ndarray,
    nodes: np.ndarray,
) -> bool:
    """:meth:`ExpressionEstimator.update_ranges` of ``units`` (signs all +1) into ``nodes`` (U, 3) from the first
    ``size`` samples; False, nothing changed, when a sample of those units is not finite."""
    for u in units:
        for k in range(size):
            if not (np.isfinite(values[u, k]) and np.isfinite(weights[u, k])):
                return False
    for u in units:
        o = np.argsort(values[u, :size], kind="mergesort")  # stable
        v, w = values[u, :size][o], weights[u, :size][o]
        span = min_span[u]
        if two_dir[u]:
            g0, g2 = _merge_outer(v, w)
            g1 = _weighted_median(v, w)
            g0, g2 = _min(g0, g1), _max(g2, g1)
            nodes[u, 0], nodes[u, 1], nodes[u, 2] = _min(g0, g1 - span), g1, _max(g2, g1 + span)
        else:
            lo = _scan_end(v, w)
            hi = _scan_end(v[::-1].copy(), w[::-1].copy())
            nodes[u, 0], nodes[u, 1], nodes[u, 2] = lo, lo, _max(hi, lo + span)
    return True


@_jit
def activations(g: np.ndarray, signs: np.ndarray, nodes: np.ndarray, two_dir: np.ndarray, out: np.ndarray) -> None:
    """``out`` (U,) ← :meth:`facecapges.capture.estimator.ExpressionEstimator.activation` of metrics ``g``: eq. 9
    on the side of the rest node (two-directional units), eq. 8 (one-directional)."""
    for u in range(len(g)):
        x = signs[u] * g[u]
        g0, g1, g2 = nodes[u, 0], nodes[u, 1], nodes[u, 2]
        up = (x - g1) / (g2 - g1)
        out[u] = up if x >= g1 or not two_dir[u] else (x - g1) / (g1 - g0)


@_jit
def skew_parts(M: np.ndarray, v: np.ndarray, half_sin: np.ndarray, half_cos: np.ndarray) -> None:
    """:func:`facecapges.rotations.log_so3`'s parts before its ``arctan2`` of rotations ``M`` (m, 3, 3): the skew
    part ``v`` (m, 3), ``|v| / 2`` (the squares summed left to right) and ``(tr M − 1) / 2`` (the diagonal summed
    left to right, as ``trace``)."""
    for i in range(len(M)):
        v[i, 0] = M[i, 2, 1] - M[i, 1, 2]
        v[i, 1] = M[i, 0, 2] - M[i, 2, 0]
        v[i, 2] = M[i, 1, 0] - M[i, 0, 1]
        half_sin[i] = np.sqrt(v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1] + v[i, 2] * v[i, 2]) / 2
        half_cos[i] = (M[i, 0, 0] + M[i, 1, 1] + M[i, 2, 2] - 1) / 2


@_jit
def scale_skew(v: np.ndarray, half_sin: np.ndarray, ang: np.ndarray) -> bool:
    """``v`` (m, 3) ← :func:`facecapges.rotations.log_so3`'s rotation vectors from :func:`skew_parts` and the angles
    ``ang``; False, ``v`` untouched, when an angle is within 1e-4 rad of π (its diagonal case)."""
    for i in range(len(v)):
        if np.pi - ang[i] < 1e-4:
            return False
    for i in range(len(v)):
        sn = half_sin[i]
        two = 2 * sn
        k = ang[i] / (two if two >= 1e-300 or two != two else 1e-300) if sn > 1e-12 else 0.5
        v[i, 0], v[i, 1], v[i, 2] = v[i, 0] * k, v[i, 1] * k, v[i, 2] * k
    return True


@_jit
def _clip01(x: float) -> float:
    """``np.clip(x, 0, 1)`` of one float64 (NaN and −0.0 kept, as NumPy's clip keeps them here)."""
    if x < 0.0:
        return 0.0
    return 1.0 if x > 1.0 else x


@_jit
def clipped_units(a: np.ndarray, pn: np.ndarray) -> None:
    """``pn`` (2U,) ← :func:`facecapges.capture.estimator.units_to_arkit`'s clipped activations of one face's
    ``a`` (U,): the positive sides, then the negative ones."""
    n = len(a)
    for u in range(n):
        pn[u] = _clip01(a[u])
        pn[n + u] = _clip01(-a[u])


@_jit
def arkit_weights(pn: np.ndarray, powers: np.ndarray, mp: np.ndarray, hybrid: bool, tables: tuple, out: np.ndarray):
    """``out`` (52,) float32 ← :meth:`facecapges.capture.estimator.ExpressionEstimator.weights` of one face:
    :func:`facecapges.capture.estimator.units_to_arkit` from :func:`clipped_units`' ``pn`` and its powers
    ``powers`` (NumPy's own ``**``), MediaPipe's ``mp`` in the other channels (``hybrid``, else 0), clipped."""
    copy_to, copy_from, pow_to, prod_to, prod_a, prod_b, one_minus, smile_to, smile, mask = tables
    w = np.zeros(len(out))
    for i in range(len(copy_to)):
        w[copy_to[i]] = pn[copy_from[i]]
    for i in range(len(pow_to)):
        w[pow_to[i]] = powers[i]
    for i in range(len(prod_to)):
        b = pn[prod_b[i]]
        w[prod_to[i]] = pn[prod_a[i]] * (1.0 - b if one_minus[i] else b)
    lift = 0.5 * (pn[smile[1]] + pn[smile[2]])  # both corners' mean lift
    for i in range(len(smile_to)):
        w[smile_to[i]] = (1.0 - SMILE_CORNER) * pn[smile[0]] + SMILE_CORNER * lift
    for i in range(len(out)):
        x = _clip01(w[i])
        if not mask[i]:
            x = _clip01(mp[i]) if hybrid else 0.0
        out[i] = np.float32(x)


@functools.cache  # once a process
def compiled() -> ModuleType | None:
    """This module when its kernels give the NumPy path's numbers on this machine (:func:`checked`), else None."""
    return sys.modules[__name__] if checked() else None


def checked(seed: int = 0) -> bool:
    """Whether :func:`insert` and :func:`estimate_ranges` give the NumPy path's bits: random sample sets (capacities
    4-40, rounded values: ties; weights over decades) filled and merged both ways, then every unit's nodes."""
    from facecapges.capture.estimator import ExpressionEstimator

    rng = np.random.default_rng(seed)
    for trial in range(60):
        est = ExpressionEstimator("geometric", capacity=4 + trial % 37, compiled=False)
        ss = est.samples
        values, weights = ss.values.copy(), ss.weights.copy()
        for _ in range(int(rng.integers(1, 3 * ss.capacity))):
            v = np.round(rng.standard_normal(len(values)) * 0.3, int(rng.integers(1, 4)))
            w = float(rng.uniform(0.01, 1.0) ** 2)
            if not insert(values, weights, ss.size, v, w):
                return False
            ss.insert(v, w)
        if not (np.array_equal(values, ss.values) and np.array_equal(weights, ss.weights)):
            return False
        nodes = est.nodes.copy()
        estimate_ranges(values, weights, ss.size, np.arange(len(values)), est.two_dir, est.min_span, nodes)
        est.update_ranges(compiled=False)
        if not np.array_equal(nodes.view(np.uint64), est.nodes.view(np.uint64)):
            return False
        g, a = rng.standard_normal(len(values)) * 0.3, np.empty(len(values))
        g[trial % len(g)] = est.nodes[trial % len(g), 1]  # on a rest node
        activations(g, est.signs, est.nodes, est.two_dir, a)
        if not np.array_equal(a.view(np.uint64), est.activation(g, compiled=False).view(np.uint64)):
            return False
        if not _weights_checked(est, rng):
            return False
    return _metrics_checked(rng) and _camera_checked(rng) and _log_checked(rng)


def _metrics_checked(rng: np.random.Generator) -> bool:
    """:func:`metrics` against :func:`facecapges.capture.metrics.compute_metrics`'s NumPy on random faces (points
    of cm scales, and one with its eye corners on each other: the floor of ``w``)."""
    g = np.empty(13)
    for trial in range(200):
        P = rng.standard_normal((478, 3)) * 10.0 ** rng.uniform(-1, 1.5)
        if trial == 0:
            P[m.INNER_EYE_L] = P[m.INNER_EYE_R]
        if trial == 1:
            P[:400] = -0.0  # signed zeros: NumPy's sums start from +0.0
        metrics(P, g)
        if not np.array_equal(g.view(np.uint64), m.compute_metrics(P, compiled=False).view(np.uint64)):
            return False
    return True


def _camera_checked(rng: np.random.Generator) -> bool:
    """:func:`ortho_points` and :func:`lift_points` against :func:`facecapges.capture.head_pose.landmarks_to_camera`'s
    NumPy on random landmarks (float32, as MediaPipe's), image sizes and intrinsics."""
    from facecapges.capture.head_pose import Intrinsics, SourceFit, landmarks_to_camera

    canonical = rng.standard_normal((468, 3)) * 5.0
    ids, weights = np.arange(0, 468, 7), rng.uniform(0.1, 1.0, 67)
    fit = SourceFit.of(canonical[ids], weights)
    for trial in range(50):
        w, h = int(rng.integers(64, 2000)), int(rng.integers(64, 2000))
        K = None if trial % 2 else Intrinsics(*rng.uniform(100.0, 1500.0, 4).tolist())
        lm = (rng.uniform(0.2, 0.8, (478, 3)) * [1.0, 1.0, 0.1]).astype(np.float32)
        got = landmarks_to_camera(lm, w, h, canonical, weights, ids, K, fit, compiled=sys.modules[__name__])
        want = landmarks_to_camera(lm, w, h, canonical, weights, ids, K, fit, compiled=False)
        if not np.array_equal(got.view(np.uint64), want.view(np.uint64)):
            return False
    return True


def _log_checked(rng: np.random.Generator) -> bool:
    """:func:`skew_parts` and :func:`scale_skew` against :func:`facecapges.rotations.log_so3` on random rotations
    (small angles as a head's frame to frame, and any, near π among them)."""
    from facecapges import rotations as rot

    for trial in range(40):
        r = rng.standard_normal((6, 3)) * 10.0 ** rng.uniform(-9, 0.5)
        if trial % 4 == 0:
            r[0] *= (np.pi - 10.0 ** rng.uniform(-7, -2)) / np.linalg.norm(r[0])
        M = rot.exp_so3(r)
        v, sn, c = np.empty((6, 3)), np.empty(6), np.empty(6)
        skew_parts(M, v, sn, c)
        if scale_skew(v, sn, np.arctan2(sn, c)) and not np.array_equal(
            v.view(np.uint64), rot.log_so3(M).view(np.uint64)
        ):
            return False
    return True


def _weights_checked(est, rng: np.random.Generator) -> bool:
    """:func:`clipped_units` and :func:`arkit_weights` (the estimator's compiled weights, its sample set given this
    module) against its NumPy weights in its two modes: activations in and around [−1, 1] (signed zeros, NaN among
    them), MediaPipe's blendshapes or none."""
    a = rng.uniform(-1.5, 1.5, len(est.activations))
    a[rng.integers(0, len(a), 3)] = (0.0, -0.0, np.nan)
    mp = rng.uniform(-0.1, 1.1, 52).astype(np.float32)
    kept, est.samples.kernels = est.samples.kernels, sys.modules[__name__]
    try:
        for mode in ("geometric", "hybrid"):
            est.mode, est.activations = mode, a
            for bs in (mp, None):
                if not np.array_equal(est.weights(bs).view(np.uint32), est.weights(bs, compiled=False).view(np.uint32)):
                    return False
    finally:
        est.samples.kernels = kept
    return True
