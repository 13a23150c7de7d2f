"""Triangle meshes: OBJ reading/writing and the manifold check the deformation needs.

A :class:`TriMesh` is ``vertices`` (N, 3) float64 and ``faces`` (F, 3) int64,
counter-clockwise seen from outside (the OBJ convention). Only ``v`` and ``f``
records matter; polygons are fan-triangulated, ``v/vt/vn`` references keep their
vertex index, negative (relative) indices are resolved, anything else is ignored.

The Laplacian deformation of :mod:`facecapges.avatar.laplacian` needs an
**oriented 2-manifold, boundary allowed**: every edge in one or two triangles, two
triangles sharing an edge traverse it in opposite directions, no degenerate
(repeated-index or zero-area) triangle, and every vertex in some triangle.
:func:`check_manifold` raises a :class:`~facecapges.errors.UserError` naming the file
and the first problem found.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facecapges.errors import file_error, require_file


@dataclass
class TriMesh:
    """Vertices (N, 3) and counter-clockwise triangles (F, 3)."""

    vertices: np.ndarray
    faces: np.ndarray

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def size(self) -> float:
        """Face size: the diagonal of the axis-aligned bounding box (mesh units)."""
        return float(np.linalg.norm(self.vertices.max(0) - self.vertices.min(0)))

    def edges(self) -> np.ndarray:
        """Unique undirected edges (E, 2), smaller index first."""
        e = np.concatenate([self.faces[:, [0, 1]], self.faces[:, [1, 2]], self.faces[:, [2, 0]]])
        return np.unique(np.sort(e, axis=1), axis=0)

    def vertex_normals(self) -> np.ndarray:
        """Area-weighted unit vertex normals (N, 3)."""
        v = self.vertices
        fn = np.cross(v[self.faces[:, 1]] - v[self.faces[:, 0]], v[self.faces[:, 2]] - v[self.faces[:, 0]])
        n = np.zeros_like(v)
        for k in range(3):
            np.add.at(n, self.faces[:, k], fn)
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def read_obj(path: str | Path) -> TriMesh:
    """Read the vertices and (triangulated) faces of a Wavefront OBJ file."""
    p = require_file(path, "mesh")
    verts: list[list[float]] = []
    faces: list[list[int]] = []
    try:
        text = p.read_text(encoding="utf-8", errors="strict")
    except (UnicodeDecodeError, OSError) as exc:
        raise file_error(p, f"cannot read as a text OBJ mesh ({exc})") from None
    for lineno, line in enumerate(text.splitlines(), 1):
        tok = line.split()
        if not tok or tok[0].startswith("#"):
            continue
        try:
            if tok[0] == "v":
                verts.append([float(t) for t in tok[1:4]])
                if len(verts[-1]) != 3:
                    raise ValueError("a vertex needs 3 coordinates")
            elif tok[0] == "f":
                idx = []
                for t in tok[1:]:
                    i = int(t.split("/")[0])
                    idx.append(i - 1 if i > 0 else len(verts) + i)
                if len(idx) < 3:
                    raise ValueError("a face needs at least 3 vertices")
                faces.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
        except ValueError as exc:
            raise file_error(p, f"line {lineno}: malformed OBJ record {line.strip()!r} ({exc})") from None
    if not verts or not faces:
        raise file_error(p, "no vertices or no faces: not a triangle mesh")
    v = np.asarray(verts, np.float64)
    f = np.asarray(faces, np.int64)
    if f.min() < 0 or f.max() >= len(v):
        raise file_error(
            p,
            f"a face refers to vertex {int(f.max()) + 1 if f.max() >= len(v) else int(f.min()) + 1}, "
            f"outside the {len(v)} vertices",
        )
    if not np.all(np.isfinite(v)):
        raise file_error(p, "a vertex coordinate is not finite")
    return TriMesh(v, f)


def write_obj(path: str | Path, mesh: TriMesh, header: str = "") -> Path:
    """Write ``mesh`` as an OBJ (``v`` then 1-based ``f`` records)."""
    p = Path(path)
    lines = [f"# {h}" for h in header.splitlines()] if header else []
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces]
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return p


def check_manifold(mesh: TriMesh, name: str | Path = "mesh") -> None:
    """Raise a UserError unless ``mesh`` is an oriented 2-manifold (boundary allowed)."""
    f, v = mesh.faces, mesh.vertices
    if f.ndim != 2 or f.shape[1] != 3:
        raise file_error(name, f"faces must be (F, 3) triangles, got {f.shape}")
    if np.any((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])):
        raise file_error(
            name,
            f"degenerate triangle {int(np.flatnonzero((f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0]))[0])} repeats a vertex",
        )
    area2 = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    if np.any(area2 <= 1e-12 * max(mesh.size, 1e-12) ** 2):
        raise file_error(name, f"triangle {int(np.argmin(area2))} has zero area")
    unused = np.setdiff1d(np.arange(len(v)), f.ravel())
    if unused.size:
        raise file_error(name, f"{unused.size} vertices belong to no triangle (first: {int(unused[0]) + 1})")
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    _, dcount = np.unique(directed, axis=0, return_counts=True)
    if np.any(dcount > 1):
        raise file_error(name, "not consistently oriented or non-manifold: a directed edge is used twice")
    und, ucount = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    if np.any(ucount > 2):
        a, b = und[np.argmax(ucount)]
        raise file_error(
            name, f"non-manifold: edge {int(a) + 1}-{int(b) + 1} is shared by {int(ucount.max())} triangles"
        )
    # Non-manifold vertices: the triangles around a vertex must form one fan.
    nv = len(v)
    kids: list[list[tuple[int, int]]] = [[] for _ in range(nv)]  # per vertex: its triangles' other two
    for tri in f:
        for k in range(3):
            kids[tri[k]].append((int(tri[(k + 1) % 3]), int(tri[(k + 2) % 3])))
    for vi, fan in enumerate(kids):
        # union-find over the fan's triangles, joined when they share an edge from vi
        parent = list(range(len(fan)))

        def find(a: int) -> int:
            while parent[a] != a:
                parent[a] = parent[parent[a]]
                a = parent[a]
            return a

        by_vertex: dict[int, int] = {}
        for t, (a, b) in enumerate(fan):
            for w in (a, b):
                if w in by_vertex:
                    parent[find(t)] = find(by_vertex[w])
                else:
                    by_vertex[w] = t
        if len({find(t) for t in range(len(fan))}) > 1:
            raise file_error(name, f"non-manifold vertex {vi + 1}: its triangles form more than one fan")


def canonical_face(task_path: str | Path | None = None) -> TriMesh:
    """MediaPipe's canonical face (468 vertices, cm; +X = the subject's left, Y up, +Z out
    of the face), read by :mod:`facecapges.capture.canonical_mesh` from the pinned
    ``face_landmarker.task`` (``task_path`` or the hash-checked bundled copy)."""
    from facecapges.capture.canonical_mesh import load_canonical_mesh
    from facecapges.capture.models import resolve_model

    m = load_canonical_mesh(resolve_model(task_path))
    return TriMesh(m.vertices.astype(np.float64).copy(), m.triangles.astype(np.int64).copy())
