"""The 52 ARKit blendshapes of the canonical face, the control table, the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from facecapges.arkit import ARKIT_NAMES
from facecapges.avatar import blendshape_table as bt
from facecapges.avatar.blendshapes import AVATAR_CACHE_ENV, arkit_blendshapes
from facecapges.avatar.mesh import TriMesh, canonical_face, read_obj, write_obj
from facecapges.errors import UserError
from runtime_helpers import cli


@pytest.fixture(scope="module")
def shapes():
    return arkit_blendshapes(compare=True)


def _target(shapes, name):
    return shapes.targets[shapes.names.index(name)]


def test_the_suites_avatar_cache_gives_the_built_targets_bit_for_bit(shapes, tmp_path, monkeypatch):
    """$FACECAPGES_AVATAR_CACHE (the suite's, tests/conftest.py): the first call builds and keeps the targets, the
    next reads them back — the same bytes as a build (``shapes``: built with ``compare``, so never from a cache)."""
    import pickle

    monkeypatch.setenv(AVATAR_CACHE_ENV, str(tmp_path))
    first = arkit_blendshapes()
    kept = list(tmp_path.glob("arkit-*.pickle"))
    assert len(kept) == 1 and not list(tmp_path.glob("*.part"))
    again = arkit_blendshapes()
    for got in (first, again):
        assert got.names == shapes.names and got.targets.tobytes() == shapes.targets.tobytes()
        assert got.neutral.vertices.tobytes() == shapes.neutral.vertices.tobytes()
        assert got.neutral.faces.tobytes() == shapes.neutral.faces.tobytes()
    changed = pickle.loads(kept[0].read_bytes())
    changed.targets[:] = 0.0
    kept[0].write_bytes(pickle.dumps(changed))
    assert not arkit_blendshapes().targets.any()  # read from the folder, not built again


def test_canonical_face_is_the_468_vertex_mediapipe_mesh():
    m = canonical_face()
    assert m.vertices.shape == (468, 3) and m.faces.shape == (898, 3)
    # +X is the subject's left: landmark 263 (left eye outer corner) has x > 0
    assert m.vertices[263, 0] > 0 > m.vertices[33, 0]


def test_shipped_table_is_what_the_authoring_rules_write():
    doc = json.loads(bt.default_table_path().read_text())
    assert doc == json.loads(json.dumps(bt.author_arkit_table(canonical_face().vertices)))
    assert list(doc["targets"]) == list(ARKIT_NAMES)


def test_all_52_targets_reach_their_controls_and_aoi_keeps_far_vertices_still(shapes):
    r = shapes.report
    assert shapes.names == list(ARKIT_NAMES) and shapes.targets.shape == (52, 468, 3)
    assert r["max_control_error"] <= 1e-4
    assert r["mean_far_motion_aoi"] < r["mean_far_motion_no_aoi"]
    assert r["targets_where_aoi_moves_far_less"] >= 0.9 * r["targets_compared"]
    # every target actually moves the face, and only a part of it
    moved = np.linalg.norm(shapes.deltas(), axis=2)
    assert np.all(moved.max(axis=1) > 0.05)  # > 0.5 mm somewhere (cm)


def test_arkit_semantics(shapes):
    V = shapes.neutral.vertices
    d = lambda name: _target(shapes, name) - V  # noqa: E731
    up_l, up_r = 386, 159  # upper lid centres: subject's left (+X) and right
    # eyeBlinkLeft closes the subject's left eye: its upper lid comes down to the lower lid
    assert d("eyeBlinkLeft")[up_l, 1] < -0.5 * (V[386, 1] - V[374, 1])
    assert abs(d("eyeBlinkLeft")[up_r, 1]) < 0.02
    assert d("eyeBlinkRight")[up_r, 1] < -0.5 * (V[159, 1] - V[145, 1])
    # jawOpen drops the chin and the lower lip, the upper lip stays
    assert d("jawOpen")[152, 1] < -1.0 and d("jawOpen")[14, 1] < -0.5 and abs(d("jawOpen")[13, 1]) < 0.05
    # smiles raise their own corner (left = +X)
    assert d("mouthSmileLeft")[291, 1] > 0.3 and abs(d("mouthSmileLeft")[61, 1]) < 0.05
    assert d("mouthSmileRight")[61, 1] > 0.3
    # jawLeft moves the jaw to the subject's left, mouthRight the mouth to the right
    assert d("jawLeft")[152, 0] > 0.3 and d("mouthRight")[0, 0] < -0.3
    # brows
    assert d("browInnerUp")[107, 1] > 0.3 and d("browDownLeft")[334, 1] < -0.2
    assert d("browOuterUpRight")[70, 1] > 0.3 and abs(d("browOuterUpRight")[300, 1]) < 0.02
    # pucker pushes the lips forward
    assert d("mouthPucker")[0, 2] > 0.3
    # left/right pairs are mirror images of each other
    mirror = np.argmin(np.linalg.norm(V[:, None] - V[None] * [-1, 1, 1], axis=2), axis=1)
    a, b = d("mouthFrownLeft"), d("mouthFrownRight")
    assert np.allclose(a, b[mirror] * [-1, 1, 1], atol=1e-3)


def test_table_validation_errors():
    ok = {"controls": [0, 1], "targets": {"x": {"1": [0, 0, 1]}}}
    bt.parse_table(ok, 10)
    bad = [
        ({"controls": [0, 12], "targets": {"x": {}}}, "out of range"),
        ({"controls": [0], "targets": {"x": {"3": [0, 0, 1]}}}, "not listed"),
        ({"controls": [0], "targets": {"x": {"0": [0, 1]}}}, "finite"),
        ({"controls": [0, 0], "targets": {"x": {}}}, "twice"),
        ({"controls": [0], "targets": {"x": {"-1": [0, 0, 1]}}}, "out of range"),
        ({"n_vertices": 468, "controls": [0], "targets": {"x": {}}}, "468"),
        ({"targets": {}}, "not a control table"),
    ]
    for doc, msg in bad:
        with pytest.raises(UserError, match=msg):
            bt.parse_table(doc, 10)


def _cli(*args):
    return cli(*map(str, args))


def test_blendshapes_cli_on_any_mesh_and_table(tmp_path):
    # a small open grid (not a face): any neutral mesh with any table works
    n = 8
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    V = np.stack([x.ravel(), y.ravel(), 0.1 * np.sin(3 * x.ravel())], 1)
    F = [[i * n + j, i * n + j + 1, (i + 1) * n + j + 1] for i in range(n - 1) for j in range(n - 1)]
    F += [[i * n + j, (i + 1) * n + j + 1, (i + 1) * n + j] for i in range(n - 1) for j in range(n - 1)]
    mesh = write_obj(tmp_path / "neutral.obj", TriMesh(V, np.asarray(F)))
    border = [i for i in range(n * n) if i % n in (0, n - 1) or i // n in (0, n - 1)]
    table = tmp_path / "t.json"
    table.write_text(json.dumps({"controls": border + [27], "targets": {"up": {"27": [0, 0, 0.2]},
                                                                        "side": {"27": [0.05, 0, 0]}}}))
    out = tmp_path / "out"
    r = _cli("blendshapes", "--mesh", mesh, "--controls", table, "--out", out)
    assert r.returncode == 0, r.stderr
    up = read_obj(out / "up.obj")
    assert np.allclose(up.vertices[27], V[27] + [0, 0, 0.2], atol=1e-5)
    report = json.loads((out / "report.json").read_text())
    assert report["n_targets"] == 2 and report["max_control_error"] <= 1e-4
    assert {"mean_far_motion_aoi", "mean_far_motion_no_aoi"} <= set(report)
    # no overwrite without --force; --no-aoi works
    r = _cli("blendshapes", "--mesh", mesh, "--controls", table, "--out", out)
    assert r.returncode == 2 and "--force" in r.stderr
    r = _cli("blendshapes", "--mesh", mesh, "--controls", table, "--out", out, "--force", "--no-aoi")
    assert r.returncode == 0, r.stderr
    # control index out of range: clear message, exit 2
    table.write_text(json.dumps({"controls": [64], "targets": {"up": {"64": [0, 0, 1]}}}))
    r = _cli("blendshapes", "--mesh", mesh, "--controls", table, "--out", tmp_path / "o2")
    assert r.returncode == 2 and "out of range" in r.stderr and "Traceback" not in r.stderr
