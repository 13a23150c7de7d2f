"""Issue 28, items 1, 5, 6: avatars from outside. A crafted VRM / GLB is refused with one clear
message before anything uses it (no fetch of any URL, no traceback, no file read whole when it is
too large), and the headless browser and every page we serve cannot reach anything but our own
server (request interception + Content-Security-Policy), checked against a real HTTP server on
127.0.0.1 that must never be hit. Bounded: small files, loopback, one short Chromium per test."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import threading
import time
import urllib.request
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from facecapges.avatar.gltf_check import MAX_DEPTH, MAX_FILE_BYTES
from facecapges.avatar.vrm.glb import join_glb, split_glb
from facecapges.avatar.vrm.read import load_model, parse_model
from facecapges.errors import UserError
from runtime_helpers import cli
from vrm_samples import build_sample


class LeakServer:
    """An HTTP server on 127.0.0.1 counting every request it gets; ``page`` is what it serves (no CSP)."""

    def __init__(self, page: bytes = b""):
        hits = self.hits = []

        class H(BaseHTTPRequestHandler):
            def do_GET(self):
                hits.append(self.path)
                self.send_response(200)
                self.send_header("Content-Type", "text/html")
                self.send_header("Content-Length", str(len(page)))
                self.send_header("Access-Control-Allow-Origin", "*")
                self.end_headers()
                self.wfile.write(page)

            def log_message(self, *a):
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), H)
        self.port = self.server.server_address[1]
        self.url = f"http://127.0.0.1:{self.port}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self):
        self.server.shutdown()
        self.server.server_close()


@pytest.fixture()
def leak():
    s = LeakServer()
    yield s
    s.close()


@pytest.fixture(scope="module")
def vrm1() -> bytes:
    return build_sample("vrm1")


@pytest.fixture(scope="module")
def vrm0() -> bytes:
    return build_sample("vrm0")


def _edit(data: bytes, fn) -> bytes:
    doc, binary = split_glb(data)
    fn(doc)
    return join_glb(doc, binary)


def _glb(json_text: str, binary: bytes) -> bytes:
    j = json_text.encode() + b" " * (-len(json_text.encode()) % 4)
    b = binary + b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<II", len(j), 0x4E4F534A) + j + struct.pack("<II", len(b), 0x004E4942) + b
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks


def _set(path: str, value):
    def fn(doc):
        *head, last = path.split(".")
        d = doc
        for k in head:
            d = d[int(k)] if isinstance(d, list) else d[k]
        if isinstance(d, list):
            d[int(last)] = value
        else:
            d[last] = value
    return fn


def _chain(n: int):
    def fn(doc):  # n extra nodes hung as a chain under the head
        base = len(doc["nodes"])
        head = doc["extensions"]["VRMC_vrm"]["humanoid"]["humanBones"]["head"]["node"]
        doc["nodes"][head].setdefault("children", []).append(base)
        for i in range(n):
            doc["nodes"].append({"name": f"c{i}", "translation": [0, 0.001, 0],
                                 **({"children": [base + i + 1]} if i < n - 1 else {})})
    return fn


def _cycle(doc):
    doc["nodes"][1].setdefault("children", []).append(0)


def _two_parents(doc):
    kid = doc["nodes"][0]["children"][0]
    doc["nodes"][2].setdefault("children", []).append(kid)


def _deep(doc):
    v: object = 1
    for _ in range(5000):
        v = [v]
    doc["extras"] = {"deep": v}


CRAFTED_VRM1 = {
    "hips node a string": _set("extensions.VRMC_vrm.humanoid.humanBones.hips.node", "abc"),
    "hips node out of range": _set("extensions.VRMC_vrm.humanoid.humanBones.hips.node", 10**6),
    "hips node a float": _set("extensions.VRMC_vrm.humanoid.humanBones.hips.node", 1.5),
    "hips entry a list": _set("extensions.VRMC_vrm.humanoid.humanBones.hips", [0]),
    "humanBones a list": _set("extensions.VRMC_vrm.humanoid.humanBones", [1, 2]),
    "extensions a list": _set("extensions", ["VRMC_vrm"]),
    "VRMC_vrm a string": _set("extensions.VRMC_vrm", "x"),
    "nodes an object": _set("nodes", {"0": {}}),
    "node a number": _set("nodes.0", 7),
    "children a string": _set("nodes.0.children", "abc"),
    "child out of range": _set("nodes.0.children", [99999]),
    "child negative": _set("nodes.0.children", [-1]),
    "node cycle": _cycle,
    "two parents": _two_parents,
    "translation NaN": _set("nodes.0.translation", [0, float("nan"), 0]),
    "rotation too short": _set("nodes.0.rotation", [0, 0, 1]),
    "matrix strings": _set("nodes.0.matrix", ["a"] * 16),
    "mesh out of range": _set("nodes.1.mesh", 4242),
    "skin out of range": _set("nodes.1.skin", 4242),
    "primitives empty": _set("meshes.0.primitives", []),
    "attribute out of range": _set("meshes.0.primitives.0.attributes.POSITION", 9999),
    "indices a string": _set("meshes.0.primitives.0.indices", "0"),
    "targetNames a dict": _set("meshes.0.extras", {"targetNames": {"a": 1}}),
    "bufferView past the buffer": _set("bufferViews.0.byteLength", 10**9),
    "buffer past the BIN chunk": _set("buffers.0.byteLength", 10**9),
    "accessor past its view": _set("accessors.0.count", 10**8),
    "accessor unknown type": _set("accessors.0.type", "VEC9"),
    "skin joint out of range": _set("skins.0.joints", [123456]),
    "scene node out of range": _set("scenes.0.nodes", [123456]),
    "expression bind node wrong": _set("extensions.VRMC_vrm.expressions.custom.JawOpen",
                                       {"morphTargetBinds": [{"node": "x", "index": 0}]}),
    "deep JSON": _deep,
    "node name a list": _set("nodes.0.name", ["x"]),
    "extensionsRequired not names": _set("extensionsRequired", [{}]),
    "buffer uri outside": _set("buffers.0.uri", "../../../../etc/passwd"),
    "image uri outside": lambda d: d.setdefault("images", []).append({"uri": "http://127.0.0.1:18999/leak-image.png"}),
    "uri in an extension": lambda d: d["extensions"].__setitem__("X_thumb", {"uri": "https://example.invalid/t.png"}),
}


@pytest.mark.parametrize("case", sorted(CRAFTED_VRM1))
def test_crafted_vrm1_is_one_clear_user_error(vrm1, case):
    if case == "deep JSON":  # json.dumps cannot write 5,000 levels: the JSON chunk is built by hand
        doc, binary = split_glb(vrm1)
        data = _glb(json.dumps(doc)[:-1] + ', "extras": {"deep": ' + "[" * 5000 + "1" + "]" * 5000 + "}}", binary)
    else:
        data = _edit(vrm1, CRAFTED_VRM1[case])
    with pytest.raises(UserError) as exc:
        parse_model(data, "crafted.vrm")
    msg = str(exc.value)
    assert msg.startswith("crafted.vrm: ") and "\n" not in msg and len(msg) < 400, msg
    if "uri" in case:
        assert "self-contained" in msg
    if case == "deep JSON":
        assert f"deeper than {MAX_DEPTH}" in msg


@pytest.mark.parametrize("case", ["hips node a string", "bones a dict", "blendshape groups a dict", "bind mesh wrong"])
def test_crafted_vrm0_is_one_clear_user_error(vrm0, case):
    def fn(doc):
        v = doc["extensions"]["VRM"]
        if case == "hips node a string":
            next(b for b in v["humanoid"]["humanBones"] if b["bone"] == "hips")["node"] = "abc"
        elif case == "bones a dict":
            v["humanoid"]["humanBones"] = {"hips": 0}
        elif case == "blendshape groups a dict":
            v["blendShapeMaster"]["blendShapeGroups"] = {"a": 1}
        else:
            v["blendShapeMaster"]["blendShapeGroups"][0]["binds"] = [{"mesh": 999, "index": 0, "weight": 100}]
    with pytest.raises(UserError, match=r"crafted\.vrm: "):
        parse_model(_edit(vrm0, fn), "crafted.vrm")


def test_a_deep_node_chain_is_checked_without_recursion(vrm1):
    """The check walks the tree iteratively: 900 levels load; a 5,000-node chain, which three.js's loader
    cannot load (it recurses; issue 34), is refused before any browser starts (tests/test_trust_files.py)."""
    m = parse_model(_edit(vrm1, _chain(900)), "chain.vrm")
    assert m.info["nodes"] >= 900 and "hips" in m.bones
    with pytest.raises(UserError, match="nest more than 1000 levels deep"):
        parse_model(_edit(vrm1, _chain(5000)), "chain.vrm")


def test_a_valid_vrm_still_loads(vrm1, vrm0):
    assert parse_model(vrm1, "a.vrm").kind == "vrm1"
    assert parse_model(vrm0, "b.vrm").kind == "vrm0"


# ------------------------------------------------------------------ size first (item 6)
def test_a_large_fake_avatar_is_refused_unread(tmp_path):
    """A 600 MB (sparse) file is refused by its size, a 200 MB fake by its header: peak memory stays low."""
    big = tmp_path / "big.vrm"
    with big.open("wb") as f:
        f.truncate(MAX_FILE_BYTES + 1)
    fake = tmp_path / "fake.vrm"
    with fake.open("wb") as f:
        f.write(b"glTF" + (2).to_bytes(4, "little") + (1000).to_bytes(4, "little"))
        f.truncate(200 * 2**20)
    code = (
        "import resource, sys\n"
        "from facecapges.avatar.vrm.read import load_model\n"
        "from facecapges.errors import UserError\n"
        "before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
        "for p in sys.argv[1:]:\n"
        "    try:\n"
        "        load_model(p)\n"
        "    except UserError as e:\n"
        "        print(e)\n"
        "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before)\n"
    )
    r = subprocess.run([sys.executable, "-c", code, str(big), str(fake)], capture_output=True, text=True, timeout=120)
    lines = r.stdout.strip().splitlines()
    assert r.returncode == 0 and len(lines) == 3, r.stdout + r.stderr
    assert "larger than an avatar can be" in lines[0] and "header says 1000 bytes" in lines[1]
    assert int(lines[2]) < 20_000  # KiB: neither file was read into memory


# ------------------------------------------------------------------ the browser (item 1)
@pytest.mark.slow
def test_the_browser_fetches_nothing_outside_our_server(leak):
    """Request interception alone (the page comes from a server without CSP): the leak server is never hit."""
    from facecapges.avatar.render.browser import Browser

    html = (f"<img src='{leak.url}/leak-image.png'><script>fetch('{leak.url}/leak-fetch')"
            f".then(()=>window.done='fetched',()=>window.done='failed')</script>").encode()
    pages = LeakServer(html)
    try:
        with Browser({}, "/", 160, 120, timeout=60) as b:
            b.call("Page.navigate", url=f"{pages.url}/page.html")
            assert b.wait_for("window.done", timeout=30) == "failed"
            assert f"{leak.url}/leak-fetch" in b.blocked, b.blocked
        assert leak.hits == [] and pages.hits[0] == "/page.html"
        # the control: that origin allowed, the same page does reach the leak server (the check can fail)
        with Browser({}, "/", 160, 120, timeout=60) as b:
            b.origins.add(leak.url)
            b.call("Page.navigate", url=f"{pages.url}/page.html")
            assert b.wait_for("window.done", timeout=30) == "fetched"
        assert "/leak-fetch" in leak.hits
    finally:
        pages.close()


@pytest.mark.slow
def test_our_pages_carry_a_csp_that_blocks_other_origins(leak, tmp_path):
    """A page served by our renderer server cannot fetch from another origin (CSP), and says so."""
    from facecapges.avatar.render.browser import Browser
    from facecapges.io.static_files import CONTENT_SECURITY_POLICY

    html = (f"<html><body><script>fetch('{leak.url}/csp').then(()=>window.done='fetched',"
            f"()=>window.done='failed')</script></body></html>").encode()
    (tmp_path / "p.html").write_bytes(html)
    with Browser({"/t/": tmp_path}, "/t/p.html", 160, 120, timeout=60) as b:
        port = b.server.server_address[1]
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/t/p.html", timeout=10) as r:
            assert r.headers["Content-Security-Policy"] == CONTENT_SECURITY_POLICY
        b.origins.add(leak.url)  # interception would let it through: only the CSP stands in the way
        assert b.wait_for("window.done", timeout=30) == "failed"
    assert leak.hits == []


def _our_avatar_with(tmp_path, uri_kind: str, leak_url: str):
    import pygltflib

    from conftest import shared_file
    from facecapges.avatar.body import default_avatar
    from facecapges.avatar.gltf import avatar_to_gltf
    from facecapges.io.bvh import read_bvh

    skel = read_bvh(shared_file("data/beat/2_scott_0_1_1.bvh")).skeleton
    doc, binary = split_glb(b"".join(avatar_to_gltf(default_avatar(skel)).save_to_bytes()))
    if uri_kind == "image":
        doc.setdefault("images", []).append({"uri": f"{leak_url}/leak-image.png"})
        doc.setdefault("textures", []).append({"source": len(doc["images"]) - 1})
    else:
        doc["buffers"].append({"uri": "../../../../etc/passwd", "byteLength": 16})
    p = tmp_path / f"crafted-{uri_kind}.glb"
    p.write_bytes(join_glb(doc, binary))
    assert pygltflib.GLTF2.load_from_bytes(p.read_bytes())  # a file a glTF library reads as it is
    return p


@pytest.mark.parametrize("uri_kind", ["image", "buffer"])
def test_render_refuses_an_avatar_with_outside_uris(tmp_path, leak, beat_bvh, uri_kind):
    avatar = _our_avatar_with(tmp_path, uri_kind, leak.url)
    r = cli("render", "--bvh", str(beat_bvh), "--avatar", str(avatar), "--out", str(tmp_path / "o.mp4"), timeout=180)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-3000:]
    assert "self-contained" in r.stderr and not (tmp_path / "o.mp4").exists()
    time.sleep(0.2)
    assert leak.hits == []


def test_every_avatar_option_refuses_an_outside_uri(tmp_path, leak, vrm1, beat_bvh, beat_wav):
    """study create --avatar, live --avatar --web, live --vmc-avatar: the same one-line refusal."""
    from _study_media import make_clips

    crafted = tmp_path / "crafted.vrm"
    crafted.write_bytes(_edit(vrm1, CRAFTED_VRM1["image uri outside"]))
    with pytest.raises(UserError, match="self-contained"):
        load_model(crafted)
    y = make_clips(tmp_path / "src", beat_bvh, beat_wav, n_clips=2, seconds=1.0)
    runs = [
        ["study", "create", "--clips", str(y), "--out", str(tmp_path / "study"), "--participants", "2", "--avatar", str(crafted)],
        ["live", "--audio", str(beat_wav), "--web", "127.0.0.1:0", "--avatar", str(crafted), "--max-seconds", "1"],
        ["live", "--audio", str(beat_wav), "--vmc", "127.0.0.1:39599", "--vmc-avatar", str(crafted),
         "--max-seconds", "1"],
    ]
    for args in runs:
        r = cli(*args, timeout=180)
        assert r.returncode == 2 and "Traceback" not in r.stderr, (args, r.stderr[-3000:])
        assert "self-contained" in r.stderr, (args, r.stderr[-2000:])
    assert leak.hits == []
