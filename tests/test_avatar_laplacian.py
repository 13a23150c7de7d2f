"""AOI Laplacian deformation (seed 2, sec. 4) and the mesh checks it relies on."""

from __future__ import annotations

import numpy as np
import pytest

from facecapges.avatar.laplacian import (
    LaplacianDeformer,
    cotangent_laplacian,
    cotangent_weights,
    deformation_factors,
    spread_displacements,
)
from facecapges.avatar.mesh import TriMesh, check_manifold, read_obj, write_obj
from facecapges.errors import UserError
from runtime_helpers import cli


def grid(n: int = 9, bump: float = 0.0) -> TriMesh:
    """An n×n vertex grid in the XY plane (z = bump·paraboloid), CCW triangles seen from +Z."""
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    z = bump * ((x - 0.5) ** 2 + (y - 0.5) ** 2)
    V = np.stack([x.ravel(), y.ravel(), z.ravel()], 1)
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j, (i + 1) * n + j + 1
            F += [[a, b, d], [a, d, c]]
    return TriMesh(V, np.asarray(F))


def test_cotangent_weights_match_hand_computed_triangle_pair():
    # two right isosceles triangles sharing the diagonal: cot 90° = 0 for the diagonal,
    # each leg has one opposite 45° angle (cot = 1) → ω = ½
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    W = cotangent_weights(V, F).toarray()
    assert np.allclose(W, W.T)
    assert W[0, 2] == pytest.approx(0.0, abs=1e-12)
    assert W[0, 1] == pytest.approx(0.5) and W[1, 2] == pytest.approx(0.5)
    M = cotangent_laplacian(V, F)
    assert np.allclose(M @ np.ones(4), 0.0)  # rows sum to zero: translation invariance


def test_flat_interior_vertices_have_zero_laplacian_and_curved_ones_do_not():
    flat, bowl = grid(), grid(bump=1.0)
    interior = [i * 9 + j for i in range(1, 8) for j in range(1, 8)]
    assert np.abs((cotangent_laplacian(flat.vertices, flat.faces) @ flat.vertices)[interior]).max() < 1e-12
    lb = cotangent_laplacian(bowl.vertices, bowl.faces) @ bowl.vertices
    assert np.all(lb[interior, 2] > 0)  # points towards the concave side (+Z) everywhere


def test_spreading_keeps_controls_and_decays_away_from_them():
    m = grid(13)
    centre = 6 * 13 + 6
    corners = [0, 12, 156, 168]
    controls = np.array([centre] + corners)
    disp = np.zeros((5, 3))
    disp[0] = [0, 0, 0.2]
    d = spread_displacements(m, controls, disp, n_spread=30)
    assert np.allclose(d[controls], disp)
    mag = np.linalg.norm(d, axis=1)
    dist = np.linalg.norm(m.vertices - m.vertices[centre], axis=1)
    near, far = mag[(dist > 0) & (dist < 0.15)].mean(), mag[dist > 0.45].mean()
    assert near > 3 * far
    delta = deformation_factors(d, s=20.0)
    assert delta.min() >= 0 and delta.max() <= 1 and delta[centre] == 1.0


@pytest.mark.parametrize("aoi", [True, False])
def test_process1_reaches_controls_and_preserves_rigid_motion(aoi):
    m = grid(11, bump=0.5)
    rng = np.random.default_rng(0)
    controls = rng.choice(m.n_vertices, 12, replace=False)
    deformer = LaplacianDeformer(m, controls)
    disp = rng.normal(scale=0.05, size=(12, 3))
    res = deformer.deform(disp, aoi=aoi)
    err = np.linalg.norm(res.vertices[controls] - (m.vertices[controls] + disp), axis=1).max()
    assert err <= 1e-4 * m.size
    if aoi:  # without AOI (D = I) every vertex re-orients; the iteration may only settle slowly
        assert res.converged
    # a pure translation of every control point translates the whole mesh
    shift = np.array([0.1, -0.2, 0.3])
    moved = deformer.deform(np.tile(shift, (12, 1)), aoi=aoi).vertices
    assert np.allclose(moved, m.vertices + shift, atol=1e-6)
    # no displacement: nothing moves
    assert np.allclose(deformer.deform(np.zeros((12, 3)), aoi=aoi).vertices, m.vertices, atol=1e-9)


def test_aoi_moves_far_vertices_less_than_without_on_a_bump():
    m = grid(21, bump=0.3)
    n = 21
    border = [i for i in range(m.n_vertices) if i % n in (0, n - 1) or i // n in (0, n - 1)]
    centre = 10 * n + 5
    controls = np.array([centre] + border)
    deformer = LaplacianDeformer(m, controls)
    disp = np.zeros((len(controls), 3))
    disp[0] = [0.0, 0.0, 0.15]
    far = np.flatnonzero(np.linalg.norm(m.vertices - m.vertices[centre], axis=1) > 0.4)
    with_aoi = np.linalg.norm(deformer.deform(disp, aoi=True).vertices[far] - m.vertices[far], axis=1).mean()
    without = np.linalg.norm(deformer.deform(disp, aoi=False).vertices[far] - m.vertices[far], axis=1).mean()
    assert with_aoi < without


# ---------------------------------------------------------------- mesh checks
def test_obj_round_trip_and_manifold_check(tmp_path):
    m = grid(5)
    p = write_obj(tmp_path / "g.obj", m)
    back = read_obj(p)
    assert np.allclose(back.vertices, m.vertices, atol=1e-6) and np.array_equal(back.faces, m.faces)
    check_manifold(back, p)


def test_quads_and_relative_indices_are_triangulated(tmp_path):
    p = tmp_path / "q.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf -4/1 -3/2 -2/3 -1/4\n")
    m = read_obj(p)
    assert m.faces.tolist() == [[0, 1, 2], [0, 2, 3]]


@pytest.mark.parametrize("text,problem", [
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 0 -1 0\n"
     "f 1 2 3\nf 2 1 4\nf 1 2 5\n", "non-manifold"),  # edge 1-2 in three triangles
    ("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\nf 1 4 3\n", "directed edge"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 2\n", "degenerate"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n", "outside"),
    ("v 0 0\nf 1 2 3\n", "malformed"),
    ("# nothing\n", "no vertices"),
    ("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "zero area"),
])
def test_bad_meshes_raise_user_errors(tmp_path, text, problem):
    p = tmp_path / "bad.obj"
    p.write_text(text)
    with pytest.raises(UserError, match=problem):
        check_manifold(read_obj(p), p)


def test_bowtie_vertex_is_non_manifold():
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [-1, 0, 0], [-1, -1, 0]], float)
    with pytest.raises(UserError, match="non-manifold vertex"):
        check_manifold(TriMesh(V, np.array([[0, 1, 2], [0, 3, 4]])))


def test_cli_rejects_unreadable_and_non_manifold_meshes(tmp_path):
    binary = tmp_path / "b.obj"
    binary.write_bytes(b"\x89PNG\x00\xff\xfe")
    nm = tmp_path / "nm.obj"
    nm.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 0 -1 0\nf 1 2 3\nf 2 1 4\nf 1 2 5\n")
    table = tmp_path / "t.json"
    table.write_text('{"controls": [0], "targets": {"a": {"0": [0, 0, 1]}}}')
    for mesh, message in ((binary, "cannot read"), (nm, "non-manifold"), (tmp_path / "none.obj", "not found")):
        r = cli("blendshapes", "--mesh", str(mesh), "--controls", str(table), "--out", str(tmp_path / "out"))
        assert r.returncode == 2, r.stderr
        assert message in r.stderr and "Traceback" not in r.stderr
