"""The ``facecapges`` command line.

Each area of the project keeps its commands in its own ``commands.py`` with a
``register(app)`` function; this file only assembles them and turns
:class:`~facecapges.errors.UserError` into one line on stderr and exit status 2.
Heavy libraries (torch, mediapipe) are imported inside the commands so ``--help``
stays fast.
"""

from __future__ import annotations

import importlib
import sys

import typer

from facecapges.errors import UserError

app = typer.Typer(
    name="facecapges",
    help="FaceCapGes: real-time co-speech gestures from face, head pose and speech.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

# The areas along the data path, in the order a user's frame meets them.
COMMAND_MODULES = [
    "facecapges.capture.commands",  # capture, capture-eval
    "facecapges.data.commands",  # prepare, export
    "facecapges.model.commands",  # generate, styles
    "facecapges.training.commands",  # train
    "facecapges.avatar.commands",  # blendshapes, avatar build, render
    "facecapges.evaluation.commands",  # fgd-train, eval
    "facecapges.runtime.commands",  # run, live
    "facecapges.serving.commands",  # serve
    "facecapges.study.commands",  # study create/serve/analyze
    "facecapges.demo",  # demo
    "facecapges.benchmarks",  # bench
]

for _name in COMMAND_MODULES:
    importlib.import_module(_name).register(app)


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt  # SIGTERM/SIGHUP end a command like Ctrl-C: its files are closed cleanly


def main() -> None:
    """Console entry point."""
    import signal

    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _interrupt)
    try:
        app()
    except UserError as exc:
        typer.secho(f"error: {exc}", err=True, fg=typer.colors.RED)
        sys.exit(2)
    except KeyboardInterrupt:
        typer.secho("interrupted", err=True)
        sys.exit(130)


if __name__ == "__main__":
    main()
