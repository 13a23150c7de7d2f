"""The benchmark runner behind ``facecapges bench``: every area's benchmark, one JSON document.

Speed and memory targets are shown here, never by timed unit tests. Each area has a
module in this package (``benchmarks/<area>.py``) with ``run(quick: bool, shared: Path) -> dict``;
its results appear under the area's key. Areas are listed in ``BENCHMARKS`` (module path of
each ``run``); the command itself is :mod:`facecapges.commands.bench`.
``shared`` is the folder of shared data (``../shared``: ``data/beat``, ``data/face``…),
given by the command (``--shared``), never looked up by the areas themselves.

Progress goes to stderr (one line as each area starts and ends, with its wall time
and the load average: the machine is shared). An area that fails does not stop the
others: its entry holds ``{"error": ...}``, the document is still printed, and the
command exits with status 1. ``bench`` in the document holds the wall time of each
area and of the whole run. Budget on this 2-core machine: the whole bench within
about 5 minutes, ``--quick`` (a smoke run of every area, run by the test suite)
within about 1 minute.
"""

from __future__ import annotations

import importlib
import math
import os
import platform
import sys
import time
import traceback
from pathlib import Path

from facecapges.errors import UserError

BENCHMARKS: dict[str, str] = {
    "capture": "facecapges.benchmarks.capture",
    "cluster": "facecapges.benchmarks.cluster",
    "data": "facecapges.benchmarks.data",
    "evaluation": "facecapges.benchmarks.evaluation",
    "model": "facecapges.benchmarks.model",
    "matching": "facecapges.benchmarks.matching",
    "render": "facecapges.benchmarks.render",
    "study": "facecapges.benchmarks.study",
    "runtime": "facecapges.benchmarks.runtime",
    "live": "facecapges.benchmarks.live",
    "serve": "facecapges.benchmarks.serving",
    "vrm": "facecapges.benchmarks.vrm",
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


def _log(msg: str) -> None:
    print(f"bench: {msg}", file=sys.stderr, flush=True)


SHARED_FILES = ("data/beat/2_scott_0_1_1.bvh", "data/beat/2_scott_0_1_1.wav", "data/face/WDA_KatieHill_000.mp4")


def check_shared(shared: Path) -> None:
    """UserError unless ``shared`` is a folder holding the shared clips the areas measure on."""
    if not shared.is_dir():
        raise UserError(f"{shared}: shared data folder not found (pass --shared PATH)")
    missing = [f for f in SHARED_FILES if not (shared / f).is_file()]
    if len(missing) == len(SHARED_FILES):
        raise UserError(f"{shared}: not the shared data folder (none of {', '.join(SHARED_FILES)}); pass --shared PATH")


def run_areas(areas: list[str], quick: bool, shared: Path) -> tuple[dict, bool]:
    """Run the areas in order; (result document, every area ran without error)."""
    import torch

    result: dict = {
        "machine": {
            "cpu_count": os.cpu_count(),
            "python": platform.python_version(),
            "torch": torch.__version__,
            "time": time.strftime("%Y-%m-%dT%H:%M:%S"),
            "load_average": [round(x, 2) for x in os.getloadavg()],
        }
    }
    walls: dict[str, float] = {}
    ok = True
    t_all = time.perf_counter()
    for n, area in enumerate(areas, 1):
        _log(f"[{n}/{len(areas)}] {area} … (load {os.getloadavg()[0]:.1f})")
        t0 = time.perf_counter()
        try:
            result[area] = importlib.import_module(BENCHMARKS[area]).run(quick=quick, shared=shared)
        except UserError as exc:  # the user's shared folder or options: one line, no traceback
            ok = False
            result[area] = {"error": str(exc)}
            _log(f"{area} FAILED: {exc}")
        except Exception as exc:  # noqa: BLE001  one broken area must not hide the others' figures
            ok = False
            result[area] = {"error": f"{exc.__class__.__name__}: {exc}"}
            _log(f"{area} FAILED: {exc.__class__.__name__}: {exc}")
            traceback.print_exc(file=sys.stderr)
        walls[area] = round(time.perf_counter() - t0, 1)
        _log(f"[{n}/{len(areas)}] {area} done in {walls[area]:.1f} s")
    total = round(time.perf_counter() - t_all, 1)
    result["bench"] = {
        "quick": quick,
        "wall_s": total,
        "area_wall_s": walls,
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
    }
    _log(f"all {len(areas)} area(s) in {total:.1f} s" + ("" if ok else " — some failed"))
    return _finite_or_null(result), ok
