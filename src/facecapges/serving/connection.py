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
"""

from __future__ import annotations

import secrets
import struct
from collections.abc import Callable
from typing import TYPE_CHECKING

from websockets.asyncio.client import ClientConnection
from websockets.asyncio.server import ServerConnection
from websockets.frames import CloseCode, Frame, Opcode, apply_mask
from websockets.protocol import Side, State

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
        message: str | bytes
        if parts[0].opcode is Opcode.TEXT and self.decode_text:
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
_HEAD = [bytes((0x81, n)) for n in range(126)]  # a short unmasked text frame's header, by length
_HEAD16 = struct.Struct("!BBH")
_HEAD64 = struct.Struct("!BBQ")


def _header(n: int, masked: int) -> bytes:
    """A text frame's header for ``n`` bytes (``masked``: 0x80 when a mask follows)."""
    if n < 126:
        return bytes((0x81, masked | n))
    return _HEAD16.pack(0x81, masked | 126, n) if n < 65536 else _HEAD64.pack(0x81, masked | 127, n)
