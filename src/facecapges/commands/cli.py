"""The ``facecapges`` command line.

Each command group has its own module in this package with a ``register(app)``
function; this file only assembles them and turns
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
    "facecapges.commands.capture",  # capture, capture-eval
    "facecapges.commands.data",  # prepare, export
    "facecapges.commands.styles",  # generate, styles
    "facecapges.commands.training",  # train
    "facecapges.commands.avatar",  # blendshapes, avatar build, render
    "facecapges.commands.evaluation",  # fgd-train, eval
    "facecapges.commands.runtime",  # run, live
    "facecapges.commands.serving",  # serve
    "facecapges.commands.study",  # study create/serve/analyze
    "facecapges.commands.demo",  # demo
    "facecapges.commands.bench",  # bench
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
