"""Range estimation of one- and two-directional expression units (paper 3.2.2, eq. 8–9).

A **one-directional** unit (mouth opening, eye closing) has two nodes: ``g_min`` (not
active, ``w = 0``) and ``g_max`` (fully active, ``w = 1``); ``w = (g − g_min) /
(g_max − g_min)`` (eq. 8). Values left of ``g_min`` are invalid, right of ``g_max``
exaggerated. A **two-directional** unit (pucker ↔ grin) has three: ``g_min``
(``w = −1``), ``g_rest`` (``w = 0``), ``g_max`` (``w = 1``), with eq. 9 on each side.

Estimating the nodes from a weighted sample set (:class:`samples.SampleSet`):

* one-directional — :func:`scan_end`, run once from each end of the sorted samples:
  walk inwards adding up sample weights; when the gap to the next sample exceeds
  ``l`` % of the set's width, everything walked so far is an outlier: it is dropped and
  the count restarts; stop when the count reaches ``k`` % of the total weight or the
  walked weight reaches ``m`` %. The paper then takes "the outermost sample" as the
  node; on a bounded, merged sample set that single sample is as noisy as the
  extreme frame that formed it, so we read the node as the weighted mean of the
  samples counted since the last restart (the outermost k % that is not an outlier).
  The
  paper chooses l, k, m "empirically" and gives no numbers; we use l = 10, k = 5,
  m = 20 (percent), tuned on nothing but the requirement that an isolated outlier
  sample (< k % of the weight) is never a node.
* two-directional — :func:`merge_to_three`: merge the nearest neighbouring samples
  (weighted mean value, summed weight, as eq. 6–7) until three remain; they are
  ``g_min, g_rest, g_max``. This relies on the paper's assumptions: enough samples,
  many near rest, few exaggerated ones. On talking-face data the distribution is one
  broad mode and the middle cluster drifts off it (measured on the HDTF clip: the
  lower-lip offset's middle node sat 0.02 eye-distances, a third of its range, off the
  median), so :func:`two_directional_range` takes ``g_rest`` as the weighted median
  (assumption 2: most weight near rest) and keeps the outer two merged clusters.

Both are numpy-vectorised over a unit's samples; the one-dimensional nearest pair is
always a pair of sorted neighbours.
"""

from __future__ import annotations

from bisect import bisect_left
from itertools import accumulate, pairwise

import numpy as np

L_PCT, K_PCT, M_PCT = 10.0, 5.0, 20.0


def scan_end(
    values: np.ndarray, weights: np.ndarray, l_pct: float = L_PCT, k_pct: float = K_PCT, m_pct: float = M_PCT
) -> float:
    """Node at the *low* end of sorted ``values`` by the paper's inward scan (pass reversed arrays for the high end)."""
    n = len(values)
    if n == 0:
        raise ValueError("empty sample set")
    if n == 1:
        return float(values[0])
    width = abs(float(values[-1] - values[0]))
    total = float(weights.sum())
    gap_limit = width * l_pct / 100.0
    k_w, m_w = total * k_pct / 100.0, total * m_pct / 100.0
    start = 0
    stop = n - 1
    count = scanned = 0.0
    # the scan over Python floats (the same numbers and sums as over NumPy's scalars, without making one a step)
    gaps = np.abs(np.diff(values)).tolist()
    ws = weights.tolist()
    for i in range(n - 1):
        count += ws[i]
        scanned += ws[i]
        if count >= k_w or scanned >= m_w:
            stop = i
            break
        if gaps[i] > gap_limit:
            start = i + 1  # samples 0..i are outliers
            count = 0.0
    if stop < start:
        return float(values[start])
    w = weights[start : stop + 1]
    return float((values[start : stop + 1] * w).sum() / w.sum())


def one_directional_range(values: np.ndarray, weights: np.ndarray, **kw) -> tuple[float, float]:
    """(low node, high node) of sorted weighted samples (module docstring)."""
    lo = scan_end(values, weights, **kw)
    hi = scan_end(values[::-1], weights[::-1], **kw)
    return lo, hi


def merge_to_three(values: np.ndarray, weights: np.ndarray) -> tuple[float, float, float]:
    """(g_min, g_rest, g_max): merge nearest sorted neighbours until three samples remain."""
    v = np.asarray(values, np.float64).tolist()  # Python floats: the same numbers as float(x) of each
    w = np.asarray(weights, np.float64).tolist()
    if not v:
        raise ValueError("empty sample set")
    # the gaps are kept between merges: a merge changes only the two gaps beside the merged pair
    # (each recomputed as ``v[i + 1] − v[i]``, as from scratch), and ``gaps.index(min(gaps))`` is the
    # first smallest gap, so the merges and the result are those of re-scanning every gap each time
    gaps = [b - a for a, b in pairwise(v)]
    n = len(v)
    while n > 3:
        i = gaps.index(min(gaps))
        j = i + 1
        wi, wj = w[i], w[j]
        ws = wi + wj
        vi = (v[i] * wi + v[j] * wj) / ws
        v[i] = vi
        w[i] = ws
        del v[j], w[j], gaps[i]
        n -= 1
        if i > 0:
            gaps[i - 1] = vi - v[i - 1]
        if j < n:
            gaps[i] = v[j] - vi
    while len(v) < 3:  # cold start: fewer than three samples
        v.insert(len(v) // 2, v[len(v) // 2])
    return v[0], v[1], v[2]


def weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """Weighted median of sorted ``values``: the first value whose running weight reaches half the total (the
    running sums added left to right, as ``np.cumsum``; found as ``np.searchsorted`` does, by ``bisect_left``)."""
    c = list(accumulate(np.asarray(weights, np.float64).tolist()))
    return float(values[min(bisect_left(c, 0.5 * c[-1]), len(values) - 1)])


def two_directional_range(values: np.ndarray, weights: np.ndarray) -> tuple[float, float, float]:
    """(g_min, g_rest, g_max) of sorted weighted samples: outer merged clusters, weighted-median rest."""
    g0, _, g2 = merge_to_three(values, weights)
    rest = weighted_median(values, weights)
    return min(g0, rest), rest, max(g2, rest)


def one_directional_weight(g, g_min: float, g_max: float):
    """Eq. 8: ``(g − g_min) / (g_max − g_min)`` (unclipped: < 0 invalid, > 1 exaggerated)."""
    return (g - g_min) / (g_max - g_min)


def two_directional_weight(g, g_min: float, g_rest: float, g_max: float):
    """Eq. 9: ``(g − g_rest)/(g_max − g_rest)`` above rest, ``(g − g_rest)/(g_rest − g_min)`` below (unclipped)."""
    g = np.asarray(g, np.float64)
    return np.where(g >= g_rest, (g - g_rest) / (g_max - g_rest), (g - g_rest) / (g_rest - g_min))
