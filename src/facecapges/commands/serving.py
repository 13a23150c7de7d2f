"""The ``serve`` command: many live streams over WebSocket (see :mod:`facecapges.serving.server`)."""

from __future__ import annotations

from pathlib import Path

import typer

from facecapges.serving.config import ServeConfig


def serve(
    host: str = typer.Option(
        ServeConfig.host, help="Address to listen on (loopback by default; there is no authentication)."
    ),
    port: int = typer.Option(ServeConfig.port, help="TCP port (0 = any free port)."),
    checkpoint: Path | None = typer.Option(
        None, help="Checkpoint file or run folder (default: the installed default style)."
    ),
    style: str | None = typer.Option(None, help="Installed style name (see `facecapges styles`)."),
    max_streams: int = typer.Option(
        ServeConfig.max_streams, help="Most concurrent streams; more connections are refused (1013)."
    ),
    rate_limit: float = typer.Option(
        ServeConfig.rate_limit,
        help="Most messages per second per connection (FPS); more are dropped with an error.",
    ),
    idle_timeout: float = typer.Option(
        ServeConfig.idle_timeout, help="Close a stream after this many seconds without input (0 = never)."
    ),
    threads: int = typer.Option(ServeConfig.threads, help="torch threads for the batched model call."),
    tick_ms: float = typer.Option(
        ServeConfig.tick_ms,
        help="Least time between two batched calls (ms): larger batches, a little more latency.",
    ),
    max_per_address: int | None = typer.Option(
        ServeConfig.max_per_address,
        help="Most streams one client address may hold (default 16; no limit on a loopback server).",
    ),
    intensity: float = typer.Option(
        ServeConfig.intensity,
        help="Gesture intensity of each new stream, 0 (rest / idle only) … 1 … 1.3; a client changes its own "
        "with an 'intensity' message.",
    ),
) -> None:
    """Serve live streams over WebSocket: audio + face + head in, pose out, one stream per connection.

    Speaks the runtime's message format (facecapges.runtime.outputs.protocol): 'hello' on
    connect, one 'input' per frame from the client, one 'pose' back per frame.
    The frames of all streams waiting at the same moment run as one batched call.
    """
    from facecapges.serving.server import serve_streams

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
    )
    serve_streams(checkpoint, style, cfg, say=typer.echo)


def register(app: typer.Typer) -> None:
    app.command()(serve)
