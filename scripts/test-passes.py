"""``make test``'s two pytest passes side by side (docs/testing.md, "How long it takes").

The tests marked ``serial`` assert a delivered rate or a wall-clock bound, so nothing may take the CPU from them;
they wait on real time most of their 3 minutes (a fifth of a core on average), and before this script the other
core idled for all of it. Now the parallel pass (``pytest -n 2 -m "not serial"``) starts with them, under the
kernel's ``SCHED_IDLE`` policy (``sched(7)``; its children inherit it): its processes run only on CPU time the
serial tests leave unused, and a serial test that wakes takes its core back at once. When the serial pass ends,
every process and thread of the parallel pass is set back to the normal policy (else, on a machine with other
work, it would keep running only in that work's idle time): best effort, as a user without ``CAP_SYS_NICE`` may
not leave ``SCHED_IDLE``; on an otherwise idle machine it makes no difference.

The parallel pass prints its progress as it goes; the serial pass's output is kept and printed after it. The exit
status is non-zero when either pass failed. ``--fast`` runs ``make test-fast``'s selection (not ``slow``); other
arguments go to the parallel pass's pytest (``--durations=50``, say).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def serial_files() -> list[str]:
    """The test files holding a ``serial`` test: the serial pass collects only those."""
    files = (REPO / "tests").glob("test_*.py")
    return sorted(str(p.relative_to(REPO)) for p in files if "mark.serial" in p.read_text())


def _idle() -> None:
    os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))


def _tree(root: int) -> set[int]:
    """``root`` and its descendants."""
    parent: dict[int, int] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                parent[int(d.name)] = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
    out, new = {root}, {root}
    while new:
        new = {pid for pid, ppid in parent.items() if ppid in new} - out
        out |= new
    return out


def back_to_normal(root: int) -> int:
    """Every thread of ``root``'s tree that is still ``SCHED_IDLE`` set to ``SCHED_OTHER``; twice over, for the
    processes forked while the first walk ran. The number of threads changed."""
    changed = 0
    for _ in range(2):
        for pid in _tree(root):
            try:
                tids = [int(t.name) for t in Path(f"/proc/{pid}/task").iterdir()]
            except OSError:
                continue
            for tid in tids:
                try:
                    if os.sched_getscheduler(tid) == os.SCHED_IDLE:
                        os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
                        changed += 1
                except OSError:  # gone, or not permitted (no CAP_SYS_NICE): it keeps the idle policy
                    pass
    return changed


def _minutes(s: float) -> str:
    return f"{int(s // 60)} min {s % 60:.0f} s"


def main(argv: list[str]) -> int:
    fast = "--fast" in argv
    extra = [a for a in argv if a != "--fast"]
    pytest = [sys.executable, "-m", "pytest", "-q"]
    parallel = [*pytest, "-n", "2", "--dist", "worksteal", "-m", "not slow and not serial" if fast else "not serial"]
    parallel += [f"--durations={10 if fast else 15}", *extra]
    # its own cache folder: the two sessions would each write the other's --lf list over
    serial = [*pytest, "-m", "serial and not slow" if fast else "serial", "--durations=5"]
    serial += ["-o", "cache_dir=.pytest_cache/serial", *serial_files()]
    t0 = time.monotonic()
    if not hasattr(os, "SCHED_IDLE"):  # Linux's: elsewhere one pass after the other, as before
        return subprocess.run(parallel, cwd=REPO).returncode or subprocess.run(serial, cwd=REPO).returncode
    par = subprocess.Popen(parallel, cwd=REPO, preexec_fn=_idle)  # Ctrl-C reaches both: one process group
    with tempfile.TemporaryFile("w+") as log:
        ser = subprocess.run(serial, cwd=REPO, stdout=log, stderr=subprocess.STDOUT)
        t_serial = time.monotonic() - t0
        changed = back_to_normal(par.pid)
        par_code = par.wait()
        t_parallel = time.monotonic() - t0
        log.seek(0)
        head = f"the serial pass (beside the parallel one, SCHED_IDLE until then; {changed} threads set back to normal)"
        print(f"\n---- {head} ----", flush=True)
        sys.stdout.write(log.read())
    took = f"the serial pass {_minutes(t_serial)} (exit {ser.returncode})"
    print(f"\n{took}, the parallel pass {_minutes(t_parallel)} (exit {par_code}), from the same start", flush=True)
    return 1 if ser.returncode or par_code else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
