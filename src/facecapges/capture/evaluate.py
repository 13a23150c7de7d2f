"""``capture-eval``: the calibration-free estimator against MediaPipe's learned outputs.

On one video, at its native frame rate, from a cold start (no calibration):

* per ARKit channel the geometric estimator writes (:data:`estimator.GEOMETRIC_CHANNELS`):
  Pearson r and mean absolute error between ``geometric`` and MediaPipe's learned
  blendshapes, over the frames after the first ``skip_s`` seconds (2 s) with a face;
  r is NaN when either track is constant;
* head pose: geodesic angle between the (smoothed) landmark pose and the rotation of
  MediaPipe's facial transformation matrix, median and 90th percentile;
* timing: landmarks (MediaPipe) and the rest of the per-face work, ms per frame.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from facecapges.arkit import ARKIT_NAMES, N_BLENDSHAPES
from facecapges.capture.estimator import GEOMETRIC_CHANNELS
from facecapges.rotations import geodesic_angle

TARGETS = {"jawOpen": 0.8, "eyeBlinkLeft": 0.8, "eyeBlinkRight": 0.8}
HEAD_TARGET_DEG = 3.0


def pearson(a: np.ndarray, b: np.ndarray) -> float:
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if len(a) < 3 or a.std() < 1e-9 or b.std() < 1e-9:
        return float("nan")
    return float(np.corrcoef(a, b)[0, 1])


def run_tracks(video: str | Path, model=None, max_frames: int | None = None, progress: bool = False) -> dict:
    """Geometric weights, MediaPipe weights, head rotations, times for every frame of ``video``."""
    from facecapges.capture.pipeline import FaceCapture
    from facecapges.capture.video import open_source
    from facecapges.progress import Progress

    src = open_source(str(video))
    cap = FaceCapture(estimator="geometric", fps=src.fps, model=model)
    geo, mp, found, R_geo, R_mp, t_ms = [], [], [], [], [], []
    t_land = t_rest = 0.0
    try:
        with Progress(disable=not progress, transient=True) as bar:
            task = bar.add_task(f"capture-eval {Path(str(video)).name}", total=src.n_frames)
            for _, ts, frame in src.frames(max_frames):
                t0 = time.perf_counter()
                res = cap.process(frame, ts)
                t_all = time.perf_counter() - t0
                t_l = getattr(cap.detector, "last_ms", 0.0) / 1000.0
                t_land += t_l
                t_rest += t_all - t_l
                geo.append(res.weights52)
                mp.append(res.mp_blendshapes if res.mp_blendshapes is not None else np.zeros(N_BLENDSHAPES, np.float32))
                ok = res.face_found and res.mp_transform is not None
                found.append(ok)
                R_geo.append(res.head_R)
                R_mp.append(res.mp_transform[:3, :3] if ok and res.mp_transform is not None else np.eye(3))
                t_ms.append(ts)
                bar.advance(task)
    finally:
        cap.close()
        src.close()
    n = max(len(t_ms), 1)
    return {
        "fps": src.fps,
        "time_ms": np.array(t_ms),
        "geometric": np.array(geo),
        "mediapipe": np.array(mp),
        "found": np.array(found, bool),
        "R_geo": np.array(R_geo),
        "R_mp": np.array(R_mp),
        "landmarks_ms": 1000 * t_land / n,
        "per_face_ms": 1000 * t_rest / n,
    }


def evaluate_tracks(tr: dict, skip_s: float = 2.0) -> dict:
    """The figures of the module docstring from :func:`run_tracks`' output."""
    sel = tr["found"] & (tr["time_ms"] >= skip_s * 1000.0)
    channels = {}
    for name in GEOMETRIC_CHANNELS:
        j = ARKIT_NAMES.index(name)
        a, b = tr["geometric"][sel, j], tr["mediapipe"][sel, j]
        channels[name] = {"r": pearson(a, b), "mae": float(np.abs(a - b).mean()) if len(a) else float("nan")}
    found = tr["found"]
    ang = np.degrees(geodesic_angle(tr["R_geo"][found], tr["R_mp"][found])) if found.any() else np.array([np.nan])
    head = {"median_deg": float(np.median(ang)), "p90_deg": float(np.percentile(ang, 90))}
    targets = {n: {"r": channels[n]["r"], "target": t, "met": bool(channels[n]["r"] >= t)} for n, t in TARGETS.items()}
    targets["head_pose_median_deg"] = {
        "value": head["median_deg"],
        "target": HEAD_TARGET_DEG,
        "met": bool(head["median_deg"] <= HEAD_TARGET_DEG),
    }
    return {
        "frames": int(len(found)),
        "frames_with_face": int(found.sum()),
        "frames_evaluated": int(sel.sum()),
        "skip_s": skip_s,
        "fps": float(tr["fps"]),
        "channels": channels,
        "head_pose": head,
        "targets": targets,
        "landmarks_ms_per_frame": tr["landmarks_ms"],
        "per_face_ms_per_frame": tr["per_face_ms"],
    }


def plot_tracks(tr: dict, path: str | Path, skip_s: float = 2.0) -> None:
    """PNG of jawOpen and eyeBlinkLeft/Right, geometric vs MediaPipe."""
    from facecapges.io.plots import pyplot

    plt = pyplot()

    t = tr["time_ms"] / 1000.0
    fig, axes = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    for ax, name in zip(axes, ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight")):
        j = ARKIT_NAMES.index(name)
        ax.plot(t, tr["mediapipe"][:, j], label="MediaPipe (learned)", lw=1.2)
        ax.plot(t, tr["geometric"][:, j], label="geometric (calibration-free)", lw=1.2)
        ax.axvspan(0, skip_s, color="0.9", zorder=0)
        ax.set_ylabel(name)
        ax.set_ylim(-0.05, 1.05)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("time (s); grey: first seconds, not scored")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_report(report: dict, out_dir: str | Path) -> Path:
    p = Path(out_dir) / "capture_eval.json"
    p.write_text(json.dumps(report, indent=2, allow_nan=True))
    return p
