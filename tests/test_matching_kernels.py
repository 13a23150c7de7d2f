"""The matching step's compiled pieces that keep the NumPy formulas' bits (docs/performance.md, "Engine step, fourth
pass"): the search's rules after its products, the idle layer's frame outside a pause, the last rot6d conversion,
and the FFTs called as ``numpy.fft`` calls them. Synthetic arrays, bytes compared."""

from __future__ import annotations

import numpy as np
import pytest

from facecapges.matching import kernels
from facecapges.matching.matcher import MatchingConfig, search
from facecapges.network.mel import irfft, rfft
from facecapges.rotations import quaternion_exp, quaternion_multiply, quaternion_to_rot6d, standardize_quaternion


@pytest.mark.parametrize("shape", [(1, 1024), (3, 5, 512), (300, 1536), (2, 1067), (4, 3)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_ffts_are_numpys_bits(shape, dtype):
    x = (np.random.default_rng(1).standard_normal(shape) * 3.0).astype(dtype)
    spec = rfft(x)
    assert spec.dtype == np.fft.rfft(x).dtype and spec.tobytes() == np.fft.rfft(x).tobytes()
    power = (spec.real**2 + spec.imag**2).astype(dtype)
    for n in (None, 2 * (shape[-1] // 2 + 1) - 1, 1536):
        assert irfft(power, n).tobytes() == np.fft.irfft(power, n).tobytes()
        assert irfft(spec, n).tobytes() == np.fft.irfft(spec, n).tobytes()


def _quaternions(rng, n):
    q = rng.standard_normal((n, 47, 4)) * rng.uniform(1e-10, 1e3, (n, 47, 1))
    q[0, :4] = [[0.0, 0.0, 0.0, 0.0], [-0.0, 1.0, -0.0, 0.0], [np.nan, 1.0, 0.0, 0.0], [-1.0, 1e-9, -1e-9, 0.0]]
    q[0, 4] = [1e-9, 0.0, 0.0, 0.0]
    return q


def test_rot6d32_is_the_numpy_formulas_bits():
    rng = np.random.default_rng(2)
    for n in (1, 300):
        q = _quaternions(rng, n)
        out = np.empty((n, 47, 6), np.float32)
        kernels.rot6d32(q, out)
        assert out.tobytes() == quaternion_to_rot6d(q).astype(np.float32).tobytes()


def test_idle_pass_is_the_fast_paths_bits_and_declines_a_pause():
    rng = np.random.default_rng(3)
    S, J = 5, 47
    ids = np.array([3, 0, 4])
    q = _quaternions(rng, 3)
    x, v = np.zeros((S, J, 3)), np.zeros((S, J, 3))
    x[1, 2, 0] = 1e-30  # a slot not stepped
    prev_in, prev_out = rng.standard_normal((S, J, 4)), rng.standard_normal((S, 2, J, 4))
    want_in, want_out = prev_in.copy(), prev_out.copy()
    out = np.empty_like(q)
    quiet, idle = np.array([0, 3, 6]), np.zeros(S, bool)
    assert kernels.idle_pass(ids, q, quiet, 7, idle, x, v, prev_in, prev_out, out)
    shown = standardize_quaternion(q)
    want_in[ids], want_out[ids, 0], want_out[ids, 1] = q, want_out[ids, 1], shown
    assert out.tobytes() == shown.tobytes()
    assert prev_in.tobytes() == want_in.tobytes() and prev_out.tobytes() == want_out.tobytes()
    for case in ("pause", "idle", "x", "v"):
        sv, idl, xx, vv = quiet.copy(), idle.copy(), x.copy(), v.copy()
        if case == "pause":
            sv[2] = 7
        elif case == "idle":
            idl[0] = True
        else:
            (xx if case == "x" else vv)[4, 46, 2] = -1e-300
        before = (prev_in.copy(), prev_out.copy())
        assert not kernels.idle_pass(ids, q, sv, 7, idl, xx, vv, prev_in, prev_out, out)
        assert prev_in.tobytes() == before[0].tobytes() and prev_out.tobytes() == before[1].tobytes()


@pytest.mark.parametrize("B", [1, 7, 300])
def test_compiled_search_is_the_numpy_formulas_bits(B):
    rng = np.random.default_rng(B)
    N, F = 400, 30
    feats = rng.standard_normal((N, F)).astype(np.float32)
    feats[200:210] = feats[100]  # ties: the first smallest wins
    sq = np.einsum("nf,nf->n", feats, feats)
    segment = np.repeat(np.arange(8), N // 8).astype(np.int32)
    lead = rng.uniform(0, 3, N).astype(np.float32)
    cfg = MatchingConfig(onset_bonus=2.0, memory_penalty=100.0, near_frames=8, margin=3.0)
    for trial in range(6):
        queries = feats[rng.integers(0, N, B)] + rng.normal(0, 0.3, (B, F)).astype(np.float32)
        if trial == 1:
            queries[0] = feats[100]  # exactly the tied rows
        playing = rng.integers(0, N, B)
        playing[0] = 0 if trial == 2 else N - 1 if trial == 3 else playing[0]  # near rows at the ends
        args = (
            rng.random(B) < 0.4,  # onset
            rng.random((B, N)) < 0.3,  # played recently
            rng.random((B, N)) < (0.99 if trial == 4 else 0.2),  # blocked
            rng.random(B) < 0.2,  # forced
            rng.random(B) < 0.3,  # stale
        )
        if trial == 5:
            args[2][0] = True  # every row blocked: cost inf, row 0
        got = search(
            feats, sq, queries, playing, segment, lead, onset_now=args[0], played_recently=args[1],
            blocked=args[2], forced=args[3], stale=args[4], config=cfg,
        )  # fmt: skip
        want = search(
            feats, sq, queries, playing, segment, lead, onset_now=args[0], played_recently=args[1],
            blocked=args[2], forced=args[3], stale=args[4], config=cfg, compiled=False,
        )  # fmt: skip
        for g, w in zip(got, want, strict=True):
            assert g.dtype == w.dtype and g.tobytes() == w.tobytes()


def _layers(acc_cap: float):
    from facecapges.matching.idle import IDLE_JOINTS, IdleLayer, IdleMotion
    from facecapges.skeleton import TORSO, UPPER_BODY

    rng = np.random.default_rng(5)
    K = len(IDLE_JOINTS)
    rest = standardize_quaternion(rng.standard_normal((4, 47, 4)))
    rest /= np.linalg.norm(rest, axis=-1, keepdims=True)
    motion = IdleMotion(
        np.array([UPPER_BODY.index(j) for j in IDLE_JOINTS]),
        rng.uniform(0.0, 0.2, (K, 3)),
        rng.uniform(0.1, 1.0, (K, 3)),
        rest,
        rng.uniform(0.0, 2.0 * np.pi, (2, K, 3)),
    )
    kw = dict(after_frames=3, enter_halflife_s=0.2, release_halflife_s=0.1, amplitude=1.1, acc_cap=acc_cap)
    return [IdleLayer(motion, 15, keep=TORSO[1:], enter_velocity=0.0, **kw) for _ in range(2)]


@pytest.mark.parametrize("acc_cap", [0.0, 40.0])
def test_idle_frame_is_the_numpy_paths_bits(acc_cap):
    """The idle layer with its compiled frames (idle_pass, idle_frame) against its NumPy path alone, 3 streams of
    a batch of 4 through pauses that start and end at different frames, bytes of every pose and of the state."""
    compiled, numpy_only = _layers(acc_cap)
    numpy_only._pass = numpy_only._frame = lambda *args: False
    rng = np.random.default_rng(6)
    for layer in (compiled, numpy_only):
        layer.grow(4)
    ids = np.array([2, 0, 3])
    q = standardize_quaternion(rng.standard_normal((3, 47, 4)))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    for layer in (compiled, numpy_only):
        layer.restart(ids, q)
    since = np.zeros(3, np.int64)
    for t in range(120):
        step = np.zeros((3, 47, 3))
        step[:, :, rng.integers(0, 3)] = rng.normal(0, 0.05, (3, 47))  # the matched motion moves on
        q = quaternion_multiply(quaternion_exp(step), q)
        voice = rng.random(3) < (0.9 if (t // 25) % 2 == 0 else 0.05)
        since = np.where(voice, 0, since + 1)
        gain = 1.0 + 0.3 * rng.random(3)
        got = compiled.apply(ids, q, since, np.full(3, t), gain)
        want = numpy_only.apply(ids, q, since, np.full(3, t), gain)
        assert got.tobytes() == want.tobytes(), t
    for name in ("idle", "target", "x", "v", "hl", "prev_in", "prev_out"):
        assert getattr(compiled, name).tobytes() == getattr(numpy_only, name).tobytes(), name


def _numpy_advance(ids, speaking, onset, st, consts):
    """The matcher's advance as NumPy formulas (main's ``_advance_and_search`` before the kernel)."""
    row_a, next_row, prev_row, direction, idle_play, since_search, since_switch = st[:7]
    was_speaking, quiet, last_used, canon, t, run_start, intensity = st[7:]
    idle_below, idle_loop, min_play, interval, memory = consts
    row = row_a[ids]
    idle_only = (~speaking) | (intensity[ids] < idle_below)
    fwd, bwd = next_row[row], prev_row[row]
    back = idle_only & (direction[ids] < 0)
    nxt = np.where(back, bwd, fwd)
    if idle_loop:
        alt = np.where(back, fwd, bwd)
        bounce = idle_only & ((nxt < 0) | ~idle_play[nxt]) & (alt >= 0) & idle_play[alt]
        nxt = np.where(bounce, alt, nxt)
        back = back ^ bounce
    direction[ids] = np.where(back, -1, 1)
    ended = nxt < 0
    nxt = np.where(ended, row, nxt)
    off_state = idle_only & ~idle_play[nxt]
    was = was_speaking[ids]
    ss, sw = since_search[ids] + 1, since_switch[ids] + 1
    since_search[ids], since_switch[ids] = ss, sw
    periodic = (speaking != was) | onset | (ss >= interval)
    last = last_used[ids, canon[nxt]]
    into_recent = (last > t[ids] - memory) & (last < run_start[ids])
    need = ended | off_state | (speaking & ~was) | into_recent | ((sw >= min_play) & periodic)
    was_speaking[ids] = speaking
    quiet[ids] = np.where(speaking, 0, quiet[ids] + 1)
    row_a[ids] = nxt
    return nxt, idle_only, ended | off_state, into_recent, need


@pytest.mark.parametrize("idle_loop", [False, True])
def test_advance_is_the_numpy_formulas(idle_loop):
    rng = np.random.default_rng(8)
    N, S = 60, 9
    seg = np.repeat(np.arange(4), N // 4)
    next_row, prev_row = np.arange(1, N + 1), np.arange(-1, N - 1)
    next_row[np.r_[seg[1:] != seg[:-1], True]] = -1
    prev_row[np.r_[True, seg[1:] != seg[:-1]]] = -1
    canon = np.arange(N) % 30
    st = [
        rng.integers(0, N, S), next_row, prev_row, rng.choice([-1, 1], S), rng.random(N) < 0.6,
        rng.integers(0, 4, S), rng.integers(0, 8, S), rng.random(S) < 0.5, rng.integers(0, 5, S),
        rng.integers(-100, 200, (S, N)), canon, rng.integers(100, 200, S), rng.integers(0, 200, S),
        rng.choice([0.0, 0.04, 1.0, 1.3], S),
    ]  # fmt: skip
    ref = [a.copy() for a in st]
    consts = (0.05, idle_loop, 6, 2, 60.0)
    for _ in range(200):
        ids = rng.permutation(S)[: rng.integers(1, S + 1)]
        speaking, onset = rng.random(len(ids)) < 0.5, rng.random(len(ids)) < 0.2
        out = tuple(np.empty(len(ids), t) for t in (np.int64,) + (np.bool_,) * 4)
        anyone = kernels.advance(ids, speaking, onset, tuple(st), consts, out)
        want = _numpy_advance(ids, speaking, onset, ref, consts)
        assert anyone == bool(want[4].any())
        assert all(np.array_equal(g, w) for g, w in zip(out, want, strict=True))
        assert all(np.array_equal(a, b) for a, b in zip(st, ref, strict=True))
        for a in (st, ref):  # a search now and then: the run restarts, the memory moves on
            a[11][ids] += 1
            a[9][ids[0], canon[a[0][ids[0]]]] = a[11][ids[0]]
