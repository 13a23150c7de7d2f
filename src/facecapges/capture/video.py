"""Frame sources for capture: a video file or a camera index, read with OpenCV.

``SOURCE`` that is all digits ("0", "1") is a camera index; anything else a file.
An unreadable file or a camera that cannot be opened is a :class:`UserError`.
Timestamps come from the frame index and the stream's frame rate for files (exact
and monotonic), and from the wall clock for cameras.

Damaged files: a frame that cannot be decoded in the middle of a file (the decoder
fails, later frames decode again) is replaced by the last good frame — its time slot
is kept, so the rest stays in sync with the audio — and counted in ``bad_frames``;
frames that fail at the end of the file up to its declared frame count are counted in
``missing_tail``. The caller reports both; a file is never cut short silently.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from facecapges.errors import UserError, file_error

if TYPE_CHECKING:
    import cv2


@dataclass
class FrameSource:
    cap: cv2.VideoCapture
    name: str
    fps: float
    n_frames: int | None  # None for cameras
    width: int
    height: int
    is_camera: bool
    bad_frames: int = 0  # undecodable frames held over (files)
    missing_tail: int = 0  # declared frames after the last decodable one (files)

    def frames(self, max_frames: int | None = None) -> Iterator[tuple[int, float, np.ndarray]]:
        """(index, timestamp_ms, BGR frame) until the stream ends or ``max_frames``."""
        i = 0
        t0 = time.monotonic()
        failed = 0  # consecutive undecodable frames not yet held over
        last = None
        while max_frames is None or i < max_frames:
            ok, frame = self.cap.read()
            if not ok or frame is None:
                if self.is_camera or self.n_frames is None or i + failed + 1 >= self.n_frames:
                    break
                failed += 1  # maybe a damaged stretch: try the next frame
                continue
            for _ in range(failed):  # a damaged stretch ended: hold the last good frame over it
                if max_frames is not None and i >= max_frames:
                    return
                yield i, i * 1000.0 / self.fps, last if last is not None else frame
                i += 1
            self.bad_frames += failed
            failed = 0
            if max_frames is not None and i >= max_frames:
                return
            ts = (time.monotonic() - t0) * 1000.0 if self.is_camera else i * 1000.0 / self.fps
            yield i, ts, frame
            last = frame
            i += 1
        if self.n_frames is not None and not self.is_camera and (max_frames is None or i < max_frames):
            self.missing_tail = max(0, min(self.n_frames, max_frames or self.n_frames) - i)

    def close(self) -> None:
        self.cap.release()


def _quiet_opencv() -> None:
    """OpenCV's and FFmpeg's own console warnings off: our errors and warnings say what matters."""
    import os

    os.environ.setdefault("OPENCV_LOG_LEVEL", "SILENT")
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")  # AV_LOG_QUIET
    os.environ.setdefault("OPENCV_VIDEOIO_DEBUG", "0")
    import cv2

    try:
        cv2.setLogLevel(0)  # type: ignore[attr-defined]  # LOG_LEVEL_SILENT; missing from OpenCV's stubs
    except AttributeError:
        pass


def open_file(path: str | Path, decode_threads: int | None = None) -> cv2.VideoCapture:
    """OpenCV's reader of the video file ``path``; ``decode_threads``: how many threads FFmpeg decodes it with
    (None: FFmpeg's choice, a thread per core and more). A file played at its frame rate (``live --realtime``)
    needs one: at 15 fps of 512² the extra threads only add their hand-overs (docs/performance.md)."""
    import cv2

    if decode_threads is not None:
        cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG, [cv2.CAP_PROP_N_THREADS, int(decode_threads)])
        if cap.isOpened():
            return cap
        cap.release()  # no FFmpeg backend: whichever OpenCV has, with its own threads
    return cv2.VideoCapture(str(path))


def open_source(source: str | int, decode_threads: int | None = None) -> FrameSource:
    """Open a video file or a camera index (see the module docstring); ``decode_threads``: :func:`open_file`."""
    _quiet_opencv()
    import cv2

    s = str(source)
    if s.isdigit():
        cap = cv2.VideoCapture(int(s))
        if not cap.isOpened():
            raise UserError(f"camera {s} cannot be opened (no such device, or it is busy)")
        ok, frame = cap.read()
        if not ok or frame is None:
            cap.release()
            raise UserError(f"camera {s} opened but gives no frames")
        fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
        h, w = frame.shape[:2]
        cap.release()
        cap = cv2.VideoCapture(int(s))
        return FrameSource(cap, f"camera {s}", float(fps), None, w, h, True)
    p = Path(s)
    if not p.is_file():
        raise file_error(p, "video not found")
    cap = open_file(p, decode_threads)
    if not cap.isOpened():
        raise file_error(p, "cannot be read as a video")
    ok, frame = cap.read()
    if not ok or frame is None:
        cap.release()
        raise file_error(p, "cannot be read as a video (no decodable frame)")
    fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
    if not (0 < fps < 1000):
        fps = 25.0
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0) or None
    h, w = frame.shape[:2]
    cap.release()
    cap = open_file(p, decode_threads)  # reopen rather than seek: seeking is unreliable for some codecs
    return FrameSource(cap, str(p), fps, n, w, h, False)


def check_video(path: str | Path, what: str = "video") -> Path:
    """Check before any model loads that ``path`` is a video OpenCV decodes (one frame is read); UserError if not."""
    p = Path(path)
    if not p.exists():
        raise file_error(p, f"{what} not found")
    if not p.is_file():
        raise file_error(p, f"{what} is not a regular file")
    open_source(str(p)).close()
    return p


CAMERA_HINT = "check the device index (--camera) and that no other program uses it"


def check_camera(index: int) -> None:
    """Check before any model loads that camera ``index`` opens (it is closed again; ``open_source`` opens it
    for the session). On Linux a missing ``/dev/videoN`` is refused without starting OpenCV."""
    import sys

    if index < 0:
        raise UserError(f"--camera {index}: a camera index is 0 or more")
    if sys.platform.startswith("linux") and not Path(f"/dev/video{index}").exists():
        raise UserError(f"camera {index} cannot be opened (no /dev/video{index}); {CAMERA_HINT}")
    _quiet_opencv()
    import cv2

    cap = cv2.VideoCapture(int(index))
    try:
        if not cap.isOpened():
            raise UserError(f"camera {index} cannot be opened (no such device, or it is busy); {CAMERA_HINT}")
    finally:
        cap.release()
