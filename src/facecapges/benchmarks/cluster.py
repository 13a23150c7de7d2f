"""Cluster benchmark (``facecapges bench --only cluster``): ``serve`` on Ray Serve, one node killed.

A local Ray cluster of two nodes on this machine (``ray.cluster_utils.Cluster``: a head and one
worker, each its own raylet and processes, 1 CPU each, all on 127.0.0.1) runs the application of
:mod:`facecapges.serving.ray_app` with two replicas, one a node. ``streams`` simulated live
clients (:func:`facecapges.serving.loadgen.run_resuming_client`: real speech frames at 15 fps,
reconnect + ``resume`` on a drop) stream through Ray Serve's HAProxy on the head node, straight to
the replicas (``serve --ray``'s ingress, with ports and files of its own); after ``kill_at`` seconds the worker
node is killed (its raylet and every process on it, no graceful stop). Reported:

- ``moved``: the clients whose stream was on the dead node; ``failover_s`` (max / median): from
  the last pose they got before the kill to the first pose of their resumed stream (the freeze a user
  sees); ``all_back`` if every client got poses again and ``within_2s`` if each did within 2 s;
  ``detect_s`` (median / max): from the kill to their connection dropping, and ``detect_by_rule``: how
  many noticed it only by their own rule (no pose for ``loadgen.STALL_S``) rather than by its close;
- ``good_lost``: frames lost by the clients that were not moved (sent, never returned);
  ``good_p99_ms``: their round trip at p99, before and after the kill;
- ``handover``: the whole-body joint acceleration (:func:`facecapges.evaluation.realism.joint_acceleration`)
  of each moved client's pose sequence as shown (last poses before the drop, first after) at the
  join, against the 99.9th percentile of the real motion (the BEAT take ``2_scott_0_1_1.bvh``,
  :func:`~facecapges.evaluation.realism.transition_threshold`): ``pops`` counts hand-overs above it;
- ``failover_hung`` (full runs only): the same clients and figures when, after a new worker node has taken
  the killed one's place, that worker node hangs instead (:meth:`LocalCluster.hang_worker`: its processes
  stopped, SIGSTOP — nothing closes, its kernel still accepts connections and nothing answers);
  ``failover_hung_s`` its worst freeze;
- ``pairs``: short trials of the same clients against one ``facecapges serve`` process and the
  cluster, interleaved (one process, Ray, one process, Ray …; both running throughout), and
  ``ray_overhead_p50`` — the median over the pairs of the ratio of median round trips (Ray / one
  process): one pair alone swings with the machine's load;
- ``ladder``: 2, 4, 8, 16 … 64 streams on the cluster until a step's p99 exceeds 50 ms or loses a frame
  twice in a row (a step that fails is tried once more: one stall of a shared machine);
  ``streams_per_node`` = half the most streams held so (``--quick``: the failover's streams, if
  its p99 before the kill was ≤ 50 ms; else 0).

The clients, the cluster and ``serve`` share this machine's cores; on a loaded machine the
figures are noisy (the load average is reported). ``--quick`` runs one pair of 3 s and the failover
with 20 streams for 8 s (10 s in the full bench), no ladder: the run of the suite's failover test
(``tests/test_serve_ray.py``: ``bench --quick --only cluster``, in the serial pass, with the 2-second
failover and the rest asserted), which ``tests/test_bench.py``'s ``bench --quick`` leaves out, so the
suite starts fewer two-node Ray clusters.
"""

import asyncio
import contextlib
import os
import time
from pathlib import Path

import numpy as np

from facecapges.benchmarks.runtime import stat_cpu
from facecapges.timing import MODEL_FPS

SPEECH = "data/beat/2_scott_0_2_2.wav"
REAL_TAKE = ("data/beat/2_scott_0_1_1.bvh", "data/beat/2_scott_0_1_1.wav")
P99_TARGET_MS = 50.0
HANDOVER_FRAMES = 3
# clients arrive this far apart: Ray's router balances by the open streams it knows of, and 20
# connections in the same instant all see the same (empty) replicas
ARRIVAL_S = 0.05  # poses either side of a hand-over looked at


def _descendants(pids: list[int]) -> list[int]:
    """``pids`` and every process descended from them (``/proc``'s parent links)."""
    kids: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            with contextlib.suppress(OSError, IndexError):
                kids.setdefault(int(stat_cpu(f"/proc/{d}/stat")[0][1]), []).append(int(d))
    out, todo = [], list(pids)
    while todo:
        p = todo.pop()
        out.append(p)
        todo += kids.get(p, [])
    return out


def _free_port() -> int:
    from facecapges.benchmarks.serving import free_port

    return free_port()


def pop_threshold(shared: Path) -> float:
    """The real motion's 99.9th-percentile whole-body acceleration (rad/s²)."""
    from facecapges.evaluation.realism import transition_threshold
    from facecapges.matching.takes import load_take

    take = load_take(shared / REAL_TAKE[0], shared / REAL_TAKE[1])
    return transition_threshold(take.pose, MODEL_FPS)


def _rot6d(flat_quats: list) -> np.ndarray:
    from facecapges import rotations as rot

    q = np.asarray(flat_quats, np.float64).reshape(-1, 4)
    return np.asarray(rot.matrix_to_rot6d(rot.quaternion_to_matrix(q)), np.float32)


def handover_accel(res, drop_t: float) -> float:
    """The largest whole-body acceleration at a hand-over: the poses shown before the drop at
    ``drop_t`` and after it, laid end to end (the client holds its last pose meanwhile)."""
    from facecapges.evaluation.realism import joint_acceleration

    frames = sorted(res.got)
    before = [k for k in frames if res.got[k][0] <= drop_t][-HANDOVER_FRAMES:]
    after = [k for k in frames if res.got[k][0] > drop_t][:HANDOVER_FRAMES]
    if len(before) < 2 or len(after) < 2:
        return float("nan")
    seq = np.stack([_rot6d(res.got[k][1]) for k in before + after])
    acc = joint_acceleration(seq, MODEL_FPS)
    j = len(before)  # the acceleration at the frames next to the join
    return float(acc[j - 1 : j + 1].max())


def _messages(shared: Path, n_frames: int) -> list[str]:
    from facecapges.io.audio import load_audio
    from facecapges.serving.loadgen import input_messages

    return input_messages(load_audio(shared / SPEECH), n_frames)


async def _clients(url: str, n: int, seconds: float, messages: list[str], seed: int = 0):
    from facecapges.serving.loadgen import run_resuming_client

    rng = np.random.default_rng(seed)
    t0 = time.perf_counter() + 0.2
    return await asyncio.gather(
        *[
            run_resuming_client(
                url, messages, seconds, phase=float(rng.uniform(0, 1 / MODEL_FPS)), t0=t0, connect_after=i * ARRIVAL_S
            )
            for i in range(n)
        ]
    )


def _rtts(results, lo: float = -1e18, hi: float = 1e18) -> np.ndarray:
    return (
        np.asarray(
            [r.got[k][0] - t for r in results for k, t in r.sent.items() if k in r.got and lo <= t < hi], np.float64
        )
        * 1e3
    )


def _pct(a: np.ndarray, q: float) -> float | None:
    return round(float(np.percentile(a, q)), 2) if a.size else None


class LocalCluster:
    """A two-node Ray cluster on this machine with the application running (module docs); a
    context manager that stops everything it started."""

    def __init__(self, checkpoint: str | None = None, nodes: int = 2, say=print, env: dict | None = None):
        """``env``: the Serve controller's and the replicas' environment (default: ``serve --ray``'s
        HAProxy ingress, its ports and files this cluster's own; ``{}``: Ray's Python proxy)."""
        self.checkpoint, self.nodes, self.say = checkpoint, nodes, say
        self.cluster = None
        self._stdout: int | None = None
        self.port = _free_port()
        self.env = env
        self._files: str | None = None  # HAProxy's configuration, sockets and state
        self._hung: list[int] = []  # the processes hang_worker stopped

    def __enter__(self):
        # Ray's processes and the driver's own threads print to stdout (a dead raylet's log tail,
        # worker logs): while the cluster runs, file descriptor 1 is stderr (stdout is the bench's JSON)
        import sys

        sys.stdout.flush()
        self._stdout = os.dup(1)
        os.dup2(2, 1)
        for attempt in (1, 2):
            try:
                return self._start()
            except Exception as exc:  # nothing left running when the start fails
                self._stop()
                # on a loaded machine a raylet may miss Ray's fixed 30 s to register: once more
                if attempt == 2 or "timed out during startup" not in str(exc):
                    self._restore()
                    raise
                self.say("cluster: a node timed out during startup (a loaded machine); starting again")
            except BaseException:
                self.__exit__(None, None, None)
                raise
        raise AssertionError("unreachable")

    def _start(self):
        import tempfile

        import ray
        from ray import serve
        from ray.cluster_utils import Cluster

        from facecapges.serving.config import ServeConfig
        from facecapges.serving.ray_app import build_app, wait_ready

        t = time.monotonic()
        # Ray's session files and HAProxy's, nothing shared with another cluster on this machine; short:
        # HAProxy takes socket paths of at most 97 characters, and Ray puts the node's id in them
        self._files = d = tempfile.mkdtemp(prefix="fcg-", dir="/tmp")
        if self.env is None:  # serve --ray's ingress
            from facecapges.serving.ray_app import INGRESS_ENV

            self.env = {
                **INGRESS_ENV,
                "RAY_SERVE_HAPROXY_STATS_PORT": str(_free_port()),
                "RAY_SERVE_HAPROXY_METRICS_PORT": str(_free_port()),
                "RAY_SERVE_HAPROXY_CONFIG_FILE_LOC": f"{d}/haproxy.cfg",
                "RAY_SERVE_HAPROXY_SOCKET_PATH": f"{d}/admin.sock",
                "RAY_SERVE_HAPROXY_SERVER_STATE_BASE": d,
                "RAY_SERVE_HAPROXY_SERVER_STATE_FILE": f"{d}/server-state",
                "RAY_SERVE_HAPROXY_METRICS_SOCKET_PATH": f"{d}/metrics.sock",
            }
        # a dead node is noticed within ~1 s (Ray's default: up to 15 s): RAY_health_check_* on a real cluster
        fast = {"health_check_period_ms": 500, "health_check_failure_threshold": 2}
        self.cluster = Cluster(
            initialize_head=True,
            head_node_args={"num_cpus": 1, "include_dashboard": False, "_system_config": fast, "temp_dir": d},
        )
        self.workers = [self.cluster.add_node(num_cpus=1, temp_dir=d) for _ in range(self.nodes - 1)]
        ray.init(address=self.cluster.address, log_to_driver=False)  # stdout is the bench's JSON
        serve.start(
            http_options={"host": "127.0.0.1", "port": self.port},
            proxy_location="HeadOnly",  # one HAProxy (the head's): every node's would want the same port here
            **({"controller_options": {"runtime_env": {"env_vars": dict(self.env)}}} if self.env else {}),
        )
        serve.run(
            # every stream comes from HAProxy (and every client is on loopback): no per-address limit
            build_app(
                self.checkpoint,
                replicas=self.nodes,
                max_per_node=1,
                config=ServeConfig(max_per_address=256),
                env=self.env,
            ),
            name="facecapges",
            route_prefix="/",
        )
        wait_ready(f"http://127.0.0.1:{self.port}", self.nodes)  # the replicas load the style after they start
        self.start_s = time.monotonic() - t
        self.say(f"cluster: {self.nodes} nodes, {self.nodes} replicas up in {self.start_s:.0f} s")
        return self

    @property
    def url(self) -> str:
        return f"ws://127.0.0.1:{self.port}/"

    def kill_worker(self) -> None:
        assert self.cluster is not None
        self.cluster.remove_node(self.workers[0], allow_graceful=False)

    def hang_worker(self) -> None:
        """The worker node stops answering without closing anything, as a hung or cut-off machine does: every
        process of it (its raylet and their descendants, the replica among them) stopped (SIGSTOP). Its
        kernel still accepts connections to the replica's port (a machine gone from the network would not
        even do that: HAProxy's connect would time out), and nothing answers them."""
        import signal

        self._hung = _descendants([p.pid for _, p in self.workers[0].live_processes()])
        for pid in self._hung:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGSTOP)

    def _kill_hung(self) -> None:
        """End the processes :meth:`hang_worker` stopped."""
        import signal

        for pid in self._hung:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        self._hung = []

    def add_worker(self) -> None:
        """A new worker node in place of the one killed or hung (whose processes are ended first); Serve places
        the missing replica there: back when both replicas answer."""
        from facecapges.serving.ray_app import wait_ready

        assert self.cluster is not None
        self._kill_hung()
        self.workers = [self.cluster.add_node(num_cpus=1, temp_dir=self._files)]
        wait_ready(f"http://127.0.0.1:{self.port}", self.nodes)

    def _stop(self) -> None:
        """The whole cluster, at once. No ``serve.shutdown()`` first: the controller waits for the replicas'
        graceful stop, which ended only at its own 30-s limit every time ("Shutdown tier 0 did not drain within
        30.0s"), while stopping the nodes ends every process of the cluster — the replicas, the controller and
        the HAProxy they started — in about 1.5 s (tests/test_serve_ray.py checks that none is left)."""
        import ray

        self._kill_hung()  # stopped processes would never end on Ray's SIGTERM
        ray.shutdown()
        if self.cluster is not None:
            self.cluster.shutdown()
            self.cluster = None

    def __exit__(self, *exc):
        self._stop()
        self._restore()

    def _restore(self) -> None:
        if self._files is not None:
            import shutil

            shutil.rmtree(self._files, ignore_errors=True)
            self._files = None
        if self._stdout is not None:
            import sys

            sys.stdout.flush()
            os.dup2(self._stdout, 1)
            os.close(self._stdout)
            self._stdout = None


def failover(
    shared: Path,
    streams: int = 20,
    seconds: float = 10.0,
    kill_at: float = 4.0,
    checkpoint=None,
    say=print,
    cluster: "LocalCluster | None" = None,
    how: str = "kill",
) -> dict:
    """Run ``streams`` resuming clients on a two-node cluster and kill the worker node after
    ``kill_at`` s (module docs); the figures as a dict. ``cluster``: one already running (it is
    left running, without its worker), else one is started and stopped here. ``how="hang"``: the
    worker node is stopped instead (:meth:`LocalCluster.hang_worker`)."""
    messages = _messages(shared, int(seconds * MODEL_FPS) + 1)
    threshold = pop_threshold(shared)
    with contextlib.nullcontext(cluster) if cluster is not None else LocalCluster(checkpoint, say=say) as lc:

        async def main():
            task = asyncio.ensure_future(_clients(lc.url, streams, seconds, messages))
            await asyncio.sleep(kill_at + 0.2)
            t_kill = time.perf_counter()
            stop = lc.hang_worker if how == "hang" else lc.kill_worker
            await asyncio.get_running_loop().run_in_executor(None, stop)
            say(f"cluster: worker node {'hung' if how == 'hang' else 'killed'} at {kill_at:g} s")
            return t_kill, await task

        t_kill, results = asyncio.run(main())
        start_s = lc.start_s
    moved = [r for r in results if r.drops and r.drops[0] >= t_kill]
    good = [r for r in results if not r.drops]
    # the freeze a user sees: from the last pose before the kill to the first of the resumed stream
    back = [r.back[0] - max([t for t, _ in r.got.values() if t <= r.drops[0]], default=t_kill) for r in moved if r.back]
    acc = [handover_accel(r, r.drops[0]) for r in moved]
    acc_ok = [a for a in acc if np.isfinite(a)]
    good_lost = sum(len([k for k in r.sent if k not in r.got]) for r in good)
    before, after = _rtts(good, hi=t_kill), _rtts(good, lo=t_kill)
    out = {
        "how": how,
        "streams": streams,
        "nodes": 2,
        "cluster_start_s": round(start_s, 1),
        "moved": len(moved),
        "dropped_not_by_kill": sum(bool(r.drops) for r in results) - len(moved),
        "all_back": len(back) == len(moved),
        "failover_s_max": round(max(back), 3) if back else None,
        "failover_s_median": round(float(np.median(back)), 3) if back else None,
        "within_2s": bool(back) and len(back) == len(moved) and max(back) <= 2.0,
        "detect_s_median": round(float(np.median([r.drops[0] - t_kill for r in moved])), 3) if moved else None,
        "detect_s_max": round(max(r.drops[0] - t_kill for r in moved), 3) if moved else None,
        # noticed by the client's own no-pose rule (loadgen.STALL_S), not by the connection's close
        "detect_by_rule": sum(r.drops[0] in r.stalls for r in moved),
        "hello_s_median": round(float(np.median([r.hellos[1] - t_kill for r in moved if len(r.hellos) > 1])), 3)
        if any(len(r.hellos) > 1 for r in moved)
        else None,
        "good_clients": len(good),
        "good_sent": sum(len(r.sent) for r in good),
        "good_lost": good_lost,  # busy drops included (a replica behind its streams)
        "good_p50_ms_before": _pct(before, 50),
        "good_p99_ms_before": _pct(before, 99),
        "good_p99_ms_after": _pct(after, 99),
        "rtt_ms_all_before": _pct(_rtts(results, hi=t_kill), 50),
        "handover": {
            "threshold_rad_s2": round(threshold, 1),
            "accel_max": round(max(acc_ok), 1) if acc_ok else None,
            "accel_median": round(float(np.median(acc_ok)), 1) if acc_ok else None,
            "measured": len(acc_ok),
            "pops": int(sum(a > threshold for a in acc_ok)),
        },
        "busy_drops": sum(sum('"busy' in e for e in r.errors) for r in results),
        "errors": sum(sum('"busy' not in e for e in r.errors) for r in results),
        "error_samples": sorted({e[:100] for r in results for e in r.errors if '"busy' not in e})[:5],
    }
    out["p50_all_before_ms"] = _pct(_rtts(results, hi=t_kill), 50)
    out["p99_all_before_ms"] = _pct(_rtts(results, hi=t_kill), 99)
    return out


def _trial(url: str, streams: int, seconds: float, messages: list[str]) -> dict:
    """``streams`` live clients against ``url`` for ``seconds`` (no kill): round trips and loss."""
    results = asyncio.run(_clients(url, streams, seconds, messages))
    rtt = _rtts(results)
    return {
        "streams": streams,
        "sent": sum(len(r.sent) for r in results),
        "lost": sum(len([k for k in r.sent if k not in r.got]) for r in results),
        "p50_ms": _pct(rtt, 50),
        "p99_ms": _pct(rtt, 99),
    }


def _held(trial: dict) -> bool:
    """A trial within the bound: p99 ≤ 50 ms and no frame lost."""
    return trial["p99_ms"] is not None and trial["p99_ms"] <= P99_TARGET_MS and not trial["lost"]


def _ladder(url: str, ladder: tuple[int, ...], trial_s: float, messages, say) -> list[dict]:
    """Trials of ``ladder``'s stream counts on the cluster, up to the first that is not held (p99 and no loss);
    a step that fails is tried once more (one stall of a shared machine)."""
    steps: list[dict] = []
    for n in ladder:
        for _ in range(2):
            r = _trial(url, n, trial_s, messages)
            steps.append(r)
            say(f"cluster: {n} streams on 2 nodes: p99 {r['p99_ms']} ms, lost {r['lost']} of {r['sent']}")
            if _held(r):
                break
        if not _held(r):
            break
    return steps


def run(quick: bool, shared: Path) -> dict:
    """One ``serve`` process and the two-node cluster side by side: ``pairs`` interleaved short
    trials of the same clients (one process, then Ray) for the overhead ratio (their median); on a
    full run, a ladder of streams on the cluster for ``streams_per_node``; then the failover."""
    import sys

    from facecapges.benchmarks.serving import start_server, stop_server

    def say(m: str) -> None:
        print(m, file=sys.stderr, flush=True)

    checkpoint = os.environ.get("FACECAPGES_BENCH_CHECKPOINT")
    streams, seconds = (20, 8.0) if quick else (20, 10.0)
    pairs, trial_s = (1, 3.0) if quick else (3, 4.0)
    ladder: tuple[int, ...] = () if quick else (2, 4, 8, 16, 24, 32, 48, 64)  # streams on the cluster (two nodes)
    load0 = os.getloadavg()[0]
    messages = _messages(shared, int(max(seconds, trial_s) * MODEL_FPS) + 1)
    port = _free_port()
    # every client is on loopback: the per-address limit (16) must not apply
    proc = start_server(port, checkpoint, extra=("--max-per-address", "256"))
    try:
        with LocalCluster(checkpoint, say=say) as lc:
            trials: list[dict] = []
            for k in range(pairs):
                one = _trial(f"ws://127.0.0.1:{port}/", streams, trial_s, messages)
                ray = _trial(lc.url, streams, trial_s, messages)
                ratio = round(ray["p50_ms"] / one["p50_ms"], 2) if ray["p50_ms"] and one["p50_ms"] else None
                trials.append({"single": one, "ray": ray, "ratio_p50": ratio})
                say(
                    f"cluster: pair {k + 1}/{pairs}, {streams} streams: p50 one process {one['p50_ms']} ms, Ray {ray['p50_ms']} ms"
                )
            steps = _ladder(lc.url, ladder, trial_s, messages, say)
            fo = failover(shared, streams, seconds, kill_at=seconds * 0.4, checkpoint=checkpoint, say=say, cluster=lc)
            hung = None
            if not quick:  # a node that stops answering without closing anything (a new worker in the dead one's place)
                lc.add_worker()
                hung = failover(shared, streams, seconds, seconds * 0.4, checkpoint, say, cluster=lc, how="hang")
    finally:
        stop_server(proc)
    held = [r["streams"] for r in steps if _held(r)]
    if not ladder:  # quick: the failover's trial before the kill
        ok = fo["p99_all_before_ms"] is not None and fo["p99_all_before_ms"] <= P99_TARGET_MS
        held = [streams] if ok else []
    ratios: list[float] = [t["ratio_p50"] for t in trials if t["ratio_p50"] is not None]
    return {
        "pairs": trials,
        "ladder": steps,
        "failover": fo,
        "streams_per_node": max(held) // 2 if held else 0,
        "ladder_top_held": bool(ladder) and ladder[-1] in held,  # then streams_per_node is a floor, not the limit
        "ray_overhead_p50": round(float(np.median(ratios)), 2) if ratios else None,
        "ray_overhead_p50_each": ratios,
        "failover_s": fo["failover_s_max"],
        "handover_pops": fo["handover"]["pops"],
        "failover_hung": hung,
        "failover_hung_s": hung["failover_s_max"] if hung else None,
        "loadavg": [round(load0, 1), round(os.getloadavg()[0], 1)],
        "ingress": "haproxy",  # serve --ray's (serving/ray_app.py, INGRESS_ENV)
    }
