"""Overlay video: landmarks, head axes and live bars of the main blendshapes.

Drawn with OpenCV on the BGR frame; written as H.264 MP4 through imageio-ffmpeg's
bundled ffmpeg (no system ffmpeg needed). Axis colours: X red, Y green, Z blue
(head frame of :mod:`head_pose`, drawn 8 cm long from the nose tip).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from facecapges.arkit import ARKIT_NAMES

BAR_CHANNELS = (
    "jawOpen",
    "eyeBlinkLeft",
    "eyeBlinkRight",
    "mouthSmileLeft",
    "mouthSmileRight",
    "browInnerUp",
    "browDownLeft",
    "mouthPucker",
    "eyeWideLeft",
    "noseSneerLeft",
)
NOSE_TIP = 1


def draw_overlay(frame_bgr: np.ndarray, result, fps_text: str = "") -> np.ndarray:
    """A copy of ``frame_bgr`` with ``result`` (:class:`pipeline.CaptureResult`) drawn on it."""
    import cv2

    img = frame_bgr.copy()
    h, w = img.shape[:2]
    if result.face_found and result.landmarks is not None:
        pts = (result.landmarks[:, :2] * [w, h]).astype(np.int32)
        for x, y in pts[:468:2]:
            img[max(0, min(h - 1, y)), max(0, min(w - 1, x))] = (0, 255, 255)
        o = pts[NOSE_TIP].astype(np.float64)
        L = 0.18 * float(np.ptp(pts[:, 0]))
        R = result.head_R
        for axis, col in ((0, (0, 0, 255)), (1, (0, 255, 0)), (2, (255, 0, 0))):
            d = R[:, axis]
            end = o + L * np.array([d[0], -d[1]])  # camera Y up → image y down (orthographic drawing)
            cv2.line(img, tuple(o.astype(int)), tuple(end.astype(int)), col, 2, cv2.LINE_AA)
    status = "face" if result.face_found else "LOST (hold/ease)"
    yaw, pitch, roll = np.degrees(result.head_angles)
    cv2.putText(
        img,
        f"{status} yaw {yaw:+.0f} pitch {pitch:+.0f} roll {roll:+.0f} {fps_text}",
        (8, 18),
        cv2.FONT_HERSHEY_SIMPLEX,
        0.45,
        (255, 255, 255),
        1,
        cv2.LINE_AA,
    )
    x0, y0, bw = 8, 30, 90
    for k, name in enumerate(BAR_CHANNELS):
        v = float(result.weights52[ARKIT_NAMES.index(name)])
        y = y0 + 14 * k
        cv2.rectangle(img, (x0, y), (x0 + bw, y + 10), (60, 60, 60), -1)
        cv2.rectangle(img, (x0, y), (x0 + int(bw * v), y + 10), (0, 200, 255), -1)
        cv2.putText(img, name, (x0 + bw + 4, y + 9), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (255, 255, 255), 1, cv2.LINE_AA)
    return img


class OverlayWriter:
    """The overlay video: frames into :class:`facecapges.io.mp4.Mp4Writer` (H.264, even sizes)."""

    def __init__(self, path: str | Path, width: int, height: int, fps: float):
        from facecapges.io.mp4 import Mp4Writer

        self.w, self.h = width + width % 2, height + height % 2
        self._mp4 = Mp4Writer(path, fps, crf=23)

    def write(self, frame_bgr: np.ndarray) -> None:
        self._mp4.write(frame_bgr)

    def close(self) -> None:
        if self._mp4.frames:
            self._mp4.close()
        else:
            self._mp4.abort()
