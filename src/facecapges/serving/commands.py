"""The ``serve`` command: many live streams over WebSocket (see :mod:`facecapges.serving.server`)."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command()
    def serve(
        host: str = typer.Option(
            "127.0.0.1", help="Address to listen on (loopback by default; there is no authentication)."
        ),
        port: int = typer.Option(8780, help="TCP port (0 = any free port)."),
        checkpoint: Path | None = typer.Option(
            None, help="Checkpoint file or run folder (default: the installed default style)."
        ),
        style: str | None = typer.Option(None, help="Installed style name (see `facecapges styles`)."),
        max_streams: int = typer.Option(256, help="Most concurrent streams; more connections are refused (1013)."),
        rate_limit: float = typer.Option(
            30.0, help="Most messages per second per connection (FPS); more are dropped with an error."
        ),
        idle_timeout: float = typer.Option(
            60.0, help="Close a stream after this many seconds without input (0 = never)."
        ),
        threads: int = typer.Option(1, help="torch threads for the batched model call."),
        tick_ms: float = typer.Option(
            15.0, help="Least time between two batched calls (ms): larger batches, a little more latency."
        ),
        max_per_address: int | None = typer.Option(
            None, help="Most streams one client address may hold (default 16; no limit on a loopback server)."
        ),
    ) -> None:
        """Serve live streams over WebSocket: audio + face + head in, pose out, one stream per connection.

        Speaks the runtime's message format (facecapges.runtime.protocol): 'hello' on
        connect, one 'input' per frame from the client, one 'pose' back per frame.
        The frames of all streams waiting at the same moment run as one batched call.
        """
        from facecapges.errors import UserError
        from facecapges.model.checkpoint import load_checkpoint
        from facecapges.runtime.web_server import is_loopback
        from facecapges.serving.server import ServeConfig, StreamServer

        if not 0 <= port <= 65535:
            raise UserError(f"--port {port} is out of range")
        if tick_ms < 0:
            raise UserError("--tick-ms must be >= 0")
        if threads < 1:
            raise UserError("--threads must be at least 1")
        if max_per_address is not None and max_per_address < 1:
            raise UserError("--max-per-address must be at least 1")
        ckpt = load_checkpoint(checkpoint, style)
        cfg = ServeConfig(
            host=host,
            port=port,
            max_streams=max_streams,
            rate_limit=rate_limit,
            idle_timeout=idle_timeout,
            threads=threads,
            tick_ms=tick_ms,
            max_per_address=max_per_address,
        )
        server = StreamServer(ckpt, cfg, log=lambda m: typer.echo(m, err=True))
        if not is_loopback(host):
            typer.secho(
                f"warning: listening on {host}: anyone who can reach it can use it (no authentication)",
                err=True,
                fg=typer.colors.YELLOW,
            )
        server.start()
        typer.echo(
            f"serving {ckpt.path.name} on {server.url} (max {max_streams} streams, "
            f"{rate_limit:g} msg/s per stream); Ctrl-C stops",
            err=False,
        )
        try:
            server.run()
        finally:
            typer.echo(f"served: {server.summary()}")
