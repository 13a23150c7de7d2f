"""The ``serve`` settings (:class:`ServeConfig`); the command line's defaults are its defaults.

Kept apart from :mod:`.server` so that ``--help`` imports nothing heavy.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class ServeConfig:
    host: str = "127.0.0.1"
    port: int = 8780
    max_streams: int = 256
    rate_limit: float = 30.0  # messages per second per connection (2× the model rate)
    max_pending: int = 4  # frames a stream may have waiting for a tick
    idle_timeout: float = 60.0  # seconds without input before a stream is closed (0 = never)
    send_buffer_bytes: int = 1 << 20  # unsent output above this closes a client that stopped reading
    threads: int = 1  # torch threads of the batched model call
    tick_ms: float = 15.0  # least time between the starts of two ticks (lets batches fill)
    first_input_timeout: float = 10.0  # seconds from hello to the first input (0 = no limit)
    min_input_rate: float = 1.0  # inputs per second a stream must keep over each rate_window (0 = none)
    rate_window: float = 10.0  # seconds
    intensity: float = 1.0  # each new stream's gesture intensity (a client changes its own: protocol docs)
    max_per_address: int | None = None  # streams per client address; None: 16 (loopback included)
    trust_proxy: bool = False  # a loopback connection's X-Forwarded-For names its client (a local reverse proxy)

    def check(self) -> None:
        """UserError for a setting no server can have (each named by its command-line option)."""
        from facecapges.errors import UserError

        if not 0 <= self.port <= 65535:
            raise UserError(f"--port {self.port} is out of range")
        if self.tick_ms < 0:
            raise UserError("--tick-ms must be >= 0")
        if self.threads < 1:
            raise UserError("--threads must be at least 1")
        from facecapges.engine.intensity import check_intensity

        check_intensity(self.intensity)
        if self.max_per_address is not None and self.max_per_address < 1:
            raise UserError("--max-per-address must be at least 1")
