"""Issue 28, items 3 and 4: slow clients cannot hold the servers' slots.

* the study server: 70 sockets trickling one header line every second (from 127.0.0.2, another
  loopback address) leave a participant (127.0.0.1) served, and each trickler is cut at the
  request deadline;
* ``serve`` on loopback (every client shares 127.0.0.1, as behind a local proxy): clients that
  reopen idle sockets as they are closed do not lock a real client out (idle streams are evicted
  first), and proxy-forwarded addresses are capped.

Loopback only, bounded in sockets and seconds."""

from __future__ import annotations

import asyncio
import json
import socket
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from _study_media import make_clips
from facecapges.serving.admission import GRACE_S
from facecapges.study.build import create_study, open_study
from facecapges.study.server import make_server, serve_in_thread


@pytest.fixture(scope="module")
def study_dir(tmp_path_factory, beat_bvh, beat_wav):
    tmp = tmp_path_factory.mktemp("trust_servers")
    y = make_clips(tmp / "src", beat_bvh, beat_wav, n_clips=2, seconds=1.0)
    create_study(y, tmp / "study", 2, seed=5, progress=False)
    return tmp / "study"


def _trickler(port: int) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port), timeout=5, source_address=("127.0.0.2", 0))
    s.sendall(b"GET /api/info HTTP/1.1\r\n")
    return s


@pytest.mark.serial
def test_trickling_clients_cannot_hold_the_study_server(study_dir):
    server = make_server(open_study(study_dir), "127.0.0.1", 0, timeout=5.0, max_connections=64,
                         request_deadline=3.0)
    serve_in_thread(server)
    port = server.server_address[1]
    socks = []
    try:
        for _ in range(70):
            try:
                socks.append(_trickler(port))
            except OSError:
                pass
        t0 = time.monotonic()
        served = 0
        while time.monotonic() - t0 < 2.5:  # the tricklers keep sending, the participant is served
            for s in socks:
                try:
                    s.sendall(b"X-Slow: 1\r\n")
                except OSError:
                    pass
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/info", timeout=5) as r:
                served += r.status == 200
            time.sleep(0.5)
        assert served >= 4
        # 127.0.0.2 holds at most its share: each newer trickler closed its longest-waiting one
        assert server.evicted >= 70 - server.max_per_address
        # … and the ones that got a slot are cut at the deadline although they never stopped sending
        time.sleep(1.5)
        cut = 0
        for s in socks:
            try:
                s.sendall(b"X-Slow: 1\r\n")
                s.settimeout(0.5)
                cut += s.recv(100) == b""
            except TimeoutError:  # still open, silent: not cut
                pass
            except OSError:  # reset / broken pipe: cut
                cut += 1
        assert cut == len(socks)
    finally:
        for s in socks:
            s.close()
        server.shutdown()
        server.server_close()


class _Tricklers:
    """``per_address`` sockets from each of ``addresses`` (other loopback addresses), each sending a
    request line and then one header line a second, reopened at once when the server closes or
    refuses it (the attack of issue 34, item 2). :meth:`step` is one round; nothing runs by itself."""

    def __init__(self, port: int, addresses: list[str], per_address: int):
        self.port = port
        self.slots: list[tuple[str, socket.socket | None]] = [(a, None) for a in addresses for _ in range(per_address)]
        self.reopened = 0

    def _open(self, address: str) -> socket.socket | None:
        try:
            s = socket.create_connection(("127.0.0.1", self.port), timeout=2, source_address=(address, 0))
            s.sendall(b"GET /api/info HTTP/1.1\r\n")
            s.setblocking(False)
            return s
        except OSError:
            return None

    def step(self, header: bool) -> None:
        for i, (address, s) in enumerate(self.slots):
            alive = s is not None
            if alive:
                try:
                    s.recv(4096, socket.MSG_PEEK)
                    alive = False  # closed (b"") or answered (a 503): reopen
                except BlockingIOError:  # open and silent: go on trickling
                    if header:
                        try:
                            s.sendall(b"X-Slow: 1\r\n")
                        except OSError:
                            alive = False
                except OSError:
                    alive = False
            if not alive:
                if s is not None:
                    s.close()
                    self.reopened += 1
                self.slots[i] = (address, self._open(address))

    def close(self) -> None:
        for _, s in self.slots:
            if s is not None:
                s.close()


@pytest.mark.serial
def test_tricklers_from_several_addresses_cannot_fill_the_study_server(study_dir):
    """Issue 34, item 2: two addresses trickling headers (reopened at once) took the 64 connections
    (32 per address) and every participant got 503. Now an address holds at most 16 and, when full,
    the connection waiting the longest for its request makes room: five trickling addresses (100
    sockets, more than the server holds) leave a participant served."""
    server = make_server(open_study(study_dir), "127.0.0.1", 0)  # the defaults: 64 connections, 30-s deadline
    serve_in_thread(server)
    port = server.server_address[1]
    attack = _Tricklers(port, [f"127.0.0.{k}" for k in range(2, 7)], 20)
    tries = served = 0
    try:
        attack.step(header=False)
        t0 = time.monotonic()
        last_header = t0
        while time.monotonic() - t0 < 8.0:  # bounded: 8 s of attack
            attack.step(header=time.monotonic() - last_header >= 1.0)
            if time.monotonic() - last_header >= 1.0:
                last_header = time.monotonic()
            tries += 1
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/info", timeout=5) as r:
                    served += r.status == 200
            except OSError:  # 503 or reset: not served
                pass
            time.sleep(0.2)
    finally:
        attack.close()
        server.shutdown()
        server.server_close()
    print(f"participant served {served} of {tries} pages under the attack; evicted {getattr(server, 'evicted', None)}, "
          f"refused {server.refused}, tricklers reopened {attack.reopened}")
    assert served >= 0.9 * tries, (served, tries, server.refused)  # main: 0
    assert server.evicted >= 100 - 64


# ------------------------------------------------------------------ serve on loopback
TINY = dict(audio_frontend_channels=(8, 8, 8), audio_tcn_channels=8, audio_dim=16, face_tcn_channels=8, face_dim=8,
            lstm_hidden=16, mlp_hidden=16, disc_channels=8)


def _tiny_network():
    import torch

    from facecapges.network.config import ModelConfig
    from facecapges.network.network import FaceCapGes
    from facecapges.network.style import NetworkStyle

    torch.manual_seed(0)
    model = FaceCapGes(ModelConfig(**TINY)).eval()
    neutral = np.zeros((16, 47, 6), np.float32)
    neutral[..., 0] = neutral[..., 4] = 1.0
    return NetworkStyle(model=model, meta={"neutral_window": neutral.tolist(), "model_config": {"fps": 15}},
                        path=Path("random-init"))


@pytest.fixture(scope="module")
def stream_server(default_checkpoint):
    """``make(**ServeConfig options)`` → a started server of the installed matching style, for the tests that assert
    the admission of connections: its model process starts without torch (about 1.5 s against 5-6 s for a random
    network's at load 6, and 0.2 s against 1.5-2.3 s to stop). ``make(network=True, ...)`` → of a tiny random
    network, for the serial tests that count a live client's poses (with the matching style the loopback test's
    client got 19 of its 30 frames, against the bound 20, in two of seven runs at load 1-3)."""
    from facecapges.serving.server import ServeConfig, StreamServer

    servers = []

    def make(network: bool = False, **over):
        s = StreamServer(_tiny_network() if network else default_checkpoint, ServeConfig(port=0, **over)).start()
        servers.append(s)
        return s

    yield make
    for s in servers:
        s.close()


def _frame(k: int) -> str:
    from facecapges.runtime.outputs import protocol

    return protocol.encode_input(k, np.zeros(1067, np.float32), np.zeros(52, np.float32),
                                 np.array([1, 0, 0, 0, 1, 0], np.float32))


def test_reopened_idle_sockets_do_not_lock_out_a_real_client(stream_server):
    from websockets.asyncio.client import connect

    srv = stream_server(max_streams=6)  # first_input_timeout: the default 10 s
    assert srv.loopback_only

    async def attacker(stop: asyncio.Event):  # keeps every slot taken: reopens each socket as it is closed
        async def one():
            while not stop.is_set():
                try:
                    async with connect(srv.url) as ws:
                        async for _ in ws:
                            pass
                except Exception:  # noqa: BLE001  refused or evicted: reopen at once
                    await asyncio.sleep(0.05)
        await asyncio.gather(*[one() for _ in range(12)])

    async def good_client() -> bool:
        try:
            async with connect(srv.url) as ws:
                if json.loads(await ws.recv())["type"] != "hello":
                    return False
                for k in range(20):  # a live stream: 15 frames a second
                    await ws.send(_frame(k))
                    if json.loads(await asyncio.wait_for(ws.recv(), 5))["type"] != "pose":
                        return False
                    await asyncio.sleep(1 / 15)
                return True
        except Exception:  # noqa: BLE001  refused or closed: not served
            return False

    async def main():
        stop = asyncio.Event()
        att = asyncio.ensure_future(attacker(stop))
        await asyncio.sleep(3.0)  # every slot held by the attacker
        results = []
        for _ in range(6):
            results.append(await good_client())
            await asyncio.sleep(0.3)
        stop.set()
        att.cancel()
        await asyncio.gather(att, return_exceptions=True)
        return results

    results = asyncio.run(asyncio.wait_for(main(), 90))
    assert sum(results) >= 5, results  # was 0 of 11 before the admission rule
    assert srv.summary().get("evicted_slow", 0) >= 5


def test_forwarded_addresses_are_capped_behind_a_local_proxy(stream_server):
    from websockets.asyncio.client import connect

    srv = stream_server(max_streams=20, max_per_address=3, trust_proxy=True)

    async def main():
        held = []
        for _ in range(3):
            ws = await connect(srv.url, additional_headers={"X-Forwarded-For": "203.0.113.7"})
            await ws.recv()
            held.append(ws)
        extra = await connect(srv.url, additional_headers={"X-Forwarded-For": "10.0.0.1, 203.0.113.7"})
        msg = json.loads(await extra.recv())
        other = await connect(srv.url, additional_headers={"X-Forwarded-For": "198.51.100.9"})
        ok = json.loads(await other.recv())
        for ws in (*held, extra, other):
            await ws.close()
        return msg, ok

    msg, ok = asyncio.run(asyncio.wait_for(main(), 30))
    assert msg["type"] == "error" and "per client address" in msg["message"]
    assert ok["type"] == "hello"


def test_forwarded_addresses_are_ignored_unless_the_proxy_is_trusted(stream_server):
    """Without ``trust_proxy`` any local program could claim an address per connection with
    X-Forwarded-For: the header is ignored and every connection counts against 127.0.0.1."""
    from websockets.asyncio.client import connect

    srv = stream_server(max_streams=20, max_per_address=3)

    async def main():
        held, replies = [], []
        for k in range(5):  # five claimed addresses, one real one
            ws = await connect(srv.url, additional_headers={"X-Forwarded-For": f"198.51.100.{k + 1}"})
            replies.append(json.loads(await ws.recv())["type"])
            held.append(ws)
        for ws in held:
            await ws.close()
        return replies

    replies = asyncio.run(asyncio.wait_for(main(), 30))
    assert replies == ["hello"] * 3 + ["error"] * 2, replies


async def _slow_holders(url: str, n: int, period: float, stop: asyncio.Event) -> None:
    """``n`` clients that each send one valid input every ``period`` seconds and reconnect at once
    when closed (the attack of issue 34, item 1)."""
    from websockets.asyncio.client import connect

    async def drain(ws):
        try:
            async for _ in ws:
                pass
        except Exception:  # noqa: BLE001  closed: the holder reconnects
            pass

    async def one():
        while not stop.is_set():
            try:
                async with connect(url) as ws:
                    reader = asyncio.ensure_future(drain(ws))
                    k = 0
                    while not stop.is_set() and not reader.done():
                        await ws.send(_frame(k))
                        k += 1
                        await asyncio.sleep(period)
                    reader.cancel()
            except Exception:  # noqa: BLE001  refused or evicted: reopen at once
                await asyncio.sleep(0.02)

    await asyncio.gather(*[one() for _ in range(n)])


async def _live_client(url: str, n: int, headers: dict | None = None) -> int:
    """A real client: ``n`` inputs at 15 a second without waiting for replies; the poses it got back."""
    from websockets.asyncio.client import connect

    got = 0
    try:
        async with connect(url, additional_headers=headers) as ws:
            if json.loads(await asyncio.wait_for(ws.recv(), 10))["type"] != "hello":
                return 0

            async def reader():
                nonlocal got
                async for m in ws:
                    got += json.loads(m)["type"] == "pose"

            task = asyncio.ensure_future(reader())
            t0 = time.monotonic()
            for k in range(n):
                if task.done():
                    break
                await ws.send(_frame(k))
                await asyncio.sleep(max(0.0, t0 + (k + 1) / 15 - time.monotonic()))
            deadline = time.monotonic() + 3.0
            while got < n and not task.done() and time.monotonic() < deadline:
                await asyncio.sleep(0.05)
            task.cancel()
    except Exception:  # noqa: BLE001  refused or closed: what it got so far
        pass
    return got


@pytest.mark.serial
def test_slow_rate_holders_do_not_lock_out_a_live_client(stream_server):
    """Issue 34, item 1: 16 sockets each sending one valid input every 0.9 s (and reopening at once)
    on ``max_streams=16`` held every slot: a live client got 0 of 600 frames. Slot-holders are now
    judged by their input rate against the model rate and the slowest is evicted for a newcomer."""
    srv = stream_server(network=True, max_streams=16)

    async def main():
        stop = asyncio.Event()
        attack = asyncio.ensure_future(_slow_holders(srv.url, 16, 0.9, stop))
        await asyncio.sleep(3.0)  # every slot held by the attack, past its grace second
        delivered = []
        for _ in range(4):
            delivered.append(await _live_client(srv.url, 45))
            await asyncio.sleep(0.3)
        stop.set()
        await asyncio.wait_for(attack, 10)
        return delivered

    delivered = asyncio.run(asyncio.wait_for(main(), 90))
    s = srv.summary()
    print(f"live client under attack: {delivered} of 4 x 45 frames; server {s}")
    # main: 0 of 180. Not all 180: on a loaded machine a few frames of a stream are dropped as busy
    assert sum(delivered) >= 2 / 3 * 4 * 45 and min(delivered) > 0, (delivered, s)
    assert s.get("evicted_slow", 0) >= 4


LIVE_INPUTS = 45  # the live newcomer's inputs (3 s at 15 a second) in the loopback cap's test


@pytest.mark.serial
def test_one_loopback_address_is_capped_and_its_slow_streams_make_room(stream_server):
    """The per-address cap holds on loopback too (16 by default): 24 slow holders from 127.0.0.1 get
    at most 16 slots of 40; a live client from the same address still gets in (it evicts the slowest
    of its address) and one from another loopback address finds a free slot."""
    srv = stream_server(network=True, max_streams=40)

    async def main():
        stop = asyncio.Event()
        attack = asyncio.ensure_future(_slow_holders(srv.url, 24, 0.9, stop))
        await asyncio.sleep(3.0)
        held = len([st for st in list(srv.streams.values()) if not st.probation and st.address == "127.0.0.1"])
        same = await _live_client(srv.url, LIVE_INPUTS)
        stop.set()
        await asyncio.wait_for(attack, 10)
        return held, same

    held, same = asyncio.run(asyncio.wait_for(main(), 60))
    s = srv.summary()
    assert held <= 16, (held, s)
    # admitted and served: it may wait on probation up to the holders' grace second (its inputs dropped meanwhile,
    # the admission policy's own bound: 15 frames), and a loaded machine may drop a few more as busy (5). With 30
    # inputs and 20 asked, 11 dropped in the wait failed it now and then, with the code before and after 2026-12-04
    assert same >= LIVE_INPUTS - GRACE_S * 15 - 5, (same, s)
    assert s.get("refused_address", 0) + s.get("evicted_slow", 0) >= 8, s


def test_a_live_newcomer_waits_out_young_slow_holders_instead_of_being_refused():
    """The policy behind the loopback test above, without a server or timing: 16 slow holders of one
    address that reopen at once and evict each other keep every slot young (each inside its grace
    second). A live newcomer
    from that address used to be refused outright (the flaky loss of the test above, refused_address
    59); it now waits on probation, its inputs dropped, and takes the first slot that ripens slow,
    before a reconnecting holder that asks first.
    Once every stream in its way has proven live, it is refused as before."""
    from facecapges.serving.admission import GRACE_S, Admission, Holder
    from facecapges.serving.config import ServeConfig

    pol = Admission(ServeConfig(max_streams=40))
    t0 = 100.0
    holders = []
    for k in range(16):  # admitted over the last 0.8 s, one input each
        h = Holder()
        pol.new(h, "127.0.0.1", t0 - 0.8 + 0.05 * k, probation=False)
        pol.record_input(h, h.since)
        h.taker = True  # each took its slot by evicting another (what admit() records)
        holders.append(h)
    arrival = pol.arrive(holders, "127.0.0.1", t0)
    assert arrival.refusal is None and arrival.probation, arrival
    me = Holder()
    pol.new(me, "127.0.0.1", t0, probation=True)
    assert pol.admit(holders + [me], me, t0 + 0.05) == (None, "waiting", None)
    assert me.probation
    for i in (2, 3):  # it waits, sending 15 a second (the oldest holder ripens at t0 + 0.2)
        assert pol.admit(holders + [me], me, t0 + i / 15 - 0.01)[1] == "waiting"
    ripe = t0 - 0.8 + GRACE_S + 0.01  # the oldest holder ripens slow
    churner = Holder()  # a holder that reconnected just now asks first: the livelier waiter gets the slot
    pol.new(churner, "127.0.0.1", ripe - 0.01, probation=True)
    assert pol.admit(holders + [me, churner], churner, ripe) == (None, "waiting", None)
    refusal, _stat, victim = pol.admit(holders + [me, churner], me, ripe + 0.01)
    assert refusal is None and victim is holders[0] and not me.probation and me.taker

    fresh = []  # young streams that got free slots (a server that just filled up): refused at once
    for _k in range(16):
        h = Holder()
        pol.new(h, "127.0.0.1", t0 - 0.2, probation=False)
        fresh.append(h)
    assert pol.arrive(fresh, "127.0.0.1", t0).refusal is not None

    live = []  # every stream in the way has proven live (15 inputs a second for 2 s): refused
    for _k in range(16):
        h = Holder()
        pol.new(h, "127.0.0.1", t0 - 2.0, probation=False)
        for i in range(30):
            pol.record_input(h, t0 - 2.0 + i / 15)
        live.append(h)
    assert pol.arrive(live, "127.0.0.1", t0).refusal is not None
