"""A soak of ``facecapges live`` (issue #38): minutes of speech with pauses, in real time, recorded.

    PYTHONPATH=src nice -n 10 python scripts/soak_live.py --minutes 10 --out build/soak [--style NAME]

1. **Audio** (:func:`soak_audio`): speech the styles never trained on — BEAT speaker 2's unseen take
   ``2_scott_0_4_4.wav`` and the held-out last 20 % of ``2_scott_0_1_1.wav`` / ``2_scott_0_2_2.wav``
   (``../shared/data/beat``) — cut into stretches of 4–20 s (random offsets, cycled), each followed by a
   pause of 2–30 s (``--pause-range``): by turns digital zeros (a muted mic) and room tone (the 20
   quietest 0.1-s stretches of those recordings, looped). Seeded; the pause intervals are kept.
2. **Video**: the real face clip ``../shared/data/face/WDA_KatieHill_000.mp4`` looped to the audio's
   length (``scripts/capture_memory.py``'s :func:`looped_video`, ffmpeg stream copy).
3. **Run**: ``facecapges live --video V --audio A --realtime --record DIR`` as a child process (niced
   like its parent); its resident memory (:func:`facecapges.benchmarks.runtime.rss_mb`) sampled every second; its status
   lines (every 5 s: ``frame N``) time-stamped on arrival, so the drift = wall time since the first
   frame − N / fps over the run.
4. **Figures** (JSON on stdout and in ``OUT/soak.json``):

   * pops per minute overall, in the pauses and in speech, by the conversation metric's rule
     (:func:`facecapges.evaluation.conversation.score`): frames of the recorded ``motion.bvh`` whose
     whole-body joint acceleration (:func:`facecapges.evaluation.realism.transitions`) exceeds the
     99.9th percentile of his real motion — the training frames [0, 0.8 T) of both paired takes
     (:func:`his_reference`, as ``scripts/conversation_report.py``); a pause frame is one inside an
     inserted pause. With them, the metric's pause/speech wrist speed, still share, settle and resume;
   * memory: RSS at start / end, its least-squares slope over the run after the first 20 % (MB per
     minute; flat ≈ 0) — while frames are made (up to the last status line): ``close`` writing the recording
     afterwards takes 13–15 MB for a few seconds (``rss_mb_max_closing``), which is not a slope;
   * timing: ``late_frames`` and the other events of live's ``report.json``, the compute latency
     percentiles, and the drift of the status lines (first, last, slope in ms per minute), with the
     machine's load average (a busy machine makes every frame late: read the figures beside it).

``--wall-limit S`` stops ``live`` as Ctrl-C would after S seconds of wall time (it still writes its
recording); the figures then cover the frames made (``frames`` < ``frames_expected``).

The suite's short version: ``tests/test_soak_live.py`` (18 s of speech with a 2–6 s pause of each kind, seed 11; slow).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

SHARED = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
SR, FPS = 16000, 15.0


def soak_audio(seconds: float, pause_range: tuple[float, float], seed: int = 0, speech_range=(4.0, 20.0)):
    """(audio (S,), pauses [(start_s, end_s, kind)]) — module docstring, step 1."""
    from facecapges.io.audio import load_audio

    beat = SHARED / "beat"
    unseen = [load_audio(beat / "2_scott_0_4_4.wav", SR)]
    for name in ("2_scott_0_1_1.wav", "2_scott_0_2_2.wav"):
        a = load_audio(beat / name, SR)
        unseen.append(a[int(len(a) * 0.8) :])  # the held-out 20 %
    speech = np.concatenate(unseen).astype(np.float32)
    win = SR // 10  # room tone: the 20 quietest 0.1-s windows of the real recordings, one after another
    frames = speech[: len(speech) // win * win].reshape(-1, win)
    quiet = np.sort(np.argsort((frames.astype(np.float64) ** 2).mean(1))[:20])
    tone = frames[quiet].ravel()
    rng = np.random.default_rng(seed)
    parts, pauses, t, kinds = [], [], 0, ("zeros", "room tone")
    total = int(seconds * SR)
    while t < total:
        n = int(rng.uniform(*speech_range) * SR)
        s0 = int(rng.integers(0, len(speech) - n)) if len(speech) > n else 0
        chunk = speech[s0 : s0 + n][: total - t]
        parts.append(chunk)
        t += len(chunk)
        if t >= total:
            break
        p = min(int(rng.uniform(*pause_range) * SR), total - t)
        kind = kinds[len(pauses) % 2]
        parts.append(np.zeros(p, np.float32) if kind == "zeros" else np.resize(tone, p))
        pauses.append((t / SR, (t + p) / SR, kind))
        t += p
    return np.concatenate(parts), pauses


def his_reference(shared: Path = SHARED):
    """(skeleton, :class:`facecapges.evaluation.conversation.Reference`) of his real motion: the training
    frames [0, 0.8 T) of both paired takes, as ``scripts/conversation_report.py`` builds it."""
    from facecapges import timing
    from facecapges.evaluation import conversation as cv
    from facecapges.matching.takes import load_take

    beat = shared / "beat"
    t1 = load_take(beat / "2_scott_0_1_1.bvh", beat / "2_scott_0_1_1.wav")
    t2 = load_take(shared / "beat2" / "2_scott_0_2_2.npz", beat / "2_scott_0_2_2.wav", t1.skeleton)
    spf = timing.samples_per_frame()
    takes = (t1, t2)
    ref = cv.reference(
        t1.skeleton, [t.pose[: t.train_until] for t in takes], [t.audio[: t.train_until * spf] for t in takes]
    )
    return t1.skeleton, ref


def pop_figures(skel, pose: np.ndarray, pauses, ref, fps: float = FPS, audio: np.ndarray | None = None) -> dict:
    """Pops a minute overall / in pauses / in speech (module docstring, step 4): the conversation metric's
    :func:`facecapges.evaluation.conversation.score` with the inserted pauses as its pause frames; with the
    ``audio``, resume counts from the first word after a pause (``conversation.word_frames``: a stretch may start
    with a breath or a silence)."""
    from facecapges.evaluation import conversation as cv

    in_pause = np.zeros(len(pose), bool)
    for a, b, _ in pauses:
        in_pause[int(np.ceil(a * fps)) : int(np.floor(b * fps))] = True
    words = None if audio is None else cv.word_frames(audio, len(pose), in_pause, fps)
    sc = cv.score(skel, pose, in_pause, ref, fps, words=words)
    frames = np.asarray(sc.pops, int)
    pause_min, speech_min = in_pause.sum() / fps / 60, (~in_pause).sum() / fps / 60
    n_pause = int(in_pause[frames].sum()) if len(frames) else 0
    return {
        "pops": int(len(frames)),
        "pops_per_min": len(frames) / (len(pose) / fps / 60),
        "pops_in_pauses": n_pause,
        "pops_per_min_in_pauses": sc.pops_pause_per_min,
        "pops_in_speech": int(len(frames)) - n_pause,
        "pops_per_min_in_speech": sc.pops_speech_per_min,
        "pop_frames": frames.tolist(),
        "pause_minutes": float(pause_min),
        "speech_minutes": float(speech_min),
        "threshold_rad_s2": ref.threshold,
        "pause_over_speech_wrist_speed": sc.pause_over_speech_speed,
        "still_share": sc.still_share,
        "longest_still_s": sc.longest_still_s,
        "settle_s": sc.settle_s,
        "settle_ahead_s": sc.settle_ahead_s,
        "resume_s": sc.resume_s,
    }


def _slope_per_min(t_s: np.ndarray, y: np.ndarray, skip: float = 0.2) -> float:
    ok = np.isfinite(y) & (t_s >= t_s[-1] * skip) if len(t_s) else np.zeros(0, bool)
    if ok.sum() < 3:
        return float("nan")
    return float(np.polyfit(t_s[ok] / 60.0, y[ok], 1)[0])


def run_soak(
    minutes: float,
    out: Path,
    pause_range=(2.0, 30.0),
    style: str | None = None,
    seed: int = 0,
    wall_limit_s: float | None = None,
) -> dict:
    """Build the inputs, run ``live`` on them in real time, measure (module docstring)."""
    import soundfile as sf
    from capture_memory import looped_video

    from facecapges.benchmarks.runtime import rss_mb
    from facecapges.io.bvh import read_bvh
    from facecapges.skeleton import motion_to_pose

    out.mkdir(parents=True, exist_ok=True)
    audio, pauses = soak_audio(minutes * 60.0, pause_range, seed)
    wav = out / "soak.wav"
    sf.write(wav, audio, SR)
    video = looped_video(SHARED / "face" / "WDA_KatieHill_000.mp4", minutes + 0.2, out / "soak.mp4")
    rec = out / "record"
    cmd = [
        sys.executable,
        "-m",
        "facecapges",
        "live",
        "--video",
        str(video),
        "--audio",
        str(wav),
        "--realtime",
        "--record",
        str(rec),
        "--force",
        "--max-seconds",
        f"{minutes * 60.0:.3f}",
    ]
    if style:
        cmd += ["--style", style]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    rss: list[tuple[float, float]] = []
    status: list[tuple[float, int]] = []
    log: list[str] = []

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            log.append(line)
            m = re.match(r"frame (\d+) ", line.strip())
            if m:
                status.append((time.monotonic(), int(m.group(1))))

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    stopped_early = False
    while proc.poll() is None:
        if wall_limit_s is not None and time.monotonic() - t0 > wall_limit_s and not stopped_early:
            proc.send_signal(signal.SIGINT)  # live stops like Ctrl-C: it still writes motion.bvh and report.json
            stopped_early = True
        v = rss_mb(proc.pid)
        if np.isfinite(v):  # NaN once the process is gone
            rss.append((time.monotonic() - t0, v))
        time.sleep(1.0)
    reader.join(timeout=10)
    (out / "live.log").write_text("".join(log))
    if proc.returncode and not stopped_early:
        raise SystemExit(f"live failed ({proc.returncode}):\n" + "".join(log[-30:]))
    report = json.loads((rec / "report.json").read_text())
    b = read_bvh(rec / "motion.bvh")
    pose = motion_to_pose(b.skeleton, b.motion)[0]
    pauses = [(a, min(e, len(pose) / b.fps), k) for a, e, k in pauses if a < len(pose) / b.fps]  # a cut-short run
    skel, ref = his_reference()
    t_all = np.array([t for t, _ in rss])
    y_all = np.array([v for _, v in rss])
    # the session's memory while it makes frames: samples up to the last status line (after it, ``close`` builds the
    # face JSON and ends the BVH — 13-15 MB for a few seconds that a slope over the whole run would count)
    making = t_all <= (status[-1][0] - t0) if status else np.ones(len(t_all), bool)
    if not making.any():
        making[:] = True
    t_rss, y_rss = t_all[making], y_all[making]
    warm = y_rss[t_rss >= t_rss[-1] * 0.2] if len(y_rss) else y_rss
    drift = []
    if status:
        w0, f0 = status[0]
        drift = [((w - w0) - (f - f0) / FPS) * 1000.0 for w, f in status]
    lat = report.get("latency_ms", {}).get("total", {})
    fig = {
        "minutes": minutes,
        "frames": int(report.get("frames", 0)),
        "frames_expected": int(round(minutes * 60 * FPS)),
        "pauses": len(pauses),
        "pause_s": [round(b_ - a, 1) for a, b_, _ in pauses],
        **pop_figures(skel, pose, pauses, ref, b.fps, audio),
        "rss_mb_start": float(warm[0]) if len(warm) else float("nan"),
        "rss_mb_end": float(y_rss[-1]) if len(y_rss) else float("nan"),
        "rss_mb_max": float(np.nanmax(y_rss)) if len(y_rss) else float("nan"),
        "rss_mb_max_closing": float(np.nanmax(y_all[~making])) if (~making).any() else float("nan"),
        "rss_slope_mb_per_min": _slope_per_min(t_rss, y_rss),
        "late_frames": int(report.get("events", {}).get("late_frames", 0)),
        "events": report.get("events", {}),
        "compute_ms_p50": lat.get("p50"),
        "compute_ms_p99": lat.get("p99"),
        "drift_ms_first": drift[0] if drift else None,
        "drift_ms_last": drift[-1] if drift else None,
        "drift_ms_max": max(drift) if drift else None,
        "drift_slope_ms_per_min": _slope_per_min(
            np.array([w - status[0][0] for w, _ in status]), np.array(drift), skip=0.0
        )
        if len(drift) >= 3
        else None,
        "wall_s": round(time.monotonic() - t0, 1),
        "stopped_by": report.get("stopped_by"),
        "cut_short_at_wall_limit": stopped_early,
        "load_average_1min_at_end": os.getloadavg()[0],
    }
    (out / "soak.json").write_text(json.dumps(fig, indent=2))
    return fig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--out", type=Path, default=Path("build/soak"))
    ap.add_argument("--pause-range", type=float, nargs=2, default=(2.0, 30.0))
    ap.add_argument("--style", default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--wall-limit", type=float, default=None, help="stop live (as Ctrl-C) after this many seconds")
    a = ap.parse_args()
    fig = run_soak(a.minutes, a.out, tuple(a.pause_range), a.style, a.seed, a.wall_limit)
    print(json.dumps(fig))


if __name__ == "__main__":
    main()
