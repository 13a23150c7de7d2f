"""Expression units → 52 ARKit blendshape weights, without calibration (paper 3.2).

Per face, :class:`ExpressionEstimator` keeps a :class:`samples.SampleSet` of the
geometric metrics (:mod:`metrics`), re-estimates each unit's range from it
(:mod:`ranges`), turns the current metrics into unit activations (eq. 8–9) and maps
them to ARKit names.

Units (:data:`UNITS`): each metric is one unit. ``sign = −1`` would mean the
expression *decreases* the metric, so the unit works on ``−g``. The paper names eye
closing a one-directional unit; here the eyelid gap is two-directional (rest in the
middle, blink below, eyeWide above) because ARKit has eyeWide, and a talking face's
open-eye level is a broad mode (gaze up/down moves the lids) rather than an end. The
nostril height is two-directional for the same reason (only its lower side is used).
``min_span`` is a population prior (in eye-corner distances): the smallest distance
between rest and full activation the range estimate may report. It gives sensible
values from the very first frame (cold start: one sample is both ends of the range,
so the span is the prior and the first frame reads as rest) and keeps noise from being
blown up while one side has not been seen yet; as real samples arrive the estimated
span takes over. ``scale`` is the unit's typical half range (compensation samples).
The jaw's prior is wide, 0.45 (the lower lip's drop at a full jawOpen; the synthetic
faces of :mod:`synthetic` use the same figure): talking, a person opens the jaw a
fraction of the way, and the top of a few seconds of speech (0.31 on the HDTF clip) read as
a full jawOpen — 1.0 where MediaPipe reads 0.56. Chosen from {0.25, 0.35, 0.45, 0.6} with the
jaw's other two constants (:mod:`metrics`' ``JAW_STRETCH``, γ below), on the rule below.

Mapping (:data:`MAPPING`, unit activation → ARKit channel):

=====================  ===============================================================
ARKit channel          from
=====================  ===============================================================
jawOpen                jaw_drop (one-dir), response γ = 1.5 (below)
mouthPucker            mouth_width below rest, × (1 − lip_gap activation)
mouthFunnel            mouth_width below rest, × lip_gap activation
mouthSmileLeft/Right   0.6 · mouth_width above rest + 0.4 · mean of mouth_corner_L, _R above rest
mouthFrownLeft/Right   mouth_corner_L/R below rest
mouthStretchLeft/Right mouth_width above rest × (1 − mouth_corner above rest)
jawLeft / jawRight     lip_offset above / below rest (lower lip towards the subject's left/right)
browOuterUpLeft/Right  brow_height_L/R above rest
browDownLeft/Right     brow_height_L/R below rest
browInnerUp            brow_inner above rest
eyeBlinkLeft/Right     eyelid_L/R below rest, response γ = 1.5
eyeWideLeft/Right      eyelid_L/R above rest
noseSneerLeft/Right    nose_L/R below rest (nostril wing rising towards the eye)
=====================  ===============================================================

The jaw and the smile: ARKit / MediaPipe define jawOpen by the jaw, but the lip gap also
grows when only the lips part — a toothy smile lifts the upper lip off the teeth with the
jaw nearly closed, and the lip gap read it as an open mouth. ``jaw_drop`` (the lower inner
lip below the base of the nose, less the part of it that follows the mouth's width: a
stretched mouth draws the lower lip down over the teeth, a rounded one pushes it up,
:mod:`metrics`) moves with the jaw; the lip gap still splits pucker from funnel. The
smile's corner part is the mean lift of both corners: one corner's height (against the lip
centre) is biased on real faces (on the HDTF clip the left corner read a smile 0.3 lower
than the right where MediaPipe reads both alike), which drew a symmetric smile lopsided; frowns stay per side. Chosen on the two face videos in
``../shared/data/face``, each choice made on one video (or its first half) and checked on
the other (docs/face-capture.md).

The head's yaw and the lip offset: ``lip_offset`` (the lower lip's sideways offset under the
upper lip, jawLeft/Right) follows the head's yaw on real video although a head turn does not
shift the jaw — MediaPipe's relative depths are off, and the two lips sit at different depths,
so turning the head moves one against the other in the head frame (r 0.85 with the yaw on the
HDTF clip, 0.80 on Megamind; jawLeft read 0.4–0.8 whenever she looked aside, where MediaPipe
reads 0.01: a lopsided mouth). :meth:`ExpressionEstimator.update` takes the face's normal and
takes out of the units in :data:`YAW_DECORRELATED` the part that follows it: a causal
weighted least-squares line of the metric on the face normal's sideways part
(``sin(yaw)·cos(pitch)``) over every accepted frame so far (the same sample weights ω), used
once the head has turned by more than :data:`YAW_MIN_STD_DEG` (weighted std) — the metric as
it would read facing the camera. A jaw shifted without a head turn reads as before.

Response curves: measured against MediaPipe's learned jawOpen the relation is convex, near
zero until the mouth is a fraction open. A power curve ``w^γ`` on the clipped unit
activation models that (γ = 1.5 for jawOpen, chosen from {1, 1.25, 1.5, 2} together with
the metric's stretch term on the rule above — 2 had been chosen when jawOpen came from
the lip gap; 1.5 for blinks, whose lids cover the iris gradually). Every other channel is
linear.

Modes: ``geometric`` — the table above, every other channel 0; ``mediapipe`` —
MediaPipe's learned blendshapes as they are; ``hybrid`` — the table above, every other
channel (eye gaze, cheeks, mouth press/roll/shrug, …) from MediaPipe.
Values beyond a range are kept unclipped in :attr:`ExpressionEstimator.activations`
("exaggerated") and clipped to [0, 1] on output.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from facecapges.arkit import ARKIT_NAMES, N_BLENDSHAPES
from facecapges.capture.metrics import METRIC_NAMES
from facecapges.capture.ranges import one_directional_range, two_directional_range
from facecapges.capture.samples import MIN_WEIGHT, SampleSet

MODES = ("geometric", "mediapipe", "hybrid")


@dataclass(frozen=True)
class Unit:
    metric: str
    two_directional: bool
    sign: float
    min_span: float
    scale: float


UNITS: tuple[Unit, ...] = (
    Unit("lip_gap", False, +1, 0.25, 0.15),
    Unit("mouth_width", True, +1, 0.15, 0.15),
    Unit("lip_offset", True, +1, 0.08, 0.03),
    Unit("brow_height_L", True, +1, 0.08, 0.05),
    Unit("brow_height_R", True, +1, 0.08, 0.05),
    Unit("eyelid_L", True, +1, 0.10, 0.05),
    Unit("eyelid_R", True, +1, 0.10, 0.05),
    Unit("nose_L", True, +1, 0.10, 0.04),
    Unit("nose_R", True, +1, 0.10, 0.04),
    Unit("brow_inner", True, +1, 0.08, 0.05),
    Unit("mouth_corner_L", True, +1, 0.06, 0.04),
    Unit("mouth_corner_R", True, +1, 0.06, 0.04),
    Unit("jaw_drop", False, +1, 0.45, 0.15),
)
assert tuple(u.metric for u in UNITS) == METRIC_NAMES
N_UNITS = len(UNITS)
_U = {u.metric: i for i, u in enumerate(UNITS)}
_A = {n: i for i, n in enumerate(ARKIT_NAMES)}

JAW_GAMMA = 1.5
#: units whose part that follows the head's yaw is taken out (module docstring)
YAW_DECORRELATED: tuple[str, ...] = ("lip_offset",)
YAW_MIN_STD_DEG = 3.0  # the yaw's weighted std before the line is used
JAW_UNIT = "jaw_drop"
SMILE_CORNER = 0.4
BLINK_GAMMA = 1.5

#: ARKit channels the geometric estimator writes (the rest are 0 or MediaPipe's)
GEOMETRIC_CHANNELS: tuple[str, ...] = (
    "jawOpen",
    "mouthPucker",
    "mouthFunnel",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthFrownLeft",
    "mouthFrownRight",
    "mouthStretchLeft",
    "mouthStretchRight",
    "jawLeft",
    "jawRight",
    "browOuterUpLeft",
    "browOuterUpRight",
    "browDownLeft",
    "browDownRight",
    "browInnerUp",
    "eyeBlinkLeft",
    "eyeBlinkRight",
    "eyeWideLeft",
    "eyeWideRight",
    "noseSneerLeft",
    "noseSneerRight",
)
GEOMETRIC_MASK = np.zeros(N_BLENDSHAPES, bool)
GEOMETRIC_MASK[[_A[n] for n in GEOMETRIC_CHANNELS]] = True


def _arkit_tables() -> tuple[np.ndarray, ...]:
    """The index tables of :func:`units_to_arkit`: which ARKit channel takes which clipped activation
    (``pos`` units 0–12, ``neg`` units 13–25 of one array), made once."""
    n = N_UNITS
    copy = []  # (channel, activation): the channel is the clipped activation itself
    for side in ("Left", "Right"):
        s = side[0]
        copy += [
            (f"mouthFrown{side}", n + _U[f"mouth_corner_{s}"]),
            (f"browOuterUp{side}", _U[f"brow_height_{s}"]),
            (f"browDown{side}", n + _U[f"brow_height_{s}"]),
            (f"eyeWide{side}", _U[f"eyelid_{s}"]),
            (f"noseSneer{side}", n + _U[f"nose_{s}"]),
        ]
    copy += [("jawLeft", _U["lip_offset"]), ("jawRight", n + _U["lip_offset"]), ("browInnerUp", _U["brow_inner"])]
    # (channel, activation, γ): the activation to a power
    power = [("jawOpen", _U[JAW_UNIT], JAW_GAMMA)]
    power += [(f"eyeBlink{side}", n + _U[f"eyelid_{side[0]}"], BLINK_GAMMA) for side in ("Left", "Right")]
    # (channel, a, b, one_minus): a · b, or a · (1 − b)
    product = [
        ("mouthPucker", n + _U["mouth_width"], _U["lip_gap"], True),
        ("mouthFunnel", n + _U["mouth_width"], _U["lip_gap"], False),
        ("mouthStretchLeft", _U["mouth_width"], _U["mouth_corner_L"], True),
        ("mouthStretchRight", _U["mouth_width"], _U["mouth_corner_R"], True),
    ]

    def idx(rows, k: int) -> np.ndarray:
        return np.array([_A[r[0]] if k == 0 else r[k] for r in rows])

    return (
        idx(copy, 0),
        idx(copy, 1),
        idx(power, 0),
        idx(power, 1),
        np.array([r[2] for r in power], np.float64),
        idx(product, 0),
        idx(product, 1),
        idx(product, 2),
        np.array([r[3] for r in product]),
    )


_COPY_TO, _COPY_FROM, _POW_TO, _POW_FROM, _POW_GAMMA, _PROD_TO, _PROD_A, _PROD_B, _PROD_ONE_MINUS = _arkit_tables()
_SMILE_TO = np.array([_A["mouthSmileLeft"], _A["mouthSmileRight"]])
# the same tables for the compiled weights (:func:`facecapges.capture.kernels.arkit_weights`)
_KERNEL_TABLES = (
    _COPY_TO,
    _COPY_FROM,
    _POW_TO,
    _PROD_TO,
    _PROD_A,
    _PROD_B,
    _PROD_ONE_MINUS,
    _SMILE_TO,
    np.array([_U["mouth_width"], _U["mouth_corner_L"], _U["mouth_corner_R"]]),
    GEOMETRIC_MASK,
)
_NO_BLENDSHAPES = np.zeros(N_BLENDSHAPES, np.float32)


def units_to_arkit(a: np.ndarray) -> np.ndarray:
    """Unit activations (..., 13) (unclipped, :data:`UNITS` order) → (..., 52) ARKit weights in [0, 1].

    Channels not in :data:`GEOMETRIC_CHANNELS` are 0. The table in the module docstring, written by channel
    groups (:func:`_arkit_tables`: a copy, a power, a product each, one NumPy call per group; the same operations
    on the same numbers as one expression per channel, issue 36).
    """
    a = np.asarray(a, np.float64)
    pn = np.clip(np.concatenate([a, -a], axis=-1), 0.0, 1.0)  # pos (13), then neg (13)
    out = np.zeros(a.shape[:-1] + (N_BLENDSHAPES,))
    out[..., _COPY_TO] = pn[..., _COPY_FROM]
    out[..., _POW_TO] = pn[..., _POW_FROM] ** _POW_GAMMA
    b = pn[..., _PROD_B]
    out[..., _PROD_TO] = pn[..., _PROD_A] * np.where(_PROD_ONE_MINUS, 1.0 - b, b)
    corner_l, corner_r = pn[..., _U["mouth_corner_L"]], pn[..., _U["mouth_corner_R"]]
    lift = 0.5 * (corner_l + corner_r)  # both corners' mean lift
    out[..., _SMILE_TO] = ((1.0 - SMILE_CORNER) * pn[..., _U["mouth_width"]] + SMILE_CORNER * lift)[..., None]
    return np.clip(out, 0.0, 1.0)


class ExpressionEstimator:
    """Calibration-free expression estimation for one face (module docstring).

    Args:
        mode: ``geometric``, ``mediapipe`` or ``hybrid``.
        capacity: samples kept per unit.
        update_every: each unit's range is re-estimated every this many frames, the
            units taking turns (round robin, about ``N_UNITS / update_every`` units a
            frame) so the cost per frame stays flat; during the first ``warmup``
            frames every unit is re-estimated every frame (cold start). Ranges move
            slowly, so this only bounds the per-frame cost.
    """

    def __init__(
        self, mode: str = "hybrid", capacity: int = 32, update_every: int = 6, warmup: int = 12, compiled: bool = True
    ):
        if mode not in MODES:
            raise ValueError(f"estimator mode must be one of {MODES}, got {mode!r}")
        self.mode = mode
        self.signs = np.array([u.sign for u in UNITS])
        self._signs_positive = bool((self.signs > 0).all())  # the compiled ranges' case
        self.min_span = np.array([u.min_span for u in UNITS])
        self.two_dir = np.array([u.two_directional for u in UNITS])
        self.samples = SampleSet(N_UNITS, capacity, scales=np.array([u.scale for u in UNITS]), compiled=compiled)
        self.update_every = max(1, int(update_every))
        self.warmup = warmup
        # nodes per unit in sign-adjusted metric space: (g_min, g_rest, g_max); one-dir units use g_min, g_max
        self.nodes = np.full((N_UNITS, 3), np.nan)
        self.activations = np.zeros(N_UNITS)
        self._frame = 0
        # the units re-estimated a frame, by turn (``update``), as index arrays made once
        per = -(-N_UNITS // self.update_every)  # ceil
        self._turns = [np.array([(start + i) % N_UNITS for i in range(per)]) for start in range(N_UNITS)]
        self._all_units = np.arange(N_UNITS)
        self._yaw_units = [_U[m] for m in YAW_DECORRELATED]
        # weighted sums of the line metric ~ s (s: the face normal's sideways part): Σω, Σω·s, Σω·s², per unit Σω·g, Σω·s·g
        self._yaw_sums = [0.0, 0.0, 0.0]
        self._yaw_g = [[0.0, 0.0] for _ in self._yaw_units]
        self._yaw_min_var = math.sin(math.radians(YAW_MIN_STD_DEG)) ** 2

    # -------------------------------------------------------------- head yaw
    def decorrelate_yaw(self, g: np.ndarray, omega: float, side: float) -> np.ndarray:
        """``g`` with the part of the :data:`YAW_DECORRELATED` units that follows the head's turn taken out.

        ``side`` is the sideways component of the face's unit normal in the camera frame (``sin(yaw)·cos(pitch)``).
        The frame first joins the weighted sums (when ``omega`` is a weight the sample set accepts), then the
        line fitted so far is applied: the metric as it would read facing the camera (module docstring)."""
        g = np.array(g, np.float64)
        s = float(side)
        ok = math.isfinite(s) and math.isfinite(omega) and omega >= MIN_WEIGHT
        w = min(float(omega), 1.0) if ok else 0.0
        sums = self._yaw_sums
        if ok:
            sums[0] += w
            sums[1] += w * s
            sums[2] += w * s * s
        sw = sums[0]
        if sw <= 0:
            return g
        mean_s = sums[1] / sw
        var = sums[2] / sw - mean_s * mean_s
        fit = var > self._yaw_min_var
        for k, u in enumerate(self._yaw_units):
            x = float(g[u])
            if ok and math.isfinite(x):
                self._yaw_g[k][0] += w * x
                self._yaw_g[k][1] += w * s * x
            if fit:
                sg, ssg = self._yaw_g[k]
                g[u] = x - (ssg / sw - mean_s * sg / sw) / var * s
        return g

    # -------------------------------------------------------------- ranges
    def update_ranges(self, units=None, compiled: bool = True) -> None:
        """Re-estimate the nodes of ``units`` (default all) from the sample set (with the min-span prior): in one
        compiled call where the sample set has its kernels (:mod:`.kernels`, the same bits) and
        ``compiled``, else unit by unit here."""
        ss = self.samples
        if ss.size == 0:
            return
        k = ss.kernels if compiled and self._signs_positive else None
        if k is not None:
            ids = self._all_units if units is None else np.asarray(units, np.int64)
            if k.estimate_ranges(ss.values, ss.weights, ss.size, ids, self.two_dir, self.min_span, self.nodes):
                return
        for u in range(N_UNITS) if units is None else units:
            v, w = self.samples.unit(u)
            if self.signs[u] < 0:
                v, w = -v[::-1], w[::-1]
            span = self.min_span[u]
            if self.two_dir[u]:
                g0, g1, g2 = two_directional_range(v, w)
                # the rest node is the heaviest cluster's side: keep it, widen thin sides
                self.nodes[u] = (min(g0, g1 - span), g1, max(g2, g1 + span))
            else:
                lo, hi = one_directional_range(v, w)
                self.nodes[u] = (lo, lo, max(hi, lo + span))

    def activation(self, g: np.ndarray, compiled: bool = True) -> np.ndarray:
        """Unclipped unit activations (13,) for metrics ``g`` (eq. 8–9): one compiled call where the sample set has
        its kernels (:mod:`.kernels`) and ``compiled``, else the NumPy below."""
        k = self.samples.kernels if compiled else None
        if k is not None:
            out = np.empty(N_UNITS)
            k.activations(np.ascontiguousarray(g, np.float64), self.signs, self.nodes, self.two_dir, out)
            return out
        x = self.signs * np.asarray(g, np.float64)
        g0, g1, g2 = self.nodes[:, 0], self.nodes[:, 1], self.nodes[:, 2]
        up = (x - g1) / (g2 - g1)
        with np.errstate(divide="ignore", invalid="ignore"):
            down = (x - g1) / (g1 - g0)
        a = np.where(x >= g1, up, down)
        # one-directional: w = (g − g_min)/(g_max − g_min) on both sides of g_min (eq. 8)
        return np.where(self.two_dir, a, up)

    # -------------------------------------------------------------- frames
    def update(self, g: np.ndarray, omega: float, normal: np.ndarray | None = None) -> np.ndarray:
        """Add one frame's metrics ``g`` (13,) with sample weight ``omega``; return unit activations (13,).

        ``normal``: the face's unit normal in the camera frame (:attr:`head_pose.HeadPose.normal`, as for the
        sample weight); when given, the :data:`YAW_DECORRELATED` units lose the part that follows the head's
        turn (module docstring)."""
        g = np.asarray(g, np.float64)
        if self.mode != "mediapipe":
            if normal is not None:
                g = self.decorrelate_yaw(g, omega, float(normal[0]))
            added = self.samples.add(g, omega)
            first = np.isnan(self.nodes[0, 0])
            if first and not added:
                # cold start on a poorly weighted frame: still give a range around it
                self.samples.insert(g, max(omega, 1e-3))
            if first or self._frame < self.warmup:
                self.update_ranges()
            else:
                per = len(self._turns[0])
                self.update_ranges(self._turns[(self._frame * per) % N_UNITS])
            self.activations = self.activation(g)
        self._frame += 1
        return self.activations

    def weights(self, mp_blendshapes: np.ndarray | None = None, compiled: bool = True) -> np.ndarray:
        """The 52 ARKit weights for the last :meth:`update` (float32, [0, 1]); where the sample set has its kernels
        (:mod:`.kernels`) and ``compiled``, in two compiled calls around NumPy's own powers."""
        k = self.samples.kernels if compiled else None
        if k is not None and self.mode != "mediapipe":  # one face's weights in two compiled calls, NumPy's bits
            pn, out = np.empty(2 * N_UNITS), np.empty(N_BLENDSHAPES, np.float32)
            k.clipped_units(np.ascontiguousarray(self.activations, np.float64), pn)
            mp_in = _NO_BLENDSHAPES if mp_blendshapes is None else np.ascontiguousarray(mp_blendshapes)
            k.arkit_weights(pn, pn[_POW_FROM] ** _POW_GAMMA, mp_in, self.mode == "hybrid", _KERNEL_TABLES, out)
            return out
        mp = np.zeros(N_BLENDSHAPES) if mp_blendshapes is None else np.asarray(mp_blendshapes, np.float64)
        if self.mode == "mediapipe":
            return np.clip(mp, 0, 1).astype(np.float32)
        out = units_to_arkit(self.activations)
        if self.mode == "hybrid":
            out = np.where(GEOMETRIC_MASK, out, mp)
        return np.clip(out, 0, 1).astype(np.float32)
