"""runtime/os_memory: glibc's malloc settings live uses (issue 36's memory)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from facecapges.runtime import os_memory


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc is Linux's")
def test_glibc_takes_the_arena_limit_and_the_trim():
    # in a child: the arena limit stays for the rest of the process, and must not change the test session's
    code = (
        "from facecapges.runtime import os_memory as m\n"
        "import numpy as np\n"
        "assert m.limit_malloc_arenas()\n"
        "blocks = [np.ones(1000) for _ in range(20000)]\n"
        "del blocks[::2]\n"
        "assert isinstance(m.release_free_memory(), bool)\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


def test_without_glibc_nothing_happens(monkeypatch):
    monkeypatch.setattr(os_memory, "_glibc", lambda: None)
    assert os_memory.limit_malloc_arenas() is False
    assert os_memory.release_free_memory() is False
