"""The trust boundary of every avatar file we load: a binary glTF (``.glb`` / ``.vrm``) from outside.

One place checks what a VRM / GLB brings before Python uses it or a browser is started on
it (``render``, ``run``, ``live --avatar``, ``live --vmc-avatar``, ``study create --avatar``):

* **Size first** (:func:`read_avatar_file`): the 20-byte header and the JSON chunk are read and
  checked before the rest; a file over :data:`MAX_FILE_BYTES`, a header whose length is not the
  file's, or a JSON chunk over :data:`MAX_JSON_BYTES` is refused without reading it whole.
* **Self-contained** (:func:`check_document`): every ``uri`` anywhere in the JSON (buffers,
  images, extensions) must be a ``data:`` URI; buffers without one are the BIN chunk. A file
  that names an outside resource (``http://…``, ``../../etc/passwd``) is refused with one
  message — nothing is ever fetched for it.
* **Types and ranges**: the glTF arrays are lists of objects, every index (node, mesh, skin,
  accessor, buffer view, buffer, image, texture, material, sampler) is an integer inside its
  array, buffer views lie inside their buffers and accessors inside their views, node
  transforms are finite numbers of the right count, every node has at most one parent and
  the node graph has no cycle (walked iteratively: a 5,000-node chain is fine), and the VRM
  0.x / 1.0 humanoid and expression entries have the types the reader and three-vrm use.
  The JSON's nesting is bounded (:data:`MAX_DEPTH`) before it is decoded.

Each failure is a :class:`~facecapges.errors.UserError` naming the file and the field.
"""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path

from facecapges.errors import UserError, file_error, require_file

MAX_FILE_BYTES = 512 * 1024 * 1024  # a VRM is a few to ~100 MB; past this it is refused unread
MAX_JSON_BYTES = 64 * 1024 * 1024
MAX_DEPTH = 64  # nesting of the glTF JSON (real files stay under ~12)
MAX_ITEMS = 1_000_000  # entries of one glTF array
#: Levels of the node tree. three.js 0.187's GLTFLoader (loadNode → _loadNodeShallow) recurses once per
#: level: in headless Chromium 156 a VRM with a chain of 1,850 nodes under its head loads and one of 2,150
#: fails with "Maximum call stack size exceeded" (scripts in the report of issue 34). Real avatars nest
#: 10–60 levels (hair and skirt chains); the cap leaves half of the measured limit for other call frames.
MAX_NODE_DEPTH = 1000
THREE_DEPTH_LIMIT = "2,000"
GLB_MAGIC = b"glTF"
JSON_CHUNK = 0x4E4F534A
BIN_CHUNK = 0x004E4942

ARRAYS = (
    "accessors",
    "animations",
    "bufferViews",
    "buffers",
    "cameras",
    "images",
    "materials",
    "meshes",
    "nodes",
    "samplers",
    "scenes",
    "skins",
    "textures",
)
COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
TYPE_COUNT = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


def read_avatar_file(path: str | Path, what: str = "avatar") -> bytes:
    """The bytes of a binary glTF file, its size checked before it is read whole (module docstring)."""
    p = require_file(path, what)
    size = p.stat().st_size
    if size > MAX_FILE_BYTES:
        raise file_error(p, f"{size / 2**20:.0f} MB is larger than an avatar can be ({MAX_FILE_BYTES // 2**20} MB)")
    with p.open("rb") as f:
        head = f.read(20)
        check_header(head, size, str(p))
        return head + f.read(size - 20)


def check_header(head: bytes, size: int, name: str) -> int:
    """Check a GLB's 20 first bytes against the file's ``size``; returns the JSON chunk's length."""
    if len(head) < 20 or head[:4] != GLB_MAGIC:
        raise UserError(f"{name}: not a VRM or binary glTF file (.vrm/.glb); no glTF header")
    version, length = struct.unpack_from("<II", head, 4)
    if version != 2:
        raise UserError(f"{name}: glTF version {version}; only glTF 2.0 (VRM 0.x and 1.0) is supported")
    if length != size:
        raise UserError(f"{name}: broken binary glTF (its header says {length} bytes, the file has {size})")
    jlen, jtype = struct.unpack_from("<II", head, 12)
    if jtype != JSON_CHUNK or 20 + jlen > size:
        raise UserError(f"{name}: broken binary glTF (no JSON chunk)")
    if jlen > MAX_JSON_BYTES:
        raise UserError(f"{name}: its glTF JSON is {jlen / 2**20:.0f} MB (at most {MAX_JSON_BYTES // 2**20} MB)")
    return jlen


def decode_json(raw: bytes, name: str) -> dict:
    """The glTF JSON chunk as a dict; nesting bounded before decoding (module docstring)."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise UserError(f"{name}: broken binary glTF JSON (not UTF-8)") from None
    depth = deepest = 0
    in_str = esc = False
    for ch in text:  # brackets outside strings: the nesting depth, without recursion
        if in_str:
            if esc:
                esc = False
            elif ch == "\\":
                esc = True
            elif ch == '"':
                in_str = False
        elif ch == '"':
            in_str = True
        elif ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
            if deepest > MAX_DEPTH:
                raise UserError(f"{name}: broken binary glTF JSON (nested deeper than {MAX_DEPTH})")
        elif ch in "]}":
            depth -= 1
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise UserError(f"{name}: broken binary glTF JSON ({str(exc)[:120]})") from None
    if not isinstance(doc, dict):
        raise UserError(f"{name}: broken binary glTF JSON (not an object)")
    return doc


# ------------------------------------------------------------------ document
class _Doc:
    """Typed access to a glTF JSON: each getter raises a UserError naming the field."""

    def __init__(self, doc: dict, name: str):
        self.doc, self.name = doc, name

    def fail(self, where: str, problem: str) -> UserError:
        return UserError(f"{self.name}: invalid glTF: {where} {problem}")

    def array(self, key: str) -> list:
        v = self.doc.get(key, [])
        if not isinstance(v, list) or len(v) > MAX_ITEMS or not all(isinstance(x, dict) for x in v):
            raise self.fail(key, f"must be a list of objects (at most {MAX_ITEMS})")
        return v

    def obj(self, parent: dict, key: str, where: str) -> dict:
        v = parent.get(key, {})
        if not isinstance(v, dict):
            raise self.fail(f"{where}.{key}" if where else key, "must be an object")
        return v

    def index(self, value, array: str, where: str, optional: bool = True) -> int | None:
        if value is None and optional:
            return None
        n = len(self.doc.get(array) or [])
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < n:
            raise self.fail(where, f"= {str(value)[:40]!r} is not an index into {array} (0…{n - 1})")
        return value

    def count(self, value, where: str, lo: int = 0) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < lo:
            raise self.fail(where, f"= {str(value)[:40]!r} must be an integer ≥ {lo}")
        return value

    def numbers(self, value, n: int, where: str) -> None:
        ok = isinstance(value, list) and len(value) == n
        if not ok or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value
        ):
            raise self.fail(where, f"must be {n} finite numbers")


def check_document(doc: dict, bin_len: int, name: str) -> None:
    """Check a glTF JSON (with a BIN chunk of ``bin_len`` bytes) as the module docstring says."""
    d = _Doc(doc, name)
    for key in ARRAYS:
        d.array(key)
    for key in ("extensions", "extras", "asset"):
        d.obj(doc, key, "")
    for key in ("extensionsUsed", "extensionsRequired"):
        v = doc.get(key, [])
        if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
            raise d.fail(key, "must be a list of names")
    _check_uris(doc, name)
    _check_buffers(d, bin_len)
    _check_nodes(d)
    _check_meshes(d)
    _check_others(d)
    _check_vrm(d)


def _check_uris(doc: dict, name: str) -> None:
    stack: list = [doc]
    while stack:  # every "uri" anywhere (buffers, images, extensions): data: only
        v = stack.pop()
        if isinstance(v, dict):
            for k, x in v.items():
                if k == "uri" and not (isinstance(x, str) and x[:5].lower() == "data:"):
                    raise UserError(
                        f"{name}: refers to an outside file or address ({str(x)[:80]!r}); an avatar must be "
                        f"self-contained (its data in the file's BIN chunk or in data: URIs): re-export it as "
                        f"one .vrm/.glb with embedded textures"
                    )
                stack.append(x)
        elif isinstance(v, list):
            stack.extend(v)


def _check_buffers(d: _Doc, bin_len: int) -> None:
    lengths = []
    for i, b in enumerate(d.array("buffers")):
        n = d.count(b.get("byteLength"), f"buffers[{i}].byteLength", 1)
        if "uri" not in b and n > bin_len:
            raise d.fail(f"buffers[{i}]", f"is {n} bytes, the file's BIN chunk only {bin_len}")
        lengths.append(n)
    views = d.array("bufferViews")
    for i, v in enumerate(views):
        w = f"bufferViews[{i}]"
        buf = d.index(v.get("buffer"), "buffers", f"{w}.buffer", optional=False)
        assert buf is not None
        off = d.count(v.get("byteOffset", 0), f"{w}.byteOffset")
        n = d.count(v.get("byteLength"), f"{w}.byteLength", 1)
        if off + n > lengths[buf]:
            raise d.fail(w, f"({off}+{n} bytes) lies outside buffer {buf} ({lengths[buf]} bytes)")
        if "byteStride" in v:
            s = d.count(v["byteStride"], f"{w}.byteStride", 4)
            if s > 252 or s % 4:
                raise d.fail(f"{w}.byteStride", "must be a multiple of 4 within 4…252")
    for i, a in enumerate(d.array("accessors")):
        w = f"accessors[{i}]"
        size = COMPONENT_BYTES.get(a.get("componentType"), 0) * TYPE_COUNT.get(a.get("type"), 0)
        if not size:
            raise d.fail(w, "has an unknown componentType or type")
        cnt = d.count(a.get("count"), f"{w}.count", 1)
        if "sparse" in a:
            raise d.fail(w, "is sparse (not supported in avatars)")
        view = d.index(a.get("bufferView"), "bufferViews", f"{w}.bufferView")
        if view is not None:
            off = d.count(a.get("byteOffset", 0), f"{w}.byteOffset")
            stride = views[view].get("byteStride", size)
            if off + stride * (cnt - 1) + size > views[view]["byteLength"]:
                raise d.fail(w, f"({cnt} × {size} bytes) does not fit in bufferView {view}")


def _check_nodes(d: _Doc) -> None:
    nodes = d.array("nodes")
    parent = [-1] * len(nodes)
    for i, n in enumerate(nodes):
        w = f"nodes[{i}]"
        for key, k in (("translation", 3), ("rotation", 4), ("scale", 3), ("matrix", 16)):
            if key in n:
                d.numbers(n[key], k, f"{w}.{key}")
        for key, arr in (("mesh", "meshes"), ("skin", "skins"), ("camera", "cameras")):
            d.index(n.get(key), arr, f"{w}.{key}")
        if not isinstance(n.get("name", ""), str):
            raise d.fail(f"{w}.name", "must be a string")
        children = n.get("children", [])
        if not isinstance(children, list):
            raise d.fail(f"{w}.children", "must be a list")
        for c in children:
            d.index(c, "nodes", f"{w}.children", optional=False)
            if parent[c] >= 0 or c == i:
                raise d.fail(f"{w}.children", f"node {c} has two parents (the node tree must be a tree)")
            parent[c] = i
    # a node on or below a cycle has no root: one walk down from the roots reaches every other node once
    below: list[list[int]] = [[] for _ in nodes]
    for c, p in enumerate(parent):
        if p >= 0:
            below[p].append(c)
    reached = [False] * len(nodes)
    todo = [(i, 1) for i, p in enumerate(parent) if p < 0]
    while todo:
        j, depth = todo.pop()
        if depth > MAX_NODE_DEPTH:  # three.js's GLTFLoader loads a node's children recursively
            raise d.fail(
                "nodes",
                f"nest more than {MAX_NODE_DEPTH} levels deep (node {j}); the browser's glTF loader recurses "
                f"through the tree and fails near {THREE_DEPTH_LIMIT}: flatten the node hierarchy",
            )
        reached[j] = True
        todo.extend((c, depth + 1) for c in below[j])
    if not all(reached):
        raise d.fail("nodes", f"form a cycle (node {reached.index(False)})")
    for i, s in enumerate(d.array("scenes")):
        for n in s.get("nodes", []) if isinstance(s.get("nodes", []), list) else [None]:
            d.index(n, "nodes", f"scenes[{i}].nodes", optional=False)
    d.index(d.doc.get("scene"), "scenes", "scene")
    for i, sk in enumerate(d.array("skins")):
        joints = sk.get("joints")
        if not isinstance(joints, list) or not joints:
            raise d.fail(f"skins[{i}].joints", "must be a non-empty list")
        for j in joints:
            d.index(j, "nodes", f"skins[{i}].joints", optional=False)
        d.index(sk.get("inverseBindMatrices"), "accessors", f"skins[{i}].inverseBindMatrices")
        d.index(sk.get("skeleton"), "nodes", f"skins[{i}].skeleton")


def _check_meshes(d: _Doc) -> None:
    for i, m in enumerate(d.array("meshes")):
        prims = m.get("primitives")
        if not isinstance(prims, list) or not prims or not all(isinstance(p, dict) for p in prims):
            raise d.fail(f"meshes[{i}].primitives", "must be a non-empty list of objects")
        for k, p in enumerate(prims):
            w = f"meshes[{i}].primitives[{k}]"
            attrs = d.obj(p, "attributes", w)
            targets = p.get("targets", [])
            if not isinstance(targets, list) or not all(isinstance(t, dict) for t in targets):
                raise d.fail(f"{w}.targets", "must be a list of objects")
            for group in (attrs, *targets):
                for key, acc in group.items():
                    d.index(acc, "accessors", f"{w}.{key}", optional=False)
            d.index(p.get("indices"), "accessors", f"{w}.indices")
            d.index(p.get("material"), "materials", f"{w}.material")
            if p.get("mode", 4) not in range(7):
                raise d.fail(f"{w}.mode", "must be 0…6")
        names = d.obj(m, "extras", f"meshes[{i}]").get("targetNames", [])
        if not isinstance(names, list):
            raise d.fail(f"meshes[{i}].extras.targetNames", "must be a list")


def _check_others(d: _Doc) -> None:
    for i, t in enumerate(d.array("textures")):
        d.index(t.get("source"), "images", f"textures[{i}].source")
        d.index(t.get("sampler"), "samplers", f"textures[{i}].sampler")
    for i, im in enumerate(d.array("images")):
        d.index(im.get("bufferView"), "bufferViews", f"images[{i}].bufferView")
        if not isinstance(im.get("mimeType", ""), str):
            raise d.fail(f"images[{i}].mimeType", "must be a string")
    stack: list = [(f"materials[{i}]", m) for i, m in enumerate(d.array("materials"))]
    while stack:  # every {"index": …} under a *Texture key points at a texture
        where, v = stack.pop()
        if isinstance(v, dict):
            for k, x in v.items():
                if k.endswith("Texture") or k.endswith("texture"):
                    if not isinstance(x, dict):
                        raise d.fail(f"{where}.{k}", "must be an object")
                    d.index(x.get("index"), "textures", f"{where}.{k}.index", optional=False)
                stack.append((f"{where}.{k}", x))
        elif isinstance(v, list):
            stack.extend((where, x) for x in v)
    for i, a in enumerate(d.array("animations")):
        for key in ("channels", "samplers"):
            if not isinstance(a.get(key), list) or not all(isinstance(x, dict) for x in a[key]):
                raise d.fail(f"animations[{i}].{key}", "must be a list of objects")
        for s in a["samplers"]:
            d.index(s.get("input"), "accessors", f"animations[{i}].samplers.input", optional=False)
            d.index(s.get("output"), "accessors", f"animations[{i}].samplers.output", optional=False)
        for c in a["channels"]:
            d.index(
                d.obj(c, "target", f"animations[{i}].channels").get("node"),
                "nodes",
                f"animations[{i}].channels.target.node",
            )
            if not isinstance(c.get("sampler"), int) or not 0 <= c["sampler"] < len(a["samplers"]):
                raise d.fail(f"animations[{i}].channels.sampler", "is not an index into its samplers")


def _check_vrm(d: _Doc) -> None:
    ext = d.obj(d.doc, "extensions", "")
    if "VRMC_vrm" in ext:
        v = d.obj(ext, "VRMC_vrm", "extensions")
        for key in ("meta", "humanoid", "expressions"):
            d.obj(v, key, "VRMC_vrm")
        _check_vrm1_meta(d, v)
        bones = d.obj(d.obj(v, "humanoid", "VRMC_vrm"), "humanBones", "VRMC_vrm.humanoid")
        for b, e in bones.items():
            if not isinstance(e, dict):
                raise d.fail(f"VRMC_vrm.humanoid.humanBones.{b}", "must be an object")
            d.index(e.get("node"), "nodes", f"VRMC_vrm.humanoid.humanBones.{b}.node", optional=False)
        ex = d.obj(v, "expressions", "VRMC_vrm")
        for group in ("preset", "custom"):
            for n, e in d.obj(ex, group, "VRMC_vrm.expressions").items():
                w = f"VRMC_vrm.expressions.{group}.{n}"
                if not isinstance(e, dict):
                    raise d.fail(w, "must be an object")
                binds = e.get("morphTargetBinds", [])
                if not isinstance(binds, list) or not all(isinstance(b, dict) for b in binds):
                    raise d.fail(f"{w}.morphTargetBinds", "must be a list of objects")
                for b in binds:
                    d.index(b.get("node"), "nodes", f"{w}.morphTargetBinds.node", optional=False)
                    d.count(b.get("index"), f"{w}.morphTargetBinds.index")
    if "VRM" in ext:
        v = d.obj(ext, "VRM", "extensions")
        for key in ("meta", "humanoid", "blendShapeMaster"):
            d.obj(v, key, "VRM")
        bones = d.obj(v, "humanoid", "VRM").get("humanBones", [])
        if not isinstance(bones, list) or not all(isinstance(b, dict) for b in bones):
            raise d.fail("VRM.humanoid.humanBones", "must be a list of objects")
        for b in bones:
            if not isinstance(b.get("bone"), str):
                raise d.fail("VRM.humanoid.humanBones.bone", "must be a name")
            d.index(b.get("node"), "nodes", f"VRM.humanoid.humanBones.{b['bone'][:40]}.node", optional=False)
        groups = d.obj(v, "blendShapeMaster", "VRM").get("blendShapeGroups", [])
        if not isinstance(groups, list) or not all(isinstance(g, dict) for g in groups):
            raise d.fail("VRM.blendShapeMaster.blendShapeGroups", "must be a list of objects")
        for g in groups:
            for key in ("name", "presetName"):
                if not isinstance(g.get(key, ""), str):
                    raise d.fail(f"VRM.blendShapeMaster.blendShapeGroups.{key}", "must be a string")
            binds = g.get("binds", [])
            if not isinstance(binds, list) or not all(isinstance(b, dict) for b in binds):
                raise d.fail("VRM.blendShapeMaster.blendShapeGroups.binds", "must be a list of objects")
            for b in binds:
                d.index(b.get("mesh"), "meshes", "VRM.blendShapeMaster.blendShapeGroups.binds.mesh", optional=False)
                d.count(b.get("index"), "VRM.blendShapeMaster.blendShapeGroups.binds.index")


def _check_vrm1_meta(d: _Doc, v: dict) -> None:
    """What @pixiv/three-vrm 3.5's loader requires of a VRM 1.0 (``VRMMetaLoaderPlugin._v1Import``, with
    the default options our pages use): the extension listed in ``extensionsUsed`` (else it ignores the
    VRM), and a ``meta`` whose ``licenseUrl`` is exactly :data:`facecapges.avatar.vrm.meta.LICENSE_URL`
    (its only accepted URL; anything else, or none, throws "The license url … is not accepted")."""
    from facecapges.avatar.vrm.meta import LICENSE_URL

    if "VRMC_vrm" not in d.doc.get("extensionsUsed", []):
        raise d.fail("extensionsUsed", "does not list VRMC_vrm (three-vrm would not read the VRM)")
    if v.get("specVersion") not in ("1.0", "1.0-beta") or v.get("meta") is None:
        return  # refused by the reader (version), or no meta: three-vrm reads none
    url = v["meta"].get("licenseUrl")
    if url != LICENSE_URL:
        raise d.fail(
            "VRMC_vrm.meta.licenseUrl",
            f"is {str(url)[:80]!r}; a VRM 1.0 must name {LICENSE_URL!r} (three-vrm refuses any other): "
            "re-export it with a VRM 1.0 exporter",
        )
