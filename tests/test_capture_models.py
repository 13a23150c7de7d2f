"""Model bundle lookup, hash check and the canonical mesh inside it."""

from __future__ import annotations

import struct
import zipfile

import numpy as np
import pytest

from facecapges.capture import canonical_mesh as cm
from facecapges.capture import models
from facecapges.errors import UserError


@pytest.fixture(scope="module")
def task_path():
    try:
        return models.resolve_model()
    except UserError as exc:
        pytest.skip(str(exc))


def test_bundled_model_is_hash_checked(task_path):
    assert task_path == models.bundled_model_path()
    assert models.sha256_of(task_path) == models.TASK_SHA256


def test_missing_user_model_is_a_user_error(tmp_path):
    with pytest.raises(UserError, match="not found"):
        models.resolve_model(tmp_path / "nope.task")


def test_non_zip_and_incomplete_bundles_are_refused(tmp_path):
    bad = tmp_path / "bad.task"
    bad.write_bytes(b"not a zip")
    with pytest.raises(UserError, match=r"not a MediaPipe \.task bundle"):
        models.resolve_model(bad)
    part = tmp_path / "part.task"
    with zipfile.ZipFile(part, "w") as z:
        z.writestr("face_detector.tflite", b"x")
    with pytest.raises(UserError, match="missing"):
        models.resolve_model(part)


def test_canonical_mesh_from_bundle(task_path):
    mesh = cm.load_canonical_mesh(task_path)
    assert mesh.vertices.shape == (468, 3) and mesh.triangles.shape == (898, 3)
    assert mesh.triangles.min() == 0 and mesh.triangles.max() == 467
    # left/right mirror symmetry of the eye corners, X towards the subject's left
    np.testing.assert_allclose(mesh.vertices[263] * [-1, 1, 1], mesh.vertices[33], atol=1e-4)
    assert mesh.vertices[263, 0] > 0 and mesh.vertices[10, 1] > mesh.vertices[152, 1]  # forehead above chin
    assert mesh.vertices[1, 2] > mesh.vertices[234, 2]  # nose tip in front of the cheek
    assert len(mesh.procrustes_ids) == len(mesh.procrustes_weights) > 10
    assert np.all(mesh.procrustes_weights > 0)


def _varint(n: int) -> bytes:
    out = b""
    while True:
        b = n & 0x7F
        n >>= 7
        out += bytes([b | (0x80 if n else 0)])
        if not n:
            return out


def _ld(field: int, payload: bytes) -> bytes:
    return _varint(field << 3 | 2) + _varint(len(payload)) + payload


def test_wire_decoder_on_a_handmade_message():
    verts = np.arange(15, dtype="<f4")  # 3 vertices × (x, y, z, u, v)
    mesh = _varint(1 << 3 | 0) + _varint(0) + _ld(3, verts.tobytes()) + _ld(4, b"".join(_varint(i) for i in (0, 1, 2)))
    ref = _varint(1 << 3 | 0) + _varint(300) + _varint(2 << 3 | 5) + struct.pack("<f", 0.25)
    data = _ld(1, mesh) + _ld(2, ref) + _varint(3 << 3 | 0) + _varint(1)
    m = cm.parse_geometry_metadata(data)
    np.testing.assert_array_equal(m.vertices, [[0, 1, 2], [5, 6, 7], [10, 11, 12]])
    np.testing.assert_array_equal(m.uv, [[3, 4], [8, 9], [13, 14]])
    np.testing.assert_array_equal(m.triangles, [[0, 1, 2]])
    assert m.procrustes_ids.tolist() == [300] and m.procrustes_weights.tolist() == [0.25]
    with pytest.raises(ValueError):
        cm.parse_geometry_metadata(_ld(1, _ld(3, verts[:7].tobytes())))
