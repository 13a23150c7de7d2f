"""Semantic-Relevance Gesture Recall (thesis 5.5.2, eq. 5.8).

    SRGR = 1/(T·J) · Σ_t Σ_j λ_t · 𝟙(‖r_tj − r̂_tj‖₁ < δ)                         (5.8)

* ``r``, ``r̂``: real and generated local joint rotations as rot6d (T, J, 6); the norm
  is the L1 norm of the 6-vector difference (5.5.2: "‖·‖₁ < δ"), δ = 0.5 (rot6d units,
  dimensionless).
* ``λ_t``: the semantic score of frame ``t`` from BEAT's semantic annotation; frames
  outside every annotated interval get 0. No rescaling is applied (CaMN's code multiplies by 1/0.165; the thesis's eq. 5.8 does not).
* Without a semantic file every ``λ_t = 1``: the value is the plain per-joint-frame
  recall, and :class:`SRGRResult` says ``weighted=False`` so reports label it
  "SRGR (unweighted)".

**A frozen pose scores well under δ = 0.5.** Most of the 47 joints (fingers, neck)
move little, so the static mean pose of the training frames scores 0.886 on
2_scott_0_1_1 (0.882 on its held-out last 20 %). BEAT/CaMN's trainer uses a different
test — the L1 distance of a joint's three Euler angles in degrees below 4°
(:func:`facecapges.evaluation.peers.srgr_beat`) — under which the same mean pose scores
0.51 on the held-out frames and a random real segment 0.47; ``eval`` reports both.
Neither threshold ranks the mean pose below real motion from elsewhere in the
clip: SRGR rewards being near the target on average, so read it beside FGD, BA and
the synchrony controls, never alone.

The per-frame scores λ_t come from BEAT's semantic ``.txt`` files, read by
:func:`facecapges.data.beat.read_semantic` (the cache stores them per clip as
``semantic`` with ``semantic_present``); this module only takes the array.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DELTA = 0.5


@dataclass(frozen=True)
class SRGRResult:
    value: float
    weighted: bool  # False: no semantic weights (λ_t = 1), report as "SRGR (unweighted)"

    @property
    def label(self) -> str:
        return "SRGR" if self.weighted else "SRGR (unweighted)"


def srgr(
    real: np.ndarray, generated: np.ndarray, weights: np.ndarray | None = None, delta: float = DELTA
) -> SRGRResult:
    """Eq. 5.8 for real and generated rot6d poses (T, J, 6); ``weights`` λ_t (T,) or None."""
    r, g = np.asarray(real, np.float64), np.asarray(generated, np.float64)
    if r.shape != g.shape or r.ndim != 3 or r.shape[-1] != 6:
        raise ValueError(f"real and generated must both be (T, J, 6), got {r.shape} and {g.shape}")
    hits = (np.abs(r - g).sum(-1) < delta).astype(np.float64)  # (T, J)
    if weights is None:
        return SRGRResult(float(hits.mean()), weighted=False)
    lam = np.asarray(weights, np.float64)
    if lam.shape != (r.shape[0],):
        raise ValueError(f"weights must be (T,) = ({r.shape[0]},), got {lam.shape}")
    return SRGRResult(float((lam[:, None] * hits).mean()), weighted=True)
