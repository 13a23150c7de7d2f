"""``facecapges bench --only capture``: speed and quality figures of the face capture.

* ``estimator_ms_per_face``: sample set → ranges → 52 weights, per face per frame
  (mean, median, p95; target ≤ 0.5 ms); ``metrics_ms_per_face``: head-frame points →
  the 13 metrics; ``head_pose_ms_per_face``: landmarks → pose (two fits). The machine
  is shared: figures move with its load, so the median is given beside the mean;
* ``capture_ms_per_frame``: the whole :meth:`FaceCapture.process` on real video frames
  (colour conversion, MediaPipe landmarks, tracking, pose, estimator; target ≤ 25 ms),
  with ``landmarks_ms_per_frame`` the MediaPipe part; video decoding is not counted;
* quality: ``capture-eval`` on the HDTF clip (r of jawOpen / eyeBlink, head-pose
  median error; quick: first 100 frames only) and the synthetic-sequence MAE.
* ``capture_body``: ``capture-body``'s cost at 640×480 (the clip's frames resized): both
  landmarkers (pose + two hands) per frame, and the solve per frame; ``fps`` against the
  target 15 (issue 32). The clip is a face close-up, so the body is mostly re-detected.

Memory against video length is measured apart (it takes ~40 s per minute of video):
``scripts/capture_memory.py --minutes 1 10 30`` loops the HDTF clip's frames into
longer videos and reports ``capture``'s peak RSS. 2026-12-01 (issue 28, this 2-core
machine, shared): 431 / 454 / 470 MB at 1 / 10 / 30 min of 25 fps video (the in-loop
RSS 430 → 447 MB over 30 min, steps where the result arrays double). Before
(per-frame dicts, the face JSON built whole in memory) it grew ~16 MB a minute.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

FACE_CLIP = "data/face/WDA_KatieHill_000.mp4"


def run(quick: bool, shared: Path) -> dict:
    from facecapges.capture.canonical_mesh import load_canonical_mesh
    from facecapges.capture.estimator import ExpressionEstimator
    from facecapges.capture.head_pose import HeadPoseEstimator
    from facecapges.capture.metrics import compute_metrics
    from facecapges.capture.models import resolve_model
    from facecapges.capture.samples import sample_weight
    from facecapges.capture.synthetic import run_geometric, synthetic_mae, synthetic_sequence

    shared_face = Path(shared) / FACE_CLIP
    model = resolve_model()
    mesh = load_canonical_mesh(model)
    pe = HeadPoseEstimator(mesh.vertices, mesh.procrustes_ids, mesh.procrustes_weights)
    out: dict = {}

    # ---- per-face costs on a synthetic sequence (no video needed)
    seq = synthetic_sequence(mesh.vertices, 150 if quick else 600, seed=1)
    poses, G, om = [], [], []
    t0 = time.perf_counter()
    for L in seq["landmarks"]:
        pose, pts = pe.estimate(L, seq["width"], seq["height"])
        poses.append((pose, pts))
    t_pose = (time.perf_counter() - t0) / len(poses)
    t0 = time.perf_counter()
    for pose, pts in poses:
        G.append(compute_metrics(pe.to_head_frame(pts, pose)))
        om.append(sample_weight(pose.distance_m, pose.normal))
    t_metrics = (time.perf_counter() - t0) / len(poses)
    est = ExpressionEstimator("geometric")
    t_each = []
    for g, w in zip(G, om):
        t0 = time.perf_counter()
        est.update(g, w)
        est.weights()
        t_each.append(time.perf_counter() - t0)
    t_est = float(np.mean(t_each))
    out["estimator_ms_per_face_median"] = round(1000 * float(np.median(t_each)), 3)
    out["estimator_ms_per_face_p95"] = round(1000 * float(np.percentile(t_each, 95)), 3)
    out["head_pose_ms_per_face"] = round(1000 * t_pose, 3)
    out["metrics_ms_per_face"] = round(1000 * t_metrics, 3)
    out["estimator_ms_per_face"] = round(1000 * t_est, 3)
    out["estimator_target_ms"] = 0.5
    out["per_face_total_ms"] = round(1000 * (t_pose + t_metrics + t_est), 3)

    maes = [
        synthetic_mae(s, run_geometric(s, pe), 30)
        for s in [synthetic_sequence(mesh.vertices, 300 if quick else 450, seed=k) for k in range(1 if quick else 4)]
    ]
    out["synthetic_mae_mean"] = round(float(np.mean([m["mean"] for m in maes])), 4)
    out["synthetic_mae_per_channel"] = {
        k: round(float(np.mean([m[k] for m in maes])), 4) for k in maes[0] if k != "mean"
    }
    out["synthetic_mae_target"] = 0.1

    # ---- real video
    if shared_face.exists():
        from facecapges.capture.evaluate import evaluate_tracks, run_tracks
        from facecapges.capture.pipeline import FaceCapture
        from facecapges.capture.video import open_source

        src = open_source(str(shared_face))
        frames = [f for _, _, f in src.frames(60 if quick else 200)]
        src.close()
        with FaceCapture(estimator="hybrid", fps=src.fps, model=model) as cap:
            cap.process(frames[0], 0)  # warm-up (model start)
            t_all = t_land = 0.0
            for i, f in enumerate(frames[1:], 1):
                t0 = time.perf_counter()
                cap.process(f, i * 1000.0 / src.fps)
                t_all += time.perf_counter() - t0
                t_land += cap.detector.last_ms / 1000.0
        n = len(frames) - 1
        out["capture_ms_per_frame"] = round(1000 * t_all / n, 2)
        out["landmarks_ms_per_frame"] = round(1000 * t_land / n, 2)
        out["capture_target_ms"] = 25.0
        rep = evaluate_tracks(run_tracks(shared_face, model=model, max_frames=100 if quick else None))
        out["hdtf_frames_evaluated"] = rep["frames_evaluated"]
        for name in ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight"):
            out[f"hdtf_r_{name}"] = round(rep["channels"][name]["r"], 3)
            out[f"hdtf_mae_{name}"] = round(rep["channels"][name]["mae"], 3)
        out["hdtf_head_pose_median_deg"] = round(rep["head_pose"]["median_deg"], 2)
    else:
        from facecapges.errors import UserError

        raise UserError(f"{shared_face}: the capture benchmark needs the shared talking-head clip")
    out["capture_body"] = _capture_body(shared_face, 10 if quick else 60)
    return out


def _capture_body(clip: Path, n: int) -> dict:
    """Pose + hand landmarkers and the solve at 640×480 (median ms per frame)."""
    import cv2

    from facecapges.capture.body import BodyLandmarker, assign_hands
    from facecapges.capture.body_models import HAND_TASK, POSE_TASK, model_path
    from facecapges.capture.body_solve import BodyLandmarks, solve
    from facecapges.capture.video import open_source
    from facecapges.errors import UserError

    try:
        model_path(POSE_TASK), model_path(HAND_TASK)
    except UserError as exc:  # models not built: say so, the other figures stand
        return {"error": str(exc)}
    src = open_source(str(clip))
    frames = [cv2.resize(f, (640, 480)) for _, _, f in src.frames(n + 1)]
    src.close()
    times, poses = [], []
    with BodyLandmarker() as lm:
        lm.detect(frames[0], 0)  # warm-up
        for i, f in enumerate(frames[1:], 1):
            t0 = time.perf_counter()
            det = lm.detect(f, int(i * 1000 / 15))
            times.append(time.perf_counter() - t0)
            assign_hands(det)
            poses.append(det["pose"] if det["pose"] is not None else np.zeros((33, 3)))
    from facecapges.styles import DEFAULT_STYLE, load_style

    skel = load_style(style=DEFAULT_STYLE).skeleton
    m = len(poses)
    lms = BodyLandmarks(np.stack(poses), np.ones((m, 33)), np.full((m, 2, 21, 3), np.nan), np.zeros((m, 2)), 15.0)
    t0 = time.perf_counter()
    solve(skel, lms)
    solve_ms = 1000 * (time.perf_counter() - t0) / m
    ms = 1000 * float(np.median(times))
    return {
        "landmarks_ms_per_frame": round(ms, 1),
        "solve_ms_per_frame": round(solve_ms, 2),
        "fps": round(1000 / (ms + solve_ms), 2),
        "target_fps": 15.0,
        "frames": m,
        "size": "640x480",
    }
