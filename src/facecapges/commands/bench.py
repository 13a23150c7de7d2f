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


def _value(v) -> str:
    """One figure as table text: floats to 4 significant digits, a list of numbers on one line."""
    if isinstance(v, bool) or v is None:
        return str(v).lower() if isinstance(v, bool) else "—"
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        shown = ", ".join(_value(x) for x in v[:8])
        return f"[{shown}{', …' if len(v) > 8 else ''}] ({len(v)})" if len(v) > 8 else f"[{shown}]"
    return str(v)


def figure_rows(figures: dict, prefix: str = "") -> list[tuple[str, str]]:
    """(figure, value) rows of one area's result: nested objects become dotted names (``step.p50_ms``) and
    lists of objects numbered ones (``trials[0].streams``), so every value is one short number or word."""
    rows: list[tuple[str, str]] = []
    for k, v in figures.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            rows += figure_rows(v, name + ".") if v else [(name, "{}")]
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for i, x in enumerate(v):
                rows += figure_rows(x, f"{name}[{i}].")
        else:
            rows.append((name, _value(v)))
    return rows


def figure_table(result: dict, areas: list[str]):
    """The rich table ``bench`` prints: one row per figure, the area named on its first row."""
    from rich.table import Table

    table = Table("area", "figure", "value")
    table.columns[1].overflow = "fold"
    table.columns[2].overflow = "fold"
    for area in areas:
        rows = figure_rows(result[area])
        for i, (name, value) in enumerate(rows):
            table.add_row(area if i == 0 else "", name, value, end_section=i == len(rows) - 1)
    return table


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

        Console().print(figure_table(result, areas))
    if not ok:
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    app.command()(bench)
