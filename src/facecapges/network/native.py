"""The streaming kernel's small-batch schedules, compiled to native code by Numba.

At one stream (``live``, ``run``, a lightly loaded ``serve``) every product of the
step is a small matrix–vector one and the torch schedule's cost is per-call dispatch
(1–3 µs a call, ~12 calls per TCN, ~8 NumPy calls per LSTM cell), not arithmetic.
These functions run the same computations as whole loops in one call each:

* :func:`tcn_taps` — :meth:`~facecapges.network.batched.TCNTaps.step` (all layers of
  one causal TCN for one new frame, shift register included);
* :func:`mel_energy`, :func:`power_spectrum`, :func:`pitch` — the work of
  :meth:`~facecapges.network.audio_features.AudioFeatures.forward` between its FFTs
  (:meth:`~facecapges.network.audio_features.AudioFeatures.forward_native`);
* :func:`cascade` — :meth:`~facecapges.network.batched.Cascade.run` (the torso LSTM and
  the limb LSTM it conditions over one window, in lockstep: iteration m runs torso
  step m and limb step m − 1, whose input is the torso output the iteration starts
  from; the limb's recurrent product skips the torso columns, so no zero block).

They are the second schedule of each computation, chosen by batch size (the callers'
``native_max_batch``, the kernel's ``mel_native_max_batch``; at large batches the torch
schedule's matrix–matrix products win), and are tested against the naive loop like the
torch one. Gates are computed
in float64 with an exponential of this module (:func:`_exp`: 2^k · Taylor series of
e^r for |r| ≤ ln 2 / 2, relative error ~1e-16 before the float32 rounding) because it
compiles to SIMD code, where each libm ``expf``/``tanhf`` call is scalar (5 and 19 ns);
tanh(x) = 2σ(2x) − 1. Sums run in another order than torch's, so values agree to float
rounding (~1e-7 relative), not bit for bit.

Compiled on first use and cached on disk (``cache=True``, beside this file): a fresh
machine pays ~8 s once (``make setup`` does it); later processes load the machine code
when their first generator is built (:func:`warm`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")

_LOG2E = 1.4426950408889634
_LN2 = 0.6931471805599453
_INV_FACTORIAL = tuple(1.0 / math.factorial(n) for n in range(10))
_SLOPE = np.float32(0.2)  # the TCNs' leaky-ReLU slope (network.CausalTCN.layer)


@_jit
def _exp(v: np.ndarray, bits: np.ndarray) -> None:
    """``v[j] ← exp(v[j])`` in place (float64, |v| clipped to 80), vectorisable: ``bits`` is
    scratch of ``v``'s length (int64), the power of two 2^k as its IEEE bit pattern."""
    scale = bits.view(np.float64)
    for j in range(v.shape[0]):
        x = min(max(v[j], -80.0), 80.0)
        k = np.floor(x * _LOG2E + 0.5)
        r = x - k * _LN2  # |r| ≤ ln 2 / 2: Taylor to r^10 / 10! leaves < 1e-16
        p = 1.0 / 3628800.0
        for n in range(9, -1, -1):  # Horner: Σ r^n / n!, n = 10 … 0
            p = p * r + _INV_FACTORIAL[n]
        bits[j] = (np.int64(k) + 1023) << 52
        v[j] = p
    for j in range(v.shape[0]):
        v[j] *= scale[j]


@_jit
def _lstm_cell(g: np.ndarray, h: np.ndarray, c: np.ndarray, t: np.ndarray, bits: np.ndarray) -> None:
    """One LSTM cell from its gates ``g`` (4H, order i, f, g, o, float32): updates ``h``, ``c`` (H)
    in place. ``t`` (4H) float64 and ``bits`` (4H) int64 are scratch."""
    H = h.shape[0]
    for j in range(4 * H):  # σ(x) = 1 / (1 + e^−x) for i, f, o; tanh(x) = 2σ(2x) − 1 for g
        t[j] = -float(g[j])
    for j in range(2 * H, 3 * H):
        t[j] *= 2.0
    _exp(t, bits)
    for j in range(4 * H):
        t[j] = 1.0 / (1.0 + t[j])
    for j in range(H):
        cj = t[H + j] * float(c[j]) + t[j] * (2.0 * t[2 * H + j] - 1.0)
        c[j] = cj
        t[j] = -2.0 * float(c[j])  # tanh of the float32 state, as torch's h = o · tanh(c)
    _exp(t[:H], bits[:H])
    for j in range(H):
        h[j] = t[3 * H + j] * (2.0 / (1.0 + t[j]) - 1.0)


@_jit
def cascade(gx: np.ndarray, hc: np.ndarray, w_top: np.ndarray, w_u: np.ndarray, out: np.ndarray) -> None:
    """The two LSTMs over each row's window (:meth:`Cascade.run`): input gates ``gx`` (B, W, 8H)
    ``[torso | limb]`` (the limb's without its torso-output term), carried ``hc`` (B, 2, 2H)
    ``[[h_t | h_u], [c_t | c_u]]``; ``w_top`` (H, 8H) = ``[W_hh,t | W_x]`` (the torso output's
    weights in both), ``w_u`` (H, 4H) the limb's W_hh. Writes the final states into ``out``."""
    B, W, G = gx.shape
    H = G // 8
    g = np.empty(G, np.float32)
    g_t, g_u = g[: 4 * H], g[4 * H :]
    t, bits = np.empty(4 * H), np.empty(4 * H, np.int64)
    for n in range(B):
        h_t, h_u = hc[n, 0, :H].copy(), hc[n, 0, H:].copy()
        c_t, c_u = hc[n, 1, :H].copy(), hc[n, 1, H:].copy()
        for m in range(W + 1):  # torso step m (m < W) and limb step m − 1 (m ≥ 1)
            g_t[:] = gx[n, min(m, W - 1), : 4 * H]  # (loops over whole rows only: they vectorise)
            g_u[:] = gx[n, max(m - 1, 0), 4 * H :]
            for k in range(H):  # h_t is the torso output of step m − 1: the limb's input too
                a, w_k = h_t[k], w_top[k]
                for j in range(G):
                    g[j] += a * w_k[j]
            if m > 0:
                for k in range(H):
                    a, w_k = h_u[k], w_u[k]
                    for j in range(4 * H):
                        g_u[j] += a * w_k[j]
                _lstm_cell(g_u, h_u, c_u, t, bits)
            if m < W:
                _lstm_cell(g_t, h_t, c_t, t, bits)
        out[n, 0, :H], out[n, 0, H:] = h_t, h_u
        out[n, 1, :H], out[n, 1, H:] = c_t, c_u


@_jit
def tcn_taps(
    reg: np.ndarray,
    idx: np.ndarray,
    x: np.ndarray,
    w_past: np.ndarray,
    w_now: np.ndarray,
    b: np.ndarray,
    rows: np.ndarray,
    extra: np.ndarray,
    skip: np.ndarray,
) -> None:
    """:meth:`TCNTaps.step`: new frames ``x`` (B, C) of the slots ``idx`` (B,) → the TCN's skip sums
    into ``skip`` (B, C); shifts the registers ``reg`` (S, R, L, C). Layer i: ``w_past[i]``,
    ``w_now[i]`` (C, C) acting on the right of its past input (register row ``rows[i]`` = d_i − 1)
    and its current one, bias ``b[i]``; ``extra`` (B, C) joins the last layer (or is (0, C))."""
    B, C = x.shape
    R, L = reg.shape[1], reg.shape[2]
    cur, y = np.empty(C, np.float32), np.empty(C, np.float32)
    ins = np.empty((L, C), np.float32)
    for n in range(B):
        s = idx[n]
        cur[:] = x[n]
        for i in range(L):
            ins[i] = cur
            past = reg[s, rows[i], i]
            y[:] = b[i]
            for k in range(C):
                p, q = past[k], cur[k]
                for j in range(C):
                    y[j] += p * w_past[i, k, j] + q * w_now[i, k, j]
            if extra.shape[0] and i == L - 1:
                y += extra[n]
            for j in range(C):
                v = y[j]
                cur[j] += v if v > 0 else _SLOPE * v  # residual: cur − x is the sum of the layers' outputs
        for j in range(C):
            skip[n, j] = cur[j] - x[n, j]
        for r in range(R - 1, 0, -1):
            reg[s, r] = reg[s, r - 1]
        reg[s, 0] = ins


_warm = False


def warm() -> None:
    """Load (or, on a fresh machine, compile) the machine code of every function here for the
    argument types the kernel passes, so the cost is paid at start-up and not by a stream's
    first frame (``serve``'s first tick would drop frames): ~0.3 s from the on-disk cache."""
    global _warm
    if _warm:
        return
    f32, i64 = np.float32, np.int64
    reg, idx, x = np.zeros((1, 1, 1, 1), f32), np.zeros(1, i64), np.zeros((1, 1), f32)
    tcn_taps(reg, idx, x, np.zeros((1, 1, 1), f32), np.zeros((1, 1, 1), f32), x.copy(), idx.copy(), x[:0], x.copy())
    cascade(
        np.zeros((1, 1, 8), f32),
        np.zeros((1, 2, 2), f32),
        np.zeros((1, 8), f32),
        np.zeros((1, 4), f32),
        np.zeros((1, 2, 2), f32),
    )
    mel_energy(np.zeros((1, 1, 1, 2), f32), x, np.zeros((1, 1)), np.zeros((1, 2), f32), x.copy())
    power_spectrum(np.zeros((1, 1, 2), f32), x)
    pitch(np.zeros((1, 2), f32), 0, 1, np.zeros(2, f32), f32(0.3), np.zeros((1, 2), f32))
    _warm = True


@_jit
def mel_energy(spec: np.ndarray, x: np.ndarray, mel_t: np.ndarray, out: np.ndarray, x0: np.ndarray) -> None:
    """:class:`AudioFeatures` around its first FFT: the frames' window spectra ``spec``
    (B, n, F, 2) (re, im), their samples ``x`` (B, S) and the Mel map ``mel_t`` (F, 40) →
    ``out[:, :40]`` log-Mel dB, ``out[:, 40]`` energy dB; ``x0`` (B, n_ac) ← the mean-removed
    samples, zero padded (the autocorrelation's input)."""
    B, n, F = spec.shape[0], spec.shape[1], spec.shape[2]
    S, M = x.shape[1], mel_t.shape[1]
    power, mel = np.empty(F), np.empty(M)
    for b in range(B):
        power[:] = 0.0
        for w in range(n):
            for k in range(F):
                re, im = float(spec[b, w, k, 0]), float(spec[b, w, k, 1])
                power[k] += re * re + im * im
        mel[:] = 0.0
        for k in range(F):  # the power's mean over the windows, through the (linear) Mel map
            p, m_k = power[k] / n, mel_t[k]
            for j in range(M):
                mel[j] += p * m_k[j]
        for j in range(M):
            out[b, j] = 10.0 * np.log10(max(mel[j], 1e-10))
        total, sq = 0.0, 0.0
        for i in range(S):
            v = float(x[b, i])
            total += v
            sq += v * v
        out[b, M] = 10.0 * np.log10(sq / S + 1e-10)
        mean = total / S
        for i in range(S):
            x0[b, i] = x[b, i] - mean
        x0[b, S:] = 0.0


@_jit
def power_spectrum(spec: np.ndarray, out: np.ndarray) -> None:
    """|X|² of spectra ``spec`` (B, F, 2) (re, im) into ``out`` (B, F)."""
    for b in range(spec.shape[0]):
        for k in range(spec.shape[1]):
            re, im = spec[b, k, 0], spec[b, k, 1]
            out[b, k] = re * re + im * im


@_jit
def pitch(
    ac: np.ndarray, lag_min: int, lag_max: int, log_f0_of_lag: np.ndarray, voiced_min: np.float32, out: np.ndarray
) -> None:
    """:class:`AudioFeatures`' F0 from the frames' autocorrelations ``ac`` (B, ≥ lag_max + 1): the lag
    lag_min … lag_max of the highest normalised value (the first on ties) → its log2(F0 / 100 Hz)
    (0 when unvoiced) into ``out[:, -2]``, the voicing (that value, clipped to 0 … 1) into
    ``out[:, -1]``."""
    for b in range(ac.shape[0]):
        norm = np.float32(max(ac[b, 0], np.float32(1e-8)))
        best, arg = ac[b, lag_min] / norm, 0
        for lag in range(lag_min + 1, lag_max + 1):
            v = ac[b, lag] / norm
            if v > best:
                best, arg = v, lag - lag_min
        voicing = min(max(best, np.float32(0.0)), np.float32(1.0))
        last = out.shape[1] - 1
        out[b, last - 1] = log_f0_of_lag[arg] if voicing >= voiced_min else 0.0
        out[b, last] = voicing
