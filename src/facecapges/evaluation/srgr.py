"""Semantic-Relevance Gesture Recall (thesis 5.5.2, eq. 5.8) and BEAT semantic files.

    SRGR = 1/(T·J) · Σ_t Σ_j λ_t · 𝟙(‖r_tj − r̂_tj‖₁ < δ)                         (5.8)

* ``r``, ``r̂``: real and generated local joint rotations as rot6d (T, J, 6); the norm
  is the L1 norm of the 6-vector difference (5.5.2: "‖·‖₁ < δ"), δ = 0.5 (rot6d units,
  dimensionless).
* ``λ_t``: the semantic score of frame ``t`` from BEAT's semantic annotation; frames
  outside every annotated interval get 0 (as in BEAT's loader). No rescaling is
  applied (CaMN's code multiplies by 1/0.165; the thesis's eq. 5.8 does not).
* Without a semantic file every ``λ_t = 1``: the value is the plain per-joint-frame
  recall, and :class:`SRGRResult` says ``weighted=False`` so reports label it
  "SRGR (unweighted)".

**BEAT semantic file** (``<clip>.txt``): one tab-separated line per annotated span,
``name  start_s  end_s  duration_s  score  [word]`` — e.g.
``deictic_l\t1.20\t2.05\t0.85\t0.8\tthere``. Frame ``t`` (time ``t/fps``) takes the
score of the first span with ``start ≤ t/fps ≤ end``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facecapges.errors import file_error, require_file

DELTA = 0.5


@dataclass(frozen=True)
class SemanticSpan:
    name: str
    start_s: float
    end_s: float
    score: float
    word: str = ""


@dataclass(frozen=True)
class SRGRResult:
    value: float
    weighted: bool  # False: no semantic weights (λ_t = 1), report as "SRGR (unweighted)"

    @property
    def label(self) -> str:
        return "SRGR" if self.weighted else "SRGR (unweighted)"


def read_semantic(path: str | Path) -> list[SemanticSpan]:
    """Parse a BEAT semantic ``.txt`` file (see module docstring)."""
    p = require_file(path, "semantic file")
    spans = []
    for k, line in enumerate(p.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        if not line.strip():
            continue
        cols = line.rstrip("\n").split("\t")
        if len(cols) < 5:
            raise file_error(p, f"line {k}: expected 5 or 6 tab-separated columns "
                                f"(name, start, end, duration, score[, word]), got {len(cols)}")
        try:
            start, end, score = float(cols[1]), float(cols[2]), float(cols[4])
        except ValueError:
            raise file_error(p, f"line {k}: start, end and score must be numbers: {line.strip()!r}") from None
        if end < start:
            raise file_error(p, f"line {k}: end {end} is before start {start}")
        spans.append(SemanticSpan(cols[0].strip(), start, end, score, cols[5].strip() if len(cols) > 5 else ""))
    return spans


def semantic_weights(spans: list[SemanticSpan], n_frames: int, fps: float = 15.0,
                     start_frame: int = 0) -> np.ndarray:
    """λ_t (n_frames,) for frames ``start_frame …`` of the clip: the first covering span's score, else 0."""
    times = (start_frame + np.arange(n_frames)) / fps
    w = np.zeros(n_frames)
    done = np.zeros(n_frames, bool)
    for s in spans:
        hit = ~done & (times >= s.start_s) & (times <= s.end_s)
        w[hit], done[hit] = s.score, True
    return w


def srgr(real: np.ndarray, generated: np.ndarray, weights: np.ndarray | None = None,
         delta: float = DELTA) -> SRGRResult:
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
