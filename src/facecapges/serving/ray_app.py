"""``facecapges serve --ray``: the streams of ``serve`` spread over the nodes of a Ray cluster.

A Ray Serve application (needs the ``ray`` extra: ``pip install 'facecapges[ray]'``). Its one
deployment, :class:`StreamReplica`, is a FastAPI ingress with one WebSocket route, ``/``; Ray's
HTTP proxy accepts a client's connection and hands it to one replica, which holds it for the
stream's life — the stream's engine state (its slot of the style's batched generator) never
leaves that replica. Every replica loads the style once and batches its own streams per tick as
``serve`` does (:mod:`facecapges.serving.server`, "Ticks"): each tick takes the oldest waiting
frame of every stream with one and runs them as one batched ``step``. Ray places the replicas
over the nodes (at most ``max_per_node`` a node) and routes each new connection to the replica
with the fewest open ones among two it picks (its power-of-two-choices router; a WebSocket
counts as one ongoing request for its whole life).

The protocol is ``serve``'s (:mod:`facecapges.runtime.outputs.protocol`): ``hello``, ``input`` →
``pose``, ``intensity``, ``ping``, and ``resume``. When a node dies its streams' connections drop;
a client reconnects (through the proxy, to a replica that lives) and sends ``resume`` with the
last pose it got: the new stream starts from that pose (docs/serve-cluster.md).

What ``serve`` has and this does not (yet): the per-address limit and fair admission, the
``loading`` status (the proxy answers only once the application is up), the shared-memory model
process (the batched step runs in the replica's own event loop — one replica per core is the
layout), the send-buffer and min-rate closes. A replica refuses a stream past ``max_streams``
(1013); a bad message gets an ``error`` and the connection stays, as in ``serve``.
"""

import asyncio
import collections
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from facecapges.errors import UserError

DEFAULT_PORT = 8000  # Ray Serve's HTTP port


def _require_ray():
    try:
        import ray  # noqa: F401
        from ray import serve  # noqa: F401
    except ImportError:
        raise UserError("--ray needs Ray Serve: pip install 'facecapges[ray]'") from None


@dataclass
class _RayStream:
    ws: Any
    slot: int | None = None
    initial: np.ndarray | None = None
    intensity: float = 1.0
    pending: collections.deque = field(default_factory=collections.deque)
    closed: bool = False
    frames: int = 0


def build_app(
    checkpoint: str | None = None,
    style: str | None = None,
    replicas: int = 2,
    max_per_node: int = 0,
    max_streams: int = 256,
    tick_ms: float = 15.0,
    max_pending: int = 4,
    rate_limit: float = 30.0,
    num_cpus: float = 1.0,
):
    """The Ray Serve application (``serve.run(build_app(...))``): ``replicas`` copies of the style,
    at most ``max_per_node`` on one node (0: no limit). ``checkpoint``/``style`` name the style as
    ``serve`` does; every node must have it (the same install and shared data)."""
    _require_ray()
    from fastapi import FastAPI, WebSocket, WebSocketDisconnect
    from ray import serve

    app = FastAPI()

    per_node: dict[str, Any] = {"max_replicas_per_node": max_per_node} if max_per_node else {}

    @serve.deployment(
        num_replicas=replicas,
        max_ongoing_requests=max_streams,  # a WebSocket is one ongoing request for its whole life
        **per_node,
        ray_actor_options={"num_cpus": num_cpus},
        health_check_period_s=1.0,
        health_check_timeout_s=5.0,
    )
    @serve.ingress(app)
    class StreamReplica:
        """One replica: the style's batched generator and the streams pinned to it (module docs)."""

        def __init__(self) -> None:
            import torch

            from facecapges.styles import load_style, resolve

            torch.set_num_threads(1)
            ckpt = load_style(resolve(checkpoint, style))
            self.fps = int(ckpt.fps)
            self.gen = ckpt.batched(capacity=64)
            self.streams: dict[int, _RayStream] = {}
            self._next = 0
            self._wake: asyncio.Event | None = None
            self._task: asyncio.Task | None = None
            self.stats: collections.Counter[str] = collections.Counter()

        def _start(self) -> None:
            if self._task is None:
                self._wake = asyncio.Event()
                self._task = asyncio.get_running_loop().create_task(self._batch_loop())

        @app.get("/-/streams")
        def count(self) -> dict:
            """This replica's open streams and counters (a health and load probe)."""
            import ray

            return dict(self.stats, streams=len(self.streams), node=ray.get_runtime_context().get_node_id())

        @app.websocket("/")
        async def stream(self, ws: WebSocket) -> None:
            from facecapges.runtime.outputs import protocol
            from facecapges.runtime.outputs.ws import error_message, pong_message

            await ws.accept()
            self._start()
            if len(self.streams) >= max_streams:
                await ws.send_text(error_message(f"server full: {max_streams} streams; try again later"))
                await ws.close(1013)
                return
            st = _RayStream(ws)
            sid, self._next = self._next, self._next + 1
            self.streams[sid] = st
            self.stats["connections"] += 1
            tokens, t_tokens, last_err = rate_limit, time.monotonic(), -1e9
            try:
                await ws.send_text(protocol.encode_hello(self.fps))
                while True:
                    text = await ws.receive_text()
                    now = time.monotonic()
                    tokens = min(rate_limit, tokens + (now - t_tokens) * rate_limit)
                    t_tokens = now
                    if tokens < 1.0:
                        self.stats["rate_limited"] += 1
                        if now - last_err >= 1.0:
                            last_err = now
                            await ws.send_text(error_message(f"rate limit: at most {rate_limit:g} messages per second"))
                        continue
                    tokens -= 1.0
                    try:
                        msg = protocol.decode_client(text, self.fps)
                    except protocol.ProtocolError as exc:
                        self.stats["bad_messages"] += 1
                        await ws.send_text(error_message(str(exc)))
                        continue
                    kind = msg["type"]
                    if kind == "ping":
                        await ws.send_text(pong_message())
                    elif kind == "intensity":
                        st.intensity = msg["value"]
                        if st.slot is not None:
                            self.gen.set_intensity(st.slot, st.intensity)
                        await ws.send_text(protocol.encode_intensity(st.intensity))
                    elif kind == "resume":
                        if st.slot is not None or st.pending:
                            await ws.send_text(error_message("resume must come before the first input"))
                        else:
                            st.initial = msg["pose"]
                            self.stats["resumed"] += 1
                            await ws.send_text(protocol.RESUMED)
                    elif len(st.pending) >= max_pending:
                        self.stats["dropped_busy"] += 1
                        await ws.send_text(error_message(f"busy: frame {msg['input'].index} dropped"))
                    else:
                        st.pending.append((msg["input"], now))
                        assert self._wake is not None
                        self._wake.set()
            except WebSocketDisconnect:
                pass
            finally:
                st.closed = True
                self.streams.pop(sid, None)
                if st.slot is not None:  # between ticks: the step runs in this same event loop
                    self.gen.close(st.slot)
                    st.slot = None

        async def _batch_loop(self) -> None:
            from facecapges import rotations as rot
            from facecapges.runtime.outputs import protocol

            assert self._wake is not None
            last = -1e9
            while True:
                await self._wake.wait()
                wait = last + tick_ms / 1000.0 - time.monotonic()
                if wait > 0:
                    await asyncio.sleep(wait)
                self._wake.clear()
                last = time.monotonic()
                due = [st for st in list(self.streams.values()) if st.pending and not st.closed]
                if not due:
                    continue
                slots: list[int] = []
                for st in due:
                    if st.slot is None:  # its first frame: open its slot (at the resumed pose, if any)
                        st.slot = self.gen.open(st.initial) if st.initial is not None else self.gen.open()
                        if st.intensity != 1.0:
                            self.gen.set_intensity(st.slot, st.intensity)
                    slots.append(st.slot)
                items = [st.pending.popleft() for st in due]
                inputs = [it[0] for it in items]
                face = np.stack([i.face for i in inputs])
                head = np.stack([i.head for i in inputs])
                t0 = time.monotonic()
                pose = self.gen.step(slots, [i.audio for i in inputs], face, head)
                quats = rot.rot6d_to_quaternion(np.asarray(pose, np.float64))
                t1 = time.monotonic()

                def latency(i: int, t0=t0, t1=t1, items=items) -> dict:
                    return protocol.tick_latency(items[i][1], t0, t1)

                index = [i.index for i in inputs]
                texts = protocol.encode_poses(
                    index, [k / self.fps for k in index], quats, face, head, [i.face_found for i in inputs], latency
                )
                sends = []
                for st, text in zip(due, texts):
                    if not st.closed:
                        st.frames += 1
                        sends.append(st.ws.send_text(text))
                self.stats["frames"] += len(due)
                self.stats["ticks"] += 1
                await asyncio.gather(*sends, return_exceptions=True)  # a client gone is its handler's to end
                if any(st.pending for st in self.streams.values()):
                    self._wake.set()

    return StreamReplica.bind()  # type: ignore[attr-defined]


def _check_reachable(address: str) -> None:
    """A ``HOST:PORT`` head that does not answer is one error line at once (Ray itself retries for
    minutes); ``auto`` and ``ray://`` addresses are left to Ray."""
    import socket

    if address == "auto" or "://" in address:
        return
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise UserError(f"--ray {address}: expected auto, local or HOST:PORT of the cluster's head")
    try:
        socket.create_connection((host, int(port)), timeout=5).close()
    except OSError as exc:
        raise UserError(f"--ray {address}: no Ray head answers there ({exc.strerror or exc})") from None


def serve_on_ray(
    address: str,
    checkpoint=None,
    style: str | None = None,
    host: str = "127.0.0.1",
    port: int = DEFAULT_PORT,
    replicas: int = 2,
    max_per_node: int = 0,
    max_streams: int = 256,
    tick_ms: float = 15.0,
    say=print,
) -> None:
    """``facecapges serve --ray ADDRESS``: connect to the cluster at ``ADDRESS`` (``auto``: the one
    ``ray start`` runs on this machine; ``local``: start a one-node cluster here), run the
    application with its proxy on ``host:port`` and serve until interrupted."""
    _require_ray()
    import signal
    import threading

    import ray
    from ray import serve

    if address == "local":
        ray.init(include_dashboard=False)
    else:
        _check_reachable(address)
        try:
            ray.init(address=address, include_dashboard=False)
        except (ConnectionError, ValueError, RuntimeError) as exc:
            raise UserError(f"--ray {address}: no Ray cluster there ({str(exc).splitlines()[0][:200]})") from None
    try:
        serve.start(http_options={"host": host, "port": port})  # a proxy on every node (Ray's default)
        say(f"starting {replicas} replicas on the cluster; clients connect to ws://{host}:{port}/")
        serve.run(
            build_app(
                str(checkpoint) if checkpoint else None,
                style,
                replicas=replicas,
                max_per_node=max_per_node,
                max_streams=max_streams,
                tick_ms=tick_ms,
            ),
            name="facecapges",
            route_prefix="/",
        )
        say(f"ready: serving streams on ws://{host}:{port}/ (Ray Serve, {replicas} replicas); Ctrl-C stops")
        # Ctrl-C or SIGTERM: Ray's driver does not always turn SIGINT into KeyboardInterrupt here
        stop = threading.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: stop.set())
        while not stop.wait(1.0):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        try:
            serve.delete("facecapges")
        except Exception:  # noqa: BLE001  the cluster may be gone already
            pass
        ray.shutdown()
    say("served: stopped")
