"""``facecapges capture`` and ``facecapges capture-eval``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from facecapges.commands.params import LANDMARK_MODEL
from facecapges.timing import MODEL_FPS

SOURCE = typer.Argument(help="A video file, or a camera index (0, 1, …).")
CAPTURE_OUT = typer.Option("--out", help="Face JSON to write (ARKit weights + head rot6d per frame).")
ESTIMATOR = typer.Option("--estimator", help="geometric | mediapipe | hybrid (see facecapges.capture.estimator).")
FPS = typer.Option("--fps", help="Capture frame rate (frames per second); BEAT's layout is written at 60.")
FACE_JSON = typer.Option(
    "--face-json", help="Layout: beat (BEAT's: 51 weights at 60 fps) or full (52 weights at --fps)."
)
OVERLAY = typer.Option("--overlay", help="Also write an MP4 with landmarks, head axes and blendshape bars.")
DEPTH = typer.Option("--depth", help="Directory of depth frames (16-bit PNG or .npy, mm), one per video frame.")
INTRINSICS = typer.Option("--intrinsics", help="Depth camera intrinsics JSON: fx, fy, cx, cy (pixels).")
CAPTURE_MAX_FRAMES = typer.Option("--max-frames", help="Stop after this many output frames (needed for cameras).")
FACES = typer.Option(
    "--faces",
    help="Faces to follow (1-8); several write OUT_1.json … one per face, numbered left to right, kept by position.",
)
CAPTURE_FORCE = typer.Option("--force", help="Overwrite existing output files.")


def capture(
    source: Annotated[str, SOURCE],
    out: Annotated[Path, CAPTURE_OUT],
    estimator: Annotated[str, ESTIMATOR] = "hybrid",
    fps: Annotated[float, FPS] = float(MODEL_FPS),
    face_json: Annotated[str, FACE_JSON] = "beat",
    overlay: Annotated[Path | None, OVERLAY] = None,
    depth: Annotated[Path | None, DEPTH] = None,
    intrinsics: Annotated[Path | None, INTRINSICS] = None,
    model: Annotated[Path | None, LANDMARK_MODEL] = None,
    max_frames: Annotated[int | None, CAPTURE_MAX_FRAMES] = None,
    faces: Annotated[int, FACES] = 1,
    force: Annotated[bool, CAPTURE_FORCE] = False,
) -> None:
    """Face capture without calibration: video/camera → ARKit blendshapes + head pose (face JSON)."""
    from rich.console import Console

    from facecapges.capture.runner import capture_video
    from facecapges.errors import UserError

    if face_json not in ("beat", "full"):
        raise UserError(f"--face-json {face_json}: choose beat or full")
    if estimator not in ("geometric", "mediapipe", "hybrid"):
        raise UserError(f"--estimator must be geometric, mediapipe or hybrid, got {estimator!r}")
    s = capture_video(
        source,
        out,
        estimator=estimator,
        fps=fps,
        overlay=overlay,
        depth_dir=depth,
        intrinsics=intrinsics,
        model=model,
        force=force,
        max_frames=max_frames,
        faces=faces,
        face_layout=face_json,
    )
    console = Console(stderr=True, soft_wrap=True)  # one line per message, whatever the width
    for w in s.get("warnings", []):
        console.print(f"[yellow]warning:[/yellow] {w}")
    console.print(
        f"wrote {s['out']}: {s['frames']} frames captured at {s['fps']:g} fps, "
        f"face found in {s['face_found']}" + (f"; overlay {overlay}" if overlay else "")
    )


VIDEO = typer.Argument(help="A video of a face.")
CAPTURE_EVAL_OUT = typer.Option("--out", help="Directory for capture_eval.json and tracks.png.")
SKIP = typer.Option("--skip", help="Seconds at the start not scored (cold start).")
CAPTURE_EVAL_MAX_FRAMES = typer.Option("--max-frames", help="Only the first N frames.")
CAPTURE_EVAL_FORCE = typer.Option("--force", help="Overwrite capture_eval.json and tracks.png in --out.")


def capture_eval(
    video: Annotated[Path, VIDEO],
    out: Annotated[Path, CAPTURE_EVAL_OUT] = Path("capture_eval"),
    skip: Annotated[float, SKIP] = 2.0,
    model: Annotated[Path | None, LANDMARK_MODEL] = None,
    max_frames: Annotated[int | None, CAPTURE_EVAL_MAX_FRAMES] = None,
    force: Annotated[bool, CAPTURE_EVAL_FORCE] = False,
) -> None:
    """Geometric (calibration-free) estimator vs MediaPipe's learned blendshapes and head transform."""
    import math

    from rich.console import Console
    from rich.table import Table

    from facecapges.capture.video import check_video
    from facecapges.errors import check_output_dir

    check_video(video)  # before MediaPipe loads
    check_output_dir(out, ("capture_eval.json", "tracks.png"), force)
    from facecapges.capture.evaluate import evaluate_tracks, plot_tracks, run_tracks, write_report

    tr = run_tracks(video, model=model, max_frames=max_frames, progress=True)
    rep = evaluate_tracks(tr, skip)
    rep["video"] = str(video)
    out.mkdir(parents=True, exist_ok=True)
    path = write_report(rep, out)
    plot_tracks(tr, out / "tracks.png", skip)
    table = Table(
        "channel", "Pearson r", "MAE", "target", title=f"geometric vs MediaPipe, {video.name}, after {skip:g} s"
    )
    for name, c in rep["channels"].items():
        tgt = rep["targets"].get(name)
        mark = "" if tgt is None else (f"≥ {tgt['target']} " + ("ok" if tgt["met"] else "MISSED"))
        table.add_row(name, "n/a" if math.isnan(c["r"]) else f"{c['r']:.3f}", f"{c['mae']:.3f}", mark)
    con = Console()
    con.print(table)
    h = rep["head_pose"]
    ok = "ok" if rep["targets"]["head_pose_median_deg"]["met"] else "MISSED"
    con.print(f"head pose vs MediaPipe transform: median {h['median_deg']:.2f}°, p90 {h['p90_deg']:.2f}° (≤ 3° {ok})")
    con.print(
        f"landmarks {rep['landmarks_ms_per_frame']:.1f} ms/frame, rest of capture {rep['per_face_ms_per_frame']:.2f} ms/frame"
    )
    con.print(f"wrote {path} and {out / 'tracks.png'}")


BODY_VIDEO = typer.Argument(help="A video of a person, upper body and hands in view.")
BODY_OUT = typer.Option("--out", help="BEAT skeleton BVH to write (15 fps, the 47 upper-body joints).")
BODY_FACE_OUT = typer.Option("--face-out", help="Also write the face capture (face JSON, 15 fps) alongside.")
BODY_MAX_FRAMES = typer.Option("--max-frames", help="Only the first N output frames (15 fps).")
BODY_FORCE = typer.Option("--force", help="Overwrite existing output files.")


def capture_body(
    video: Annotated[Path, BODY_VIDEO],
    out: Annotated[Path, BODY_OUT],
    face_out: Annotated[Path | None, BODY_FACE_OUT] = None,
    max_frames: Annotated[int | None, BODY_MAX_FRAMES] = None,
    force: Annotated[bool, BODY_FORCE] = False,
) -> None:
    """Body and hands from ordinary video: MediaPipe pose + hand landmarks → BEAT upper-body BVH."""
    from rich.console import Console

    from facecapges.capture.body import capture_body as run
    from facecapges.capture.body_models import HAND_TASK, POSE_TASK, model_path
    from facecapges.errors import UserError, check_output_file
    from facecapges.styles import DEFAULT_STYLE, load_style

    check_output_file(out, force)
    if face_out is not None:
        check_output_file(face_out, force)
    if max_frames is not None and max_frames < 1:
        raise UserError(f"--max-frames must be at least 1, got {max_frames}")
    model_path(POSE_TASK), model_path(HAND_TASK)  # a missing model fails before the video is read
    console = Console(stderr=True, soft_wrap=True)
    skeleton = load_style(style=DEFAULT_STYLE).skeleton

    def progress(i: int, n: int | None) -> None:
        if i % 15 == 0 or i == n:
            console.print(f"capture-body: {i}/{n if n is not None else '?'} frames", end="\r")

    res, s = run(video, out, skeleton, max_frames=max_frames, progress=progress)
    console.print()
    hands = s["hands_found"]
    console.print(
        f"wrote {out}: {s['frames']} frames at 15 fps; person found in {s['pose_found']:.0%}, "
        f"right hand {hands[0]:.0%}, left hand {hands[1]:.0%}, both {s['both_hands_found']:.0%}; "
        f"{s['ms_per_frame']:.0f} ms/frame"
    )
    warning = s["warning"]
    if warning:
        console.print(f"[yellow]warning:[/yellow] {warning}")
    if face_out is not None:
        from facecapges.capture.runner import capture_video

        f = capture_video(str(video), face_out, fps=15.0, force=force, max_frames=max_frames, face_layout="full")
        console.print(f"wrote {face_out}: face found in {f['face_found']}")
        _head_from_face(out, face_out, res.pose, skeleton)
        console.print(f"{out}: Neck and Neck1 follow the face capture's head where the face was found")


def _head_from_face(out: Path, face_out: Path, pose, skeleton) -> None:
    """Neck/Neck1 of the captured body from the face capture's head (as ``run --head capture`` shows it)."""
    import json

    from facecapges.io.bvh import write_bvh
    from facecapges.runtime.head import HeadDriver
    from facecapges.skeleton import pose_to_motion
    from facecapges.timing import MODEL_FPS

    frames = json.loads(Path(face_out).read_text())["frames"]
    driver = HeadDriver("capture")
    posed = pose.copy()
    for t in range(min(len(frames), len(pose))):
        fr = frames[t]
        posed[t] = driver(pose[t], fr["head_rot6d"], bool(fr.get("face_found", True)), t / MODEL_FPS)
    write_bvh(out, skeleton, pose_to_motion(skeleton, posed), float(MODEL_FPS))


def register(app: typer.Typer) -> None:
    app.command("capture-body")(capture_body)
    app.command("capture")(capture)
    app.command("capture-eval")(capture_eval)
