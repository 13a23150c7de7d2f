"""Benchmark of the motion-matching engine (``facecapges bench --only matching``).

On the shipped matching style (:data:`BENCH_STYLE`; its database and speech predictor), one
thread, unseen speech of the shared folder (``data/beat/2_scott_0_4_4.wav``), no face, the head
facing the camera:

* ``step_ms_p50`` / ``step_ms_p99`` — :meth:`MatchingStream.step` of one stream, every step
  (predictor, speech cues, search every few frames and at onsets, blending); also the p50 of the
  steps that searched and of those that did not, and of the predictor alone;
* ``step_cpu_ms_p50`` / ``step_cpu_ms_mean`` — the same steps' CPU time (``time.thread_time``: what the
  step costs, without the waits of a busy machine that the wall-clock figures above include);
* ``batched_ms_per_stream`` — :meth:`BatchedMatchingStreams.step` time / B at B = 1, 16, 64 and 300 (what
  ``serve`` steps per tick at its target); ``batched_cpu_ms_per_stream`` the same in CPU time, and
  ``batched_tick_cpu_ms`` one tick's CPU time (the median step of all B streams);
* ``search`` — one query's nearest row over the whole database: the engine's brute force in
  NumPy against ``scipy.spatial.cKDTree`` (build and query), the measurement behind the choice
  of brute force (the kd-tree cannot apply the engine's masks and penalties either).

``quick`` runs 150 frames (B = 1, 16 and 300; 40 ticks at 300) instead of 900 (B = 1, 16, 64, 300; 150 ticks
each).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from facecapges import timing

BENCH_STYLE = "beat2-scott-mm"
AUDIO = "data/beat/2_scott_0_4_4.wav"


def _pct(xs: list[float], q: float) -> float:
    return round(float(np.percentile(np.asarray(xs) * 1e3, q)), 4)


def _single(ck, audio: np.ndarray, n: int) -> dict:
    from facecapges import rotations as rot

    spf = timing.samples_per_frame()
    gen = ck.streaming()
    face, head = np.zeros(52, np.float32), rot.identity_rot6d().astype(np.float32)
    times, cpu, searched = [], [], []
    for t in range(n):
        c0, t0 = time.thread_time(), time.perf_counter()
        gen.step(audio[t * spf : (t + 1) * spf], face, head)
        times.append(time.perf_counter() - t0)
        cpu.append(time.thread_time() - c0)
        searched.append(int(gen.kernel.since_search[0]) == 0)  # reset by a search in this step
    s = np.array(searched)
    out = {
        "frames": n,
        "step_ms_p50": _pct(times, 50),
        "step_ms_p99": _pct(times, 99),
        "step_cpu_ms_p50": _pct(cpu, 50),
        "step_cpu_ms_mean": round(float(np.mean(cpu)) * 1e3, 4),
        "search_step_ms_p50": _pct([x for x, k in zip(times, s, strict=True) if k], 50) if s.any() else None,
        "plain_step_ms_p50": _pct([x for x, k in zip(times, s, strict=True) if not k], 50) if (~s).any() else None,
        "searches_per_s": round(float(s.mean()) * timing.MODEL_FPS, 2),
        "switches_per_s": round(int(gen.kernel.switches[0]) / (n / timing.MODEL_FPS), 2),
    }
    if ck.predictor is not None:
        ps, pt = ck.predictor.stream(), []
        for t in range(min(n, 300)):
            t0 = time.perf_counter()
            ps.step(audio[t * spf : (t + 1) * spf], face, head)
            pt.append(time.perf_counter() - t0)
        out["predictor_ms_p50"] = _pct(pt, 50)
    return out


def _batched(ck, audio: np.ndarray, n: int, B: int) -> tuple[float, float, float]:
    """Per stream, the median step's wall-clock and CPU ms at B streams, and the tick's CPU ms (all B)."""
    from facecapges import rotations as rot

    spf = timing.samples_per_frame()
    kb = ck.batched(B)
    slots = [kb.open() for _ in range(B)]
    offs = (np.arange(B) * 37) % max(1, len(audio) // spf - n)
    face = np.zeros((B, 52), np.float32)
    head = np.broadcast_to(rot.identity_rot6d().astype(np.float32), (B, 6))
    times, cpu = [], []
    for t in range(n):
        a = np.stack([audio[(o + t) * spf : (o + t + 1) * spf] for o in offs])
        c0, t0 = time.thread_time(), time.perf_counter()
        kb.step(slots, a, face, head)
        times.append(time.perf_counter() - t0)
        cpu.append(time.thread_time() - c0)
    tick = float(np.median(cpu)) * 1e3
    return round(float(np.median(times)) * 1e3 / B, 4), round(tick / B, 4), round(tick, 3)


def _search(ck, reps: int) -> dict:
    from scipy.spatial import cKDTree

    F = ck.streaming().kernel.row_features
    rng = np.random.default_rng(0)
    qs = F[rng.integers(0, len(F), reps)] + rng.normal(0, 0.3, (reps, F.shape[1])).astype(np.float32)
    F_sq = np.einsum("nf,nf->n", F, F)
    t0 = time.perf_counter()
    for q in qs:
        int(np.argmin(F_sq - 2.0 * (F @ q)))
    brute = (time.perf_counter() - t0) / reps
    t0 = time.perf_counter()
    tree = cKDTree(F)
    build = time.perf_counter() - t0
    t0 = time.perf_counter()
    for q in qs:
        tree.query(q, k=1)
    kd = (time.perf_counter() - t0) / reps
    return {
        "rows": int(len(F)),
        "features": int(F.shape[1]),
        "brute_force_ms": round(brute * 1e3, 4),
        "kdtree_query_ms": round(kd * 1e3, 4),
        "kdtree_build_ms": round(build * 1e3, 3),
    }


def run(quick: bool, shared: Path) -> dict:
    """Figures of the matching engine on the shipped matching style (module docs)."""
    import torch

    from facecapges.errors import UserError
    from facecapges.io.audio import load_audio
    from facecapges.styles import load_style

    wav = Path(shared) / AUDIO
    if not wav.is_file():
        raise UserError(f"{wav}: the matching benchmark needs this shared clip")
    ck = load_style(style=BENCH_STYLE)
    from facecapges.matching.style import MatchingStyle

    if not isinstance(ck, MatchingStyle):
        raise UserError(f"style {BENCH_STYLE!r} is not a matching style")
    audio = load_audio(wav)
    n = 150 if quick else 900
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        out = {"style": BENCH_STYLE, "database_rows": len(ck.db), "threads": 1}
        out.update(_single(ck, audio, n))
        sizes = (1, 16, 300) if quick else (1, 16, 64, 300)
        batched = {B: _batched(ck, audio, 40 if (quick and B >= 300) else min(n, 150), B) for B in sizes}
        out["batched_ms_per_stream"] = {str(B): v[0] for B, v in batched.items()}
        out["batched_cpu_ms_per_stream"] = {str(B): v[1] for B, v in batched.items()}
        out["batched_tick_cpu_ms"] = {str(B): v[2] for B, v in batched.items()}
        out["search"] = _search(ck, 50 if quick else 300)
    finally:
        torch.set_num_threads(threads)
    return out
