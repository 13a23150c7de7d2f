"""Helpers shared by the runtime tests (not a test module).

The runtime tests use the installed default style (``load_checkpoint()``); when it is
missing they fail (nothing is skipped).
"""

from __future__ import annotations

import subprocess
import sys
from functools import lru_cache


@lru_cache(maxsize=1)
def checkpoint():
    from facecapges.model.checkpoint import load_checkpoint

    return load_checkpoint()


def cli(*args: str, timeout: float = 300, **kw) -> subprocess.CompletedProcess:
    """Run ``facecapges ARGS`` in a subprocess (real exit codes and stderr)."""
    return subprocess.run([sys.executable, "-m", "facecapges.cli", *args], capture_output=True, text=True,
                          timeout=timeout, **kw)


def cli_popen(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-u", "-m", "facecapges.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


def wait_line(proc: subprocess.Popen, prefix: str, timeout: float = 120.0) -> str | None:
    """The first stdout line of ``proc`` starting with ``prefix`` (None if it ends or ``timeout`` s pass first)."""
    import time

    deadline = time.time() + timeout
    while time.time() < deadline:
        line = proc.stdout.readline()
        if not line:
            return None
        if line.startswith(prefix):
            return line
    return None


def refused(p: subprocess.CompletedProcess, *words: str) -> None:
    """Assert a command failed the way a user should see it: exit 2, one ``error:`` line, no traceback."""
    assert p.returncode == 2, p.stdout + p.stderr
    assert "Traceback" not in p.stderr and p.stderr.startswith("error:"), p.stderr
    for w in words:
        assert w in p.stderr, p.stderr


def viewer_page(proc: subprocess.Popen, done, width: int, height: int, timeout: float = 90) -> tuple[dict | None, bytes]:
    """Open the viewer a ``live --web`` process announces in headless Chromium; wait (``timeout`` s) for
    ``done(state)`` on its ``window.facecapgesViewer``; return (the last state, a PNG screenshot)."""
    import base64
    import time

    from facecapges.avatar.render.browser import Browser

    line = wait_line(proc, "viewer: ")
    assert line, proc.stderr.read()[-2000:]
    with Browser({}, "/", width=width, height=height, timeout=timeout) as b:
        b.call("Page.navigate", url=line.split()[1])
        state = None
        deadline = time.time() + timeout
        while time.time() < deadline:
            state = b.evaluate("window.facecapgesViewer ? JSON.parse(JSON.stringify(window.facecapgesViewer)) : null")
            if state and done(state):
                break
            time.sleep(0.5)
        return state, base64.b64decode(b.call("Page.captureScreenshot", format="png")["data"])
