"""``facecapges serve``: many live streams over WebSocket, batched into one model call per tick.

Every WebSocket connection is one live stream with its own history and LSTM state —
a slot of a :class:`~facecapges.network.batched.BatchedNetworkStreams`. Messages are
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
new connection gets an ``error`` and is closed with 1013 ("try again later") — unless a
slow stream is in its way (fair admission, below).

Slots are for streams, not for sockets: the handshake must end within 10 s
(:data:`facecapges.runtime.outputs.ws.HANDSHAKE_TIMEOUT`), the first ``input`` must come within
``first_input_timeout`` seconds of the ``hello``, and afterwards a stream must keep at
least ``min_input_rate`` inputs per second over every ``rate_window`` seconds (a live
stream sends 15) — else it is closed (1008) and its slot freed.

Fair admission and addresses: the policy of :mod:`facecapges.serving.admission` (one
implementation, shared with the Ray replicas; docs/serve-protocol.md). When the server is full, or
the newcomer's address holds its ``max_per_address`` share (16 by default, loopback included), a
newcomer is not refused while some stream in its way is *slow* (below half the model rate): it gets
``hello`` on probation, and its first ``input`` takes the slot of the slowest such stream, which is
closed (1013, "evicted"). ``X-Forwarded-For`` counts only with ``trust_proxy``.

Loading. :meth:`StreamServer.start` may listen before the style is loaded (``serve`` does:
its socket is bound first, within a second of starting): a client that connects meanwhile
gets ``{"type": "status", "state": "loading", …}`` and waits; :meth:`StreamServer.load`
makes it ready, and every waiting client gets its ``hello`` then. At most ``max_streams``
clients wait (more get 1013).
Bad messages are answered and logged on one line per connection.

Cost per stream-frame (issue 36: "server CPU per stream-frame is the figure to push"). The event loop is
uvloop's where it is installed (:func:`facecapges.runtime.outputs.server_thread.new_event_loop`); each message
is handled as the WebSocket parser finds it (:mod:`facecapges.serving.connection`: no future, task switch or
queue per message) and every reply is written without waiting, as UTF-8 bytes straight into one WebSocket frame
(:meth:`StreamServer._send`, :func:`~facecapges.runtime.outputs.protocol.encode_poses_utf8`); the model pipe is
watched for the whole run, not registered again each tick (:meth:`StreamServer._compute`).

Security: it binds 127.0.0.1 unless told otherwise; while bound to loopback it only
answers handshakes whose ``Host`` names a loopback host (:mod:`facecapges.runtime.outputs.ws`,
as the viewer server does). There is no authentication: bind other addresses only on
trusted networks.
"""

from __future__ import annotations

import asyncio
import collections
import os
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
from facecapges.serving.admission import (
    EVICTED_SLOW,
    EVICTED_WAITING,
    FULL_CODE,
    Admission,
    Holder,
    close_reason,
    forwarded_address,
)
from facecapges.serving.config import ServeConfig
from facecapges.timing import AUDIO_SR

if TYPE_CHECKING:
    from websockets.asyncio.server import Server, ServerConnection

    from facecapges.serving.connection import MessageConnection
    from facecapges.serving.model_process import ModelProcess

KERNEL_SEND_BUFFER = 64 * 1024  # SO_SNDBUF per connection (~2 s of poses at 15 fps)


def client_address(ws, trust_proxy: bool = False) -> str:
    """The address a stream counts against (module docs, "Addresses").

    Its peer's address; with ``trust_proxy``, a loopback connection that carries
    ``X-Forwarded-For`` (a reverse proxy on this machine) counts against the address the proxy
    saw — the header's last entry — if that is an IP address. Without ``trust_proxy`` the
    header is ignored: any local program could claim any address with it."""
    request = getattr(ws, "request", None)
    fwd = request.headers.get("X-Forwarded-For") if request is not None else None
    return forwarded_address(peer_host(ws), fwd, trust_proxy)


@dataclass
class _Stream(Holder):
    ws: MessageConnection
    id: int
    slot: int | None = None
    pending: collections.deque = field(default_factory=collections.deque)
    frames: int = 0
    intensity: float = 1.0  # the stream's intensity dial (its client's `intensity` messages)
    applied: float | None = None  # the value its slot has (set between ticks)
    initial: np.ndarray | None = None  # a resumed stream's first pose (rot6d (47, 6)): protocol ``resume``


_error = error_message


def _ignore(_message) -> None:
    """The message callback of a stream that is over."""


class StreamServer(ServerThread):
    """The multi-stream WebSocket server (module docs). :meth:`start` runs it in a thread,
    :meth:`run` blocks until interrupted (:class:`~facecapges.runtime.outputs.server_thread.ServerThread`)."""

    thread_name = "serve"
    fast_loop = True  # uvloop (ServerThread.new_loop)
    start_timeout = 30.0
    join_timeout = 10.0

    def __init__(self, checkpoint=None, config: ServeConfig | None = None, log=None, sock=None, name: str = ""):
        super().__init__()
        self.cfg = config or ServeConfig()
        c = self.cfg
        if c.max_streams < 1:
            raise UserError("--max-streams must be at least 1")
        if c.rate_limit <= 0:
            raise UserError("--rate-limit must be a positive number of frames per second")
        self.sock = sock  # a socket already listening (``serve`` binds before it loads), else host:port
        self.name = name  # what is loaded, for the loading message
        self.ckpt = None
        self.gen: ModelProcess | None = None  # the model process, once loaded
        self.fps = 15  # the model's rate; set by load()
        self.sr = AUDIO_SR
        self.loopback_only = is_loopback(c.host)
        self.policy = Admission(c)  # fair admission, limits (module docs); its fps is set by load()
        self.log = log or (lambda *_: None)
        self.conn_log = ConnectionLog(self.log, "serve")
        self.streams: dict[int, _Stream] = {}
        self._next_id = 0
        self._wake = asyncio.Event()  # made anew in the server's loop by _listen
        self._loaded = asyncio.Event()  # set in the server's loop once load() is done (or failed)
        self.load_error: str | None = None
        self.waiting = 0  # clients connected while loading
        self.stats: collections.Counter[str] = collections.Counter()
        self._closing: set[asyncio.Future] = set()  # close tasks still running
        self._answer: asyncio.Future | None = None  # the tick waiting for the model process
        self._reading: tuple[asyncio.AbstractEventLoop, int] | None = None  # the model pipe watched, by loop
        self.batch_sizes: collections.deque = collections.deque(maxlen=10_000)
        if checkpoint is not None:
            self.load(checkpoint)

    def load(self, checkpoint) -> None:
        """Start the style's model process (``checkpoint``: a loaded style, either engine); the
        clients waiting for it get their ``hello``. Blocks until the model process is ready."""
        from facecapges.serving.model_process import ModelProcess

        self.ckpt = checkpoint
        self.fps = checkpoint.fps  # an int, as in the viewer's hello
        self.policy.fps = self.fps
        # the batched kernel in a process of its own: the event loop never holds it up (model_process docs)
        self.gen = ModelProcess(checkpoint, self.cfg.threads, self.cfg.max_streams)
        self.call_soon(self._loaded.set)

    def fail(self, message: str) -> None:
        """Loading failed: the waiting clients get ``message`` as an error and are closed (1011)."""
        self.load_error = message
        self.call_soon(self._loaded.set)

    @property
    def ready(self) -> bool:
        return self.gen is not None

    # ---------------------------------------------------------------- WebSocket
    def _process_request(self, connection, request):
        refused = refuse_foreign_host(connection, request, self.loopback_only)
        if refused is not None:
            self.stats["rejected_hosts"] += 1
        return refused

    async def _refuse(self, ws, refusal: str, code: int = 1013) -> None:
        from websockets.exceptions import ConnectionClosed

        try:
            await ws.send(_error(refusal))
            await ws.close(code, close_reason(refusal))
        except ConnectionClosed:
            pass

    async def _wait_loaded(self, ws) -> bool:
        """While the style loads: tell the client and wait (module docs, "Loading"). False if the
        connection was refused, closed or loading failed."""
        from websockets.exceptions import ConnectionClosed

        if self._loaded.is_set() and self.load_error is None:
            return True
        if self.waiting >= self.cfg.max_streams:
            self.stats["refused_loading"] += 1
            await self._refuse(ws, f"server loading: {self.cfg.max_streams} clients already wait; try again later")
            return False
        self.waiting += 1
        loaded = asyncio.ensure_future(self._loaded.wait())
        gone = asyncio.ensure_future(ws.wait_closed())  # a client that leaves (or a server that stops) ends the wait
        try:
            if not self._loaded.is_set():
                await ws.send(
                    protocol.encode_status(
                        "loading", f"loading {self.name or 'the style'}; hello follows when it is ready"
                    )
                )
                await asyncio.wait({loaded, gone}, return_when=asyncio.FIRST_COMPLETED)
        except ConnectionClosed:
            return False
        finally:
            self.waiting -= 1
            loaded.cancel()
            gone.cancel()
        if not self._loaded.is_set():
            return False
        if self.load_error is not None:
            await self._refuse(ws, f"server failed to load: {self.load_error}"[:400], 1011)
            return False
        return True

    async def _handler(self, ws) -> None:
        from websockets.exceptions import ConnectionClosed

        if not await self._wait_loaded(ws):
            return
        address = client_address(ws, self.cfg.trust_proxy)
        now = time.monotonic()
        arrival = self.policy.arrive(self.streams.values(), address, now)
        if arrival.refusal is not None:
            self.stats[arrival.stat] += 1
            await self._refuse(ws, arrival.refusal, FULL_CODE)
            return
        if arrival.make_room is not None:  # the newcomer on probation waiting the longest makes room
            old = arrival.make_room
            assert isinstance(old, _Stream)
            old.closed = True
            self.streams.pop(old.id, None)
            self.stats["evicted_waiting"] += 1
            self._close_later(old.ws, FULL_CODE, EVICTED_WAITING)
        sock = ws.transport.get_extra_info("socket") if getattr(ws, "transport", None) else None
        if sock is not None:  # a bounded kernel buffer, so a client that stops reading shows up in ours
            try:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, KERNEL_SEND_BUFFER)
            except OSError:
                pass
        st = _Stream(ws=ws, id=self._next_id, intensity=self.cfg.intensity)
        self.policy.new(st, address, now, arrival.probation)
        self._next_id += 1
        self.streams[st.id] = st
        self.stats["connections"] += 1
        try:
            await ws.send(protocol.encode_hello(self.fps, self.sr, intensity=st.intensity))
            # every message from now on is handled as the parser finds it (serving.connection)
            ws.deliver(lambda message: self._on_message(st, address, message))
            await ws.wait_closed()
        except ConnectionClosed:
            pass
        finally:
            self._gone(st)
            self.conn_log.closed(ws)
            if ws.close_code == 1009:
                self.stats["oversized_closes"] += 1

    def _gone(self, st: _Stream) -> None:
        """The stream is over (closed by either side): its slot is freed between ticks."""
        st.closed = True
        st.ws.on_message = _ignore
        self.streams.pop(st.id, None)
        self._wake.set()

    def _on_message(self, st: _Stream, address: str, message: str | bytes) -> None:
        """One message of a stream, handled at once (replies are written without waiting: :meth:`_send`)."""
        if st.closed:
            return
        try:
            self._handle(st, message)
        except Exception as exc:  # noqa: BLE001  never expected: one line, this connection only
            self.stats["handler_errors"] += 1
            self.log(f"serve: stream {st.id} ({address}) closed after an internal error: {exc!r:.200}")
            self._gone(st)
            self._close_later(st.ws, 1011, "internal error")

    def _handle(self, st: _Stream, message: str | bytes) -> None:
        ws = st.ws
        now = time.monotonic()
        allowed, limit_error = self.policy.allow(st, now)
        if not allowed:
            self.stats["rate_limited"] += 1
            if limit_error is not None:
                self._send(st, _error(limit_error))
            return
        try:
            msg = protocol.decode_client(message, self.fps, self.sr)
        except protocol.ProtocolError as exc:
            self.stats["bad_messages"] += 1
            self.conn_log.bad_message(ws, exc)
            self._send(st, _error(str(exc)))
            return
        kind = msg["type"]
        if kind == "ping":
            self._send(st, pong_message())
            return
        if kind == "intensity":  # applied to the stream's slot between ticks
            st.intensity = msg["value"]
            self._send(st, protocol.encode_intensity(st.intensity))
            return
        if kind == "resume":  # before the first input: the slot opens at that pose
            if st.slot is not None or st.frames or st.pending:
                self._send(st, _error("resume must come before the first input"))
            else:
                st.initial = msg["pose"]
                self.stats["resumed"] += 1
                self._send(st, protocol.RESUMED)
            return
        if st.probation:
            refusal = self._admit(st, now)
            if refusal is not None:
                self._send(st, _error(refusal))
                self._gone(st)
                self._close_later(ws, FULL_CODE, close_reason(refusal))
                return
            if st.probation:  # waiting for a stream in its way to be judged: this input is dropped
                self.stats["dropped_waiting"] += 1
                return
        self.policy.record_input(st, now)
        if len(st.pending) >= self.cfg.max_pending:
            self.stats["dropped_busy"] += 1
            self._send(
                st,
                _error(
                    f"busy: frame {msg['input'].index} dropped "
                    f"({self.cfg.max_pending} frames of this stream are waiting)"
                ),
            )
            return
        st.pending.append((msg["input"], now))
        self._wake.set()

    def _admit(self, st: _Stream, now: float) -> str | None:
        """A stream on probation sent its first input: give it a slot — a free one, or that of the
        slowest stream in its way, which is closed (1013, "evicted"). The refusal when every stream
        in the way is live (or new)."""
        refusal, stat, victim = self.policy.admit(self.streams.values(), st, now)
        if refusal is not None:
            self.stats[stat] += 1
            return refusal
        if victim is not None:
            assert isinstance(victim, _Stream)
            self.streams.pop(victim.id, None)  # its slot is freed at the next tick, before this one's opens
            self.stats["evicted_slow"] += 1
            self._close_later(victim.ws, FULL_CODE, EVICTED_SLOW)
        return None

    # ---------------------------------------------------------------- ticks
    async def _compute(
        self, slots: list[int], audio: list, face: np.ndarray, head: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """One batched step in the model process: poses (B, 47, 6) and quaternions (B, 47, 4). The event
        loop runs on while the model process works and resumes when its pipe is readable."""
        gen = self.gen
        assert gen is not None  # streams are admitted only once loaded
        loop = asyncio.get_running_loop()
        gen.submit(slots, audio, face, head)
        self._answer = ready = loop.create_future()
        if self._reading is None:
            self._watch_pipe(loop, gen.fileno())
        try:
            await ready
        finally:
            self._answer = None
        return gen.collect()

    def _watch_pipe(self, loop: asyncio.AbstractEventLoop, fd: int) -> None:
        """Watch the model pipe for the ticks to come (not one registration a tick): :meth:`_pipe_readable`."""
        loop.add_reader(fd, self._pipe_readable)
        self._reading = (loop, fd)
        # uvloop's add_reader makes the descriptor non-blocking (asyncio's leaves it): the model process's
        # blocking calls (collect, sync) need it blocking (a sync failed with EAGAIN); readiness is the same
        os.set_blocking(fd, True)

    def _pipe_readable(self) -> None:
        """The model process answered: the waiting tick goes on. Readable with no tick waiting (the model
        process died between ticks: end of file), the pipe is no longer watched until the next tick (else
        the loop would be woken at once, again and again); that tick's ``collect`` says what happened."""
        ready = self._answer
        if ready is not None:
            if not ready.done():
                ready.set_result(None)
        elif self._reading is not None:
            loop, fd = self._reading
            self._reading = None
            loop.remove_reader(fd)

    def _sync_slots(self) -> None:
        """Between ticks, in one round trip: free the slots of closed streams, give new streams theirs,
        apply changed intensity dials."""
        gen = self.gen
        if gen is None:
            return
        live = {st.slot for st in self.streams.values() if st.slot is not None}
        close = sorted(gen.open_slots - live)
        new = [st for st in self.streams.values() if st.slot is None and not st.probation]
        ref = {id(st): -1 - k for k, st in enumerate(new)}  # the k-th stream opened by this sync
        dial = [
            st for st in self.streams.values() if (st.slot is not None or id(st) in ref) and st.applied != st.intensity
        ]
        if not (close or new or dial):
            return
        dials = [(ref[id(st)] if st.slot is None else st.slot, st.intensity) for st in dial]
        slots = gen.sync(close, len(new), dials, [st.initial for st in new])
        for st, slot in zip(new, slots):
            st.slot = slot
        for st in dial:
            st.applied = st.intensity

    def _send(self, st: _Stream, message: str | bytes) -> None:
        """Write without waiting for the client (as UTF-8 bytes: :meth:`MessageConnection.send_text_now`);
        close a client that stopped reading."""
        if st.closed:
            return
        ws = st.ws
        ws.send_text_now(message.encode() if isinstance(message, str) else message)
        transport = ws.transport
        if transport is not None and transport.get_write_buffer_size() > self.cfg.send_buffer_bytes:
            self.stats["slow_closes"] += 1
            st.closed = True
            st.pending.clear()
            self._close_later(ws, 1008, "not reading its output")

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
                return protocol.tick_latency(items[i][1], t0, t1)

            index = [i.index for i in inputs]
            texts = protocol.encode_poses_utf8(
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

    async def _idle_loop(self) -> None:
        await self.policy.close_overdue(self.streams.values, self.stats, self._close_overdue)

    def _close_overdue(self, st, code: int, reason: str) -> None:
        st.closed = True
        self._close_later(st.ws, code, reason)

    # ---------------------------------------------------------------- lifecycle (ServerThread)
    async def _listen(self) -> Server:
        from websockets.asyncio.server import serve

        self._wake = asyncio.Event()
        if self.gen is not None or self.load_error is not None:  # loaded before the loop ran
            self._loaded.set()
        c = self.cfg
        where: dict = {"sock": self.sock} if self.sock is not None else {"host": c.host, "port": c.port}
        from facecapges.serving.connection import MessageConnection

        return await serve(
            self._handler,
            process_request=self._process_request,
            compression=None,
            create_connection=MessageConnection,
            **where,
            **SERVE_OPTIONS,
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
        if self.gen is not None:
            self.gen.shutdown()


def serve_streams(
    checkpoint, style: str | None, cfg: ServeConfig, say=echo, warn=echo_warning, sock: socket.socket | None = None
) -> dict:
    """The whole ``serve`` command: check ``cfg``, listen, load the style while listening (clients that
    connect meanwhile wait: module docs, "Loading"), serve until interrupted; returns the summary.

    ``sock``: a socket already listening on ``cfg.host:cfg.port`` (the command binds it before
    importing anything heavy). ``say(text, err=False)`` gets the start line, the ``ready`` line,
    the server's log (``err=True``) and the summary; ``warn`` a warning when the address is not a
    loopback one. Ctrl-C (or SIGTERM) stops it with the one summary line."""
    t0 = time.monotonic()
    server = StreamServer(None, cfg, log=lambda m: say(m, err=True), sock=sock)
    server.start()  # handshakes are answered (and told "loading") from now on, before torch is imported
    try:
        try:
            from facecapges.styles import load_style, resolve

            cfg.check()
            path = resolve(checkpoint, style)
            server.name = path.name
            if not is_loopback(cfg.host):
                warn(f"warning: listening on {cfg.host}: anyone who can reach it can use it (no authentication)")
            say(
                f"serving {path.name} on {server.url} (max {cfg.max_streams} streams, "
                f"{cfg.rate_limit:g} msg/s per stream); loading the style, clients wait for it; Ctrl-C stops"
            )
            server.load(load_style(path))
        except Exception as exc:
            why = (str(exc).splitlines() or [exc.__class__.__name__])[0]
            server.fail(why)
            server.close()
            if isinstance(exc, UserError):
                raise
            raise UserError(f"cannot load the style ({why})") from None
        say(f"ready: {path.name} loaded in {time.monotonic() - t0:.1f} s; serving streams")
        server.run()
    except KeyboardInterrupt:  # Ctrl-C while loading: the same quiet stop
        server.close()
    summary = server.summary()
    say(f"served: {summary}")
    return summary
