"""``facecapges bench --quick --json`` over every area: a broken area fails CI.

One real run of the command as users run it (no timing is asserted: speed targets are
shown by the bench's figures, not by tests). The document must be strict JSON with
every area present and none failed, and progress must reach stderr. All areas but ``cluster``:
tests/test_serve_ray.py runs that one (``benchmarks.cluster.run``, with its failover asserted) in the
serial pass, so the suite starts one two-node Ray cluster (~40 s of start-up), not two.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from facecapges.benchmarks import BENCHMARKS
from runtime_helpers import cli_process

AREAS = [a for a in BENCHMARKS if a != "cluster"]  # cluster: tests/test_serve_ray.py (module docs)
REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_quick_bench_runs_every_area(beat_bvh, beat_wav, unseen_wav, face_video):
    shared = beat_bvh.parents[2]  # ../shared (data/beat/<clip>.bvh)
    p = cli_process("bench", "--quick", "--json", "--only", ",".join(AREAS), "--shared", str(shared), timeout=900,
                    cwd=REPO)
    assert p.returncode == 0, p.stderr[-4000:]
    doc = json.loads(p.stdout)  # strict JSON: no NaN
    failed = {a: doc[a]["error"] for a in AREAS if "error" in doc.get(a, {"error": "missing"})}
    assert not failed
    assert set(doc["bench"]["area_wall_s"]) == set(AREAS)
    n = len(AREAS)
    assert f"[{n}/{n}]" in p.stderr and "done in" in p.stderr  # progress on stderr, JSON alone on stdout
    m = doc["model"]
    # the cached kernel computes what the naive loop computes: float32 rounding of the shipped network's rot6d (near-unit
    # columns: 1e-4 on each number turns a joint by ≤ √3·1e-4 rad ≈ 0.01°, the suite's bound for two paths to one pose)
    assert m["max_abs_diff_naive"] < 1e-4
    assert m["step_with_euler_ms_p50"] >= m["step_ms_p50"] > 0
    assert doc["serve"]["trials"] and doc["serve"]["trials"][0]["frames_returned"] > 0
    assert {"main", "viewer-server", "upsample"} <= set(doc["live"]["cpu_by_thread"])  # live's threads, by name
    # the second reference (decoding + the landmarker) is the larger floor, so its ratio is the smaller
    assert doc["live"]["landmarker"]["decode_cpu_ms_per_frame"] > 0
    assert 0 < doc["live"]["cpu_ratio_to_decode_and_landmarker"] < doc["live"]["cpu_ratio_to_landmarker"]


def test_bench_live_sums_cpu_per_thread_name():
    """``bench --only live``'s ``cpu_by_thread``: each thread's CPU over the window, threads of one name summed
    (FFmpeg's ``av:…`` as one), the process's first thread as ``main``, a thread born meanwhile counted from 0."""
    from facecapges.benchmarks.live import FPS, _cpu_by_thread

    before = {10: ("main", 1.0), 11: ("drishti", 2.0), 12: ("drishti", 0.5), 13: ("av:h264:df0", 0.1)}
    after = {10: ("main", 1.6), 11: ("drishti", 2.5), 12: ("drishti", 1.0), 13: ("av:h264:df0", 0.2),
             14: ("av:h264:df1", 0.1)}
    got = _cpu_by_thread(before, after, 2.0)
    assert list(got) == ["drishti", "main", "av:"]  # most CPU first
    assert got["drishti"] == {"threads": 2, "share_of_core": 0.5, "ms_per_frame": round(1000.0 / 2.0 / FPS, 2)}
    assert got["main"]["share_of_core"] == 0.3 and got["av:"]["threads"] == 2 and got["av:"]["share_of_core"] == 0.1


def test_bench_table_is_one_short_value_per_row():
    """`bench`'s table (not --json) puts every figure on its own row with a short value: nested objects as
    dotted names, not JSON wrapped into a 30-character column."""
    from rich.console import Console

    from facecapges.commands.bench import figure_rows, figure_table

    result = {"model": {"step_ms": {"p50": 0.8412345, "p99": 1.52, "cpu": True},
                        "naive": {"p50_ms": 4.02, "ratio": 6.08},
                        "trials": [{"streams": 40, "p99_ms": 58.0}, {"streams": 20, "p99_ms": 40.1}],
                        "batch_sizes": [1, 16, 64], "note": "ok"}}
    rows = dict(figure_rows(result["model"]))
    assert rows["step_ms.p50"] == "0.8412" and rows["trials[1].p99_ms"] == "40.1"
    assert rows["batch_sizes"] == "[1, 16, 64]" and rows["step_ms.cpu"] == "true"
    console = Console(width=100, record=True, color_system=None)
    console.print(figure_table(result, ["model"]))
    text = console.export_text()
    assert "{" not in text and '"' not in text, text
    assert "step_ms.p99" in text and "1.52" in text
