"""The ``serve`` command: many live streams over WebSocket (see :mod:`facecapges.serving.server`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from facecapges.commands.params import STYLE_NAME
from facecapges.serving.config import ServeConfig

HOST = typer.Option("--host", help="Address to listen on (loopback by default; there is no authentication).")
PORT = typer.Option("--port", help="TCP port (0 = any free port).")
CHECKPOINT = typer.Option(
    "--checkpoint", help="NetworkStyle file or run folder (default: the installed default style)."
)
MAX_STREAMS = typer.Option("--max-streams", help="Most concurrent streams; more connections are refused (1013).")
RATE_LIMIT = typer.Option(
    "--rate-limit", help="Most messages per second per connection (FPS); more are dropped with an error."
)
IDLE_TIMEOUT = typer.Option("--idle-timeout", help="Close a stream after this many seconds without input (0 = never).")
THREADS = typer.Option("--threads", help="torch threads for the batched model call.")
TICK_MS = typer.Option(
    "--tick-ms", help="Least time between two batched calls (ms): larger batches, a little more latency."
)
MAX_PER_ADDRESS = typer.Option(
    "--max-per-address",
    help="Most streams one client address may hold (default 16, loopback included); when full, slow streams "
    "make room (docs/serve-protocol.md). With --ray: per replica, and off unless given (every stream comes "
    "from Ray's HAProxy; see --trust-proxy).",
)
TRUST_PROXY = typer.Option(
    "--trust-proxy",
    help="Every loopback connection comes through a local reverse proxy: count it against the last "
    "X-Forwarded-For address (otherwise the header is ignored). With --ray: every connection (they all come "
    "through Ray's HAProxy; a load balancer in front sets the header).",
)
INTENSITY = typer.Option(
    "--intensity",
    help="Gesture intensity of each new stream, 0 (rest / idle only) … 1 … 1.3; a client changes its own "
    "with an 'intensity' message.",
)
RAY = typer.Option(
    "--ray",
    metavar="ADDRESS",
    help="Serve on a Ray cluster (needs the 'ray' extra): ADDRESS of its head ('auto': the cluster `ray start` "
    "runs here; 'local': start a one-node cluster). Clients connect to Ray Serve's HAProxy at --host/--port "
    "of a node (default port 8000; --host 0.0.0.0 on a cluster of several machines), which hands each stream "
    "to a replica for its life; see docs/serve-cluster.md.",
)
REPLICAS = typer.Option("--replicas", help="With --ray: copies of the style, each batching its own streams.")


def serve(
    host: Annotated[str, HOST] = ServeConfig.host,
    port: Annotated[int, PORT] = ServeConfig.port,
    checkpoint: Annotated[Path | None, CHECKPOINT] = None,
    style: Annotated[str | None, STYLE_NAME] = None,
    max_streams: Annotated[int, MAX_STREAMS] = ServeConfig.max_streams,
    rate_limit: Annotated[float, RATE_LIMIT] = ServeConfig.rate_limit,
    idle_timeout: Annotated[float, IDLE_TIMEOUT] = ServeConfig.idle_timeout,
    threads: Annotated[int, THREADS] = ServeConfig.threads,
    tick_ms: Annotated[float, TICK_MS] = ServeConfig.tick_ms,
    max_per_address: Annotated[int | None, MAX_PER_ADDRESS] = ServeConfig.max_per_address,
    intensity: Annotated[float, INTENSITY] = ServeConfig.intensity,
    trust_proxy: Annotated[bool, TRUST_PROXY] = ServeConfig.trust_proxy,
    ray: Annotated[str | None, RAY] = None,
    replicas: Annotated[int, REPLICAS] = 2,
) -> None:
    """Serve live streams over WebSocket: audio + face + head in, pose out, one stream per connection.

    Speaks the runtime's message format (facecapges.runtime.outputs.protocol): 'hello' on
    connect, one 'input' per frame from the client, one 'pose' back per frame.
    The frames of all streams waiting at the same moment run as one batched call.
    It listens at once and loads the style while listening ("ready: …" when done); Ctrl-C stops
    it with one summary line and exit status 0.
    """
    from facecapges.errors import check_port
    from facecapges.runtime.outputs.server_thread import listening_socket
    from facecapges.styles import resolve

    check_port(port)
    resolve(checkpoint, style)  # a wrong style name or file is said at once, before torch loads
    if ray is not None:
        from facecapges.errors import UserError
        from facecapges.serving.ray_app import DEFAULT_PORT, serve_on_ray

        if replicas < 1:
            raise UserError("--replicas must be at least 1")
        serve_on_ray(
            ray,
            checkpoint,
            style,
            ServeConfig(
                host=host,
                port=DEFAULT_PORT if port == ServeConfig.port else port,
                max_streams=max_streams,
                rate_limit=rate_limit,
                idle_timeout=idle_timeout,
                tick_ms=tick_ms,
                max_per_address=max_per_address,
                intensity=intensity,
                trust_proxy=trust_proxy,
            ),
            replicas=replicas,
            say=typer.echo,
        )
        return
    sock = listening_socket(host, port)  # before anything heavy: a client started now waits, not refused
    try:
        from facecapges.serving.server import serve_streams
    except KeyboardInterrupt:  # Ctrl-C while starting: the same one-line stop
        sock.close()
        typer.echo("served: nothing (stopped while starting)")
        return

    cfg = ServeConfig(
        host=host,
        port=port,
        max_streams=max_streams,
        rate_limit=rate_limit,
        idle_timeout=idle_timeout,
        threads=threads,
        tick_ms=tick_ms,
        max_per_address=max_per_address,
        intensity=intensity,
        trust_proxy=trust_proxy,
    )
    try:
        serve_streams(checkpoint, style, cfg, say=typer.echo, sock=sock)
    finally:
        sock.close()


def register(app: typer.Typer) -> None:
    app.command()(serve)
