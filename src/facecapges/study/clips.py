"""The study's material: ``CLIPS.yaml`` — N clips, each with its speech, face track and K BVHs.

Format (paths are relative to the YAML file's folder; ids and system names may use
letters, digits, ``_``, ``-`` and ``.``)::

    fps: 15                # optional: playback rate of the study (default 15, the model rate)
    tolerance_frames: 1    # optional: allowed length mismatch, in frames (default 1)
    systems: [facecapges, camn, ground_truth]   # optional: the K systems, in this order
                                                # (default: the systems of the first clip)
    clips:
      - id: scott_1
        audio: media/2_scott_0_1_1.wav     # any format facecapges.io.audio reads
        face: media/2_scott_0_1_1.json     # BEAT face JSON (optional: neutral face)
        bvh:
          facecapges: out/ours/2_scott_0_1_1.bvh
          camn: out/camn/2_scott_0_1_1.bvh
          ground_truth: beat/2_scott_0_1_1.bvh

Every system needs a BVH for every clip (thesis 5.2.2: the same speech and face track
for every system, so the body motion is the only difference). Checks, each a
:class:`~facecapges.errors.UserError` naming the clip and system:

* a missing BVH entry or file, a system not in ``systems``;
* lengths: the audio sets a clip's duration D. Each BVH must have D·fps_bvh frames at
  its own frame rate, within ``tolerance_frames``; the face track must last D within
  ``tolerance_frames`` frames of the study rate. (BEAT's own wav files run a few
  frames longer than their motion — raise ``tolerance_frames`` for them knowingly.)
* the face track gives the 52 ARKit weights only; a ``head_rot6d`` in it is ignored,
  the head moves as each system's BVH says (thesis 5.2.2 keeps each model's own head);
* every BVH must have the avatar's BEAT skeleton, and all BVHs the same joint tree
  (one avatar is built from the first BVH's skeleton; only the rotations of each BVH
  are played, so bone offsets may differ slightly between systems).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facecapges.errors import UserError, file_error, require_file
from facecapges.timing import AUDIO_SR, MODEL_FPS

_ID = re.compile(r"^[A-Za-z0-9_.-]+$")


@dataclass
class Clip:
    """One clip after validation: audio (S,) at 16 kHz, optional face track, one BVH per system."""

    id: str
    audio_path: Path
    face_path: Path | None
    bvh_paths: dict[str, Path]
    audio: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, np.float32))  # loaded by validation
    duration: float = 0.0


@dataclass
class ClipSet:
    path: Path
    fps: float
    tolerance_frames: float
    systems: list[str]
    clips: list[Clip]

    @property
    def clip_ids(self) -> list[str]:
        return [c.id for c in self.clips]


def _load_yaml(path: Path) -> dict:
    import yaml

    from facecapges.io.yaml_text import safe_load

    try:
        doc = safe_load(path.read_text(encoding="utf-8"))  # nesting bounded: a deep file fails at once
    except UnicodeDecodeError:
        raise file_error(path, "not a text YAML file") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise file_error(path, f"malformed YAML{where}: {getattr(exc, 'problem', exc)}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("clips"), list) or not doc["clips"]:
        raise file_error(path, "must be a mapping with a non-empty 'clips' list (see facecapges.study.clips)")
    return doc


def _positive(path: Path, doc: dict, key: str, default: float, allow_zero: bool = False) -> float:
    v = doc.get(key, default)
    bad = isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v)
    if bad or v < 0 or (v == 0 and not allow_zero):
        raise file_error(path, f"'{key}' must be a positive number, got {v!r}")
    return float(v)


def _name(path: Path, value, what: str) -> str:
    if not isinstance(value, str) or not _ID.match(value):
        raise file_error(path, f"{what} {value!r} must be a non-empty name of letters, digits, '_', '-' or '.'")
    return value


def parse_clips(path: str | Path) -> ClipSet:
    """Read and check the structure of CLIPS.yaml (files exist, every clip has every system)."""
    path = require_file(path, "clips file")
    doc = _load_yaml(path)
    base = path.parent
    fps = _positive(path, doc, "fps", float(MODEL_FPS))
    tol = _positive(path, doc, "tolerance_frames", 1.0, allow_zero=True)
    raw = doc["clips"]
    systems = doc.get("systems")
    if systems is None:
        first = raw[0].get("bvh") if isinstance(raw[0], dict) else None
        systems = list(first) if isinstance(first, dict) else []
    if not isinstance(systems, list) or len(systems) < 2:
        raise file_error(path, f"a study needs at least two systems, got {systems!r}")
    systems = [_name(path, s, "system") for s in systems]
    if len(set(systems)) != len(systems):
        raise file_error(path, f"system names repeat: {systems}")
    clips: list[Clip] = []
    for i, entry in enumerate(raw):
        if not isinstance(entry, dict):
            raise file_error(path, f"clip {i + 1} must be a mapping with 'id', 'audio' and 'bvh'")
        cid = _name(path, entry.get("id"), f"clip {i + 1} id")
        if cid in [c.id for c in clips]:
            raise file_error(path, f"clip id {cid!r} is used twice")
        if not isinstance(entry.get("audio"), str):
            raise file_error(path, f"clip {cid!r} has no 'audio' file")
        audio = require_file(base / entry["audio"], f"audio of clip {cid!r}")
        face = entry.get("face")
        if face is not None and not isinstance(face, str):
            raise file_error(path, f"clip {cid!r}: 'face' must be a file name")
        face_path = require_file(base / face, f"face track of clip {cid!r}") if face else None
        bvh = entry.get("bvh")
        if not isinstance(bvh, dict):
            raise file_error(path, f"clip {cid!r} has no 'bvh' mapping (system: file)")
        extra = [s for s in bvh if s not in systems]
        if extra:
            raise file_error(
                path, f"clip {cid!r} has a BVH for system {extra[0]!r}, which is not one of the systems {systems}"
            )
        paths = {}
        for s in systems:
            if not isinstance(bvh.get(s), str):
                raise file_error(path, f"clip {cid!r} has no BVH for system {s!r}")
            paths[s] = require_file(base / bvh[s], f"BVH of clip {cid!r}, system {s!r}")
        clips.append(Clip(cid, audio, face_path, paths))
    return ClipSet(path, fps, tol, systems, clips)


def load_clips(path: str | Path):
    """Parse CLIPS.yaml and check every file's content and length. Returns (ClipSet, motions, faces).

    ``motions[clip][system]`` is the :class:`~facecapges.io.bvh.BVH`; ``faces[clip]`` the
    :class:`~facecapges.io.face_json.FaceTrack` or None.
    """
    cs = parse_clips(path)  # structure first: a typo is reported before the heavy imports

    from facecapges.avatar.body import check_skeleton
    from facecapges.io.audio import load_audio
    from facecapges.io.bvh import read_bvh
    from facecapges.io.face_json import read_face_json

    motions: dict[str, dict] = {}
    faces: dict[str, object] = {}
    ref = None
    for clip in cs.clips:
        clip.audio = load_audio(clip.audio_path, AUDIO_SR)
        clip.duration = len(clip.audio) / AUDIO_SR
        motions[clip.id] = {}
        for s in cs.systems:
            where = f"{cs.path}: clip {clip.id!r}, system {s!r} ({clip.bvh_paths[s]})"
            b = read_bvh(clip.bvh_paths[s])
            check_skeleton(b.skeleton, where)
            if ref is None:
                ref = (b.skeleton, where)
            elif not b.skeleton.is_same_tree(ref[0]):
                raise UserError(
                    f"{where}: its skeleton's joints differ from those of {ref[1]}; every BVH must "
                    "have the same BEAT joint tree"
                )
            expected = clip.duration * b.fps
            if abs(b.n_frames - expected) > cs.tolerance_frames + 1e-6:
                raise UserError(
                    f"{where}: {b.n_frames} frames at {b.fps:g} fps ({b.n_frames / b.fps:.3f} s) but the clip's "
                    f"audio lasts {clip.duration:.3f} s ({expected:.1f} frames); all versions of a clip must be "
                    f"as long as its audio (tolerance {cs.tolerance_frames:g} frame; 'tolerance_frames' in the clips file "
                    "sets it)"
                )
            motions[clip.id][s] = b
        if clip.face_path is not None:
            tr = read_face_json(clip.face_path)
            face_dur = tr.n_frames / tr.fps
            if abs(face_dur - clip.duration) * cs.fps > cs.tolerance_frames + 1e-6:
                raise UserError(
                    f"{cs.path}: clip {clip.id!r}: the face track {clip.face_path} lasts {face_dur:.3f} s "
                    f"but the audio {clip.duration:.3f} s (tolerance {cs.tolerance_frames:g} frame at "
                    f"{cs.fps:g} fps)"
                )
            faces[clip.id] = tr
        else:
            faces[clip.id] = None
    return cs, motions, faces
