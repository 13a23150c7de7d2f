"""Frame sources for capture: a video file or a camera index, read with OpenCV.

``SOURCE`` that is all digits ("0", "1") is a camera index; anything else a file.
An unreadable file or a camera that cannot be opened is a :class:`UserError`.
Timestamps come from the frame index and the stream's frame rate for files (exact
and monotonic), and from the wall clock for cameras.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from facecapges.errors import UserError, file_error


@dataclass
class FrameSource:
    cap: object
    name: str
    fps: float
    n_frames: int | None  # None for cameras
    width: int
    height: int
    is_camera: bool

    def frames(self, max_frames: int | None = None) -> Iterator[tuple[int, float, np.ndarray]]:
        """(index, timestamp_ms, BGR frame) until the stream ends or ``max_frames``."""
        i = 0
        t0 = time.monotonic()
        while max_frames is None or i < max_frames:
            ok, frame = self.cap.read()
            if not ok or frame is None:
                break
            ts = (time.monotonic() - t0) * 1000.0 if self.is_camera else i * 1000.0 / self.fps
            yield i, ts, frame
            i += 1

    def close(self) -> None:
        self.cap.release()


def open_source(source: str | int) -> FrameSource:
    """Open a video file or a camera index (see the module docstring)."""
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
    cap = cv2.VideoCapture(str(p))
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
    cap = cv2.VideoCapture(str(p))  # reopen rather than seek: seeking is unreliable for some codecs
    return FrameSource(cap, str(p), fps, n, w, h, False)
