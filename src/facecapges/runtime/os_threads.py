"""OS-level names for ``live``'s own threads, so a profiler or ``/proc`` tells them apart.

Python (before 3.14) names its threads only for Python: the kernel sees every one of them as
``python``, beside MediaPipe's ``drishti`` and FFmpeg's ``av:h264:…`` threads, which name themselves.
:func:`name_os_thread` gives the calling thread its ``threading`` name in the kernel too
(``/proc/PID/task/TID/comm``, ``top -H``, ``py-spy``): ``bench --only live`` reads the CPU time of
each thread of ``live`` by these names (docs/performance.md).
"""

from __future__ import annotations

import ctypes
import functools
import sys

PR_SET_NAME = 15  # linux/prctl.h
MAX_NAME_BYTES = 15  # the kernel keeps 16 bytes with the NUL


@functools.cache
def _prctl():
    try:
        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):  # not glibc/musl: names stay Python's own
        return None


def name_os_thread(name: str) -> None:
    """Name the calling thread ``name`` (its first 15 bytes) for the OS; nothing happens off Linux."""
    if not sys.platform.startswith("linux"):
        return
    prctl = _prctl()
    if prctl is not None:
        prctl(PR_SET_NAME, ctypes.c_char_p(name.encode("utf-8", "replace")[:MAX_NAME_BYTES]), 0, 0, 0)
