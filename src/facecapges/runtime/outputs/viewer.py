"""The browser viewer's server: static files over HTTP and the frame feed over WebSocket.

One ``websockets`` server on one port serves both (plain HTTP GETs are answered in
``process_request`` before any WebSocket handshake):

* ``/`` — the viewer page ``facecapges/web/viewer.html`` (+ ``/web/*`` its scripts,
  ``avatar_scene.js`` included);
* ``/three/*`` — three.js from the project's ``node_modules/three`` (npm, pinned);
* ``/avatar.glb`` — the avatar built for the checkpoint's skeleton;
* ``/ws`` — the WebSocket feed in the format of :mod:`.protocol`: a ``hello``, then
  one ``pose`` message per frame.

Security: it binds 127.0.0.1 unless the user passes another address (``--host``);
the Host check, message size limit and handshake timeout are those of every
WebSocket server of the project (:mod:`.ws`); a bad client message gets an ``error``
reply and one log line per connection; paths are resolved inside their directory (no
``..`` escapes; a path the file system cannot hold is a 404). Nothing is fetched
from outside this machine.

The server runs its asyncio loop in a background thread; :class:`WebFeed` is the
scheduler's sink: :meth:`WebFeed.write` encodes the frame in the caller's thread and
hands it to the loop, which broadcasts it to every viewer without waiting for slow
ones.
"""

from __future__ import annotations

import asyncio
import mimetypes
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Self

from facecapges.avatar.render.browser import CONTENT_SECURITY_POLICY
from facecapges.errors import UserError
from facecapges.runtime.frames import OutputFrame
from facecapges.runtime.outputs import protocol
from facecapges.runtime.outputs.ws import (
    SERVE_OPTIONS,
    ConnectionLog,
    error_message,
    is_loopback,
    pong_message,
    refuse_foreign_host,
)
from facecapges.timing import MODEL_FPS

if TYPE_CHECKING:
    from websockets.asyncio.server import Server

__all__ = ["ViewerServer", "WebFeed", "is_loopback", "parse_address"]

TYPES = {
    ".js": "text/javascript",
    ".mjs": "text/javascript",
    ".html": "text/html; charset=utf-8",
    ".glb": "model/gltf-binary",
    ".json": "application/json",
    ".css": "text/css",
}


def parse_address(text: str, default_host: str = "127.0.0.1", what: str = "--web") -> tuple[str, int]:
    """``"HOST:PORT"`` or ``"PORT"`` → (host, port)."""
    host, _, port = text.rpartition(":")
    host = host or default_host
    try:
        p = int(port)
    except ValueError:
        raise UserError(f"{what} must be HOST:PORT or PORT, got {text!r}") from None
    if not 0 <= p <= 65535:
        raise UserError(f"{what}: port {p} is out of range")
    return host.strip("[]"), p


class ViewerServer:
    """HTTP + WebSocket server of the viewer (module docstring). Use :meth:`start` / :meth:`close`."""

    def __init__(
        self,
        glb: bytes,
        host: str = "127.0.0.1",
        port: int = 8765,
        fps: float = float(MODEL_FPS),
        web_dir: Path | None = None,
        three_dir: Path | None = None,
        log=None,
    ):
        from facecapges.avatar.render.browser import three_dir as find_three
        from facecapges.avatar.render.browser import web_dir as find_web

        self.glb = glb
        self.host, self.port, self.fps = host, port, fps
        self.web_dir = (web_dir or find_web()).resolve()
        self.three_dir = (three_dir or find_three()).resolve()
        self.loopback_only = is_loopback(host)
        self.clients: set = set()
        self.frames_sent = 0
        self.rejected_requests = 0
        self.oversized_closes = 0
        self.bad_messages = 0
        self.conn_log = ConnectionLog(log or (lambda m: print(m, file=sys.stderr)), "viewer")
        # the intensity slider: ``on_intensity(value) -> applied`` (set by ``live``); None: not adjustable
        self.on_intensity: Callable[[float], float] | None = None
        self.intensity = 1.0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: Server | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None

    # ------------------------------------------------------------------ HTTP
    def _file(self, path: str) -> tuple[bytes, str] | None:
        if path in ("/", "/index.html", "/viewer.html"):
            path = "/web/viewer.html"
        if path == "/avatar.glb":
            return self.glb, TYPES[".glb"]
        for prefix, root in (("/web/", self.web_dir), ("/three/", self.three_dir)):
            if path.startswith(prefix):
                try:  # a name the file system cannot hold (too long, NUL) is simply not there
                    full = (root / path[len(prefix) :]).resolve()
                    found = root in full.parents and full.is_file()
                except (OSError, ValueError):
                    return None
                if found:
                    ctype = (
                        TYPES.get(full.suffix.lower())
                        or mimetypes.guess_type(full.name)[0]
                        or "application/octet-stream"
                    )
                    return full.read_bytes(), ctype
        return None

    def _process_request(self, connection, request):
        from websockets.datastructures import Headers
        from websockets.http11 import Response

        refused = refuse_foreign_host(connection, request, self.loopback_only)
        if refused is not None:
            self.rejected_requests += 1
            return refused
        path = request.path.split("?", 1)[0].split("#", 1)[0]
        if path == "/ws":
            return None  # continue with the WebSocket handshake
        try:
            found = self._file(path)
        except OSError:  # unreadable file
            found = None
        if found is None:
            return connection.respond(404, "not found\n")
        body, ctype = found
        headers = Headers(
            [
                ("Content-Type", ctype),
                ("Content-Length", str(len(body))),
                ("Cache-Control", "no-store"),
                ("Content-Security-Policy", CONTENT_SECURITY_POLICY),
                ("Connection", "close"),
            ]
        )
        return Response(200, "OK", headers, body)

    # ------------------------------------------------------------------ WebSocket
    async def _handler(self, ws) -> None:
        from websockets.exceptions import ConnectionClosed

        self.clients.add(ws)
        try:
            await ws.send(protocol.encode_hello(self.fps, intensity=self.intensity))
            async for message in ws:
                try:
                    msg = protocol.decode_client(message, self.fps)
                except protocol.ProtocolError as exc:
                    self.bad_messages += 1
                    self.conn_log.bad_message(ws, exc)
                    await ws.send(error_message(str(exc)))
                    continue
                if msg["type"] == "ping":
                    await ws.send(pong_message())
                elif msg["type"] == "intensity" and self.on_intensity is not None:
                    self.intensity = self.on_intensity(msg["value"])
                    from websockets.asyncio.server import broadcast

                    broadcast(set(self.clients), protocol.encode_intensity(self.intensity))  # every slider agrees
                else:
                    await ws.send(error_message("this server is a viewer feed; it takes no inputs"))
        except ConnectionClosed:
            pass
        finally:
            self.conn_log.closed(ws)
            self.clients.discard(ws)
            sent = getattr(ws.protocol, "close_sent", None)
            if ws.close_code == 1009 or (sent is not None and sent.code == 1009):
                self.oversized_closes += 1

    # ------------------------------------------------------------------ lifecycle
    async def _main(self) -> None:
        from websockets.asyncio.server import serve

        try:
            self._server = await serve(
                self._handler, self.host, self.port, process_request=self._process_request, **SERVE_OPTIONS
            )
        except OSError as exc:
            self._error = UserError(f"viewer server cannot listen on {self.host}:{self.port} ({exc.strerror or exc})")
            self._ready.set()
            return
        sock = next(iter(self._server.sockets))
        self.port = sock.getsockname()[1]
        self.bound = sock.getsockname()[:2]
        self._ready.set()
        await self._server.wait_closed()

    def start(self) -> Self:
        def run():
            self._loop = asyncio.new_event_loop()
            try:
                self._loop.run_until_complete(self._main())
            finally:
                self._loop.close()

        self._thread = threading.Thread(target=run, name="viewer-server", daemon=True)
        self._thread.start()
        self._ready.wait(timeout=20)
        if self._error is not None:
            raise self._error
        return self

    @property
    def url(self) -> str:
        host = self.host if ":" not in self.host else f"[{self.host}]"
        return f"http://{host}:{self.port}/"

    def broadcast(self, text: str) -> None:
        """Send ``text`` to every connected viewer (thread-safe, never blocks the caller)."""
        if self._loop is None or not self.clients:
            return
        from websockets.asyncio.server import broadcast

        def send():
            broadcast(set(self.clients), text)

        try:
            self._loop.call_soon_threadsafe(send)
            self.frames_sent += 1
        except RuntimeError:  # loop closed during shutdown
            pass

    def close(self) -> None:
        if self._loop is not None and self._server is not None:

            def shut():
                self._server.close()

            try:
                self._loop.call_soon_threadsafe(shut)
            except RuntimeError:
                pass
        if self._thread is not None:
            self._thread.join(timeout=5)


class WebFeed:
    """Sink: every frame as a ``pose`` message to every viewer of a :class:`ViewerServer`."""

    def __init__(self, server: ViewerServer):
        self.server = server

    def write(self, out: OutputFrame) -> None:
        if self.server.clients:
            self.server.broadcast(protocol.encode_pose(out))

    def close(self) -> None:
        pass
