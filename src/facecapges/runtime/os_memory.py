"""``live``'s resident memory: glibc's malloc told what a long-running process of many threads needs.

``live`` runs MediaPipe's graph threads (``drishti``: three graphs with ``--body``), FFmpeg's, the 30 Hz ticks,
the viewer's server and the scheduler; glibc gives each thread that allocates at the same time as another an
arena of its own (up to 8 per core), and keeps what a thread freed inside that arena for its next allocation.
Two things follow, measured on ``live --body`` (issue 36: resident memory ≤ 500 MB; docs/performance.md):

* :func:`limit_malloc_arenas` (``mallopt(M_ARENA_MAX, 2)``, what ``MALLOC_ARENA_MAX=2`` sets): the threads share
  two arenas — about 11 MB less resident after the start;
* :func:`release_free_memory` (``malloc_trim(0)``) once the start-up is over: the heap the start freed (the
  style's and the models' loading, the avatar's build for the viewer) goes back to the OS — about 13 MB.

Both are glibc's; elsewhere (macOS, musl) they do nothing and return False.
"""

from __future__ import annotations

import ctypes
import functools
import sys

M_ARENA_MAX = -8  # malloc.h
ARENAS = 2


@functools.cache
def _glibc():
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(None)
        return libc if hasattr(libc, "mallopt") and hasattr(libc, "malloc_trim") else None
    except OSError:
        return None


def limit_malloc_arenas(arenas: int = ARENAS) -> bool:
    """At most ``arenas`` malloc arenas for the threads started from now on (module docstring)."""
    libc = _glibc()
    return bool(libc is not None and libc.mallopt(M_ARENA_MAX, int(arenas)) == 1)


def release_free_memory() -> bool:
    """Give the heap's free pages back to the OS (module docstring); True if glibc released any."""
    libc = _glibc()
    return bool(libc is not None and libc.malloc_trim(0) == 1)
