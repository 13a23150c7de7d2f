"""Who holds a slot, and for how long: the admission policy of ``serve`` (docs/serve-protocol.md).

One implementation for both servers — the single-process one (:mod:`.server`) and every replica of
the Ray application (:mod:`.ray_app`). The policy decides; the server does the talking (the
``error`` message, the close code and reason returned here) with whatever WebSocket it has.

Fair admission. A slot-holder is judged by its input rate against the model rate: inputs over the
last :data:`RATE_WINDOW_S` seconds (or since it got its slot, if that is shorter). Once it has held
its slot for :data:`GRACE_S` seconds, a stream below :data:`LIVE_FRACTION` of the model rate (7.5
inputs/s at 15 fps) is *slow*. When the server is full, or the newcomer's address holds its share,
a newcomer is not refused while some stream in the way is slow: it gets ``hello`` *on probation*
(no slot; at most ``max_streams`` such at once, the one waiting the longest closed to make room for
a newer one), and its first ``input`` takes the slot of the slowest such stream, which is closed
(1013, "evicted"). A live stream (15 inputs a second) is never evicted.

Churn. A stream that took its slot by evicting another is not judged in its grace second either, so
slow holders that reopen at once could keep every slot of an address young and a live client of
that address refused. A newcomer whose way holds such a young *taker* therefore waits on probation
instead of being refused: its inputs are dropped, each one looks again, and a slot that ripens
slow goes to the waiter with the highest input rate since it connected (a live client, sending 15 a
second, before holders that reconnect and send one input now and then). Once no taker in its
way is young and none is slow, it is refused as before. A server that simply filled up with new
connections refuses at once, as before.

Addresses. One client address holds at most ``max_per_address`` streams (16 by default, loopback
included). ``X-Forwarded-For`` is ignored unless ``trust_proxy`` is set (:func:`forwarded_address`).

Limits on a stream: ``rate_limit`` messages per second (a token bucket holding one second of
messages; one ``error`` a second about the dropped ones), ``idle_timeout`` seconds without input
(1000), the first input within ``first_input_timeout`` seconds (1008), at least ``min_input_rate``
inputs a second over every ``rate_window`` seconds (1008).
"""

from __future__ import annotations

import asyncio
import collections
import ipaddress
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TypeVar

from facecapges.runtime.outputs.ws import is_loopback
from facecapges.serving.config import ServeConfig

RATE_WINDOW_S = 2.0  # a slot-holder's input rate is counted over this many seconds
GRACE_S = 1.0  # a stream is not judged slow before it has held its slot this long
LIVE_FRACTION = 0.5  # below this fraction of the model rate a stream is slow (evicted first when full)
DEFAULT_PER_ADDRESS = 16  # streams per client address unless --max-per-address says otherwise

FULL_CODE = 1013  # "try again later": refused, or evicted to make room
EVICTED_SLOW = "evicted: slower than a live stream while the server was full"
EVICTED_WAITING = "evicted: no input while the server was full"


H = TypeVar("H", bound="Holder")  # a server's own stream record


def forwarded_address(peer: str, forwarded_for: str | None, trust_proxy: bool) -> str:
    """The address a stream counts against: its peer's; with ``trust_proxy``, a loopback peer that
    carries ``X-Forwarded-For`` (a reverse proxy on this machine) counts against the header's last
    entry (the address the proxy saw) if that is an IP address. Without ``trust_proxy`` the header
    is ignored: any local program could claim any address with it."""
    if trust_proxy and is_loopback(peer) and forwarded_for:
        try:
            return str(ipaddress.ip_address(forwarded_for.split(",")[-1].strip()))
        except ValueError:
            pass
    return peer


def close_reason(refusal: str) -> str:
    """The close frame's reason for a refusal (its first clause, within the frame's limit)."""
    return refusal.split(":")[0][:100]


@dataclass(kw_only=True)
class Holder:
    """What the policy keeps of one connection (a server's stream record extends it)."""

    address: str = "?"
    probation: bool = False  # connected while full: no slot until its first input takes a slow one's
    closed: bool = False
    since: float = 0.0  # when it got its slot
    taker: bool = False  # it got its slot by evicting a slow stream (module docs, "Churn")
    connected: float = 0.0  # when it connected
    waited: int = 0  # inputs dropped while it waited on probation
    last_input: float = 0.0  # (or when it connected)
    times: collections.deque = field(default_factory=lambda: collections.deque(maxlen=256))  # inputs' arrivals
    tokens: float = 0.0
    t_tokens: float = 0.0
    last_limit_error: float = -1e9
    inputs: int = 0  # inputs received in the current rate window
    window_t0: float | None = None  # start of the rate window (the first input)


@dataclass
class Arrival:
    """What to do with a newcomer: ``refusal`` (send it as an ``error``, close 1013; ``stat`` names
    the counter), else admit it — on ``probation`` if the server is full — after closing
    ``make_room`` (a newcomer on probation waiting the longest; 1013, :data:`EVICTED_WAITING`)."""

    refusal: str | None = None
    stat: str = ""
    probation: bool = False
    make_room: Holder | None = None


class Admission:
    """The policy for one server's streams (module docs); ``fps`` is the model rate."""

    def __init__(self, cfg: ServeConfig, fps: float = 15.0):
        self.cfg = cfg
        self.fps = fps
        self.per_address = cfg.max_per_address if cfg.max_per_address is not None else DEFAULT_PER_ADDRESS

    def new(self, st: Holder, address: str, now: float, probation: bool) -> None:
        """Set up a newcomer's record: a full token bucket, its clocks."""
        st.address, st.probation, st.since, st.last_input, st.connected = address, probation, now, now, now
        st.tokens, st.t_tokens = self.cfg.rate_limit, now

    # ------------------------------------------------------------ messages
    def allow(self, st: Holder, now: float) -> tuple[bool, str | None]:
        """Token bucket: ``rate_limit`` messages per second, one second of burst. (allowed, the
        ``error`` to send about a dropped message — at most one a second — or None)."""
        rate = self.cfg.rate_limit
        st.tokens = min(rate, st.tokens + (now - st.t_tokens) * rate)
        st.t_tokens = now
        if st.tokens >= 1.0:
            st.tokens -= 1.0
            return True, None
        if now - st.last_limit_error >= 1.0:
            st.last_limit_error = now
            return False, f"rate limit: at most {rate:g} messages per second; messages dropped"
        return False, None

    def record_input(self, st: Holder, now: float) -> None:
        st.last_input = now
        st.times.append(now)
        st.inputs += 1
        if st.window_t0 is None:
            st.window_t0 = now

    # ------------------------------------------------------------ slots
    @staticmethod
    def holders(streams: Iterable[Holder], address: str | None = None) -> list:
        """Streams holding a slot (of ``address`` only, if given)."""
        return [
            st for st in streams if not st.closed and not st.probation and (address is None or st.address == address)
        ]

    def in_the_way(self, streams: Iterable[Holder], address: str) -> tuple[list, str] | None:
        """The streams a newcomer from ``address`` must displace one of, and the refusal if none
        is slow; None when there is room for it."""
        streams = list(streams)
        mine = self.holders(streams, address)
        if len(mine) >= self.per_address:
            return mine, f"at most {self.per_address} streams per client address; try again later"
        held = self.holders(streams)
        if len(held) >= self.cfg.max_streams:
            return held, f"server full: {self.cfg.max_streams} streams; try again later"
        return None

    def rate(self, st: Holder, now: float) -> float:
        """A slot-holder's inputs per second over the last :data:`RATE_WINDOW_S` s (or since it got its slot)."""
        span = max(1e-3, min(RATE_WINDOW_S, now - st.since))
        return sum(t >= now - span for t in st.times) / span

    @staticmethod
    def unproven(streams: Iterable[Holder], now: float) -> bool:
        """Whether some of ``streams`` took its slot by eviction less than :data:`GRACE_S` s ago (module
        docs, "Churn"): not judged yet, so a newcomer waits for it rather than being refused."""
        return any(st.taker and now - st.since < GRACE_S for st in streams)

    def slowest(self, streams: Iterable[Holder], now: float) -> Holder | None:
        """The slowest of ``streams`` below :data:`LIVE_FRACTION` of the model rate that has held its
        slot for :data:`GRACE_S` s; None if every one streams (or is new)."""
        slow = [
            (r, st.last_input, st)
            for st in streams
            if now - st.since >= GRACE_S and (r := self.rate(st, now)) < LIVE_FRACTION * self.fps
        ]
        return min(slow, key=lambda x: (x[0], x[1]))[2] if slow else None

    @staticmethod
    def _stat(refusal: str) -> str:
        return "refused_address" if "per client address" in refusal else "refused_full"

    def arrive(self, streams: Iterable[Holder], address: str, now: float) -> Arrival:
        """A newcomer from ``address`` connected (module docs, "Fair admission")."""
        streams = list(streams)
        way = self.in_the_way(streams, address)
        if way is None:
            return Arrival()
        if self.slowest(way[0], now) is None and not self.unproven(way[0], now):
            return Arrival(refusal=way[1], stat=self._stat(way[1]))
        waiting = [st for st in streams if st.probation and not st.closed]
        old = min(waiting, key=lambda s: s.last_input) if len(waiting) >= self.cfg.max_streams else None
        return Arrival(probation=True, make_room=old)

    @staticmethod
    def waiting_rate(st: Holder, now: float) -> float:
        """A probationer's inputs per second since it connected (this one counted; at least 0.2 s)."""
        return (st.waited + 1) / max(0.2, now - st.connected)

    def admit(self, streams: Iterable[Holder], st: Holder, now: float) -> tuple[str | None, str, Holder | None]:
        """A stream on probation sent an input: (refusal, its counter, None) when no stream in its way
        is slow or a young taker; (None, "waiting", None) — it stays on probation, the input is
        dropped — while none is slow but one is a young taker, or while another waiter sends faster
        (module docs, "Churn"); else it holds a slot now — (None, "",
        the slowest stream in its way, to be closed 1013 :data:`EVICTED_SLOW`, or None if a slot
        was free)."""
        streams = list(streams)
        way = self.in_the_way(streams, st.address)
        victim = None
        if way is not None:
            victim = self.slowest(way[0], now)
            mine = self.waiting_rate(st, now)
            faster = any(  # a slot that ripens goes to the livest waiter, not to whoever asks first
                o is not st and o.probation and not o.closed and o.waited and self.waiting_rate(o, now) > mine
                for o in streams
            )
            if victim is None or faster:
                if victim is not None or self.unproven(way[0], now):
                    st.waited += 1
                    return None, "waiting", None
                return way[1], self._stat(way[1]), None
            victim.closed = True
        st.probation = False
        st.taker = victim is not None
        st.since = now
        return None, "", victim

    # ------------------------------------------------------------ closes
    def overdue(self, st: Holder, now: float) -> tuple[str, int, str] | None:
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

    def check_period(self) -> float | None:
        """How often to look for overdue streams (None: never)."""
        c = self.cfg
        periods = [p for p in (c.idle_timeout, c.first_input_timeout, c.rate_window) if p > 0]
        return min(1.0, min(periods) / 4) if periods else None

    async def close_overdue(
        self, holders: Callable[[], Iterable[H]], stats: dict, close: Callable[[H, int, str], None]
    ) -> None:
        """Every :meth:`check_period`, ``close(holder, code, reason)`` each open holder that is :meth:`overdue`
        (counted in ``stats``); returns at once when nothing can be overdue. Both servers' idle loop."""
        period = self.check_period()
        while period is not None:
            await asyncio.sleep(period)
            now = time.monotonic()
            for st in list(holders()):
                why = None if st.closed else self.overdue(st, now)
                if why is not None:
                    stats[why[0]] += 1
                    close(st, why[1], why[2])
