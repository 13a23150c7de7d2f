"""``facecapges demo``: the main job, offline, on a fresh clone.

It takes the bundled speech clip (``assets/demo/speech.wav``: our own text,
``speech.txt``, synthesised with espeak-ng — free to ship), generates gestures with
the default style frame by frame (no look-ahead, the live code path) and writes

* ``OUT/demo.bvh`` — the motion on the BEAT skeleton (opens in Blender / three.js),
* ``OUT/demo.mp4`` — the skeleton animation with the speech muxed in,
* ``OUT/demo_avatar.mp4`` — the avatar (our skinned BEAT body with the ARKit face,
  three.js in headless Chromium) performing the same motion, with the speech and a
  face close-up inset; the demo has speech only, so its jaw and lips are driven by the
  speech itself (:mod:`facecapges.capture.speech_mouth`, causal, frame by frame;
  ``facecapges run`` drives the whole face from a video),

then prints where they are.
"""

from __future__ import annotations

import json
import time
from importlib import resources
from pathlib import Path
from typing import Annotated

import typer

from facecapges.errors import echo


def demo_speech() -> Path:
    return Path(str(resources.files("facecapges") / "assets" / "demo" / "speech.wav"))


def make_demo(out: Path, audio: Path | None = None, force: bool = False, say=echo) -> dict:
    """The whole ``demo`` (module docstring): ``out``'s three files from ``audio`` (default: the bundled
    clip) with the default style; ``say`` gets the summary (JSON) and where the files are. Returns it."""
    from facecapges.avatar.body import default_avatar
    from facecapges.avatar.gltf import avatar_to_gltf
    from facecapges.avatar.render.skeleton_video import render_skeleton_video
    from facecapges.avatar.render.video import bvh_quaternions, our_avatar, render_video
    from facecapges.capture.speech_mouth import speech_mouth_track
    from facecapges.engine.generate import generate_poses
    from facecapges.errors import check_output_file
    from facecapges.io.bvh import write_bvh
    from facecapges.rotations import normalize_rot6d
    from facecapges.skeleton import pose_to_motion
    from facecapges.styles import load_style

    speech = audio or demo_speech()
    bvh_path, mp4_path, avatar_path = out / "demo.bvh", out / "demo.mp4", out / "demo_avatar.mp4"
    for p in (bvh_path, mp4_path, avatar_path):
        check_output_file(p, force)
    t0 = time.perf_counter()
    ckpt = load_style()
    inputs = ckpt.prepare_inputs(speech)
    poses, ms = generate_poses(ckpt, inputs)
    poses = normalize_rot6d(poses)
    skel = ckpt.skeleton
    motion = pose_to_motion(skel, poses)
    write_bvh(bvh_path, skel, motion, ckpt.fps)
    render_skeleton_video(
        [poses], [f"FaceCapGes ({ckpt.path.stem})"], skel, mp4_path, fps=ckpt.fps, wav=speech, progress=True
    )
    glb = b"".join(avatar_to_gltf(default_avatar(skel)).save_to_bytes())
    quats = bvh_quaternions(list(skel.names), skel, motion, name=str(bvh_path))
    mouth = speech_mouth_track(inputs.audio[: len(poses)], ckpt.fps)
    render_video(our_avatar(glb), quats, mouth, ckpt.fps, avatar_path, audio=speech, progress=True)
    summary = {
        "speech": str(speech),
        "frames": int(len(poses)),
        "fps": ckpt.fps,
        "ms_per_frame": round(ms, 2),
        "seconds": round(time.perf_counter() - t0, 1),
        "bvh": str(bvh_path),
        "video": str(mp4_path),
        "avatar_video": str(avatar_path),
    }
    say(json.dumps(summary, indent=2))
    say(
        f"\nGestures for {len(poses) / ckpt.fps:.1f} s of speech ({ms:.2f} ms per frame):\n"
        f"  motion: {bvh_path.resolve()}\n  video:  {mp4_path.resolve()}\n"
        f"  avatar: {avatar_path.resolve()}"
    )
    return summary


OUT = typer.Option("--out", help="Output folder.")
AUDIO = typer.Option("--audio", help="Speech to use instead of the bundled clip.")
FORCE = typer.Option("--force", help="Overwrite the demo files in OUT.")


def demo(
    out: Annotated[Path, OUT] = Path("out"),
    audio: Annotated[Path | None, AUDIO] = None,
    force: Annotated[bool, FORCE] = False,
) -> None:
    """Generate gestures for a speech clip: out/demo.bvh, out/demo.mp4 (skeleton), out/demo_avatar.mp4."""
    make_demo(out, audio, force, say=typer.echo)


def register(app: typer.Typer) -> None:
    app.command()(demo)
