"""Whole-video capture: a source → BEAT-format face JSON (+ overlay video).

Face JSON written (read back by ``facecapges.io.face_json``)::

    {"names": [52 ARKIT_NAMES], "fps": 15,
     "frames": [{"time": t_s, "weights": [52 floats], "head_rot6d": [6 floats],
                 "face_found": bool, "distance_m": float}, ...]}

``time`` is ``k / fps`` for output frame ``k``. Every source frame is processed
(MediaPipe's tracker and the sample set see the full frame rate), and output frame
``k`` is the result of the first source frame at or after ``k / fps``; a source slower
than ``fps`` repeats results. (Decimating before the landmark model would be
cheaper for fast sources but gives MediaPipe's tracker larger jumps between frames.)
``distance_m`` is ``null`` while no face has been seen yet. ``head_rot6d`` follows :mod:`head_pose` (identity = facing the camera).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from facecapges.arkit import ARKIT_NAMES
from facecapges.errors import UserError, check_output_file


def face_json_document(records: list[dict], fps: float) -> dict:
    return {"names": list(ARKIT_NAMES), "fps": fps, "frames": records}


def result_record(res, time_s: float) -> dict:
    d = float(res.distance_m)
    return {
        "time": round(float(time_s), 6),
        "weights": [round(float(x), 5) for x in res.weights52],
        "head_rot6d": [round(float(x), 6) for x in res.head_rot6d],
        "face_found": bool(res.face_found),
        "distance_m": None if not math.isfinite(d) else round(d, 4),
    }


def capture_video(source: str, out: str | Path, estimator: str = "hybrid", fps: float = 15.0,
                  overlay: str | Path | None = None, depth_dir=None, intrinsics=None, model=None,
                  force: bool = False, max_frames: int | None = None, progress: bool = True) -> dict:
    """Run the capture over ``source`` and write ``out`` (face JSON); returns a summary dict."""
    from facecapges.capture.video import open_source

    if not (0 < fps <= 120):
        raise UserError(f"--fps must be in (0, 120], got {fps}")
    out = check_output_file(out, force)
    if overlay is not None:
        check_output_file(overlay, force)
    depth_files, K = (None, None)
    if depth_dir is not None or intrinsics is not None:
        from facecapges.capture.depth import check_depth_inputs

        depth_files, K = check_depth_inputs(depth_dir, intrinsics)
    from facecapges.capture.models import resolve_model
    from facecapges.capture.pipeline import FaceCapture

    model = resolve_model(model)  # a missing model fails before any video is opened
    src = open_source(source)

    try:
        cap = FaceCapture(estimator=estimator, fps=src.fps, model=model, intrinsics=K, num_faces=2)
    except BaseException:
        src.close()
        raise
    if depth_files is not None:
        from facecapges.capture.depth import DepthHeadTracker

        cap.depth_tracker = DepthHeadTracker(cap.mesh.vertices / 100.0, K)
    writer = None
    records: list[dict] = []
    n_found = 0
    n_several = 0  # input frames with more than one face in view
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
                n_several += getattr(cap, "faces_in_view", 1) > 1
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
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(face_json_document(records, fps)))
    warnings = []
    if src.bad_frames:
        warnings.append(f"{src.bad_frames} frame(s) of the video could not be decoded (damaged stretch); the last "
                        "good frame was held over them, so timing stays right")
    if src.missing_tail > max(2, (src.n_frames or 0) // 100):  # containers often over-count by a frame
        warnings.append(f"the last {src.missing_tail} of {src.n_frames} frames the video declares could not be "
                        "decoded (file cut short or damaged at its end)")
    if n_found == 0:
        warnings.append("no face was found in any frame: the output holds a neutral face and a resting head")
    if n_several:
        warnings.append(f"more than one face was in view in {n_several} frame(s); the largest face was tracked")
    return {"frames": len(records), "face_found": n_found, "fps": fps, "out": str(out), "warnings": warnings,
            "bad_frames": src.bad_frames, "missing_frames": src.missing_tail}
