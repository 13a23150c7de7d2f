"""``facecapges bench``: the command over the runner in :mod:`facecapges.benchmarks`."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from facecapges.benchmarks import BENCHMARKS, check_shared, run_areas
from facecapges.errors import UserError


def bench(
    json_out: bool = typer.Option(False, "--json", help="Print one JSON document (default: a table)."),
    only: str = typer.Option("", help=f"Comma-separated areas to run, of: {', '.join(BENCHMARKS)}."),
    quick: bool = typer.Option(False, help="Fewer repetitions (smoke run, about a minute)."),
    shared: Path = typer.Option(
        Path("../shared"),
        "--shared",
        envvar="FACECAPGES_SHARED",
        help="The shared data folder (holds data/beat, data/face …).",
    ),
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
