"""MediaPipe FaceLandmarker in VIDEO mode, with face identities kept across frames.

:class:`LandmarkDetector` wraps ``mediapipe.tasks.vision.FaceLandmarker`` (VIDEO running
mode, several faces, blendshapes and facial transformation matrices on) and returns
plain numpy :class:`FaceObservation` objects. :class:`FaceTracker` gives every face a
stable integer identity: each frame's faces are matched to the tracks of the previous
frames by the Hungarian method on the distance between face centres, measured in
face sizes (a face that moved more than one face width is a new face).

Conventions
-----------
* ``landmarks`` (478, 3): MediaPipe's normalised image coordinates — x of the image
  width, y of the image height (down), z relative depth in the scale of x (smaller =
  nearer the camera). Indices 0–467 follow the canonical mesh, 468–477 are the irises.
* ``blendshapes`` (52,): MediaPipe's learned coefficients in :data:`ARKIT_NAMES` order
  (its ``_neutral`` entry is dropped). Left/Right are the subject's sides.
* ``transform`` (4, 4): MediaPipe's facial transformation matrix (canonical mesh,
  cm → OpenGL camera space), or None when the model did not give one.
"""

from __future__ import annotations

import ctypes
import functools
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from itertools import chain
from operator import attrgetter

import numpy as np

from facecapges.arkit import ARKIT_NAMES, arkit_index
from facecapges.errors import UserError

N_LANDMARKS = 478
_XYZ = attrgetter("x", "y", "z")


@dataclass
class FaceObservation:
    """One detected face in one frame (see the module docstring for conventions)."""

    landmarks: np.ndarray  # (478, 3) float32 normalised
    blendshapes: np.ndarray  # (52,) float32, ARKIT_NAMES order
    transform: np.ndarray | None  # (4, 4) float64
    face_id: int = -1

    @property
    def center(self) -> np.ndarray:
        """Mean of the landmarks' x, y (normalised image coordinates)."""
        return self.landmarks[:, :2].mean(axis=0)

    @property
    def size(self) -> float:
        """Face width: extent of the landmarks' x (normalised)."""
        x = self.landmarks[:, 0]
        return float(x.max() - x.min())


class NativeStderrToFile:
    """Send the process's fd 2 to a temporary file for a block (C++ logs bypass Python).

    Lines that look like errors (``E…``/``F…`` glog/absl prefixes) are kept in
    ``errors`` so the caller can still show them.
    """

    errors = ""

    def __enter__(self):
        sys.stderr.flush()
        self._tmp = tempfile.TemporaryFile(mode="w+b")
        self._saved = os.dup(2)
        os.dup2(self._tmp.fileno(), 2)
        return self

    def __exit__(self, *exc) -> None:
        os.dup2(self._saved, 2)
        os.close(self._saved)
        self._tmp.seek(0)
        text = self._tmp.read().decode("utf-8", "replace")
        self._tmp.close()
        self.errors = "".join(ln + "\n" for ln in text.splitlines() if ln[:1] in ("E", "F"))


def create_task(create, failure: str):
    """``create()`` of a MediaPipe task with its C++ start-up lines kept off the terminal (written to stderr
    only when there were errors among them); a model MediaPipe refuses is a UserError ``failure: why``."""
    log = NativeStderrToFile()
    try:
        with log:
            return create()
    except (ValueError, RuntimeError) as exc:
        raise UserError(f"{failure}: {exc}") from None
    finally:
        if log.errors:
            sys.stderr.write(log.errors)


class _LazyDrawing:
    """A ``sys.meta_path`` finder that loads MediaPipe's drawing modules lazily (:func:`_mediapipe`)."""

    NAMES = ("mediapipe.tasks.python.vision.drawing_utils", "mediapipe.tasks.python.vision.drawing_styles")

    def find_spec(self, name, path, target=None):
        import importlib.machinery
        import importlib.util

        if name not in self.NAMES:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is not None and spec.loader is not None:
            spec.loader = importlib.util.LazyLoader(spec.loader)
        return spec


def _mediapipe(*names: str) -> list:
    """MediaPipe's modules ``names``, its drawing modules left unexecuted until first used.

    ``mediapipe.tasks.python.vision/__init__`` imports ``drawing_utils``, and with it
    ``matplotlib.pyplot``: ~70 MB of memory and ~2 s of start-up the face landmarker never
    uses (a known upstream issue: google-ai-edge/mediapipe pull request 5830 makes that
    import lazy). While MediaPipe is imported here, those two modules are loaded with
    :class:`importlib.util.LazyLoader` — real modules, run on their first attribute
    access — so the package is whole and anything using ``drawing_utils`` later still
    works.
    """
    import importlib

    if all(n in sys.modules for n in names):
        return [sys.modules[n] for n in names]
    finder = _LazyDrawing()
    sys.meta_path.insert(0, finder)
    try:
        return [importlib.import_module(n) for n in names]
    finally:
        sys.meta_path.remove(finder)


def mp_image(rgb: np.ndarray):
    """A ``mediapipe.Image`` (SRGB) of an (H, W, 3) uint8 RGB array."""
    (img,) = _mediapipe("mediapipe.tasks.python.vision.core.image")
    return img.Image(image_format=img.ImageFormat.SRGB, data=rgb)


@functools.cache  # per struct and fields, built once (every frame reads the same two)
def _c_fields(struct, names: tuple[str, ...]) -> np.dtype:
    """A NumPy dtype reading the float32 fields ``names`` of the ctypes ``struct`` in place (its other fields,
    pointers among them, skipped by the offsets)."""
    return np.dtype(
        {
            "names": list(names),
            "formats": [np.float32] * len(names),
            "offsets": [getattr(struct, n).offset for n in names],
            "itemsize": ctypes.sizeof(struct),
        }
    )


def _c_array(ptr, n: int, dtype: np.dtype) -> np.ndarray:
    """The ``dtype`` fields of ``n`` structs at ``ptr`` as an (n, fields) float32 copy."""
    if n == 0:
        return np.zeros((0, len(dtype.names or ())), np.float32)
    raw = np.ctypeslib.as_array(ctypes.cast(ptr, ctypes.POINTER(ctypes.c_uint8)), shape=(n * dtype.itemsize,))
    rows = raw.view(dtype)
    return np.stack([rows[f] for f in dtype.names or ()], axis=1)


def _has_raw_results(task) -> bool:
    """Whether this MediaPipe's face landmarker is the ctypes one :func:`_raw_results` reads (the pinned 1.2.2 is)."""
    (fl,) = _mediapipe("mediapipe.tasks.python.vision.face_landmarker")
    return all(hasattr(task, a) for a in ("_lib", "_handle")) and hasattr(fl, "MpFaceLandmarkerResultC")


def _raw_results(task, image, ts: int, want_names: bool = False) -> list:
    """``task.detect_for_video(image, ts)``'s faces read from MediaPipe's C result structs: what
    :meth:`LandmarkDetector._results` makes of the Python result, the same numbers (the structs' float32 are
    what MediaPipe's Python objects hold as floats), without one Python object per landmark and blendshape
    (478 + 52 a face: ~1 ms a frame, issue 36). The same C calls as MediaPipe's own ``detect_for_video``."""
    (fl,) = _mediapipe("mediapipe.tasks.python.vision.face_landmarker")
    from mediapipe.tasks.python.components.containers import category_c, landmark_c

    result_c = fl.MpFaceLandmarkerResultC()
    task._lib.MpFaceLandmarkerDetectForVideo(task._handle, image._image_ptr, None, ts, ctypes.byref(result_c))
    try:
        xyz = _c_fields(landmark_c.MpNormalizedLandmarkC, ("x", "y", "z"))
        score = _c_fields(category_c.MpCategoryC, ("score",))
        out = []
        for k in range(result_c.face_landmarks_count):
            lc = result_c.face_landmarks[k]
            pts = _c_array(lc.landmarks, lc.landmarks_count, xyz)
            scores, names = None, None
            if k < result_c.face_blendshapes_count:
                cc = result_c.face_blendshapes[k]
                scores = _c_array(cc.categories, cc.categories_count, score)[:, 0].copy()
                if want_names:  # read while the result is open (the C strings are freed with it)
                    cats = (cc.categories[j].category_name for j in range(cc.categories_count))
                    names = [c.decode("utf-8") if c else None for c in cats]
            m = None
            if k < result_c.facial_transformation_matrixes_count:
                m = result_c.facial_transformation_matrixes[k].to_numpy()
            out.append((pts, scores, names, m))
        return out
    finally:
        task._lib.MpFaceLandmarkerCloseResult(ctypes.byref(result_c))


class LandmarkDetector:
    """FaceLandmarker in VIDEO mode. Use as a context manager or call :meth:`close`.

    Args:
        model_path: a face_landmarker.task (see :func:`models.resolve_model`).
        num_faces: largest number of faces looked for per frame.
        min_confidence: detection / presence / tracking thresholds.
    """

    def __init__(self, model_path, num_faces: int = 1, min_confidence: float = 0.5):
        os.environ.setdefault("GLOG_minloglevel", "2")  # MediaPipe's C++ start-up chatter
        os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")
        base, fl, mode = _mediapipe(
            "mediapipe.tasks.python.core.base_options",
            "mediapipe.tasks.python.vision.face_landmarker",
            "mediapipe.tasks.python.vision.core.vision_task_running_mode",
        )
        opts = fl.FaceLandmarkerOptions(
            base_options=base.BaseOptions(model_asset_path=str(model_path)),
            running_mode=mode.VisionTaskRunningMode.VIDEO,
            num_faces=int(num_faces),
            min_face_detection_confidence=min_confidence,
            min_face_presence_confidence=min_confidence,
            min_tracking_confidence=min_confidence,
            output_face_blendshapes=True,
            output_facial_transformation_matrixes=True,
        )
        self._task = create_task(
            lambda: fl.FaceLandmarker.create_from_options(opts),
            f"{model_path}: MediaPipe cannot load the face landmarker model",
        )
        self._last_ts = -1
        self.last_ms = 0.0
        self._bs_map: np.ndarray | None = None
        # read the results from MediaPipe's C structs (:func:`_raw_results`) where this MediaPipe has them
        self.raw_results = _has_raw_results(self._task)

    def _blendshape_map(self, names) -> np.ndarray:
        # index into MediaPipe's category list for every ARKit name (-1: absent)
        m = np.full(len(ARKIT_NAMES), -1, np.int64)
        for k, name in enumerate(names):
            i = arkit_index(name or "")
            if i is not None:
                m[i] = k
        return m

    def _results(self, image, ts: int) -> list[tuple[np.ndarray, np.ndarray | None, list | None, np.ndarray | None]]:
        """Per face: landmarks (n, 3) float32, blendshape scores (float32) or None, their names (until the
        blendshape map is made, else None), the transformation matrix or None."""
        want_names = self._bs_map is None
        if self.raw_results:
            return _raw_results(self._task, image, ts, want_names)
        res = self._task.detect_for_video(image, ts)
        out = []
        for k, lms in enumerate(res.face_landmarks):
            # x, y, z of each landmark straight into float32 (the same rounding as np.array of (x, y, z) tuples)
            pts = np.fromiter(chain.from_iterable(map(_XYZ, lms)), np.float32, 3 * len(lms)).reshape(-1, 3)
            cats = res.face_blendshapes[k] if k < len(res.face_blendshapes) else None
            scores = np.array([c.score for c in cats], np.float32) if cats is not None else None
            names = [c.category_name for c in cats] if cats is not None and want_names else None
            mats = res.facial_transformation_matrixes
            out.append((pts, scores, names, mats[k] if k < len(mats) else None))
        return out

    def detect(self, frame_bgr: np.ndarray, timestamp_ms: int) -> list[FaceObservation]:
        """Faces in one BGR uint8 frame. Timestamps must increase; equal or older ones are bumped by 1 ms."""
        import cv2

        if frame_bgr is None or frame_bgr.ndim != 3 or frame_bgr.shape[2] != 3:
            raise ValueError(f"expected an (H, W, 3) BGR frame, got {None if frame_bgr is None else frame_bgr.shape}")
        ts = int(timestamp_ms)
        if ts <= self._last_ts:
            ts = self._last_ts + 1
        self._last_ts = ts
        rgb = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2RGB)
        image = mp_image(np.ascontiguousarray(rgb))
        t0 = time.perf_counter()
        faces = []
        for pts, scores, names, matrix in self._results(image, ts):
            bs = np.zeros(len(ARKIT_NAMES), np.float32)
            if scores is not None:
                if self._bs_map is None:
                    self._bs_map = self._blendshape_map(names or [])
                ok = self._bs_map >= 0
                bs[ok] = scores[self._bs_map[ok]]
            tf = None if matrix is None else np.asarray(matrix, np.float64).reshape(4, 4)
            faces.append(FaceObservation(pts, bs, tf))
        self.last_ms = (time.perf_counter() - t0) * 1000.0  # model + result conversion
        return faces

    def close(self) -> None:
        if self._task is not None:
            self._task.close()
            self._task = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


@dataclass
class _Track:
    face_id: int
    center: np.ndarray
    size: float
    last_seen_ms: float


@dataclass
class FaceTracker:
    """Stable identities for the faces of consecutive frames.

    Args:
        max_jump: largest centre displacement, in face widths, still counted as the same face.
        forget_ms: a track unseen for longer than this is dropped (its identity retired).
    """

    max_jump: float = 1.0
    forget_ms: float = 3000.0
    tracks: dict[int, _Track] = field(default_factory=dict)
    _next_id: int = 0

    def update(self, faces: list[FaceObservation], timestamp_ms: float) -> list[FaceObservation]:
        """Set ``face_id`` on every face (in place) and return the faces."""
        from scipy.optimize import linear_sum_assignment

        for tid in [t for t, tr in self.tracks.items() if timestamp_ms - tr.last_seen_ms > self.forget_ms]:
            del self.tracks[tid]
        ids = list(self.tracks)
        assigned: dict[int, int] = {}
        if faces and ids:
            cost = np.empty((len(faces), len(ids)))
            for a, f in enumerate(faces):
                for b, tid in enumerate(ids):
                    tr = self.tracks[tid]
                    cost[a, b] = np.linalg.norm(f.center - tr.center) / max(tr.size, 1e-6)
            rows, cols = linear_sum_assignment(cost)
            for a, b in zip(rows, cols):
                if cost[a, b] <= self.max_jump:
                    assigned[a] = ids[b]
        for a, f in enumerate(faces):
            tid = assigned.get(a, -1)
            if tid < 0:  # a new face (track ids count from 0)
                tid = self._next_id
                self._next_id += 1
            f.face_id = tid
            self.tracks[tid] = _Track(tid, f.center.copy(), f.size, timestamp_ms)
        return faces
