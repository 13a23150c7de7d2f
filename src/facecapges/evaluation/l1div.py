"""L1 diversity (thesis 5.5.4): two quantities, named apart.

``l1div_samples`` — **eq. 5.11, across generated samples**. For N sequences
r̂^(i) (T, J, 6) generated for the same input (e.g. different seeds or initial poses):

    L1DIV = 1/(N(N−1)) · Σ_{i<k} 1/(T·J) Σ_t Σ_j ‖r̂_tj^(i) − r̂_tj^(k)‖₁          (5.11)

exactly as printed: the pair sum runs over i < k but the normaliser is N(N−1), so
the value is *half* the mean pairwise distance. Unit: rot6d L1 per joint-frame.
Needs N ≥ 2.

``l1div_temporal`` — **per-sequence deviation from the temporal mean**: for one
sequence (T, J, 6) with temporal mean m (J, 6),

    L1DIV_seq = 1/T · Σ_t Σ_j ‖r̂_tj − m_j‖₁

a sum over all J·6 rot6d components per frame, averaged over frames. Several
sequences: frame-weighted mean (``l1div_temporal_many``). A constant sequence gives 0.
This is the *formula* of BEAT/CaMN's ``L1div`` class, but their code runs it on the 141
denormalised Euler channels in degrees, not on rot6d: on 2_scott_0_1_1 that gives
988 from the file's own Euler channels and 512 from the same motion converted to
principal-branch Euler (the forearms' branch choice alone moves it by hundreds),
against 10.9 on rot6d. So Table 5.2's 7–13 magnitudes match this rot6d form, not
BEAT/CaMN's numbers; :func:`facecapges.evaluation.peers.l1div_beat` computes theirs.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def _check(x: np.ndarray, what: str) -> np.ndarray:
    x = np.asarray(x, np.float64)
    if x.ndim != 3 or x.shape[-1] != 6 or x.shape[0] == 0:
        raise ValueError(f"{what} must be (T ≥ 1, J, 6) rot6d, got {x.shape}")
    return x


def l1div_samples(samples: Sequence[np.ndarray] | np.ndarray) -> float:
    """Eq. 5.11 over N ≥ 2 generated sequences of equal shape (T, J, 6)."""
    xs = [_check(s, "each sample") for s in samples]
    if len(xs) < 2:
        raise ValueError(f"eq. 5.11 needs at least 2 generated samples, got {len(xs)}")
    if any(x.shape != xs[0].shape for x in xs):
        raise ValueError(f"all samples must have one shape, got {[x.shape for x in xs]}")
    n = len(xs)
    T, J = xs[0].shape[:2]
    total = sum(np.abs(xs[i] - xs[k]).sum() / (T * J) for i in range(n) for k in range(i + 1, n))
    return float(total / (n * (n - 1)))


def l1div_temporal(seq: np.ndarray) -> float:
    """Mean over frames of Σ_{j,d} |r̂_tjd − mean_t r̂_jd| for one sequence (T, J, 6)."""
    x = _check(seq, "sequence")
    return float(np.abs(x - x.mean(0, keepdims=True)).sum(axis=(1, 2)).mean())


def l1div_temporal_many(seqs: Sequence[np.ndarray]) -> float:
    """:func:`l1div_temporal` of several sequences, weighted by their frame counts."""
    xs = [_check(s, "each sequence") for s in seqs]
    if not xs:
        raise ValueError("no sequences")
    n = sum(len(x) for x in xs)
    return float(sum(l1div_temporal(x) * len(x) for x in xs) / n)
