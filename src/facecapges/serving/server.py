"""``facecapges serve``: many live streams over WebSocket, batched into one model call per tick.

Every WebSocket connection is one live stream with its own history and LSTM state —
a slot of a :class:`~facecapges.model.batched.BatchedStreamingGenerator`. Messages are
those of :mod:`facecapges.runtime.outputs.protocol` (the browser viewer's format): the server
sends ``hello`` on connect; the client sends one ``input`` per frame (its audio
samples, 52 face weights, head rot6d) and gets one ``pose`` back with the same
``frame`` number; ``ping`` → ``pong``; a bad message → ``error`` (the connection stays).

Ticks (continuous batching). A single batching task runs for the whole server: each
*tick* it takes, from every stream that has a frame waiting, its oldest frame, and
runs all of them as ONE batched ``step`` (in the model's own process,
:mod:`facecapges.serving.model_process`; the event loop keeps receiving while it waits
for the pipe); the next tick starts as soon as that one is done, something is waiting
and at least ``tick_ms`` (15 ms by default) have passed since the previous tick
started — the pause lets the frames of more streams arrive, because a batched call
costs a fixed ~2 ms plus a fraction of a millisecond per stream. A stream's frames
are therefore processed in order, at most one per tick, and a frame waits at most
for the tick in progress and the pause. ``latency_ms`` in each ``pose`` holds
``queue`` (receipt → its tick starts), ``model`` (the batched call, shared by the
tick), ``output`` (encoding) and ``total`` (receipt → sent).

Isolation. Nothing a client does reaches another stream's state: a message that is
not valid JSON/protocol gets an ``error`` reply and is dropped; messages above
``rate_limit`` per second (a token bucket holding one second of messages) are dropped
with one ``error`` per second; a stream with ``max_pending`` frames still waiting
drops new ones (``error`` "busy"); a message larger than the protocol's 64 KiB closes
that connection (1009); a client that stops reading is closed once its unsent output
exceeds ``send_buffer_bytes`` (1008), because replies are written without waiting
for any client (each connection's kernel send buffer is capped at 64 KiB so that
unsent output shows up in ours); one that stops sending is closed after ``idle_timeout`` seconds
(1000); disconnects free the slot between ticks. When ``max_streams`` are connected a
new connection gets an ``error`` and is closed with 1013 ("try again later").

Slots are for streams, not for sockets: the handshake must end within 10 s
(:data:`facecapges.runtime.outputs.ws.HANDSHAKE_TIMEOUT`), the first ``input`` must come within
``first_input_timeout`` seconds of the ``hello``, and afterwards a stream must keep at
least ``min_input_rate`` inputs per second over every ``rate_window`` seconds (a live
stream sends 15) — else it is closed (1008) and its slot freed. One client address may
hold at most ``max_per_address`` streams (1013 beyond); by default 16, and no limit
while the server is bound to loopback (every client is this machine) — except that a
connection from loopback with an ``X-Forwarded-For`` header (a local reverse proxy) counts
against the forwarded address, capped at ``max_per_address`` or 16.

Fair admission when full: while some slot-holding stream has sent no input for
:data:`EVICT_IDLE_S` seconds, a new client is not refused but let in *on probation* (a
hello, no slot; at most ``max_streams`` such at once, the one waiting the longest closed to
make room for a newer one). Its first input takes the slot of
the stream idle the longest, which is closed (1013, "evicted"); a newcomer that sends no
input evicts nobody and is closed by ``first_input_timeout``. A live stream (15 inputs a
second) is never evicted, so clients that reopen idle sockets as they are closed cannot
lock real ones out, even when every client shares one address (loopback, a proxy).
Bad messages are answered and logged on one line per connection.

Security: it binds 127.0.0.1 unless told otherwise; while bound to loopback it only
answers handshakes whose ``Host`` names a loopback host (:mod:`facecapges.runtime.outputs.ws`,
as the viewer server does). There is no authentication: bind other addresses only on
trusted networks.
"""

from __future__ import annotations

import asyncio
import collections
import socket
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from facecapges.errors import UserError, echo, echo_warning
from facecapges.runtime.outputs import protocol
from facecapges.runtime.outputs.server_thread import ServerThread
from facecapges.runtime.outputs.ws import (
    SERVE_OPTIONS,
    ConnectionLog,
    error_message,
    is_loopback,
    peer_host,
    pong_message,
    refuse_foreign_host,
)
from facecapges.serving.config import ServeConfig
from facecapges.timing import AUDIO_SR

if TYPE_CHECKING:
    from websockets.asyncio.server import Server, ServerConnection

KERNEL_SEND_BUFFER = 64 * 1024  # SO_SNDBUF per connection (~2 s of poses at 15 fps)
EVICT_IDLE_S = 2.0  # a stream without input this long gives its slot to a new client when the server is full


def client_address(ws) -> tuple[str, bool]:
    """(the address a stream counts against, whether a local proxy forwarded it).

    A connection from loopback that carries ``X-Forwarded-For`` (a reverse proxy on this
    machine) counts against the address the proxy saw — its last entry — so the per-address
    cap holds behind a proxy too; from anywhere else the header is ignored (it is the client's word)."""
    address = peer_host(ws)
    if is_loopback(address):
        request = getattr(ws, "request", None)
        fwd = request.headers.get("X-Forwarded-For") if request is not None else None
        if fwd and fwd.split(",")[-1].strip():
            return fwd.split(",")[-1].strip()[:64], True
    return address, False


@dataclass
class _Stream:
    ws: ServerConnection
    id: int
    slot: int | None = None
    pending: collections.deque = field(default_factory=collections.deque)
    tokens: float = 0.0
    t_tokens: float = 0.0
    last_input: float = 0.0
    last_limit_error: float = -1e9
    closed: bool = False
    frames: int = 0
    address: str = "?"
    inputs: int = 0  # inputs received in the current rate window
    window_t0: float | None = None  # start of the rate window (the first input)
    intensity: float = 1.0  # the stream's intensity dial (its client's `intensity` messages)
    applied: float | None = None  # the value its slot has (set between ticks)
    probation: bool = False  # connected while full: no slot until its first input takes an idle one


_error = error_message


class StreamServer(ServerThread):
    """The multi-stream WebSocket server (module docs). :meth:`start` runs it in a thread,
    :meth:`run` blocks until interrupted (:class:`~facecapges.runtime.outputs.server_thread.ServerThread`)."""

    thread_name = "serve"
    start_timeout = 30.0
    join_timeout = 10.0

    def __init__(self, checkpoint, config: ServeConfig | None = None, log=None):
        from facecapges.serving.model_process import ModelProcess

        super().__init__()
        self.cfg = config or ServeConfig()
        c = self.cfg
        if c.max_streams < 1:
            raise UserError("--max-streams must be at least 1")
        if c.rate_limit <= 0:
            raise UserError("--rate-limit must be a positive number of frames per second")
        self.ckpt = checkpoint
        self.fps = checkpoint.fps  # an int, as in the viewer's hello
        self.sr = AUDIO_SR
        # the batched kernel in a process of its own: the event loop never holds it up (model_process docs)
        self.gen = ModelProcess(checkpoint, c.threads, c.max_streams)
        self.loopback_only = is_loopback(c.host)
        # streams per client address: None = no cap (loopback without a proxy: every client is this machine)
        self.per_address = c.max_per_address if c.max_per_address is not None else (None if self.loopback_only else 16)
        self.log = log or (lambda *_: None)
        self.conn_log = ConnectionLog(self.log, "serve")
        self.streams: dict[int, _Stream] = {}
        self._next_id = 0
        self._wake = asyncio.Event()  # made anew in the server's loop by _listen
        self.stats: collections.Counter[str] = collections.Counter()
        self._closing: set[asyncio.Future] = set()  # close tasks still running
        self.batch_sizes: collections.deque = collections.deque(maxlen=10_000)

    # ---------------------------------------------------------------- WebSocket
    def _process_request(self, connection, request):
        refused = refuse_foreign_host(connection, request, self.loopback_only)
        if refused is not None:
            self.stats["rejected_hosts"] += 1
        return refused

    def _allow(self, st: _Stream, now: float) -> bool:
        """Token bucket: ``rate_limit`` messages per second, one second of burst."""
        rate = self.cfg.rate_limit
        st.tokens = min(rate, st.tokens + (now - st.t_tokens) * rate)
        st.t_tokens = now
        if st.tokens >= 1.0:
            st.tokens -= 1.0
            return True
        return False

    async def _handler(self, ws) -> None:
        from websockets.exceptions import ConnectionClosed

        address, forwarded = client_address(ws)
        per_address = (self.cfg.max_per_address or 16) if forwarded else self.per_address
        refusal = None
        probation = False
        if per_address is not None and sum(st.address == address for st in self.streams.values()) >= per_address:
            self.stats["refused_address"] += 1
            refusal = f"at most {per_address} streams per client address; try again later"
        elif sum(not st.probation for st in self.streams.values()) >= self.cfg.max_streams:
            probation = self._idlest(time.monotonic()) is not None
            waiting = [st for st in self.streams.values() if st.probation and not st.closed]
            if probation and len(waiting) >= self.cfg.max_streams:  # the oldest waiting one makes room
                old = min(waiting, key=lambda s: s.last_input)
                old.closed = True
                self.streams.pop(old.id, None)
                self.stats["evicted_waiting"] += 1
                self._close_later(old.ws, 1013, "evicted: no input while the server was full")
            if not probation:
                self.stats["refused_full"] += 1
                refusal = f"server full: {self.cfg.max_streams} streams; try again later"
        if refusal is not None:
            try:
                await ws.send(_error(refusal))
                await ws.close(1013, refusal.split(":")[0][:100])
            except ConnectionClosed:
                pass
            return
        sock = ws.transport.get_extra_info("socket") if getattr(ws, "transport", None) else None
        if sock is not None:  # a bounded kernel buffer, so a client that stops reading shows up in ours
            try:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, KERNEL_SEND_BUFFER)
            except OSError:
                pass
        now = time.monotonic()
        st = _Stream(
            ws=ws,
            id=self._next_id,
            tokens=self.cfg.rate_limit,
            t_tokens=now,
            last_input=now,
            address=address,
            intensity=self.cfg.intensity,
            probation=probation,
        )
        self._next_id += 1
        self.streams[st.id] = st
        self.stats["connections"] += 1
        try:
            await ws.send(protocol.encode_hello(self.fps, self.sr, intensity=st.intensity))
            async for message in ws:
                now = time.monotonic()
                if not self._allow(st, now):
                    self.stats["rate_limited"] += 1
                    if now - st.last_limit_error >= 1.0:
                        st.last_limit_error = now
                        await ws.send(
                            _error(f"rate limit: at most {self.cfg.rate_limit:g} messages per second; messages dropped")
                        )
                    continue
                try:
                    msg = protocol.decode_client(message, self.fps, self.sr)
                except protocol.ProtocolError as exc:
                    self.stats["bad_messages"] += 1
                    self.conn_log.bad_message(ws, exc)
                    await ws.send(_error(str(exc)))
                    continue
                if msg["type"] == "ping":
                    await ws.send(pong_message())
                    continue
                if msg["type"] == "intensity":  # applied to the stream's slot between ticks
                    st.intensity = msg["value"]
                    await ws.send(protocol.encode_intensity(st.intensity))
                    continue
                if st.probation and not self._admit(st, now):
                    refusal = f"server full: {self.cfg.max_streams} streams; try again later"
                    await ws.send(_error(refusal))
                    await ws.close(1013, "server full")
                    break
                st.last_input = now
                st.inputs += 1
                if st.window_t0 is None:
                    st.window_t0 = now
                if len(st.pending) >= self.cfg.max_pending:
                    self.stats["dropped_busy"] += 1
                    await ws.send(
                        _error(
                            f"busy: frame {msg['input'].index} dropped "
                            f"({self.cfg.max_pending} frames of this stream are waiting)"
                        )
                    )
                    continue
                st.pending.append((msg["input"], now))
                self._wake.set()
        except ConnectionClosed:
            pass
        except Exception as exc:  # noqa: BLE001  never expected: one line, this connection only
            self.stats["handler_errors"] += 1
            self.log(f"serve: stream {st.id} ({address}) closed after an internal error: {exc!r:.200}")
            await ws.close(1011, "internal error")
        finally:
            st.closed = True
            self.conn_log.closed(ws)
            self.streams.pop(st.id, None)
            if ws.close_code == 1009:
                self.stats["oversized_closes"] += 1
            self._wake.set()  # the batching task frees the slot between ticks

    def _idlest(self, now: float) -> _Stream | None:
        """The slot-holding stream without input for the longest, if that is :data:`EVICT_IDLE_S` or more."""
        idle = [
            st
            for st in self.streams.values()
            if not st.closed and not st.probation and now - st.last_input >= EVICT_IDLE_S
        ]
        return min(idle, key=lambda s: s.last_input) if idle else None

    def _admit(self, st: _Stream, now: float) -> bool:
        """A stream on probation sent its first input: give it a slot — a free one, or that of the
        idlest stream, which is closed (1013, "evicted"). False when every slot streams."""
        if sum(not s.probation for s in self.streams.values()) >= self.cfg.max_streams:
            victim = self._idlest(now)
            if victim is None:
                self.stats["refused_full"] += 1
                return False
            victim.closed = True
            self.streams.pop(victim.id, None)  # its slot is freed at the next tick, before this one's opens
            self.stats["evicted_idle"] += 1
            self._close_later(victim.ws, 1013, "evicted: idle while the server was full")
        st.probation = False
        return True

    # ---------------------------------------------------------------- ticks
    async def _compute(
        self, slots: list[int], audio: list, face: np.ndarray, head: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """One batched step in the model process: poses (B, 47, 6) and quaternions (B, 47, 4). The event
        loop runs on while the model process works and resumes when its pipe is readable."""
        loop = asyncio.get_running_loop()
        self.gen.submit(slots, audio, face, head)
        ready = loop.create_future()
        fd = self.gen.fileno()

        def wake() -> None:
            if not ready.done():
                ready.set_result(None)

        loop.add_reader(fd, wake)
        try:
            await ready
        finally:
            loop.remove_reader(fd)
        return self.gen.collect()

    def _sync_slots(self) -> None:
        """Between ticks, in one round trip: free the slots of closed streams, give new streams theirs,
        apply changed intensity dials."""
        live = {st.slot for st in self.streams.values() if st.slot is not None}
        close = sorted(self.gen.open_slots - live)
        new = [st for st in self.streams.values() if st.slot is None and not st.probation]
        ref = {id(st): -1 - k for k, st in enumerate(new)}  # the k-th stream opened by this sync
        dial = [
            st for st in self.streams.values() if (st.slot is not None or id(st) in ref) and st.applied != st.intensity
        ]
        if not (close or new or dial):
            return
        dials = [(ref[id(st)] if st.slot is None else st.slot, st.intensity) for st in dial]
        slots = self.gen.sync(close, len(new), dials)
        for st, slot in zip(new, slots):
            st.slot = slot
        for st in dial:
            st.applied = st.intensity

    def _send(self, st: _Stream, text: str) -> None:
        """Write without waiting for the client; close a client that stopped reading."""
        from websockets.asyncio.server import broadcast

        if st.closed:
            return
        broadcast([st.ws], text)
        transport = getattr(st.ws, "transport", None)
        if transport is not None and transport.get_write_buffer_size() > self.cfg.send_buffer_bytes:
            self.stats["slow_closes"] += 1
            st.closed = True
            st.pending.clear()
            self._close_later(st.ws, 1008, "not reading its output")

    def _close_later(self, ws: ServerConnection, code: int, reason: str) -> None:
        """Close ``ws`` without waiting; the task is kept until it ends (asyncio holds tasks weakly)."""
        task = asyncio.ensure_future(ws.close(code, reason))
        self._closing.add(task)
        task.add_done_callback(self._closing.discard)

    async def _batch_loop(self) -> None:
        last = -1e9
        while True:
            await self._wake.wait()
            wait = last + self.cfg.tick_ms / 1000.0 - time.monotonic()
            if wait > 0:  # let the frames of more streams arrive: fewer, larger batched calls
                await asyncio.sleep(wait)
            self._wake.clear()
            last = time.monotonic()
            self._sync_slots()
            due = [st for st in self.streams.values() if st.pending and not st.closed and st.slot is not None]
            if not due:
                continue
            items = [st.pending.popleft() for st in due]
            inputs = [it[0] for it in items]
            face = np.stack([i.face for i in inputs])  # the tick's face and head: the step's and the replies'
            head = np.stack([i.head for i in inputs])
            t0 = time.monotonic()
            try:
                _, quats = await self._compute(
                    [st.slot for st in due if st.slot is not None], [i.audio for i in inputs], face, head
                )
            except Exception as exc:  # noqa: BLE001  never expected: report it to the streams of this tick
                self.stats["tick_errors"] += 1
                self.log(f"tick failed: {exc!r}")
                for st in due:
                    self._send(st, _error(f"internal error in this frame: {exc.__class__.__name__}"))
                continue
            t1 = time.monotonic()

            def latency(i: int) -> dict:
                now = time.monotonic()
                return {
                    "queue": (t0 - items[i][1]) * 1e3,
                    "model": (t1 - t0) * 1e3,
                    "output": (now - t1) * 1e3,
                    "total": (now - items[i][1]) * 1e3,
                }

            index = [i.index for i in inputs]
            texts = protocol.encode_poses(
                index,
                [k / self.fps for k in index],
                quats,
                face,
                head,
                [i.face_found for i in inputs],
                latency,
            )
            for st, text in zip(due, texts):
                st.frames += 1
                self._send(st, text)
            self.stats["frames"] += len(due)
            self.stats["ticks"] += 1
            self.batch_sizes.append(len(due))
            if any(st.pending for st in self.streams.values()):
                self._wake.set()

    def _overdue(self, st: _Stream, now: float) -> tuple[str, int, str] | None:
        """Why a stream loses its slot now: (stats key, close code, reason), or None."""
        c = self.cfg
        if c.idle_timeout > 0 and now - st.last_input > c.idle_timeout:
            return "idle_closes", 1000, f"idle for {c.idle_timeout:g} s"
        if st.window_t0 is None:
            if c.first_input_timeout > 0 and now - st.last_input > c.first_input_timeout:
                return "no_input_closes", 1008, f"no input within {c.first_input_timeout:g} s"
        elif c.min_input_rate > 0 and now - st.window_t0 >= c.rate_window:
            rate = st.inputs / (now - st.window_t0)
            st.inputs, st.window_t0 = 0, now
            if rate < c.min_input_rate:
                return "slow_input_closes", 1008, f"input slower than {c.min_input_rate:g} frames/s"
        return None

    async def _idle_loop(self) -> None:
        c = self.cfg
        periods = [p for p in (c.idle_timeout, c.first_input_timeout, c.rate_window) if p > 0]
        while periods:
            await asyncio.sleep(min(1.0, min(periods) / 4))
            now = time.monotonic()
            for st in list(self.streams.values()):
                why = None if st.closed else self._overdue(st, now)
                if why is not None:
                    self.stats[why[0]] += 1
                    st.closed = True
                    self._close_later(st.ws, why[1], why[2])

    # ---------------------------------------------------------------- lifecycle (ServerThread)
    async def _listen(self) -> Server:
        from websockets.asyncio.server import serve

        self._wake = asyncio.Event()
        c = self.cfg
        return await serve(
            self._handler, c.host, c.port, process_request=self._process_request, compression=None, **SERVE_OPTIONS
        )

    def _address(self) -> tuple[str, int]:
        return self.cfg.host, self.cfg.port

    def _background(self) -> list:
        return [self._batch_loop(), self._idle_loop()]

    @property
    def url(self) -> str:
        host, port = self.bound or (self.cfg.host, self.cfg.port)
        return f"ws://{host if ':' not in host else f'[{host}]'}:{port}/"

    def summary(self) -> dict:
        b = list(self.batch_sizes)
        return dict(
            self.stats,
            streams=len(self.streams),
            mean_batch=round(float(np.mean(b)), 2) if b else 0.0,
            max_batch=max(b) if b else 0,
        )

    def close(self) -> None:
        super().close()
        self.gen.shutdown()


def serve_streams(checkpoint, style: str | None, cfg: ServeConfig, say=echo, warn=echo_warning) -> dict:
    """The whole ``serve`` command: check ``cfg``, load the style, serve until interrupted; returns the summary.

    ``say(text, err=False)`` gets the start line, the server's log (``err=True``) and the
    summary; ``warn`` a warning when the address is not a loopback one."""
    from facecapges.model.checkpoint import load_checkpoint

    cfg.check()
    ckpt = load_checkpoint(checkpoint, style)
    server = StreamServer(ckpt, cfg, log=lambda m: say(m, err=True))
    if not is_loopback(cfg.host):
        warn(f"warning: listening on {cfg.host}: anyone who can reach it can use it (no authentication)")
    server.start()
    say(
        f"serving {ckpt.path.name} on {server.url} (max {cfg.max_streams} streams, "
        f"{cfg.rate_limit:g} msg/s per stream); Ctrl-C stops"
    )
    try:
        server.run()
    finally:
        summary = server.summary()
        say(f"served: {summary}")
    return summary
