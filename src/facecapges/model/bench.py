"""Speed of the gesture model (``facecapges bench --only model``).

Figures (one stream, batch 1, one thread, the default checkpoint):

* ``step_ms_p50`` / ``step_ms_p99`` — :meth:`StreamingGenerator.step` (cached
  encoder state), and ``naive_step_ms_p50`` / ``naive_step_ms_p99`` for the loop that
  re-encodes the whole window every frame; the two run interleaved, frame by frame,
  on the same inputs, so machine load hits both alike. ``speedup`` is their ratio.
* ``max_abs_diff_naive`` — the two loops' outputs must agree (they compute the same
  function).
* ``offline_fps`` — frames per second of :func:`generate_poses` over a 60 s input.
"""

from __future__ import annotations

import time

import numpy as np
import torch


def _inputs(T: int, spf: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.arange(T * spf) / 16000.0
    # speech-like: a few harmonics with a syllable-rate envelope, plus a little noise
    env = 0.5 * (1 + np.sin(2 * np.pi * 4.0 * t))
    wave = env * (0.2 * np.sin(2 * np.pi * 140 * t) + 0.1 * np.sin(2 * np.pi * 280 * t)) + 0.01 * rng.standard_normal(t.size)
    audio = wave.astype(np.float32).reshape(T, spf)
    face = rng.uniform(0, 0.3, (T, 52)).astype(np.float32)
    head = np.tile(np.array([1, 0, 0, 0, 1, 0], np.float32), (T, 1))
    return audio, face, head


def run(quick: bool = False) -> dict:
    from facecapges.model.checkpoint import load_checkpoint
    from facecapges.model.generate import FrameInputs, generate_poses
    from facecapges.model.streaming import NaiveStreamingGenerator, StreamingGenerator

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        ckpt = load_checkpoint()
        cfg = ckpt.model.cfg
        n = 150 if quick else 900
        audio, face, head = _inputs(n, cfg.samples_per_frame)
        fast = StreamingGenerator(ckpt.model, ckpt.neutral_window)
        naive = NaiveStreamingGenerator(ckpt.model, ckpt.neutral_window)
        for g in (fast, naive):  # warm the allocator and caches
            for t in range(20):
                g.step(audio[t], face[t], head[t])
            g.reset()
        t_fast, t_naive, diff = [], [], 0.0
        for t in range(n):
            t0 = time.perf_counter()
            a = fast.step(audio[t], face[t], head[t])
            t1 = time.perf_counter()
            b = naive.step(audio[t], face[t], head[t])
            t2 = time.perf_counter()
            t_fast.append(t1 - t0)
            t_naive.append(t2 - t1)
            diff = max(diff, float(np.abs(a - b).max()))
        t_fast_ms, t_naive_ms = np.array(t_fast) * 1e3, np.array(t_naive) * 1e3

        T = 60 * cfg.fps
        audio, face, head = _inputs(T, cfg.samples_per_frame, seed=1)
        t0 = time.perf_counter()
        generate_poses(ckpt, FrameInputs(audio=audio, face=face, head=head, fps=cfg.fps, notes=[]), progress=False)
        offline_s = time.perf_counter() - t0
    finally:
        torch.set_num_threads(threads)
    return {
        "threads": 1,
        "frames": n,
        "step_ms_p50": round(float(np.percentile(t_fast_ms, 50)), 3),
        "step_ms_p99": round(float(np.percentile(t_fast_ms, 99)), 3),
        "step_ms_mean": round(float(t_fast_ms.mean()), 3),
        "naive_step_ms_p50": round(float(np.percentile(t_naive_ms, 50)), 3),
        "naive_step_ms_p99": round(float(np.percentile(t_naive_ms, 99)), 3),
        "speedup": round(float(np.percentile(t_naive_ms, 50) / np.percentile(t_fast_ms, 50)), 2),
        "max_abs_diff_naive": diff,
        "offline_fps": round(T / offline_s, 1),
        "offline_seconds_for_60s": round(offline_s, 2),
        "target": {"step_ms_p50_max": 2.0, "speedup_min": 3.0},
    }
