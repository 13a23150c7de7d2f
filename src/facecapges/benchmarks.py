"""``facecapges bench``: every area's benchmark, one JSON document.

Speed and memory targets are shown here, never by timed unit tests. Each area has a
``bench.py`` with ``run(quick: bool) -> dict``; its results appear under the area's
key. Areas are listed in ``BENCHMARKS`` (module path of each ``run``).
"""

from __future__ import annotations

import importlib
import json
import math
import platform
import time

import typer

BENCHMARKS: dict[str, str] = {
    "capture": "facecapges.capture.bench",
    "data": "facecapges.data.bench",
    "evaluation": "facecapges.evaluation.bench",
    "model": "facecapges.model.bench",
    "render": "facecapges.avatar.bench",
    "study": "facecapges.study.bench",
    "runtime": "facecapges.runtime.bench",
    "serve": "facecapges.serving.bench",
    "vrm": "facecapges.avatar.vrm_bench",
}


def _finite_or_null(x):
    """NaN/inf (e.g. a correlation over a stretch without blinks) become null: strict JSON."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _finite_or_null(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite_or_null(v) for v in x]
    return x


def register(app: typer.Typer) -> None:
    @app.command()
    def bench(
        json_out: bool = typer.Option(False, "--json", help="Print one JSON document (default: a table)."),
        only: str = typer.Option("", help=f"Comma-separated areas to run, of: {', '.join(BENCHMARKS)}."),
        quick: bool = typer.Option(False, help="Fewer repetitions (smoke run)."),
    ) -> None:
        """Measure speed and memory of every stage and print the figures."""
        from facecapges.errors import UserError

        areas = [a.strip() for a in only.split(",") if a.strip()] or list(BENCHMARKS)
        unknown = [a for a in areas if a not in BENCHMARKS]
        if unknown:
            raise UserError(f"unknown benchmark area(s) {unknown}; known: {list(BENCHMARKS)}")
        import torch

        result: dict = {"machine": {"cpu_count": __import__("os").cpu_count(), "python": platform.python_version(),
                                    "torch": torch.__version__, "time": time.strftime("%Y-%m-%dT%H:%M:%S")}}
        for area in areas:
            result[area] = importlib.import_module(BENCHMARKS[area]).run(quick=quick)
        result = _finite_or_null(result)
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
