"""MediaPipe's canonical face mesh, read from the ``face_landmarker.task`` bundle.

The bundle member ``geometry_pipeline_metadata_landmarks.binarypb`` is a serialized
``mediapipe.tasks.vision.face_geometry.proto.GeometryPipelineMetadata`` message::

    message GeometryPipelineMetadata {
      optional Mesh3d canonical_mesh = 1;
      repeated WeightedLandmarkRef procrustes_landmark_basis = 2;  // {landmark_id=1 uint32, weight=2 float}
      optional InputSource input_source = 3;
    }
    message Mesh3d {
      optional VertexType vertex_type = 1;         // VERTEX_PT: x, y, z, u, v per vertex
      optional PrimitiveType primitive_type = 2;   // TRIANGLE
      repeated float vertex_buffer = 3 [packed];
      repeated uint32 index_buffer = 4 [packed];
    }

No protobuf runtime is installed (mediapipe 1.2.2 no longer depends on it), so the
few wire-format rules needed (varints, length-delimited fields, fixed32 floats,
packed repeated fields) are decoded here directly.

Convention: vertices are in **centimetres**, right-handed, Y up, +Z out of the face
(towards a camera the face looks at), X towards the subject's left. Mesh indices
0–467 are the indices of MediaPipe's 478 face landmarks (468–477 are the irises,
which the canonical mesh does not have).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from facecapges.capture.models import GEOMETRY_MEMBER, read_member
from facecapges.errors import file_error

N_MESH_VERTICES = 468


@dataclass(frozen=True)
class CanonicalMesh:
    """The canonical face: ``vertices`` (468, 3) cm, ``uv`` (468, 2), ``triangles`` (F, 3) int.

    ``procrustes_ids`` / ``procrustes_weights`` are the landmarks (and weights) MediaPipe
    itself uses for its rigid head-pose fit (the stable, mostly non-expressive points).
    """

    vertices: np.ndarray
    uv: np.ndarray
    triangles: np.ndarray
    procrustes_ids: np.ndarray
    procrustes_weights: np.ndarray


# ------------------------------------------------------------ protobuf wire format
def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    result = shift = 0
    while True:
        if pos >= len(buf):
            raise ValueError("truncated varint")
        b = buf[pos]
        pos += 1
        result |= (b & 0x7F) << shift
        if not b & 0x80:
            return result, pos
        shift += 7


def _fields(buf: bytes) -> list[tuple[int, int, int | bytes]]:
    """(field number, wire type, value) for every field of one message, in order.

    Value is an int for varints, bytes for length-delimited fields and the raw 4/8
    bytes for fixed32/fixed64.
    """
    out: list[tuple[int, int, int | bytes]] = []
    pos = 0
    value: int | bytes
    while pos < len(buf):
        key, pos = _varint(buf, pos)
        field, wire = key >> 3, key & 7
        if wire == 0:
            value, pos = _varint(buf, pos)
        elif wire == 1:
            value, pos = buf[pos : pos + 8], pos + 8
        elif wire == 2:
            n, pos = _varint(buf, pos)
            value, pos = buf[pos : pos + n], pos + n
        elif wire == 5:
            value, pos = buf[pos : pos + 4], pos + 4
        else:
            raise ValueError(f"unsupported wire type {wire}")
        if pos > len(buf):
            raise ValueError("truncated field")
        out.append((field, wire, value))
    return out


def _packed_varints(data: bytes) -> list[int]:
    vals, pos = [], 0
    while pos < len(data):
        v, pos = _varint(data, pos)
        vals.append(v)
    return vals


def parse_geometry_metadata(data: bytes) -> CanonicalMesh:
    """Decode a serialized GeometryPipelineMetadata into a :class:`CanonicalMesh`."""
    ids, weights = [], []
    vbuf: list[float] = []
    ibuf: list[int] = []
    for field, wire, value in _fields(data):
        if field == 2 and wire == 2 and isinstance(value, bytes):
            lid, w = 0, 0.0
            for f2, w2, v2 in _fields(value):
                if f2 == 1 and isinstance(v2, int):  # wire 0
                    lid = v2
                elif f2 == 2 and w2 == 5 and isinstance(v2, bytes):
                    w = struct.unpack("<f", v2)[0]
            ids.append(lid)
            weights.append(w)
        elif field == 1 and wire == 2 and isinstance(value, bytes):
            for f2, w2, v2 in _fields(value):
                if isinstance(v2, int):  # wire 0: a varint
                    if f2 == 4:
                        ibuf.append(v2)
                elif f2 == 3 and w2 == 2:  # packed floats
                    vbuf.extend(np.frombuffer(v2, "<f4").tolist())
                elif f2 == 3 and w2 == 5:  # unpacked float
                    vbuf.append(struct.unpack("<f", v2)[0])
                elif f2 == 4 and w2 == 2:
                    ibuf.extend(_packed_varints(v2))
    if len(vbuf) % 5 or len(ibuf) % 3 or not vbuf:
        raise ValueError(f"unexpected canonical mesh sizes: {len(vbuf)} vertex floats, {len(ibuf)} indices")
    v = np.asarray(vbuf, np.float64).reshape(-1, 5)
    tris = np.asarray(ibuf, np.int64).reshape(-1, 3)
    if tris.size and tris.max() >= len(v):
        raise ValueError("triangle index out of range")
    return CanonicalMesh(
        v[:, :3].copy(), v[:, 3:].copy(), tris, np.asarray(ids, np.int64), np.asarray(weights, np.float64)
    )


@lru_cache(maxsize=4)
def load_canonical_mesh(task_path: str | Path) -> CanonicalMesh:
    """The canonical mesh inside a face_landmarker.task bundle (cached per path)."""
    data = read_member(task_path, GEOMETRY_MEMBER)
    try:
        mesh = parse_geometry_metadata(data)
    except ValueError as exc:
        raise file_error(task_path, f"cannot parse {GEOMETRY_MEMBER}: {exc}") from None
    if len(mesh.vertices) != N_MESH_VERTICES:
        raise file_error(task_path, f"canonical mesh has {len(mesh.vertices)} vertices, expected {N_MESH_VERTICES}")
    return mesh
