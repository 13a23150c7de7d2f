"""Head pose from depth frames (RGB-D input, paper 3.1.1).

Per depth frame (millimetres, 0 = no reading):

1. **Foreground / background** — K-means with two clusters on the valid depths
   (scikit-learn); the nearer cluster is the user. Pixels of that cluster form the
   head region (when a face box from the colour landmarks is given, only pixels inside
   it are kept).
2. **Point cloud** — back-projection with the pinhole intrinsics, in the OpenGL camera
   frame of :mod:`head_pose` (X right, Y up, +Z towards the camera), metres.
3. **Registration** — the first frame's cloud is registered to a template (the
   canonical face mesh, cm → m, facing the camera, placed at the cloud's centroid) to
   get the user's initial head pose. Later frames are tracked from the previous
   frame's pose. The paper registers consecutive *clouds* frame to frame; we
   register the template again, started at the previous pose. Reason, measured on
   rendered depth: two depth images share one pixel grid, and point-to-point ICP
   between them locks onto the identity for small motions (it recovered under a
   fifth of a 3°/frame turn, so the pose drifted 3° per frame), while the template's
   irregular vertices do not lock and do not drift.

ICP (:func:`icp`) follows the paper's Algorithm 1 with row-vector points: nearest
neighbours of C2 in C1 (a scipy cKDTree) → ``M = 1/n Σ (C'2i − C'2m)ᵀ (C2i − C2m)`` →
``M = U W Vᵀ`` → ``R = U Vᵀ`` (with the usual sign fix so det R = +1) and
``t = C'2m − C2m · R``… applied to C2 until the mean step is below a tolerance. In
row-vector form the update is ``C2 ← C2 · Rᵀ + t`` with ``R`` mapping column vectors.
Correspondences farther than ``max_dist`` are ignored (the head region changes a little
between frames). The resulting pose jitter is smoothed by the caller
(:class:`head_pose.PoseSmoother`).

:func:`render_depth` z-buffers a triangle mesh into a depth image: it makes the test
data (depth of the canonical face under known motions, in front of a wall).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from facecapges import rotations as rot
from facecapges.capture.head_pose import HeadPose, Intrinsics, procrustes
from facecapges.errors import UserError, file_error


# ----------------------------------------------------------------- inputs
def load_intrinsics(path: str | Path) -> Intrinsics:
    """K.json: ``{"fx", "fy", "cx", "cy"}`` in pixels, or ``{"K": [[fx,0,cx],[0,fy,cy],[0,0,1]]}``."""
    p = Path(path)
    if not p.is_file():
        raise file_error(p, "intrinsics file not found")
    try:
        d = json.loads(p.read_text())
        if "K" in d:
            K = np.asarray(d["K"], np.float64)
            return Intrinsics(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))
        return Intrinsics(float(d["fx"]), float(d["fy"]), float(d["cx"]), float(d["cy"]))
    except (ValueError, KeyError, TypeError, IndexError) as exc:
        raise file_error(p, f"not valid intrinsics JSON (need fx, fy, cx, cy or K): {exc}") from None


def list_depth_frames(depth_dir: str | Path) -> list[Path]:
    """The depth frames of a directory (16-bit PNG or .npy, millimetres), sorted by name."""
    d = Path(depth_dir)
    if not d.is_dir():
        raise file_error(d, "depth directory not found")
    files = sorted([p for p in d.iterdir() if p.suffix.lower() in (".png", ".npy")])
    if not files:
        raise file_error(d, "holds no depth frames (*.png 16-bit or *.npy, millimetres)")
    return files


def read_depth(path: str | Path) -> np.ndarray:
    """One depth frame in millimetres, float32 (H, W)."""
    p = Path(path)
    if p.suffix.lower() == ".npy":
        a = np.load(p)
    else:
        import cv2

        a = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if a is None:
            raise file_error(p, "cannot be read as a depth image")
        if a.dtype != np.uint16:
            raise file_error(p, f"depth PNG must be 16-bit (millimetres), got {a.dtype}")
    if a.ndim != 2:
        raise file_error(p, f"depth frame must be (H, W), got {a.shape}")
    return a.astype(np.float32)


# ----------------------------------------------------------------- geometry
def foreground_mask(depth_mm: np.ndarray, seed: int = 0) -> np.ndarray:
    """Bool (H, W): the nearer of two K-means depth clusters among valid pixels."""
    from sklearn.cluster import KMeans

    valid = depth_mm > 0
    z = depth_mm[valid].reshape(-1, 1)
    if len(z) < 10:
        return np.zeros_like(valid)
    sub = z[:: max(1, len(z) // 5000)]  # clustering on a subsample; labels by nearest centre
    km = KMeans(n_clusters=2, n_init=3, random_state=seed).fit(sub)
    c = np.sort(km.cluster_centers_.ravel())
    thresh = c.mean()
    return valid & (depth_mm < thresh)


def depth_to_points(depth_mm: np.ndarray, K: Intrinsics, mask: np.ndarray | None = None) -> np.ndarray:
    """Back-project (masked) pixels to (N, 3) metres in the OpenGL camera frame."""
    _h, _w = depth_mm.shape  # (H, W): one depth image
    vs, us = np.nonzero((depth_mm > 0) if mask is None else mask & (depth_mm > 0))
    z = depth_mm[vs, us].astype(np.float64) / 1000.0
    x = (us + 0.5 - K.cx) * z / K.fx
    y = (vs + 0.5 - K.cy) * z / K.fy
    return np.stack([x, -y, -z], axis=1)


def icp(
    C1: np.ndarray,
    C2: np.ndarray,
    iters: int = 50,
    tol: float = 1e-6,
    max_dist: float | None = None,
    R0: np.ndarray | None = None,
    t0: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Rigid ICP (paper Algorithm 1): ``R, t`` such that ``C2 @ R.T + t`` lies on ``C1``; also the final RMS (m)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(C1)
    R = np.eye(3) if R0 is None else R0.copy()
    t = np.zeros(3) if t0 is None else t0.copy()
    rms = float("inf")
    for _ in range(iters):
        cur = C2 @ R.T + t
        d, j = tree.query(cur)
        keep = np.ones(len(d), bool) if max_dist is None else d < max_dist
        if keep.sum() < 6:
            break
        _, dR, dt = procrustes(cur[keep], C1[j[keep]], with_scale=False)  # Algorithm 1, steps 2–4 (Kabsch)
        R = dR @ R
        t = t @ dR.T + dt
        rms = float(np.sqrt(np.mean(d[keep] ** 2)))
        step = np.linalg.norm(dt) + float(rot.geodesic_angle(np.eye(3), dR)) * 0.1
        if step < tol:  # converged: the last step moved points by less than tol (m)
            break
    return R, t, rms


class DepthHeadTracker:
    """First frame → template, then frame-to-frame ICP (module docstring).

    Args:
        template_m: (N, 3) template points in metres, head frame (the canonical mesh / 100).
        K: depth camera intrinsics.
    """

    def __init__(self, template_m: np.ndarray, K: Intrinsics):
        self.template = np.asarray(template_m, np.float64)
        self.K = K
        self.prev: np.ndarray | None = None
        self.pose: HeadPose | None = None

    def _cloud(self, depth_mm: np.ndarray, box: tuple[int, int, int, int] | None) -> np.ndarray:
        mask = foreground_mask(depth_mm)
        if box is not None:
            x0, y0, x1, y1 = box
            m2 = np.zeros_like(mask)
            m2[max(0, y0) : y1, max(0, x0) : x1] = True
            mask &= m2
        return depth_to_points(depth_mm, self.K, mask)

    def update(self, depth_mm: np.ndarray, box: tuple[int, int, int, int] | None = None) -> HeadPose | None:
        """Head pose (R head→camera, t in cm like :mod:`head_pose`) for this depth frame; None without a head."""
        cloud = self._cloud(depth_mm, box)
        if len(cloud) < 50:
            self.prev = None
            return None
        if self.prev is None or self.pose is None:
            # first frame: register the template (facing the camera, at the centroid) onto the cloud
            c = cloud.mean(axis=0)
            t0 = c - self.template.mean(axis=0)
            R, t, _ = icp(cloud, self.template, iters=100, t0=t0)
            self.pose = HeadPose(R, t * 100.0)
        else:
            # tracking: the template again, started from the previous frame's pose
            R, t, _ = icp(cloud, self.template, iters=40, max_dist=0.015, R0=self.pose.R, t0=self.pose.t / 100.0)
            self.pose = HeadPose(R, t * 100.0)
        self.prev = cloud
        return self.pose


def render_depth(
    vertices_m: np.ndarray,
    triangles: np.ndarray,
    K: Intrinsics,
    width: int,
    height: int,
    background_mm: float | None = None,
) -> np.ndarray:
    """Z-buffered depth (H, W) in millimetres of a mesh in the OpenGL camera frame (metres, in front: z < 0).

    Pixels the mesh does not cover are ``background_mm`` (a wall) or 0 (no reading).
    """
    depth = np.full((height, width), np.inf)
    z = -vertices_m[:, 2]
    u = vertices_m[:, 0] / z * K.fx + K.cx - 0.5
    v = -vertices_m[:, 1] / z * K.fy + K.cy - 0.5
    for a, b, c in triangles:
        xs = np.array([u[a], u[b], u[c]])
        ys = np.array([v[a], v[b], v[c]])
        x0, x1 = int(max(np.floor(xs.min()), 0)), int(min(np.ceil(xs.max()), width - 1))
        y0, y1 = int(max(np.floor(ys.min()), 0)), int(min(np.ceil(ys.max()), height - 1))
        if x1 < x0 or y1 < y0:
            continue
        gx, gy = np.meshgrid(np.arange(x0, x1 + 1), np.arange(y0, y1 + 1))
        den = (ys[1] - ys[2]) * (xs[0] - xs[2]) + (xs[2] - xs[1]) * (ys[0] - ys[2])
        if abs(den) < 1e-12:
            continue
        l0 = ((ys[1] - ys[2]) * (gx - xs[2]) + (xs[2] - xs[1]) * (gy - ys[2])) / den
        l1 = ((ys[2] - ys[0]) * (gx - xs[2]) + (xs[0] - xs[2]) * (gy - ys[2])) / den
        l2 = 1 - l0 - l1
        inside = (l0 >= 0) & (l1 >= 0) & (l2 >= 0)
        if not inside.any():
            continue
        # perspective-correct depth: interpolate 1/z
        inv = l0 / z[a] + l1 / z[b] + l2 / z[c]
        zz = np.where(inside, 1.0 / np.where(inside, inv, 1.0), np.inf)
        sub = depth[y0 : y1 + 1, x0 : x1 + 1]
        np.minimum(sub, zz, out=sub)
    out = depth * 1000.0
    out[~np.isfinite(out)] = 0.0 if background_mm is None else background_mm
    return out.astype(np.float32)


def check_depth_inputs(depth_dir, intrinsics) -> tuple[list[Path], Intrinsics]:
    """Validate the ``--depth`` / ``--intrinsics`` pair of the capture command."""
    if (depth_dir is None) != (intrinsics is None):
        raise UserError("--depth and --intrinsics go together: give both or neither")
    return list_depth_frames(depth_dir), load_intrinsics(intrinsics)
