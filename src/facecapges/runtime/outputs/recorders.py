"""File sinks of the runtime: BVH motion and BEAT-format face JSON recorders.

A sink has ``write(OutputFrame)`` (called once per frame by the scheduler, cheap: it
only appends) and ``close()`` (safe to call twice). The BVH is written as it happens
(a growing :class:`facecapges.io.bvh.BvhWriter`, valid after every second of frames,
so a long ``live --record`` keeps no motion in memory and a cut-off one still opens);
the face JSON is written atomically by ``close`` (its frames wait in a temporary file, a
second at a time, so it keeps no face in memory either) through
:func:`facecapges.io.face_json.write_face_json`. ``close`` runs on Ctrl-C and on
SIGTERM/SIGHUP (the command line turns both into an interrupt). Other sinks: :mod:`.vmc` (VMC over OSC/UDP) and the WebSocket feed in
:mod:`.viewer`.

* :class:`BvhRecorder` — the full BEAT skeleton of the checkpoint at the model rate;
  the 47 generated joints, every other joint at rest (``skeleton.pose_to_motion``).
* :class:`FaceJsonRecorder` — the ARKit weights the avatar showed, with the head
  rotation (rot6d) per frame: BEAT's layout (51 names, 60 fps) or ``layout="full"``
  (52 names at the model rate), :func:`facecapges.io.face_json.write_face_json`.
* :class:`MemoryRecorder` — keeps quaternions and weights in memory for rendering the
  avatar video after ``run``.
* :class:`ForFace` — passes on one face's frames only (a recorder per face for ``--faces N``).
* :func:`file_recorders` / :func:`per_face` — the one rule of ``run`` and ``live`` for several
  faces: face ``i`` of N > 1 writes ``motion_{i+1}.bvh`` / ``face_{i+1}.json`` and each of its sinks
  sees only its own frames (one face: ``motion.bvh`` / ``face.json``, no filter).

Every sink satisfies :class:`facecapges.runtime.interfaces.Sink`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, TYPE_CHECKING

import numpy as np

from facecapges.runtime.frames import OutputFrame

if TYPE_CHECKING:
    from facecapges.io.bvh import BvhWriter
    from facecapges.runtime.interfaces import Sink


class BvhRecorder:
    """The BVH of the frames shown, a second (``block`` frames) at a time. A full second is converted and written
    over the next second's frames, a step a frame (:meth:`_steps`: the rotations, the Euler angles, then two rows
    of text a frame, then the write), so no frame pays for all of it (issue 36: the frame that wrote a second took
    ~1 ms, the output stage's p99); the file on disk is then one second behind, and valid, as before."""

    ROWS_A_STEP = 2  # 15 rows in 8 steps, 11 steps in all: done before the next second is full

    def __init__(self, path: str | Path, skeleton, fps: float, compiled: bool = False):
        """``compiled``: the text by :mod:`facecapges.io.bvh_text` (Numba: ``live`` and ``run``, which load it
        anyway), a second's rows in one step, where it writes ``%``'s text on this machine."""
        self.path, self.skeleton, self.fps = Path(path), skeleton, fps
        self._lines: Callable[[np.ndarray], list[str]] | None = None
        if compiled:
            from facecapges.io import bvh_text

            self._lines = bvh_text.motion_lines if bvh_text.checked() else None
        self.poses: list[np.ndarray] = []  # the frames of the current second, not yet on disk
        self.block = max(1, int(round(fps)))
        self.writer: BvhWriter | None = None
        self.pending: Iterator[None] | None = None  # the last full second's steps not yet taken
        self.closed = False

    def write(self, out: OutputFrame) -> None:
        self.poses.append(np.asarray(out.pose, np.float32))
        if len(self.poses) >= self.block:
            self._finish()  # (done already unless a second is shorter than its steps)
            self.pending, self.poses = self._steps(self.poses), []
        elif self.pending is not None and next(self.pending, True):
            self.pending = None

    def _finish(self) -> None:
        if self.pending is not None:
            for _ in self.pending:
                pass
            self.pending = None

    def _steps(self, poses: list[np.ndarray]) -> Iterator[None]:
        """Converts and writes ``poses``, yielding between steps (a generator: one ``next`` a frame)."""
        from facecapges.io.bvh import BvhWriter, motion_rows
        from facecapges.rotations import normalize_rot6d
        from facecapges.skeleton import pose_to_motion

        p = normalize_rot6d(np.stack(poses).astype(np.float64))
        yield
        motion = pose_to_motion(self.skeleton, p)
        yield
        lines: list[str] = []
        if self._lines is not None:
            lines = self._lines(motion)
            yield
        else:
            fmt, rows = motion_rows(motion)
            for i in range(0, len(rows), self.ROWS_A_STEP):
                lines += [fmt % tuple(row) for row in rows[i : i + self.ROWS_A_STEP]]
                yield
        if self.writer is None:  # the file appears with its first second (a BVH of no frame is not valid)
            self.writer = BvhWriter(self.path, self.skeleton, None, self.fps)
        self.writer.write_lines(lines)
        self.writer.flush()

    def close(self) -> Path | None:
        if self.closed:
            return None
        self.closed = True
        self._finish()
        if self.poses:
            self.pending, self.poses = self._steps(self.poses), []
            self._finish()
        return self.writer.close() if self.writer is not None else None


class FaceJsonRecorder:
    """The face JSON is one document written at ``close``; until then each second of frames (52 weights and a
    6-value head, float32) goes to an anonymous temporary file (``tempfile.TemporaryFile``: removed when closed,
    also if the process dies), so a long ``live --record`` keeps one second of face in memory, not all of it
    (issue #38's soak: the lists of every frame's arrays grew 0.43 MB a minute)."""

    WIDTH = 52 + 6

    def __init__(self, path: str | Path, fps: float, layout: str = "beat"):
        self.path, self.fps, self.layout = Path(path), fps, layout
        self.rows: list[np.ndarray] = []  # the frames of the current second, not yet spooled
        self.block = max(1, int(round(fps)))
        self.spool: IO[bytes] | None = None  # the temporary file of the earlier seconds (float32 rows of WIDTH)
        self.frames = 0
        self.closed = False

    def write(self, out: OutputFrame) -> None:
        row = np.empty(self.WIDTH, np.float32)
        row[:52], row[52:] = np.asarray(out.face, np.float32).reshape(52), np.asarray(out.head, np.float32).reshape(6)
        self.rows.append(row)
        self.frames += 1
        if len(self.rows) >= self.block:
            self._spool()

    def _spool(self) -> None:
        import tempfile

        if not self.rows:
            return
        if self.spool is None:
            self.spool = tempfile.TemporaryFile(prefix="facecapges-face-")  # noqa: SIM115 (open until close())
        self.spool.write(np.stack(self.rows).tobytes())
        self.rows = []

    def close(self) -> Path | None:
        if self.closed:
            return None
        self.closed = True
        self._spool()
        if self.spool is None:
            return None
        from facecapges.io.face_json import write_face_json

        try:
            self.spool.seek(0)
            data = np.frombuffer(self.spool.read(), np.float32).reshape(-1, self.WIDTH)
        finally:
            self.spool.close()
            self.spool = None
        return write_face_json(self.path, data[:, :52], self.fps, data[:, 52:], layout=self.layout)


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


def file_recorders(folder: Path, skeleton, fps: float, face_layout: str, index: int, faces: int) -> list[Sink]:
    """Face ``index``'s motion BVH and face JSON in ``folder`` (``_{index+1}`` suffixed when ``faces`` > 1)."""
    sfx = "" if faces == 1 else f"_{index + 1}"
    return [
        BvhRecorder(folder / f"motion{sfx}.bvh", skeleton, fps, compiled=True),  # (Numba: loaded by the engines)
        FaceJsonRecorder(folder / f"face{sfx}.json", fps, face_layout),
    ]


def per_face(faces: int, sinks_of: Callable[[int], list[Sink]]) -> list[Sink]:
    """Every face's sinks (``sinks_of(i)``, face by face), each behind :class:`ForFace` when ``faces`` > 1."""
    sinks: list[Sink] = []
    for i in range(faces):
        per = sinks_of(i)
        sinks += per if faces == 1 else [ForFace(i, x) for x in per]
    return sinks
