"""Commands of the model area: ``generate``, ``styles`` (``train`` is in :mod:`facecapges.training.commands`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer


def register(app: typer.Typer) -> None:
    @app.command()
    def generate(
        audio: Path = typer.Option(..., help="Speech audio (any format soundfile/ffmpeg reads; resampled to 16 kHz)."),
        out: Path = typer.Option(..., help="Output BVH file (full BEAT skeleton, model fps)."),
        face: Optional[Path] = typer.Option(None, help="BEAT-format face JSON, any fps (resampled)."),
        head: Optional[Path] = typer.Option(None, help="Head rotation .npy (T, 6) rot6d at the model fps."),
        checkpoint: Optional[Path] = typer.Option(None, help="Checkpoint file (default: the installed default style)."),
        style: Optional[str] = typer.Option(None, help="Installed style name (see `facecapges styles`)."),
        json_out: bool = typer.Option(False, "--json", help="Print a JSON summary instead of text."),
        force: bool = typer.Option(False, "--force", help="Overwrite OUT if it exists."),
    ) -> None:
        """Generate upper-body gestures for a recording, frame by frame, no look-ahead."""
        from facecapges.errors import refuse_overwrite
        from facecapges.io.bvh import write_bvh
        from facecapges.model.checkpoint import load_checkpoint
        from facecapges.model.generate import generate_poses, prepare_inputs
        from facecapges.rotations import normalize_rot6d
        from facecapges.skeleton import pose_to_motion

        refuse_overwrite(out, force)
        ckpt = load_checkpoint(checkpoint, style)
        inputs = prepare_inputs(audio, face, head, fps=ckpt.fps)
        for note in inputs.notes:
            typer.secho(f"warning: {note}", err=True, fg=typer.colors.YELLOW)
        poses, ms = generate_poses(ckpt, inputs, progress=not json_out)
        skel = ckpt.skeleton
        write_bvh(out, skel, pose_to_motion(skel, normalize_rot6d(poses)), ckpt.fps)
        summary = {"out": str(out), "frames": int(len(poses)), "fps": ckpt.fps,
                   "duration_s": round(len(poses) / ckpt.fps, 3), "ms_per_frame": round(ms, 3),
                   "checkpoint": str(ckpt.path), "warnings": inputs.notes}
        if json_out:
            typer.echo(json.dumps(summary))
        else:
            typer.echo(f"wrote {out}: {summary['frames']} frames at {ckpt.fps} fps "
                       f"({summary['duration_s']} s), {ms:.2f} ms/frame")

    @app.command()
    def styles(json_out: bool = typer.Option(False, "--json", help="Print JSON.")) -> None:
        """List the installed speaking styles (per-speaker checkpoints)."""
        from facecapges.model.checkpoint import DEFAULT_STYLE, list_styles, load_checkpoint

        rows = []
        for name, path in list_styles().items():
            meta = load_checkpoint(path).meta
            rows.append({"name": name, "default": name == DEFAULT_STYLE, "speaker": meta.get("speaker"),
                         "epochs": meta.get("epochs_trained"), "path": str(path)})
        if json_out:
            typer.echo(json.dumps(rows, indent=2))
            return
        if not rows:
            typer.echo("no styles installed")
        for r in rows:
            typer.echo(f"{'*' if r['default'] else ' '} {r['name']}  speaker {r['speaker']}  "
                       f"{r['epochs']} epochs  {r['path']}")
