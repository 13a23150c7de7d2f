"""The command line: :mod:`.cli` assembles one module per command group.

Each module declares its commands as module-level functions and has a ``register(app)``
that adds them to the typer app. Every option is declared once, as a typer
``Annotated[TYPE, OPTION]`` parameter whose ``OPTION`` object (name and help text) sits at
module level; the options several commands share are in :mod:`.params`. A command with an
options dataclass (``RunOptions``, ``EvalOptions`` …) takes its defaults from the class and
passes the object on. This is the one place with lazy imports (torch, mediapipe … inside the
commands so ``--help`` stays fast), and the library never imports it.
"""
