"""Commands of the runtime: ``run`` (a video to files) and ``live`` (devices to avatar)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from facecapges.commands.params import CHECKPOINT, ESTIMATOR, FACE_JSON, FACES_HELP, HEAD, INTENSITY, STYLE
from facecapges.runtime.options import LiveOptions, RunOptions

VIDEO_ARG = typer.Argument(help="Talking-head video (its audio track is the speech unless --audio).")
RUN_OUT = typer.Option(
    "--out", help="Output directory: motion.bvh, face.json, avatar.mp4, side_by_side.mp4, report.json."
)
RUN_AUDIO = typer.Option("--audio", help="Speech audio file instead of the video's track.")
MAX_FRAMES = typer.Option("--max-frames", help="Stop after this many model frames.")
NO_VIDEO = typer.Option("--no-video", help="Skip avatar.mp4 and side_by_side.mp4.")
VIDEO_SIZE = typer.Option(
    "--video-size", help="Avatar video size WxH (default 640x480; side_by_side.mp4 has its height)."
)
RUN_FACES = typer.Option("--faces", help=FACES_HELP)
RUN_AVATAR = typer.Option("--avatar", help="Avatar of avatar.mp4: a VRM 0.x/1.0 or a humanoid GLB (default: ours).")
RUN_JSON = typer.Option("--json", help="Print the report as JSON.")
RUN_FORCE = typer.Option("--force", help="Overwrite outputs in --out.")


def run_cmd(
    video: Annotated[Path, VIDEO_ARG],
    out: Annotated[Path, RUN_OUT],
    audio: Annotated[Path | None, RUN_AUDIO] = RunOptions.audio,
    checkpoint: Annotated[Path | None, CHECKPOINT] = RunOptions.checkpoint,
    style: Annotated[str | None, STYLE] = RunOptions.style,
    intensity: Annotated[float, INTENSITY] = RunOptions.intensity,
    estimator: Annotated[str, ESTIMATOR] = RunOptions.estimator,
    max_frames: Annotated[int | None, MAX_FRAMES] = RunOptions.max_frames,
    no_video: Annotated[bool, NO_VIDEO] = RunOptions.no_video,
    face_json: Annotated[str, FACE_JSON] = RunOptions.face_json,
    video_size: Annotated[str | None, VIDEO_SIZE] = RunOptions.video_size,
    head: Annotated[str, HEAD] = RunOptions.head,
    faces: Annotated[int, RUN_FACES] = RunOptions.faces,
    avatar: Annotated[Path | None, RUN_AVATAR] = RunOptions.avatar,
    json_out: Annotated[bool, RUN_JSON] = RunOptions.json_out,
    force: Annotated[bool, RUN_FORCE] = RunOptions.force,
) -> None:
    """Video → face capture → gestures → avatar, frame by frame as live, as fast as it goes, to files."""
    options = RunOptions(**locals())  # before any other name is bound here
    from facecapges.runtime.run import run_offline

    run_offline(options, say=typer.echo)


CAMERA = typer.Option("--camera", help="Camera index (OpenCV); camera 0 when no other input is chosen.")
LIVE_VIDEO = typer.Option("--video", help="A video file as the camera (+ its audio).")
LIVELINK = typer.Option(
    "--livelink", help="Receive iPhone Live Link Face on this UDP port (the app's default is 11111)."
)
REALTIME = typer.Option("--realtime", help="Pace --video like a device (else as fast as it goes).")
LOOP = typer.Option("--loop", help="Loop --video (and its audio) until stopped.")
MIC = typer.Option("--mic", help="Microphone: sounddevice index or name (default device for --camera / --livelink).")
LIVE_AUDIO = typer.Option("--audio", help="Speech from a file instead of a microphone.")
VMC = typer.Option("--vmc", help="Send VMC (OSC/UDP) to HOST:PORT, e.g. 127.0.0.1:39539.")
VMC_BLEND = typer.Option(
    "--vmc-blend",
    help="Face clips sent over VMC: vrm (VRM presets Blink, A…O, Joy…; every VRM), perfect-sync (the 52 ARKit "
    "clips, EyeBlinkLeft…) or both.",
)
VMC_AVATAR = typer.Option(
    "--vmc-avatar",
    help="The receiver's VRM file: send in its own rest bone positions and bone frames (it keeps its "
    "proportions, and a VRM 1.0 with rest rotations moves right). Default: our avatar's (avatar build).",
)
VMC_PARTS = typer.Option(
    "--vmc-parts",
    help="What VMC drives: all (root, body, face), upper (no root/hips), or arms (shoulders, arms, "
    "hands, fingers only: your own face tracker keeps the head and face).",
)
RATE = typer.Option(
    "--rate",
    help="VMC output rate in Hz, a multiple of the model's 15 fps: 30 or 60 interpolate between model frames "
    "(+33 / +50 ms latency); the viewer gets the model frames and blends between them the same way in the page.",
)
WEB = typer.Option(
    "--web", help="Serve the browser viewer on [HOST:]PORT, e.g. 127.0.0.1:8765 (port 0: any free port)."
)
HOST = typer.Option(
    "--host",
    help="Bind servers (viewer, Live Link) to this address instead of 127.0.0.1, e.g. 0.0.0.0 for a phone on the LAN.",
)
RECORD = typer.Option("--record", help="Record motion.bvh, face.json and report.json into this directory.")
VRMA = typer.Option(
    "--vrma", help="With --record: also record motion.vrma (VRM Animation, gestures + face as VRM presets)."
)
LIVE_AVATAR = typer.Option(
    "--avatar", help="Show this avatar in --web: a VRM 0.x/1.0 or a humanoid GLB (default: ours)."
)
DEPTH = typer.Option("--depth", help="RGB-D: directory of depth frames for --video (16-bit PNG or .npy, mm).")
INTRINSICS = typer.Option("--intrinsics", help="RGB-D: camera intrinsics K.json.")
MAX_SECONDS = typer.Option("--max-seconds", help="Stop after this much stream time.")
LIVE_FACES = typer.Option("--faces", help=FACES_HELP + " VMC: face i on PORT+i-1.")
BODY = typer.Option(
    "--body",
    help="Your arms and hands on the avatar where the camera sees them (MediaPipe pose + hands, as "
    "capture-body); where they leave the frame the engine's gestures take over, blended (docs/capture-body.md).",
)
GESTURES = typer.Option(
    "--gestures", help="With --body: the engine's gestures on the arms even where yours are seen (body still captured)."
)
LIVE_FORCE = typer.Option("--force", help="Overwrite files in --record.")


def live_cmd(
    camera: Annotated[int | None, CAMERA] = LiveOptions.camera,
    video: Annotated[Path | None, LIVE_VIDEO] = LiveOptions.video,
    livelink: Annotated[int | None, LIVELINK] = LiveOptions.livelink,
    realtime: Annotated[bool, REALTIME] = LiveOptions.realtime,
    loop: Annotated[bool, LOOP] = LiveOptions.loop,
    mic: Annotated[str | None, MIC] = LiveOptions.mic,
    audio: Annotated[Path | None, LIVE_AUDIO] = LiveOptions.audio,
    vmc: Annotated[str | None, VMC] = LiveOptions.vmc,
    vmc_blend: Annotated[str, VMC_BLEND] = LiveOptions.vmc_blend,
    vmc_avatar: Annotated[Path | None, VMC_AVATAR] = LiveOptions.vmc_avatar,
    vmc_parts: Annotated[str, VMC_PARTS] = LiveOptions.vmc_parts,
    rate: Annotated[float | None, RATE] = LiveOptions.rate,
    web: Annotated[str | None, WEB] = LiveOptions.web,
    host: Annotated[str | None, HOST] = LiveOptions.host,
    record: Annotated[Path | None, RECORD] = LiveOptions.record,
    face_json: Annotated[str, FACE_JSON] = LiveOptions.face_json,
    vrma: Annotated[bool, VRMA] = LiveOptions.vrma,
    avatar: Annotated[Path | None, LIVE_AVATAR] = LiveOptions.avatar,
    checkpoint: Annotated[Path | None, CHECKPOINT] = LiveOptions.checkpoint,
    style: Annotated[str | None, STYLE] = LiveOptions.style,
    intensity: Annotated[float, INTENSITY] = LiveOptions.intensity,
    estimator: Annotated[str, ESTIMATOR] = LiveOptions.estimator,
    depth: Annotated[Path | None, DEPTH] = LiveOptions.depth,
    intrinsics: Annotated[Path | None, INTRINSICS] = LiveOptions.intrinsics,
    max_seconds: Annotated[float | None, MAX_SECONDS] = LiveOptions.max_seconds,
    head: Annotated[str, HEAD] = LiveOptions.head,
    faces: Annotated[int, LIVE_FACES] = LiveOptions.faces,
    body: Annotated[bool, BODY] = LiveOptions.body,
    gestures: Annotated[bool, GESTURES] = LiveOptions.gestures,
    force: Annotated[bool, LIVE_FORCE] = LiveOptions.force,
) -> None:
    """Real-time avatar: camera/video/Live Link + microphone/audio → VMC, browser viewer, recording."""
    options = LiveOptions(**locals())  # before any other name is bound here
    from facecapges.runtime.live import run_live

    run_live(options, say=typer.echo)


def register(app: typer.Typer) -> None:
    app.command("run")(run_cmd)
    app.command("live")(live_cmd)
