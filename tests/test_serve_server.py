"""``facecapges serve``: real WebSocket clients on loopback against the real server.

The model is a randomly initialised FaceCapGes of the default config (what is tested
is the serving, not the weights): every stream's poses must equal a NetworkStream
fed the same frames, whatever the other connections do.
"""

from __future__ import annotations

import asyncio
import base64
import json
import signal
import socket
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from facecapges import rotations as rot
from facecapges.network.config import ModelConfig
from facecapges.network.network import FaceCapGes
from facecapges.network.streaming import NetworkStream
from facecapges.network.style import NetworkStyle, save_checkpoint
from facecapges.runtime.outputs import protocol
from facecapges.serving.server import ServeConfig, StreamServer

websockets = pytest.importorskip("websockets")
from websockets.asyncio.client import connect  # noqa: E402
from websockets.exceptions import ConnectionClosed  # noqa: E402

from runtime_helpers import cli, cli_process  # noqa: E402
from tolerances import assert_rotations_close  # noqa: E402


@pytest.fixture(autouse=True, scope="module")
def one_thread():
    """One intra-op thread: on a loaded 2-core machine two OpenMP threads spin-wait for each other."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def ckpt() -> NetworkStyle:
    torch.manual_seed(0)
    model = FaceCapGes(ModelConfig()).eval()
    with torch.no_grad():
        for p in model.decoder.parameters():
            p.mul_(2.0)
    neutral = (np.random.default_rng(1).normal(size=(16, 47, 6)) * 0.3).astype(np.float32)
    return NetworkStyle(model=model, meta={"neutral_window": neutral.tolist(), "model_config": {"fps": 15}},
                      path=Path("random-init"))


def frames(n: int, seed: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        yaw = rng.uniform(-0.3, 0.3)
        head = np.array([np.cos(yaw), 0, -np.sin(yaw), 0, 1, 0], np.float32)
        out.append(((rng.normal(size=1067) * 0.2).astype(np.float32), rng.uniform(size=52).astype(np.float32), head))
    return out


def reference(ckpt: NetworkStyle, fr) -> np.ndarray:
    """Quaternions (T, 47, 4) a single-stream generator gives for these frames."""
    g = NetworkStream(ckpt.model, ckpt.neutral_window)
    poses = np.array([g.step(a, f, h) for a, f, h in fr])
    return rot.rot6d_to_quaternion(poses.astype(np.float64))


@pytest.fixture()
def server(ckpt, default_checkpoint):
    """``make(**ServeConfig options)`` → a started server of the random network; ``make(matching=True, ...)`` → of
    the installed matching style, for the tests that assert what the server does with connections and messages,
    not the poses: its model process starts without torch (about 1.5 s against 5-7 s at load 6)."""
    servers = []

    def make(matching: bool = False, **over) -> StreamServer:
        cfg = ServeConfig(port=0, **over)
        s = StreamServer(default_checkpoint if matching else ckpt, cfg).start()
        servers.append(s)
        return s

    yield make
    for s in servers:
        s.close()


@pytest.fixture(scope="module")
def shared_server(ckpt):
    """One server of the default settings for this module's tests that only stream on it and count what their own
    streams did (a server's start spawns the model process: seconds of a torch import): frames wait rather than
    drop (``max_pending=100``; the others send one frame and wait for its pose, so it changes nothing for them).
    A test that needs its own limits or a fresh server uses ``server``. Under xdist each worker has its own."""
    s = StreamServer(ckpt, ServeConfig(port=0, max_pending=100)).start()
    yield s
    s.close()


def added(srv: StreamServer, before: dict, key: str) -> int:
    """How much ``srv.summary()[key]`` grew since ``before`` (an earlier summary): a shared server's counts."""
    return srv.summary().get(key, 0) - before.get(key, 0)


async def stream(url: str, fr, pace_s: float = 0.0) -> list[dict]:
    """Send the frames one by one (waiting for each pose), return the pose messages."""
    out = []
    async with connect(url, max_size=protocol.MAX_MESSAGE_BYTES) as ws:
        hello = json.loads(await ws.recv())
        assert hello["type"] == "hello" and hello["samples_per_frame"] == 1067 and len(hello["joints"]) == 47
        for k, (a, f, h) in enumerate(fr):
            await ws.send(protocol.encode_input(k, a, f, h))
            msg = json.loads(await ws.recv())
            assert msg["type"] == "pose", msg
            out.append(msg)
            if pace_s:
                await asyncio.sleep(pace_s)
    return out


def quats(msgs: list[dict]) -> np.ndarray:
    return np.array([protocol.decode_pose(json.dumps(m))["pose"] for m in msgs])


def test_concurrent_streams_each_equal_single_stream(ckpt, shared_server):
    srv, before = shared_server, shared_server.summary()
    streams = [frames(25, seed) for seed in range(4)]

    async def main():
        return await asyncio.gather(*[stream(srv.url, fr, pace_s=0.005 * i) for i, fr in enumerate(streams)])

    results = asyncio.run(main())
    for fr, msgs in zip(streams, results):
        assert [m["frame"] for m in msgs] == list(range(25))
        # the server batches the streams (another batch, another schedule): float32 rounding, 0.01° (tolerances.py)
        assert_rotations_close(quats(msgs), reference(ckpt, fr), what="served poses")
        lat = msgs[-1]["latency_ms"]
        assert set(lat) == {"queue", "model", "output", "total"} and lat["total"] >= lat["model"] >= 0
        assert msgs[3]["time"] == pytest.approx(3 / 15)
        np.testing.assert_allclose(msgs[3]["weights"], fr[3][1], atol=6e-6)  # echoed, 5 decimals
    assert added(srv, before, "frames") == 100


def test_garbage_stalls_and_disconnects_do_not_affect_others(ckpt, server):
    srv = server(idle_timeout=2.0)
    good, other = frames(30, 10), frames(12, 11)

    async def garbage():
        async with connect(srv.url, max_size=None) as ws:
            await ws.recv()  # hello
            errors = []
            for bad in ("not json", "[1, 2]", json.dumps({"type": "dance"}), json.dumps({"type": "input"}),
                        protocol.encode_input(0, np.zeros(1067), np.full(52, np.nan), np.eye(3)[:, :2].T.ravel()),
                        protocol.encode_input(0, np.zeros(2000), np.zeros(52), np.array([1, 0, 0, 0, 1, 0.])),
                        b"\x00\x01binary"):
                await ws.send(bad)
                errors.append(json.loads(await ws.recv()))
            assert all(e["type"] == "error" and e["message"] for e in errors), errors
            # the same connection then streams normally, from a clean state
            out = []
            for k, (a, f, h) in enumerate(other):
                await ws.send(protocol.encode_input(k, a, f, h))
                out.append(json.loads(await ws.recv()))
            await ws.send(json.dumps({"type": "ping"}))
            assert json.loads(await ws.recv())["type"] == "pong"
            return out

    async def oversized():
        async with connect(srv.url, max_size=None) as ws:
            await ws.recv()
            await ws.send("x" * (protocol.MAX_MESSAGE_BYTES + 10))
            with pytest.raises(ConnectionClosed) as exc:
                await ws.recv()
            return exc.value.rcvd.code

    async def quitter():  # disconnects abruptly in the middle of its stream
        ws = await connect(srv.url)
        await ws.recv()
        for k, (a, f, h) in enumerate(frames(5, 12)):
            await ws.send(protocol.encode_input(k, a, f, h))
        ws.transport.abort()

    async def staller():  # connects, says nothing: closed after idle_timeout
        async with connect(srv.url) as ws:
            await ws.recv()
            with pytest.raises(ConnectionClosed) as exc:
                await asyncio.wait_for(ws.recv(), timeout=10)
            return exc.value.rcvd.code

    async def main():
        return await asyncio.gather(stream(srv.url, good, pace_s=0.03), garbage(), oversized(), quitter(), staller())

    good_msgs, other_msgs, big_code, _, idle_code = asyncio.run(main())
    # batched against one stream: float32 rounding, 0.01° (tolerances.py); another stream's poses are far off
    assert_rotations_close(quats(good_msgs), reference(ckpt, good), what="the good stream")
    assert_rotations_close(quats(other_msgs), reference(ckpt, other), what="the stream after garbage")
    with pytest.raises(AssertionError, match="differ by more than"):  # the check sees a wrong slot
        assert_rotations_close(quats(good_msgs)[: len(other)], reference(ckpt, other))
    assert big_code == 1009 and idle_code == 1000
    s = srv.summary()
    assert s["bad_messages"] >= 6 and s["idle_closes"] >= 1 and s["streams"] == 0


def test_messages_are_handled_as_parsed_in_order_fragmented_and_utf8_checked(server):
    """``serve`` handles each message as websockets' parser finds it (serving/connection.py): a message sent
    before ``hello`` is answered after it, in order; a fragmented message is joined; an input, a ping and
    another input in one burst are answered in that order; a text frame that is not UTF-8 closes with 1007."""
    srv = server(matching=True)
    fr = frames(2, 21)

    async def main():
        async with connect(srv.url) as ws:
            await ws.send('{"type":"ping"}')  # before reading hello: waits, then is answered after it
            first = json.loads(await ws.recv())
            second = json.loads(await ws.recv())
            await ws.send(['{"type":', '"ping"}'])  # one message in two frames
            joined = json.loads(await ws.recv())
            a, f, h = fr[0]
            await ws.send(protocol.encode_input(0, a, f, h))
            await ws.send('{"type":"intensity","value":0.5}')
            replies = [json.loads(await ws.recv()) for _ in range(2)]
        async with connect(srv.url) as ws:
            await ws.recv()
            await ws.send(b'{"type":"ping","x":"\xff"}', text=True)  # a text frame that is not UTF-8
            with pytest.raises(ConnectionClosed) as exc:
                await asyncio.wait_for(ws.recv(), timeout=10)
        return first, second, joined, replies, exc.value.rcvd.code

    first, second, joined, replies, code = asyncio.run(main())
    assert first["type"] == "hello" and second["type"] == "pong" and joined["type"] == "pong"
    # the intensity reply is written at once, the pose at its tick: both come, the pose for frame 0
    assert sorted(r["type"] for r in replies) == ["intensity", "pose"], replies
    assert next(r for r in replies if r["type"] == "pose")["frame"] == 0
    assert code == 1007


@pytest.mark.serial
def test_max_streams_and_rate_limit(server):
    srv = server(max_streams=2, rate_limit=5.0, max_pending=16)  # the network: it counts the poses of a burst

    async def main():
        a = await connect(srv.url)
        b = await connect(srv.url)
        await a.recv(), await b.recv()
        c = await connect(srv.url)
        full = json.loads(await c.recv())
        with pytest.raises(ConnectionClosed) as exc:
            await c.recv()
        assert full["type"] == "error" and "full" in full["message"] and exc.value.rcvd.code == 1013
        # a burst of 12 frames at once: one second of burst (5) passes, the rest is dropped
        fr = [protocol.encode_input(k, au, f, h) for k, (au, f, h) in enumerate(frames(12, 20))]
        t0 = time.monotonic()
        for m in fr:
            await a.send(m)
        refill = 5.0 * (time.monotonic() - t0)  # tokens that came back while sending
        got = []
        try:
            while True:
                got.append(json.loads(await asyncio.wait_for(a.recv(), timeout=3.0)))
        except TimeoutError:
            pass
        poses = [m for m in got if m["type"] == "pose"]
        errors = [m for m in got if m["type"] == "error"]
        assert 5 <= len(poses) <= 6 + refill and len(errors) == 1 and "rate limit" in errors[0]["message"]
        await b.close()
        await asyncio.sleep(0.3)
        d = await connect(srv.url)  # a freed place is taken again
        assert json.loads(await d.recv())["type"] == "hello"
        await a.close(), await d.close()

    asyncio.run(main())
    assert srv.summary()["refused_full"] == 1 and srv.summary()["rate_limited"] >= 5


def test_client_that_stops_reading_is_closed(server):
    srv = server(matching=True, send_buffer_bytes=16_000, rate_limit=1000.0)
    fr = frames(400, 30)

    async def main():
        sock = socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        sock.connect(srv.bound)
        ws = await connect(srv.url, sock=sock, max_queue=1)
        await ws.recv()
        msg = [protocol.encode_input(k, a, f, h) for k, (a, f, h) in enumerate(fr)]
        try:
            for m in msg:  # never read the poses
                await ws.send(m)
                await asyncio.sleep(0.01)
                if srv.summary().get("slow_closes"):
                    break
        except ConnectionClosed:
            pass
        other = await stream(srv.url, frames(3, 31))  # the server still serves others
        ws.transport.abort()
        return other

    other = asyncio.run(main())
    assert len(other) == 3
    assert srv.summary().get("slow_closes") == 1


def test_pose_messages_are_the_runtime_format():
    from facecapges.runtime.frames import OutputFrame

    rng = np.random.default_rng(0)
    pose = rng.normal(size=(2, 47, 6))
    q = rot.rot6d_to_quaternion(pose)
    face, head = rng.uniform(size=(2, 52)), rng.normal(size=(2, 6))
    ours = [m.decode() for m in protocol.encode_poses_utf8([7, 8], [7 / 15, 8 / 15], q, face, head, [True, False],
                                                           [{"model": 1.25}, {"model": 2.5}])]
    ref = protocol.encode_pose(OutputFrame(7, 7 / 15, pose[0], q[0], face[0], head[0], True, {"model": 1.25}))
    a, b = protocol.decode_pose(ours[0]), protocol.decode_pose(ref)
    assert set(a) == set(b)
    for k in ("pose", "weights", "head"):
        np.testing.assert_allclose(a[k], b[k], atol=2e-6)
    assert (a["frame"], a["time"], a["face_found"], a["latency_ms"]) == (b["frame"], b["time"], True, {"model": 1.25})
    assert protocol.decode_pose(ours[1])["face_found"] is False


def test_pose_numbers_written_from_float32_read_back_as_the_same_float64():
    """``encode_poses_utf8`` writes rounded rows within [-1, 1] from float32 (half the cost): every number of 6
    decimals there reads back as the float64 it was; only ±1e-6 … ±9e-6 change text ('0.000005' for '5e-6')."""
    import orjson

    v = np.round(np.arange(-10**6, 10**6 + 1) / 1e6, 6)
    opt = orjson.OPT_SERIALIZE_NUMPY
    t64, t32 = orjson.dumps(v, option=opt), orjson.dumps(v.astype(np.float32), option=opt)
    back = np.array(orjson.loads(t32))
    assert np.array_equal(back, v) and np.array_equal(np.signbit(back), np.signbit(v))
    changed = {a for a, b in zip(t64[1:-1].split(b","), t32[1:-1].split(b",")) if a != b}
    assert changed == {b"%de-6" % k for k in range(-9, 10) if k}
    # a row beyond [-1, 1] (a head, weights out of range) is written from float64 as before
    q = np.zeros((1, 47, 4))
    q[0, :, 0] = 1.0
    msg = next(protocol.encode_poses_utf8([0], [0.0], q, np.full((1, 52), 1.5), np.full((1, 6), 2e-6), [True],
                                          [{}])).decode()
    assert '"weights":[1.5,' in msg and '"head":[2e-6,' in msg and '"pose":[1.0,0.0,' in msg


def test_input_decoding_checks_face_and_head_at_once_names_each_fault_and_refuses_loose_base64():
    """``decode_client`` checks an input's face and head as one array and its audio by one product: what it
    accepts and the fault it names are those of the field-by-field checks (near their bounds these decide);
    the base64 is strict (pybase64: alphabet and padding), so a '=' after unpadded data is refused."""
    eye = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0]

    def msg(face=None, head=None, audio=None, raw_b64=None) -> str:
        a = np.asarray(np.linspace(-0.5, 0.5, 1067) if audio is None else audio, "<f4")
        return json.dumps({"type": "input", "frame": 3, "face": [0.5] * 52 if face is None else face,
                           "head": eye if head is None else head,
                           "audio": raw_b64 if raw_b64 is not None else base64.b64encode(a.tobytes()).decode()})

    def fault(text: str) -> str:
        with pytest.raises(protocol.ProtocolError) as exc:
            protocol.decode_client(text)
        return str(exc.value)

    face = [-0.5, 2.0, 0.25] + [0.125] * 49
    frame = protocol.decode_client(msg(face=face, head=[0.6, 0, -0.8, 0, 1, 0]))["input"]
    assert frame.index == 3 and frame.audio.dtype == frame.face.dtype == frame.head.dtype == np.float32
    np.testing.assert_array_equal(frame.face, np.clip(np.float32(face), 0, 1))
    np.testing.assert_array_equal(frame.head, np.float32([0.6, 0, -0.8, 0, 1, 0]))
    np.testing.assert_array_equal(frame.audio, np.float32(np.linspace(-0.5, 0.5, 1067)))
    for head in ([1e-5, 0, 0, 0, 1, 0], [1e17, 0, 0, 0, 1, 0], [1, 0, 0, 0, 0, 3e-6], [1, 2, 3, 4, 5, 6]):
        assert protocol.decode_client(msg(head=head))["type"] == "input", head  # close to a bound, still valid
    assert fault(msg(face=[0.5] * 51)) == "'face' must be a list of 52 numbers"
    assert fault(msg(face=[0.5] * 51 + ["x"])) == "'face' must hold numbers only"
    assert fault(msg(face=[0.5] * 51 + [[1]])) == "'face' must hold numbers only"
    assert fault(msg(face={"a": 1}, head=[0])) == "'face' must be a list of 52 numbers"  # face named first
    assert fault(msg(head=[1, 0, 0, 0, 1])) == "'head' must be a list of 6 numbers"
    assert fault(msg(head=[1, 0, 0, 0, 1, None])) == "'head' must hold 6 finite numbers"  # None: NaN
    with np.errstate(over="ignore"):  # 1e39 is float32's infinity
        for head in ([0, 0, 0, 0, 1, 0], [1, 0, 0, 1e-7, 0, 0], [1e39, 0, 0, 0, 1, 0]):  # zero, tiny, too large
            assert fault(msg(head=head)) == "'head' is not a rotation (a rot6d column is zero)", head
    for bad in (np.nan, np.inf, -np.inf):
        audio = np.zeros(1067, np.float32)
        audio[500] = bad
        assert fault(msg(audio=audio)) == "'audio' holds NaN or infinite samples"
    twelve = base64.b64encode(bytes(12)).decode()  # 16 characters, no padding needed
    assert protocol.decode_client(msg(raw_b64=twelve))["input"].audio.shape == (3,)
    for b64 in (twelve + "=", twelve[:-1] + "=A", twelve[:8] + " " + twelve[8:], twelve[:-1]):
        assert fault(msg(raw_b64=b64)) == "'audio' is not valid base64", b64


def test_serve_command(tmp_path, ckpt):
    path = save_checkpoint(tmp_path / "m.safetensors", ckpt.model, {"neutral_window": ckpt.meta["neutral_window"]})
    p = cli("serve", "--checkpoint", str(tmp_path / "none"), "--port", "0", timeout=120)
    assert p.returncode == 2 and p.stderr.startswith("error:") and "none" in p.stderr
    from facecapges.errors import UserError

    with pytest.raises(UserError, match="--max-streams"):
        StreamServer(ckpt, ServeConfig(max_streams=0))
    proc = cli_process("serve", "--checkpoint", str(path), "--port", "0", background=True)
    try:
        line = proc.stdout.readline()
        assert line.startswith("serving"), line + proc.stderr.read()
        url = line.split(" on ")[1].split()[0]
        assert proc.stdout.readline().startswith("ready:")  # it listens first, then loads: hello comes now
        msgs = asyncio.run(stream(url, frames(4, 40)))
        assert_rotations_close(quats(msgs), reference(ckpt, frames(4, 40)), what="poses of the serve command")
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert "'frames': 4" in out


def test_loadgen_clients_get_every_frame_back(shared_server, beat_wav):
    """The benchmark's simulated clients (real speech frames, 15 fps each) against the server."""
    from facecapges.io.audio import load_audio
    from facecapges.serving import loadgen

    srv, before = shared_server, shared_server.summary()  # max_pending=100: on a loaded machine frames wait, none drops
    msgs = loadgen.input_messages(load_audio(beat_wav)[: 16000 * 3], 40)
    assert len(msgs) == 40 and all(protocol.decode_client(m)["type"] == "input" for m in msgs[:3])
    res = asyncio.run(loadgen.run_clients(srv.url, 3, 2.0, msgs, warmup_s=0.5, drain_s=60))
    s = loadgen.summarize(res, 1000 / 15)
    assert s["frames_sent"] == 90 and s["lost"] == 0 and s["errors"] == 0 and s["measured_frames"] == 3 * 22
    assert s["p50_ms"] > 0 and added(srv, before, "frames") == 90


def test_model_process_sync_and_split_step(ckpt):
    """One ``sync`` round trip opens, closes and dials slots (a new slot named ``-1 - k``); the split
    submit/collect gives the kernel's poses and their quaternions, as ``step`` does."""
    from facecapges.serving.model_process import ModelProcess

    gen = ckpt.batched(capacity=4)
    mp = ModelProcess(ckpt, max_rows=4)
    try:
        a, b = mp.sync([], 2, [(-2, 0.5)])  # the second new stream at intensity 0.5
        assert mp.open_slots == {a, b}
        ga, gb = gen.open(), gen.open()
        gen.set_intensity(gb, 0.5)
        for audio, face, head in frames(6, seed=3):
            audio2, face2, head2 = [audio, audio[::-1].copy()], np.stack([face, face[::-1]]), np.stack([head, head])
            mp.submit([a, b], audio2, face2, head2)
            poses, quats = mp.collect()
            want = gen.step([ga, gb], audio2, face2, head2)
            # the same batch in another process: float32 rounding may differ there (threads), 0.01° (tolerances.py)
            assert_rotations_close(poses, want, what="the model process's poses")
            # the same float64 function of the same poses, compiled there (rotations_compiled.checked_rot6d_to_quaternions): the same bits
            np.testing.assert_array_equal(quats, rot.rot6d_to_quaternion(poses.astype(np.float64)), strict=True)
        (c,) = mp.sync([a], 1, [])
        assert mp.open_slots == {b, c}
        still = np.array([[1.0, 0, 0, 0, 1, 0]])  # the head facing the camera (rot6d)
        assert mp.step([c], [frames(1, seed=4)[0][0]], np.zeros((1, 52)), still).shape == (1, 47, 6)
    finally:
        mp.shutdown()


@pytest.mark.serial
def test_serve_listens_at_once_a_client_started_with_it_waits_and_ctrl_c_is_one_line(tmp_path, ckpt):
    """Issue 33, items 1 and 5: ``serve`` listens before it loads its style (a client connecting meanwhile
    gets ``status`` "loading", then ``hello`` once ready; the docs' client started together with the
    server is served, not refused), says ``ready:`` on stdout, and Ctrl-C to its process group (as a
    terminal sends it, reaching the model process too) stops it with one line, exit 0, no traceback."""
    import os
    import subprocess
    import sys

    path = save_checkpoint(tmp_path / "m.safetensors", ckpt.model, {"neutral_window": ckpt.meta["neutral_window"]})
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = f"ws://127.0.0.1:{port}/"
    root = Path(__file__).resolve().parents[1]
    t0 = time.monotonic()
    proc = cli_process("serve", "--checkpoint", str(path), "--port", str(port), background=True,
                       start_new_session=True)
    client = subprocess.Popen([sys.executable, str(root / "docs" / "examples" / "serve_client.py"), url,
                               str(root / "src" / "facecapges" / "assets" / "demo" / "speech.wav"), "--seconds", "1"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        while True:  # listening: a TCP connection is accepted
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert time.monotonic() - t0 < 60 and proc.poll() is None, proc.stderr.read()
                time.sleep(0.05)
        t_listen = time.monotonic() - t0

        async def first_messages():
            async with connect(url, open_timeout=60) as ws:
                kinds = [json.loads(await ws.recv())["type"]]
                while kinds[-1] == "status":
                    kinds.append(json.loads(await asyncio.wait_for(ws.recv(), 120))["type"])
                return kinds, time.monotonic() - t0

        kinds, t_ready = asyncio.run(first_messages())
        out, err = client.communicate(timeout=120)
        assert client.returncode == 0, err
        assert out.splitlines()[-1] == "15 frames" and "loading" in err, (out, err)
        print(f"serve: listening after {t_listen:.1f} s, hello after {t_ready:.1f} s")
        assert kinds[0] == "status" and kinds[-1] == "hello", kinds  # it listened before it was ready
    finally:
        if client.poll() is None:
            client.kill()
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C in a terminal: the whole process group
        out, err = proc.communicate(timeout=60)
    lines = out.splitlines()
    assert proc.returncode == 0, err
    assert lines[0].startswith("serving") and lines[1].startswith("ready:") and lines[-1].startswith("served:"), out
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert len(lines) == 3 and err.strip() == "", (out, err)


def test_a_server_that_listens_before_loading_says_loading_then_hello_or_the_error(ckpt):
    """Issue 33, item 1: a client connected while the style loads gets ``status`` "loading", then
    its ``hello`` once :meth:`StreamServer.load` is done, and is served; if loading fails, the
    waiting client gets the reason as an ``error`` and close 1011."""
    ok = StreamServer(None, ServeConfig(port=0), name="test style").start()
    bad = StreamServer(None, ServeConfig(port=0)).start()
    try:
        async def wait_then(srv, finish):
            async with connect(srv.url) as ws:
                first = json.loads(await ws.recv())
                await asyncio.get_running_loop().run_in_executor(None, finish)
                second = json.loads(await asyncio.wait_for(ws.recv(), 120))
                if second["type"] != "hello":
                    with pytest.raises(ConnectionClosed) as exc:
                        await ws.recv()
                    return first, second, exc.value.rcvd.code
                await ws.send(protocol.encode_input(0, *frames(1, 50)[0]))
                return first, second, json.loads(await asyncio.wait_for(ws.recv(), 60))["type"]

        first, hello, pose = asyncio.run(wait_then(ok, lambda: ok.load(ckpt)))
        assert first["type"] == "status" and first["state"] == "loading" and "test style" in first["message"]
        assert hello["type"] == "hello" and pose == "pose" and ok.ready
        first, err, code = asyncio.run(wait_then(bad, lambda: bad.fail("the style file is damaged")))
        assert first["type"] == "status" and err["type"] == "error" and "damaged" in err["message"] and code == 1011
    finally:
        ok.close()
        bad.close()


def test_serve_with_a_style_that_cannot_load_is_one_error_line(tmp_path):
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"\x08\x00\x00\x00\x00\x00\x00\x00{\"a\": 1}" + b"\x00" * 64)
    p = cli("serve", "--checkpoint", str(bad), "--port", "0", timeout=120)
    assert p.returncode == 2 and p.stderr.startswith("error:") and "Traceback" not in p.stderr, p.stderr
    assert len(p.stderr.strip().splitlines()) == 1, p.stderr


@pytest.mark.serial
def test_serve_on_a_busy_port_says_so_before_loading_anything():
    """Issue 33, item 1: the port is bound before torch or the style loads, so a port in use is one
    error line within seconds (was: after the style and the model process had loaded, 20-40 s)."""
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        t0 = time.monotonic()
        p = cli_process("serve", "--port", str(port), timeout=120)
        took = time.monotonic() - t0
    assert p.returncode == 2 and p.stderr.strip() == f"error: cannot listen on 127.0.0.1:{port} (Address already in use)"
    assert took < 5.0, took  # an interpreter start and typer; measured 2.7 s at load average 17


def test_resume_starts_the_stream_from_the_clients_last_pose(ckpt, shared_server):
    """A reconnecting client's ``resume`` (its last pose, as the pose messages carry it) starts the
    new stream from that pose: its poses equal a single-stream generator reset to it; a resume after
    the first input is refused with an error and changes nothing."""
    srv, before = shared_server, shared_server.summary()
    fr = frames(12, 21)
    last = quats(asyncio.run(stream(srv.url, frames(6, 22))))[-1]  # a pose the server gave
    start = np.asarray(rot.matrix_to_rot6d(rot.quaternion_to_matrix(last)), np.float32)

    async def resumed():
        async with connect(srv.url, max_size=protocol.MAX_MESSAGE_BYTES) as ws:
            assert json.loads(await ws.recv())["type"] == "hello"
            await ws.send(json.dumps({"type": "resume", "pose": last.ravel().tolist()}))
            assert json.loads(await ws.recv()) == {"type": "resumed"}
            out = []
            for k, (a, f, h) in enumerate(fr):
                await ws.send(protocol.encode_input(k, a, f, h))
                out.append(json.loads(await ws.recv()))
                if k == 0:
                    await ws.send(json.dumps({"type": "resume", "pose": last.ravel().tolist()}))
                    err = json.loads(await ws.recv())
                    assert err["type"] == "error" and "before the first input" in err["message"]
            await ws.send(json.dumps({"type": "resume", "pose": [0.0] * 188}))
            assert "zero quaternion" in json.loads(await ws.recv())["message"]
            return out

    msgs = asyncio.run(resumed())
    g = NetworkStream(ckpt.model, ckpt.neutral_window)
    g.reset(start)
    want = rot.rot6d_to_quaternion(np.array([g.step(a, f, h) for a, f, h in fr]).astype(np.float64))
    assert_rotations_close(quats(msgs), want)  # 0.01°: float32, a batch against one stream
    cold = reference(ckpt, fr)  # without the resume the stream would start elsewhere
    assert np.abs(quats(msgs)[0] - cold[0]).max() > 1e-3
    assert added(srv, before, "resumed") == 1


def test_sample_client_reconnects_and_resumes_when_its_server_dies(default_checkpoint, tmp_path):
    """The docs' client, its server stopped mid-stream and a new one started on the same port:
    it reconnects, sends ``resume`` (the new server counts it) and finishes its stream. The servers serve the
    installed matching style, as ``serve`` does by default (two model processes started without torch)."""
    ckpt = default_checkpoint
    import subprocess
    import sys

    first = StreamServer(ckpt, ServeConfig(port=0)).start()
    port = first.bound[1]
    root = Path(__file__).resolve().parents[1]
    client = subprocess.Popen([sys.executable, str(root / "docs" / "examples" / "serve_client.py"),
                               f"ws://127.0.0.1:{port}/",
                               str(root / "src" / "facecapges" / "assets" / "demo" / "speech.wav"), "--seconds", "4"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    second = None
    try:
        t0 = time.monotonic()
        while first.summary().get("frames", 0) < 10:
            assert time.monotonic() - t0 < 60 and client.poll() is None, client.communicate()
            time.sleep(0.05)
        first.close()  # the node dies: the client's connection drops
        second = StreamServer(ckpt, ServeConfig(port=port)).start()
        _out, err = client.communicate(timeout=120)
        assert client.returncode == 0, err
        assert "reconnecting" in err and "resuming at frame" in err, err
        assert second.summary()["resumed"] == 1 and second.summary()["frames"] > 0
    finally:
        if client.poll() is None:
            client.kill()
        first.close()
        if second is not None:
            second.close()


def _shared_blocks(pid: int) -> set[str]:
    """The /dev/shm segments process ``pid`` has mapped (the model process's shared blocks)."""
    return {line.split()[-1] for line in Path(f"/proc/{pid}/maps").read_text().splitlines()
            if line.split()[-1].startswith("/dev/shm/")}


def test_a_network_styles_model_process_forks_from_a_one_thread_forkserver(ckpt):
    """A network style's model process is forked from multiprocessing's forkserver, which has imported torch
    once (serving/model_process.py: no torch import per start) and which runs one thread when it forks (no pool
    thread of OpenBLAS or torch is copied half-way into a child); the child steps the style."""
    import os
    from multiprocessing import forkserver

    from facecapges.serving.model_process import ModelProcess

    mp = ModelProcess(ckpt, max_rows=4)
    try:
        server = forkserver._forkserver._forkserver_pid
        assert server is not None
        stat = Path(f"/proc/{mp._proc.pid}/stat").read_text()
        assert int(stat.rsplit(")", 1)[1].split()[1]) == server  # the child's parent: the forkserver
        assert os.listdir(f"/proc/{server}/task") == [str(server)]  # one thread
        assert "libtorch" in Path(f"/proc/{server}/maps").read_text()  # torch imported there once
        (a,) = frames(1, seed=2)
        (slot,) = mp.sync([], 1)
        assert np.isfinite(mp.step([slot], [a[0]], a[1][None], a[2][None])).all()
    finally:
        mp.shutdown()


def test_a_matching_style_serves_without_torch():
    """``serve`` with a matching style (issue 36): the server imports neither torch nor Numba, its model process
    maps no torch (the engine's compiled loops load Numba there: docs/performance.md, "Engine step, third pass"),
    the step works, and stopping leaves no shared-memory block behind."""
    import subprocess
    import sys

    code = (
        "import os, sys, numpy as np\n"
        "from facecapges.styles import load_style\n"
        "from facecapges.serving.model_process import ModelProcess\n"
        "m = ModelProcess(load_style(style='beat2-scott-mm'), 1, 4)\n"
        "slots = m.sync([], 2, [])\n"
        "for i in range(5):\n"
        "    rng = np.random.default_rng(i)\n"
        "    p, q = (m.submit(slots, rng.normal(0, 0.1, (2, 1067)).astype(np.float32), np.zeros((2, 52)),"
        " np.tile([1.0, 0, 0, 0, 1, 0], (2, 1))), m.collect())[1]\n"
        "    assert p.shape == (2, 47, 6) and q.shape == (2, 47, 4) and np.isfinite(q).all()\n"
        "maps = open(f'/proc/{m._proc.pid}/maps').read()\n"
        "shm = sorted({l.split()[-1] for l in maps.splitlines() if '/dev/shm/' in l})\n"
        "print(sorted(x for x in ('torch', 'numba', 'llvmlite') if x in sys.modules))\n"
        "print(sorted(x for x in ('libtorch', 'libc10') if x in maps))\n"
        "m.shutdown()\n"
        "print(len(shm), [s for s in shm if os.path.exists(s)])\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    server, model, blocks = out.stdout.strip().splitlines()[-3:]
    assert server == "[]", f"the server imported {server}"
    assert model == "[]", f"the model process loaded {model}"
    assert blocks == "5 []", f"shared blocks (how many, left after shutdown): {blocks}"


def test_no_shared_block_outlives_a_crashed_model_process_or_a_terminated_server(ckpt):
    """The tick's shared-memory blocks are unlinked when the model process dies (the server shuts down after
    it) and when ``serve`` is stopped by SIGTERM."""
    import os

    from facecapges.serving.model_process import ModelProcess

    mp = ModelProcess(ckpt, max_rows=4)
    try:
        shm = _shared_blocks(mp._proc.pid)
        assert len(shm) == 5 and all(os.path.exists(s) for s in shm), shm
        os.kill(mp._proc.pid, signal.SIGKILL)  # the child crashes
        mp._proc.join(timeout=30)
        (a,) = frames(1, seed=5)
        with pytest.raises((EOFError, OSError, RuntimeError)):
            mp.step([0], [a[0]], a[1][None], a[2][None])
    finally:
        mp.shutdown()
    assert not [s for s in shm if os.path.exists(s)]

    proc = cli_process("serve", "--port", "0", background=True)  # the default (matching) style
    try:
        assert proc.stdout.readline().startswith("serving")
        assert proc.stdout.readline().startswith("ready:"), proc.stderr.read()
        kids = [int(p) for p in Path(f"/proc/{proc.pid}/task/{proc.pid}/children").read_text().split()]
        shm = set().union(*(_shared_blocks(k) for k in kids))
        assert len(shm) == 5, shm
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0 and "served:" in out, err
    assert not [s for s in shm if os.path.exists(s)]
