"""``facecapges prepare`` and ``facecapges export``: BEAT files → cache → BVH."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    """Add the data commands to ``app``."""
