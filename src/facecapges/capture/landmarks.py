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

    @functools.cached_property
    def center(self) -> np.ndarray:
        """Mean of the landmarks' x, y (normalised image coordinates); worked out once (the tracker reads it twice)."""
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
    import importlib.machinery  # imported before the finder is in place: its find_spec uses them, and importing
    import importlib.util  # them with the finder installed would ask the finder again, without end

    if all(n in sys.modules for n in names):
        return [sys.modules[n] for n in names]
    finder = _LazyDrawing()
    sys.meta_path.insert(0, finder)
    try:
        return [importlib.import_module(n) for n in names]
    finally:
        sys.meta_path.remove(finder)


_U8_P = ctypes.POINTER(ctypes.c_uint8)


@functools.cache
def _image_c():
    """(MediaPipe's ``Image`` module, its C library with the image functions' signatures registered — None where
    this MediaPipe's ``Image`` is not the ctypes one)."""
    (img,) = _mediapipe("mediapipe.tasks.python.vision.core.image")
    try:
        from mediapipe.tasks.python.core import mediapipe_c_bindings

        lib = mediapipe_c_bindings.load_raw_library(img._CTYPES_SIGNATURES)
        lib.MpImageCreateFromUint8Data  # noqa: B018 - the function this MediaPipe must have
    except (ImportError, AttributeError):
        lib = None
    return img, lib


def mp_image(rgb: np.ndarray):
    """A ``mediapipe.Image`` (SRGB) of an (H, W, 3) uint8 RGB array, C-contiguous.

    MediaPipe's ``Image(image_format=…, data=…)`` registers every image function's ctypes signature again on each
    call (a fifth of the image's cost, issue 36); this makes the same C call (the pixels copied into MediaPipe's
    own image, freed by the ``Image``) with the signatures registered once."""
    img, lib = _image_c()
    if lib is None or not rgb.flags.c_contiguous:
        return img.Image(image_format=img.ImageFormat.SRGB, data=rgb)
    h, w = rgb.shape[:2]
    ptr, err = ctypes.c_void_p(), ctypes.c_char_p()
    status = lib.MpImageCreateFromUint8Data(
        img.ImageFormat.SRGB, w, h, rgb.ctypes.data_as(_U8_P), rgb.size, ctypes.byref(ptr), ctypes.byref(err)
    )
    _check_status(lib, status, err)
    image = img.Image.__new__(img.Image)
    image._lib, image._image_ptr = lib, ptr
    return image


class _FrameImage:
    """One MediaPipe image (SRGB, ``h`` × ``w``) that every frame of a detector is converted into.

    A frame costs MediaPipe a copy of its pixels into an image of its own, made for that frame; the BGR → RGB
    conversion before it makes another array. Here the conversion writes straight into this image's pixels
    (``cv2.cvtColor(…, dst=)``, the same conversion), kept from frame to frame: one pass over the frame fewer and
    no image made and freed a frame (~0.25 ms of the main thread's CPU at 15 fps, issue 36). Safe only where
    MediaPipe is done with the image when the call returns, as in VIDEO mode: its ``TaskRunner::Process`` waits
    until the graph is idle before it returns the results. :meth:`of` gives None where this MediaPipe's image is
    not the ctypes one, or its rows are not contiguous."""

    def __init__(self, image, pixels: np.ndarray):
        self.image = image
        self.pixels = pixels  # (h, w, 3) uint8, writable, over the image's own buffer

    @classmethod
    def of(cls, h: int, w: int) -> _FrameImage | None:
        _, lib = _image_c()
        if lib is None:
            return None
        image = mp_image(np.zeros((h, w, 3), np.uint8))
        if not isinstance(getattr(image, "_image_ptr", None), ctypes.c_void_p):
            return None
        ptr = image._image_ptr
        if not lib.MpImageIsContiguous(ptr) or lib.MpImageGetWidthStep(ptr) != 3 * w:
            return None
        data, err = _U8_P(), ctypes.c_char_p()
        _check_status(lib, lib.MpImageDataUint8(ptr, ctypes.byref(data), ctypes.byref(err)), err)
        addr = ctypes.cast(data, ctypes.c_void_p).value
        if not addr:
            return None
        pixels = np.frombuffer(memoryview((ctypes.c_uint8 * (h * w * 3)).from_address(addr)), np.uint8).reshape(h, w, 3)
        return cls(image, pixels)

    def fill(self, frame_bgr: np.ndarray):
        """The image, holding ``frame_bgr`` (h, w, 3 uint8) converted to RGB."""
        import cv2

        out = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2RGB, dst=self.pixels)
        if out is not self.pixels:  # OpenCV made an array of its own (not expected): an image of it
            return mp_image(np.ascontiguousarray(out))
        return self.image


def _check_status(lib, status: int, err: ctypes.c_char_p) -> None:
    """MediaPipe's own error for a C call's status (its message freed), as its Python API raises it."""
    if status == 0 and err.value is None:
        return
    from mediapipe.tasks.python.core import mediapipe_c_utils

    try:
        mediapipe_c_utils.handle_status(status, err)
    finally:
        if err.value is not None:
            lib.MpErrorFree(err)


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
    """The ``dtype`` fields of ``n`` structs at ``ptr`` as an (n, fields) float32 copy: one strided copy when the
    fields follow each other in the struct (x, y, z of a landmark; a blendshape's score), else field by field."""
    names = dtype.names or ()
    if n == 0:
        return np.zeros((0, len(names)), np.float32)
    buf = memoryview((ctypes.c_char * (n * dtype.itemsize)).from_address(ctypes.cast(ptr, ctypes.c_void_p).value or 0))
    offsets = [dtype.fields[f][1] for f in names] if dtype.fields else []
    if offsets == list(range(offsets[0], offsets[0] + 4 * len(names), 4)):
        return np.ndarray((n, len(names)), np.float32, buf, offsets[0], (dtype.itemsize, 4)).copy()
    rows = np.frombuffer(buf, dtype)
    return np.stack([rows[f] for f in names], axis=1)


def _has_raw_results(task) -> bool:
    """Whether this MediaPipe's face landmarker is the ctypes one :func:`_raw_results` reads (the pinned 1.2.2 is)."""
    (fl,) = _mediapipe("mediapipe.tasks.python.vision.face_landmarker")
    return all(hasattr(task, a) for a in ("_lib", "_handle")) and hasattr(fl, "MpFaceLandmarkerResultC")


class DirectCalls:
    """A VIDEO-mode task's detect and close-result C functions, called on the caller's thread.

    MediaPipe's Python API sends every C call of a task through its ``SerialDispatcher``: a one-worker thread pool
    (``ThreadPoolExecutor-N_0``, one per task) that runs the call while the caller waits on a future — two thread
    hand-overs a frame (detect, close the result), ~0.3 ms of CPU on the two threads together (issue 36). The
    dispatcher serialises calls from many threads; a detector is called from one thread at a time, so the same C
    functions (the raw library under the dispatcher, their signatures as MediaPipe registered them) are called
    directly. None of the numbers change: the same C calls with the same arguments. ``name`` is the task's prefix
    in MediaPipe's C API: ``MpFaceLandmarker`` (default), ``MpPoseLandmarker``, ``MpHandLandmarker``."""

    def __init__(self, task, name: str = "MpFaceLandmarker"):
        raw = task._lib._lib  # the SerialDispatcher's ctypes.CDLL
        self.lib = raw
        self.detect = getattr(raw, f"{name}DetectForVideo")
        self.close_result = getattr(raw, f"{name}CloseResult")
        n = len(self.detect.argtypes or ())
        if n != 6 or not self.close_result.argtypes:  # not the signatures this was written for
            raise AttributeError(f"{name}DetectForVideo")

    @classmethod
    def of(cls, task, name: str = "MpFaceLandmarker") -> DirectCalls | None:
        try:
            return cls(task, name)
        except (AttributeError, TypeError):
            return None

    def detect_for_video(self, handle, image_ptr, ts: int, result_c) -> None:
        err = ctypes.c_char_p()
        status = self.detect(handle, image_ptr, None, ts, ctypes.byref(result_c), ctypes.byref(err))
        _check_status(self.lib, status, err)

    def result(self, task, image, ts: int, result_c, convert):
        """MediaPipe's own ``task.detect_for_video(image, ts)`` with the C calls on this thread: ``convert`` (the
        result class's ``from_ctypes``, as MediaPipe's method calls it) of the C result, then the result closed."""
        self.detect_for_video(task._handle, image._image_ptr, ts, result_c)
        try:
            return convert(result_c)
        finally:
            self.close_result(ctypes.byref(result_c))


class FrameImages:
    """The MediaPipe image (SRGB) of each BGR frame a detector is given: with ``keep`` (its C functions called
    directly in VIDEO mode: :class:`DirectCalls`) every frame is converted into one kept image
    (:class:`_FrameImage`), else into a new one."""

    def __init__(self, keep: bool):
        self.keep = keep
        self.kept: _FrameImage | None = None  # made for the first frame's size

    def __call__(self, frame_bgr: np.ndarray):
        h, w = frame_bgr.shape[:2]
        if self.keep and frame_bgr.dtype == np.uint8:
            fi = self.kept
            if fi is None or fi.pixels.shape[:2] != (h, w):
                fi = self.kept = _FrameImage.of(h, w)
            if fi is not None:
                return fi.fill(frame_bgr)
        import cv2

        return mp_image(np.ascontiguousarray(cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2RGB)))


def _raw_results(task, image, ts: int, want_names: bool = False, direct: DirectCalls | None = None) -> list:
    """``task.detect_for_video(image, ts)``'s faces read from MediaPipe's C result structs: what
    :meth:`LandmarkDetector._results` makes of the Python result, the same numbers (the structs' float32 are
    what MediaPipe's Python objects hold as floats), without one Python object per landmark and blendshape
    (478 + 52 a face: ~1 ms a frame, issue 36). The same C calls as MediaPipe's own ``detect_for_video``; with
    ``direct``, on this thread (:class:`DirectCalls`)."""
    (fl,) = _mediapipe("mediapipe.tasks.python.vision.face_landmarker")
    from mediapipe.tasks.python.components.containers import category_c, landmark_c

    result_c = fl.MpFaceLandmarkerResultC()
    if direct is not None:
        direct.detect_for_video(task._handle, image._image_ptr, ts, result_c)
    else:
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
        (direct.close_result if direct is not None else task._lib.MpFaceLandmarkerCloseResult)(ctypes.byref(result_c))


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
        # ...and call its C functions on this thread, not through MediaPipe's dispatcher thread (DirectCalls)
        self.direct = DirectCalls.of(self._task) if self.raw_results else None
        self._images = FrameImages(self.direct is not None)  # every frame into one kept image (direct calls only)

    def _blendshape_map(self, names) -> np.ndarray:
        # index into MediaPipe's category list for every ARKit name (-1: absent)
        m = np.full(len(ARKIT_NAMES), -1, np.int64)
        for k, name in enumerate(names):
            i = arkit_index(name or "")
            if i is not None:
                m[i] = k
        return m

    def _results(
        self, image, ts: int, want_names: bool
    ) -> list[tuple[np.ndarray, np.ndarray | None, list | None, np.ndarray | None]]:
        """Per face: landmarks (n, 3) float32, blendshape scores (float32) or None, their names (with
        ``want_names``, else None), the transformation matrix or None."""
        if self.raw_results:
            return _raw_results(self._task, image, ts, want_names, self.direct)
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

    def run_model(self, image, timestamp_ms: int) -> int:
        """MediaPipe's face landmarker alone on ``image`` (a MediaPipe SRGB image), called as :meth:`detect` calls
        it, none of our per-frame code: the number of faces found (``bench --only live``'s floor)."""
        return len(self._results(image, int(timestamp_ms), want_names=False))

    def detect(self, frame_bgr: np.ndarray, timestamp_ms: int) -> list[FaceObservation]:
        """Faces in one BGR uint8 frame. Timestamps must increase; equal or older ones are bumped by 1 ms."""
        if frame_bgr is None or frame_bgr.ndim != 3 or frame_bgr.shape[2] != 3:
            raise ValueError(f"expected an (H, W, 3) BGR frame, got {None if frame_bgr is None else frame_bgr.shape}")
        ts = int(timestamp_ms)
        if ts <= self._last_ts:
            ts = self._last_ts + 1
        self._last_ts = ts
        image = self._images(frame_bgr)  # the detector's own image with direct calls, else a new one
        t0 = time.perf_counter()
        faces = []
        # the blendshapes' names until their map is made (the first frame with a face)
        for pts, scores, names, matrix in self._results(image, ts, want_names=self._bs_map is None):
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
        self._images = FrameImages(False)
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
            if cost.shape == (1, 1) and np.isfinite(cost[0, 0]):  # one face, one track: the only assignment
                rows, cols = (0,), (0,)
            else:
                from scipy.optimize import linear_sum_assignment

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
