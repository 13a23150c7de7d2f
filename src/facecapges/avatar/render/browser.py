"""Headless Chromium driven through the DevTools protocol, serving pages from 127.0.0.1.

:class:`Browser` starts a small HTTP server on a free loopback port that serves
``routes`` (URL prefix ``/p/`` → directory, or exact URL → bytes or a file: the route table of
:mod:`facecapges.io.static_files`, with its content types, no caching and its CSP), launches the Debian
``chromium`` with software WebGL and no network use (a fresh ``--user-data-dir``,
``--remote-debugging-port=0``), opens one page and offers :meth:`Browser.evaluate`:
run a JavaScript expression in the page, await it if it is a promise, and return its
JSON value. Nothing is fetched from outside this machine: every request the page makes is
intercepted (DevTools ``Fetch`` domain) and only our server's origin, the origins of pages we
navigate to ourselves, and ``data:``/``blob:`` URLs go through; anything else fails unfetched
and is listed in :attr:`Browser.blocked`. The pages also carry
:data:`~facecapges.io.static_files.CONTENT_SECURITY_POLICY`.

The page's three.js comes from ``node_modules/three`` of the project checkout
(``scripts/setup-avatar.sh`` installs the pinned 0.187.0); :func:`three_dir` finds it.
"""

from __future__ import annotations

import functools
import json
import os
import shutil
import subprocess
import tempfile
import threading
import time
import urllib.request
from http.server import ThreadingHTTPServer
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

from facecapges.errors import UserError
from facecapges.io.static_files import PageHandler, Routes, find, request_path


class PageError(RuntimeError):
    """A script of the page threw (:meth:`Browser.evaluate`): what the page did with its inputs, not the browser."""


if TYPE_CHECKING:
    from websockets.sync.client import ClientConnection

CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",
    "--use-angle=swiftshader",
    "--disable-quic",
    "--no-first-run",
    "--no-default-browser-check",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-extensions",
    "--disable-default-apps",
    "--mute-audio",
    "--hide-scrollbars",
    "--disable-dev-shm-usage",
    "--remote-debugging-port=0",
    "--remote-allow-origins=*",
]
SETUP_HINT = "run scripts/setup-avatar.sh"


def web_dir() -> Path:
    """The package's web assets (avatar_scene.js, render.html)."""
    return Path(str(resources.files("facecapges") / "web"))


def three_dir() -> Path:
    """``node_modules/three`` (pinned 0.187.0): $FACECAPGES_THREE, else searched upwards from here and the cwd."""
    env = os.environ.get("FACECAPGES_THREE")
    candidates = [Path(env)] if env else []
    for start in (Path(__file__).resolve(), Path.cwd().resolve()):
        candidates += [p / "node_modules" / "three" for p in start.parents]
        candidates.append(start / "node_modules" / "three")
    for c in candidates:
        if (c / "build" / "three.module.js").is_file():
            return c
    raise UserError(f"three.js (npm three 0.187.0) not found in node_modules; {SETUP_HINT}")


def chromium_path() -> str:
    exe = os.environ.get("FACECAPGES_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    if not exe:
        raise UserError(f"chromium is not installed; {SETUP_HINT}")
    return exe


class _Handler(PageHandler):
    routes: ClassVar[Routes] = {}

    def do_GET(self) -> None:
        found = find(self.routes, request_path(self.path))
        if found is None:
            return self.send_not_found()
        self.send_page(200, *found)

    do_HEAD = do_GET


class Browser:
    """One headless Chromium page on a loopback HTTP server. Use as a context manager."""

    def __init__(self, routes: Routes, page: str, width: int = 640, height: int = 480, timeout: float = 60.0):
        self.routes = dict(routes)
        self.page = page
        self.width, self.height = width, height
        self.timeout = timeout
        self._id = 0
        self.origins: set[str] = set()  # where the page may fetch from: our server and pages we navigate to
        self.blocked: list[str] = []  # every other URL the page asked for (failed, never fetched)

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> Browser:
        from websockets.sync.client import connect

        handler = type("Handler", (_Handler,), {"routes": self.routes})
        self.server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
        self.server.daemon_threads = True
        self._thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self._thread.start()
        port = self.server.server_address[1]
        self.origins.add(f"http://127.0.0.1:{port}")
        self.profile = tempfile.mkdtemp(prefix="facecapges-chromium-")
        self.proc = subprocess.Popen(
            [
                chromium_path(),
                *CHROMIUM_FLAGS,
                f"--user-data-dir={self.profile}",
                f"--window-size={self.width},{self.height}",
                "about:blank",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        try:
            devtools = self._devtools_port()
            targets = json.load(urllib.request.urlopen(f"http://127.0.0.1:{devtools}/json/list", timeout=10))
            page = next(t for t in targets if t.get("type") == "page")
            self._ws_cm: ClientConnection | None = connect(page["webSocketDebuggerUrl"], max_size=None, open_timeout=20)
            self.ws = self._ws_cm.__enter__()
            self.call("Runtime.enable")
            self.call("Page.enable")
            self.call("Fetch.enable", patterns=[{"urlPattern": "*"}])  # every request: _on_event decides
            self.call("Page.navigate", url=f"http://127.0.0.1:{port}{self.page}")
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        cm = getattr(self, "_ws_cm", None)
        if cm is not None:
            self._ws_cm = None
            try:
                cm.__exit__(None, None, None)
            except Exception:  # noqa: BLE001  closing a dead DevTools socket: nothing left to do
                pass
        proc = getattr(self, "proc", None)
        if proc is not None and proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        server = getattr(self, "server", None)
        if server is not None:
            server.shutdown()
            server.server_close()
        if getattr(self, "profile", None):
            shutil.rmtree(self.profile, ignore_errors=True)

    def _devtools_port(self) -> int:
        marker = Path(self.profile) / "DevToolsActivePort"
        deadline = time.time() + self.timeout
        while time.time() < deadline:
            if self.proc.poll() is not None:
                assert self.proc.stderr is not None  # stderr=PIPE
                err = self.proc.stderr.read().decode(errors="replace")[-800:]
                raise RuntimeError(f"chromium exited with status {self.proc.returncode}: {err}")
            if marker.is_file():
                lines = marker.read_text().split()
                if lines:
                    return int(lines[0])
            time.sleep(0.05)
        raise RuntimeError("chromium did not open its DevTools port in time")

    # ------------------------------------------------------------------- protocol
    def call(self, method: str, **params) -> dict:
        """Send one DevTools command and return its result (events in between are skipped)."""
        if method == "Page.navigate":  # a page we open ourselves: its origin may serve it
            self.origins.add(_origin(str(params.get("url", ""))))
        my_id = self._send(method, **params)
        while True:
            msg = json.loads(self.ws.recv(timeout=self.timeout))
            if msg.get("id") == my_id:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})
            if msg.get("method") == "Fetch.requestPaused":
                self._on_request(msg["params"])

    def _send(self, method: str, **params) -> int:
        self._id += 1
        self.ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        return self._id

    def _on_request(self, params: dict) -> None:
        """Request interception: our origins (and data:/blob:) go on, anything else fails unfetched."""
        url = str(params.get("request", {}).get("url", ""))
        if url.startswith(("data:", "blob:")) or _origin(url) in self.origins:
            self._send("Fetch.continueRequest", requestId=params["requestId"])
        else:
            self.blocked.append(url)
            self._send("Fetch.failRequest", requestId=params["requestId"], errorReason="BlockedByClient")

    def evaluate(self, expression: str):
        """Value of a JavaScript expression in the page (promises awaited), JSON-decoded."""
        res = self.call("Runtime.evaluate", expression=expression, awaitPromise=True, returnByValue=True)
        if "exceptionDetails" in res:
            det = res["exceptionDetails"]
            text = det.get("exception", {}).get("description") or det.get("text")
            raise PageError(f"page error: {text}")
        return res.get("result", {}).get("value")

    def wait_for(self, expression: str, timeout: float | None = None):
        """Poll until ``expression`` is defined, then evaluate it (awaiting it)."""
        deadline = time.time() + (timeout or self.timeout)
        while time.time() < deadline:
            ok = self.evaluate(
                f"(() => {{ try {{ return ({expression}) !== undefined; }} catch (e) {{ return false; }} }})()"
            )
            if ok:
                return self.evaluate(expression)
            time.sleep(0.05)
        raise RuntimeError(f"page never defined {expression}")


def _origin(url: str) -> str:
    """``scheme://host:port`` of a URL (the port spelled out), "" when it has none."""
    from urllib.parse import urlsplit

    try:
        u = urlsplit(url)
        port = u.port or {"http": 80, "https": 443, "ws": 80, "wss": 443}.get(u.scheme, 0)
    except ValueError:
        return ""
    return f"{u.scheme}://{u.hostname}:{port}" if u.hostname else ""


def avatar_routes(glb: bytes | Path) -> dict[str, bytes | Path]:
    """Routes for render.html: the web assets, three.js and the avatar at /avatar.glb."""
    data = glb.read_bytes() if isinstance(glb, Path) else glb
    return {"/web/": web_dir(), "/three/": three_dir(), "/avatar.glb": data}


@functools.lru_cache(maxsize=1)
def chromium_version() -> str:
    try:
        return subprocess.run([chromium_path(), "--version"], capture_output=True, text=True, timeout=30).stdout.strip()
    except Exception:  # noqa: BLE001  a version string only: never fail over it
        return "unknown"
