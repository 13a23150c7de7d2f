"""Helpers shared by the runtime tests (not a test module).

The runtime tests use the installed default style (``load_style()``); when it is
missing they fail (nothing is skipped).
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import lru_cache


@lru_cache(maxsize=1)
def checkpoint():
    from facecapges.styles import load_style

    return load_style()


class CliResult(subprocess.CompletedProcess):
    """What :func:`cli` returns: the fields of a finished subprocess (``returncode``, ``stdout``, ``stderr``)."""


class _TimedOut(BaseException):
    """Raised in the main thread by SIGALRM when an in-process command runs past its ``timeout``."""


def cli(*args: str, timeout: float = 300, env: dict[str, str] | None = None, cwd: str | os.PathLike | None = None
        ) -> CliResult:
    """Run ``facecapges ARGS`` in this process, through the console entry point ``facecapges.commands.cli.main``.

    It is what the subprocess did, minus 5-10 s of interpreter start, torch import and checkpoint load: the
    same ``main()`` turns a ``UserError`` into one ``error:`` line on stderr and exit status 2, a usage error
    exits 2, and an exception that escapes ``main()`` is printed as the interpreter would (a ``Traceback`` on
    stderr, status 1), so "one clear line, no traceback" is still checked. Python warnings go to stderr as
    they would in a fresh interpreter. ``env`` is set in ``os.environ`` and ``cwd`` made the working folder for the call only, and torch's thread
    count (which ``generate``/``run``/``live`` set) is put back afterwards. A command still
    running after ``timeout`` s is stopped (SIGALRM) and ``subprocess.TimeoutExpired`` raised, as
    ``subprocess.run`` does.
    For what only a real process shows (signals, servers, the installed script, torchrun) use
    :func:`cli_process`.
    """
    import contextlib
    import io
    import signal
    import traceback
    import warnings

    from facecapges.commands.cli import main

    out, err = io.StringIO(), io.StringIO()
    argv, saved_env, saved_cwd = list(sys.argv), dict(os.environ), os.getcwd()
    handlers = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGHUP, signal.SIGALRM)}
    torch = sys.modules.get("torch")
    threads = torch.get_num_threads() if torch is not None else None
    code: int | str | None = 0
    sys.argv = ["facecapges", *map(str, args)]
    os.environ.update(env or {})
    if cwd is not None:
        os.chdir(cwd)

    def alarm(signum, frame):
        raise _TimedOut

    signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
            warnings.resetwarnings()  # the filters of a fresh interpreter, not pytest's
            for category in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
                warnings.simplefilter("ignore", category)
            try:
                main()
            except SystemExit as exc:
                code = exc.code
            except Exception:  # noqa: BLE001 — what the interpreter does with an exception nobody caught
                traceback.print_exc()
                code = 1
    except _TimedOut:
        raise subprocess.TimeoutExpired(["facecapges", *map(str, args)], timeout, out.getvalue(),
                                       err.getvalue()) from None
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        torch = sys.modules.get("torch")
        if torch is not None:
            torch.set_num_threads(threads or int(os.environ.get("OMP_NUM_THREADS", "1")))
        sys.argv = argv
        os.chdir(saved_cwd)
        for key in set(os.environ) - set(saved_env):
            del os.environ[key]
        for key, value in saved_env.items():
            if os.environ.get(key) != value:
                os.environ[key] = value
        for s, h in handlers.items():
            signal.signal(s, h)
    if code is None:
        code = 0
    elif not isinstance(code, int):  # sys.exit("message"): the message goes to stderr, status 1
        err.write(f"{code}\n")
        code = 1
    return CliResult(["facecapges", *map(str, args)], code, out.getvalue(), err.getvalue())


def cli_process(*args: str, background: bool = False, launcher: tuple[str, ...] = ("-m", "facecapges"),
                timeout: float = 300, **kw) -> subprocess.CompletedProcess | subprocess.Popen:
    """Run ``facecapges ARGS`` in a real subprocess: the one helper for the tests where the process matters
    (Ctrl-C and other signals, servers and ``live`` loops, the installed entry point, torchrun, read-only
    mounts). ``launcher`` is what runs between the interpreter and ``ARGS`` (default ``-m facecapges``;
    e.g. ``("-m", "torch.distributed.run", ..., "-m", "facecapges")``); a ``launcher`` whose first word
    is not an interpreter option (no leading ``-``) is the whole command before ``ARGS`` instead (the
    installed ``facecapges`` script, ``unshare ... python -m facecapges``).
    ``background=True`` returns the running ``Popen`` (stdout/stderr piped, text, unbuffered)."""
    if launcher and not launcher[0].startswith("-"):
        cmd = [*launcher, *map(str, args)]
    else:
        cmd = [sys.executable, "-u", *launcher, *map(str, args)]
    if background:
        return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, **kw)


_CLI_SEQUENCE = """
import json, sys
sys.path.insert(0, sys.argv[1])
from runtime_helpers import cli
done = [cli(*args, timeout=timeout) for args, timeout in json.loads(sys.argv[2])]
sys.stdout.write("\\n" + json.dumps([[r.returncode, r.stdout, r.stderr] for r in done]) + "\\n")
"""


def cli_process_sequence(*commands: tuple[str, ...], launcher: tuple[str, ...] = (), timeout: float = 300
                         ) -> list[CliResult]:
    """Run several ``facecapges`` commands one after another in ONE real subprocess (each through :func:`cli`
    inside it): for checks that need a process of their own but not one per command, e.g. a private mount
    namespace with a read-only folder (``launcher`` = the command before the interpreter, such as
    ``("unshare", "-rm", "sh", "-c", "mount ... && exec \"$0\" \"$@\"")``). One interpreter, torch import
    and checkpoint load instead of one per command; each command's exit status, stdout and stderr as
    :func:`cli` gives them."""
    import json
    from pathlib import Path

    plan = json.dumps([[list(map(str, c)), timeout] for c in commands])
    p = cli_process(str(Path(__file__).resolve().parent), plan,
                    launcher=(*launcher, sys.executable, "-c", _CLI_SEQUENCE), timeout=timeout * len(commands))
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-4000:]
    done = json.loads(p.stdout.rstrip("\n").rsplit("\n", 1)[-1])
    assert len(done) == len(commands), done
    return [CliResult(["facecapges", *map(str, c)], code, out, err) for c, (code, out, err) in zip(commands, done)]


def cli_popen(*args: str, **kw) -> subprocess.Popen:
    """``facecapges ARGS`` running in the background (see :func:`cli_process`)."""
    return cli_process(*args, background=True, **kw)


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


@contextmanager
def vmc_frames(on_frame: Callable[[bytes, float], None]) -> Iterator[tuple[str, int]]:
    """A loopback UDP receiver for a VMC sender, yielding its ``(host, port)``: a thread calls
    ``on_frame(datagram, time.monotonic())`` for every datagram holding ``/VMC/Ext/T`` (a frame's last, so one
    call per frame), stamped as it arrives. The thread is stopped and the socket closed on leaving."""
    import socket
    import threading
    import time

    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.2)
    stop = threading.Event()

    def receive() -> None:
        while not stop.is_set():
            try:
                d = rx.recv(65535)
            except OSError:
                continue
            if b"/VMC/Ext/T" in d:
                on_frame(d, time.monotonic())

    th = threading.Thread(target=receive, daemon=True)
    th.start()
    try:
        yield rx.getsockname()
    finally:
        stop.set()
        th.join(2)
        rx.close()


def refused(p: subprocess.CompletedProcess, *words: str) -> None:
    """Assert a command failed the way a user should see it: exit 2, one ``error:`` line, no traceback."""
    assert p.returncode == 2, p.stdout + p.stderr
    assert "Traceback" not in p.stderr and p.stderr.startswith("error:"), p.stderr
    for w in words:
        assert w in p.stderr, p.stderr


def viewer_url(proc: subprocess.Popen) -> str:
    """The viewer's URL a ``live --web`` process announces."""
    line = wait_line(proc, "viewer: ")
    assert line, proc.stderr.read()[-2000:]
    return line.split()[1]


def viewer_page(proc: subprocess.Popen, done, width: int, height: int, timeout: float = 90) -> tuple[dict | None, bytes]:
    """Open the viewer a ``live --web`` process announces in headless Chromium; wait (``timeout`` s) for
    ``done(state)`` on its ``window.facecapgesViewer``; return (the last state, a PNG screenshot)."""
    return open_viewer(viewer_url(proc), done, width, height, timeout)


def _wait_state(b, done, timeout: float) -> dict | None:
    import time

    state = None
    deadline = time.time() + timeout
    while time.time() < deadline:
        state = b.evaluate("window.facecapgesViewer ? JSON.parse(JSON.stringify(window.facecapgesViewer)) : null")
        if state and done(state):
            break
        time.sleep(0.5)
    return state


def open_viewer(url: str, done, width: int, height: int, timeout: float = 90) -> tuple[dict | None, bytes]:
    """The viewer page at ``url`` in headless Chromium: (its state once ``done(state)``, a PNG screenshot)."""
    import base64

    from facecapges.avatar.render.browser import Browser

    with Browser({}, "/", width=width, height=height, timeout=timeout) as b:
        b.call("Page.navigate", url=url)
        state = _wait_state(b, done, timeout)
        return state, base64.b64decode(b.call("Page.captureScreenshot", format="png")["data"])


def obs_views(url: str, width: int = 640, height: int = 480, timeout: float = 90, frames: int = 5) -> dict:
    """The viewer at ``url`` as OBS's browser source shows it: the page's own background transparent (as
    OBS makes it), ``?bg=transparent&hud=0&frame=F`` for F in head, upper. Returns, per frame, its state,
    the screenshot as an RGBA array and whether the HUD is displayed; under ``"orbit"`` the camera
    (``state.camera()``) before and after a mouse drag and after a wheel turn on the upper frame, and the
    same with ``&orbit=0``; under ``"bad"`` the errors of ``?frame=knees&bg=nope``. Each page is looked at
    once it has drawn ``frames`` feed frames."""
    import base64
    import time

    import cv2
    import numpy as np

    from facecapges.avatar.render.browser import Browser

    def ready(s):
        return s["ready"] and s["drawn"] >= frames

    def drag(b):
        x, y = width // 2, height // 2
        b.call("Input.dispatchMouseEvent", type="mouseMoved", x=x, y=y)
        b.call("Input.dispatchMouseEvent", type="mousePressed", x=x, y=y, button="left", buttons=1, clickCount=1)
        for k in range(1, 11):
            b.call("Input.dispatchMouseEvent", type="mouseMoved", x=x + 12 * k, y=y, button="left", buttons=1)
        b.call("Input.dispatchMouseEvent", type="mouseReleased", x=x + 120, y=y, button="left", buttons=0,
               clickCount=1)
        return b.evaluate("window.facecapgesViewer.camera()")

    out: dict = {}
    with Browser({}, "/", width=width, height=height, timeout=timeout) as b:
        b.call("Emulation.setDefaultBackgroundColorOverride", color={"r": 0, "g": 0, "b": 0, "a": 0})
        for frame in ("head", "upper"):
            b.call("Page.navigate", url=f"{url}?bg=transparent&hud=0&frame={frame}")
            time.sleep(0.5)  # (the previous page's state must not answer)
            state = _wait_state(b, ready, timeout)
            png = base64.b64decode(b.call("Page.captureScreenshot", format="png")["data"])
            out[frame] = {
                "state": state,
                "rgba": cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED),
                "hud": b.evaluate("getComputedStyle(document.getElementById('hud')).display"),
                "png": png,
                "camera": b.evaluate("window.facecapgesViewer.camera()"),
            }
        before = b.evaluate("window.facecapgesViewer.camera()")
        dragged = drag(b)
        b.call("Input.dispatchMouseEvent", type="mouseWheel", x=width // 2, y=height // 2, deltaX=0, deltaY=-400)
        time.sleep(0.3)
        zoomed = b.evaluate("window.facecapgesViewer.camera()")
        b.call("Page.navigate", url=f"{url}?frame=upper&orbit=0")
        time.sleep(0.5)
        _wait_state(b, ready, timeout)
        fixed = [b.evaluate("window.facecapgesViewer.camera()"), drag(b)]
        out["orbit"] = {"before": before, "dragged": dragged, "zoomed": zoomed, "fixed": fixed}
        b.call("Page.navigate", url=f"{url}?frame=knees&bg=nope")
        time.sleep(0.5)
        out["bad"] = _wait_state(b, ready, timeout)["errors"]
    return out


def _head_width(alpha, top: int) -> int:
    """The widest opaque row of the head in an RGBA screenshot's ``alpha``: from the avatar's ``top`` row down to
    the chin (the first row narrower than 0.8 of the widest above it: the head narrows to the neck, which is 0.3
    of the sample VRM's cube head and 0.64 of our avatar's)."""
    import numpy as np

    widest = 0
    for row in alpha[top:]:
        n = int(np.count_nonzero(row))
        if n < 0.8 * widest:
            break
        widest = max(widest, n)
    return widest


def check_obs_views(views: dict, name: str) -> None:
    """Assert what :func:`obs_views` saw (screenshots kept as /tmp/facecapges-obs-NAME-FRAME.png for a look):
    alpha 0 around the avatar and where the HUD was, no HUD, the head framed larger than in the upper-body
    frame, the mouse orbiting and zooming (and not with orbit=0), bad values reported."""
    from pathlib import Path

    import numpy as np

    widths = {}
    for frame in ("head", "upper"):
        v = views[frame]
        Path(f"/tmp/facecapges-obs-{name}-{frame}.png").write_bytes(v["png"])
        assert v["state"]["errors"] == [] and v["state"]["options"]["background"] is None, v["state"]
        assert v["hud"] == "none"
        img = v["rgba"]
        assert img.ndim == 3 and img.shape[2] == 4, img.shape  # a PNG with an alpha channel
        alpha = img[..., 3]
        h, w = alpha.shape
        # nothing behind the avatar: the corners, the HUD's place (top left) and most of the picture. The head
        # frame crops the body at the shoulders, so a wide gesture's arms may reach its bottom corners (a fresh
        # clone's CI caught both hands up at the face with the sleeves at the bottom left): its top corners only
        corners = ((0, 0), (0, w - 1)) if frame == "head" else ((0, 0), (0, w - 1), (h - 1, 0), (h - 1, w - 1))
        for y, x in corners:
            assert alpha[y, x] == 0, (frame, y, x, alpha[y, x])
        assert (alpha[: h // 4, : w // 4] == 0).all(), frame
        empty = (alpha == 0).mean()
        assert 0.3 < empty < 0.97, (frame, empty)
        rows = np.flatnonzero((alpha > 0).any(axis=1))
        top = rows[0]
        assert top < 0.2 * h, (frame, top)  # the avatar's top near the picture's top in both
        widths[frame] = _head_width(alpha, top)
        views[frame]["rows"] = (int(rows[0]), int(rows[-1]))

    def scale(c):  # pixels per metre at the camera's target: 1 / (distance * tan(fov / 2))
        return 1 / (np.linalg.norm(np.subtract(c["position"], c["target"])) * np.tan(np.radians(c["fov"]) / 2))

    # head and shoulders: the head framed at least 1.3 times as large as in the upper-body frame. Exactly on the
    # cameras; in the pictures on the head's widest row, with room for the head's turn between the two moments
    # (a cube head turned 30 degrees is 1.37 times as wide as face-on)
    zoom = scale(views["head"]["camera"]) / scale(views["upper"]["camera"])
    assert zoom >= 1.3, (zoom, views["head"]["camera"], views["upper"]["camera"])
    assert widths["head"] > zoom / 1.37 * widths["upper"] > 0, (widths, zoom)
    o = views["orbit"]
    moved = np.linalg.norm(np.subtract(o["dragged"]["position"], o["before"]["position"]))
    assert moved > 0.05, o  # the drag turned the camera about its target
    np.testing.assert_allclose(o["dragged"]["target"], o["before"]["target"], atol=1e-6)

    def dist(c):
        return np.linalg.norm(np.subtract(c["position"], c["target"]))

    assert dist(o["zoomed"]) < 0.95 * dist(o["dragged"]), o  # the wheel zoomed in
    np.testing.assert_allclose(o["fixed"][1]["position"], o["fixed"][0]["position"], atol=1e-9)
    assert any("frame=knees" in e for e in views["bad"]) and any("bg=nope" in e for e in views["bad"]), views["bad"]
