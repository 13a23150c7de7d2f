"""What the project's two WebSocket servers share: the viewer feed (:mod:`.viewer`) and
``serve`` (:mod:`facecapges.serving.server`).

* :func:`is_loopback` / :func:`refuse_foreign_host` — while a server is bound to a
  loopback address it answers only requests whose ``Host`` header names a loopback
  host (web pages elsewhere cannot reach it by DNS rebinding): others get 403.
* :data:`SERVE_OPTIONS` — the ``websockets.serve`` settings both use: messages above
  :data:`~.protocol.MAX_MESSAGE_BYTES` close the connection (1009), the opening
  handshake must finish within :data:`HANDSHAKE_TIMEOUT` seconds, no keep-alive pings,
  no ``Server`` header.
* :func:`error_message` / :func:`pong_message` — the two replies every server sends.
* :class:`ConnectionLog` — one log line per connection for its first bad message (the
  rest are only counted), so a client sending garbage cannot flood the log.
* :func:`peer_host` — the client's address, for per-address limits.

Their thread and event-loop lifecycle is :class:`.server_thread.ServerThread`; the files the
viewer sends over HTTP come from :mod:`facecapges.io.static_files`.
"""

from __future__ import annotations

import ipaddress
import json
import time
from collections.abc import Callable
from typing import Any

from facecapges.runtime.outputs import protocol

LOOPBACK_NAMES = {"localhost", "127.0.0.1", "::1", "[::1]"}
HANDSHAKE_TIMEOUT = 10.0  # seconds from TCP connect to the end of the WebSocket handshake
SERVE_OPTIONS: dict[str, Any] = {
    "max_size": protocol.MAX_MESSAGE_BYTES,
    "ping_interval": None,
    "server_header": None,
    "open_timeout": HANDSHAKE_TIMEOUT,
}


def is_loopback(host: str) -> bool:
    if host in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def host_of_header(host_header: str) -> str:
    """The host name of an HTTP ``Host`` header (``name:port``, ``[v6]:port`` or bare)."""
    if host_header.startswith("["):
        return host_header.split("]")[0] + "]"
    return host_header.rsplit(":", 1)[0]


def refuse_foreign_host(connection, request, loopback_only: bool):
    """``process_request`` guard: a 403 response for a non-loopback ``Host`` on a loopback server, else None."""
    if loopback_only and not is_loopback(host_of_header(request.headers.get("Host", ""))):
        return connection.respond(403, "forbidden: this server only answers loopback hosts\n")
    return None


def peer_host(ws) -> str:
    addr = getattr(ws, "remote_address", None)
    return str(addr[0]) if addr else "?"


def error_message(message: str) -> str:
    return json.dumps({"type": "error", "message": message})


def pong_message() -> str:
    return json.dumps({"type": "pong", "sent_ms": time.time() * 1000.0})


class ConnectionLog:
    """Logs the first bad message of each connection on one line; counts the rest."""

    def __init__(self, log: Callable[[str], None] | None, what: str):
        self.log = log or (lambda _msg: None)
        self.what = what
        self._logged: set[int] = set()

    def bad_message(self, ws, exc: Exception) -> None:
        key = id(ws)
        if key not in self._logged:
            self._logged.add(key)
            self.log(
                f"{self.what}: client {peer_host(ws)} sent a bad message ({str(exc)[:160]}); further bad "
                "messages on this connection are answered but not logged"
            )

    def closed(self, ws) -> None:
        self._logged.discard(id(ws))
