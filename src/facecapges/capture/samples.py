"""The weighted geometric-metric sample set of the paper (3.2.1, eq. 4–7).

Every frame gives one sample per metric ("unit"), all with the same weight, since the
weight only depends on the head pose:

* eq. 4  ``ω_t = 1 − |t_z − z_opt| · 0.2``  (``t_z`` face-to-camera distance in metres,
  ``z_opt = 0.5``; clipped at 0),
* eq. 5  ``ω_R = max(n_c · n_f, 0) ^ α``  (``n_c`` the face normal, ``n_f = (0, 0, 1)``
  the normal of a face looking into the camera, ``α = 0.5``),
* ``ω = ω_t · ω_R``.

**Compensation samples.** The true value of a sample with observation ``v`` and weight
``ω`` is taken to be Gaussian, ``N(v, σ²)`` with ``σ = −ln ω``. For ``ω < 1`` two extra
samples ``v ± δ`` of weight ``(1 − ω)/2`` are added, with ``δ`` chosen so that
``ω / ((1 − ω)/2) = f(v) / f(v ± δ)``, i.e. ``δ = σ·sqrt(2·ln(2ω / (1 − ω)))``. A sample
with ``ω < 1/3`` would make its compensation samples outweigh it; it is dropped.
The paper does not say in which unit σ is measured. Metrics here are ratios to the
inner eye-corner distance with very different spreads per unit (a mouth width near
1.7, an eyelid gap near 0.25), so σ is scaled per unit: ``σ_u = −ln ω · scale_u`` with
``scale_u`` the unit's typical half range (:data:`estimator.UNITS`).

**Bounded set, merging.** Each unit keeps at most ``capacity`` samples. When full, a new
sample ``(v1, ω1)`` is merged with its nearest neighbour ``(v2, ω2)`` (eq. 6–7):
``v3 = (v1·ω1 + v2·ω2) / (ω1 + ω2)``, ``ω3 = ω1 + ω2``. The set therefore keeps its size,
keeps learning, and its weights reflect the density of values seen so far.

All units are stored in one (U, capacity) array and updated together, so adding a frame
costs a handful of numpy operations whatever the number of units; a sample's merge is one compiled call where
:mod:`facecapges.capture.kernels` keeps NumPy's bits on this machine (its NumPy form otherwise).
"""

from __future__ import annotations

import math

import numpy as np

Z_OPT_M = 0.5
ALPHA = 0.5
MIN_WEIGHT = 1.0 / 3.0


def sample_weight(distance_m: float, face_normal: np.ndarray, z_opt: float = Z_OPT_M, alpha: float = ALPHA) -> float:
    """ω = ω_t · ω_R (eq. 4–5) for a face at ``distance_m`` whose unit normal is ``face_normal`` (camera frame)."""
    w_t = max(0.0, 1.0 - abs(float(distance_m) - z_opt) * 0.2)
    w_r = max(float(face_normal[2]), 0.0) ** alpha  # n_c · n_f with n_f = +Z
    return w_t * w_r


def compensation_delta(omega: float) -> float:
    """δ/scale of the compensation samples for weight ``omega`` (0 when ω ≥ 1; NaN when ω < 1/3)."""
    if omega < MIN_WEIGHT:
        return float("nan")
    if omega >= 1.0 - 1e-9:
        return 0.0
    sigma = -math.log(omega)
    ratio = 2.0 * omega / (1.0 - omega)  # ≥ 1 for ω ≥ 1/3
    return sigma * math.sqrt(2.0 * math.log(ratio))


class SampleSet:
    """Bounded weighted sample sets for ``n_units`` metrics (module docstring).

    Attributes:
        values, weights: (U, capacity) arrays; only the first :attr:`size` columns are used.
    """

    def __init__(self, n_units: int, capacity: int = 64, scales: np.ndarray | None = None, compiled: bool = True):
        if capacity < 4:
            raise ValueError(f"capacity must be at least 4, got {capacity}")
        self.capacity = int(capacity)
        self.values = np.zeros((n_units, capacity))
        self.weights = np.zeros((n_units, capacity))
        self.size = 0
        self.scales = np.ones(n_units) if scales is None else np.asarray(scales, np.float64)
        self.n_frames = 0  # frames accepted
        self.n_dropped = 0  # frames with ω < 1/3
        self._rows = np.arange(n_units)
        self.kernels = None  # kernels where it keeps NumPy's bits (``compiled``)
        if compiled:
            from facecapges.capture import kernels

            self.kernels = kernels.compiled()

    def insert(self, v: np.ndarray, w: float) -> None:
        """Insert one sample per unit, all with weight ``w`` (merging when full, eq. 6–7)."""
        v = np.asarray(v, np.float64)
        k = self.kernels
        if k is not None and v.flags.c_contiguous and k.insert(self.values, self.weights, self.size, v, w):
            self.size = min(self.size + 1, self.capacity)
            return
        if self.size < self.capacity:
            self.values[:, self.size] = v
            self.weights[:, self.size] = w
            self.size += 1
            return
        j = np.abs(self.values - v[:, None]).argmin(axis=1)  # nearest neighbour per unit
        r = self._rows
        w2 = self.weights[r, j]
        self.values[r, j] = (v * w + self.values[r, j] * w2) / (w + w2)
        self.weights[r, j] = w + w2

    def add(self, v: np.ndarray, omega: float) -> bool:
        """Add a frame's metrics ``v`` (U,) with sample weight ``omega``; False when it was dropped."""
        if not np.isfinite(omega) or omega < MIN_WEIGHT or not np.isfinite(v).all():
            self.n_dropped += 1
            return False
        omega = min(float(omega), 1.0)
        self.insert(v, omega)
        d = compensation_delta(omega)
        if d > 0:
            wc = (1.0 - omega) / 2.0
            self.insert(v + d * self.scales, wc)
            self.insert(v - d * self.scales, wc)
        self.n_frames += 1
        return True

    def unit(self, u: int) -> tuple[np.ndarray, np.ndarray]:
        """(values, weights) of unit ``u``, sorted by value."""
        v = self.values[u, : self.size]
        o = v.argsort(kind="stable")
        return v[o], self.weights[u, : self.size][o]
