"""``facecapges bench``: the command over the runner in :mod:`facecapges.benchmarks`."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from facecapges.benchmarks import BENCHMARKS, check_shared, run_areas
from facecapges.errors import UserError

JSON_OUT = typer.Option("--json", help="Print one JSON document (default: a table).")
ONLY = typer.Option("--only", help=f"Comma-separated areas to run, of: {', '.join(BENCHMARKS)}.")
QUICK = typer.Option(help="Fewer repetitions (smoke run, about a minute).")
SHARED = typer.Option(
    "--shared", envvar="FACECAPGES_SHARED", help="The shared data folder (holds data/beat, data/face …)."
)


def bench(
    json_out: Annotated[bool, JSON_OUT] = False,
    only: Annotated[str, ONLY] = "",
    quick: Annotated[bool, QUICK] = False,
    shared: Annotated[Path, SHARED] = Path("../shared"),
) -> None:
    """Measure speed and memory of every stage and print the figures."""
    areas = [a.strip() for a in only.split(",") if a.strip()] or list(BENCHMARKS)
    unknown = [a for a in areas if a not in BENCHMARKS]
    if unknown:
        raise UserError(f"unknown benchmark area(s) {unknown}; known: {list(BENCHMARKS)}")
    check_shared(shared)
    result, ok = run_areas(areas, quick, shared.resolve())
    if json_out:
        print(json.dumps(result, indent=2, allow_nan=False))
    else:
        from rich.console import Console
        from rich.table import Table

        table = Table("area", "figure", "value")
        for area in areas:
            for k, v in result[area].items():
                table.add_row(area, k, json.dumps(v) if not isinstance(v, str) else v)
        Console().print(table)
    if not ok:
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    app.command()(bench)
