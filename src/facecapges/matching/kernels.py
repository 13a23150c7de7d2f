"""The matching engine's compiled loops (Numba): every batch size runs them, one stream (``live``) and a served
batch (``serve``) alike (docs/performance.md, "Engine step, third pass").

* :func:`dense_chain` — the speech predictor's runs of linear layers (:mod:`facecapges.matching.predictor`; its
  TCNs are the streaming kernel's :func:`facecapges.network.native.tcn_taps`, its Mel features'
  loops :mod:`facecapges.network.native`'s);
* :func:`step_offsets` — inertialization's frame (decay, ``exp(x) · base``, the acceleration cap) for the matcher's
  blend and the idle layer (:mod:`facecapges.matching.inertialize`, :mod:`facecapges.matching.idle`);
* :func:`dial` — the matcher's intensity dial (:mod:`facecapges.matching.matcher`, step 6);
* :func:`track` — the speech tracker's frame after its FFTs (:mod:`facecapges.matching.speech`);
* :func:`advance` — the matcher's advance to each stream's next row and its search triggers;
* :func:`search_rows` — the search's costs and choice after its matrix-vector products
  (:func:`facecapges.matching.matcher.search`), :func:`idle_pass` and :func:`idle_frame` — the idle layer's frame outside a pause and
  while no stream enters or leaves one,
  :func:`rot6d32` — the step's last conversion: unlike the others, these give the NumPy formulas' bits
  (only +, −, ·, /, sqrt, comparisons and float64 sin and cos — libm's and NumPy's agree here — in the formulas'
  order).

Each is one call for all the streams of a step instead of tens of NumPy calls on arrays of one stream. In the
dtypes of the NumPy formulas they replace; libm's exp, log, sin, cos and atan2 (NumPy has its own SIMD ones) and
sums in another order, so values agree to about one ulp, not bit for bit. Imported when an engine is built, not
with the modules that use it (``serve``'s server process and a command's error path never load Numba); the machine
code is cached beside this file (``cache=True``), filled by ``make setup`` (``scripts/warm-numba-caches.py``) and
loaded by :func:`warm` when an engine is built, never on a stream's first frame.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from facecapges.matching.inertialize import LN2
from facecapges.matching.predictor import LEAK
from facecapges.matching.speech import (
    BAND_OF,
    BAND_WEIGHT,
    ENERGY_ALPHA,
    FLAT_MAX,
    FLOOR_RISE_DB,
    HANGOVER,
    LAGS_0,
    LAGS_1,
    LEVEL_DECAY_DB,
    MIN_FLUX,
    N_BANDS,
    NEAR_DB,
    ONSET_K,
    OPEN_FRAMES,
    REFRACTORY,
    SILENCE_DB,
    SINCE_CAP,
    SINCE_VOICE_CAP,
    TONAL_BINS,
    TONAL_FRAMES,
    TONAL_SHARE,
    VAD_MARGIN_DB,
    VOICE_0,
    VOICE_1,
    VOICING,
)
from facecapges.rotations_compiled import qexp, qlog_abs, qmul, qmul_conj, quaternion_to_rot6d

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def dense_chain(x: np.ndarray, buf: np.ndarray, table: np.ndarray, out: np.ndarray, col: int) -> None:
    """Linear layers in a row over the rows of ``x`` (B, n_in) → ``out[:, col : col + n_out]``.

    Layer ``l`` is ``table[l]`` = (offset of its weights (n_in, n_out) in ``buf``, offset of its bias, n_in,
    n_out, activation: 0 none, 1 leaky ReLU 0.2, 2 ReLU), applied to every row before the next layer; each
    output is the sum over the inputs in their order, then the bias (float32, as ``x @ W + b``: the values
    equal NumPy's to float32 rounding, not bit for bit: BLAS sums in another order)."""
    B, width = x.shape[0], x.shape[1]
    for n_out in table[:, 3]:
        width = max(width, n_out)
    cur, nxt = np.empty((B, width), np.float32), np.empty((B, width), np.float32)
    n = x.shape[1]
    cur[:, :n] = x
    for layer in range(table.shape[0]):
        w_at, b_at, n_in, n = table[layer, 0], table[layer, 1], table[layer, 2], table[layer, 3]
        W, bias, act = buf[w_at : w_at + n_in * n].reshape((n_in, n)), buf[b_at : b_at + n], table[layer, 4]
        for b in range(B):
            acc, src = nxt[b, :n], cur[b]
            acc[:] = 0.0
            for i in range(n_in):
                xi, w_i = src[i], W[i]
                for o in range(n):
                    acc[o] += xi * w_i[o]
            for o in range(n):
                v = acc[o] + bias[o]
                if v < 0 and act == 1:
                    v = LEAK * v
                elif v < 0 and act == 2:
                    v = np.float32(0.0)
                acc[o] = v
        cur, nxt = nxt, cur
    out[:, col : col + n] = cur[:, :n]


@_jit
def step_offsets(
    slots: np.ndarray,
    x: np.ndarray,
    v: np.ndarray,
    halflife: np.ndarray,
    base: np.ndarray,
    prev: np.ndarray,
    cap: float,
    fps: float,
    shift: bool,
    out: np.ndarray,
) -> None:
    """One frame of inertialized streams: the shown poses ``out`` (n, J, 4) = exp(x) · ``base`` (n, J, 4) after the
    offsets ``x`` and velocities ``v`` (S, J, 3) of ``slots`` (n,) decay one frame (:func:`decay_spring`, half-life
    ``halflife[slot]``); then, unless ``cap`` < 0 (no cap), the whole-body angular acceleration against the last two poses shown
    (``prev[slot, 1]``, the last, and ``prev[slot, 0]``; (S, 2, J, 4)) stays below ``cap`` (rad/s², root sum of
    squares over the joints): a larger step is shortened along itself and the offset takes up the difference
    (``x ← log(shown · base⁻¹)``: the clip continues from the limited pose). ``shift``: ``prev[slot]`` ← (its last,
    the pose shown now). The matcher's blend and the idle layer's (:mod:`facecapges.matching.idle`) in one compiled
    loop: libm's exp, sin, cos and atan2 where NumPy has its own, and the acceleration's sum in order, so the values
    equal the NumPy formulas' to ~1 ulp, not bit for bit."""
    dt = 1.0 / fps
    J = x.shape[1]
    pred, t, d, e = np.empty(4), np.empty(4), np.empty((J, 3)), np.empty(4)
    for n in range(len(slots)):
        s = slots[n]
        y = 2.0 * LN2 / max(halflife[s], 1e-5)  # half the damping 4·ln2/h
        decay = np.exp(-y * dt)
        for j in range(J):
            for c in range(3):
                xj, vj = x[s, j, c], v[s, j, c]
                j1 = vj + xj * y
                x[s, j, c] = decay * (xj + j1 * dt)
                v[s, j, c] = decay * (vj - j1 * y * dt)
            qexp(x[s, j], e)
            qmul(e, base[n, j], out[n, j])
        if cap >= 0:
            total = 0.0
            for j in range(J):
                qmul_conj(prev[s, 1, j], prev[s, 0, j], t)
                qmul(t, prev[s, 1, j], pred)  # constant angular velocity
                qmul_conj(out[n, j], pred, t)
                qlog_abs(t, d[j])  # acceleration · dt²
                total += d[j, 0] * d[j, 0] + d[j, 1] * d[j, 1] + d[j, 2] * d[j, 2]
            total = np.sqrt(total) * fps**2
            if total > cap:
                for j in range(J):
                    for c in range(3):
                        d[j, c] *= cap / total
                    qmul_conj(prev[s, 1, j], prev[s, 0, j], t)
                    qmul(t, prev[s, 1, j], pred)
                    qexp(d[j], e)
                    qmul(e, pred, out[n, j])
                    qmul_conj(out[n, j], base[n, j], t)
                    qlog_abs(t, x[s, j])
        if shift:
            prev[s, 0] = prev[s, 1]
            prev[s, 1] = out[n]


@_jit
def dial(slots: np.ndarray, q: np.ndarray, mean: np.ndarray, slow: np.ndarray, beta: float, gain: np.ndarray) -> None:
    """The matcher's intensity dial on poses ``q`` (n, J, 4) of streams ``slots`` (n,), in place: each joint's
    deviation ``d = log(m⁻¹ q)`` from the style's idle mean ``mean`` (J, 4), its smoothing ``slow`` (S, J, 3) ←
    ``slow + beta · (d − slow)``, and where ``gain`` (n,) is not 1 (beyond 1e-9) ``q ← m · exp(d + (gain − 1) ·
    slow)`` (:mod:`facecapges.matching.matcher`, step 6). ``beta`` = 1 with ``slow`` zero and ``gain`` 1 sets the
    smoothing to the deviation itself (a stream's restart)."""
    t, inv, d = np.empty(4), np.empty((mean.shape[0], 4)), np.empty(3)
    for j in range(mean.shape[0]):
        inv[j, 0], inv[j, 1], inv[j, 2], inv[j, 3] = mean[j, 0], -mean[j, 1], -mean[j, 2], -mean[j, 3]
    for n in range(len(slots)):
        s, g = slots[n], gain[n]
        for j in range(mean.shape[0]):
            qmul(inv[j], q[n, j], t)
            qlog_abs(t, d)
            for c in range(3):
                slow[s, j, c] = slow[s, j, c] + beta * (d[c] - slow[s, j, c])
            if abs(g - 1.0) > 1e-9:
                for c in range(3):
                    d[c] = d[c] + (g - 1.0) * slow[s, j, c]
                qexp(d, t)
                qmul(mean[j], t, q[n, j])


@_jit
def search_rows(
    cost, row_sq, q_sq, playing, segment, lead, onset, recent, blocked, forced, stale, near, consts, out
) -> None:
    """:func:`facecapges.matching.matcher.search` after its matrix-vector products, for float32 costs: ``cost``
    (B, N) holds each query's products with the rows and becomes its costs; ``consts`` (4,) float32 = onset bonus,
    memory penalty (a float32 number), memory penalty of continuing, margin; ``out`` = best (B,) int64, its cost
    and the continuing cost (B,) float32, switch (B,) bool. Per query one pass over the rows instead of one NumPy
    call per rule: the same float32 operations in the same order (``sq − dot·2 + |q|²``, − the onset's bonus · lead,
    + the penalty, inf where blocked or continuing), and ``argmin``'s first smallest (a NaN first: itself), so the
    bits of the NumPy formulas."""
    best, best_cost, continue_cost, switch = out
    bonus, pen, stale_pen, margin = consts[0], consts[1], consts[2], consts[3]
    B, N = cost.shape
    two, inf = np.float32(2.0), np.float32(np.inf)
    for b in range(B):
        c, qs, p = cost[b], q_sq[b], playing[b]
        for r in range(N):
            c[r] = (row_sq[r] - c[r] * two) + qs
        cc = c[p]
        if onset[b]:
            for r in range(N):
                c[r] = c[r] - bonus * lead[r]
            cc = cc - bonus * lead[p]
        for r in range(N):
            if recent[b, r]:
                c[r] = c[r] + pen
            if blocked[b, r]:
                c[r] = inf
        for k in range(1 - near, near):
            r = p + k
            if r >= 0 and r < N and segment[r] == segment[p]:
                c[r] = inf
        at, v = 0, c[0]
        if not np.isnan(v):
            for r in range(1, N):
                if np.isnan(c[r]):
                    at = r
                    break
                if c[r] < v:
                    at, v = r, c[r]
        best[b], best_cost[b] = at, c[at]
        if forced[b]:
            cc = inf
        elif stale[b]:
            cc = cc + stale_pen
        continue_cost[b] = cc
        switch[b] = np.isfinite(c[at]) and c[at] < cc - margin


@_jit
def rot6d32(q: np.ndarray, out: np.ndarray) -> None:
    """``quaternion_to_rot6d(q).astype(np.float32)`` (:mod:`facecapges.rotations`) of poses ``q`` (B, J, 4) float64
    into ``out`` (B, J, 6) float32 in one call (the matcher's last step): each row by
    :func:`facecapges.rotations_compiled.quaternion_to_rot6d` (its bits), rounded to float32 once."""
    for b in range(q.shape[0]):
        for j in range(q.shape[1]):
            r = quaternion_to_rot6d(q[b, j, 0], q[b, j, 1], q[b, j, 2], q[b, j, 3])
            for k in range(6):
                out[b, j, k] = np.float32(r[k])


@_jit
def idle_pass(ids, q, since_voice, after, idle, x, v, prev_in, prev_out, out) -> bool:
    """The idle layer's frame when no stream of ``ids`` (n,) is in or entering a pause and every offset ``x``, ``v``
    (S, J, 3) is spent (zero): ``out`` (n, J, 4) ← the matched poses ``q`` with w ≥ 0 (``standardize_quaternion``:
    negated where w < 0), ``prev_in[slot]`` ← ``q``, ``prev_out[slot]`` ← (its last, ``out``); True. Else nothing
    is written and False (:meth:`facecapges.matching.idle.IdleLayer.apply` takes its general path)."""
    J = q.shape[1]
    for n in range(len(ids)):
        s = ids[n]
        if since_voice[n] >= after or idle[s]:
            return False
        for j in range(J):
            for c in range(3):
                if x[s, j, c] != 0.0 or v[s, j, c] != 0.0:
                    return False
    for n in range(len(ids)):
        s = ids[n]
        for j in range(J):
            neg = q[n, j, 0] < 0.0
            for c in range(4):
                out[n, j, c] = -q[n, j, c] if neg else q[n, j, c]
                prev_in[s, j, c] = q[n, j, c]
                prev_out[s, 0, j, c] = prev_out[s, 1, j, c]
                prev_out[s, 1, j, c] = out[n, j, c]
    return True


@_jit
def _spent_max(a: np.ndarray, spent: float) -> bool:
    """``np.maximum.reduce(np.abs(a)) > spent`` of one stream's offsets (J, 3) (a NaN makes the maximum NaN: False)."""
    m = 0.0
    for j in range(a.shape[0]):
        for c in range(a.shape[1]):
            v = abs(a[j, c])
            if np.isnan(v):
                return False
            m = max(m, v)
    return m > spent


@_jit
def _idle_pose(rest, joints, motion, secs, scale, base) -> None:
    """``IdleMotion.pose`` of one stream into ``base`` (J, 4): the rest pose ``rest`` (J, 4) with the idle of
    ``secs`` on ``joints``; ``motion`` (5, K, 3) = amplitude, the two sines' angular frequencies and phases.
    ``(amplitude · ((0 + sin(w₀ t + φ₀)) + sin(w₁ t + φ₁))) · scale``, then ``rest · exp(·)``: NumPy's operations
    in its order (its float64 ``sin`` and ``cos`` are libm's here: tests/test_matching_kernels.py)."""
    r, e = np.empty(3), np.empty(4)
    base[:] = rest
    for i in range(len(joints)):
        for c in range(3):
            s0 = np.sin(motion[1, i, c] * secs + motion[3, i, c])
            s1 = np.sin(motion[2, i, c] * secs + motion[4, i, c])
            r[c] = (motion[0, i, c] * ((0.0 + s0) + s1)) * scale
        qexp(r, e)
        qmul(rest[joints[i]], e, base[joints[i]])


@_jit
def idle_frame(ids, q, since_voice, t, gain, layer, state, motion, out) -> bool:
    """:meth:`facecapges.matching.idle.IdleLayer.apply`'s frame when no stream of ``ids`` (n,) enters or leaves a
    pause (else nothing is written and False): per stream the rest pose with the idle (in a pause) or the matched
    pose ``q`` (n, J, 4) as the base, the offset decayed and applied (:func:`step_offsets`, under the cap) while it
    is live (in a pause, or beyond ``SPENT``; else zeroed and ``q`` shown), w ≥ 0, the history shifted; True.
    ``layer`` = (after, fps, spent, cap, amplitude), ``state`` = the layer's (idle, target, x, v, hl, prev_in,
    prev_out, rest poses, idle joints, kept joints), ``motion`` as :func:`_idle_pose`'s. The NumPy formulas' bits."""
    after, fps, spent, cap, amplitude = layer
    idle, target, x, v, hl, prev_in, prev_out, rest, joints, keep = state
    for n in range(len(ids)):
        if (since_voice[n] >= after) != idle[ids[n]]:
            return False
    J = q.shape[1]
    base, shown, one = np.empty((1, J, 4)), np.empty((1, J, 4)), np.empty(1, np.int64)
    for n in range(len(ids)):
        s = ids[n]
        if idle[s]:
            _idle_pose(rest[target[s]], joints, motion, t[n] / fps, amplitude * gain[n], base[0])
            for j in range(J):
                if keep[j]:
                    base[0, j] = q[n, j]
        else:
            base[0] = q[n]
        if idle[s] or _spent_max(x[s], spent) or _spent_max(v[s], spent):
            one[0] = s
            step_offsets(one, x, v, hl, base, prev_out, cap, fps, False, shown)
        else:
            x[s], v[s] = 0.0, 0.0
            shown[0] = q[n]
        for j in range(J):
            neg = shown[0, j, 0] < 0.0
            for c in range(4):
                out[n, j, c] = -shown[0, j, c] if neg else shown[0, j, c]
                prev_in[s, j, c] = q[n, j, c]
                prev_out[s, 0, j, c] = prev_out[s, 1, j, c]
                prev_out[s, 1, j, c] = out[n, j, c]
    return True


@_jit
def advance(ids, speaking, onset, state, consts, out) -> bool:
    """The matcher's advance (step 3 of :mod:`facecapges.matching.matcher`) for streams ``ids`` (n,) with their
    speech cues ``speaking``, ``onset`` (n,): each plays its next row (backwards in an idle run played back; the
    same row at a clip's end), its counters move on, and whether it must search. ``state`` = the matcher's (row,
    next_row, prev_row, direction, idle_play, since_search, since_switch, was_speaking, quiet, last_used, canon, t,
    run_start, intensity_target), updated; ``consts`` = (idle-only intensity, idle_loop, min_play_frames,
    search_interval, memory in frames); ``out`` (n,) each = the next row, idle only, forced (the clip ended or left
    idle motion in a pause), into a recent stretch, must search. True if any stream must search. Integer and
    boolean rules and one float64 comparison: the NumPy formulas' values."""
    row, next_row, prev_row, direction, idle_play, since_search, since_switch = state[:7]
    was_speaking, quiet, last_used, canon, t, run_start, intensity = state[7:]
    idle_below, idle_loop, min_play, interval, memory = consts
    nxt_out, idle_out, forced_out, recent_out, need_out = out
    anyone = False
    for n in range(len(ids)):
        s, sp = ids[n], speaking[n]
        r = row[s]
        idle_only = (not sp) or intensity[s] < idle_below
        fwd, bwd = next_row[r], prev_row[r]
        back = idle_only and direction[s] < 0  # speech always plays forwards
        nxt = bwd if back else fwd
        if idle_loop:  # in a pause an idle run that ends plays back the way it came
            alt = fwd if back else bwd
            if idle_only and (nxt < 0 or not idle_play[nxt]) and alt >= 0 and idle_play[alt]:
                nxt, back = alt, not back
        direction[s] = -1 if back else 1
        ended = nxt < 0
        if ended:
            nxt = r
        off_state = idle_only and not idle_play[nxt]
        was = was_speaking[s]
        since_search[s] += 1
        since_switch[s] += 1
        settled = since_switch[s] >= min_play  # a clip plays a while before a search leaves it
        periodic = sp != was or onset[n] or since_search[s] >= interval
        last = last_used[s, canon[nxt]]
        into_recent = last > t[s] - memory and last < run_start[s]
        need = ended or off_state or (sp and not was) or into_recent or (settled and periodic)
        was_speaking[s] = sp
        quiet[s] = 0 if sp else quiet[s] + 1
        row[s] = nxt
        nxt_out[n], idle_out[n], forced_out[n], recent_out[n], need_out[n] = (
            nxt,
            idle_only,
            ended or off_state,
            into_recent,
            need,
        )
        anyone = anyone or need
    return anyone


@_jit
def _spectrum_cues(power: np.ndarray, ac: np.ndarray, bands: np.ndarray) -> tuple[float, float, float]:
    """One frame's log band powers into ``bands`` (N_BANDS,) from its power spectrum (513,) and autocorrelation
    (1024,); → voicing, flatness and the top bins' share (module docs)."""
    bands[:] = 0.0
    for k in range(power.shape[0]):  # each bin is in one band or none: spec @ _BANDS's sums without its zeros
        if BAND_OF[k] >= 0:
            bands[BAND_OF[k]] += power[k] * BAND_WEIGHT[k]
    for b in range(N_BANDS):
        bands[b] = np.log(bands[b] + np.float32(1e-10))
    peak = ac[LAGS_0]
    for k in range(LAGS_0 + 1, LAGS_1):
        peak = max(peak, ac[k])
    voicing = peak / max(ac[0], np.float32(1e-20))
    total, mantissas, exponents = 0.0, 1.0, 0
    top = np.zeros(TONAL_BINS)  # the largest bins, ascending (as a full sort leaves them)
    for k in range(VOICE_0, VOICE_1):
        v = float(power[k]) + 1e-12
        total += v
        m, e = math.frexp(v)  # the logs' sum as one log: of the mantissas' product (≥ 2^-249), plus the exponents
        mantissas *= m
        exponents += e
        if v > top[0]:
            i = 1
            while i < TONAL_BINS and top[i] < v:
                top[i - 1] = top[i]
                i += 1
            top[i - 1] = v
    n = VOICE_1 - VOICE_0
    flat = np.exp((np.log(mantissas) + exponents * LN2) / n) / (total / n)
    share = 0.0
    for v in top:
        share += v
    return voicing, flat, share / total


@_jit
def _level(x: np.ndarray) -> np.float32:
    """A frame's RMS level in dBFS (floor −100), float32, of its samples ``x`` (S,) (the sum in float64)."""
    sq, lanes, S = 0.0, np.zeros(8), len(x)
    for i in range(0, S - S % 8, 8):  # eight running sums (as NumPy's pairwise sum has): not one long chain
        for j in range(8):
            lanes[j] += float(x[i + j]) * float(x[i + j])
    for i in range(S - S % 8, S):
        sq += float(x[i]) * float(x[i])
    sq += ((lanes[0] + lanes[1]) + (lanes[2] + lanes[3])) + ((lanes[4] + lanes[5]) + (lanes[6] + lanes[7]))
    rms = np.sqrt(sq / S + 1e-20) if S else 0.0
    return np.float32(max(20.0 * np.log10(rms + 1e-12), -100.0))


@_jit
def _flux(bands: np.ndarray, prev: np.ndarray, hist: np.ndarray) -> tuple[Any, Any, Any]:
    """The spectral flux of ``bands`` (N_BANDS,) against the last frame's ``prev`` (NaN: none, flux 0), and the mean
    and variance of the flux history ``hist`` (FLUX_HISTORY,) over its entries that are not NaN (0, 0: none)."""
    flux = np.float32(0.0)
    if not np.isnan(prev[0]):
        for b in range(N_BANDS):
            flux += max(bands[b] - prev[b], np.float32(0.0))
        flux /= np.float32(N_BANDS)
    valid, total = 0, np.float32(0.0)
    for v in hist:
        if not np.isnan(v):
            valid += 1
            total += v
    mean, var = 0.0, 0.0
    if valid:
        mean = total / valid
        for v in hist:
            if not np.isnan(v):
                var += (v - mean) ** 2
        var /= valid
    return flux, mean, var


@_jit
def _shift_in(row: np.ndarray, value: Any) -> None:
    """``row`` (k,) one place to the left, ``value`` last (a history)."""
    for k in range(len(row) - 1):
        row[k] = row[k + 1]
    row[len(row) - 1] = value


@_jit
def track(idx, a, power, ac, state, level, speaking, onset, since_onset, energy, since_voice) -> None:
    """The tracker's frame (module docs) for streams ``idx`` (B,): samples ``a`` (B, S), power spectra (B, 513) and
    autocorrelations (B, 1024) of the frames' last N_FFT samples (Hann); ``state`` :class:`SpeechTracker`'s arrays
    (updated); the cues into the last six (B,) arrays (:class:`SpeechFrame`). One compiled loop per stream, in the
    dtypes NumPy's formulas had (float32 levels, float64 sums): libm's log and exp and the sums in order, so the
    values equal those formulas' to ~1 ulp."""
    floor_, hang_, prev_bands, flux_hist, since_, energy_, count_, talk_, tonal_, run_, voice_ = state
    f32 = np.float32
    bands = np.empty(N_BANDS, np.float32)
    for n in range(len(idx)):
        s = idx[n]
        lv, first = _level(a[n]), count_[s] == 0
        floor = lv if first else min(lv, floor_[s] + f32(FLOOR_RISE_DB))
        loud = lv > max(f32(SILENCE_DB), floor + f32(VAD_MARGIN_DB))
        voicing, flat, top = _spectrum_cues(power[n], ac[n], bands)
        tonal = 0.0
        for k in range(1, TONAL_FRAMES):
            tonal += tonal_[s, k]
        tonal = (tonal + top) / TONAL_FRAMES
        voice_like = loud and (voicing >= f32(VOICING) or flat < FLAT_MAX) and tonal < TONAL_SHARE
        talk = max(talk_[s] - f32(LEVEL_DECAY_DB), lv if voice_like else f32(-100.0))
        like = voice_like and lv > talk - f32(NEAR_DB)
        run = run_[s] + 1 if like else 0
        hang = HANGOVER if run >= OPEN_FRAMES else max(hang_[s] - 1, 0)
        talking = run >= OPEN_FRAMES or hang > 0
        flux, mean, var = _flux(bands, prev_bands[s], flux_hist[s])
        since = min(since_[s] + 1, SINCE_CAP)
        fired = talking and flux > max(mean + ONSET_K * np.sqrt(var), MIN_FLUX) and since >= REFRACTORY
        since = 0 if fired else since
        en = lv if first else energy_[s] + f32(ENERGY_ALPHA) * (lv - energy_[s])
        voice = 0 if like else min(voice_[s] + 1, SINCE_VOICE_CAP)
        floor_[s], hang_[s], prev_bands[s], talk_[s], run_[s] = floor, hang, bands, talk, run
        _shift_in(tonal_[s], top)
        _shift_in(flux_hist[s], flux)
        since_[s], energy_[s], count_[s], voice_[s] = since, en, count_[s] + 1, voice
        level[n], speaking[n], onset[n], since_onset[n], energy[n], since_voice[n] = (
            lv,
            talking,
            fired,
            since,
            en,
            voice,
        )


def warm() -> None:
    """Load (or, on a fresh machine, compile: ``make setup`` does it once) the machine code of every function here
    and of the streaming kernel's (:func:`facecapges.network.native.warm`) for the argument types the engine
    passes."""
    from facecapges.matching.speech import N_FFT, SpeechTracker
    from facecapges.network import native

    native.warm()
    one = np.zeros((1, 1), np.float32)
    dense_chain(one, np.zeros(2, np.float32), np.array([[0, 1, 1, 1, 0]], np.int64), one.copy(), 0)
    ids, ones, z3, z4 = np.zeros(1, np.int64), np.ones(1), np.zeros((1, 1, 3)), np.zeros((1, 1, 4))
    step_offsets(ids, z3, z3.copy(), ones, z4, np.zeros((1, 2, 1, 4)), 1.0, 15.0, True, z4.copy())
    dial(ids, z4.copy(), z4[0].copy(), z3.copy(), 0.5, ones)
    f2, b1, b2 = np.zeros(2, np.float32), np.zeros(1, np.bool_), np.zeros((1, 2), np.bool_)
    out = (np.empty(1, np.intp), np.empty(1, np.float32), np.empty(1, np.float32), np.empty(1, np.bool_))
    search_rows(f2[None].copy(), f2, f2[:1], ids, np.zeros(2, np.int32), f2, b1, b2, b2, b1, b1, 1, f2.repeat(2), out)
    rot6d32(z4, np.empty((1, 1, 6), np.float32))
    i1, b1s = np.zeros(1, np.int64), np.zeros(1, np.bool_)
    state = (i1, i1, i1, i1, b1s, i1, i1, b1s, i1, np.zeros((1, 1), np.int64), i1, i1, i1, ones)
    advance(ids, b1s, b1s, state, (0.05, False, 1, 1, 900.0), (i1, b1s, b1s, b1s, b1s))
    idle_pass(ids, z4, ids, 1, b1, z3, z3, z4, np.zeros((1, 2, 1, 4)), z4.copy())
    state = (b1, ids, z3, z3, ones, z4, np.zeros((1, 2, 1, 4)), z4, ids, b1)
    idle_frame(ids, z4, ids, ids, ones, (1, 15.0, 1e-6, -1.0, 1.0), state, np.zeros((5, 1, 3)), z4.copy())
    SpeechTracker(1).step(ids, np.zeros((1, N_FFT), np.float32))
