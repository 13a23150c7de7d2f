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

Several faces (``faces=N``, ``capture --faces N``): one face JSON per face,
``NAME_1.json`` … ``NAME_N.json`` beside ``--out NAME.json``; face ``i`` is the ``i``-th
from the left as the faces first appear, and keeps that number when it leaves and
comes back (:meth:`FaceCapture.process_slots`: identity by position). A face not in
view (yet) is written as not found, neutral.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from facecapges.errors import UserError, check_output_file
from facecapges.timing import MODEL_FPS


def result_record(res, time_s: float) -> dict:
    d = float(res.distance_m)
    return {
        "time": round(float(time_s), 6),
        "weights": np.asarray(res.weights52, np.float64),
        "head_rot6d": np.asarray(res.head_rot6d, np.float64),
        "face_found": bool(res.face_found),
        "distance_m": None if not math.isfinite(d) else round(d, 4),
    }


class Records:
    """One face's per-frame results, kept compactly: float64 arrays grown by doubling (~0.5 kB a frame,
    where a dict per frame took several) — with the streaming face JSON writer, ``capture`` memory
    stays flat in the video's length."""

    def __init__(self) -> None:
        self.n = 0
        self.weights = np.zeros((1024, 52))
        self.head = np.zeros((1024, 6))
        self.found = np.zeros(1024, bool)
        self.distance = np.zeros(1024)

    def append(self, res) -> None:
        if self.n == len(self.found):
            for k in ("weights", "head", "found", "distance"):
                a = getattr(self, k)
                setattr(self, k, np.concatenate([a, np.zeros_like(a)]))
        r = result_record(res, 0.0)
        self.weights[self.n], self.head[self.n], self.found[self.n] = r["weights"], r["head_rot6d"], r["face_found"]
        self.distance[self.n] = np.nan if r["distance_m"] is None else r["distance_m"]
        self.n += 1

    def __len__(self) -> int:
        return self.n

    def write(self, path: Path, fps: float, layout: str) -> None:
        from facecapges.io.face_json import write_face_json

        n = self.n
        extras: dict[str, list] = {
            "face_found": [bool(x) for x in self.found[:n]],
            "distance_m": [None if not math.isfinite(d) else float(d) for d in self.distance[:n]],
        }
        write_face_json(path, self.weights[:n], fps, self.head[:n], layout=layout, extras=extras)


def capture_video(
    source: str,
    out: str | Path,
    estimator: str = "hybrid",
    fps: float = float(MODEL_FPS),
    overlay: str | Path | None = None,
    depth_dir=None,
    intrinsics=None,
    model=None,
    force: bool = False,
    max_frames: int | None = None,
    progress: bool = True,
    faces: int = 1,
    face_layout: str = "beat",
) -> dict:
    """Run the capture over ``source`` and write ``out`` (face JSON; one per face, module docstring);
    returns a summary dict."""
    out = Path(out)
    outs, depth_files, K = _check_inputs(source, out, fps, faces, overlay, depth_dir, intrinsics, force)
    src, cap = _open_capture(source, estimator, model, K, faces, depth_files is not None)
    writer = None
    records = [Records() for _ in outs]
    n_found = [0] * len(outs)
    try:
        if overlay is not None:
            from facecapges.capture.overlay import OverlayWriter

            writer = OverlayWriter(overlay, src.width, src.height, fps)
        n_several = _run_frames(
            src, cap, writer, records, n_found, source, fps, faces, max_frames, depth_files, progress
        )
    finally:
        cap.close()
        src.close()
        if writer is not None:
            writer.close()
    if not len(records[0]):
        raise UserError(f"{source}: no frames could be read")
    for p, rec in zip(outs, records):
        rec.write(p, fps, face_layout)
    warnings = _warnings(src, n_found, n_several)
    common = {
        "frames": len(records[0]),
        "fps": fps,
        "warnings": warnings,
        "bad_frames": src.bad_frames,
        "missing_frames": src.missing_tail,
    }
    if faces == 1:
        return {**common, "face_found": n_found[0], "out": str(out)}
    return {**common, "face_found": n_found, "out": ", ".join(map(str, outs)), "outs": [str(p) for p in outs]}


def _open_capture(source: str, estimator: str, model, K, faces: int, depth: bool):
    """The landmark model (a missing one fails before any video is opened), the source and the capture."""
    from facecapges.capture.models import resolve_model
    from facecapges.capture.pipeline import FaceCapture
    from facecapges.capture.video import open_source

    model = resolve_model(model)  # a missing model fails before any video is opened
    src = open_source(source)

    try:
        # one face: MediaPipe looks for two so that a second face in view can be reported
        cap = FaceCapture(estimator=estimator, fps=src.fps, model=model, intrinsics=K, num_faces=max(faces, 2))
    except BaseException:
        src.close()
        raise
    if depth and K is not None:
        from facecapges.capture.depth import DepthHeadTracker

        cap.depth_tracker = DepthHeadTracker(cap.mesh.vertices / 100.0, K)
    return src, cap


def _check_inputs(
    source: str,
    out: Path,
    fps: float,
    faces: int,
    overlay: str | Path | None,
    depth_dir,
    intrinsics,
    force: bool,
) -> tuple[list[Path], list | None, Any]:
    """The checks before any model loads: options, outputs (one per face), depth inputs, the source;
    returns the output paths, the depth files and the intrinsics."""
    if not (0 < fps <= 120):
        raise UserError(f"--fps must be in (0, 120], got {fps}")
    if not 1 <= int(faces) <= 8:
        raise UserError(f"--faces must be 1 to 8, got {faces}")
    outs = [out] if faces == 1 else [out.with_name(f"{out.stem}_{i + 1}{out.suffix}") for i in range(faces)]
    for p in outs:
        check_output_file(p, force)
    if overlay is not None:
        check_output_file(overlay, force)
    depth_files, K = (None, None)
    if depth_dir is not None or intrinsics is not None:
        from facecapges.capture.depth import check_depth_inputs

        depth_files, K = check_depth_inputs(depth_dir, intrinsics)
    from facecapges.capture.video import check_camera, check_video

    if str(source).isdigit():  # the source before the landmark model loads: a typo is reported at once
        check_camera(int(source))
    else:
        check_video(source)
    return outs, depth_files, K


def _run_frames(
    src,
    cap,
    writer,
    records: list[Records],
    n_found: list[int],
    source: str,
    fps: float,
    faces: int,
    max_frames: int | None,
    depth_files: list | None,
    progress: bool,
) -> int:
    """Capture the frames of ``src`` at ``fps`` into ``records`` (one per face; ``n_found`` counts the frames
    with a face), drawing the overlay; returns how many input frames had more than one face in view."""
    n_several = 0  # input frames with more than one face in view (one-face capture)
    total = None
    if src.n_frames:
        total = int(math.floor((src.n_frames - 1) / src.fps * fps)) + 1
        if max_frames:
            total = min(total, max_frames)
    from facecapges.progress import Progress

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
            if faces == 1:
                results = [cap.process(frame, ts, depth)]
                n_several += getattr(cap, "faces_in_view", 1) > 1
            else:
                results = [r if r is not None else cap.neutral(ts) for r in cap.process_slots(frame, ts, depth)]
            # a slow source (fps below --fps) repeats the frame on the skipped ticks
            while (k * 1000.0 / fps) <= ts + 1e-6 and (max_frames is None or k < max_frames):
                for i, res in enumerate(results):
                    n_found[i] += bool(res.face_found)
                    records[i].append(res)
                if writer is not None:
                    from facecapges.capture.overlay import draw_overlay

                    img = frame
                    for res in results:
                        img = draw_overlay(img, res)
                    writer.write(img)
                k += 1
                bar.advance(task)
    return n_several


def _warnings(src, n_found: list[int], n_several: int) -> list[str]:
    """What the user should know about the capture: damaged frames, a cut-short file, no face, several faces."""
    warnings = []
    if src.bad_frames:
        warnings.append(
            f"{src.bad_frames} frame(s) of the video could not be decoded (damaged stretch); the last "
            "good frame was held over them, so timing stays right"
        )
    if src.missing_tail > max(2, (src.n_frames or 0) // 100):  # containers often over-count by a frame
        warnings.append(
            f"the last {src.missing_tail} of {src.n_frames} frames the video declares could not be "
            "decoded (file cut short or damaged at its end)"
        )
    if sum(n_found) == 0:
        warnings.append("no face was found in any frame: the output holds a neutral face and a resting head")
    if n_several:
        warnings.append(
            f"more than one face was in view in {n_several} frame(s); the largest face was tracked "
            "(--faces N captures several)"
        )
    return warnings
