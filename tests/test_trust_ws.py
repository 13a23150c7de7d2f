"""Attacks on the two WebSocket servers (serve and the viewer feed), bounded and on loopback only:
idle sockets holding slots, one address taking every slot, a trickle of input, deep JSON, long paths."""

from __future__ import annotations

import asyncio
import json
import urllib.error
import urllib.request

import numpy as np
import pytest
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

from facecapges.runtime.outputs import protocol
from facecapges.runtime.outputs.viewer import ViewerServer
from facecapges.serving.server import ServeConfig, StreamServer


@pytest.fixture()
def serve(default_checkpoint):
    """``make(**ServeConfig options)`` → a started server of the installed matching style: these tests attack the
    server's connections, not the poses, and its model process starts without torch (about 1.5 s against 5-6 s
    for a random network's at load 6)."""
    ckpt = default_checkpoint
    servers = []
    logs: list[str] = []

    def make(**over) -> StreamServer:
        s = StreamServer(ckpt, ServeConfig(port=0, **over), log=logs.append).start()
        s.logs = logs
        servers.append(s)
        return s

    yield make
    for s in servers:
        s.close()


def frame(k: int) -> str:
    return protocol.encode_input(k, np.zeros(1067, np.float32), np.zeros(52, np.float32),
                                 np.array([1, 0, 0, 0, 1, 0], np.float32))


async def close_code(ws, timeout: float = 10.0) -> int:
    try:
        while True:
            await asyncio.wait_for(ws.recv(), timeout=timeout)
    except ConnectionClosed as exc:
        return exc.rcvd.code if exc.rcvd else -1


def test_idle_sockets_cannot_hold_the_slots(serve):
    srv = serve(max_streams=12, first_input_timeout=1.0)

    async def main():
        idle = [await connect(srv.url) for _ in range(12)]  # the attack: connect, never send
        for ws in idle:
            await ws.recv()  # hello
        late = await connect(srv.url)
        refused = json.loads(await late.recv())
        assert refused["type"] == "error" and "full" in refused["message"] and await close_code(late) == 1013
        codes = await asyncio.gather(*[close_code(ws) for ws in idle])  # freed after the first-input timeout
        assert codes == [1008] * 12
        await asyncio.sleep(0.2)
        async with connect(srv.url) as ws:  # a real client gets in and is served
            assert json.loads(await ws.recv())["type"] == "hello"
            await ws.send(frame(0))
            assert json.loads(await ws.recv())["type"] == "pose"

    asyncio.run(asyncio.wait_for(main(), 30))
    assert srv.summary()["no_input_closes"] == 12


def test_one_address_cannot_take_every_slot_and_a_trickle_is_closed(serve):
    srv = serve(max_streams=10, max_per_address=3, min_input_rate=2.0, rate_window=1.0)

    async def main():
        held = [await connect(srv.url) for _ in range(3)]
        for ws in held:
            await ws.recv()
        extra = await connect(srv.url)
        msg = json.loads(await extra.recv())
        assert "per client address" in msg["message"] and await close_code(extra) == 1013

        async def trickle(ws):  # one frame now and then keeps no slot
            for k in range(6):
                await ws.send(frame(k))
                await asyncio.sleep(0.8)

        async def live(ws):  # 15 frames per second keeps its slot
            for k in range(45):
                await ws.send(frame(k))
                assert json.loads(await ws.recv())["type"] == "pose"
                await asyncio.sleep(1 / 15)
            return "served"

        t = asyncio.ensure_future(trickle(held[0]))
        code = await close_code(held[0])
        t.cancel()
        assert code == 1008
        assert await live(held[1]) == "served"
        for ws in held[1:]:
            await ws.close()

    asyncio.run(asyncio.wait_for(main(), 40))
    assert srv.summary()["slow_input_closes"] >= 1 and srv.summary()["refused_address"] == 1


def test_deep_json_is_a_bad_message_logged_once_per_connection(serve, capfd):
    srv = serve(rate_limit=1000.0)

    async def main():
        async with connect(srv.url) as ws:
            await ws.recv()
            for _ in range(40):
                await ws.send("[" * 60000)  # fits in 64 KiB
                err = json.loads(await ws.recv())
                assert err["type"] == "error" and "nested too deeply" in err["message"]
            await ws.send(frame(0))
            assert json.loads(await ws.recv())["type"] == "pose"  # the connection still works

    asyncio.run(asyncio.wait_for(main(), 30))
    assert srv.summary()["bad_messages"] == 40
    assert len([m for m in srv.logs if "bad message" in m]) == 1
    assert "Traceback" not in capfd.readouterr().err


def test_viewer_rejects_deep_json_and_impossible_paths(tmp_path, capfd):
    (tmp_path / "web").mkdir()
    (tmp_path / "web" / "viewer.html").write_text("<html></html>")
    (tmp_path / "three").mkdir()
    logs: list[str] = []
    v = ViewerServer(b"glTF", port=0, web_dir=tmp_path / "web", three_dir=tmp_path / "three", log=logs.append).start()
    try:
        for path in ("/web/" + "a" * 5000, "/three/" + "b/" * 3000 + "c.js", "/web/%00x"):
            try:
                with urllib.request.urlopen(v.url.rstrip("/") + path, timeout=10) as r:
                    status = r.status
            except urllib.error.HTTPError as e:
                status = e.code
            assert status == 404, path

        async def main():
            async with connect(v.url.replace("http", "ws") + "ws") as ws:
                await ws.recv()  # hello
                for _ in range(30):
                    await ws.send("[" * 60000)
                    assert "nested too deeply" in json.loads(await ws.recv())["message"]

        asyncio.run(asyncio.wait_for(main(), 30))
    finally:
        v.close()
    assert v.bad_messages == 30 and len(logs) == 1
    assert "Traceback" not in capfd.readouterr().err
