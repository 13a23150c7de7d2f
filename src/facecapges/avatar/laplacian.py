"""Laplacian mesh deformation with areas of influence (AOI), seed 2 section 4.

Notation follows the paper (eq. 10–13, "Process 1"). A mesh has N vertices V (N, 3);
some are **control points** whose target positions are given; the rest are solved.

* **Laplacian coordinates** (eq. 10–11): ``l_v = Σ_i ω_i (v_i − v)`` over the
  neighbours ``v_i`` of ``v`` with cotangent weights ``ω_i = ½ (cot α_i + cot β_i)``
  (α, β: the angles opposite the edge ``v v_i``; a boundary edge has only one). As a
  matrix, ``L = M V`` with ``M = W − diag(W 1)`` (:func:`cotangent_laplacian`). The
  weights are not normalised, as eq. 10 writes them.
* **Solving for V** given L: least squares ``min ‖M V − L‖²`` with the control
  points as **hard** constraints (eliminated unknowns), so they reach their targets
  exactly. The normal matrix ``M_fᵀ M_f`` of the free vertices depends only on the
  mesh and *which* vertices are controls, so it is factored **once**
  (``scipy.sparse.linalg.splu``) and reused by every iteration and every target that
  shares the control set (:class:`LaplacianDeformer`).
* **AOI spreading** (eq. 12): control displacements start as given, other vertices
  at 0; each smoothing pass sets every non-control vertex to
  ``d'_v = Σ_i ω_i d_{v_i} / l_i  /  Σ_i ω_i / l_i`` with ``l_i = ‖v − v_i‖`` and a
  per-neighbour weight ``ω_i`` that is large (``control_weight``, default 10) for
  control points and 1 otherwise. The paper does not say how many passes; we run a
  fixed ``n_spread`` (default 20) Jacobi passes, which lets a control point's
  influence reach about that many rings while unmoved control points (d = 0, large
  weight) hold their neighbourhoods still — so the region grows with the displacement.
* **Deformation factor** ``δ_v = min(‖d_v‖·s, 1)`` and ``D = diag(δ)`` (eq. 13).
  The paper gives no value for ``s``; we set it relative to the mesh size,
  ``s = aoi_scale / size`` with ``size`` the bounding-box diagonal (default
  ``aoi_scale = 100``: a vertex whose spread displacement reaches 1 % of the face
  size changes its local shape fully).
* **Process 1** (:meth:`LaplacianDeformer.deform`): ``L0 = M V0``; repeat: solve V
  under the control constraints from L; ``L' = M V``; rescale every row of L' to the
  length of L0's row, ``L'' = (|L0| / |L'|) L'``; ``L = D L'' + (I − D) L0`` — until
  the largest vertex change is below ``tol · size``. With ``D = I`` (``aoi=False``)
  the same iteration runs without areas of influence, every vertex free to re-orient
  its local shape: the comparison the paper's figure 9 makes.
* :meth:`LaplacianDeformer.plain` is the classic one-shot Laplacian edit
  (``L = L0``, one solve), kept as a further reference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from facecapges.avatar.mesh import TriMesh


def cotangent_weights(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """Symmetric (N, N) matrix of ω_ij = ½ (cot α_ij + cot β_ij) (eq. 11); zero diagonal."""
    n = vertices.shape[0]
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, o = faces[:, (k + 1) % 3], faces[:, (k + 2) % 3], faces[:, k]  # edge (i, j) opposite o
        a = vertices[i] - vertices[o]
        b = vertices[j] - vertices[o]
        cot = np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(np.cross(a, b), axis=1), 1e-12)
        rows += [i, j]
        cols += [j, i]
        vals += [0.5 * cot, 0.5 * cot]
    W = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    return W.tocsr()  # duplicates (the two triangles of an edge) are summed


def cotangent_laplacian(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """M with ``(M V)_v = Σ_i ω_i (v_i − v)`` (eq. 10): ``M = W − diag(W 1)``."""
    W = cotangent_weights(vertices, faces)
    return (W - sp.diags(np.asarray(W.sum(axis=1)).ravel())).tocsr()


def spread_displacements(
    mesh: TriMesh, controls: np.ndarray, control_disp: np.ndarray, n_spread: int = 20, control_weight: float = 10.0
) -> np.ndarray:
    """Per-vertex displacements (N, 3) spread from the control points by eq. 12.

    ``controls`` (K,) vertex indices, ``control_disp`` (K, 3) their displacements
    (0 for control points that stay). Control rows keep their displacement.
    """
    n = mesh.n_vertices
    e = mesh.edges()
    length = np.linalg.norm(mesh.vertices[e[:, 0]] - mesh.vertices[e[:, 1]], axis=1)
    is_ctrl = np.zeros(n, bool)
    is_ctrl[controls] = True
    omega = np.where(is_ctrl, control_weight, 1.0)
    # row v, column i: ω_i / l_i for every neighbour i of v
    r = np.concatenate([e[:, 0], e[:, 1]])
    c = np.concatenate([e[:, 1], e[:, 0]])
    w = omega[c] / np.concatenate([length, length])
    S = sp.csr_matrix((w, (r, c)), shape=(n, n))
    S = sp.diags(1.0 / np.maximum(np.asarray(S.sum(axis=1)).ravel(), 1e-12)) @ S
    d = np.zeros((n, 3))
    d[controls] = control_disp
    free = ~is_ctrl
    for _ in range(n_spread):
        d[free] = (S @ d)[free]
    return d


def deformation_factors(displacements: np.ndarray, s: float) -> np.ndarray:
    """δ_v = min(‖d_v‖·s, 1) (N,), the diagonal of D (eq. 13)."""
    return np.minimum(np.linalg.norm(displacements, axis=1) * s, 1.0)


@dataclass
class DeformResult:
    vertices: np.ndarray  # (N, 3)
    iterations: int
    converged: bool
    factors: np.ndarray  # (N,) δ used (ones without AOI)


class LaplacianDeformer:
    """Cotangent-Laplacian deformation of one mesh with one fixed control set.

    The factorisation of the free-vertex normal equations is computed here once and
    shared by :meth:`plain` and every :meth:`deform` call.
    """

    def __init__(self, mesh: TriMesh, controls: np.ndarray):
        self.mesh = mesh
        self.controls = np.asarray(controls, np.int64)
        n = mesh.n_vertices
        if self.controls.size == 0:
            raise ValueError("at least one control point is needed")
        if self.controls.min() < 0 or self.controls.max() >= n:
            raise ValueError(f"control indices must be in [0, {n}), got {self.controls.min()}..{self.controls.max()}")
        if np.unique(self.controls).size != self.controls.size:
            raise ValueError("control indices repeat")
        self.size = mesh.size
        self.M = cotangent_laplacian(mesh.vertices, mesh.faces)
        self.L0 = self.M @ mesh.vertices
        mask = np.ones(n, bool)
        mask[self.controls] = False
        self.free = np.flatnonzero(mask)
        Mcsc = self.M.tocsc()
        self.M_free = Mcsc[:, self.free]
        self.M_ctrl = Mcsc[:, self.controls]
        self._M_free_T = self.M_free.T  # made once: a transpose per solve was a fifth of building the 52 targets
        A = (self._M_free_T @ self.M_free).tocsc()
        self._lu = splu(A)

    def solve(self, L: np.ndarray, control_pos: np.ndarray, control_L: np.ndarray | None = None) -> np.ndarray:
        """V (N, 3) minimising ‖M V − L‖² with ``V[controls] = control_pos`` exactly (``control_L``: the controls'
        part ``M_ctrl @ control_pos`` when the caller has it already)."""
        if control_L is None:
            control_L = self.M_ctrl @ control_pos
        rhs = self._M_free_T @ (L - control_L)
        V = np.empty_like(self.mesh.vertices)
        V[self.free] = self._lu.solve(np.asarray(rhs))
        V[self.controls] = control_pos
        return V

    def plain(self, control_disp: np.ndarray) -> np.ndarray:
        """One-shot Laplacian edit: keep L0, move the controls by ``control_disp`` (K, 3)."""
        return self.solve(self.L0, self.mesh.vertices[self.controls] + control_disp)

    def factors(
        self, control_disp: np.ndarray, aoi_scale: float = 100.0, n_spread: int = 20, control_weight: float = 10.0
    ) -> np.ndarray:
        """AOI deformation factors δ (N,) for one set of control displacements."""
        d = spread_displacements(self.mesh, self.controls, control_disp, n_spread, control_weight)
        return deformation_factors(d, aoi_scale / self.size)

    def deform(
        self,
        control_disp: np.ndarray,
        aoi: bool = True,
        aoi_scale: float = 100.0,
        n_spread: int = 20,
        control_weight: float = 10.0,
        tol: float = 1e-6,
        max_iter: int = 500,
    ) -> DeformResult:
        """Process 1: iterate solve → L' → rescale to |L0| → L = D L'' + (I − D) L0."""
        target = self.mesh.vertices[self.controls] + control_disp
        if aoi:
            delta = self.factors(control_disp, aoi_scale, n_spread, control_weight)
        else:
            delta = np.ones(self.mesh.n_vertices)
        L0 = self.L0
        len0 = np.linalg.norm(L0, axis=1, keepdims=True)
        L = L0
        V = self.mesh.vertices
        converged = False
        it = 0
        target_L = self.M_ctrl @ target  # the same every iteration
        for it in range(1, max_iter + 1):
            V_new = self.solve(L, target, target_L)
            change = float(np.abs(V_new - V).max())
            V = V_new
            Lp = self.M @ V
            lenp = np.linalg.norm(Lp, axis=1, keepdims=True)
            Lpp = np.where(lenp > 1e-12, Lp * (len0 / np.maximum(lenp, 1e-12)), L0)
            L = delta[:, None] * Lpp + (1.0 - delta[:, None]) * L0
            if change < tol * self.size and it > 1:
                converged = True
                break
        return DeformResult(V, it, converged, delta)
