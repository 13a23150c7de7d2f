"""``serve``'s WebSocket connection: each message handed to a callback as it is parsed.

``websockets``' own connection queues every received message for a coroutine that awaits it
(``async for message in ws``): per message a future, a task switch and the queue's bookkeeping.
``serve`` handles a message in a few dozen microseconds and never awaits while it does (its
replies are written without waiting: :meth:`StreamServer._send`), so :class:`MessageConnection`
calls :attr:`~MessageConnection.on_message` with each complete message straight from the
protocol parser instead — the same parser, limits and close codes (a message above ``max_size``
closes with 1009, a text message that is not UTF-8 with 1007, as ``recv`` does). Messages that
arrive before a callback is set (while the style loads and before ``hello``) wait, in order,
and reading pauses while 16 of them wait (``websockets``' own high-water mark); :meth:`deliver`
hands them over. Measured (2026-12-04, load 13–19, 50 connections, 6.6 KB messages, server CPU
per message, two runs): 64–90 µs against 86–102 µs for ``async for`` on uvloop.

Replies go out the same way: :meth:`~MessageConnection.send_text_now` writes a message that is already
UTF-8 bytes as one text frame straight to the transport — what ``websockets``' ``broadcast`` does for one
connection (an open connection only, never inside a fragmented message), without encoding the text again,
building a ``Frame`` and queueing its bytes first.

:class:`ClientMessageConnection` is the same delivery at the client end, for :mod:`.loadgen`'s simulated
clients (messages as the bytes of their frames, not decoded).

Complete text frames are cut from the received bytes here (:meth:`~_Delivering.data_received`), not by
``websockets``' parser (a generator that reads each frame's header, length, mask and payload in turn, and a
``Frame`` object with its checks, per message): when the connection is open, ``websockets``' parser stands
between two frames with nothing buffered, and every complete frame of the received bytes is a final
(unfragmented) text frame without reserved bits, masked as the side requires (a client's frames are, a
server's are not) and within ``max_size``, those frames are unmasked and handed over at once; bytes of a
frame that has not fully arrived wait here for the rest (they are handed to ``websockets`` first when the
stream ends, so an end of stream mid-frame fails as before). Any other bytes — the handshake, control
frames (ping, pong, close), fragments, binary frames, a frame too large, a bad header — go, whole and in
order, to ``websockets``' own parser, which handles them as it always has (close codes included); the
direct path resumes once its parser stands between frames again. Measured (2026-12-04, callgrind of the
``serve`` process, 40 clients): see docs/performance.md, "eighth pass".
"""

from __future__ import annotations

import secrets
import struct
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from websockets.asyncio.client import ClientConnection
from websockets.asyncio.server import ServerConnection
from websockets.frames import CloseCode, Frame, Opcode, apply_mask
from websockets.protocol import Side, State
from websockets.streams import StreamReader

HIGH_WATER = 16  # messages waiting for a callback before reading pauses
MAX_FRAGMENTS = 1024  # frames of one fragmented message (its bytes are bounded by max_size)


if TYPE_CHECKING:  # the mixin's attributes are those of websockets' connection
    from websockets.asyncio.connection import Connection as _Connection
else:
    _Connection = object


class _Delivering(_Connection):
    """What both ends share: each complete message handed to :attr:`on_message` (module docs)."""

    decode_text = True  # text messages as str (UTF-8 checked, 1007 else); False: as the frames' bytes

    def _start_delivery(self) -> None:
        self.on_message: Callable[[str | bytes], None] | None = None
        self._inbox: list[str | bytes] = []  # messages before a callback was set
        self._parts: list[Frame] = []  # the frames of a fragmented message so far
        self._paused = False
        self._tail = bytearray()  # the start of a frame not fully received (the direct path: module docs)
        self._need = 0  # the bytes it must reach before it is looked at again (a frame sent in pieces)
        self._direct = False  # websockets' parser is known to stand between frames with nothing buffered
        self._masked = 0x80 if self.protocol.side is Side.SERVER else 0  # the mask bit a received frame has

    def deliver(self, callback: Callable[[str | bytes], None]) -> None:
        """From now on, hand every message to ``callback``; the ones waiting first, in order."""
        self.on_message = callback
        inbox, self._inbox = self._inbox, []
        for message in inbox:
            if self.on_message is not callback:  # the callback replaced itself (a stream closed)
                break
            callback(message)
        if self._paused:
            self._paused = False
            self.transport.resume_reading()

    def send_text_now(self, data: bytes) -> bool:
        """Write ``data`` (UTF-8 text) as one text frame now, without waiting (module docs); False (nothing
        written) when the connection is not open or the transport refuses it, as ``broadcast`` skips it."""
        protocol = self.protocol
        if protocol.state is not State.OPEN or self.send_in_progress is not None:
            return False
        try:
            if protocol.extensions:  # none on serve's connections (no compression): websockets' own framing
                protocol.send_text(data)
                self.send_data()
                return True
            n = len(data)  # FIN + text, the length in 7, 7+16 or 7+64 bits; a client's frame masked (RFC 6455)
            if protocol.side is Side.CLIENT:
                mask = secrets.token_bytes(4)  # as websockets draws it
                head = _header(n, 0x80) + mask
                data = apply_mask(data, mask)
            else:
                head = _HEAD[n] if n < 126 else _header(n, 0)
            self.transport.write(head + data)
        except Exception:  # noqa: BLE001  as broadcast: a connection that cannot take it is skipped
            return False
        return True

    def process_event(self, event) -> None:
        if not isinstance(event, Frame) or event.opcode not in _DATA:
            super().process_event(event)  # the handshake, pings, pongs and close: websockets' own handling
            return
        if event.opcode is not Opcode.CONT:
            self._parts.clear()
        self._parts.append(event)
        if not event.fin:
            if len(self._parts) > MAX_FRAGMENTS:
                self._fail(CloseCode.MESSAGE_TOO_BIG, "too many fragments")
            return
        parts, self._parts = self._parts, []
        data = parts[0].data if len(parts) == 1 else b"".join(p.data for p in parts)
        self._message(parts[0].opcode is Opcode.TEXT, data)

    def data_received(self, data: bytes) -> None:
        """Complete text frames straight to :meth:`_message`, anything else to ``websockets`` (module docs)."""
        if self._tail:  # collected, not re-parsed, until it can be a whole frame (or a whole header)
            self._tail += data
            if len(self._tail) < self._need:
                return
            data, self._tail = bytes(self._tail), bytearray()
        cut = self._cut(data) if self._direct or self._between_frames() else None
        if cut is None:  # websockets' own parsing, as before, until its parser stands between frames again
            self._direct = False
            super().data_received(data)
            return
        frames, rest, self._need = cut
        if rest < len(data):
            self._tail = bytearray(data[rest:])
        for start, end in frames:  # a masked frame's key is the 4 bytes before its payload
            self._message(
                True, apply_mask(data[start:end], data[start - 4 : start]) if self._masked else data[start:end]
            )

    def eof_received(self) -> None:
        if self._tail:  # a frame cut short: websockets' parser sees its bytes and fails as it did before
            tail, self._tail = bytes(self._tail), bytearray()
            super().data_received(tail)
        super().eof_received()

    def _between_frames(self) -> bool:
        """``websockets``' parser waits for a frame's first byte with nothing buffered, on an open connection
        without extensions or debug logging: the condition for the direct path (module docs)."""
        protocol = self.protocol
        if protocol.state is not State.OPEN or protocol.extensions or protocol.debug or protocol.reader.buffer:
            return False
        gen: Any = protocol.parser  # the innermost generator it waits in: reader.at_eof() between frames (parse())
        while getattr(gen, "gi_yieldfrom", None) is not None:
            gen = gen.gi_yieldfrom
        self._direct = getattr(gen, "gi_code", None) is _AT_EOF
        return self._direct

    def _cut(self, data: bytes) -> tuple[list[tuple[int, int]], int, int] | None:
        """The payloads (start, end) of the complete frames of ``data``, where the incomplete rest starts and how
        many bytes that rest needs before it is worth looking at again (its frame's, or its header's, while its
        length is not known: so a frame sent a byte at a time is not parsed and copied again at each byte);
        None if any frame is not for the direct path (module docs: websockets' parser takes ``data`` whole)."""
        protocol = self.protocol
        if protocol.state is not State.OPEN or protocol.current_size is not None:
            return None
        limit = protocol.max_message_size
        if protocol.max_fragment_size is not None:
            limit = protocol.max_fragment_size if limit is None else min(limit, protocol.max_fragment_size)
        frames, pos, end, masked = [], 0, len(data), self._masked
        need = 2
        while end - pos >= 2:
            head, length = data[pos], data[pos + 1]
            if head != 0x81 or length & 0x80 != masked:  # not a final text frame, masked as this side's
                return None
            length &= 0x7F
            start = pos + 2
            if length >= 126:
                size = 2 if length == 126 else 8
                if end - start < size:
                    need = start + size - pos
                    break
                length = int.from_bytes(data[start : start + size], "big")
                start += size
            if limit is not None and length > limit:
                return None
            start += 4 if masked else 0
            if end - start < length:
                need = start + length - pos
                break
            frames.append((start, start + length))
            pos = start + length
            need = 2
        return frames, pos, need

    def _message(self, text: bool, data) -> None:
        """A complete message: to the callback (or the inbox while there is none; module docs)."""
        message: str | bytes
        if text and self.decode_text:
            try:
                message = bytes(data).decode()
            except UnicodeDecodeError as exc:
                self._fail(CloseCode.INVALID_DATA, f"{exc.reason} at position {exc.start}")
                return
        else:
            message = bytes(data)
        callback = self.on_message
        if callback is not None:
            callback(message)
            return
        self._inbox.append(message)
        if len(self._inbox) >= HIGH_WATER and not self._paused:
            self._paused = True
            self.transport.pause_reading()

    def _fail(self, code: CloseCode, reason: str) -> None:
        self._parts = []
        self.protocol.fail(code, reason)
        try:
            self.send_data()
        except Exception as exc:  # noqa: BLE001  as websockets' own data_received: the connection is lost
            self.set_connection_exc(exc)


class MessageConnection(_Delivering, ServerConnection):
    """A server connection that calls :attr:`on_message` (text as ``str``, binary as ``bytes``) for
    each complete message (module docs). Not for ``recv``: nothing reaches its queue."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._start_delivery()


class ClientMessageConnection(_Delivering, ClientConnection):
    """The client end (:mod:`.loadgen`'s simulated clients): every message, text or binary, handed to
    :attr:`on_message` as the bytes of its frames (not decoded: the load generator matches bytes)."""

    decode_text = False

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._start_delivery()


_DATA = (Opcode.TEXT, Opcode.BINARY, Opcode.CONT)
_AT_EOF = StreamReader.at_eof.__code__  # what websockets' parser runs between frames (_between_frames)
_HEAD = [bytes((0x81, n)) for n in range(126)]  # a short unmasked text frame's header, by length
_HEAD16 = struct.Struct("!BBH")
_HEAD64 = struct.Struct("!BBQ")


def _header(n: int, masked: int) -> bytes:
    """A text frame's header for ``n`` bytes (``masked``: 0x80 when a mask follows)."""
    if n < 126:
        return bytes((0x81, masked | n))
    return _HEAD16.pack(0x81, masked | 126, n) if n < 65536 else _HEAD64.pack(0x81, masked | 127, n)
