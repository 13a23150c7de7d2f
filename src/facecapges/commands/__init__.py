"""The command line: :mod:`.cli` assembles one module per command group.

Each module has a ``register(app)`` function adding its commands to the typer app. This is the
one place with lazy imports (torch, mediapipe … inside the commands so ``--help`` stays fast),
and the library never imports it.
"""
