"""Serving benchmark (``facecapges bench --only serve``): ``streams_at_15fps``.

The largest number of simulated concurrent clients (:mod:`.loadgen`: real speech
frames, one ``input`` per frame at 15 fps each, random phases) on loopback
(127.0.0.1 only) for which every frame comes back and the round trip of the frames
at p99 is within :data:`P99_LIMIT_MS` (50 ms, issue 36's bound, as ``bench --only cluster``'s; until
2026-12-03 it was one frame period, 66.7 ms: older figures count against that), against ``facecapges serve``
run as its own process with the default style (or ``FACECAPGES_BENCH_CHECKPOINT``).

Search: trials of N clients for ``seconds`` (5 s) each (the first second of every
client is warm-up and not measured) with N = 40, 80, 160, … doubling until a trial
fails, then bisection between the last pass and the first fail down to a step of
``max(2, 5 %)``. Every trial is listed with p50/p99/max, lost frames and errors, and
reported on stderr as it ends. ``--quick`` runs one 2 s trial of 20 clients (a smoke
run: ``streams_at_15fps`` is then that trial's N if it passed, not a search result).
The clients run in the benchmark's process on the same machine, so they take CPU
from the server; the load average before and after is reported because the machine
is shared, and so is the CPU time per returned frame of the server process and of
the clients (from /proc and the process clock). ``streams_cpu_bound_estimate`` =
cores × 1000 / ((server + client ms per frame) × 15): how many streams those CPU
costs would fit on the idle machine — an estimate that ignores the GIL and
scheduling, shown beside the measured figure, never instead of it.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

from facecapges.benchmarks.runtime import stat_cpu
from facecapges.timing import MODEL_FPS

TARGET = 300  # concurrent real-time streams with p99 ≤ P99_LIMIT_MS (issue 36 part 2, on the quiet machine)
P99_LIMIT_MS = 50.0
SPEECH = "data/beat/2_scott_0_2_2.wav"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(
    port: int, checkpoint: str | None = None, threads: int = 1, extra: tuple[str, ...] = ()
) -> subprocess.Popen:
    """``facecapges serve`` on 127.0.0.1:port as a child process; returns once it is ready (its style loaded)."""
    cmd = [
        sys.executable,
        "-m",
        "facecapges",
        "serve",
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
        "--threads",
        str(threads),
        *extra,
    ]
    if checkpoint:
        cmd += ["--checkpoint", checkpoint]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stderr is not None  # both PIPE
    line = proc.stdout.readline()
    ready = proc.stdout.readline() if line.startswith("serving") else ""
    if not ready.startswith("ready"):
        proc.kill()
        raise RuntimeError(f"serve did not start: {line}{ready}{proc.stderr.read()[-2000:]}")
    return proc


def stop_server(proc: subprocess.Popen) -> str:
    """Stop ``serve`` as Ctrl-C does and return its summary line. SIGTERM, not SIGINT: the command line
    turns both into the same clean stop, but a bench started in the background of a script hands its
    children SIGINT *ignored* (they would never see it and be killed 20 s later without a summary)."""
    import signal

    proc.send_signal(signal.SIGTERM)
    try:
        out, _ = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return out.strip().splitlines()[-1] if out.strip() else ""


def proc_cpu_s(pid: int) -> float:
    """User + system CPU seconds so far of a process and its live children (the server's
    model process), from Linux /proc."""
    total = 0.0
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields, cpu = stat_cpu(stat)
        except OSError:
            continue
        if stat.parent.name == str(pid) or fields[1] == str(pid):  # fields[1]: the parent's pid
            total += cpu
    return total


def run(quick: bool, shared: Path, threads: int = 1) -> dict:
    from facecapges.errors import UserError
    from facecapges.io.audio import load_audio
    from facecapges.serving import loadgen

    seconds = 2.0 if quick else 5.0
    period_ms = 1000.0 / 15
    wav = Path(shared) / SPEECH
    if not wav.is_file():
        raise UserError(f"{wav}: the serving benchmark needs this shared speech clip")
    audio = load_audio(wav)
    messages = loadgen.input_messages(audio, int(seconds * 15) + 15)
    load_before = [round(x, 2) for x in os.getloadavg()]
    port = free_port()
    proc = start_server(
        port,
        os.environ.get("FACECAPGES_BENCH_CHECKPOINT") or None,
        threads,
        ("--max-streams", "2048", "--max-per-address", "2048", "--idle-timeout", "0"),
    )
    url = f"ws://127.0.0.1:{port}/"
    trials: list[dict] = []

    def trial(n: int) -> bool:
        srv0, cli0 = proc_cpu_s(proc.pid), time.process_time()
        res = loadgen.run(loadgen.run_clients(url, n, seconds, messages, warmup_s=1.0, seed=n))
        srv_cpu, cli_cpu = proc_cpu_s(proc.pid) - srv0, time.process_time() - cli0
        s = loadgen.summarize(res, P99_LIMIT_MS)
        s["load_average"] = round(os.getloadavg()[0], 2)
        frames = max(1, s["frames_returned"])
        s["server_cpu_ms_per_frame"] = round(1e3 * srv_cpu / frames, 3)
        s["client_cpu_ms_per_frame"] = round(1e3 * cli_cpu / frames, 3)
        trials.append(s)
        print(
            f"bench: serve {n} clients: p99 {s.get('p99_ms')} ms, lost {s['lost']}, errors {s['errors']}, "
            f"load {s['load_average']} → {'pass' if s['ok'] else 'fail'}",
            file=sys.stderr,
            flush=True,
        )
        time.sleep(0.5)  # let the server drop the finished streams
        return s["ok"]

    try:
        # no uncounted warm-up: the model process runs one tick before ``ready:`` (model_process.warm_engine)
        best, fail, n = 0, None, 20 if quick else 40
        while n <= 1024:
            if trial(n):
                best, n = n, n * 2
            else:
                fail = n
                break
            if quick:
                break
        while not quick and fail is not None and fail - best > max(2, int(0.05 * fail)):
            mid = (best + fail) // 2
            if trial(mid):
                best = mid
            else:
                fail = mid
    finally:
        served = stop_server(proc)
    at_best = next((t for t in trials if t["clients"] == best and t["ok"]), {})
    # CPU cost of one stream-frame in the largest passing trial (or the first trial): what
    # the two cores could carry if nothing else ran — an estimate, not a measurement
    ref = at_best or trials[0]
    per_frame = ref["server_cpu_ms_per_frame"] + ref["client_cpu_ms_per_frame"]
    return {
        "streams_at_15fps": best,
        "target": TARGET,
        "meets_target": best >= TARGET,
        "period_ms": round(period_ms, 2),
        "p99_limit_ms": P99_LIMIT_MS,
        "p99_ms_at_best": at_best.get("p99_ms"),
        "p50_ms_at_best": at_best.get("p50_ms"),
        "seconds_per_trial": seconds,
        "server_threads": threads,
        "load_average_before": load_before,
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
        "cpu_count": os.cpu_count(),
        "niceness": os.nice(0),
        "server_cpu_ms_per_frame": ref["server_cpu_ms_per_frame"],
        "client_cpu_ms_per_frame": ref["client_cpu_ms_per_frame"],
        "streams_cpu_bound_estimate": int((os.cpu_count() or 1) * 1000.0 / (per_frame * MODEL_FPS)),
        "trials": trials,
        "server_summary": served,
    }
