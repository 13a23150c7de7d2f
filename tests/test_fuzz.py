"""Fuzzing every parser that takes bytes from outside: clean error or valid result, never a traceback.

Parsers: BVH files, BEAT face JSON, Live Link Face UDP packets, the WebSocket protocol
(client messages and pose messages), the study server's API (in process, and raw HTTP
over loopback), and ``train --config`` YAML. VMC/OSC is only sent by the project, never
parsed, so it has no parser to fuzz. Each property runs a bounded, derandomized number of
examples (``MAX_EXAMPLES``, no deadline: the machine is shared); the cases tried are
counted in ``CASES`` and printed at the end of the test session (tests/conftest.py).
"""

from __future__ import annotations

import collections
import json
import socket
import tempfile
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from facecapges.errors import UserError

MAX_EXAMPLES = 200
CASES: collections.Counter = collections.Counter()
FUZZ = settings(max_examples=MAX_EXAMPLES, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
TMP = Path(tempfile.mkdtemp(prefix="facecapges-fuzz-"))

json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=True, allow_infinity=True) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=6) | st.dictionaries(st.text(max_size=8), inner, max_size=6),
    max_leaves=30)


def _file(name: str, data: bytes | str) -> Path:
    p = TMP / f"{threading.get_ident()}-{name}"
    p.write_bytes(data.encode("utf-8", "surrogatepass") if isinstance(data, str) else data)
    return p


def mutate(base: bytes):
    """Strategy: ``base`` with random bytes overwritten, inserted, deleted or cut off."""
    @st.composite
    def _m(draw):
        b = bytearray(base)
        for _ in range(draw(st.integers(1, 6))):
            op = draw(st.sampled_from(["flip", "insert", "delete", "cut", "dup"]))
            i = draw(st.integers(0, max(len(b) - 1, 0)))
            if op == "flip" and b:
                b[i] = draw(st.integers(0, 255))
            elif op == "insert":
                b[i:i] = draw(st.binary(min_size=1, max_size=12))
            elif op == "delete":
                del b[i:i + draw(st.integers(1, 40))]
            elif op == "cut":
                del b[i:]
            elif op == "dup":
                b[i:i] = b[i:i + draw(st.integers(1, 60))]
        return bytes(b)
    return _m()


# ---------------------------------------------------------------------------- BVH
BVH_TEXT = """HIERARCHY
ROOT Hips
{
  OFFSET 0.0 0.0 0.0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0.0 10.0 0.0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0.0 5.0 0.0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.0666667
0 90 0 0 0 0 1 2 3
0 90 0 1 1 1 2 3 4
0 90 0 2 2 2 3 4 5
"""


@FUZZ
@given(mutate(BVH_TEXT.encode()))
def test_fuzz_bvh(data):
    from facecapges.io.bvh import read_bvh

    CASES["bvh"] += 1
    try:
        b = read_bvh(_file("f.bvh", data))
    except UserError:
        return
    assert b.motion.ndim == 2 and np.isfinite(b.motion).all() and b.fps > 0


# ---------------------------------------------------------------------------- face JSON
def _face_doc(n=4, names=("jawOpen", "eyeBlinkLeft")):
    return json.dumps({"names": list(names), "frames": [{"time": i / 30, "weights": [0.1] * len(names)}
                                                        for i in range(n)]}).encode()


face_docs = st.one_of(
    mutate(_face_doc()),
    st.fixed_dictionaries({"names": json_values, "frames": json_values}).map(lambda d: json.dumps(d).encode()),
    st.fixed_dictionaries({"names": st.just(["jawOpen"]), "frames": st.lists(st.fixed_dictionaries(
        {"time": json_values, "weights": st.lists(json_values, min_size=1, max_size=1)}), max_size=5)}
    ).map(lambda d: json.dumps(d).encode()),
    st.integers(1, 3000).map(lambda n: b"[" * n * 20),
    st.binary(max_size=200),
)


@FUZZ
@given(face_docs)
@example(b'{"names": ["jawOpen"], "frames": [{"weights": [3447e89]}]}')  # found by this test: inf as float32
@example(b'{"names": ["jawOpen"], "frames": [{"weights": [[]]}]}')  # found by this test: nested weights
def test_fuzz_face_json(data):
    from facecapges.io.face_json import read_face_json

    CASES["face_json"] += 1
    try:
        t = read_face_json(_file("f.json", data))
    except UserError:
        return
    assert t.weights.shape[1] == 52 and np.isfinite(t.weights).all() and 1.0 <= t.fps <= 1000.0


# ---------------------------------------------------------------------------- Live Link packets
def _packet() -> bytes:
    from facecapges.runtime.livelink import N_VALUES, encode_packet

    return encode_packet(np.linspace(0, 1, N_VALUES, dtype=np.float32))


@FUZZ
@given(st.one_of(mutate(_packet()), st.binary(max_size=400)))
def test_fuzz_livelink_packets(data):
    from facecapges.runtime.livelink import PacketError, decode_packet

    CASES["livelink"] += 1
    try:
        f = decode_packet(data)
    except PacketError:
        return
    assert np.isfinite(f.values).all() and f.weights52.shape == (52,)


# ---------------------------------------------------------------------------- WebSocket protocol
def _input_message() -> str:
    from facecapges.runtime import protocol

    return protocol.encode_input(3, np.zeros(1067, np.float32), np.full(52, 0.5, np.float32),
                                 np.array([1, 0, 0, 0, 1, 0], np.float32))


client_messages = st.one_of(
    mutate(_input_message().encode()).map(lambda b: b.decode("utf-8", "replace")),
    json_values.map(json.dumps),
    st.fixed_dictionaries({"type": st.sampled_from(["input", "ping", "pose", ""]), "frame": json_values,
                           "audio": json_values, "face": json_values, "head": json_values}).map(json.dumps),
    st.text(max_size=300),
    st.binary(max_size=100),
    st.integers(1, 3000).map(lambda n: "[{" * n * 10),
)


@FUZZ
@given(client_messages)
def test_fuzz_websocket_client_messages(text):
    from facecapges.runtime import protocol

    CASES["ws_client"] += 1
    try:
        msg = protocol.decode_client(text)
    except protocol.ProtocolError as exc:
        assert str(exc)
        return
    assert msg["type"] in ("ping", "input")
    if msg["type"] == "input":
        i = msg["input"]
        assert np.isfinite(i.audio).all() and i.face.shape == (52,) and i.head.shape == (6,)


@FUZZ
@given(st.one_of(json_values.map(json.dumps), st.text(max_size=200),
                 st.fixed_dictionaries({"type": st.just("pose"), "pose": json_values, "weights": json_values,
                                        "head": json_values}).map(json.dumps)))
def test_fuzz_websocket_pose_messages(text):
    from facecapges.runtime import protocol

    CASES["ws_pose"] += 1
    try:
        msg = protocol.decode_pose(text)
    except protocol.ProtocolError:
        return
    assert msg["pose"].shape == (47, 4)


# ---------------------------------------------------------------------------- config YAML
config_docs = st.one_of(
    st.fixed_dictionaries({}, optional={
        "model": st.dictionaries(st.sampled_from(["lstm_hidden", "n_joints", "dropout", "audio_tcn_dilations",
                                                  "fps", "typo"]), json_values, max_size=4) | json_values,
        "train": st.dictionaries(st.sampled_from(["batch_size", "clip_len", "stride", "epochs", "lr_base",
                                                  "optimizer", "holdout_from"]), json_values, max_size=4)
        | json_values,
    }).map(lambda d: yaml.safe_dump(d).encode()),
    mutate(b"model:\n  lstm_hidden: 16\ntrain:\n  batch_size: 16\n  epochs: 3\n"),
    st.binary(max_size=200),
)


@FUZZ
@given(config_docs)
def test_fuzz_config_yaml(data):
    from facecapges.model.config import load_config_file, model_config_from_dict, train_config_from_dict

    CASES["config_yaml"] += 1
    try:
        model, train = load_config_file(_file("c.yaml", data))
    except UserError:
        return
    m = model_config_from_dict(dict(model))
    t = train_config_from_dict(dict(train), m)
    assert t.batch_size >= 1 and t.epochs >= 1 and t.clip_len > m.n_history and m.lstm_hidden >= 1


# ---------------------------------------------------------------------------- study API
@pytest.fixture(scope="module")
def study_app():
    from facecapges.study.build import Study
    from facecapges.study.criteria import CRITERIA
    from facecapges.study.design import make_plan, new_token
    from facecapges.study.server import StudyApp

    d = TMP / "study"
    plan = make_plan(["c1", "c2"], ["a", "b", "c"], 3, seed=0)
    for p in plan.participants:
        p.token = new_token()
    doc = {"criteria": [c.to_json() for c in CRITERIA], "fps": 15, "systems": ["a", "b", "c"],
           "clips": [{"id": c, "frames": 30, "duration": 2.0} for c in ("c1", "c2")]}
    return StudyApp(Study(d, doc, plan))


@FUZZ
@given(st.sampled_from(["/api/session", "/api/event", "/api/answer", "/api/x", "/"]),
       st.dictionaries(st.sampled_from(["token", "participant", "index", "type", "ranks"]), json_values, max_size=5),
       st.booleans())
def test_fuzz_study_api(study_app, path, body, with_token):
    from facecapges.study.server import HttpError

    CASES["study_api"] += 1
    if with_token:
        body["token"] = study_app.study.plan.participants[0].token
    try:
        doc = study_app.post(path, body)
    except HttpError as exc:
        assert 400 <= exc.status < 600 and str(exc)
        return
    assert isinstance(doc, dict)


@FUZZ
@given(st.text(max_size=300), st.dictionaries(st.sampled_from(["token", "index"]), st.lists(st.text(max_size=40),
                                                                                        min_size=1, max_size=2)))
def test_fuzz_study_get(study_app, path, query):
    from facecapges.study.server import HttpError

    CASES["study_get"] += 1
    try:
        doc, f = study_app.get("/" + path, query)
    except HttpError as exc:
        assert 400 <= exc.status < 600
        return
    assert doc is not None or f is not None


@pytest.fixture(scope="module")
def study_http(study_app):
    from facecapges.study.server import _Handler, StudyServer

    handler = type("FuzzHandler", (_Handler,), {"app": study_app, "timeout": 2.0})
    server = StudyServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield server.server_address[1]
    server.shutdown()
    server.server_close()


REQUEST = (b"POST /api/session HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
           b"Content-Length: 15\r\n\r\n{\"token\": \"x\"}")


@FUZZ
@given(st.one_of(mutate(REQUEST), st.binary(max_size=300)))
def test_fuzz_study_raw_http(study_http, data):
    CASES["study_http"] += 1
    with socket.create_connection(("127.0.0.1", study_http), timeout=5) as s:
        try:
            s.sendall(data)
            s.shutdown(socket.SHUT_WR)
            got = s.recv(200)
        except (ConnectionResetError, BrokenPipeError, socket.timeout):
            got = b""
    assert got == b"" or got.startswith(b"HTTP/")  # an answer or a closed connection, nothing else
    with socket.create_connection(("127.0.0.1", study_http), timeout=5) as s:  # and the server still serves
        s.sendall(b"GET /api/info HTTP/1.0\r\n\r\n")
        assert s.recv(20).startswith(b"HTTP/1.0 200")
