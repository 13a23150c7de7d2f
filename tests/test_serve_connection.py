"""``serve``'s WebSocket connection (``serving/connection.py``): complete text frames cut from the received bytes
directly, everything else by ``websockets``' own parser — the same messages, in the same order, and the same
close codes, however the bytes arrive."""

from __future__ import annotations

import asyncio
import os
import struct

import pytest

websockets = pytest.importorskip("websockets")
from websockets.asyncio.client import connect  # noqa: E402
from websockets.asyncio.server import serve  # noqa: E402
from websockets.frames import apply_mask  # noqa: E402

from facecapges.serving.connection import ClientMessageConnection, MessageConnection  # noqa: E402


def frame(payload: bytes, head: int = 0x81, masked: bool = True, wide: int = 0) -> bytes:
    """One frame as a client writes it (``wide``: the 16- or 64-bit length form even for a short payload)."""
    n = len(payload)
    if wide == 64 or n >= 65536:
        length = struct.pack("!BQ", 0x80 * masked | 127, n)
    elif wide == 16 or n >= 126:
        length = struct.pack("!BH", 0x80 * masked | 126, n)
    else:
        length = bytes([0x80 * masked | n])
    if not masked:
        return bytes([head]) + length + payload
    key = os.urandom(4)
    return bytes([head]) + length + key + apply_mask(payload, key)


def exchange(chunks: list[bytes], max_size: int = 1 << 16, pause: float = 0.05) -> tuple[list, list, int | None, dict]:
    """Write ``chunks`` (raw bytes after the handshake) one by one; the messages the server's connection got,
    the replies the client got (each message echoed as text), the close code the client saw, the server side's
    state."""
    got: list = []
    seen: dict = {}

    async def handler(ws):
        def on_message(message):
            got.append(message)
            seen.setdefault("direct", []).append(ws._direct)  # True: cut directly (module docs)
            ws.send_text_now(message.encode() if isinstance(message, str) else b"binary")

        ws.deliver(on_message)
        await ws.wait_closed()

    async def main():
        async with serve(
            handler, "127.0.0.1", 0, create_connection=MessageConnection, max_size=max_size, compression=None
        ) as server:
            port = server.sockets[0].getsockname()[1]
            replies: list = []
            async with connect(
                f"ws://127.0.0.1:{port}/", create_connection=ClientMessageConnection, compression=None
            ) as ws:
                ws.deliver(replies.append)
                for chunk in chunks:
                    ws.transport.write(chunk)
                    await asyncio.sleep(pause)
                await asyncio.sleep(0.2)
                code = ws.protocol.close_rcvd.code if ws.protocol.close_rcvd else None
            await asyncio.sleep(0.1)
            return replies, code

    replies, code = asyncio.run(main())
    return got, replies, code, seen


def test_text_frames_however_split_and_whatever_the_length_form():
    msgs = [b'{"type":"ping"}', b"x" * 200, b"y" * 70000, "é€".encode() * 10]
    raw = frame(msgs[0]) + frame(msgs[1]) + frame(msgs[2], wide=64) + frame(msgs[3], wide=16)
    cuts = [1, 3, 7, 40, 220, 230, 5000, 70100, len(raw) - 2]  # within headers, keys, payloads, between frames
    chunks = [raw[a:b] for a, b in zip([0, *cuts], [*cuts, len(raw)])]
    got, replies, code, seen = exchange(chunks, max_size=1 << 17)
    assert got == [m.decode() for m in msgs] and replies == msgs and code is None
    assert seen["direct"] == [True] * 4  # the direct path took them


def test_control_frames_fragments_and_binary_keep_their_order():
    ping = frame(b"hi", head=0x89)
    raw = (
        frame(b"a")
        + ping
        + frame(b"b")
        + frame(b"c1", head=0x01)  # a text message in two fragments
        + frame(b"c2", head=0x80)
        + frame(b"\x00\x01", head=0x82)  # binary
        + frame(b"d")
    )
    got, replies, code, seen = exchange([raw[:9], raw[9:], frame(b"e")])
    assert got == ["a", "b", "c1c2", b"\x00\x01", "d", "e"] and code is None
    assert replies == [b"a", b"b", b"c1c2", b"binary", b"d", b"e"]
    # the first chunk ends inside the ping: websockets takes it whole, then the direct path takes "e"
    assert seen["direct"] == [False] * 5 + [True]


@pytest.mark.parametrize(
    ("raw", "code"),
    [
        (frame(b'{"x":"\xff"}'), 1007),  # not UTF-8
        (frame(b"z" * 300), 1009),  # above max_size
        (frame(b"a", masked=False), 1002),  # a client's frame must be masked
        (frame(b"a", head=0xC1), 1002),  # a reserved bit without an extension
        (frame(b"a", head=0x83), 1002),  # an unknown opcode
    ],
    # named: the frames' masks are random, and pytest-xdist's workers must collect the same test ids
    ids=["not-utf8", "above-max-size", "unmasked", "reserved-bit", "unknown-opcode"],
)
def test_faults_close_as_websockets_does(raw, code):
    got, _, seen_code, _ = exchange([frame(b"ok") + raw], max_size=256)
    assert got == ["ok"] and seen_code == code


def test_a_frame_cut_short_by_the_end_of_the_stream_is_reported_as_before():
    """An end of stream in the middle of a frame: websockets' parser gets the frame's first bytes and fails (1006)."""
    done: dict = {}

    async def handler(ws):
        ws.deliver(lambda m: None)
        await ws.wait_closed()
        done["code"], done["reason"] = ws.protocol.close_code, ws.protocol.close_exc

    async def main():
        async with serve(handler, "127.0.0.1", 0, create_connection=MessageConnection, compression=None) as server:
            port = server.sockets[0].getsockname()[1]
            async with connect(f"ws://127.0.0.1:{port}/", compression=None) as ws:
                ws.transport.write(frame(b"abcdef")[:5])
                await asyncio.sleep(0.1)
                ws.transport.write_eof()
                await asyncio.sleep(0.3)

    asyncio.run(main())
    assert done["code"] == 1006 and "stream ends after 3 bytes" in str(done["reason"].__cause__ or done["reason"])


def test_a_frame_sent_a_byte_at_a_time_is_looked_at_only_when_it_can_be_whole(monkeypatch):
    """A slow sender's frame (here 2,000 bytes, one per write) is collected until its length is reached, not
    parsed and copied again at each piece (that is quadratic in the frame's size: a client could spend the
    server's CPU with 64 KiB frames sent a byte at a time)."""
    calls = {"cut": 0, "received": 0}
    cut, received = MessageConnection._cut, MessageConnection.data_received

    def counting_cut(self, data):
        calls["cut"] += 1
        return cut(self, data)

    def counting_received(self, data):
        calls["received"] += 1
        return received(self, data)

    monkeypatch.setattr(MessageConnection, "_cut", counting_cut)
    monkeypatch.setattr(MessageConnection, "data_received", counting_received)
    payload = b"z" * 2000
    raw = frame(payload)
    got, replies, code, _ = exchange([raw[k : k + 1] for k in range(len(raw))], pause=0.001)
    assert got == [payload.decode()] and replies == [payload] and code is None
    assert calls["received"] > 100, calls  # it did arrive in pieces
    assert calls["cut"] <= 6, calls  # its first bytes, its header, its length known, the whole frame (not 2,000)
