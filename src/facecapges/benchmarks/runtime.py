"""Runtime benchmark (``facecapges bench --only runtime``): the targets of the runtime issue.

* ``per_frame`` — compute per frame from input frame to pose + blendshapes, MediaPipe
  capture included (the scheduler's ``total`` stage: capture → features → model →
  output), over the shared HDTF clip (8 s, 25 fps) run offline; p50 / p99 per stage.
  Targets: p50 ≤ 30 ms, p99 ≤ 50 ms.
* ``run_60s`` — ``facecapges run`` on a talking-head video (the 8 s clip looped with
  ffmpeg: 10 s in the full bench, 2 s quick, so the whole bench stays within minutes),
  both MP4s included; ``wall_s_per_60s_input`` scales it to the target's 60 s of input
  (target ≤ 180 s per 60 s).
* ``session`` — a simulated live session: the clip and its audio looped as a file
  source, realtime pacing off (60 s of stream time in the full bench, 10 s quick;
  ``run(..., session_s=3600)`` is the 1 h soak; the figure reports what ran). Memory: resident set size sampled every
  150 frames; ``rss_change_pct`` = (last − first sample after warm-up) / first, and the
  max deviation, target within ±5 %. Drift: every output frame is compared with the
  training data (the shared BEAT clip the default style is trained on): a frame is
  *inside* when every joint's rotation is within the training data's largest
  geodesic distance of that joint from its training mean (+5°); the mean distance to
  the training mean per tenth of the session shows whether it creeps away.

* ``vmc_output`` — the VMC sender's cost per frame (OSC messages, bundles ≤ 1200 B,
  ``sendto`` on loopback) for each ``--vmc-blend`` mode, with datagrams per frame and the
  largest one.

* ``vmc_rate`` — the VMC stream's delivered rate at ``--rate 30`` and ``60`` with the other
  core kept busy by a spinning process: a loopback receiver timestamps each frame's last
  datagram; the median over 0.5 s windows and the overall rate, with model frames arriving
  with ±20 ms jitter (the upsampler sends on its own clock). Target: within 2 % of the rate.

Figures measured so far, with their loads: docs/performance.md.
"""

from __future__ import annotations

import math
import os
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from facecapges.arkit import N_BLENDSHAPES

CLIP = "data/face/WDA_KatieHill_000.mp4"
TRAIN_BVH = "data/beat/2_scott_0_1_1.bvh"


def shared_file(shared: Path, rel: str) -> Path:
    """``rel`` in the shared folder the command passes; a clear error if it is missing."""
    from facecapges.errors import UserError

    p = Path(shared) / rel
    if not p.is_file():
        raise UserError(f"{p}: the runtime benchmark needs this shared file")
    return p


def rss_mb(pid: int | None = None, key: str = "VmRSS") -> float:
    """Resident memory (MB) of this process, or of process ``pid`` (``key``: ``VmRSS`` now, ``VmHWM`` its peak);
    NaN when it is gone."""
    try:
        with open(f"/proc/{pid if pid is not None else 'self'}/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")


def stat_cpu(path: str | Path) -> tuple[list[str], float]:
    """A Linux ``/proc/…/stat`` file (a process's or a thread's): its fields after the command name, and its
    user + system CPU seconds."""
    fields = Path(path).read_text().rsplit(")", 1)[1].split()
    return fields, (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _checkpoint():
    from facecapges.styles import load_style

    return load_style(os.environ.get("FACECAPGES_BENCH_CHECKPOINT") or None)


def per_frame(ckpt, video: Path, max_frames: int | None = None) -> dict:
    from facecapges.runtime.session import build_session

    sess = build_session(ckpt, video=video)
    try:
        sess.scheduler.run(max_frames=max_frames)
        rep = sess.scheduler.report(warmup=10)
    finally:
        sess.close()
    lat = rep["latency_ms"]
    return {
        "frames": rep["frames"],
        "latency_ms": lat,
        "target_ms": {"p50": 30, "p99": 50},
        "meets_target": lat["total"]["p50"] <= 30 and lat["total"]["p99"] <= 50,
        "events": rep["events"],
    }


def ffmpeg(*args: str) -> None:
    """Run the ffmpeg of ``imageio-ffmpeg`` with ``args``, overwriting its output, printing only errors."""
    import imageio_ffmpeg

    subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-loglevel", "error", *args], check=True)


def looped_video(src: Path, seconds: float, out: Path, fps: float | None = None) -> Path:
    """``src`` looped to ``seconds`` (H.264 + AAC), resampled to ``fps`` when given."""
    ffmpeg(
        "-stream_loop",
        "-1",
        "-i",
        str(src),
        "-t",
        f"{seconds:g}",
        *(["-vf", f"fps={fps:g}"] if fps else []),
        "-c:v",
        "libx264",
        "-preset",
        "veryfast",
        "-crf",
        "18",
        "-c:a",
        "aac",
        str(out),
    )
    return out


def run_60s(ckpt, clip: Path, seconds: float = 60.0) -> dict:
    from facecapges.runtime.run import run_video

    with tempfile.TemporaryDirectory(prefix="facecapges-bench-") as tmp:
        video = looped_video(clip, seconds, Path(tmp) / "talk.mp4")
        t0 = time.perf_counter()
        rep = run_video(video, Path(tmp) / "out", ckpt, progress=False)
        wall = time.perf_counter() - t0
    return {
        "input_seconds": seconds,
        "frames": rep["frames"],
        "wall_s": round(wall, 2),
        "phases_s": rep["seconds"],
        "wall_s_per_60s_input": round(wall * 60.0 / seconds, 1),
        "latency_ms_total": rep["latency_ms"]["total"],
        "target_s": 180 * seconds / 60.0,
        "meets_target": wall <= 180 * seconds / 60.0,
    }


class PoseRange:
    """Per-joint geodesic distance from the training mean rotation (module docstring)."""

    def __init__(self, bvh_path: Path):
        from facecapges import rotations as rot
        from facecapges.io.bvh import read_bvh
        from facecapges.skeleton import motion_to_pose

        b = read_bvh(bvh_path)
        pose, _ = motion_to_pose(b.skeleton, b.motion)
        R = rot.rot6d_to_matrix(pose.astype(np.float64))  # (T, 47, 3, 3)
        self.mean = rot.rot6d_to_matrix(pose.astype(np.float64).mean(0))  # chordal-ish mean, re-orthonormalised
        d = rot.geodesic_angle(self.mean[None], R)  # (T, 47)
        self.max_deg = np.degrees(d.max(0))

    def distances_deg(self, poses: np.ndarray) -> np.ndarray:
        from facecapges import rotations as rot

        R = rot.rot6d_to_matrix(np.asarray(poses, np.float64))
        return np.degrees(rot.geodesic_angle(self.mean[None], R))


def session(ckpt, video: Path, train_bvh: Path, seconds: float) -> dict:
    from facecapges.runtime.inputs.sources import FileVideo
    from facecapges.runtime.session import build_session

    rng = PoseRange(train_bvh)
    sess = build_session(ckpt, video=video, loop=True)
    sched = sess.scheduler
    n = int(round(seconds * ckpt.fps))
    rss: list[float] = []
    dist_sum: list[float] = []
    dist_n: list[int] = []
    inside, seg = 0, max(n // 10, 1)
    worst = -math.inf

    class Probe:
        def write(self, out):
            nonlocal inside, worst
            d = rng.distances_deg(out.pose[None])[0]
            inside_now = bool(np.all(d <= rng.max_deg + 5.0))
            inside += inside_now
            worst = max(worst, float((d - rng.max_deg).max()))
            s = out.index // seg
            while len(dist_sum) <= s:
                dist_sum.append(0.0)
                dist_n.append(0)
            dist_sum[s] += float(d.mean())
            dist_n[s] += 1
            if out.index % 150 == 0:
                rss.append(rss_mb())

        def close(self):
            pass

    sched.sinks.append(Probe())
    t0 = time.perf_counter()
    video = sess.video
    assert isinstance(video, FileVideo)  # the session plays the clip as a camera
    try:
        sched.run(max_frames=n)
        rep = sched.report(warmup=10)
    finally:
        sess.close()
    wall = time.perf_counter() - t0
    warm = rss[max(1, len(rss) // 10) :] or rss
    base = warm[0]
    seg_mean = [round(s / max(c, 1), 3) for s, c in zip(dist_sum, dist_n)]
    return {
        "stream_seconds": round(rep["frames"] / ckpt.fps, 1),
        "frames": rep["frames"],
        "wall_s": round(wall, 1),
        "loops_of_clip": video.loops,
        "rss_mb": {
            "first_after_warmup": round(base, 1),
            "last": round(warm[-1], 1),
            "min": round(min(warm), 1),
            "max": round(max(warm), 1),
            "samples": len(rss),
        },
        "rss_change_pct": round(100 * (warm[-1] - base) / base, 2),
        "rss_max_deviation_pct": round(100 * max(abs(x - base) for x in warm) / base, 2),
        "memory_flat": all(abs(x - base) <= 0.05 * base for x in warm),
        "pose_inside_training_range_pct": round(100 * inside / max(rep["frames"], 1), 2),
        "worst_excess_over_training_range_deg": round(worst, 2),
        "mean_distance_to_training_mean_deg_per_tenth": seg_mean,
        "latency_ms_total": rep["latency_ms"]["total"],
        "events": rep["events"],
    }


def vmc_output(ckpt, train_bvh: Path, frames: int = 300) -> dict:
    """VMC sending cost per frame (messages, bundles, sendto on loopback) per ``--vmc-blend`` mode, and sizes.

    Real poses of the training clip, real faces (a talking-face-like sweep). At ``--rate 60``
    this runs 60 times a second, so ``p50_ms × 60 / 1000`` is the share of one core it takes.
    """
    import socket

    from facecapges import rotations as rot
    from facecapges.io.bvh import read_bvh
    from facecapges.runtime.frames import OutputFrame
    from facecapges.runtime.outputs.vmc import BLEND_MODES, VmcSender
    from facecapges.skeleton import motion_to_pose

    bvh = read_bvh(train_bvh)
    pose = motion_to_pose(bvh.skeleton, bvh.motion[:frames])[0]
    quats = rot.rot6d_to_quaternion(pose.astype(np.float64))
    rng = np.random.default_rng(0)
    faces = np.clip(0.3 + 0.3 * np.sin(np.arange(len(pose))[:, None] / 5.0 + rng.uniform(0, 6, N_BLENDSHAPES)), 0, 1)
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    out = {}
    try:
        for blend in BLEND_MODES:
            host, port = rx.getsockname()
            sender = VmcSender(bvh.skeleton, host, port, blend=blend)
            ms = []
            for k in range(len(pose)):
                fr = OutputFrame(k, k / 15, pose[k], quats[k], faces[k], rot.identity_rot6d(), True, {})
                t = time.perf_counter()
                sender.write(fr)
                ms.append((time.perf_counter() - t) * 1000.0)
                while True:  # drain, so the socket buffer never fills
                    rx.setblocking(False)
                    try:
                        rx.recv(65535)
                    except BlockingIOError:
                        break
            sender.close()
            st = sender.stats()
            out[blend] = {
                "p50_ms": round(float(np.median(ms)), 3),
                "p99_ms": round(float(np.percentile(ms, 99)), 3),
                "datagrams_per_frame": round(st["datagrams"] / max(st["frames"], 1), 2),
                "largest_datagram_bytes": st["largest_datagram_bytes"],
            }
    finally:
        rx.close()
    return out


def _delivered(stamps: list[float]) -> dict:
    """Frames a second from arrival times: the median over 0.5 s windows and overall (after 0.25 s of start-up)."""
    t = np.asarray(stamps)
    t = t[t > t[0] + 0.25] if len(t) else t
    edges = np.arange(t[0], t[-1], 0.5) if len(t) > 2 else np.array([])
    windows = [np.sum((t >= a) & (t < a + 0.5)) / 0.5 for a in edges[:-1]]
    return {
        "delivered_hz_median": round(float(np.median(windows)), 2) if windows else 0.0,
        "delivered_hz_overall": round(float((len(t) - 1) / (t[-1] - t[0])), 2) if len(t) > 2 else 0.0,
    }


_BUSY = "import time\nend = time.monotonic() + {s}\nwhile time.monotonic() < end:\n    pass\n"


def vmc_rate(skeleton, rate_hz: float, seconds: float = 3.0, busy: bool = True) -> dict:
    """Delivered VMC frames a second at ``rate_hz`` on a loopback receiver, one core busy (module docstring)."""
    import socket
    import sys
    import threading

    from facecapges import rotations as rot
    from facecapges.runtime.frames import OutputFrame
    from facecapges.runtime.outputs.upsample import Upsampler
    from facecapges.runtime.outputs.vmc import VmcSender

    spin = subprocess.Popen([sys.executable, "-c", _BUSY.format(s=seconds + 10)]) if busy else None
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.2)
    stamps: list[float] = []
    done = threading.Event()

    def receive() -> None:
        while not done.is_set():
            try:
                d = rx.recv(65535)
            except OSError:
                continue
            if b"/VMC/Ext/T" in d:
                stamps.append(time.monotonic())

    th = threading.Thread(target=receive, daemon=True)
    th.start()
    up = Upsampler([VmcSender(skeleton, *rx.getsockname())], 15, rate_hz)
    rng = np.random.default_rng(0)
    try:
        t0 = time.monotonic()
        for k in range(int(seconds * 15)):
            time.sleep(max(0.0, t0 + k / 15 + rng.uniform(-0.02, 0.02) - time.monotonic()))
            q = rot.matrix_to_quaternion(rot.axis_angle_matrix("Z", np.full(47, np.sin(k / 7.0))))
            up.write(
                OutputFrame(
                    k,
                    k / 15,
                    rot.matrix_to_rot6d(rot.quaternion_to_matrix(q)),
                    q,
                    np.zeros(N_BLENDSHAPES),
                    rot.identity_rot6d(),
                    True,
                    {},
                )
            )
    finally:
        up.close()
        done.set()
        th.join(2)
        rx.close()
        if spin is not None:
            spin.kill()
            spin.wait()
    return {
        "rate_hz": rate_hz,
        **_delivered(stamps),
        "late_ticks": up.late,
        "resyncs": up.resyncs,
        "other_core_busy": busy,
    }


def run(quick: bool, shared: Path, session_s: float | None = None) -> dict:
    """Quick: 30 frames, ``run`` on 2 s, a 10 s session, 1.5 s of each VMC rate; full: the whole 8 s clip, ``run`` on
    10 s (its wall time per 60 s of input reported beside), a 60 s session. ``session_s``
    sets the session length (e.g. 3600 for the 1 h soak of the runtime issue)."""
    ckpt = _checkpoint()
    clip, train = shared_file(shared, CLIP), shared_file(shared, TRAIN_BVH)
    out: dict[str, object] = {"checkpoint": str(ckpt.path)}
    out["vmc_output"] = vmc_output(ckpt, train, 60 if quick else 300)
    out["vmc_rate"] = {f"{r}hz": vmc_rate(ckpt.skeleton, r, 1.5 if quick else 5.0) for r in (30, 60)}
    out["per_frame"] = per_frame(ckpt, clip, max_frames=30 if quick else None)
    out["run_60s"] = run_60s(ckpt, clip, 2.0 if quick else 10.0)
    out["session"] = session(ckpt, clip, train, session_s or (10.0 if quick else 60.0))
    return out
