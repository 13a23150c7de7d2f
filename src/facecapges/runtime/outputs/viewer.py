"""The browser viewer's server: static files over HTTP and the frame feed over WebSocket.

One ``websockets`` server on one port serves both (plain HTTP GETs are answered in
``process_request`` before any WebSocket handshake):

* ``/`` — the viewer page ``facecapges/web/viewer.html`` (:attr:`ViewerServer.page`; + ``/web/*``
  its scripts, ``avatar_scene.js`` included);
* ``/three/*`` — three.js from the project's ``node_modules/three`` (npm, pinned);
* ``/avatar.glb`` — the avatar built for the checkpoint's skeleton;
* ``/ws`` — the WebSocket feed in the format of :mod:`.protocol`: a ``hello``, then
  one ``pose`` message per frame.

Between the model's frames (``live --rate R`` above the model's rate): the feed still carries the
model's frames only (15 a second), and right after ``hello`` one more message tells the page to blend
towards each one itself, as the upsampler of the VMC stream does (:mod:`.upsample`)::

    {"type": "rate", "fps": 15, "rate": 30}

The page (``web/viewer.js``) draws that blend at the display's rate: the same added latency as at
``R`` Hz (33.3 ms at 30 Hz), smoother, and the server encodes and sends a frame once, not ``R/fps``
times (issue 36: the output ticks' CPU).

Security: it binds 127.0.0.1 unless the user passes another address (``--host``);
the Host check, message size limit and handshake timeout are those of every
WebSocket server of the project (:mod:`.ws`); a bad client message gets an ``error``
reply and one log line per connection; files are served from :attr:`ViewerServer.routes` by
:mod:`facecapges.io.static_files` (paths resolved inside their folder: no ``..`` escapes, a path
the file system cannot hold is a 404; its content types, no caching, the CSP). Nothing is fetched
from outside this machine.

The server runs its asyncio loop in a background thread (:mod:`.server_thread`, as ``serve``
does); :class:`WebFeed` is the
scheduler's sink: :meth:`WebFeed.write` encodes the frame in the caller's thread and
hands it to the loop, which broadcasts it to every viewer without waiting for slow
ones.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from facecapges.errors import UserError
from facecapges.io.static_files import NOT_FOUND, content_type, find, page_headers, request_path
from facecapges.runtime.frames import OutputFrame
from facecapges.runtime.outputs import protocol
from facecapges.runtime.outputs.server_thread import ServerThread
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

_TEXT = content_type("reply.txt")
_CLOSE = ("Connection", "close")

INDEX_PATHS = ("/", "/index.html", "/viewer.html")  # the page, by any of its names
# no permessage-deflate: a pose message (~2 KB of numbers) compresses poorly, and deflating each one for each viewer
# cost more CPU than the bytes it saved on loopback or a LAN (issue 36; ``serve`` sends uncompressed too)
VIEWER_OPTIONS = {**SERVE_OPTIONS, "compression": None}


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


class ViewerServer(ServerThread):
    """HTTP + WebSocket server of the viewer (module docstring). Use :meth:`start` / :meth:`close`."""

    thread_name = "viewer-server"
    cannot_listen = "viewer server cannot listen"
    # the feed's server loop on uvloop (in C), as ``serve``'s: with one viewer it is most of the feed's CPU (issue 36)
    fast_loop = True

    def __init__(
        self,
        glb: bytes,
        host: str = "127.0.0.1",
        port: int = 8765,
        fps: float = float(MODEL_FPS),
        web_dir: Path | None = None,
        three_dir: Path | None = None,
        log=None,
        rate: float | None = None,
    ):
        from facecapges.avatar.render.browser import three_dir as find_three
        from facecapges.avatar.render.browser import web_dir as find_web

        super().__init__()
        self.glb = glb
        self.host, self.port, self.fps = host, port, fps
        self.rate = fps if rate is None else float(rate)  # the page blends between frames above fps (module docs)
        self.web_dir = (web_dir or find_web()).resolve()
        self.three_dir = (three_dir or find_three()).resolve()
        self.page = "/web/viewer.html"  # served at INDEX_PATHS
        # /vrm/layout.json is null here: the page asks it which scene to draw (a VRM server serves its layout)
        self.routes: dict[str, bytes | Path] = {
            "/avatar.glb": glb,
            "/vrm/layout.json": b"null",
            "/web/": self.web_dir,
            "/three/": self.three_dir,
        }
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

    # ------------------------------------------------------------------ HTTP
    def _file(self, path: str) -> tuple[bytes, str] | None:
        return find(self.routes, self.page if path in INDEX_PATHS else path)

    def _process_request(self, connection, request):
        from websockets.datastructures import Headers
        from websockets.http11 import Response

        refused = refuse_foreign_host(connection, request, self.loopback_only)
        if refused is not None:
            self.rejected_requests += 1
            return refused
        path = request_path(request.path)
        if path == "/ws":
            return None  # continue with the WebSocket handshake
        found = self._file(path)
        if found is None:
            return Response(404, "Not Found", Headers([*page_headers(_TEXT, len(NOT_FOUND)), _CLOSE]), NOT_FOUND)
        body, ctype = found
        return Response(200, "OK", Headers([*page_headers(ctype, len(body)), _CLOSE]), body)

    # ------------------------------------------------------------------ WebSocket
    async def _handler(self, ws) -> None:
        from websockets.exceptions import ConnectionClosed

        self.clients.add(ws)
        try:
            await ws.send(protocol.encode_hello(self.fps, intensity=self.intensity))
            if self.rate > self.fps:
                await ws.send(json.dumps({"type": "rate", "fps": self.fps, "rate": self.rate}))
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

    # ------------------------------------------------------------------ lifecycle (ServerThread)
    async def _listen(self) -> Server:
        from websockets.asyncio.server import serve

        server = await serve(
            self._handler, self.host, self.port, process_request=self._process_request, **VIEWER_OPTIONS
        )
        self.port = next(iter(server.sockets)).getsockname()[1]
        return server

    def _address(self) -> tuple[str, int]:
        return self.host, self.port

    @property
    def url(self) -> str:
        host = self.host if ":" not in self.host else f"[{self.host}]"
        return f"http://{host}:{self.port}/"

    def broadcast(self, text: str | bytes) -> None:
        """Send ``text`` to every connected viewer as a text frame (thread-safe, never blocks the caller); ``bytes``
        are its UTF-8, sent as they are."""
        if self._loop is None or not self.clients:
            return
        from websockets.asyncio.server import broadcast

        def send():
            broadcast(set(self.clients), text, text=True)

        if self.call_soon(send):
            self.frames_sent += 1


class WebFeed:
    """Sink: every frame as a ``pose`` message to every viewer of a :class:`ViewerServer`."""

    def __init__(self, server: ViewerServer):
        self.server = server

    def write(self, out: OutputFrame) -> None:
        if self.server.clients:
            self.server.broadcast(protocol.encode_pose_utf8(out))

    def close(self) -> None:
        pass
