"""Simulated live clients for ``facecapges serve`` (benchmark and tests).

Each client is one WebSocket stream that behaves like a webcam + microphone client:
it connects, reads ``hello``, then sends one ``input`` message per frame at the
model rate (frame k at ``start + phase + k/fps``, with a random phase per client so
the streams are not aligned), and records for every frame the time from just before
its ``send`` to the arrival of the ``pose`` with the same ``frame`` number (the round
trip, loopback included). Inputs are real: consecutive frames of a speech recording
(each frame its own samples), a slowly varying face and a head turning a little.
Messages are encoded once before the run (to UTF-8 bytes too: a frame's number is put in with
a bytes replace and the bytes go out as a text frame), replies are matched as bytes without
decoding them, each client is driven by callbacks (its replies through the connection's
callback, its frames by timers: no coroutine, future or queue per frame) and :func:`run` drives
the clients on uvloop's event loop where it is installed, so the clients spend their CPU on the
sockets, not on JSON or asyncio — they share the machine with the server they measure (``bench
--only serve`` reports their CPU per frame beside the server's).
"""

from __future__ import annotations

import asyncio
import math
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from facecapges import timing
from facecapges.runtime.outputs import protocol

_FRAME = re.compile(r'"frame":(\d+)')
_FRAME_B = re.compile(rb'"frame":(\d+)')
_FRAME_FIELD = re.compile(r'"frame":\d+,')


def input_messages(
    audio: np.ndarray, n_frames: int, fps: float = timing.MODEL_FPS, sr: int = timing.AUDIO_SR, seed: int = 0
) -> list[str]:
    """``n_frames`` consecutive ``input`` messages from a 16 kHz recording (looped)."""
    rng = np.random.default_rng(seed)
    bounds = [timing.frame_sample_bounds(k, fps, sr) for k in range(n_frames)]
    need = bounds[-1][1]
    a = np.asarray(audio, np.float32).reshape(-1)
    if a.size == 0:
        raise ValueError("no audio to send")
    a = np.tile(a, math.ceil(need / a.size))[:need]
    out = []
    base = rng.uniform(0.0, 0.3, 52)
    for k, (lo, hi) in enumerate(bounds):
        face = np.clip(base + 0.2 * np.sin(k / 7.0 + np.arange(52)), 0.0, 1.0)
        yaw = 0.2 * math.sin(k / 23.0)
        head = np.array([math.cos(yaw), 0.0, -math.sin(yaw), 0.0, 1.0, 0.0])  # first two columns of R_y(yaw)
        out.append(protocol.encode_input(k, a[lo:hi], face, head))
    return out


@dataclass
class ClientResult:
    sent: int = 0
    received: int = 0
    errors: list[str] = field(default_factory=list)
    latencies_ms: list[float] = field(default_factory=list)  # frames sent after the warm-up
    closed: str | None = None  # why the server closed us early, if it did


class _Client:
    """One simulated stream driven by callbacks, not a coroutine: its messages arrive through
    :class:`~facecapges.serving.connection.ClientMessageConnection`'s callback and each frame is sent by
    a timer callback, so a frame costs the client no task switch, future or queue (the clients share the
    machine's cores with the server they measure)."""

    def __init__(self, ws, res: ClientResult, encoded: list[bytes], n: int, period: float, warmup_s: float, phase):
        self.ws, self.res, self.encoded, self.n = ws, res, encoded, n
        self.period, self.warmup_s, self.phase = period, warmup_s, phase
        self.loop = asyncio.get_running_loop()
        self.sent_all = self.loop.create_future()  # every frame sent (or sending stopped)
        self.done = self.loop.create_future()  # every pose back, or the connection over
        self.sent_at: dict[int, float] = {}
        self.measured: set[int] = set()
        self.k = 0
        self.start = 0.0
        self.hello = False

    def on_message(self, msg) -> None:
        now = time.perf_counter()
        res = self.res
        if not self.hello:
            if b'"status"' in msg[:40]:  # the server is still loading its style: hello follows
                return
            if b'"hello"' not in msg:
                res.errors.append(f"no hello: {bytes(msg[:80]).decode('utf-8', 'replace')}")
                self.finish()
                return
            self.hello = True
            self.start = time.perf_counter() + self.phase
            self.loop.call_later(self.phase, self.send)
            return
        m = _FRAME_B.search(msg, 0, 40)
        if msg.startswith(b'{"type":"pose"') and m:
            k = int(m.group(1))
            res.received += 1
            if k in self.measured:
                res.latencies_ms.append((now - self.sent_at[k]) * 1e3)
            if res.received >= self.n:
                self.finish()
        else:
            res.errors.append(bytes(msg[:120]).decode("utf-8", "replace"))

    def send(self) -> None:
        """Frame k, then the timer for frame k + 1 (at start + (k + 1) / fps)."""
        if self.done.done():
            self._set(self.sent_all)
            return
        k = self.k
        now = time.perf_counter()
        self.sent_at[k] = now
        if k * self.period >= self.warmup_s:
            self.measured.add(k)
        m0 = self.encoded[k % len(self.encoded)]
        if not self.ws.send_text_now(m0.replace(b'"frame":0,', b'"frame":%d,' % k, 1) if k else m0):
            self._set(self.sent_all)  # closed meanwhile: the connection's end says why
            return
        self.res.sent += 1
        self.k = k = k + 1
        if k >= self.n:
            self._set(self.sent_all)
            return
        self.loop.call_later(max(0.0, self.start + k * self.period - time.perf_counter()), self.send)

    def finish(self) -> None:
        self._set(self.done)
        self._set(self.sent_all)

    @staticmethod
    def _set(fut: asyncio.Future) -> None:
        if not fut.done():
            fut.set_result(None)


async def run_client(
    url: str,
    messages: Sequence[str | bytes],
    seconds: float,
    warmup_s: float = 1.0,
    fps: float = timing.MODEL_FPS,
    phase: float = 0.0,
    drain_s: float = 5.0,
) -> ClientResult:
    """One client for ``seconds`` of stream time; latencies of frames sent after ``warmup_s``;
    after the last frame it waits up to ``drain_s`` for the missing poses."""
    from websockets.asyncio.client import connect
    from websockets.exceptions import ConnectionClosed

    from facecapges.serving.connection import ClientMessageConnection

    res = ClientResult()
    encoded = [m.encode() if isinstance(m, str) else m for m in messages]
    try:
        async with connect(
            url,
            max_size=protocol.MAX_MESSAGE_BYTES,
            ping_interval=None,
            compression=None,
            open_timeout=30,
            create_connection=ClientMessageConnection,
        ) as ws:
            assert isinstance(ws, ClientMessageConnection)
            client = _Client(ws, res, encoded, int(seconds * fps), 1.0 / fps, warmup_s, phase)
            closed = asyncio.ensure_future(ws.wait_closed())
            closed.add_done_callback(lambda _: client.finish())
            ws.deliver(client.on_message)
            await client.sent_all
            try:
                await asyncio.wait_for(asyncio.shield(client.done), timeout=drain_s)
            except TimeoutError:
                pass
            if closed.done() and res.received < client.n and client.hello:
                rcvd = ws.protocol.close_rcvd
                res.closed = f"{rcvd.code if rcvd else '?'} {rcvd.reason if rcvd else ''}"
            elif closed.done() and not client.hello and not res.errors:
                res.errors.append("no hello: the connection closed")
            closed.cancel()
    except (TimeoutError, OSError, ConnectionClosed) as exc:
        res.errors.append(f"connection: {exc.__class__.__name__}: {exc}")
    return res


def run(coro):
    """Run the clients' coroutine to its end on a new event loop (uvloop's where it is installed:
    :func:`facecapges.runtime.outputs.server_thread.new_event_loop`), as ``asyncio.run`` does."""
    from facecapges.runtime.outputs.server_thread import new_event_loop

    with asyncio.Runner(loop_factory=new_event_loop) as runner:
        return runner.run(coro)


def _frame0(messages: list[str]) -> list[str]:
    """Every message with frame number 0 (run_client puts the real number in)."""
    return [re.sub(r'"frame":\d+,', '"frame":0,', m, count=1) for m in messages]


async def run_clients(
    url: str,
    n_clients: int,
    seconds: float,
    messages: list[str],
    warmup_s: float = 1.0,
    fps: float = timing.MODEL_FPS,
    seed: int = 0,
    drain_s: float = 5.0,
) -> list[ClientResult]:
    """``n_clients`` concurrent clients, random phases within one frame period."""
    rng = np.random.default_rng(seed)
    msgs = [m.encode() for m in _frame0(messages)]  # once for all clients
    return list(
        await asyncio.gather(
            *[
                run_client(url, msgs, seconds, warmup_s, fps, phase=float(rng.uniform(0, 1.0 / fps)), drain_s=drain_s)
                for _ in range(n_clients)
            ]
        )
    )


def summarize(results: list[ClientResult], period_ms: float) -> dict:
    """p50/p99/max round trip over every measured frame; lost frames; errors."""
    lat = np.concatenate([np.asarray(r.latencies_ms, np.float64) for r in results]) if results else np.zeros(0)
    sent = sum(r.sent for r in results)
    received = sum(r.received for r in results)
    errors = sum(len(r.errors) for r in results)
    closed = sum(r.closed is not None for r in results)
    out: dict[str, float] = {
        "clients": len(results),
        "frames_sent": sent,
        "frames_returned": received,
        "lost": sent - received,
        "errors": errors,
        "closed_early": closed,
        "measured_frames": int(lat.size),
    }
    if lat.size:
        out.update(
            p50_ms=round(float(np.percentile(lat, 50)), 2),
            p99_ms=round(float(np.percentile(lat, 99)), 2),
            max_ms=round(float(lat.max()), 2),
        )
    out["ok"] = bool(lat.size and sent == received and errors == 0 and closed == 0 and out["p99_ms"] <= period_ms)
    return out


@dataclass
class ResumeResult:
    """A client that reconnects and resumes (:func:`run_resuming_client`)."""

    sent: dict[int, float] = field(default_factory=dict)  # frame → send time (perf_counter)
    got: dict[int, tuple[float, list]] = field(default_factory=dict)  # frame → (arrival, pose 47 × 4 flat)
    drops: list[float] = field(default_factory=list)  # when a connection dropped
    stalls: list[float] = field(default_factory=list)  # those of drops the no-pose rule made (stall_s)
    back: list[float] = field(default_factory=list)  # the first pose after each drop
    hellos: list[float] = field(default_factory=list)  # each connection's hello
    errors: list[str] = field(default_factory=list)
    last_pose: list | None = None


STALL_S = 0.8  # no pose for this long while frames are due: the connection is taken as dead
# a connection given up is closed without waiting long for the server's close frame: behind a proxy a
# dead server's never comes (websockets' default waits 10 s)
CLOSE_TIMEOUT_S = 0.2


async def run_resuming_client(
    url: str,
    messages: list[str],
    seconds: float,
    fps: float = timing.MODEL_FPS,
    phase: float = 0.0,
    t0=None,
    stall_s: float = STALL_S,
    connect_after: float = 0.0,
) -> ResumeResult:
    """A live client that survives a dropped connection, as the sample client does: it reconnects
    (every 50 ms) and sends ``resume`` with the last pose it got, then goes on with the frame its
    clock is at (the frames of the outage are lost). Frame k is due at ``t0 + phase + k / fps``.
    A connection that returns no pose for ``stall_s`` seconds while frames are sent counts as
    dropped (a proxy may keep a client's socket open after the node behind it died). It first
    connects ``connect_after`` seconds after ``t0`` (clients arriving over time, as users do)."""
    import orjson
    from websockets.asyncio.client import connect
    from websockets.exceptions import ConnectionClosed, InvalidHandshake

    res = ResumeResult()
    n = int(seconds * fps)
    start = (t0 if t0 is not None else time.perf_counter()) + phase
    await asyncio.sleep(max(0.0, start + connect_after - time.perf_counter()))
    k = int(connect_after * fps)
    while k < n:
        # after a drop, a server that does not answer within the no-pose rule is given up as dead too (a hung
        # node's kernel still accepts connections): the next attempt may reach a live replica
        wait = stall_s if res.drops else None  # (the first connection waits for the hello as long as it takes)
        try:
            ws = await connect(
                url, max_size=protocol.MAX_MESSAGE_BYTES, ping_interval=None, compression=None, open_timeout=wait or 5.0
            )
        except (TimeoutError, OSError, InvalidHandshake):
            await asyncio.sleep(0.05)
            k = max(k, int((time.perf_counter() - start) * fps))
            continue
        ws.close_timeout = CLOSE_TIMEOUT_S
        dropped_at = 0.0  # when the no-pose rule gave the connection up (its close may take a moment)
        try:
            try:
                hello = await asyncio.wait_for(ws.recv(decode=True), wait)
                while '"status"' in hello[:40]:
                    hello = await asyncio.wait_for(ws.recv(decode=True), wait)
            except TimeoutError:
                await ws.close()
                continue
            if '"hello"' not in hello:
                res.errors.append(f"no hello: {hello[:80]}")
                await ws.close()
                await asyncio.sleep(0.05)
                continue
            res.hellos.append(time.perf_counter())
            if res.last_pose is not None:
                await ws.send(orjson.dumps({"type": "resume", "pose": res.last_pose}).decode())
            dropped = bool(res.drops)
            last_rx = time.perf_counter()

            async def reader(ws=ws):
                nonlocal dropped, last_rx
                try:
                    async for msg in ws:
                        now = time.perf_counter()
                        if msg.startswith('{"type":"pose"'):
                            last_rx = now  # errors ("busy") do not count: a stream is alive while poses come
                            m = orjson.loads(msg)
                            res.got[m["frame"]] = (now, m["pose"])
                            res.last_pose = m["pose"]
                            if dropped:
                                res.back.append(now)
                                dropped = False
                        elif '"resumed"' not in msg[:30]:
                            res.errors.append(msg[:120])
                except ConnectionClosed:  # the sender sees the task done and reconnects
                    pass

            rtask = asyncio.ensure_future(reader())
            while k < n and not rtask.done():
                k = max(k, int((time.perf_counter() - start) * fps))  # frames missed while away are skipped
                delay = start + k / fps - time.perf_counter()
                if delay > 0:
                    await asyncio.sleep(delay)
                if time.perf_counter() - last_rx > stall_s:  # frames go out, nothing comes back
                    dropped_at = time.perf_counter()
                    res.stalls.append(dropped_at)
                    rtask.cancel()
                    await ws.close()
                    raise ConnectionClosed(None, None)
                res.sent[k] = time.perf_counter()
                await ws.send(_FRAME_FIELD.sub(f'"frame":{k},', messages[k % len(messages)], count=1))
                k += 1
            if k >= n:
                try:
                    await asyncio.wait_for(asyncio.shield(rtask), timeout=2.0)
                except TimeoutError:
                    pass
                rtask.cancel()
                await ws.close()
                break
            await rtask  # it ended: the connection dropped
        except ConnectionClosed:
            pass
        res.drops.append(dropped_at or time.perf_counter())
    return res
