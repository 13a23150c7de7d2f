"""Build blendshape targets from a neutral mesh and a control table (seed 2, section 4).

:func:`build_blendshapes` deforms the neutral mesh once per target with
:class:`~facecapges.avatar.laplacian.LaplacianDeformer` (one factorisation for the
whole table) and measures what the issue asks to see:

* **control error**: the largest distance between a control point and its target
  position, relative to the face size (bounding-box diagonal);
* **far-vertex motion**: for each target, the mean displacement of the vertices
  farther than ``far_radius`` (default 25 % of the face size, measured on the neutral
  mesh) from every *moved* control point, relative to the face size; averaged over
  targets. It is reported for Process 1 with AOI, without AOI (``D = I``) and for the
  one-shot plain Laplacian edit.
"""

from __future__ import annotations

import os
import pickle
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from facecapges.avatar.blendshape_table import ControlTable
from facecapges.avatar.laplacian import LaplacianDeformer
from facecapges.avatar.mesh import TriMesh


@dataclass
class Blendshapes:
    """Target vertex positions (T, N, 3) named ``names``, on ``neutral``'s triangles."""

    neutral: TriMesh
    names: list[str]
    targets: np.ndarray
    report: dict = field(default_factory=dict)

    def deltas(self) -> np.ndarray:
        """Morph-target offsets (T, N, 3) = target − neutral."""
        return self.targets - self.neutral.vertices[None]


def far_vertices(mesh: TriMesh, moved: np.ndarray, far_radius: float) -> np.ndarray:
    """Indices of vertices farther than ``far_radius`` from every vertex in ``moved``."""
    if moved.size == 0:
        return np.arange(mesh.n_vertices)
    dist = np.linalg.norm(mesh.vertices[:, None, :] - mesh.vertices[None, moved, :], axis=2).min(axis=1)
    return np.flatnonzero(dist > far_radius)


def build_blendshapes(
    mesh: TriMesh,
    table: ControlTable,
    aoi: bool = True,
    compare: bool = True,
    far_radius: float = 0.25,
    progress=None,
    **deform_kw,
) -> Blendshapes:
    """Deform ``mesh`` for every target of ``table``.

    ``aoi`` picks the targets returned (Process 1 with or without areas of
    influence); with ``compare`` the other variant and the plain edit are also run,
    for the report only. ``progress(i)`` is called after each target.
    """
    deformer = LaplacianDeformer(mesh, table.controls)
    size = mesh.size
    out = np.empty((len(table.targets), mesh.n_vertices, 3))
    per_target = {}
    far_aoi, far_free, far_plain, errors, iters = [], [], [], [], []
    for k, (name, disp) in enumerate(table.targets.items()):
        res = deformer.deform(disp, aoi=aoi, **deform_kw)
        out[k] = res.vertices
        target_pos = mesh.vertices[table.controls] + disp
        err = float(np.linalg.norm(res.vertices[table.controls] - target_pos, axis=1).max() / size)
        errors.append(err)
        iters.append(res.iterations)
        entry = {
            "control_error": err,
            "iterations": res.iterations,
            "converged": res.converged,
            "aoi_vertices": int((res.factors > 0.01).sum()) if aoi else mesh.n_vertices,
        }
        if compare:
            motion = _far_motion(deformer, mesh, table.controls, disp, res.vertices, aoi, far_radius, deform_kw)
            if motion is not None:
                far_aoi.append(motion["far_motion_aoi"])
                far_free.append(motion["far_motion_no_aoi"])
                far_plain.append(motion["far_motion_plain"])
                entry.update(motion)
        per_target[name] = entry
        if progress is not None:
            progress(k)
    report = _report(mesh, table, aoi, far_radius, errors, iters, far_aoi, far_free, far_plain)
    report["targets"] = per_target
    return Blendshapes(mesh, list(table.targets), out, report)


def _far_motion(
    deformer: LaplacianDeformer,
    mesh: TriMesh,
    controls: np.ndarray,
    disp: np.ndarray,
    vertices: np.ndarray,
    aoi: bool,
    far_radius: float,
    deform_kw: dict,
) -> dict[str, Any] | None:
    """How far vertices (beyond ``far_radius`` of the face size from the moved controls) move with AOI,
    without, and by the plain edit (mean, fraction of face size); None when no vertex is that far.

    ``vertices``: the target as deformed with ``aoi``; the other variant is run here."""
    size = mesh.size
    moved = controls[np.linalg.norm(disp, axis=1) > 1e-9]
    far = far_vertices(mesh, moved, far_radius * size)
    other = deformer.deform(disp, aoi=not aoi, **deform_kw).vertices
    with_aoi, without = (vertices, other) if aoi else (other, vertices)
    plain = deformer.plain(disp)
    if not far.size:
        return None
    motion = [
        float(np.linalg.norm(x[far] - mesh.vertices[far], axis=1).mean() / size) for x in (with_aoi, without, plain)
    ]
    return {
        "far_vertices": int(far.size),
        "far_motion_aoi": motion[0],
        "far_motion_no_aoi": motion[1],
        "far_motion_plain": motion[2],
    }


def _report(
    mesh: TriMesh,
    table: ControlTable,
    aoi: bool,
    far_radius: float,
    errors: list[float],
    iters: list,
    far_aoi: list[float],
    far_free: list[float],
    far_plain: list[float],
) -> dict[str, Any]:
    """The run's summary (control error, iterations, far-vertex motion with / without AOI)."""
    report: dict[str, Any] = {
        "n_vertices": mesh.n_vertices,
        "n_controls": int(table.controls.size),
        "n_targets": len(table.targets),
        "face_size": mesh.size,
        "aoi": aoi,
        "far_radius": far_radius,
        "max_control_error": max(errors),
        "mean_iterations": float(np.mean(iters)),
    }
    if far_aoi:
        report.update(
            mean_far_motion_aoi=float(np.mean(far_aoi)),
            mean_far_motion_no_aoi=float(np.mean(far_free)),
            mean_far_motion_plain=float(np.mean(far_plain)),
            targets_where_aoi_moves_far_less=int(np.sum(np.asarray(far_aoi) < np.asarray(far_free))),
            targets_compared=len(far_aoi),
        )
    return report


AVATAR_CACHE_ENV = "FACECAPGES_AVATAR_CACHE"  # set by the test suite only (tests/conftest.py, docs/testing.md)


def arkit_blendshapes(aoi: bool = True, compare: bool = False, progress=None) -> Blendshapes:
    """The 52 ARKit targets of MediaPipe's canonical face from the shipped control table,
    in :data:`facecapges.arkit.ARKIT_NAMES` order.

    With ``$FACECAPGES_AVATAR_CACHE`` set (the test suite only) a build without ``compare`` or ``progress`` is kept
    in that folder, keyed by what decides it (:func:`_arkit_key`), and read back by later calls and processes: the
    same arrays, built once per session instead of at every ``live --web`` start and ``default_avatar`` call."""
    cache = os.environ.get(AVATAR_CACHE_ENV)
    if not cache or compare or progress is not None:
        return _build_arkit(aoi, compare, progress)
    path = Path(cache) / f"arkit-{_arkit_key(aoi)}.pickle"
    if path.is_file():
        with path.open("rb") as f:
            return pickle.load(f)
    shapes = _build_arkit(aoi, compare, progress)
    path.parent.mkdir(parents=True, exist_ok=True)
    part = path.with_name(f"{path.name}.{os.getpid()}.part")  # written under another name, then renamed: a reader
    with part.open("wb") as f:  # never sees half a file (two processes building at once each write a whole one)
        pickle.dump(shapes, f, protocol=pickle.HIGHEST_PROTOCOL)
    os.replace(part, path)
    return shapes


def package_digest(h) -> None:
    """Feed every file of the installed package (code and assets, with their paths) to the hash ``h``."""
    package = Path(__file__).resolve().parents[1]
    for f in sorted(package.rglob("*")):
        if f.is_file() and "__pycache__" not in f.parts:
            h.update(str(f.relative_to(package)).encode() + f.read_bytes())


def _arkit_key(aoi: bool) -> str:
    """What decides :func:`arkit_blendshapes`'s result: ``aoi``, every file of the package (the code, the control
    table) and the face model the canonical face is read from."""
    import hashlib

    from facecapges.capture.models import resolve_model

    h = hashlib.sha256(repr(("arkit", aoi)).encode())
    package_digest(h)
    h.update(Path(resolve_model(None)).read_bytes())
    return h.hexdigest()[:32]


def _build_arkit(aoi: bool, compare: bool, progress) -> Blendshapes:
    from facecapges.arkit import ARKIT_NAMES
    from facecapges.avatar.blendshape_table import default_table_path, load_table, require_arkit
    from facecapges.avatar.mesh import canonical_face

    neutral = canonical_face()
    table = load_table(default_table_path(), neutral.n_vertices)
    require_arkit(table, default_table_path())
    table.targets = {n: table.targets[n] for n in ARKIT_NAMES}
    return build_blendshapes(neutral, table, aoi=aoi, compare=compare, progress=progress)
