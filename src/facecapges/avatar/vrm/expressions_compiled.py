"""The ARKit → VRM preset mapping compiled (Numba): :mod:`.expressions`' formulas, one call a frame (issue 36).

* :func:`nnls` — the visemes' non-negative least squares, solved exactly: with 5 unknowns there are 31 non-empty
  passive sets; each set's unconstrained solution is a fixed matrix (its columns' pseudo-inverse, built once by
  :func:`.expressions.viseme_solver`) times the features, and the solution is the set whose solution is
  non-negative and meets the other KKT conditions (no unknown outside the set would lower the residual). It
  replaced ``scipy.optimize.nnls`` (Lawson–Hanson), whose Python wrapper's checks cost more than the solve:
  the same solution, not the same last bits (:mod:`.expressions`, tests hold it to SciPy's);
* :func:`visemes` — per row: that solve (when a feature is above 1e-4), each weight clipped to 1, their sum
  scaled down to 1;
* :func:`presets` — per row of ARKit weights the 17 preset weights of :func:`.expressions.vrm0_weights` in the
  same IEEE operations in the same order as its NumPy form (so the same bits: tested on random and edge frames),
  or ``False`` at the first weight that is not finite (the caller then takes the NumPy form).

Imported when the presets are first computed (:func:`.expressions.vrm0_weights`), never when :mod:`.expressions`
is (``live``'s option checks, a style's load); cached beside this file (``cache=True``), filled by ``make setup``
(``scripts/warm-numba-caches.py``, :func:`warm`). The tables are arguments, not globals: a cached function's
constants would not follow a change of :mod:`.expressions`' prototypes.
"""

from __future__ import annotations

import numba
import numpy as np

# the GIL kept, as the VMC sender's kernels (runtime/outputs/vmc_kernels.py): a call of a few µs
_jit = numba.njit(cache=True, error_model="numpy")


@_jit
def nnls(A, pinv, f, x) -> None:
    """``x`` (n,) ← argmin ‖A·x − f‖ over x ≥ 0, ``A`` (m, n) of full column rank; ``pinv[s]`` (n, m): the
    pseudo-inverse of the columns of the set ``s`` (a bit mask) in their rows, zeros elsewhere (module docstring).

    Among the sets whose solution is non-negative, the one whose largest positive gradient ``Aᵢ·(f − A·x)`` off the
    set is smallest (0 at the optimum, which is unique: a strictly convex problem); the empty set (x = 0) first."""
    m, n = A.shape
    r, xs = np.empty(m), np.empty(n)
    best = np.inf
    for s in range(1 << n):
        feasible = True
        for i in range(n):
            v = 0.0
            for j in range(m):
                v += pinv[s, i, j] * f[j]
            if v < 0.0:
                feasible = False
                break
            xs[i] = v
        if not feasible:
            continue
        for j in range(m):
            v = f[j]
            for i in range(n):
                v -= A[j, i] * xs[i]
            r[j] = v
        worst = 0.0  # the KKT conditions' violation: a positive gradient of an unknown held at 0
        for i in range(n):
            if not (s >> i) & 1:
                g = 0.0
                for j in range(m):
                    g += A[j, i] * r[j]
                worst = max(worst, g)
        if worst < best:
            best = worst
            x[:] = xs


@_jit
def _visemes_row(A, pinv, f, out) -> None:
    """``out`` (5,) ← one row's visemes from its features ``f`` (6,) (module docstring): zeros unless a feature is
    above 1e-4 (a NaN feature: zeros, as ``f.max() > 1e-4`` is for NumPy)."""
    on = False
    for j in range(f.shape[0]):
        if np.isnan(f[j]):
            on = False
            break
        on = on or f[j] > 1e-4
    out[:] = 0.0
    if on:
        nnls(A, pinv, f, out)
    total = 0.0
    for i in range(out.shape[0]):
        out[i] = out[i] if out[i] < 1.0 else 1.0  # np.minimum(out, 1.0)
        total += out[i]
    if total > 1.0:  # the sum scaled down to 1 (receivers add the clips)
        for i in range(out.shape[0]):
            out[i] = out[i] / total


@_jit
def visemes(A, pinv, feats, out) -> None:
    """``out`` (T, 5) ← :func:`_visemes_row` of each row of ``feats`` (T, 6)."""
    for t in range(feats.shape[0]):
        _visemes_row(A, pinv, feats[t], out[t])


@_jit
def _max(a, b):
    return a if a > b else b  # np.maximum's pick on floats that are not NaN (a tie gives b: 0.0 vs -0.0)


@_jit
def _min(a, b):
    return a if a < b else b


@_jit
def _clip(x):
    return 0.0 if x < 0.0 else (1.0 if x > 1.0 else x)  # np.clip(x, 0, 1) of a finite x (−0.0 stays −0.0)


@_jit
def _ramp(x, lo, hi):
    return _min(_max((x - lo) / (hi - lo), 0.0), 1.0)


@_jit
def _mean(x, i, k):
    return (x[i[k]] + x[i[k + 1]]) * 0.5


@_jit
def _both(x, i, k):
    return _min(x[i[k]], x[i[k + 1]])


@_jit
def _presets_row(x, i, A, pinv, f, vis, out) -> None:
    """``out`` (17,) ← the presets of one clipped row ``x`` (52,); ``i``: the ARKit indices in
    :data:`.expressions.PRESET_INPUTS` order (pairs left, right)."""
    f[0] = _max(x[i[0]] - x[i[1]], 0.0)  # jawOpen − mouthClose
    f[1], f[2] = x[i[2]], x[i[3]]  # funnel, pucker
    f[3], f[4], f[5] = _mean(x, i, 4), _mean(x, i, 6), _mean(x, i, 8)  # stretch, lower lip down, upper lip up
    _visemes_row(A, pinv, f, vis)
    left, right = x[i[10]], x[i[11]]
    blink = _min(left, right)
    smile = _ramp(_both(x, i, 12), 0.3, 0.7)
    joy = smile * _ramp(_mean(x, i, 14), 0.15, 0.5)
    tense = _max(_max(_mean(x, i, 16), _mean(x, i, 18)), _mean(x, i, 20))
    angry = _ramp(_both(x, i, 22), 0.3, 0.7) * _ramp(tense, 0.2, 0.5) * (1.0 - smile)
    sorrow = _ramp(x[i[24]], 0.3, 0.7) * _ramp(_both(x, i, 25), 0.3, 0.7) * (1.0 - smile)
    surprised = _ramp(_both(x, i, 27), 0.3, 0.7) * _ramp(_mean(x, i, 29), 0.2, 0.5)
    out[0], out[1], out[2] = _clip(blink), _clip(left - blink), _clip(right - blink)
    for k in range(5):
        out[3 + k] = _clip(vis[k])
    out[8], out[9], out[10], out[11], out[12] = (
        _clip(joy),
        _clip(angry),
        _clip(sorrow),
        _clip(smile - joy),
        _clip(surprised),
    )
    for k in range(4):
        out[13 + k] = _clip(_mean(x, i, 31 + 2 * k))


@_jit
def presets(w, i, A, pinv, out) -> bool:
    """``out`` (T, 17) ← the presets of each row of ``w`` (T, 52), each weight clipped to [0, 1] first; ``False``
    (``out`` not all written) at the first weight that is not finite."""
    x, f, vis = np.empty(w.shape[1]), np.empty(A.shape[0]), np.empty(A.shape[1])
    for t in range(w.shape[0]):
        for k in range(w.shape[1]):
            v = w[t, k]
            if not np.isfinite(v):
                return False
            x[k] = _clip(v)
        _presets_row(x, i, A, pinv, f, vis, out[t])
    return True


def warm() -> None:
    """Load (or compile: ``make setup`` does it once) the machine code of :func:`presets` and :func:`visemes` for
    the argument types :mod:`.expressions` passes."""
    from facecapges.avatar.vrm import expressions

    expressions.vrm0_weights(np.full(52, 0.5))
    expressions.viseme_weights(np.full((1, 52), np.nan))
