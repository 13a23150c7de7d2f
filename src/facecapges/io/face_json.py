"""BEAT facial JSON: ARKit blendshape weights over time (and optionally head rotation).

Format (BEAT's ``.json`` face files; written back the same way)::

    {"names": ["browDownLeft", ..., "noseSneerRight"],      # K channel names
     "frames": [{"time": 0.0,   "weights": [w_0, ..., w_K-1]},
                {"time": 0.0167, "weights": [...]}, ...]}

* BEAT stores the 51 ARKit names without ``tongueOut`` at 60 fps. Weights are
  reordered into the project's 52-channel ARKit order
  (:data:`facecapges.arkit.ARKIT_NAMES`; ``tongueOut`` is 0 when absent) by
  :func:`facecapges.arkit.to_arkit52`. Names are matched case-insensitively; unknown
  names are returned to the caller (who reports them) and their channels ignored.
* **Frame rate** is derived from the ``time`` fields: ``1 / median(Δtime)``, rounded
  to an integer when within 0.01 of one. Without times (fewer than two frames, or a
  frame without ``time``) it falls back to :data:`BEAT_FACE_FPS` = 60. Times that do
  not increase, or a rate outside :data:`FPS_RANGE`, are a UserError (a 15 fps track
  read as 60 fps would play 4× fast).
* **Head rotation** (an extension of BEAT's format, written by our capture tools):
  each frame may carry ``"head_rot6d": [6 floats]``, the global head rotation as
  rot6d (first two matrix columns, see :mod:`facecapges.rotations`). It is read only
  when every frame has it.
* NaN or infinite weights, frames of the wrong length, or JSON that is not this shape
  raise :class:`~facecapges.errors.UserError` naming the file.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facecapges.arkit import ARKIT_NAMES, N_BLENDSHAPES, to_arkit52
from facecapges.errors import file_error, require_file

BEAT_FACE_FPS = 60.0
FPS_RANGE = (1.0, 1000.0)  # frame rates a face track may have


@dataclass
class FaceTrack:
    """Face weights (T, 52) in ARKit order at ``fps``; optional head rot6d (T, 6)."""

    weights: np.ndarray
    fps: float
    unknown_names: list[str] = field(default_factory=list)
    head_rot6d: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return int(self.weights.shape[0])


def _fps_from_times(times: list[float | None], path: Path | None = None) -> float:
    if len(times) < 2 or any(t is None for t in times):
        return BEAT_FACE_FPS
    dt = np.diff(np.asarray(times, dtype=np.float64))
    if not np.all(np.isfinite(dt)) or np.any(dt <= 0):
        bad = int(np.argmax(~np.isfinite(dt) | (dt <= 0))) + 1
        raise file_error(path or "face JSON", f"frame times must increase; frame {bad} has time {times[bad]} after "
                                              f"{times[bad - 1]}")
    fps = 1.0 / float(np.median(dt))
    if not FPS_RANGE[0] <= fps <= FPS_RANGE[1]:
        raise file_error(path or "face JSON", f"frame times are {float(np.median(dt)):g} s apart ({fps:.3g} fps); "
                                              f"a face track runs at {FPS_RANGE[0]:g}–{FPS_RANGE[1]:g} fps")
    return float(round(fps)) if abs(fps - round(fps)) < 0.01 else fps


def read_face_json(path: str | Path) -> FaceTrack:
    """Read a BEAT face JSON file into a :class:`FaceTrack` (see the module docstring)."""
    path = require_file(path, "face JSON file")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise file_error(path, "not a text JSON file") from None
    except json.JSONDecodeError as exc:
        raise file_error(path, f"malformed JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    except (ValueError, RecursionError) as exc:  # nested deeper than the parser goes, huge integers
        raise file_error(path, f"malformed JSON ({exc.__class__.__name__})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("names"), list) or not isinstance(doc.get("frames"), list):
        raise file_error(path, "face JSON must be an object with a 'names' list and a 'frames' list")
    names = doc["names"]
    if not names or not all(isinstance(n, str) for n in names):
        raise file_error(path, "'names' must be a non-empty list of blendshape names")
    frames = doc["frames"]
    if not frames:
        raise file_error(path, "face JSON has no frames")
    rows, times, heads = [], [], []
    for i, fr in enumerate(frames):
        w = fr.get("weights") if isinstance(fr, dict) else None
        if not isinstance(w, list) or len(w) != len(names):
            got = len(w) if isinstance(w, list) else "no"
            raise file_error(path, f"frame {i} has {got} weights, 'names' lists {len(names)}")
        rows.append(w)
        t = fr.get("time")
        times.append(float(t) if isinstance(t, (int, float)) and not isinstance(t, bool) else None)
        heads.append(fr.get("head_rot6d"))
    try:
        weights = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError):
        raise file_error(path, "face weights must all be numbers") from None
    if weights.ndim != 2 or weights.dtype == object:
        raise file_error(path, "face weights must all be numbers (one list of numbers per frame)")
    if not np.isfinite(weights).all():
        bad = int(np.argwhere(~np.isfinite(weights))[0, 0])
        raise file_error(path, f"face weights contain NaN or infinite values (first in frame {bad})")
    head = None
    if all(h is not None for h in heads):
        try:
            head = np.asarray(heads, dtype=np.float64)
        except (TypeError, ValueError):
            raise file_error(path, "'head_rot6d' values must be numbers") from None
        if head.shape != (len(frames), 6):
            raise file_error(path, f"'head_rot6d' must hold 6 numbers per frame, got shape {head.shape}")
        if not np.isfinite(head).all() or np.abs(head).max(initial=0.0) > 1e6:
            raise file_error(path, "'head_rot6d' contains NaN, infinite or out-of-range values")
        head = head.astype(np.float32)
    if np.abs(weights).max(initial=0.0) > 1e6:  # finite here, infinite as float32: not a weight
        raise file_error(path, "face weights out of range (blendshape weights are about 0 to 1)")
    out, unknown = to_arkit52(weights, names)
    return FaceTrack(weights=out, fps=_fps_from_times(times, path), unknown_names=unknown, head_rot6d=head)


def write_face_json(path: str | Path, weights52: np.ndarray, fps: float,
                    head_rot6d: np.ndarray | None = None) -> Path:
    """Write (T, 52) ARKit-order weights (and optional (T, 6) head rot6d) as face JSON.

    All 52 names are written (``tongueOut`` included); ``time`` of frame i is i / fps.
    The file is written under a temporary name and renamed. Returns the path.
    """
    w = np.asarray(weights52, dtype=np.float64)
    if w.ndim != 2 or w.shape[1] != N_BLENDSHAPES:
        raise ValueError(f"weights52 must be (T, {N_BLENDSHAPES}), got {w.shape}")
    if not np.isfinite(w).all():
        raise ValueError("weights52 contains NaN or infinite values")
    if fps <= 0 or not math.isfinite(fps):
        raise ValueError(f"fps must be positive, got {fps}")
    if head_rot6d is not None:
        head_rot6d = np.asarray(head_rot6d, dtype=np.float64)
        if head_rot6d.shape != (w.shape[0], 6):
            raise ValueError(f"head_rot6d must be ({w.shape[0]}, 6), got {head_rot6d.shape}")
    frames = []
    for i, row in enumerate(w):
        fr: dict = {"time": round(i / fps, 6), "weights": [round(float(v), 6) for v in row]}
        if head_rot6d is not None:
            fr["head_rot6d"] = [round(float(v), 7) for v in head_rot6d[i]]
        frames.append(fr)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(json.dumps({"names": list(ARKIT_NAMES), "frames": frames}, separators=(",", ":")),
                   encoding="utf-8")
    tmp.replace(path)
    return path
