"""The speech mouth's sums over its spectrum, compiled (Numba): :class:`facecapges.capture.speech_mouth.SpeechMouth`'s
NumPy steps after the FFT, one call instead of a dozen on ~300 bins a frame (issue 36, ``live``'s output stage).

Every number is NumPy's: a power is ``|X|² / n`` as ``np.abs(X) ** 2 / n`` computes it (the square and the division
rounded once each; ``|X|`` itself stays NumPy's, whose complex absolute on this machine is its own SIMD one), and a
sum is NumPy's pairwise summation (:func:`pairwise_sum`: its blocks of 8 running sums, its halves above 128 numbers).
:func:`checked` holds the sums against ``ndarray.sum`` on this machine once a process, else NumPy's are used.
Imported only by callers that load Numba anyway (``live``'s scheduler).
"""

from __future__ import annotations

import functools

import numba
import numpy as np

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def _block_sum(a: np.ndarray, lo: int, n: int) -> float:
    """NumPy's pairwise sum of at most 128 numbers: fewer than 8 left to right from −0.0; else eight running sums
    combined ``((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))``, then the rest left to right."""
    if n < 8:
        res = -0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3, r4, r5, r6, r7 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3], a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    m = n - n % 8
    for i in range(lo + 8, lo + m, 8):
        r0, r1, r2, r3 = r0 + a[i], r1 + a[i + 1], r2 + a[i + 2], r3 + a[i + 3]
        r4, r5, r6, r7 = r4 + a[i + 4], r5 + a[i + 5], r6 + a[i + 6], r7 + a[i + 7]
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for i in range(lo + m, lo + n):
        res += a[i]
    return res


@_jit
def pairwise_sum(a: np.ndarray, lo: int, n: int) -> float:
    """``a[lo : lo + n].sum()`` of float64 as NumPy sums a contiguous run (``pairwise_sum`` of its ``loops_utils.h``):
    blocks of at most 128 numbers (:func:`_block_sum`), a longer run the sum of its two halves (the first a multiple
    of 8), left + right. Its recursion walked with a stack (Numba's cache of a recursive function crashed on
    loading): a run is pushed, then its halves; a run met again after its halves adds their two sums."""
    los, ns = np.empty(64, np.int64), np.empty(64, np.int64)  # the runs to do (a run's depth ≤ log2(n / 64))
    split = np.zeros(64, np.bool_)  # whether the run's halves are done
    sums = np.empty(64)
    los[0], ns[0], top, k = lo, n, 1, 0
    while top:
        top -= 1
        s_lo, s_n = los[top], ns[top]
        if s_n <= 128:
            sums[k] = _block_sum(a, s_lo, s_n)
            k += 1
        elif split[top]:
            k -= 1
            sums[k - 1] = sums[k - 1] + sums[k]  # left + right
        else:
            half = s_n // 2 - (s_n // 2) % 8
            split[top] = True
            los[top + 1], ns[top + 1], split[top + 1] = s_lo + half, s_n - half, False  # the right half after
            los[top + 2], ns[top + 2], split[top + 2] = s_lo, half, False  # the left
            top += 3
    return sums[0]


@_jit
def mouth_sums(mag: np.ndarray, n: int, v0: int, v1: int, b0: int, b1: int, f_band: np.ndarray) -> tuple:
    """``mag`` (bins,) the FFT's ``np.abs``, made the power ``mag² / n`` in place over ``[0, max(v1, b1))``; returns
    the vowel band's power ``spec[v0:v1].sum()``, the centroid band's ``spec[b0:b1].sum()`` and
    ``(f_band * spec[b0:b1]).sum()``."""
    for i in range(max(v1, b1)):
        mag[i] = mag[i] * mag[i] / n  # np.square, then the division
    weighted = np.empty(b1 - b0)
    for i in range(b1 - b0):
        weighted[i] = f_band[i] * mag[b0 + i]
    return pairwise_sum(mag, v0, v1 - v0), pairwise_sum(mag, b0, b1 - b0), pairwise_sum(weighted, 0, b1 - b0)


@functools.cache  # once a process
def checked() -> bool:
    """Whether :func:`mouth_sums` gives NumPy's numbers on this machine: every run length 1–400 of random
    magnitudes (and the spectra's own scale), against ``np.abs(X) ** 2 / n`` and ``ndarray.sum``."""
    rng = np.random.default_rng(0)
    for m in range(1, 401):
        mag = np.abs(rng.standard_normal(m + 3) * rng.uniform(0.0, 10.0 ** rng.integers(-6, 3), m + 3))
        f = rng.uniform(80.0, 5000.0, m)
        n = 1066 + m % 2
        spec = mag**2 / n
        want = (spec[1 : m + 1].sum(), spec[2 : m + 2].sum(), (f * spec[2 : m + 2]).sum())
        got = mouth_sums(mag.copy(), n, 1, m + 1, 2, m + 2, f)
        if any(np.float64(a).view(np.uint64) != np.float64(b).view(np.uint64) for a, b in zip(got, want)):
            return False
    return True
