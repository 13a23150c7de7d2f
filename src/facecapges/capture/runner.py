"""Whole-video capture: a source → BEAT-format face JSON (+ overlay video).

Face JSON written by :func:`facecapges.io.face_json.write_face_json` (BEAT's layout by
default: 51 names at 60 fps; ``face_layout="full"``: 52 names at ``fps``), each frame
with the extensions ``head_rot6d``, ``face_found`` and ``distance_m``::

    {"names": [...], "fps": 60,
     "frames": [{"time": t_s, "weights": [...], "head_rot6d": [6 floats],
                 "face_found": bool, "distance_m": float}, ...]}

Capture frame ``k`` is the result at ``k / fps``. Every source frame is processed
(MediaPipe's tracker and the sample set see the full frame rate), and output frame
``k`` is the result of the first source frame at or after ``k / fps``; a source slower
than ``fps`` repeats results. (Decimating before the landmark model would be
cheaper for fast sources but gives MediaPipe's tracker larger jumps between frames.)
``distance_m`` is ``null`` while no face has been seen yet. ``head_rot6d`` follows :mod:`head_pose` (identity = facing the camera).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from facecapges.errors import UserError, refuse_overwrite


def result_record(res, time_s: float) -> dict:
    d = float(res.distance_m)
    return {
        "time": round(float(time_s), 6),
        "weights": np.asarray(res.weights52, np.float64),
        "head_rot6d": np.asarray(res.head_rot6d, np.float64),
        "face_found": bool(res.face_found),
        "distance_m": None if not math.isfinite(d) else round(d, 4),
    }


def capture_video(source: str, out: str | Path, estimator: str = "hybrid", fps: float = 15.0,
                  overlay: str | Path | None = None, depth_dir=None, intrinsics=None, model=None,
                  force: bool = False, max_frames: int | None = None, progress: bool = True,
                  face_layout: str = "beat") -> dict:
    """Run the capture over ``source`` and write ``out`` (face JSON); returns a summary dict."""
    from facecapges.capture.video import open_source

    if not (0 < fps <= 120):
        raise UserError(f"--fps must be in (0, 120], got {fps}")
    out = refuse_overwrite(out, force)
    if overlay is not None:
        refuse_overwrite(overlay, force)
    depth_files, K = (None, None)
    if depth_dir is not None or intrinsics is not None:
        from facecapges.capture.depth import check_depth_inputs

        depth_files, K = check_depth_inputs(depth_dir, intrinsics)
    from facecapges.capture.models import resolve_model
    from facecapges.capture.pipeline import FaceCapture

    model = resolve_model(model)  # a missing model fails before any video is opened
    src = open_source(source)

    try:
        cap = FaceCapture(estimator=estimator, fps=src.fps, model=model, intrinsics=K)
    except BaseException:
        src.close()
        raise
    if depth_files is not None:
        from facecapges.capture.depth import DepthHeadTracker

        cap.depth_tracker = DepthHeadTracker(cap.mesh.vertices / 100.0, K)
    writer = None
    records: list[dict] = []
    n_found = 0
    try:
        if overlay is not None:
            from facecapges.capture.overlay import OverlayWriter

            writer = OverlayWriter(overlay, src.width, src.height, fps)
        total = None
        if src.n_frames:
            total = int(math.floor((src.n_frames - 1) / src.fps * fps)) + 1
            if max_frames:
                total = min(total, max_frames)
        from rich.progress import Progress

        with Progress(disable=not progress, transient=True) as bar:
            task = bar.add_task(f"capture {Path(str(source)).name}", total=total)
            k = 0
            for i, ts, frame in src.frames():
                if max_frames is not None and k >= max_frames:
                    break
                depth = None
                if depth_files is not None:
                    from facecapges.capture.depth import read_depth

                    if i < len(depth_files):
                        depth = read_depth(depth_files[i])
                res = cap.process(frame, ts, depth)
                # a slow source (fps below --fps) repeats the frame on the skipped ticks
                while (k * 1000.0 / fps) <= ts + 1e-6 and (max_frames is None or k < max_frames):
                    n_found += bool(res.face_found)
                    records.append(result_record(res, k / fps))
                    if writer is not None:
                        from facecapges.capture.overlay import draw_overlay

                        writer.write(draw_overlay(frame, res))
                    k += 1
                    bar.advance(task)
    finally:
        cap.close()
        src.close()
        if writer is not None:
            writer.close()
    if not records:
        raise UserError(f"{source}: no frames could be read")
    from facecapges.io.face_json import write_face_json

    write_face_json(out, np.stack([r["weights"] for r in records]), fps, np.stack([r["head_rot6d"] for r in records]),
                    layout=face_layout, extras={k: [r[k] for r in records] for k in ("face_found", "distance_m")})
    return {"frames": len(records), "face_found": n_found, "fps": fps, "out": str(out)}
