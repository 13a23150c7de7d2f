"""The 52 ARKit blendshape names, in the one order the project uses.

``ARKIT_NAMES`` is Apple's ARKit set sorted alphabetically (``browDownLeft`` …
``noseSneerRight``) with ``tongueOut`` last. This is BEAT's face JSON order for its
first 51 channels (BEAT stores no ``tongueOut``) and MediaPipe's blendshape order
without its leading ``_neutral``. A face vector is (52,) float in [0, 1], this order;
``tongueOut`` is 0 when the source does not measure it.
"""

from __future__ import annotations

import numpy as np

ARKIT_NAMES: tuple[str, ...] = (
    "browDownLeft",
    "browDownRight",
    "browInnerUp",
    "browOuterUpLeft",
    "browOuterUpRight",
    "cheekPuff",
    "cheekSquintLeft",
    "cheekSquintRight",
    "eyeBlinkLeft",
    "eyeBlinkRight",
    "eyeLookDownLeft",
    "eyeLookDownRight",
    "eyeLookInLeft",
    "eyeLookInRight",
    "eyeLookOutLeft",
    "eyeLookOutRight",
    "eyeLookUpLeft",
    "eyeLookUpRight",
    "eyeSquintLeft",
    "eyeSquintRight",
    "eyeWideLeft",
    "eyeWideRight",
    "jawForward",
    "jawLeft",
    "jawOpen",
    "jawRight",
    "mouthClose",
    "mouthDimpleLeft",
    "mouthDimpleRight",
    "mouthFrownLeft",
    "mouthFrownRight",
    "mouthFunnel",
    "mouthLeft",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
    "mouthPressLeft",
    "mouthPressRight",
    "mouthPucker",
    "mouthRight",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthStretchLeft",
    "mouthStretchRight",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "noseSneerLeft",
    "noseSneerRight",
    "tongueOut",
)
N_BLENDSHAPES = len(ARKIT_NAMES)  # 52
BEAT_NAMES: tuple[str, ...] = ARKIT_NAMES[:51]  # BEAT JSON: no tongueOut
_INDEX = {n.lower(): i for i, n in enumerate(ARKIT_NAMES)}

assert N_BLENDSHAPES == 52 and tuple(sorted(ARKIT_NAMES[:51])) == ARKIT_NAMES[:51]


def arkit_index(name: str) -> int | None:
    """Index of ``name`` in ARKIT_NAMES, case-insensitive (Live Link writes ``EyeBlinkLeft``); None if unknown."""
    return _INDEX.get(name.lower().replace("_", ""))


def to_arkit52(weights: np.ndarray, names: list[str] | tuple[str, ...]) -> tuple[np.ndarray, list[str]]:
    """Reorder (T, K) weights named ``names`` into (T, 52) ARKit order.

    Channels with unknown names are dropped and returned as the second value so the
    caller can report them; ARKit channels absent from ``names`` are 0.
    """
    weights = np.asarray(weights, dtype=np.float32)
    out = np.zeros(weights.shape[:-1] + (N_BLENDSHAPES,), np.float32)
    unknown = []
    for k, n in enumerate(names):
        i = arkit_index(n)
        if i is None:
            unknown.append(n)
        else:
            out[..., i] = weights[..., k]
    return out, unknown
