"""Commands of the model area: ``generate``, ``styles`` (``train`` is in :mod:`facecapges.commands.training`)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from facecapges.commands.params import JSON, STYLE_NAME
from facecapges.runtime.generate import GenerateOptions


def _check_extensions(out: Path, vrma: Path | None) -> None:
    """An output's format follows its name: ``--out`` is a BVH, ``--vrma`` a VRM Animation; any other suffix is refused."""
    from facecapges.errors import UserError

    if out.suffix and out.suffix.lower() != ".bvh":
        hint = f" --vrma {out.name}" if out.suffix.lower() == ".vrma" else ""
        raise UserError(
            f"--out {out}: generate writes BVH motion there, so it must end in .bvh "
            f"(e.g. --out {out.with_suffix('.bvh').name}{hint})"
        )
    if vrma is not None and vrma.suffix.lower() != ".vrma":
        raise UserError(
            f"--vrma {vrma}: VRM Animation files end in .vrma (e.g. --vrma {vrma.with_suffix('.vrma').name})"
        )


AUDIO = typer.Option("--audio", help="Speech audio (any format soundfile/ffmpeg reads; resampled to 16 kHz).")
GENERATE_OUT = typer.Option("--out", help="Output BVH file, .bvh (full BEAT skeleton, model fps).")
FACE = typer.Option("--face", help="BEAT-format face JSON, any fps (resampled).")
HEAD = typer.Option("--head", help="Head rotation .npy (T, 6) rot6d at the model fps.")
CHECKPOINT = typer.Option("--checkpoint", help="NetworkStyle file (default: the installed default style).")
INTENSITY = typer.Option(
    "--intensity",
    help="Gesture intensity: 0 (rest / idle only) … 1 (as the style moves) … 1.3 (larger than recorded).",
)
FACE_OUT = typer.Option(
    "--face-out",
    help="Also write the face to show with the motion (face JSON): --face resampled, or without --face, "
    "jaw and lips from the speech.",
)
JSON_OUT = typer.Option("--json", help="Print a JSON summary instead of text.")
VRMA = typer.Option(
    "--vrma",
    help="Also write the gestures and the face (--face, else jaw and lips from the speech) as VRM Animation "
    "(.vrma) for any VRM avatar.",
)
VRMA_FACE = typer.Option(
    "--vrma-face",
    help="Face in the .vrma: presets (VRM presets from ARKit, any VRM) or perfect-sync (52 ARKit).",
)
GENERATE_FORCE = typer.Option("--force", help="Overwrite OUT if it exists.")


def generate(
    audio: Annotated[Path, AUDIO],
    out: Annotated[Path, GENERATE_OUT],
    face: Annotated[Path | None, FACE] = None,
    head: Annotated[Path | None, HEAD] = None,
    checkpoint: Annotated[Path | None, CHECKPOINT] = None,
    style: Annotated[str | None, STYLE_NAME] = None,
    intensity: Annotated[float, INTENSITY] = GenerateOptions.intensity,
    face_out: Annotated[Path | None, FACE_OUT] = None,
    json_out: Annotated[bool, JSON_OUT] = GenerateOptions.json_out,
    vrma: Annotated[Path | None, VRMA] = None,
    vrma_face: Annotated[str, VRMA_FACE] = GenerateOptions.vrma_face,
    force: Annotated[bool, GENERATE_FORCE] = GenerateOptions.force,
) -> None:
    """Generate upper-body gestures for a recording, frame by frame, no look-ahead."""
    options = GenerateOptions(**locals())  # before any other name is bound here
    _check_extensions(out, vrma)
    from facecapges.runtime.generate import generate_recording

    generate_recording(options, say=typer.echo)


def _list(json_out: bool) -> None:
    from facecapges.errors import UserError
    from facecapges.styles import DEFAULT_STYLE, list_styles, load_style, styles_dir

    rows = []
    for name, path in list_styles().items():
        row = {"name": name, "default": name == DEFAULT_STYLE, "shipped": path.parent == styles_dir()}
        try:
            ckpt = load_style(path)
        except UserError as exc:  # a broken file is marked; the others are still listed
            rows.append(
                {
                    **row,
                    "engine": None,
                    "speaker": None,
                    "epochs": None,
                    "inputs": None,
                    "path": str(path),
                    "error": str(exc).removeprefix(f"{path}: "),
                }
            )
            continue
        meta = ckpt.meta
        rows.append(
            {
                **row,
                "engine": ckpt.engine,
                "speaker": meta.get("speaker"),
                "takes": ", ".join(str(t.get("source") or t.get("name")) for t in meta.get("takes") or []) or None,
                "epochs": meta.get("epochs_trained"),
                "inputs": meta.get("inputs"),
                "path": str(path),
                "error": None,
            }
        )
    if json_out:
        typer.echo(json.dumps(rows, indent=2))
        return
    if not rows:
        typer.echo("no styles installed")
    for r in rows:
        if r["error"] is not None:
            typer.echo(f"! {r['name']}  broken: {r['error']}  {r['path']}")
            continue
        who = f"speaker {r['speaker']}" if r["speaker"] is not None else f"from {r['takes'] or 'unnamed takes'}"
        typer.echo(
            f"{'*' if r['default'] else ' '} {r['name']}  {r['engine']}  {who}  "
            + (f"{r['epochs']} epochs  " if r["engine"] == "network" else "")
            + f"{'shipped' if r['shipped'] else 'user'}  {r['path']}"
        )


def styles(ctx: typer.Context, json_out: Annotated[bool, JSON] = False) -> None:
    """List the installed speaking styles (per-speaker checkpoints); `styles install RUN` adds one."""
    if ctx.invoked_subcommand is None:
        _list(json_out)


def styles_list(json_out: Annotated[bool, JSON] = False) -> None:
    """List the installed styles: shipped ones and the user's own."""
    _list(json_out)


RUN = typer.Argument(help="A training run folder (its model.safetensors) or a .safetensors file.")
STYLES_INSTALL_NAME = typer.Option("--name", help="Style name for --style (default: the run folder's name).")
STYLES_INSTALL_FORCE = typer.Option("--force", help="Replace an installed user style of that name.")


def styles_install(
    run: Annotated[Path, RUN],
    name: Annotated[str | None, STYLES_INSTALL_NAME] = None,
    force: Annotated[bool, STYLES_INSTALL_FORCE] = False,
) -> None:
    """Install a trained model as a style: `--style NAME` then finds it (the package is not touched).

    Styles go to $FACECAPGES_STYLES, else $XDG_DATA_HOME/facecapges/styles
    (default ~/.local/share/facecapges/styles).
    """
    from facecapges.styles import install_style

    dest = install_style(run, name, force)
    typer.echo(f"installed style {dest.stem!r}: {dest}  (use it with --style {dest.stem})")


STYLES_BUILD_NAME = typer.Argument(help="The style's name (letters, digits, '.', '_', '-').")
TAKE = typer.Option(
    "--take",
    help="MOTION WAV: a paired take (BEAT BVH, BEAT2 .npz, or another skeleton's BVH, retargeted). Repeat.",
    metavar="MOTION WAV",
)
WAV = typer.Argument(hidden=True)
VIDEO_TAKE = typer.Option(
    "--video",
    help="A video of you talking (upper body and hands in view): capture-body gives the motion, its "
    "soundtrack the speech. Repeat.",
)
STYLES_BUILD_OUT = typer.Option("--out", help="Write the style here instead of installing it.")
STYLES_BUILD_FORCE = typer.Option("--force", help="Replace an existing style file of that name.")
SEED = typer.Option("--seed", help="Seed of the speech predictor's training.")
STEPS = typer.Option(
    "--steps",
    help="At most this many training steps of the speech predictor (default 800; fewer: a quick trial).",
)


def styles_build(
    name: Annotated[str, STYLES_BUILD_NAME],
    take: Annotated[list[str] | None, TAKE] = None,
    wav: Annotated[list[str] | None, WAV] = None,
    video: Annotated[list[Path] | None, VIDEO_TAKE] = None,
    out: Annotated[Path | None, STYLES_BUILD_OUT] = None,
    force: Annotated[bool, STYLES_BUILD_FORCE] = False,
    seed: Annotated[int, SEED] = 0,
    steps: Annotated[int | None, STEPS] = None,
) -> None:
    """Build a motion-matching style from paired takes (motion + speech): database + speech predictor.

    Each take's last 20 % is held out (never read). The style is installed into the user styles
    folder (or written to --out) with a model card NAME.md; use it with --style NAME.
    """
    from facecapges.errors import UserError
    from facecapges.styles import build_matching_style

    pairs = _take_pairs(take or [], wav or [])
    if not pairs and not video:
        raise UserError("give at least one --take MOTION WAV or --video VIDEO")
    if not video:
        build_matching_style(name, pairs, out=out, force=force, seed=seed, say=typer.echo, predictor_steps=steps)
        return
    import tempfile

    with tempfile.TemporaryDirectory(prefix="facecapges-video-takes-") as tmp:
        captured, seen = _video_takes(video, Path(tmp))
        build_matching_style(
            name, pairs + captured, out=out, force=force, seed=seed, say=typer.echo, predictor_steps=steps, seen=seen
        )


def _video_takes(videos: list[Path], tmp: Path) -> tuple[list[tuple[Path, Path]], dict[str, dict]]:
    """capture-body of each video into ``tmp``: (its BVH, the video itself as the speech) pairs, and per BVH
    name how well its motion was seen (for the model card)."""
    from facecapges.capture.body import capture_body, seen_report
    from facecapges.capture.body_models import HAND_TASK, POSE_TASK, model_path
    from facecapges.io.audio import check_audio
    from facecapges.styles import DEFAULT_STYLE, load_style

    model_path(POSE_TASK), model_path(HAND_TASK)
    for v in videos:
        check_audio(v)  # a video without a soundtrack fails before any capture
    skeleton = load_style(style=DEFAULT_STYLE).skeleton
    pairs = []
    seen = {}
    for k, v in enumerate(videos):
        (tmp / str(k)).mkdir()
        bvh = tmp / str(k) / f"{v.name[:150]}.capture-body.bvh"  # the model card names the video

        def progress(i: int, n: int | None, v: Path = v) -> None:
            if i % 150 == 0 or i == n:
                typer.echo(f"  capture-body {v.name}: {i}/{n if n is not None else '?'} frames")

        _, s = capture_body(v, bvh, skeleton, progress=progress, for_style=True)  # smoothed for a database
        typer.echo(
            f"  {v.name}: person found in {s['pose_found']:.0%} of {s['frames']} frames, both hands in "
            f"{s['both_hands_found']:.0%}, mean arm confidence {s['arm_confidence']:.2f}"
        )
        warning = s["warning"]
        if warning:
            typer.echo(f"  warning: {warning}")
        pairs.append((bvh, v))
        seen[bvh.name] = seen_report(v, s)
    return pairs, seen


def _take_pairs(take: list[str], rest: list[str]) -> list[tuple[Path, Path]]:
    """`--take MOTION WAV` pairs: typer reads one value per --take; each WAV follows as an extra argument."""
    from facecapges.errors import UserError

    if len(rest) != len(take):
        raise UserError("each --take needs two paths: --take MOTION WAV (motion file, then its .wav)")
    return [(Path(m), Path(w)) for m, w in zip(take, rest, strict=True)]


def register(app: typer.Typer) -> None:
    app.command()(generate)
    styles_app = typer.Typer(
        help="The installed speaking styles (per-speaker models, either engine): list, install, build.",
        invoke_without_command=True,
        no_args_is_help=False,
    )
    app.add_typer(styles_app, name="styles")
    styles_app.callback()(styles)
    styles_app.command("list")(styles_list)
    styles_app.command("install")(styles_install)
    styles_app.command("build")(styles_build)
