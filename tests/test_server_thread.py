"""runtime/outputs/server_thread: the one start / ready / stop / join lifecycle of our WebSocket servers."""

from __future__ import annotations

import asyncio
import socket

import pytest
from websockets.sync.client import connect

from facecapges.errors import UserError
from facecapges.runtime.outputs.server_thread import ServerThread
from facecapges.runtime.outputs.viewer import ViewerServer


class Echo(ServerThread):
    """A real websockets echo server with a background task that counts its ticks."""

    thread_name = "echo-test"

    def __init__(self, port: int = 0, fail: BaseException | None = None):
        super().__init__()
        self.port, self.fail, self.ticks, self.cancelled = port, fail, 0, False

    async def _listen(self):
        from websockets.asyncio.server import serve

        if self.fail is not None:
            raise self.fail

        async def echo(ws):
            async for message in ws:
                await ws.send(message)

        return await serve(echo, "127.0.0.1", self.port)

    def _address(self):
        return "127.0.0.1", self.port

    def _background(self):
        return [self._tick()]

    async def _tick(self):
        try:
            while True:
                self.ticks += 1
                await asyncio.sleep(0.01)
        except asyncio.CancelledError:
            self.cancelled = True
            raise


def test_start_serves_runs_background_work_and_close_ends_the_thread():
    s = Echo().start()
    assert s.bound is not None and s.bound[0] == "127.0.0.1" and s.bound[1] > 0
    with connect(f"ws://127.0.0.1:{s.bound[1]}/") as ws:
        ws.send("hi")
        assert ws.recv(timeout=10) == "hi"
    ran = []
    assert s.call_soon(lambda: ran.append(1))
    s.close()
    assert not s._thread.is_alive() and s.cancelled and s.ticks > 0 and ran == [1]
    assert not s.call_soon(lambda: None)  # the loop is gone
    with socket.socket() as probe:  # the port is free again
        assert probe.connect_ex(("127.0.0.1", s.bound[1])) != 0
    s.close()  # twice is harmless


def test_an_address_in_use_is_one_user_error():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(UserError, match=rf"^cannot listen on 127\.0\.0\.1:{port} \("):
            Echo(port).start()
        with pytest.raises(UserError, match=rf"^viewer server cannot listen on 127\.0\.0\.1:{port} \("):
            ViewerServer(b"glTF", "127.0.0.1", port).start()


def test_a_failure_before_listening_is_raised_by_start_not_lost_in_the_thread():
    with pytest.raises(RuntimeError, match="broken"):
        Echo(fail=RuntimeError("broken")).start()


def test_close_before_start_does_nothing():
    s = Echo()
    s.close()
    assert s._thread is None and not s.call_soon(lambda: None)
