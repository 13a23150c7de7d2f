"""Speed of the gesture model (``facecapges bench --only model``).

Figures (one stream, batch 1, one thread, the default checkpoint):

* ``step_ms_p50`` / ``step_ms_p99`` — :meth:`NetworkStream.step` (the cached
  kernel, a one-slot :class:`~facecapges.network.batched.BatchedNetworkStreams`);
  ``to_bvh_euler_ms_p50`` — that frame's rot6d → BVH Euler motion row
  (:func:`facecapges.skeleton.pose_to_motion`, what every BVH / viewer output runs);
  ``step_with_euler_ms_p50`` / ``_p99`` — the two together, per frame (target
  ≤ 1.0 ms at p50). ``naive_step_ms_p50`` / ``_p99`` — the loop that re-encodes the
  whole window every frame (the test oracle); the two generators run side by side in
  alternating blocks of 25 frames on the same inputs, so machine load hits both alike.
  ``speedup`` is the ratio of their p50 step times (target ≥ 3).
* ``cpu_ms`` — the same steps' CPU time (``time.thread_time``, the thread's own
  clock): on a loaded machine the wall clock adds waits for a core to every step,
  short ones most (so the wall-clock ``speedup`` shrinks towards 1); the CPU time does
  not.
* ``max_abs_diff_naive`` — the two loops' outputs must agree (same function).
* ``offline_fps`` — frames per second of :func:`generate_poses` (60 s of input; 10 s
  with ``--quick``).
* ``load_average_before`` / ``_after`` — the machine is shared: read ratios, not
  absolute times, when it is busy.

Thesis 5.8 figures (:func:`speed_report`, under ``"thesis_5_8"``; batch 1, one thread):

* ``per_frame`` — 5.8.1: :meth:`NetworkStream.step` over **all held-out frames**
  of the shared clip (``data/beat/2_scott_0_1_1`` of the shared folder the command
  passes; frames ≥ the checkpoint's ``holdout_from``, its own audio and head rotation,
  face zero as in the cache) from a cold start: mean, p50, p99, total. Without the
  shared folder, synthetic speech-like frames, and ``inputs`` says so.
* ``stages_ms`` — 5.8.2's compute chain split by stage, per frame (mean and p50): the
  kernel's own stage scopes (``facecapges::<stage>`` for ``torch.profiler``:
  :data:`~facecapges.network.batched.STAGES` — input_prep, audio_frontend, audio_tcn,
  face_encoder, head_encoder, decoder), each timed by a wall-clock listener during
  the real step (the torch profiler's per-op recording would cost more than the ops),
  and ``to_bvh_euler``. ``audio_features_ms`` = frontend + TCN step.
* ``compute`` — multiply–accumulates per frame, **counted** with
  ``torch.utils.flop_counter.FlopCounterMode`` over one ``step`` and one naive step,
  per kernel stage too (a nested counter per stage scope). The counted step runs the
  kernel's torch schedules (``native_max_batch`` = 0 on the TCNs and the
  :class:`~facecapges.network.batched.Cascade`, ``mel_native_max_batch`` = 0): the
  one-stream native loops (:mod:`facecapges.network.native`) are the same arithmetic, which
  the counter cannot see. The counter counts matrix
  products and convolutions as 2 FLOPs per MAC, so MACs = FLOPs / 2; element-wise
  work (activations, gates, additions) is not counted and is small beside the
  products. ``lstm_window_check`` compares the count for one 17-step LSTM window with
  the analytic 17·H·4H MACs.
* ``cpu_peak_gflops_1thread`` — a 1024×1024 float32 matmul on one thread (best of
  several), the practical peak of this CPU for dense float32 work;
  ``step_gflops_per_s`` = counted FLOPs / measured step time, and
  ``fraction_of_peak`` their ratio. Where the rest goes (per-call overhead of 70
  torch calls per frame, matrix–vector products bound by reading their weights from
  L2 — the recurrence's 3.5 MB per frame —, FFTs and element-wise work the counter
  does not count): :mod:`facecapges.network.batched`'s docs.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import torch

from facecapges.arkit import N_BLENDSHAPES
from facecapges.timing import AUDIO_SR


def _inputs(T: int, spf: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.arange(T * spf) / AUDIO_SR
    # speech-like: a few harmonics with a syllable-rate envelope, plus a little noise
    env = 0.5 * (1 + np.sin(2 * np.pi * 4.0 * t))
    wave = env * (0.2 * np.sin(2 * np.pi * 140 * t) + 0.1 * np.sin(2 * np.pi * 280 * t)) + 0.01 * rng.standard_normal(
        t.size
    )
    audio = wave.astype(np.float32).reshape(T, spf)
    face = rng.uniform(0, 0.3, (T, N_BLENDSHAPES)).astype(np.float32)
    head = np.tile(np.array([1, 0, 0, 0, 1, 0], np.float32), (T, 1))
    return audio, face, head


def _to_bvh_euler(skel):
    """One frame's rot6d (47, 6) → its BVH motion row: the conversion every BVH/viewer output runs."""
    from facecapges.skeleton import pose_to_motion

    return lambda pose: pose_to_motion(skel, pose[None])


def run(quick: bool = False, shared: Path | None = None) -> dict:
    from facecapges.engine.generate import generate_poses
    from facecapges.engine.inputs import FrameInputs
    from facecapges.network.streaming import NaiveNetworkStream, NetworkStream
    from facecapges.styles import DEFAULT_NETWORK_STYLE, load_style, network_only

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    load_before = [round(x, 2) for x in os.getloadavg()]
    try:
        ckpt = network_only(load_style(style=DEFAULT_NETWORK_STYLE), "the model bench")
        cfg = ckpt.model.cfg
        n = 150 if quick else 450
        audio, face, head = _inputs(n, cfg.samples_per_frame)
        fast = NetworkStream(ckpt.model, ckpt.neutral_window)
        naive = NaiveNetworkStream(ckpt.model, ckpt.neutral_window)
        euler = _to_bvh_euler(ckpt.skeleton)
        for g in (fast, naive):  # warm the allocator and caches
            for t in range(20):
                euler(g.step(audio[t], face[t], head[t]))
            g.reset()
        # side by side in alternating blocks of frames: both see the same machine load,
        # and neither evicts the other's working set from the cache on every frame
        # wall clock, and the thread's CPU time (time.thread_time: without the waits for a
        # core that a loaded machine adds to every step alike)
        t_fast, t_euler, t_naive, c_fast, c_euler, c_naive, diff, block = [], [], [], [], [], [], 0.0, 25
        clock, cpu = time.perf_counter, time.thread_time
        for start in range(0, n, block):
            frames = range(start, min(start + block, n))
            outs = []
            for t in frames:
                t0, c0 = clock(), cpu()
                outs.append(fast.step(audio[t], face[t], head[t]))
                t1, c1 = clock(), cpu()
                euler(outs[-1])
                t_fast.append(t1 - t0)
                c_fast.append(c1 - c0)
                t_euler.append(clock() - t1)
                c_euler.append(cpu() - c1)
            for t, a in zip(frames, outs):
                t0, c0 = clock(), cpu()
                b = naive.step(audio[t], face[t], head[t])
                t_naive.append(clock() - t0)
                c_naive.append(cpu() - c0)
                diff = max(diff, float(np.abs(a - b).max()))
        ms = {
            k: np.array(v) * 1e3
            for k, v in (
                ("fast", t_fast),
                ("euler", t_euler),
                ("naive", t_naive),
                ("fast_cpu", c_fast),
                ("euler_cpu", c_euler),
                ("naive_cpu", c_naive),
            )
        }
        with_euler = ms["fast"] + ms["euler"]
        with_euler_cpu = ms["fast_cpu"] + ms["euler_cpu"]
        T = (10 if quick else 60) * cfg.fps
        audio, face, head = _inputs(T, cfg.samples_per_frame, seed=1)
        t0 = time.perf_counter()
        generate_poses(ckpt, FrameInputs(audio=audio, face=face, head=head, fps=cfg.fps, notes=[]), progress=False)
        offline_s = time.perf_counter() - t0
        thesis = speed_report(ckpt, quick, shared)
    finally:
        torch.set_num_threads(threads)

    def pct(x, q):
        return round(float(np.percentile(x, q)), 3)

    return {
        "threads": 1,
        "frames": n,
        "load_average_before": load_before,
        "step_ms_p50": pct(ms["fast"], 50),
        "step_ms_p99": pct(ms["fast"], 99),
        "step_ms_mean": round(float(ms["fast"].mean()), 3),
        "to_bvh_euler_ms_p50": pct(ms["euler"], 50),
        "step_with_euler_ms_p50": pct(with_euler, 50),
        "step_with_euler_ms_p99": pct(with_euler, 99),
        "naive_step_ms_p50": pct(ms["naive"], 50),
        "naive_step_ms_p99": pct(ms["naive"], 99),
        "speedup": round(float(np.percentile(ms["naive"], 50) / np.percentile(ms["fast"], 50)), 2),
        "cpu_ms": {
            "step_p50": pct(ms["fast_cpu"], 50),
            "step_p99": pct(ms["fast_cpu"], 99),
            "to_bvh_euler_p50": pct(ms["euler_cpu"], 50),
            "step_with_euler_p50": pct(with_euler_cpu, 50),
            "step_with_euler_p99": pct(with_euler_cpu, 99),
            "naive_step_p50": pct(ms["naive_cpu"], 50),
            "speedup": round(float(np.percentile(ms["naive_cpu"], 50) / np.percentile(ms["fast_cpu"], 50)), 2),
            "what": "the same steps' CPU time (time.thread_time): no waiting for a core",
        },
        "max_abs_diff_naive": diff,
        "offline_fps": round(T / offline_s, 1),
        "offline_seconds": round(offline_s, 2),
        "offline_input_seconds": T // cfg.fps,
        "target": {"step_with_euler_ms_p50_max": 1.0, "speedup_min": 3.0},
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
        "thesis_5_8": thesis,
    }


# ------------------------------------------------------------------ thesis 5.8
def shared_held_out(ckpt, shared: Path | None):
    """(audio frames (T, S), face (T, 52), head (T, 6), label) of the shared clip's held-out frames, or None.

    ``shared``: the shared folder (``../shared`` beside the repository), given by the caller.
    """
    from facecapges import timing
    from facecapges.data import beat
    from facecapges.data.prepare import prepare_clip

    root = Path(shared) / "data" / "beat" if shared is not None else None
    files = [
        f
        for f in (beat.find_clips(root) if root is not None and root.is_dir() else [])
        if f.clip.stem == "2_scott_0_1_1"
    ]
    if not files or files[0].get("bvh") is None or files[0].get("wav") is None:
        return None
    fps, sr = ckpt.fps, ckpt.model.cfg.sr
    arrays = prepare_clip(files[0], fps, sr, None)[0]
    T = len(arrays["pose"])
    start = (ckpt.meta.get("train_config") or {}).get("holdout_from") or int(round(0.8 * T))
    s0 = int(timing.frame_sample_bounds(start, fps, sr)[0])
    n = T - start
    audio = timing.frame_audio(arrays["audio"][s0:], n, fps, sr)
    label = f"shared BEAT clip 2_scott_0_1_1, held-out frames {start}-{T - 1}"
    return audio.astype(np.float32), arrays["face"][start:], arrays["head"][start:], label


def _flops(fn, by_stage: bool = False):
    """FLOPs of ``fn()`` counted by ``FlopCounterMode``: (total, per op) and, with ``by_stage``,
    per kernel stage (each stage scope of the kernel counted by its own nested counter)."""
    import contextlib

    from torch.utils.flop_counter import FlopCounterMode

    from facecapges.network import batched

    stages: dict[str, int] = {}

    @contextlib.contextmanager
    def count(name: str):
        with FlopCounterMode(display=False) as inner:
            yield
        stages[name] = stages.get(name, 0) + int(inner.get_total_flops())

    if by_stage:
        batched.stage_listener = count
    try:
        with FlopCounterMode(display=False) as fc:
            fn()
    finally:
        batched.stage_listener = None
    per_op = {str(k).split(".")[-1]: int(v) for k, v in fc.get_flop_counts().get("Global", {}).items()}
    if by_stage:
        return int(fc.get_total_flops()), per_op, {k: stages.get(k, 0) for k in batched.STAGES}
    return int(fc.get_total_flops()), per_op


def cpu_peak_gflops(n: int = 1024, reps: int = 8) -> float:
    """Best GFLOP/s of an n×n float32 matmul on the current thread setting."""
    g = torch.Generator().manual_seed(0)
    a, b = torch.randn(n, n, generator=g), torch.randn(n, n, generator=g)
    out = torch.empty(n, n)
    torch.mm(a, b, out=out)
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        torch.mm(a, b, out=out)
        best = min(best, time.perf_counter() - t0)
    return 2 * n**3 / best / 1e9


def _profile_stages(gen, audio, face, head, euler) -> dict[str, np.ndarray]:
    """ms per frame of each kernel stage over the frames, timed at the kernel's own stage scopes.

    The kernel marks its stages with :func:`facecapges.network.batched.stage` (the
    ``facecapges::<stage>`` ``torch.profiler`` scopes); here a listener times each scope
    with the wall clock instead of the profiler, whose per-op recording costs more than
    the ops themselves and would distort the shares.
    """
    import contextlib

    from facecapges.network import batched

    times: dict[str, list] = {k: [] for k in (*batched.STAGES, "to_bvh_euler")}

    @contextlib.contextmanager
    def timed(name: str):
        t0 = time.perf_counter()
        yield
        times[name].append((time.perf_counter() - t0) * 1e3)

    batched.stage_listener = timed
    try:
        for t in range(len(audio)):
            pose = gen.step(audio[t], face[t], head[t])
            with timed("to_bvh_euler"):
                euler(pose)
    finally:
        batched.stage_listener = None
    return {k: np.array(v) for k, v in times.items()}


def speed_report(ckpt, quick: bool = False, shared: Path | None = None) -> dict:
    """Thesis 5.8 figures (module docstring); expects torch at one thread."""
    from facecapges.network.batched import lstm_window
    from facecapges.network.streaming import NaiveNetworkStream, NetworkStream

    cfg = ckpt.model.cfg
    data = shared_held_out(ckpt, shared)
    if data is None:
        audio, face, head = _inputs(191, cfg.samples_per_frame, seed=2)
        label = "synthetic speech-like frames (../shared/data/beat not found)"
    else:
        audio, face, head, label = data
    if quick:
        audio, face, head = audio[:60], face[:60], head[:60]
    T = len(audio)
    euler = _to_bvh_euler(ckpt.skeleton)
    # 5.8.1: per-frame inference, batching off, every held-out frame, cold start
    gen = NetworkStream(ckpt.model, ckpt.neutral_window)
    for t in range(min(20, T)):  # warm the allocator, then start the stream for real
        gen.step(audio[t], face[t], head[t])
    gen.reset()
    step_ms, ref = np.empty(T), np.empty((T, cfg.n_joints, 6), np.float32)
    t_all = time.perf_counter()
    for t in range(T):
        t0 = time.perf_counter()
        ref[t] = gen.step(audio[t], face[t], head[t])
        step_ms[t] = (time.perf_counter() - t0) * 1e3
    total_s = time.perf_counter() - t_all
    # 5.8.2: the same frames, the step's stages from its profiler scopes
    n_prof = min(T, 30 if quick else 120)
    gen2 = NetworkStream(ckpt.model, ckpt.neutral_window)
    times = _profile_stages(gen2, audio[:n_prof], face[:n_prof], head[:n_prof], euler)
    stage_ms = {k: {"mean": round(float(v.mean()), 4), "p50": round(float(np.median(v)), 4)} for k, v in times.items()}
    # counted MACs: one step (mid-stream), per stage, and one naive step
    gen3 = NetworkStream(ckpt.model, ckpt.neutral_window)
    # the torch schedules of the TCNs and the LSTM window: the counter sees only torch operations,
    # not the one-stream native ones (model.native)
    gen3.kernel.torch_schedules_only()
    naive = NaiveNetworkStream(ckpt.model, ckpt.neutral_window)
    k = min(T - 1, 3 * cfg.n_history)
    for t in range(k):  # a full window of real history first
        gen3.step(audio[t], face[t], head[t])
        naive.step(audio[t], face[t], head[t])
    step_flops, step_ops, stage_flops = _flops(lambda: gen3.step(audio[k], face[k], head[k]), by_stage=True)
    naive_flops, _ = _flops(lambda: naive.step(audio[k], face[k], head[k]))
    H, W = cfg.lstm_hidden, cfg.window
    analytic_lstm = W * H * 4 * H  # MACs of one 17-step recurrence (h·W_hh per step)
    lstm_counted = (
        _flops(
            lambda: lstm_window(torch.zeros(1, W, 4 * H), torch.zeros(1, H), torch.zeros(1, H), torch.zeros(H, 4 * H))
        )[0]
        // 2
    )
    peak = cpu_peak_gflops(512 if quick else 1024, 4 if quick else 8)
    step_mean_s = float(step_ms.mean()) / 1e3
    rate = step_flops / step_mean_s / 1e9
    audio_feat = times["audio_frontend"] + times["audio_tcn"]
    return {
        "inputs": label,
        "per_frame": {
            "frames": T,
            "batch": 1,
            "threads": torch.get_num_threads(),
            "mean_ms": round(float(step_ms.mean()), 4),
            "p50_ms": round(float(np.median(step_ms)), 4),
            "p99_ms": round(float(np.percentile(step_ms, 99)), 4),
            "max_ms": round(float(step_ms.max()), 4),
            "total_s": round(total_s, 4),
        },
        "audio_features_ms": {
            "mean": round(float(audio_feat.mean()), 4),
            "p50": round(float(np.median(audio_feat)), 4),
            "what": "audio frontend (strided convs over 1067 samples) + one cached audio TCN step "
            "+ MLP → z_A (profiled)",
        },
        "stages_ms": stage_ms,
        "stages_profiled_frames": n_prof,
        "stages_sum_ms_mean": round(float(sum(v.mean() for v in times.values())), 4),
        "compute": {
            "macs_per_frame": step_flops // 2,
            "flops_per_frame": step_flops,
            "macs_per_frame_by_stage": {n: f // 2 for n, f in stage_flops.items()},
            "macs_per_frame_by_op": {n: f // 2 for n, f in step_ops.items()},
            "naive_macs_per_frame": naive_flops // 2,
            "counter": "torch.utils.flop_counter.FlopCounterMode (matmul/conv FLOPs = 2·MACs; element-wise ops "
            "not counted)",
            "lstm_window_check": {
                "counted_macs": int(lstm_counted),
                "analytic_macs": int(analytic_lstm),
                "counted_equals_analytic": bool(lstm_counted == analytic_lstm),
            },
        },
        "cpu_peak_gflops_1thread": round(peak, 2),
        "step_gflops_per_s": round(rate, 4),
        "fraction_of_peak": round(rate / peak, 5),
    }
