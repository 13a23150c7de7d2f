"""BVH reading and writing (hierarchy + motion), exactly as the file declares it.

A BVH file is a joint tree (``ROOT``/``JOINT``/``End Site`` with ``OFFSET`` and
``CHANNELS``) followed by ``MOTION``: ``Frames: T``, ``Frame Time: dt`` and T lines of
channel values. Rotation channels are Euler angles in **degrees**, applied in the order
the ``CHANNELS`` line lists them (see :mod:`facecapges.rotations`); positions and
offsets are in the file's unit (BEAT: centimetres).

:func:`read_bvh` returns a :class:`BVH` (a :class:`~facecapges.skeleton.Skeleton`, the
motion as a (T, C) float array in file channel order, and the frame rate from the
header). :func:`write_bvh` writes one back; the two round-trip.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facecapges.errors import file_error, require_file
from facecapges.skeleton import Skeleton

_VALID_CHANNELS = {"Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation"}


@dataclass
class BVH:
    """A parsed BVH file: skeleton, motion (T, C) in file channel order, fps."""

    skeleton: Skeleton
    motion: np.ndarray
    fps: float

    @property
    def n_frames(self) -> int:
        return int(self.motion.shape[0])


class _Hierarchy:
    """The joints of a BVH ``HIERARCHY`` as its lines are read, one token list at a time."""

    def __init__(self) -> None:
        self.names: list[str] = []
        self.parents: list[int] = []
        self.offsets: list[list[float]] = []
        self.channels: list[list[str]] = []
        self.end_sites: dict[int, np.ndarray] = {}
        self.stack: list[int] = []
        self.pending_end = False

    def token(self, tok: list[str]) -> bool:
        """Read one line's tokens; True at ``MOTION``. ValueError / IndexError on a malformed line."""
        key = tok[0]
        if key in ("ROOT", "JOINT"):
            if len(tok) < 2:
                raise ValueError(f"{key} without a name")
            if key == "ROOT" and self.names:
                raise ValueError("more than one ROOT")
            self.names.append(tok[1])
            self.parents.append(self.stack[-1] if self.stack else -1)
            self.offsets.append([0.0, 0.0, 0.0])
            self.channels.append([])
        elif key == "End":
            self.pending_end = True
        elif key == "{":
            if self.pending_end:
                self.stack.append(-2)  # marker: inside an End Site
            else:
                self.stack.append(len(self.names) - 1)
        elif key == "}":
            if not self.stack:
                raise ValueError("unbalanced '}'")
            self.stack.pop()
            self.pending_end = False
        elif key == "OFFSET":
            vals = [float(v) for v in tok[1:4]]
            if len(vals) != 3:
                raise ValueError("OFFSET needs 3 numbers")
            if self.stack and self.stack[-1] == -2:
                owner = [s for s in self.stack if s >= 0][-1]
                self.end_sites[owner] = np.array(vals)
            else:
                self.offsets[-1] = vals
        elif key == "CHANNELS":
            n = int(tok[1])
            ch = tok[2 : 2 + n]
            if len(ch) != n or not set(ch) <= _VALID_CHANNELS:
                raise ValueError(f"bad CHANNELS line {' '.join(tok)!r}")
            self.channels[-1] = ch
        elif key == "MOTION":
            if self.stack:
                raise ValueError("hierarchy not closed before MOTION")
            return True
        else:
            raise ValueError(f"unexpected token {key!r}")
        return False

    def skeleton(self) -> Skeleton:
        return Skeleton(
            names=self.names,
            parents=np.array(self.parents),
            offsets=np.array(self.offsets, dtype=np.float64),
            channels=self.channels,
            end_sites=self.end_sites,
        )


def _parse_hierarchy(lines: list[str], path: Path) -> tuple[Skeleton, int]:
    if not lines or lines[0].strip() != "HIERARCHY":
        raise file_error(path, "not a BVH file (first line is not 'HIERARCHY')")
    h = _Hierarchy()
    i = 1
    while i < len(lines):
        tok = lines[i].split()
        i += 1
        if not tok:
            continue
        try:
            if h.token(tok):
                break
        except (ValueError, IndexError) as exc:
            raise file_error(path, f"malformed BVH hierarchy at line {i}: {exc}") from None
    else:
        raise file_error(path, "truncated BVH: no MOTION section")
    if not h.names:
        raise file_error(path, "BVH hierarchy has no joints")
    return h.skeleton(), i


MIN_FRAME_TIME = 0.001  # 1000 fps: the fastest motion rate read (header values outside are refused)
MAX_FRAME_TIME = 1.0  # 1 fps


def read_bvh(path: str | Path) -> BVH:
    """Read a BVH file. Raises :class:`~facecapges.errors.UserError` naming the file."""
    path = require_file(path, "BVH file")
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except UnicodeDecodeError:
        raise file_error(path, "not a text BVH file") from None
    lines = text.splitlines()
    skel, i = _parse_hierarchy(lines, path)
    try:
        n_frames = int(lines[i].split(":")[1])
        frame_time = float(lines[i + 1].split(":")[1])
    except (IndexError, ValueError):
        raise file_error(path, "malformed MOTION header (expected 'Frames:' and 'Frame Time:')") from None
    if not MIN_FRAME_TIME <= frame_time <= MAX_FRAME_TIME:
        raise file_error(
            path,
            f"Frame Time {frame_time:g} s is out of range ({MIN_FRAME_TIME:g}–{MAX_FRAME_TIME:g} s, i.e. 1–1000 fps)",
        )
    if n_frames < 1:
        raise file_error(path, f"Frames: {n_frames}; a BVH needs at least one motion frame")
    rows = [ln for ln in lines[i + 2 :] if ln.strip()]
    if len(rows) < n_frames:
        raise file_error(path, f"truncated BVH: header says {n_frames} frames, file has {len(rows)}")
    try:
        motion = np.array([np.array(r.split(), dtype=np.float64) for r in rows[:n_frames]])
    except ValueError:
        raise file_error(path, "malformed motion line (not all numbers)") from None
    if motion.ndim != 2 or motion.shape[1] != skel.n_channels:
        widths = sorted({len(r.split()) for r in rows[:n_frames]})
        raise file_error(path, f"motion lines have {widths} values, the hierarchy declares {skel.n_channels} channels")
    if not np.isfinite(motion).all():
        raise file_error(path, "motion contains NaN or infinite values")
    fps = 1.0 / frame_time
    if abs(fps - round(fps)) < 0.01:  # "0.0666667" means 15 fps, "0.008333" means 120
        fps = float(round(fps))
    return BVH(skeleton=skel, motion=motion, fps=fps)


def write_bvh(path: str | Path, skeleton: Skeleton, motion: np.ndarray, fps: float) -> Path:
    """Write ``motion`` (T, C) on ``skeleton`` as a BVH file at ``fps``. Returns the path.

    The file is written to a temporary name and renamed, so a crash never leaves half
    a file behind.
    """
    motion = np.asarray(motion, dtype=np.float64)
    if motion.ndim != 2 or motion.shape[1] != skeleton.n_channels:
        raise ValueError(f"motion must be (T, {skeleton.n_channels}), got {motion.shape}")
    with BvhWriter(path, skeleton, motion.shape[0], fps) as w:
        w.write(motion)
    return Path(path)


class BvhWriter:
    """A BVH file written block by block (memory flat in its length): the header with
    ``n_frames``, then :meth:`write` as many (n, C) blocks as make ``n_frames`` rows.

    Written under ``PATH.part`` and renamed by :meth:`close` once every declared frame is
    there; :meth:`abort` (or an exception inside ``with``) removes the partial file.

    ``n_frames=None`` (a live recording of unknown length): the file is written at
    ``PATH`` itself and is a valid BVH after every :meth:`flush` — the frame count is a
    fixed-width field (``Frames: 0000000042``) rewritten in place — so a recording cut
    off at any moment still opens.
    """

    COUNT_WIDTH = 10

    def __init__(self, path: str | Path, skeleton: Skeleton, n_frames: int | None, fps: float):
        self.path = Path(path)
        self.growing = n_frames is None
        self.skeleton, self.n_frames, self.written = skeleton, (0 if n_frames is None else int(n_frames)), 0
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = self.path if self.growing else self.path.with_name(self.path.name + ".part")
        self._f = self.tmp.open("w", encoding="utf-8")
        head = "\n".join(_header_lines(skeleton, self.n_frames, fps)) + "\n"
        if self.growing:
            head = head.replace("Frames: 0\n", "Frames: " + "0" * self.COUNT_WIDTH + "\n")
            self._count_at = len(head.encode("utf-8").split(b"\nFrames: ")[0]) + len("\nFrames: ")
        self._f.write(head)

    def flush(self) -> None:
        """Growing file: patch the frame count and push everything to disk (a valid BVH now)."""
        self._f.flush()
        if self.growing:
            end = self._f.tell()
            self._f.seek(self._count_at)
            self._f.write(f"{self.written:0{self.COUNT_WIDTH}d}")
            self._f.seek(end)
            self._f.flush()

    def write(self, motion: np.ndarray) -> None:
        motion = np.asarray(motion, dtype=np.float64)
        if motion.ndim != 2 or motion.shape[1] != self.skeleton.n_channels:
            raise ValueError(f"motion must be (n, {self.skeleton.n_channels}), got {motion.shape}")
        if not self.growing and self.written + len(motion) > self.n_frames:
            raise ValueError(f"more than the {self.n_frames} frames declared")
        fmt, rows = motion_rows(motion)
        self.write_lines([fmt % tuple(row) for row in rows])

    def write_lines(self, lines: list[str]) -> None:
        """Frames already written as text, one line each (:func:`motion_rows`' format of each row): ``live``'s
        recorder formats a second of frames over the next second's frames (issue 36: no frame pays for all 15)."""
        if not self.growing and self.written + len(lines) > self.n_frames:
            raise ValueError(f"more than the {self.n_frames} frames declared")
        if lines:
            self._f.write("\n".join(lines) + "\n")
        self.written += len(lines)

    def close(self) -> Path:
        if self.growing:
            self.flush()
            self._f.close()
            return self.path
        self._f.close()
        if self.written != self.n_frames:
            self.abort()
            raise ValueError(f"{self.written} frames written, {self.n_frames} declared")
        self.tmp.replace(self.path)
        return self.path

    def abort(self) -> None:
        if self.growing:  # what was recorded stays, as a valid file
            self.close()
            return
        self._f.close()
        self.tmp.unlink(missing_ok=True)

    def __enter__(self) -> BvhWriter:
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def motion_rows(motion: np.ndarray) -> tuple[str, list[list[float]]]:
    """A block of motion (n, C) float64 as a row format and the rows' numbers: ``fmt % tuple(row)`` is a row's line
    of the MOTION section. One %-format per row (the text of f"{v:.6f}" for each value, ~3x faster: live's recorder,
    issue 36); a column that is +0.0 in every row of the block (the joints at rest: 87 of BEAT's 228) is the literal
    "0.000000" in the format, so only the others are converted (the same text, issue 36)."""
    zero = ~(motion.any(axis=0) | np.signbit(motion).any(axis=0))
    fmt = " ".join(["0.000000" if z else "%.6f" for z in zero.tolist()])
    return fmt, (motion[:, ~zero] if zero.any() else motion).tolist()


def _header_lines(skeleton: Skeleton, n_frames: int, fps: float) -> list[str]:
    """HIERARCHY … MOTION, Frames, Frame Time: the lines before the motion rows."""
    out: list[str] = ["HIERARCHY"]
    children = skeleton.children()

    def emit(j: int, depth: int) -> None:
        ind = "\t" * depth
        kind = "ROOT" if skeleton.parents[j] < 0 else "JOINT"
        out.append(f"{ind}{kind} {skeleton.names[j]}")
        out.append(f"{ind}{{")
        o = skeleton.offsets[j]
        out.append(f"{ind}\tOFFSET {o[0]:.6f} {o[1]:.6f} {o[2]:.6f}")
        ch = skeleton.channels[j]
        out.append(f"{ind}\tCHANNELS {len(ch)} {' '.join(ch)}".rstrip())
        for c in children[j]:
            emit(c, depth + 1)
        if j in skeleton.end_sites:
            e = skeleton.end_sites[j]
            out.append(f"{ind}\tEnd Site")
            out.append(f"{ind}\t{{")
            out.append(f"{ind}\t\tOFFSET {e[0]:.6f} {e[1]:.6f} {e[2]:.6f}")
            out.append(f"{ind}\t}}")
        out.append(f"{ind}}}")

    for root in (j for j in range(skeleton.n_joints) if skeleton.parents[j] < 0):
        emit(root, 0)
    out.append("MOTION")
    out.append(f"Frames: {n_frames}")
    out.append(f"Frame Time: {1.0 / fps:.7f}")
    return out
