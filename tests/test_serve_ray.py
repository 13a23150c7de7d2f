"""``serve`` on Ray Serve: local Ray clusters on 127.0.0.1 — the failover test's bench starts a two-node one (the
head and one worker), the admission test's fixture a one-node one (~15 s) after the bench's has stopped.

Admission: a second application on the same cluster (one replica, at most 2 streams per
address) shows ``serve``'s per-address cap and the eviction of a slow holder on the Ray path —
the same policy code (serving/admission.py), messages and close codes. Before, a replica had no
per-address limit: the third stream of an address got its ``hello``.

Failover (runs first, before the fixture's cluster starts: the bench's ``cluster`` area as users run
it, ``bench --quick --only cluster``, which test_bench.py's ``bench --quick`` leaves to this file): 20
live clients through Ray Serve's HAProxy, the worker node killed mid-run. Every stream must be served again within 2 s of the freeze its user sees,
and no hand-over may pop (whole-body acceleration above the real motion's 99.9th percentile);
the loss of the clients whose replica lived is measured. Without ``resume`` (the old protocol)
the moved streams would restart from the rest pose; without the Ray application there is nothing
to connect to. The clusters, their processes and the clients are stopped by the bench and the fixture
(benchmarks/cluster.py).
"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from conftest import shared_file
from runtime_helpers import cli_process

REPO = Path(__file__).resolve().parents[1]

PER_ADDRESS = 2


@pytest.fixture(scope="module")
def cluster():
    from ray import serve

    from facecapges.benchmarks.cluster import LocalCluster
    from facecapges.serving.config import ServeConfig
    from facecapges.serving.ray_app import build_app, wait_ready

    shared_file("data/beat/2_scott_0_1_1.bvh")
    # one node: the admission test needs an application behind the cluster's HAProxy, not a second node
    # (the failover test's bench starts its own two); the head takes this application's replica too
    with LocalCluster(nodes=1, say=print) as lc:
        files = lc._files
        # the admission test's own application: one replica, no CPU of its own (the head's is the first application's)
        cfg = ServeConfig(max_per_address=PER_ADDRESS)
        # its replica in the cluster's environment: served through the same HAProxy
        app = build_app(replicas=1, config=cfg, num_cpus=0, env=lc.env)
        serve.run(app, name="admission", route_prefix="/admission")
        wait_ready(f"http://127.0.0.1:{lc.port}/admission", 1)
        yield lc
        cluster_procs = _cluster_processes(files)  # its raylets, GCS and HAProxy, and their descendants
        assert any("haproxy" in cmd for cmd in cluster_procs.values()), cluster_procs
    # stopped without Serve's own shutdown (LocalCluster._stop): no process of the cluster is left, HAProxy and
    # the replicas included
    left = _still_running(cluster_procs)
    assert not left, left


def _command_lines() -> dict[int, tuple[int, str]]:
    """Every process's parent and command line."""
    import os

    procs = {}
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                cmd = f.read().replace(b"\0", b" ").decode(errors="replace")
            with open(f"/proc/{pid}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
        except (FileNotFoundError, ProcessLookupError, PermissionError):
            continue
        procs[int(pid)] = (ppid, cmd)
    return procs


def _cluster_processes(folder: str) -> dict[int, str]:
    """The processes whose command line names ``folder`` (the cluster's own), and their descendants."""
    procs = _command_lines()
    found = {pid for pid, (_, cmd) in procs.items() if folder in cmd}
    grew = True
    while grew:
        more = {pid for pid, (ppid, _) in procs.items() if ppid in found} - found
        found |= more
        grew = bool(more)
    return {pid: procs[pid][1] for pid in found}


def _still_running(procs: dict[int, str], wait_s: float = 10.0) -> dict[int, str]:
    """Those of ``procs`` (pid → command line) still running after ``wait_s``."""
    import time

    end = time.monotonic() + wait_s
    while True:
        now = _command_lines()
        left = {pid: cmd for pid, cmd in procs.items() if pid in now and now[pid][1] == cmd}
        if not left or time.monotonic() > end:
            return left
        time.sleep(0.2)


async def _admission(url: str, messages: list[str]) -> dict:
    from websockets.asyncio.client import connect
    from websockets.exceptions import ConnectionClosed

    async def open_stream():
        ws = await connect(url, open_timeout=30)
        first = json.loads(await ws.recv())
        while first["type"] == "status":  # the replica still loads: hello follows
            first = json.loads(await ws.recv())
        return ws, first

    async def closed(ws) -> tuple[list[str], int | None, str]:
        """What a connection got until it was closed: its messages' types / errors, code, reason."""
        got = []
        try:
            while True:
                m = json.loads(await asyncio.wait_for(ws.recv(), 10))
                got.append(m.get("message", m["type"]))
        except ConnectionClosed:
            pass
        return got, ws.close_code, ws.close_reason

    async def live(ws, stop: asyncio.Event) -> int:
        """15 inputs a second until ``stop``; the poses it got."""
        poses = 0

        async def read():
            nonlocal poses
            async for m in ws:
                poses += '"pose"' in m[:20]

        reader = asyncio.ensure_future(read())
        k = 0
        while not stop.is_set():
            await ws.send(messages[k % len(messages)])
            k += 1
            await asyncio.sleep(1 / 15)
        reader.cancel()
        return poses

    out: dict = {}
    a, _ = await open_stream()  # sends one input, then nothing: slow once its grace is over
    await a.send(messages[0])
    out["a_first"] = json.loads(await a.recv())["type"]
    b, _ = await open_stream()  # a live stream
    stop = asyncio.Event()
    b_task = asyncio.ensure_future(live(b, stop))
    await asyncio.sleep(0.3)
    c, c_first = await open_stream()  # a third of the address while both are new: refused
    out["c"] = (c_first.get("message"), *(await closed(c))[1:])
    await asyncio.sleep(1.5)  # past the grace: a is slow (one input in 1.8 s), b live
    d, d_first = await open_stream()
    out["d_first"] = d_first["type"]  # hello on probation
    await d.send(messages[1])
    out["a"] = await closed(a)  # d's first input takes a's slot
    out["d_pose"] = json.loads(await asyncio.wait_for(d.recv(), 10))["type"]
    # b live and d a young taker (it took a's slot by eviction, then sent nothing): e is not refused but
    # waits on probation, its inputs dropped, until d's grace second is over; d is then slow and e takes its
    # slot (admission.py, "Churn")
    e, e_first = await open_stream()
    out["e_first"] = e_first["type"]

    async def feed_e():
        try:
            for k in range(90):
                await e.send(messages[k % len(messages)])
                await asyncio.sleep(1 / 15)
        except ConnectionClosed:
            pass

    feeder = asyncio.ensure_future(feed_e())
    out["d"] = await closed(d)
    kinds: list[str] = []
    while "pose" not in kinds:
        kinds.append(json.loads(await asyncio.wait_for(e.recv(), 10))["type"])
    out["e_pose"] = "pose"
    feeder.cancel()
    stop.set()
    out["b_poses"] = await b_task
    out["b_open"] = b.close_code is None
    for ws in (b, e):
        await ws.close()
    return out


@pytest.mark.slow
@pytest.mark.serial
def test_a_node_dies_and_its_streams_resume_on_the_other(capsys):
    """The bench's ``cluster`` area as users run it (``bench --quick --only cluster``: one ``serve`` process, then
    the cluster, 20 streams for 8 s, the worker killed at 3.2 s); test_bench.py's ``bench --quick`` leaves this
    area to this test, so the suite starts one Ray cluster, not two."""
    shared = shared_file("data/beat/2_scott_0_2_2.wav").parents[2]
    shared_file("data/beat/2_scott_0_1_1.bvh")
    p = cli_process("bench", "--quick", "--json", "--only", "cluster", "--shared", str(shared), timeout=900, cwd=REPO)
    assert p.returncode == 0, p.stderr[-4000:]
    out = json.loads(p.stdout)["cluster"]  # strict JSON alone on stdout: Ray's processes print to stderr
    with capsys.disabled():
        print("\ncluster failover:", json.dumps(out))
    one = out["pairs"][0]["single"]
    assert one["streams"] == 20 and one["sent"] > 0, one
    r = out["failover"]
    assert r["errors"] == 0, r["error_samples"]
    assert r["moved"] >= 1 and r["dropped_not_by_kill"] == 0  # the kill moved some, and only the kill
    assert r["all_back"] and r["within_2s"], r
    # the dead node's replica closed its clients' connections (ray_app.watch_raylet): not all of them had to
    # wait for their own no-pose rule (Ray alone ends the replica within 10 s; a stalled replica's clients
    # may still notice by the rule first on a loaded machine)
    assert r["detect_by_rule"] < r["moved"], r
    assert r["good_clients"] + r["moved"] == 20
    # streams on the live node keep streaming (measured; on a loaded 2-core machine a replica falls
    # behind and drops "busy" frames, so this bounds the loss rather than requiring none)
    assert r["good_clients"] == 0 or r["good_lost"] < 0.5 * r["good_sent"], r
    assert r["handover"]["measured"] == r["moved"] and r["handover"]["pops"] == 0, r["handover"]
    assert out["failover_s"] == r["failover_s_max"] and out["handover_pops"] == 0


@pytest.mark.slow
@pytest.mark.serial
def test_ray_replica_caps_an_address_and_evicts_its_slow_holder(cluster, capsys):
    from facecapges.benchmarks.cluster import _messages

    shared = shared_file("data/beat/2_scott_0_2_2.wav").parents[2]
    # the application is not deleted after it (serve.delete waited 30 s for its replica's graceful stop): the
    # fixture's cluster ends with the module, and no other test uses it (the failover's bench starts its own)
    r = asyncio.run(_admission(f"ws://127.0.0.1:{cluster.port}/admission/", _messages(shared, 60)))
    with capsys.disabled():
        print("\nray admission:", json.dumps(r))
    cap = f"at most {PER_ADDRESS} streams per client address; try again later"
    assert r["a_first"] == "pose" and r["d_first"] == "hello"
    assert r["c"] == (cap, 1013, cap), r["c"]
    assert r["a"][1:] == (1013, "evicted: slower than a live stream while the server was full"), r["a"]
    assert r["d_pose"] == "pose"
    assert r["e_first"] == "hello" and r["e_pose"] == "pose", r
    assert r["d"][1:] == (1013, "evicted: slower than a live stream while the server was full"), r["d"]
    assert r["b_open"] and r["b_poses"] >= 15, r  # the live stream kept its slot and its poses


def test_ray_address_that_does_not_answer_is_one_error_line():
    """``serve --ray HOST:PORT`` with nothing there: one ``error:`` line and a non-zero exit at once
    (Ray itself would retry for minutes); a malformed address likewise."""
    import socket
    import subprocess
    import sys

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # closed again: nothing listens there
    for address, says in ((f"127.0.0.1:{port}", "no Ray head answers"), ("nowhere", "expected auto, local or")):
        p = subprocess.run([sys.executable, "-m", "facecapges", "serve", "--ray", address],
                           capture_output=True, text=True, timeout=120)
        assert p.returncode != 0
        lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith("error:") and says in lines[0], p.stderr


def test_behind_haproxy_a_stream_counts_against_the_forwarded_address_only_with_trust_proxy():
    """Every peer of a replica is the cluster's HAProxy (on the head node: loopback or the node's address):
    with ``--trust-proxy`` the last ``X-Forwarded-For`` entry counts, from any such peer; without it the
    header is ignored (a client could claim any address), and a malformed header counts as the peer."""
    from facecapges.serving.ray_app import INGRESS_ENV, STREAM_LIFE_S, _client_address

    for peer in ("127.0.0.1", "10.0.0.5"):
        assert _client_address(peer, "203.0.113.9", False) == peer
        assert _client_address(peer, "198.51.100.1, 203.0.113.9", True) == "203.0.113.9"
        assert _client_address(peer, "not an address", True) == peer
        assert _client_address(peer, None, True) == peer
    # an HAProxy reload (a replica gone or added) must not close the streams of the old HAProxy process
    # after Ray's default 120 s: they are stopped only after a stream's life
    assert int(INGRESS_ENV["RAY_SERVE_HAPROXY_HARD_STOP_AFTER_S"]) >= STREAM_LIFE_S >= 3600
    assert INGRESS_ENV["FORWARDED_ALLOW_IPS"] == ""  # uvicorn must not trust HAProxy's X-Forwarded-For itself


RAYLET = """
import subprocess, sys, time
subprocess.Popen([sys.executable, "-c", sys.argv[1]])  # its stdout is ours
time.sleep(600)
"""
REPLICA = """
import os, socket, threading, time
from facecapges.serving.ray_app import shutdown_tcp, watch_raylet
def died():
    print("dropped", shutdown_tcp(), flush=True)
threading.Thread(target=watch_raylet, args=(0.02, died), daemon=True).start()  # as a replica starts it
srv = socket.create_server(("127.0.0.1", 0))
print(os.getpid(), srv.getsockname()[1], flush=True)
conn, _ = srv.accept()
print("accepted", flush=True)
time.sleep(600)
"""


def test_a_replica_closes_its_connections_when_its_raylet_dies():
    """``watch_raylet`` in a process standing for a replica, its parent for the node's raylet: the parent is
    killed and the replica shuts its TCP sockets down itself while it still lives — its client (HAProxy) sees
    the end at once; the kernel would close a killed process's sockets only after tearing down its memory
    (0.1–1 s for a replica on a loaded machine, docs/serve-cluster.md)."""
    import os
    import signal
    import socket
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": str(REPO / "src")}
    env.pop("RAY_RAYLET_PID", None)
    raylet = subprocess.Popen([sys.executable, "-c", RAYLET, REPLICA], stdout=subprocess.PIPE, text=True, env=env)
    pid = None
    try:
        pid, port = map(int, raylet.stdout.readline().split())
        with socket.create_connection(("127.0.0.1", port), timeout=30) as conn:
            assert raylet.stdout.readline() == "accepted\n"
            raylet.kill()
            raylet.wait()
            assert conn.recv(16) == b""  # the replica's FIN (within the 30 s timeout)
            os.kill(pid, 0)  # the replica still lives: the end came from its shutdown, not from its exit
        dropped = raylet.stdout.readline().split()
        assert dropped[:2] == ["dropped", "2"], dropped  # the listening socket and the connection
    finally:
        raylet.kill()
        if pid is not None:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
