"""Commands of the model area: ``generate``, ``styles`` (``train`` is in :mod:`facecapges.training.commands`)."""

from __future__ import annotations

import json
from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command()
    def generate(
        audio: Path = typer.Option(..., help="Speech audio (any format soundfile/ffmpeg reads; resampled to 16 kHz)."),
        out: Path = typer.Option(..., help="Output BVH file (full BEAT skeleton, model fps)."),
        face: Path | None = typer.Option(None, help="BEAT-format face JSON, any fps (resampled)."),
        head: Path | None = typer.Option(None, help="Head rotation .npy (T, 6) rot6d at the model fps."),
        checkpoint: Path | None = typer.Option(None, help="Checkpoint file (default: the installed default style)."),
        style: str | None = typer.Option(None, help="Installed style name (see `facecapges styles`)."),
        face_out: Path | None = typer.Option(
            None,
            "--face-out",
            help="Also write the face to show with the "
            "motion (face JSON): --face resampled, or "
            "without --face, jaw and lips from the "
            "speech.",
        ),
        json_out: bool = typer.Option(False, "--json", help="Print a JSON summary instead of text."),
        vrma: Path | None = typer.Option(
            None,
            "--vrma",
            help="Also write the gestures (+ the --face weights) as VRM Animation (.vrma) for any VRM avatar.",
        ),
        vrma_face: str = typer.Option(
            "presets",
            "--vrma-face",
            help="Face in the .vrma: presets (VRM presets from ARKit, any VRM) or perfect-sync (52 ARKit).",
        ),
        force: bool = typer.Option(False, "--force", help="Overwrite OUT if it exists."),
    ) -> None:
        """Generate upper-body gestures for a recording, frame by frame, no look-ahead."""
        import numpy as np

        from facecapges.errors import check_output_file
        from facecapges.io.bvh import BvhWriter
        from facecapges.model.checkpoint import load_checkpoint
        from facecapges.model.generate import generate_blocks, plan_inputs
        from facecapges.rotations import normalize_rot6d
        from facecapges.skeleton import pose_to_motion

        check_output_file(out, force)  # before the work: existing, folder, unwritable
        if face_out is not None:
            check_output_file(face_out, force)
        if vrma is not None:
            from facecapges.avatar.vrma import check_face_mode

            check_output_file(vrma, force)
            check_face_mode(vrma_face)
        ckpt = load_checkpoint(checkpoint, style)
        inputs = plan_inputs(audio, face, head, fps=ckpt.fps)
        for note in inputs.notes:
            typer.secho(f"warning: {note}", err=True, fg=typer.colors.YELLOW)
        skel = ckpt.skeleton
        timing_ms: list[float] = []
        mouth = None
        if face_out is not None and face is None:  # no face track: jaw and lips from the speech
            from facecapges.capture.speech_mouth import SpeechMouth

            mouth, spoken = SpeechMouth(ckpt.fps), []

        def blocks():
            for a, f, h in inputs.blocks():
                if mouth is not None:
                    spoken.extend(mouth.step(x) for x in a)
                yield a, f, h

        kept = []  # the poses, only when a .vrma is asked for
        with BvhWriter(out, skel, inputs.n_frames, ckpt.fps) as bvh:  # block by block: memory flat in length
            for poses in generate_blocks(ckpt, blocks(), inputs.n_frames, ckpt.fps, not json_out, timing_ms):
                bvh.write(pose_to_motion(skel, normalize_rot6d(poses)))
                if vrma is not None:
                    kept.append(normalize_rot6d(poses))
        if face_out is not None:
            from facecapges.io.face_json import write_face_json

            shown = inputs.face if mouth is None else np.stack(spoken).astype(np.float32)
            write_face_json(face_out, shown, ckpt.fps, inputs.head)
        if vrma is not None:
            from facecapges.avatar.vrma import write_pose_vrma

            write_pose_vrma(vrma, skel, np.concatenate(kept), ckpt.fps, inputs.face if face else None, vrma_face)
            typer.echo(f"wrote {vrma} (VRM Animation)", err=json_out)
        ms, n = timing_ms[0], inputs.n_frames
        summary = {
            "out": str(out),
            "frames": int(n),
            "fps": ckpt.fps,
            "duration_s": round(n / ckpt.fps, 3),
            "ms_per_frame": round(ms, 3),
            "checkpoint": str(ckpt.path),
            "warnings": inputs.notes,
        }
        if json_out:
            typer.echo(json.dumps(summary))
        else:
            typer.echo(
                f"wrote {out}: {summary['frames']} frames at {ckpt.fps} fps "
                f"({summary['duration_s']} s), {ms:.2f} ms/frame"
            )

    styles_app = typer.Typer(
        help="The installed speaking styles (per-speaker models): list, install.",
        invoke_without_command=True,
        no_args_is_help=False,
    )
    app.add_typer(styles_app, name="styles")

    def _list(json_out: bool) -> None:
        from facecapges.model.checkpoint import DEFAULT_STYLE, list_styles, load_checkpoint, styles_dir

        rows = []
        for name, path in list_styles().items():
            meta = load_checkpoint(path).meta
            rows.append(
                {
                    "name": name,
                    "default": name == DEFAULT_STYLE,
                    "speaker": meta.get("speaker"),
                    "epochs": meta.get("epochs_trained"),
                    "inputs": meta.get("inputs"),
                    "shipped": path.parent == styles_dir(),
                    "path": str(path),
                }
            )
        if json_out:
            typer.echo(json.dumps(rows, indent=2))
            return
        if not rows:
            typer.echo("no styles installed")
        for r in rows:
            typer.echo(
                f"{'*' if r['default'] else ' '} {r['name']}  speaker {r['speaker']}  "
                f"{r['epochs']} epochs  {'shipped' if r['shipped'] else 'user'}  {r['path']}"
            )

    @styles_app.callback()
    def styles(ctx: typer.Context, json_out: bool = typer.Option(False, "--json", help="Print JSON.")) -> None:
        """List the installed speaking styles (per-speaker checkpoints); `styles install RUN` adds one."""
        if ctx.invoked_subcommand is None:
            _list(json_out)

    @styles_app.command("list")
    def styles_list(json_out: bool = typer.Option(False, "--json", help="Print JSON.")) -> None:
        """List the installed styles: shipped ones and the user's own."""
        _list(json_out)

    @styles_app.command("install")
    def styles_install(
        run: Path = typer.Argument(..., help="A training run folder (its model.safetensors) or a .safetensors file."),
        name: str | None = typer.Option(None, help="Style name for --style (default: the run folder's name)."),
        force: bool = typer.Option(False, "--force", help="Replace an installed user style of that name."),
    ) -> None:
        """Install a trained model as a style: `--style NAME` then finds it (the package is not touched).

        Styles go to $FACECAPGES_STYLES, else $XDG_DATA_HOME/facecapges/styles
        (default ~/.local/share/facecapges/styles).
        """
        from facecapges.model.checkpoint import install_style

        dest = install_style(run, name, force)
        typer.echo(f"installed style {dest.stem!r}: {dest}  (use it with --style {dest.stem})")
