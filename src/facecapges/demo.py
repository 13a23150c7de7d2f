"""``facecapges demo``: the main job, offline, on a fresh clone.

It takes the bundled speech clip (``assets/demo/speech.wav``: our own text,
``speech.txt``, synthesised with espeak-ng — free to ship), generates gestures with
the default style frame by frame (no look-ahead, the live code path) and writes

* ``OUT/demo.bvh`` — the motion on the BEAT skeleton (opens in Blender / three.js),
* ``OUT/demo.mp4`` — the skeleton animation with the speech muxed in,

then prints where they are.
"""

from __future__ import annotations

import json
import time
from importlib import resources
from pathlib import Path

import typer


def demo_speech() -> Path:
    return Path(str(resources.files("facecapges") / "assets" / "demo" / "speech.wav"))


def register(app: typer.Typer) -> None:
    @app.command()
    def demo(
        out: Path = typer.Option(Path("out"), help="Output folder."),
        audio: Path = typer.Option(None, help="Speech to use instead of the bundled clip."),
        force: bool = typer.Option(False, "--force", help="Overwrite the demo files in OUT."),
    ) -> None:
        """Generate gestures for a speech clip and write out/demo.bvh and out/demo.mp4."""
        from facecapges.errors import refuse_overwrite
        from facecapges.io.bvh import write_bvh
        from facecapges.model.checkpoint import load_checkpoint
        from facecapges.model.generate import generate_poses, prepare_inputs
        from facecapges.outputs.skeleton_video import render_skeleton_video
        from facecapges.rotations import normalize_rot6d
        from facecapges.skeleton import pose_to_motion

        speech = audio or demo_speech()
        bvh_path, mp4_path = out / "demo.bvh", out / "demo.mp4"
        for p in (bvh_path, mp4_path):
            refuse_overwrite(p, force)
        t0 = time.perf_counter()
        ckpt = load_checkpoint()
        inputs = prepare_inputs(speech, fps=ckpt.fps)
        poses, ms = generate_poses(ckpt, inputs)
        poses = normalize_rot6d(poses)
        skel = ckpt.skeleton
        write_bvh(bvh_path, skel, pose_to_motion(skel, poses), ckpt.fps)
        render_skeleton_video([poses], [f"FaceCapGes ({ckpt.path.stem})"], skel, mp4_path, fps=ckpt.fps,
                              wav=speech, progress=True)
        summary = {"speech": str(speech), "frames": int(len(poses)), "fps": ckpt.fps,
                   "ms_per_frame": round(ms, 2), "seconds": round(time.perf_counter() - t0, 1),
                   "bvh": str(bvh_path), "video": str(mp4_path)}
        typer.echo(json.dumps(summary, indent=2))
        typer.echo(f"\nGestures for {len(poses) / ckpt.fps:.1f} s of speech ({ms:.2f} ms per frame):\n"
                   f"  motion: {bvh_path.resolve()}\n  video:  {mp4_path.resolve()}")
