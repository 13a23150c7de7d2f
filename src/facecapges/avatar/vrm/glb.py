"""The glTF binary container VRM files use: split into / join from JSON + BIN, and node rest matrices."""

from __future__ import annotations

import json
import struct

import numpy as np

from facecapges.avatar.gltf_check import BIN_CHUNK, GLB_MAGIC, JSON_CHUNK, check_document, check_header, decode_json
from facecapges.errors import UserError
from facecapges.rotations import quaternion_to_matrix


def split_glb(data: bytes, name: str = "file") -> tuple[dict, bytes]:
    """A binary glTF's JSON (parsed and checked, :mod:`facecapges.avatar.gltf_check`) and its BIN chunk.

    UserError if ``data`` is not one, or is not a self-contained, well-formed glTF."""
    jlen = check_header(data[:20], len(data), name)
    doc = decode_json(data[20 : 20 + jlen], name)
    off = 20 + ((jlen + 3) & ~3)
    binary = b""
    if off + 8 <= len(data):
        blen, btype = struct.unpack_from("<II", data, off)
        if btype == BIN_CHUNK:
            binary = data[off + 8 : off + 8 + blen]
    check_document(doc, len(binary), name)
    return doc, binary


def join_glb(doc: dict, binary: bytes) -> bytes:
    """A binary glTF from its JSON and BIN chunk."""
    j = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    j += b" " * (-len(j) % 4)
    b = binary + b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<II", len(j), JSON_CHUNK) + j
    if b:
        chunks += struct.pack("<II", len(b), BIN_CHUNK) + b
    return GLB_MAGIC + struct.pack("<II", 2, 12 + len(chunks)) + chunks


def node_world_matrices(doc: dict) -> np.ndarray:
    """World matrices (N, 4, 4) of every node at rest (scene roots at the origin).

    Walked parents first without recursion (a long node chain is fine); the tree was checked
    by :func:`facecapges.avatar.gltf_check.check_document` (one parent per node, no cycle)."""
    nodes = doc.get("nodes") or []
    N = len(nodes)
    local = np.zeros((N, 4, 4))
    children: list[list[int]] = [[] for _ in range(N)]
    has_parent = np.zeros(N, bool)
    for i, n in enumerate(nodes):
        if "matrix" in n:
            local[i] = np.asarray(n["matrix"], float).reshape(4, 4).T
        else:
            m = np.eye(4)
            x, y, z, w = np.asarray(n.get("rotation", [0, 0, 0, 1]), float)  # glTF stores (x, y, z, w)
            m[:3, :3] = quaternion_to_matrix(np.array([w, x, y, z])) * np.asarray(n.get("scale", [1, 1, 1]), float)
            m[:3, 3] = n.get("translation", [0, 0, 0])
            local[i] = m
        for c in n.get("children", []):
            if 0 <= c < N and not has_parent[c]:
                children[i].append(c)
                has_parent[c] = True
    world = np.full((N, 4, 4), np.nan)
    stack = [int(i) for i in np.flatnonzero(~has_parent)]
    for i in stack:
        world[i] = local[i]
    while stack:
        i = stack.pop()
        for c in children[i]:
            world[c] = world[i] @ local[c]
            stack.append(c)
    if np.isnan(world[:, 0, 0]).any():
        raise UserError("the glTF node tree has a cycle")
    return world
