"""The lifecycle both WebSocket servers share (the viewer, :mod:`.viewer`, and ``serve``,
:mod:`facecapges.serving.server`): a ``websockets`` server on an asyncio event loop of its own,
in a daemon thread.

:meth:`ServerThread.start` starts the thread and returns once the server listens (or raises
the :class:`~facecapges.errors.UserError` saying why it cannot: address in use, not this
machine's, …); :meth:`ServerThread.close` stops it from any thread and joins the thread;
:meth:`ServerThread.run` blocks until the server stops or Ctrl-C. A subclass says how it
listens (:meth:`ServerThread._listen`) and what else runs while it serves
(:meth:`ServerThread._background`); everything it schedules from other threads goes through
:meth:`ServerThread.call_soon`.
"""

from __future__ import annotations

import asyncio
import os
import socket
import threading
from collections.abc import Callable, Coroutine
from typing import TYPE_CHECKING, Any, Self

from facecapges.errors import UserError
from facecapges.runtime.os_threads import name_os_thread

if TYPE_CHECKING:
    from websockets.asyncio.server import Server


def listening_socket(host: str, port: int, what: str = "cannot listen") -> socket.socket:
    """A TCP socket listening on ``host:port`` now, for a server started on it later
    (``websockets.serve(sock=…)``): connections that arrive meanwhile wait in its backlog
    instead of being refused. A UserError "{what} on HOST:PORT (why)" when it cannot."""
    try:
        family = socket.AF_INET6 if ":" in host.strip("[]") else socket.AF_INET
        return socket.create_server((host.strip("[]"), port), family=family, backlog=1024)
    except OSError as exc:  # create_server words its own strerror ("… (while attempting to bind …)")
        why = os.strerror(exc.errno) if exc.errno else str(exc)
        raise UserError(f"{what} on {host}:{port} ({why})") from None


def new_event_loop(fast: bool = True) -> asyncio.AbstractEventLoop:
    """A new event loop: uvloop's (its transports and selector in C: ``serve`` spends about half of its
    CPU per stream-frame in the event loop and the WebSocket layer, docs/performance.md) when ``fast`` and
    uvloop is installed (a core dependency on Linux and macOS; there is none for Windows), else asyncio's."""
    if fast:
        try:
            import uvloop
        except ImportError:
            pass
        else:
            return uvloop.new_event_loop()
    return asyncio.new_event_loop()


class ServerThread:
    """A server on its own event loop in a daemon thread (module docstring)."""

    thread_name = "server"
    cannot_listen = "cannot listen"  # the start of the error when it cannot: "{cannot_listen} on HOST:PORT (why)"
    start_timeout = 20.0  # seconds start() waits for the server to listen
    join_timeout = 5.0  # seconds close() waits for the thread to end
    fast_loop = False  # run on uvloop's event loop (libuv, in C) where it is installed: ``serve`` does (new_loop)

    def __init__(self) -> None:
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: Server | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._stop: asyncio.Event | None = None  # made in the server's loop
        self.bound: tuple[str, int] | None = None  # (host, port) it listens on

    # ------------------------------------------------------------------ what a subclass says
    async def _listen(self) -> Server:
        """Open the server (``websockets.asyncio.server.serve``) in the server's loop."""
        raise NotImplementedError

    def _address(self) -> tuple[str, int]:
        """(host, port) it was asked to listen on, for the error when it cannot."""
        raise NotImplementedError

    def _background(self) -> list[Coroutine[Any, Any, None]]:
        """Coroutines to run beside the server while it serves (cancelled when it stops)."""
        return []

    # ------------------------------------------------------------------ lifecycle
    async def _main(self) -> None:
        self._stop = asyncio.Event()
        try:
            self._server = await self._listen()
        except OSError as exc:
            host, port = self._address()
            self._error = UserError(f"{self.cannot_listen} on {host}:{port} ({exc.strerror or exc})")
            return
        self.bound = next(iter(self._server.sockets)).getsockname()[:2]
        tasks = [asyncio.ensure_future(c) for c in self._background()]
        self._ready.set()
        try:
            await self._stop.wait()
        finally:
            self._server.close()
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            await self._server.wait_closed()

    def new_loop(self) -> asyncio.AbstractEventLoop:
        """The server's event loop: uvloop's when :attr:`fast_loop` and it is installed, else asyncio's own."""
        return new_event_loop(self.fast_loop)

    def _run_loop(self) -> None:
        name_os_thread(self.thread_name)
        self._loop = self.new_loop()
        try:
            self._loop.run_until_complete(self._main())
        except BaseException as exc:
            if self._ready.is_set():  # it was serving: the thread's own traceback reports it
                raise
            self._error = exc  # start() raises it
        finally:
            self._loop.close()
            self._ready.set()

    def start(self) -> Self:
        """Serve in a background thread; returns once listening (raises UserError if it cannot)."""
        self._thread = threading.Thread(target=self._run_loop, name=self.thread_name, daemon=True)
        self._thread.start()
        self._ready.wait(timeout=self.start_timeout)
        if self._error is not None:
            raise self._error
        return self

    def call_soon(self, fn: Callable[[], object]) -> bool:
        """Run ``fn()`` in the server's loop (thread-safe, never blocks); False once the loop is gone."""
        loop = self._loop
        if loop is None or loop.is_closed():
            return False
        try:
            loop.call_soon_threadsafe(fn)
        except RuntimeError:  # closed in between
            return False
        return True

    def run(self) -> None:
        """Block until Ctrl-C / :meth:`close` (starts the server if needed)."""
        if self._thread is None:
            self.start()
        assert self._thread is not None  # start() made it
        try:
            while self._thread.is_alive():
                self._thread.join(timeout=0.5)
        except KeyboardInterrupt:
            pass
        finally:
            self.close()

    def close(self) -> None:
        """Stop serving and join the thread (from any thread; nothing happens if it never started)."""
        stop = self._stop
        if stop is not None:
            self.call_soon(stop.set)
        if self._thread is not None:
            self._thread.join(timeout=self.join_timeout)
