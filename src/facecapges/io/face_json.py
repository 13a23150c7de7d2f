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

Writing (:func:`write_face_json`): two layouts.

* ``"beat"`` (the default, :data:`FACE_LAYOUTS`) — exactly what BEAT's own loaders
  read: the **51** names of :data:`facecapges.arkit.BEAT_NAMES` (no ``tongueOut``) at
  **60 fps**. BEAT's loader derives the frame step from ``frames[10]`` and
  ``frames[20]`` (``ceil(1 / Δt) // pose_fps``) and keeps every 4th frame for 15 fps,
  then normalises with the dataset's 51-channel mean/std — a 52-weight file fails
  there with a (52,) vs (51,) shape error, a 15 fps file read as 60 fps shrinks 8 s to
  2 s. Model-rate frames are resampled to 60 fps by linear interpolation of the
  weights (and slerp of ``head_rot6d``) between neighbouring frames; every 4th output
  frame (``time = k/15``) is exactly input frame ``k``, so BEAT's decimation gets our
  frames back unchanged. The last input frame is held to the end of its period, so
  the duration is kept (T input frames at 15 fps → 4T frames, T/15 s).
* ``"full"`` — all **52** names (``tongueOut`` included) at the frames' own rate,
  nothing resampled.

Both carry a top-level ``"fps"`` and may carry per-frame extensions (``head_rot6d``,
and the capture's ``face_found``/``distance_m``, taken from the frame that covers each
output time); BEAT's loaders ignore the keys they do not know.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facecapges.arkit import ARKIT_NAMES, BEAT_NAMES, N_BLENDSHAPES, to_arkit52
from facecapges.errors import UserError, file_error, require_file

BEAT_FACE_FPS = 60.0
FACE_LAYOUTS = ("beat", "full")


def check_face_layout(layout: str) -> str:
    """``layout`` if it is one of :data:`FACE_LAYOUTS`, else the user's error (``--face-json``)."""
    if layout not in FACE_LAYOUTS:
        raise UserError(f"--face-json {layout}: choose {' or '.join(FACE_LAYOUTS)}")
    return layout


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
        raise file_error(
            path or "face JSON", f"frame times must increase; frame {bad} has time {times[bad]} after {times[bad - 1]}"
        )
    fps = 1.0 / float(np.median(dt))
    if not FPS_RANGE[0] <= fps <= FPS_RANGE[1]:
        raise file_error(
            path or "face JSON",
            f"frame times are {float(np.median(dt)):g} s apart ({fps:.3g} fps); "
            f"a face track runs at {FPS_RANGE[0]:g}–{FPS_RANGE[1]:g} fps",
        )
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


def _resample_grid(T: int, src_fps: float, dst_fps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For output frames ``j / dst_fps`` covering T source frames: (k0, k1, fraction) to blend (last frame held)."""
    n = max(1, int(math.ceil(T * dst_fps / src_fps - 1e-6)))
    pos = np.minimum(np.arange(n) * (src_fps / dst_fps), T - 1)
    k0 = np.floor(pos + 1e-9).astype(np.int64)
    return k0, np.minimum(k0 + 1, T - 1), np.maximum(pos - k0, 0.0)[:, None]


WRITE_BLOCK = 4096  # output frames made and written at a time


def _frame_block(w, head_rot6d, extras, k0, k1, a, first: int, out_fps: float, n_names: int) -> list[dict]:
    """Face JSON frames ``first`` … of output frames blending source frames k0, k1 by a."""
    rows = (1.0 - a) * w[k0] + a * w[k1]
    head = None
    if isinstance(head_rot6d, tuple):  # resampled: (quaternions of the source frames,)
        from facecapges import rotations as rot

        q = head_rot6d[0]
        head = rot.matrix_to_rot6d(rot.quaternion_to_matrix(rot.quaternion_slerp(q[k0], q[k1], a)))
    elif head_rot6d is not None:
        head = head_rot6d[k0]
    frames = []
    for i, row in enumerate(rows):
        fr: dict = {"time": round((first + i) / out_fps, 6), "weights": [round(float(v), 6) for v in row[:n_names]]}
        if head is not None:
            fr["head_rot6d"] = [round(float(v), 7) for v in head[i]]
        for key, values in extras.items():
            fr[key] = values[int(k0[i])]
        frames.append(fr)
    return frames


def write_face_json(
    path: str | Path,
    weights52: np.ndarray,
    fps: float,
    head_rot6d: np.ndarray | None = None,
    layout: str = "beat",
    extras: dict[str, list] | None = None,
) -> Path:
    """Write (T, 52) ARKit-order weights at ``fps`` (and optional (T, 6) head rot6d) as face JSON.

    ``layout`` is ``"beat"`` (51 names at 60 fps, BEAT's loaders) or ``"full"`` (52
    names at ``fps``), module docstring. ``extras`` maps a per-frame key to T values
    written into each frame (the value of the frame covering that time). ``time`` of
    output frame j is j / output fps. The file is written under a temporary name and
    renamed. Returns the path.
    """
    w = np.asarray(weights52, dtype=np.float64)
    if w.ndim != 2 or w.shape[1] != N_BLENDSHAPES:
        raise ValueError(f"weights52 must be (T, {N_BLENDSHAPES}), got {w.shape}")
    if not np.isfinite(w).all():
        raise ValueError("weights52 contains NaN or infinite values")
    if fps <= 0 or not math.isfinite(fps):
        raise ValueError(f"fps must be positive, got {fps}")
    if layout not in FACE_LAYOUTS:
        raise ValueError(f"layout must be one of {FACE_LAYOUTS}, got {layout!r}")
    if head_rot6d is not None:
        head_rot6d = np.asarray(head_rot6d, dtype=np.float64)
        if head_rot6d.shape != (w.shape[0], 6):
            raise ValueError(f"head_rot6d must be ({w.shape[0]}, 6), got {head_rot6d.shape}")
    extras = dict(extras or {})
    for key, values in extras.items():
        if len(values) != w.shape[0]:
            raise ValueError(f"extras[{key!r}] must have {w.shape[0]} values, got {len(values)}")
    names = list(ARKIT_NAMES)
    out_fps = float(fps)
    k0 = k1 = np.arange(w.shape[0])
    a = np.zeros((w.shape[0], 1))
    if layout == "beat":
        names = list(BEAT_NAMES)
        out_fps = BEAT_FACE_FPS
        if w.shape[0] and abs(fps - out_fps) > 1e-9:
            k0, k1, a = _resample_grid(w.shape[0], fps, out_fps)
            if head_rot6d is not None:
                from facecapges import rotations as rot

                head_rot6d = (rot.matrix_to_quaternion(rot.rot6d_to_matrix(head_rot6d)),)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".part")
    dumps = functools.partial(json.dumps, separators=(",", ":"))
    with tmp.open("w", encoding="utf-8") as f:  # frame blocks as they are made: memory flat in the length
        f.write('{"names":' + dumps(names) + ',"fps":' + dumps(out_fps) + ',"frames":[')
        for b in range(0, len(k0), WRITE_BLOCK):
            sl = slice(b, b + WRITE_BLOCK)
            frames = _frame_block(w, head_rot6d, extras, k0[sl], k1[sl], a[sl], b, out_fps, len(names))
            f.write(("," if b else "") + ",".join(dumps(fr) for fr in frames))
        f.write("]}")
    tmp.replace(path)
    return path
