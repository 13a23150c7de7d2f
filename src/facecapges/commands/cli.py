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


def _commands_with(group, opt: str, path: str = "") -> list[str]:
    """The (sub)commands of the click ``group`` that take option ``opt``, as "styles build"."""
    found = []
    for name, cmd in sorted(getattr(group, "commands", {}).items()):
        full = f"{path} {name}".strip()
        if any(opt in p.opts for p in cmd.params):
            found.append(full)
        found += _commands_with(cmd, opt, full)
    return found


def _better_option_suggestions() -> None:
    """An unknown option's "Possible options" only when the name is a near typo (click's difflib cut-off, 0.6,
    offered --vrma-face for --max-frames); an option another command has is named with that command."""
    from difflib import get_close_matches

    from typer._click import parser

    base = parser.NoSuchOption
    if getattr(base, "facecapges", False):  # main() ran before in this process
        return

    class NoSuchOption(base):  # type: ignore[misc, valid-type]
        facecapges = True

        def __init__(self, option_name, message=None, possibilities=None, ctx=None):
            near = get_close_matches(option_name.lstrip("-"), [p.lstrip("-") for p in possibilities or []], 3, 0.8)
            if message is None and ctx is not None:
                elsewhere = _commands_with(ctx.find_root().command, option_name)
                here = ctx.command_path.split(" ", 1)[-1]
                if elsewhere:
                    message = (
                        f"No such option: {option_name} ({here} has none; it is an option of {', '.join(elsewhere)})"
                    )
            super().__init__(option_name, message, [f"--{n}" for n in near], ctx)

    parser.NoSuchOption = NoSuchOption  # type: ignore[misc]


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt  # SIGTERM/SIGHUP end a command like Ctrl-C: its files are closed cleanly


def main() -> None:
    """Console entry point."""
    import signal

    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _interrupt)
    _better_option_suggestions()
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
