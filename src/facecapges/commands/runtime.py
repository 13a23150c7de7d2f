"""Commands of the runtime: ``run`` (a video to files) and ``live`` (devices to avatar)."""

from __future__ import annotations

from pathlib import Path

import typer

from facecapges.runtime.options import LiveOptions, RunOptions

STYLE_HELP = "Installed speaking style (see `facecapges styles`); default: the default style."
CKPT_HELP = "Checkpoint file of a speaking style (instead of --style)."
HEAD_HELP = (
    "What the avatar's head shows: capture (the person's head; the model's when the face is lost), "
    "model (the gesture model's neck) or blend (half-way)."
)
FACE_JSON_HELP = "face.json layout: beat (BEAT's: 51 weights at 60 fps) or full (52 weights at the model rate)."
INTENSITY_HELP = (
    "Gesture intensity: 0 (rest / idle only) … 1 (as the style moves) … 1.3 (larger than recorded); "
    "the viewer has a slider for it."
)
FACES_HELP = "Faces to follow, each with its own avatar (1-8; files, VMC ports and viewer avatars per face)."


def run_cmd(
    video: Path = typer.Argument(..., help="Talking-head video (its audio track is the speech unless --audio)."),
    out: Path = typer.Option(
        ..., "--out", help="Output directory: motion.bvh, face.json, avatar.mp4, side_by_side.mp4, report.json."
    ),
    audio: Path | None = typer.Option(None, "--audio", help="Speech audio file instead of the video's track."),
    checkpoint: Path | None = typer.Option(None, "--checkpoint", help=CKPT_HELP),
    style: str | None = typer.Option(None, "--style", help=STYLE_HELP),
    intensity: float = typer.Option(RunOptions.intensity, "--intensity", help=INTENSITY_HELP),
    estimator: str = typer.Option(RunOptions.estimator, help="Face capture estimator: geometric, mediapipe or hybrid."),
    max_frames: int | None = typer.Option(None, "--max-frames", help="Stop after this many model frames."),
    no_video: bool = typer.Option(RunOptions.no_video, "--no-video", help="Skip avatar.mp4 and side_by_side.mp4."),
    face_json: str = typer.Option(
        RunOptions.face_json,
        "--face-json",
        help=FACE_JSON_HELP,
    ),
    video_size: str | None = typer.Option(
        None, "--video-size", help="Avatar video size WxH (default 640x480; side_by_side.mp4 has its height)."
    ),
    head: str = typer.Option(RunOptions.head, "--head", help=HEAD_HELP),
    faces: int = typer.Option(RunOptions.faces, "--faces", help=FACES_HELP),
    avatar: Path | None = typer.Option(
        None, "--avatar", help="Avatar of avatar.mp4: a VRM 0.x/1.0 or a humanoid GLB (default: ours)."
    ),
    json_out: bool = typer.Option(RunOptions.json_out, "--json", help="Print the report as JSON."),
    force: bool = typer.Option(RunOptions.force, "--force", help="Overwrite outputs in --out."),
) -> None:
    """Video → face capture → gestures → avatar, frame by frame as live, as fast as it goes, to files."""
    options = RunOptions(**locals())  # before any other name is bound here
    from facecapges.runtime.run import run_offline

    run_offline(options, say=typer.echo)


def live_cmd(
    camera: int | None = typer.Option(
        None, "--camera", help="Camera index (OpenCV); camera 0 when no other input is chosen."
    ),
    video: Path | None = typer.Option(None, "--video", help="A video file as the camera (+ its audio)."),
    livelink: int | None = typer.Option(
        None, "--livelink", help="Receive iPhone Live Link Face on this UDP port (the app's default is 11111)."
    ),
    realtime: bool = typer.Option(
        LiveOptions.realtime, "--realtime", help="Pace --video like a device (else as fast as it goes)."
    ),
    loop: bool = typer.Option(LiveOptions.loop, "--loop", help="Loop --video (and its audio) until stopped."),
    mic: str | None = typer.Option(
        None, "--mic", help="Microphone: sounddevice index or name (default device for --camera / --livelink)."
    ),
    audio: Path | None = typer.Option(None, "--audio", help="Speech from a file instead of a microphone."),
    vmc: str | None = typer.Option(None, "--vmc", help="Send VMC (OSC/UDP) to HOST:PORT, e.g. 127.0.0.1:39539."),
    vmc_blend: str = typer.Option(
        LiveOptions.vmc_blend,
        "--vmc-blend",
        help="Face clips sent over VMC: vrm (VRM presets Blink, "
        "A…O, Joy…; every VRM), perfect-sync (the 52 ARKit "
        "clips, EyeBlinkLeft…) or both.",
    ),
    vmc_avatar: Path | None = typer.Option(
        None,
        "--vmc-avatar",
        help="The receiver's VRM file: send in its own rest bone positions and bone frames (it keeps its "
        "proportions, and a VRM 1.0 with rest rotations moves right). Default: our avatar's (avatar build).",
    ),
    vmc_parts: str = typer.Option(
        LiveOptions.vmc_parts,
        "--vmc-parts",
        help="What VMC drives: all (root, body, face), upper (no root/hips), or arms (shoulders, arms, "
        "hands, fingers only: your own face tracker keeps the head and face).",
    ),
    rate: float | None = typer.Option(
        None,
        "--rate",
        help="VMC and viewer output rate in Hz, a multiple of "
        "the model's 15 fps: 30 or 60 interpolate between "
        "model frames (+33 / +50 ms latency).",
    ),
    web: str | None = typer.Option(
        None, "--web", help="Serve the browser viewer on [HOST:]PORT, e.g. 127.0.0.1:8765 (port 0: any free port)."
    ),
    host: str | None = typer.Option(
        None,
        "--host",
        help="Bind servers (viewer, Live Link) to this address "
        "instead of 127.0.0.1, e.g. 0.0.0.0 for a phone on "
        "the LAN.",
    ),
    record: Path | None = typer.Option(
        None, "--record", help="Record motion.bvh, face.json and report.json into this directory."
    ),
    face_json: str = typer.Option(
        LiveOptions.face_json,
        "--face-json",
        help=FACE_JSON_HELP,
    ),
    vrma: bool = typer.Option(
        LiveOptions.vrma,
        "--vrma",
        help="With --record: also record motion.vrma (VRM Animation, gestures + face as VRM presets).",
    ),
    avatar: Path | None = typer.Option(
        None, "--avatar", help="Show this avatar in --web: a VRM 0.x/1.0 or a humanoid GLB (default: ours)."
    ),
    checkpoint: Path | None = typer.Option(None, "--checkpoint", help=CKPT_HELP),
    style: str | None = typer.Option(None, "--style", help=STYLE_HELP),
    intensity: float = typer.Option(LiveOptions.intensity, "--intensity", help=INTENSITY_HELP),
    estimator: str = typer.Option(
        LiveOptions.estimator, help="Face capture estimator: geometric, mediapipe or hybrid."
    ),
    depth: Path | None = typer.Option(
        None, "--depth", help="RGB-D: directory of depth frames for --video (16-bit PNG or .npy, mm)."
    ),
    intrinsics: Path | None = typer.Option(None, "--intrinsics", help="RGB-D: camera intrinsics K.json."),
    max_seconds: float | None = typer.Option(None, "--max-seconds", help="Stop after this much stream time."),
    head: str = typer.Option(LiveOptions.head, "--head", help=HEAD_HELP),
    faces: int = typer.Option(LiveOptions.faces, "--faces", help=FACES_HELP + " VMC: face i on PORT+i-1."),
    force: bool = typer.Option(LiveOptions.force, "--force", help="Overwrite files in --record."),
) -> None:
    """Real-time avatar: camera/video/Live Link + microphone/audio → VMC, browser viewer, recording."""
    options = LiveOptions(**locals())  # before any other name is bound here
    from facecapges.runtime.live import run_live

    run_live(options, say=typer.echo)


def register(app: typer.Typer) -> None:
    app.command("run")(run_cmd)
    app.command("live")(live_cmd)
