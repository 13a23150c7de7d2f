"""The options several commands share, each declared once with its help text.

A command takes one as ``name: Annotated[TYPE, OPTION] = DEFAULT`` (typer copies the option
object, so one object serves every command); its default is the options dataclass field's
where the command has one. Options of one command only are declared at that command.
"""

from __future__ import annotations

import typer

CACHE = typer.Option("--cache", help="A cache written by `facecapges prepare`.")
STYLE = typer.Option("--style", help="Installed speaking style (see `facecapges styles`); default: the default style.")
STYLE_NAME = typer.Option("--style", help="Installed style name (see `facecapges styles`).")
CHECKPOINT = typer.Option("--checkpoint", help="NetworkStyle file of a speaking style (instead of --style).")
INTENSITY = typer.Option(
    "--intensity",
    help="Gesture intensity: 0 (rest / idle only) … 1 (as the style moves) … 1.3 (larger than recorded); "
    "the viewer has a slider for it.",
)
HEAD = typer.Option(
    "--head",
    help="What the avatar's head shows: capture (the person's head; the model's when the face is lost), "
    "model (the gesture model's neck) or blend (half-way).",
)
FACE_JSON = typer.Option(
    "--face-json",
    help="face.json layout: beat (BEAT's: 51 weights at 60 fps) or full (52 weights at the model rate).",
)
FACES_HELP = "Faces to follow, each with its own avatar (1-8; files, VMC ports and viewer avatars per face)."
ESTIMATOR = typer.Option("--estimator", help="Face capture estimator: geometric, mediapipe or hybrid.")
LANDMARK_MODEL = typer.Option("--model", help="A face_landmarker.task to use instead of the bundled one.")
OFFSETS = typer.Option("--offsets", help="BeatAlign control: audio shifts in s (START:STOP:STEP or list).")
QUIET = typer.Option("--quiet", help="No progress bars.")
QUIET_BAR = typer.Option("--quiet", help="No progress bar.")  # the commands with one bar
FORCE_OUT = typer.Option("--force", help="Overwrite --out if it exists.")
JSON = typer.Option("--json", help="Print JSON.")
