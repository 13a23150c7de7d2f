"""The BEAT dataset on disk: clip names, the train/val/test split, the side files, and the skeleton check.

Clip names
----------
BEAT names every file of a take ``{speaker}_{name}_{type}_{start}_{end}.{ext}``, e.g.
``2_scott_0_1_1.bvh``: speaker id 2, performer "scott", recording type 0, clip 1 to
clip 1. In BEAT's English part type 0 is *speech* (a prepared monologue, clips
1–118) and type 1 is *conversation* (free talk with a partner). BEAT's other language
blocks continue the numbering (CaMN's loader treats types 0, 2, 4, 6 as speech), so
here an **even type is speech and an odd type is conversation**.

The **clip number** is the ``start`` field (the 4th). BEAT writes ``start == end`` for
ordinary clips; when a file spans several (``start < end``) it is filed under its
first clip.

Split (BEAT / CaMN's English rule)
----------------------------------
* **test**: speech clips 1–8 and 65, 73, 81, 87, 95, 103, 111; conversation clip 1;
* **val**: speech clips 57–64 and 72, 80, 86, 94, 102, 110, 118; conversation 12;
* **train**: everything else.

The single test/val clips above are the first/last clip of each emotion block of the
speech script (:data:`SPEECH_EMOTION_BLOCKS`), so every emotion is represented.

Side files
----------
* ``.txt`` — semantic relevance, one segment per line, tab separated:
  ``name  start_s  end_s  duration_s  score  keywords``. Frame i (time i/fps) gets the
  **maximum** score of the segments with ``start <= i/fps <= end``, 0 elsewhere
  (:func:`read_semantic`). An optional header line (non-numeric start/end) is skipped.
* ``.csv`` — emotion (:func:`read_emotion`). BEAT labels a clip with one of 8
  emotions, ``EMOTIONS`` = neutral 0, happiness 1, anger 2, sadness 3, contempt 4,
  surprise 5, fear 6, disgust 7. Accepted layouts (comma, semicolon or tab separated;
  an optional header row of non-numeric cells is skipped; a label is an integer
  0–7 or one of the emotion words):

  1. *per clip*: a single label (one row, one cell) → every frame gets it;
  2. *timed*: rows ``time_s, label`` → each frame takes the label of the last row
     whose time is <= the frame's time (frames before the first row take the first);
  3. *per frame*: a single column of several labels → one label per frame of the
     model rate, cut or padded with the last label to the clip length.

A clip without one of these files gets zeros plus a presence flag ``False``.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facecapges.errors import UserError, file_error, require_file
from facecapges.skeleton import N_JOINTS, UPPER_BODY, Skeleton

SPEECH, CONVERSATION = "speech", "conversation"

TEST_SPEECH = frozenset(range(1, 9)) | {65, 73, 81, 87, 95, 103, 111}
VAL_SPEECH = frozenset(range(57, 65)) | {72, 80, 86, 94, 102, 110, 118}
TEST_CONVERSATION = frozenset({1})
VAL_CONVERSATION = frozenset({12})

EMOTIONS: tuple[str, ...] = ("neutral", "happiness", "anger", "sadness", "contempt", "surprise", "fear", "disgust")
#: Speech clip numbers of each emotion in BEAT's script (inclusive ranges).
SPEECH_EMOTION_BLOCKS: tuple[tuple[int, int], ...] = (
    (1, 64),
    (65, 72),
    (73, 80),
    (81, 86),
    (87, 94),
    (95, 102),
    (103, 110),
    (111, 118),
)

#: File kinds of a clip, by suffix.
SUFFIXES = {".bvh": "bvh", ".wav": "wav", ".json": "json", ".txt": "txt", ".csv": "csv"}

_NAME_RE = re.compile(r"^(\d+)_([A-Za-z][A-Za-z0-9-]*)_(\d+)_(\d+)_(\d+)$")


@dataclass(frozen=True)
class ClipName:
    """A parsed BEAT clip name."""

    speaker: int
    performer: str
    type: int
    start: int
    end: int

    @property
    def stem(self) -> str:
        return f"{self.speaker}_{self.performer}_{self.type}_{self.start}_{self.end}"

    @property
    def kind(self) -> str:
        """``"speech"`` (even type) or ``"conversation"`` (odd type)."""
        return SPEECH if self.type % 2 == 0 else CONVERSATION

    @property
    def clip_number(self) -> int:
        """The clip number the split uses: the ``start`` field."""
        return self.start


def parse_clip_name(stem: str) -> ClipName | None:
    """Parse ``"2_scott_0_1_1"`` (no suffix) into a :class:`ClipName`; None if it is not a BEAT name."""
    m = _NAME_RE.match(stem)
    if not m:
        return None
    spk, name, typ, start, end = m.groups()
    return ClipName(int(spk), name, int(typ), int(start), int(end))


def split_of(clip: ClipName) -> str:
    """``"train"``, ``"val"`` or ``"test"`` by the BEAT rule (module docstring)."""
    n = clip.clip_number
    if clip.kind == SPEECH:
        return "test" if n in TEST_SPEECH else "val" if n in VAL_SPEECH else "train"
    return "test" if n in TEST_CONVERSATION else "val" if n in VAL_CONVERSATION else "train"


def emotion_from_clip_number(clip: ClipName) -> int | None:
    """BEAT's scripted emotion of a speech clip from its number (CaMN's rule); None for conversation."""
    if clip.kind != SPEECH:
        return None
    for label, (lo, hi) in enumerate(SPEECH_EMOTION_BLOCKS):
        if lo <= clip.clip_number <= hi:
            return label
    return None


@dataclass
class ClipFiles:
    """The files of one BEAT clip found under a root (absent kinds are None)."""

    clip: ClipName
    files: dict[str, Path] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.clip.stem

    def get(self, kind: str) -> Path | None:
        return self.files.get(kind)


def find_clips(root: str | Path) -> list[ClipFiles]:
    """All BEAT clips under ``root`` (recursively), grouped by name, sorted by (speaker, type, clip).

    Files whose names do not follow the BEAT pattern are ignored. Two files of the same
    kind for one clip (e.g. the same ``.bvh`` in two folders) are an error.
    """
    root = Path(root)
    if not root.exists():
        raise file_error(root, "folder not found")
    if not root.is_dir():
        raise file_error(root, "is not a folder")
    groups: dict[str, ClipFiles] = {}
    for p in sorted(root.rglob("*")):
        kind = SUFFIXES.get(p.suffix.lower())
        if kind is None or not p.is_file():
            continue
        clip = parse_clip_name(p.stem)
        if clip is None:
            continue
        g = groups.setdefault(clip.stem, ClipFiles(clip))
        if kind in g.files:
            raise file_error(p, f"clip {clip.stem} has two {kind} files: {g.files[kind]} and {p}")
        g.files[kind] = p
    return sorted(groups.values(), key=lambda c: (c.clip.speaker, c.clip.type, c.clip.start, c.clip.end))


# ----------------------------------------------------------------- semantic .txt
def read_semantic(path: str | Path, n_frames: int, fps: float) -> np.ndarray:
    """Per-frame semantic relevance score (n_frames,) float32 from a BEAT ``.txt`` file."""
    path = require_file(path, "semantic file")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise file_error(path, "not a text file") from None
    times = np.arange(n_frames, dtype=np.float64) / fps
    out = np.zeros(n_frames, np.float64)
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        cols = line.rstrip("\r\n").split("\t")
        try:
            start, end, score = float(cols[1]), float(cols[2]), float(cols[4])
        except (IndexError, ValueError):
            if lineno == 1 and len(cols) >= 5:  # a header row
                continue
            raise file_error(
                path, f"line {lineno}: expected tab-separated name, start, end, duration, score, keywords"
            ) from None
        if not (np.isfinite(start) and np.isfinite(end) and np.isfinite(score)) or end < start:
            raise file_error(path, f"line {lineno}: bad segment start={cols[1]} end={cols[2]} score={cols[4]}")
        inside = (times >= start - 1e-9) & (times <= end + 1e-9)
        out[inside] = np.maximum(out[inside], score)
    return out.astype(np.float32)


# ------------------------------------------------------------------ emotion .csv
def _label(cell: str) -> int | None:
    cell = cell.strip().lower()
    if cell in EMOTIONS:
        return EMOTIONS.index(cell)
    try:
        v = float(cell)
    except ValueError:
        return None
    if v != int(v) or not 0 <= v < len(EMOTIONS):
        raise ValueError(f"emotion label {cell!r} is not an integer 0-{len(EMOTIONS) - 1}")
    return int(v)


def read_emotion(path: str | Path, n_frames: int, fps: float) -> np.ndarray:
    """Per-frame emotion label (n_frames,) int16 from an emotion ``.csv`` (layouts in the module docstring)."""
    path = require_file(path, "emotion file")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise file_error(path, "not a text file") from None
    lines = [ln for ln in text.splitlines() if ln.strip()]
    if not lines:
        raise file_error(path, "emotion file is empty")
    delim = next((d for d in ",;\t" if d in text), ",")
    rows = [[c for c in r if c.strip()] for r in csv.reader(lines, delimiter=delim)]
    rows = [r for r in rows if r]
    try:
        if len(rows) > 1 and not any(_is_number(c) or c.strip().lower() in EMOTIONS for c in rows[0]):
            rows = rows[1:]  # a header row
        width = {len(r) for r in rows}
        if width == {1}:
            labels = [_label(r[0]) for r in rows]
            if any(lab is None for lab in labels):
                bad = next(r[0] for r, lab in zip(rows, labels) if lab is None)
                raise ValueError(f"unknown emotion label {bad!r} (use 0-{len(EMOTIONS) - 1} or {', '.join(EMOTIONS)})")
            if len(labels) == 1:
                return np.full(n_frames, labels[0], np.int16)
            arr = np.asarray(labels[:n_frames], np.int16)
            return np.concatenate([arr, np.full(n_frames - len(arr), arr[-1], np.int16)])
        if width == {2}:
            if not all(_is_number(r[0]) for r in rows):
                raise ValueError("two-column rows must be 'time_s, label'")
            t = np.array([float(r[0]) for r in rows])
            if np.any(np.diff(t) < 0):
                raise ValueError("rows must be 'time_s, label' with increasing times")
            labels = [_label(r[1]) for r in rows]
            if any(lab is None for lab in labels):
                raise ValueError(f"unknown emotion label in {[r[1] for r in rows][:5]}")
            idx = np.searchsorted(t, np.arange(n_frames) / fps + 1e-9, side="right") - 1
            return np.asarray(labels, np.int16)[np.clip(idx, 0, len(labels) - 1)]
        raise ValueError(f"rows have {sorted(width)} columns; expected 1 (label) or 2 (time_s, label)")
    except ValueError as exc:
        raise file_error(path, f"bad emotion CSV: {exc}") from None


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def check_skeleton(skel: Skeleton, path: Path, reference: tuple[Skeleton, Path] | None) -> None:
    """Raise a UserError naming ``path`` if ``skel`` is not a usable BEAT skeleton."""
    missing = skel.missing(UPPER_BODY)
    if missing:
        shown = ", ".join(missing[:6]) + (", …" if len(missing) > 6 else "")
        raise file_error(
            path, f"wrong skeleton: missing {len(missing)} of the {N_JOINTS} BEAT upper-body joints ({shown})"
        )
    if reference is not None:
        ref, ref_path = reference
        if not ref.is_same_tree(skel) or ref.channels != skel.channels:
            raise file_error(path, f"wrong skeleton: joint tree or channel layout differs from {ref_path.name}")


def require_beat_clips(root: str | Path) -> list[ClipFiles]:
    """:func:`find_clips`, but an error when the folder holds no BEAT files at all."""
    clips = find_clips(root)
    if not clips:
        raise UserError(f"{root}: no BEAT files found (expected names like 2_scott_0_1_1.bvh / .wav)")
    return clips
