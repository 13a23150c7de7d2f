"""Fuzzing every parser that takes bytes from outside: clean error or valid result, never a traceback.

Parsers: BVH files, BEAT face JSON, Live Link Face UDP packets, the WebSocket protocol
(client messages and pose messages), the study server's API (in process, and raw HTTP
over loopback), ``train --config`` YAML, and (issue 28) the VRM/GLB avatar reader,
CLIPS.yaml, study.json, a ``styles install`` run folder (links, loops, FIFOs, sparse
giants), WAV headers, checkpoint metadata, the cache index and its npz files, and the
viewer's HTTP paths; (issue 34) matching style files (metadata and database tensors). The BEAT2 npz reader (issue 20) has its own fuzz test beside it
(tests/test_data_beat2.py). VMC/OSC is only sent by the project, never
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
    from facecapges.runtime.inputs.livelink import N_VALUES, encode_packet

    return encode_packet(np.linspace(0, 1, N_VALUES, dtype=np.float32))


@FUZZ
@given(st.one_of(mutate(_packet()), st.binary(max_size=400)))
def test_fuzz_livelink_packets(data):
    from facecapges.runtime.inputs.livelink import PacketError, decode_packet

    CASES["livelink"] += 1
    try:
        f = decode_packet(data)
    except PacketError:
        return
    assert np.isfinite(f.values).all() and f.weights52.shape == (52,)


# ---------------------------------------------------------------------------- WebSocket protocol
def _input_message() -> str:
    from facecapges.runtime.outputs import protocol

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
    from facecapges.runtime.outputs import protocol

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
    from facecapges.runtime.outputs import protocol

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
    from facecapges.network.config import load_config_file, model_config_from_dict, train_config_from_dict

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
    from facecapges.study.server import StudyServer, _Handler

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
        except (TimeoutError, ConnectionResetError, BrokenPipeError):
            got = b""
    assert got == b"" or got.startswith(b"HTTP/")  # an answer or a closed connection, nothing else
    with socket.create_connection(("127.0.0.1", study_http), timeout=5) as s:  # and the server still serves
        s.sendall(b"GET /api/info HTTP/1.0\r\n\r\n")
        assert s.recv(20).startswith(b"HTTP/1.0 200")


# ============================================================================ issue 28: every other parser
def _json_edit(doc: dict, paths: list[str]):
    """Strategy: ``doc`` (a JSON object) with one value at a path from ``paths`` replaced by a random one."""
    import copy

    @st.composite
    def _e(draw):
        d = copy.deepcopy(doc)
        path = draw(st.sampled_from(paths)).split(".")
        value = draw(json_values | st.integers(-3, 60))
        node = d
        for k in path[:-1]:
            node = node[int(k)] if isinstance(node, list) else node.setdefault(k, {})
            if not isinstance(node, (dict, list)):
                return d
        if isinstance(node, list):
            if node:
                node[int(path[-1]) % len(node)] = value
        else:
            node[path[-1]] = value
        return d
    return _e()


# ---------------------------------------------------------------------------- VRM / GLB avatars
def _vrm_sample() -> bytes:
    from vrm_samples import build_sample

    return build_sample("vrm1")


_VRM = _vrm_sample()
_VRM_PATHS = ["nodes", "nodes.0", "nodes.0.children", "nodes.3.children.0", "nodes.2.translation", "nodes.1.rotation",
              "nodes.1.mesh", "nodes.1.skin", "nodes.4.matrix", "nodes.5.name", "meshes.0.primitives",
              "meshes.0.primitives.0.attributes.POSITION", "meshes.0.primitives.0.indices",
              "meshes.0.primitives.0.targets", "meshes.0.extras.targetNames", "accessors.0.count",
              "accessors.1.bufferView", "accessors.0.componentType", "bufferViews.0.byteLength",
              "bufferViews.0.buffer", "buffers.0.byteLength", "buffers.0.uri", "skins.0.joints",
              "skins.0.inverseBindMatrices", "scenes.0.nodes", "scene", "extensions", "extensionsRequired",
              "extensions.VRMC_vrm", "extensions.VRMC_vrm.specVersion", "extensions.VRMC_vrm.humanoid.humanBones",
              "extensions.VRMC_vrm.humanoid.humanBones.hips", "extensions.VRMC_vrm.humanoid.humanBones.hips.node",
              "extensions.VRMC_vrm.humanoid.humanBones.head.node", "extensions.VRMC_vrm.expressions.custom",
              "extensions.VRMC_vrm.meta.name", "materials", "images", "textures", "animations"]


def _vrm_docs():
    from facecapges.avatar.vrm.glb import join_glb, split_glb

    doc, binary = split_glb(_VRM)
    return st.one_of(
        mutate(_VRM[:4000]).map(lambda b: b + _VRM[4000:]),  # the header and JSON chunk
        _json_edit(doc, _VRM_PATHS).map(lambda d: join_glb(d, binary)),
        st.integers(1, 3000).map(lambda n: join_glb({}, b"")[:12] + b"[" * n * 4),
        st.binary(max_size=200).map(lambda b: b"glTF" + b),
    )


@FUZZ
@given(_vrm_docs())
def test_fuzz_vrm_glb(data):
    from facecapges.avatar.vrm.humanoid import REQUIRED_BONES
    from facecapges.avatar.vrm.read import parse_model

    CASES["vrm_glb"] += 1
    try:
        m = parse_model(data, "fuzz.vrm")
    except UserError as exc:
        assert str(exc).startswith("fuzz.vrm: ") and "\n" not in str(exc)
        return
    assert all(b in m.bones for b in REQUIRED_BONES)
    assert all(np.isfinite(v).all() for v in m.rest.values())


# ---------------------------------------------------------------------------- CLIPS.yaml
_CLIPS = (b"systems: [a, b]\nfps: 15\nclips:\n  - id: c1\n    audio: media/c1.wav\n    face: media/c1.json\n"
          b"    bvh: {a: media/c1-a.bvh, b: media/c1-b.bvh}\n")


@settings(FUZZ, max_examples=100)
@given(st.one_of(
    mutate(_CLIPS),
    st.fixed_dictionaries({"systems": json_values, "clips": json_values, "fps": json_values}).map(
        lambda d: yaml.safe_dump(d).encode()),
    st.fixed_dictionaries({"clips": st.lists(st.fixed_dictionaries(
        {"id": json_values, "audio": json_values, "bvh": json_values}), max_size=3)}).map(
        lambda d: yaml.safe_dump(d).encode()),
    st.integers(1, 600).map(lambda n: b"clips: " + b"[" * n * 5),
    st.binary(max_size=200),
))
def test_fuzz_clips_yaml(data):
    from facecapges.study.clips import parse_clips

    CASES["clips_yaml"] += 1
    try:
        cs = parse_clips(_file("CLIPS.yaml", data))
    except UserError:
        return
    assert cs.clips and cs.systems


# ---------------------------------------------------------------------------- study.json
def _study_doc() -> dict:
    from facecapges.study.build import FORMAT
    from facecapges.study.design import make_plan, new_token

    plan = make_plan(["c1", "c2"], ["a", "b"], 2, seed=0)
    for p in plan.participants:
        p.token = new_token()
    return {"format": FORMAT, "fps": 15, "systems": ["a", "b"], "clips": [{"id": "c1"}, {"id": "c2"}],
            "plan": plan.to_json()}


_STUDY = _study_doc()


@FUZZ
@given(st.one_of(
    mutate(json.dumps(_STUDY).encode()),
    _json_edit(_STUDY, ["format", "plan", "plan.participants", "plan.participants.0",
                        "plan.participants.0.id", "plan.participants.0.token", "plan.participants.0.trials",
                        "plan.clips", "plan.systems", "systems"]).map(lambda d: json.dumps(d).encode()),
    st.integers(1, 3000).map(lambda n: b"[" * n * 40),
    st.binary(max_size=200),
))
def test_fuzz_study_json(data):
    from facecapges.study.build import STUDY_FILE, open_study

    CASES["study_json"] += 1
    d = TMP / f"study-{threading.get_ident()}"
    d.mkdir(exist_ok=True)
    (d / STUDY_FILE).write_bytes(data)
    try:
        s = open_study(d)
    except UserError as exc:
        assert "study" in str(exc)
        return
    assert s.plan.participants is not None


# ---------------------------------------------------------------------------- styles install run folder
_RUN_ENTRIES = ["log.csv", "model_card.md", "model.fgd", "model.fgd/a.json", "model.fgd/sub", "model.fgd/sub/b.pt"]
_KINDS = ["file", "big", "dir", "link-passwd", "link-outside-dir", "link-loop", "link-sibling", "fifo"]


@settings(FUZZ, max_examples=60)
@given(st.lists(st.tuples(st.sampled_from(_RUN_ENTRIES), st.sampled_from(_KINDS)), max_size=6))
def test_fuzz_styles_install_run_folder(entries):
    import os
    import shutil

    from facecapges.styles import install_style, styles_dir

    CASES["styles_install"] += 1
    root = Path(tempfile.mkdtemp(dir=TMP))
    run, store, outside = root / "run", root / "store", root / "outside"
    run.mkdir()
    outside.mkdir()
    (outside / "secret").write_text("secret")
    shutil.copyfile(sorted(styles_dir().glob("*.safetensors"))[0], run / "model.safetensors")
    for rel, kind in entries:
        p = run / rel
        if p.exists() or p.is_symlink() or not p.parent.is_dir():
            continue
        if kind == "file":
            p.write_text("x")
        elif kind == "big":
            with p.open("wb") as f:
                f.truncate(3 << 30)  # sparse: no disk
        elif kind == "dir":
            p.mkdir()
        elif kind == "link-passwd":
            p.symlink_to("/etc/passwd")
        elif kind == "link-outside-dir":
            p.symlink_to(outside)
        elif kind == "link-loop":
            p.symlink_to(p)
        elif kind == "link-sibling":
            p.symlink_to(run / "model.safetensors")
        else:
            os.mkfifo(p)
    os.environ["FACECAPGES_STYLES"] = str(store)
    try:
        install_style(run, name="fz", force=True)
    except UserError:
        pass
    finally:
        del os.environ["FACECAPGES_STYLES"]
    if store.exists():  # whatever happened: only regular files and folders, nothing of outside, nothing half-made
        for p in store.rglob("*"):
            assert not p.is_symlink() and (p.is_file() or p.is_dir()), p
            assert not p.name.startswith(".install-") and (not p.is_file() or p.stat().st_size < 64 << 20)
            assert not p.is_file() or p.read_bytes() != b"secret"
    shutil.rmtree(root, ignore_errors=True)


# ---------------------------------------------------------------------------- WAV headers
def _wav() -> bytes:
    import io

    import soundfile as sf

    buf = io.BytesIO()
    sf.write(buf, (np.sin(np.arange(1600) / 5) * 0.3).astype(np.float32), 16000, format="WAV", subtype="PCM_16")
    return buf.getvalue()


@FUZZ
@given(st.one_of(mutate(_wav()[:200]).map(lambda b: b + _wav()[200:]), mutate(_wav()), st.binary(max_size=100).map(
    lambda b: b"RIFF" + b)))
def test_fuzz_wav_headers(data):
    from facecapges.io.audio import check_audio, load_audio

    CASES["wav"] += 1
    p = _file("a.wav", data)
    try:
        check_audio(p)
        a = load_audio(p)
    except UserError:
        return
    assert a.ndim == 1 and np.isfinite(a).all()


# ---------------------------------------------------------------------------- checkpoint metadata
def _ckpt_parts():
    from safetensors import safe_open

    p = sorted(__import__("facecapges.styles", fromlist=["x"]).styles_dir().glob("*.safetensors"))[0]
    with safe_open(str(p), framework="pt") as f:
        return json.loads(f.metadata()["facecapges"]), {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118


_CKPT_META, _CKPT_TENSORS = _ckpt_parts()


@settings(FUZZ, max_examples=100)
@given(st.one_of(
    _json_edit(_CKPT_META, ["format", "model_config", "model_config.lstm_hidden", "model_config.fps",
                            "model_config.n_joints", "neutral_window", "skeleton", "skeleton.names",
                            "skeleton.parents", "speaker"]).map(json.dumps),
    mutate(json.dumps({k: _CKPT_META[k] for k in ("format", "model_config")}).encode()).map(
        lambda b: b.decode("utf-8", "replace")),
    st.integers(1, 3000).map(lambda n: "[" * n * 40),
))
def test_fuzz_checkpoint_metadata(meta):
    from safetensors.torch import save_file

    from facecapges.styles import load_style

    CASES["checkpoint_meta"] += 1
    p = TMP / f"{threading.get_ident()}-c.safetensors"
    save_file(_CKPT_TENSORS, str(p), metadata={"facecapges": meta})
    try:
        ck = load_style(p)
    except UserError:
        return
    assert ck.fps >= 1 and ck.neutral_window.shape[1:] == (47, 6) and np.isfinite(ck.neutral_window).all()
    try:
        assert ck.skeleton.n_joints >= 1
    except UserError:  # no skeleton: said so where one is needed
        pass


# ---------------------------------------------------------------------------- matching styles (issue 34)
def _mm_parts():
    from safetensors import safe_open

    from facecapges.styles import styles_dir

    with safe_open(str(styles_dir() / "beat2-scott-mm.safetensors"), framework="pt") as f:
        return json.loads(f.metadata()["facecapges"]), {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118


_MM_META, _MM_TENSORS = _mm_parts()
_MM_PATHS = (["fps", "engine_config", "database", "database.weights", "database.segments", "database.segments.0",
              "database.segments.0.row", "database.segments.0.name", "predictor", "predictor.model",
              "predictor.settings.hidden", "predictor.target_mean", "predictor.head_reference", "neutral_window"]
             + [f"engine_config.{k}" for k in _MM_META["engine_config"]]
             + [f"database.weights.{k}" for k in _MM_META["database"]["weights"]])


@st.composite
def _mm_tensor_edit(draw):
    """One database tensor of the style cut, widened, retyped, filled with extreme values or swapped for a scalar."""
    import torch

    key = draw(st.sampled_from(sorted(k for k in _MM_TENSORS if k.startswith("db."))))
    v = _MM_TENSORS[key]
    op = draw(st.sampled_from(["cut", "widen", "retype", "fill", "scalar", "drop"]))
    if op == "cut":
        v = v[: draw(st.integers(0, max(len(v) - 1, 0)))]
    elif op == "widen":
        v = torch.cat([v, v[..., :1]], dim=-1) if v.ndim else v
    elif op == "retype":
        v = v.to(draw(st.sampled_from([torch.float64, torch.int64, torch.uint8, torch.bool, torch.float16])))
    elif op == "fill":
        v = torch.full_like(v, draw(st.sampled_from([-1, 0, 7, 255, 1e30])) if v.is_floating_point()
                            else draw(st.sampled_from([-1, 0, 7, 100])))
    elif op == "scalar":
        v = torch.zeros((), dtype=v.dtype)
    return key, (None if op == "drop" else v.contiguous())


@settings(FUZZ, max_examples=120)
@given(st.one_of(
    st.tuples(_json_edit(_MM_META, _MM_PATHS).map(json.dumps), st.none()),
    st.tuples(st.just(json.dumps(_MM_META)), _mm_tensor_edit()),
))
def test_fuzz_matching_style(case):
    """A crafted matching style: refused by its check (UserError), or it loads and runs a few frames."""
    from safetensors.torch import save_file

    from facecapges.styles import load_style

    meta, edit = case
    CASES["matching_style"] += 1
    tensors = dict(_MM_TENSORS)
    if edit is not None:
        key, value = edit
        if value is None:
            del tensors[key]
        else:
            tensors[key] = value
    p = TMP / f"{threading.get_ident()}-mm.safetensors"
    save_file(tensors, str(p), metadata={"facecapges": meta})
    try:
        ck = load_style(p)
    except UserError:
        return
    gen = ck.streaming()
    gen.reset()
    for t in range(3):
        pose = gen.step(np.zeros(1067, np.float32) + 0.01 * t, np.zeros(52, np.float32),
                        np.array([1, 0, 0, 0, 1, 0], np.float32))
        assert pose.shape == (47, 6) and np.isfinite(pose).all()


# ---------------------------------------------------------------------------- cache index and npz
def _cache_index() -> dict:
    from facecapges.data.cache import CACHE_VERSION

    return {"version": CACHE_VERSION, "fps": 15, "sr": 16000, "skeleton": {}, "stats": {},
            "clips": [{"name": "a", "file": "a.npz", "speaker": 2, "split": "train"}]}


def _npz() -> bytes:
    import io

    from facecapges.data.cache import PRESENCE_KEYS

    buf = io.BytesIO()
    np.savez(buf, pose=np.zeros((4, 47, 6), np.float32), **{k: np.array(True) for k in PRESENCE_KEYS})
    return buf.getvalue()


@FUZZ
@given(st.one_of(
    _json_edit(_cache_index(), ["version", "fps", "sr", "clips", "clips.0", "clips.0.name", "clips.0.file",
                                "clips.0.speaker", "clips.0.split", "skeleton", "stats"]).map(json.dumps).map(str.encode),
    mutate(json.dumps(_cache_index()).encode()),
    st.integers(1, 3000).map(lambda n: b"[" * n * 40),
), st.one_of(st.just(_npz()), mutate(_npz()), st.binary(max_size=300)))
def test_fuzz_cache_index_and_npz(index, npz):
    from facecapges.data.cache import INDEX_NAME, Cache

    CASES["cache"] += 1
    d = Path(tempfile.mkdtemp(dir=TMP))
    (d / INDEX_NAME).write_bytes(index)
    (d / "a.npz").write_bytes(npz)
    try:
        c = Cache(d)
        names = [e["name"] for e in c.clips()]
        assert c.fps > 0 and c.sr > 0 and isinstance(c.speakers, list)
        for n in names:
            clip = c.load(n)
            assert all(isinstance(clip[k], bool) for k in clip if k.endswith("_present"))
    except UserError:
        return


# ---------------------------------------------------------------------------- viewer HTTP paths
@pytest.fixture(scope="module")
def viewer_port():
    from facecapges.runtime.outputs.viewer import ViewerServer

    s = ViewerServer(b"glTF-not-really", "127.0.0.1", 0).start()
    yield s.bound[1] if getattr(s, "bound", None) else s.port
    s.close()


VIEWER_GET = b"GET /web/viewer.html HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"


@FUZZ
@given(st.one_of(
    st.text(max_size=200).map(lambda t: b"GET /" + t.encode("utf-8", "surrogatepass") + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"),
    st.sampled_from(["/../../../etc/passwd", "/web/../../pyproject.toml", "/three/%2e%2e/%2e%2e/x", "/web/\0",
                     "/three/" + "a/" * 3000, "/avatar.glb?x=1", "/ws", "//etc/passwd"]).map(
        lambda t: b"GET " + t.encode() + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"),
    mutate(VIEWER_GET),
))
def test_fuzz_viewer_http_paths(viewer_port, data):
    CASES["viewer_http"] += 1
    # 1 s: a cut-off request the server keeps waiting on until its handshake timeout reads as no answer
    # (allowed below); the check that matters is that it still serves afterwards
    with socket.create_connection(("127.0.0.1", viewer_port), timeout=1) as s:
        try:
            s.sendall(data)
            s.shutdown(socket.SHUT_WR)  # all of the request: the server answers or closes, no waiting
            got = s.recv(4096)
        except (ConnectionResetError, BrokenPipeError, TimeoutError):
            got = b""
    assert got == b"" or got.startswith(b"HTTP/1.1 ")
    assert b"root:" not in got and b"[project]" not in got  # nothing outside the served folders
    with socket.create_connection(("127.0.0.1", viewer_port), timeout=5) as s:  # and it still serves
        s.sendall(VIEWER_GET)
        assert s.recv(20).startswith(b"HTTP/1.1 200")


# ---------------------------------------------------------------------------- capture-body's video input
def _video_head() -> bytes:
    from conftest import shared_file

    return shared_file("data/face/Megamind.avi").read_bytes()[:120_000]  # the header and the first frames


@settings(FUZZ, max_examples=40)
@given(st.one_of(mutate(_video_head()), st.binary(max_size=4096)))
def test_fuzz_capture_body_video(data):
    """A damaged or foreign file given to ``capture-body`` is a UserError (one error line) or a few frames'
    landmarks, never another exception (issue #34: fuzz the parsers the new work adds)."""
    from facecapges.capture.body import collect_landmarks

    CASES["capture_body_video"] += 1
    p = _file("v.avi", data)
    try:
        collect_landmarks(p, 15.0, max_frames=2)
    except UserError:
        return
