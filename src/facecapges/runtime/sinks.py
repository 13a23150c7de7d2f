"""File sinks of the runtime: BVH motion and BEAT-format face JSON recorders.

A sink has ``write(OutputFrame)`` (called once per frame by the scheduler, cheap: it
only appends) and ``close()`` (writes the file atomically through
:func:`facecapges.io.bvh.write_bvh` / :func:`facecapges.io.face_json.write_face_json`;
safe to call twice). ``close`` is what makes Ctrl-C in ``live --record`` leave whole
files behind. Other sinks: :mod:`.vmc` (VMC over OSC/UDP) and the WebSocket feed in
:mod:`.web_server`.

* :class:`BvhRecorder` — the full BEAT skeleton of the checkpoint at the model rate;
  the 47 generated joints, every other joint at rest (``skeleton.pose_to_motion``).
* :class:`FaceJsonRecorder` — the 52 ARKit weights the avatar showed, with the head
  rotation (rot6d) per frame, at the model rate.
* :class:`MemoryRecorder` — keeps quaternions and weights in memory for rendering the
  avatar video after ``run``.
* :class:`ForFace` — passes on one face's frames only (a recorder per face for ``--faces N``).

Every sink satisfies :class:`facecapges.runtime.interfaces.Sink`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from facecapges.runtime.frames import OutputFrame


class BvhRecorder:
    def __init__(self, path: str | Path, skeleton, fps: float):
        self.path, self.skeleton, self.fps = Path(path), skeleton, fps
        self.poses: list[np.ndarray] = []
        self.closed = False

    def write(self, out: OutputFrame) -> None:
        self.poses.append(np.asarray(out.pose, np.float32))

    def close(self) -> Path | None:
        if self.closed:
            return None
        self.closed = True
        if not self.poses:
            return None
        from facecapges.io.bvh import write_bvh
        from facecapges.rotations import normalize_rot6d
        from facecapges.skeleton import pose_to_motion

        poses = normalize_rot6d(np.stack(self.poses).astype(np.float64))
        return write_bvh(self.path, self.skeleton, pose_to_motion(self.skeleton, poses), self.fps)


class FaceJsonRecorder:
    def __init__(self, path: str | Path, fps: float):
        self.path, self.fps = Path(path), fps
        self.weights: list[np.ndarray] = []
        self.heads: list[np.ndarray] = []
        self.closed = False

    def write(self, out: OutputFrame) -> None:
        self.weights.append(np.asarray(out.face, np.float32))
        self.heads.append(np.asarray(out.head, np.float32))

    def close(self) -> Path | None:
        if self.closed:
            return None
        self.closed = True
        if not self.weights:
            return None
        from facecapges.io.face_json import write_face_json

        return write_face_json(self.path, np.stack(self.weights), self.fps, np.stack(self.heads))


class MemoryRecorder:
    """(T, 47, 4) quaternions, (T, 47, 6) poses, (T, 52) weights, (T, 6) heads and face-found flags,
    for the videos and the report of ``run``."""

    def __init__(self):
        self.quats: list[np.ndarray] = []
        self.poses: list[np.ndarray] = []
        self.weights: list[np.ndarray] = []
        self.heads: list[np.ndarray] = []
        self.found: list[bool] = []

    def write(self, out: OutputFrame) -> None:
        self.quats.append(np.asarray(out.quats, np.float32))
        self.poses.append(np.asarray(out.pose, np.float32))
        self.weights.append(np.asarray(out.face, np.float32))
        self.heads.append(np.asarray(out.head, np.float32))
        self.found.append(bool(out.face_found))

    def close(self) -> None:
        return None


class ForFace:
    """A sink that receives only face ``index``'s frames of a several-face session (``--faces N``)."""

    def __init__(self, index: int, sink):
        self.index, self.sink = int(index), sink

    def write(self, out: OutputFrame) -> None:
        if out.face_index == self.index:
            self.sink.write(out)

    def close(self):
        return self.sink.close()
