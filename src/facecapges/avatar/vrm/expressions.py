"""ARKit weights → VRM expressions: the one mapping every VRM consumer uses (VMC, VRM export, viewer).

A standard VRM 0.x avatar has no ARKit clips, only the *presets* of its
``BlendShapeProxy`` (VRM 1.0: ``expressions``). This module derives them from the 52
ARKit weights (:data:`facecapges.arkit.ARKIT_NAMES` order) and names the ARKit clips the
way "perfect-sync" avatars spell them.

Names
-----
* :data:`VRM0_PRESETS` — the VRM 0.x preset names as UniVRM writes them (case matters:
  VMC receivers match ``BlendShapeProxy`` names case-sensitively), plus ``Surprised``,
  the extra clip VRoid Studio exports (the VRM 1.0 preset ``surprised``).
* :data:`VRM1_NAMES` — the VRM 1.0 expression name of each (``A`` → ``aa``, ``Joy`` →
  ``happy``, ``Fun`` → ``relaxed``, ``Sorrow`` → ``sad``, ``Blink_L`` → ``blinkLeft`` …,
  as in the VRM 1.0 migration guide).
* :data:`PERFECT_SYNC_NAMES` — the 52 ARKit names in UpperCamelCase (``EyeBlinkLeft``,
  ``JawOpen``, ``TongueOut``): the clip names of perfect-sync VRM models (the convention
  of iFacialMocap/VSeeFace and Apple's ``ARFaceAnchor.BlendShapeLocation`` spelling).
  ``Left``/``Right`` are the *face's own* sides, as in ARKit and VRM: no mirroring.

How the presets are derived (:func:`vrm0_weights`)
--------------------------------------------------
Per frame, every value in [0, 1]:

* **Blink / Blink_L / Blink_R.** ``Blink = min(L, R)``, ``Blink_L = L − Blink``,
  ``Blink_R = R − Blink`` with ``L, R = eyeBlinkLeft, eyeBlinkRight``. VRM clips add
  linearly, so the left eyelid ends up exactly at ``L`` and the right at ``R`` on an
  avatar whose ``Blink`` closes both eyes and ``Blink_L``/``Blink_R`` one each — sending
  ``Blink = mean`` *and* ``Blink_L/R`` would close a winking eye 1.5 times.
* **A, I, U, E, O (visemes)** from the jaw and mouth shapes. Six mouth features
  (left/right averaged): *opening* ``max(jawOpen − mouthClose, 0)`` (``mouthClose`` =
  lips together while the jaw hangs open), *funnel*, *pucker*, *stretch*, *lower lip
  down*, *upper lip up*. Each vowel has a prototype in that space, set from the
  articulation of the five (Japanese) vowels the VRM visemes are: jaw opening
  A > O > E > I > U, lip rounding U and O (pucker, funnel), lip spreading I and E
  (stretch), lips parted from the teeth in A/E/I (:data:`VISEME_PROTOTYPES`). The
  viseme weights are the non-negative least-squares combination of the prototypes
  that best reproduces the frame's features (5 unknowns: solved exactly over the 31
  non-empty sets of prototypes, compiled, :func:`.expressions_compiled.nnls`; SciPy's
  ``nnls``'s solution to ~1e-15, the same float32 values on every frame tried), each
  clipped to 1 and scaled so that their sum is at most 1 (receivers add the clips; a sum
  above 1 over-opens the mouth). A closed, relaxed mouth gives all zeros. Smiles are not
  a viseme feature: they drive ``Joy``/``Fun``.
* **Joy, Fun, Angry, Sorrow, Surprised** — VRM's emotion clips are whole-face
  expressions, so each needs the *conjunction* of the FACS action units of that emotion
  (Ekman & Friesen), not one of them: speech alone moves brows and lip corners, and a
  single-unit rule would flip the avatar between emotions while it talks. With
  ``ramp(x, lo, hi) = clip((x − lo)/(hi − lo), 0, 1)`` (the small resting values of every
  tracker stay at 0) and both sides required (``min`` of left and right):

  - ``smile = ramp(min(mouthSmileL, R), 0.3, 0.7)`` (AU12, lip-corner puller);
    ``Joy = smile · ramp(mean(cheekSquintL/R), 0.15, 0.5)`` (+ AU6, the cheek raiser
    of a genuine smile; VRM's ``Joy`` closes the eyes), ``Fun = smile − Joy`` (a smile
    with open eyes);
  - ``Angry = ramp(min(browDownL, R), 0.3, 0.7) · ramp(max(mean(eyeSquintL/R),
    mean(mouthPressL/R), mean(noseSneerL/R)), 0.2, 0.5) · (1 − smile)`` (AU4 with AU7,
    AU23/24 or AU9);
  - ``Sorrow = ramp(browInnerUp, 0.3, 0.7) · ramp(min(mouthFrownL, R), 0.3, 0.7) ·
    (1 − smile)`` (AU1 with AU15);
  - ``Surprised = ramp(min(browOuterUpL, R), 0.3, 0.7) · ramp(mean(eyeWideL/R), 0.2,
    0.5)`` (AU2 with AU5).

  On the real talking-head clip (``WDA_KatieHill_000``, 8 s of neutral speech, our
  capture) the single-unit rules this replaced had ``Sorrow`` active (> 0.1) in 52 % of
  the frames and ``Angry`` in 18 %; these give ``Fun`` 17 %, ``Angry`` 11 %, ``Sorrow``
  10 %, ``Surprised`` 8 %, ``Joy`` 0 %, each as a few runs of 0.2–1 s where the speaker
  really frowns or smiles, not frame-to-frame flicker (a check, not a fit: the
  thresholds are round FACS-style values, not tuned on the clip).
* **LookUp / LookDown / LookLeft / LookRight** (for avatars whose eyes are blendshapes,
  not bones): ``LookUp = mean(eyeLookUpL/R)``, ``LookDown = mean(eyeLookDownL/R)``;
  the avatar's left is the left eye looking out and the right eye looking in:
  ``LookLeft = mean(eyeLookOutLeft, eyeLookInRight)``,
  ``LookRight = mean(eyeLookInLeft, eyeLookOutRight)``.
* ``Neutral`` is the rest face (all 0): not sent.

The 17 presets of a frame are one compiled call (:mod:`.expressions_compiled`, Numba, imported
on the first frame's presets, not with this module): a VMC tick computes them once per model
frame (issue 36). :func:`vrm0_weights_array` is the NumPy form (weights that are not finite
take it; the compiled form gives its bits).

The thresholds are engineering choices (no published reference maps ARKit to VRM
presets); they are here, once, for every consumer.

The other way and on a model
----------------------------
* :data:`PRESET_BINDS` — the presets of the avatar we write, as combinations of its ARKit
  morph targets (the inverse of the mapping above).
* :class:`ExpressionMap` — the expressions a model offers (``VrmModel.expressions`` of
  :mod:`facecapges.avatar.vrm.read`): a model with perfect-sync expressions gets the ARKit
  weights as they are; any other gets its VRM presets from :func:`vrm0_weights`.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np

from facecapges.arkit import ARKIT_NAMES, N_BLENDSHAPES, arkit_index

VRM0_PRESETS: tuple[str, ...] = (
    "Blink",
    "Blink_L",
    "Blink_R",
    "A",
    "I",
    "U",
    "E",
    "O",
    "Joy",
    "Angry",
    "Sorrow",
    "Fun",
    "Surprised",
    "LookUp",
    "LookDown",
    "LookLeft",
    "LookRight",
)
VRM1_NAMES: dict[str, str] = {
    "Blink": "blink",
    "Blink_L": "blinkLeft",
    "Blink_R": "blinkRight",
    "A": "aa",
    "I": "ih",
    "U": "ou",
    "E": "ee",
    "O": "oh",
    "Joy": "happy",
    "Angry": "angry",
    "Sorrow": "sad",
    "Fun": "relaxed",
    "Surprised": "surprised",
    "LookUp": "lookUp",
    "LookDown": "lookDown",
    "LookLeft": "lookLeft",
    "LookRight": "lookRight",
}
VRM1_EXPRESSIONS: tuple[str, ...] = tuple(VRM1_NAMES[n] for n in VRM0_PRESETS)
PERFECT_SYNC_NAMES: tuple[str, ...] = tuple(n[0].upper() + n[1:] for n in ARKIT_NAMES)
VISEMES: tuple[str, ...] = ("A", "I", "U", "E", "O")

_I = {n: i for i, n in enumerate(ARKIT_NAMES)}
# features: opening, funnel, pucker, stretch, lower lip down, upper lip up (module docstring)
VISEME_PROTOTYPES = np.array(
    [
        # open  funnel pucker stretch lowerDn upperUp
        [0.70, 0.00, 0.00, 0.05, 0.35, 0.15],  # A  (aa): jaw wide open, lips relaxed, parted
        [0.15, 0.00, 0.00, 0.50, 0.15, 0.30],  # I  (ih): nearly closed jaw, lips spread, teeth shown
        [0.10, 0.35, 0.75, 0.00, 0.00, 0.00],  # U  (ou): small opening, lips rounded and protruded
        [0.35, 0.00, 0.00, 0.30, 0.35, 0.15],  # E  (ee): half-open jaw, lips a little spread
        [0.45, 0.70, 0.30, 0.00, 0.10, 0.05],  # O  (oh): open jaw, lips rounded into a funnel
    ],
    np.float64,
)


def _mean(w: np.ndarray, a: str, b: str) -> np.ndarray:
    # = np.mean([w[..., a], w[..., b]], axis=0) to the bit ((x + y) / 2), without the list and the reduction
    # (a VMC tick calls this a dozen times: issue 36)
    return (w[..., _I[a]] + w[..., _I[b]]) * 0.5


def _both(w: np.ndarray, stem: str) -> np.ndarray:
    """The weaker side of a left/right pair (both sides must move)."""
    return np.minimum(w[..., _I[stem + "Left"]], w[..., _I[stem + "Right"]])


def _ramp(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return np.minimum(np.maximum((x - lo) / (hi - lo), 0.0), 1.0)  # np.clip's values, fewer calls


def mouth_features(face52: np.ndarray) -> np.ndarray:
    """(..., 52) ARKit weights → (..., 6) viseme features (module docstring)."""
    w = np.asarray(face52, np.float64)
    opening = np.maximum(w[..., _I["jawOpen"]] - w[..., _I["mouthClose"]], 0.0)
    return np.stack(
        [
            opening,
            w[..., _I["mouthFunnel"]],
            w[..., _I["mouthPucker"]],
            _mean(w, "mouthStretchLeft", "mouthStretchRight"),
            _mean(w, "mouthLowerDownLeft", "mouthLowerDownRight"),
            _mean(w, "mouthUpperUpLeft", "mouthUpperUpRight"),
        ],
        axis=-1,
    )


PRESET_INPUTS: tuple[str, ...] = (
    "jawOpen", "mouthClose", "mouthFunnel", "mouthPucker",
    "mouthStretchLeft", "mouthStretchRight", "mouthLowerDownLeft", "mouthLowerDownRight",
    "mouthUpperUpLeft", "mouthUpperUpRight", "eyeBlinkLeft", "eyeBlinkRight",
    "mouthSmileLeft", "mouthSmileRight", "cheekSquintLeft", "cheekSquintRight",
    "eyeSquintLeft", "eyeSquintRight", "mouthPressLeft", "mouthPressRight", "noseSneerLeft", "noseSneerRight",
    "browDownLeft", "browDownRight", "browInnerUp", "mouthFrownLeft", "mouthFrownRight",
    "browOuterUpLeft", "browOuterUpRight", "eyeWideLeft", "eyeWideRight",
    "eyeLookUpLeft", "eyeLookUpRight", "eyeLookDownLeft", "eyeLookDownRight",
    "eyeLookOutLeft", "eyeLookInRight", "eyeLookInLeft", "eyeLookOutRight",
)  # fmt: skip
"""The ARKit weights the presets read, in the order the compiled form takes their indices
(:func:`.expressions_compiled.presets`; left/right pairs side by side)."""


@functools.cache
def viseme_solver():
    """The compiled form (:mod:`.expressions_compiled`, Numba: imported here, on the first frame's presets, never
    with this module) and its tables: the prototypes as columns ``A`` (6, 5), per set of them (a bit mask) its
    columns' pseudo-inverse in their rows (32, 5, 6), the :data:`PRESET_INPUTS` indices."""
    from facecapges.avatar.vrm import expressions_compiled

    A = np.ascontiguousarray(VISEME_PROTOTYPES.T)
    n = A.shape[1]
    pinv = np.zeros((1 << n, n, A.shape[0]))
    for s in range(1, 1 << n):
        cols = [i for i in range(n) if (s >> i) & 1]
        pinv[s, cols] = np.linalg.pinv(A[:, cols])
    idx = np.array([_I[name] for name in PRESET_INPUTS], np.int64)
    return expressions_compiled, A, pinv, idx


def viseme_weights(face52: np.ndarray) -> np.ndarray:
    """(..., 52) ARKit weights → (..., 5) A, I, U, E, O weights (NNLS on the prototypes; sum ≤ 1)."""
    kernels, A, pinv, _ = viseme_solver()
    feats = mouth_features(face52)
    flat = np.ascontiguousarray(feats.reshape(-1, feats.shape[-1]))
    out = np.empty((flat.shape[0], len(VISEMES)))
    kernels.visemes(A, pinv, flat, out)
    return out.reshape(feats.shape[:-1] + (len(VISEMES),))


def vrm0_weights(face52: np.ndarray) -> np.ndarray:
    """(..., 52) ARKit weights → (..., 17) VRM 0.x preset weights in :data:`VRM0_PRESETS` order.

    Finite weights go through the compiled form (:func:`.expressions_compiled.presets`: one call, a VMC tick's
    frame in a few µs; issue 36), any other through :func:`vrm0_weights_array` — the same bits."""
    w = np.asarray(face52, np.float64)
    if w.shape[-1:] != (N_BLENDSHAPES,):
        raise ValueError(f"face weights must be (..., {N_BLENDSHAPES}), got {w.shape}")
    kernels, A, pinv, idx = viseme_solver()
    out = np.empty(w.shape[:-1] + (len(VRM0_PRESETS),))
    if kernels.presets(w.reshape(-1, N_BLENDSHAPES), idx, A, pinv, out.reshape(-1, len(VRM0_PRESETS))):
        return out
    return vrm0_weights_array(w)


def vrm0_weights_array(face52: np.ndarray) -> np.ndarray:
    """:func:`vrm0_weights` in NumPy (its visemes compiled: :func:`viseme_weights`): the form of weights that are not
    all finite, and the reference the compiled form is held to, bit for bit (tests)."""
    w = np.clip(np.asarray(face52, np.float64), 0.0, 1.0)
    if w.shape[-1] != N_BLENDSHAPES:
        raise ValueError(f"face weights must be (..., {N_BLENDSHAPES}), got {w.shape}")
    left, right = w[..., _I["eyeBlinkLeft"]], w[..., _I["eyeBlinkRight"]]
    both = np.minimum(left, right)
    vis = viseme_weights(w)
    smile = _ramp(_both(w, "mouthSmile"), 0.3, 0.7)
    joy = smile * _ramp(_mean(w, "cheekSquintLeft", "cheekSquintRight"), 0.15, 0.5)
    tense = np.maximum(
        np.maximum(_mean(w, "eyeSquintLeft", "eyeSquintRight"), _mean(w, "mouthPressLeft", "mouthPressRight")),
        _mean(w, "noseSneerLeft", "noseSneerRight"),
    )
    angry = _ramp(_both(w, "browDown"), 0.3, 0.7) * _ramp(tense, 0.2, 0.5) * (1.0 - smile)
    sorrow = _ramp(w[..., _I["browInnerUp"]], 0.3, 0.7) * _ramp(_both(w, "mouthFrown"), 0.3, 0.7) * (1.0 - smile)
    surprised = _ramp(_both(w, "browOuterUp"), 0.3, 0.7) * _ramp(_mean(w, "eyeWideLeft", "eyeWideRight"), 0.2, 0.5)
    cols = [
        both,
        left - both,
        right - both,
        *np.moveaxis(vis, -1, 0),
        joy,
        angry,
        sorrow,
        smile - joy,
        surprised,
        _mean(w, "eyeLookUpLeft", "eyeLookUpRight"),
        _mean(w, "eyeLookDownLeft", "eyeLookDownRight"),
        _mean(w, "eyeLookOutLeft", "eyeLookInRight"),
        _mean(w, "eyeLookInLeft", "eyeLookOutRight"),
    ]
    return np.clip(np.stack(cols, axis=-1), 0.0, 1.0)


def vrm0_presets(face52: np.ndarray) -> dict[str, float]:
    """One frame's (52,) ARKit weights → ``{VRM 0.x preset name: weight}``."""
    return dict(zip(VRM0_PRESETS, vrm0_weights(np.asarray(face52).reshape(N_BLENDSHAPES)).tolist()))


def vrm1_expressions(face52: np.ndarray) -> dict[str, float]:
    """One frame's (52,) ARKit weights → ``{VRM 1.0 expression name: weight}``."""
    return {VRM1_NAMES[k]: v for k, v in vrm0_presets(face52).items()}


def _preset_binds() -> dict[str, dict[str, float]]:
    """The VRM presets of the avatar we write, as combinations of its ARKit targets.

    They are the inverse of this module's ARKit → preset mapping (:func:`vrm0_weights`, the
    one mapping of the project): the visemes are its mouth prototypes spelled as ARKit
    targets, the emotions sit at the top of its ramps, so that a face showing preset
    ``p`` maps back to ``p`` (tested).
    """
    binds: dict[str, dict[str, float]] = {}
    for v, (opening, funnel, pucker, stretch, lower, upper) in zip(VISEMES, VISEME_PROTOTYPES):
        b = {"jawOpen": opening, "mouthFunnel": funnel, "mouthPucker": pucker}
        for side in ("Left", "Right"):
            b.update({f"mouthStretch{side}": stretch, f"mouthLowerDown{side}": lower, f"mouthUpperUp{side}": upper})
        binds[VRM1_NAMES[v]] = {a: float(w) for a, w in b.items() if w > 0}
    both = lambda stem, w: {f"{stem}Left": w, f"{stem}Right": w}  # noqa: E731
    binds.update(
        {
            "happy": {**both("mouthSmile", 0.8), **both("cheekSquint", 0.6), **both("eyeSquint", 0.3)},
            "relaxed": both("mouthSmile", 0.8),
            "angry": {**both("browDown", 0.8), **both("noseSneer", 0.4), **both("mouthPress", 0.3)},
            "sad": {"browInnerUp": 0.8, **both("mouthFrown", 0.7)},
            "surprised": {**both("eyeWide", 0.8), **both("browOuterUp", 0.8), "browInnerUp": 0.5},
            "blink": both("eyeBlink", 1.0),
            "blinkLeft": {"eyeBlinkLeft": 1.0},
            "blinkRight": {"eyeBlinkRight": 1.0},
            # the model's left is +X: looking left turns the left eye out and the right eye in
            "lookUp": both("eyeLookUp", 1.0),
            "lookDown": both("eyeLookDown", 1.0),
            "lookLeft": {"eyeLookOutLeft": 1.0, "eyeLookInRight": 1.0},
            "lookRight": {"eyeLookInLeft": 1.0, "eyeLookOutRight": 1.0},
            "neutral": {},
        }
    )
    return binds


PRESET_BINDS: dict[str, dict[str, float]] = _preset_binds()
PERFECT_SYNC_MIN = 26  # a model with at least this many ARKit-named expressions is driven by them


class ExpressionMap:
    """ARKit weights (T, 52) → a model's expression weights (T, E), E = ``names``.

    Built from the expression names the model offers (``VrmModel.expressions``).
    Perfect-sync models (≥ :data:`PERFECT_SYNC_MIN` expressions named as ARKit shapes, any
    case) get the ARKit weights as they are; the others their VRM presets, derived by
    :func:`vrm0_weights` (the project's one ARKit → preset mapping).
    """

    def __init__(self, expressions: Sequence[str]):
        direct: dict[int, str] = {}
        for n in expressions:
            a = arkit_index(n)
            if a is not None:
                direct.setdefault(a, n)
        self.perfect_sync = len(direct) >= PERFECT_SYNC_MIN
        if self.perfect_sync:
            self._index = sorted(direct)
            self.names = [direct[a] for a in self._index]
        else:
            self._index = [k for k, n in enumerate(VRM1_EXPRESSIONS) if n in expressions]
            self.names = [VRM1_EXPRESSIONS[k] for k in self._index]

    def __call__(self, arkit: np.ndarray) -> np.ndarray:
        arkit = np.clip(np.asarray(arkit, np.float64), 0.0, 1.0)
        w = arkit if self.perfect_sync else vrm0_weights(arkit)
        return np.ascontiguousarray(w[..., self._index], dtype=np.float32)
