"""Build a cache (:mod:`facecapges.data.cache`) from a BEAT folder.

For every clip that has both a ``.bvh`` and a ``.wav`` (a *training clip*):

1. The BVH is read (:func:`facecapges.io.bvh.read_bvh`); its frame rate comes from
   the header's ``Frame Time``. The skeleton must contain all 47 UPPER_BODY joints and
   the same joint tree and channel layout as the first BVH of the run.
2. Motion is resampled to the cache rate with BEAT's rule
   (:func:`facecapges.timing.resample`: 120 → 15 keeps every 8th frame, 15 → 15 is
   unchanged). **T, the clip length, is the number of motion frames after this.**
3. ``pose`` (T, 47, 6) and ``head`` (T, 6) come from
   :func:`facecapges.skeleton.motion_to_pose`.
4. Audio is read at 16 kHz mono and cut/zero-padded to S = floor(T·sr/fps) samples.
5. Face JSON (60 fps in BEAT → every 4th frame at 15 fps) is resampled the same way
   and cut to T, or padded by repeating its last frame; semantic and emotion files are
   evaluated at the T frame times. Missing ones give zeros and ``*_present = False``.

**BEAT2 takes** (``smplxflame_30/<BEAT name>.npz`` anywhere under the root, with the
clip's ``.wav`` — BEAT2 keeps it in ``wave16k/``) are training clips too: their SMPL-X
motion is converted to the 47 joints by :mod:`facecapges.data.beat2` on the first BEAT
BVH's skeleton (or ``target``), and without a face JSON their face is the jaw's jawOpen
track (``face_source: "jaw"``). A clip with both a ``.bvh`` and a BEAT2 take uses the
``.bvh``. Their entries say ``dataset: "BEAT2"``, ``origin: "beat2"``.

Clips of the selected speakers without a ``.bvh`` (or BEAT2 take) are not training clips: they are
listed in ``index["skipped"]`` and counted in the summary as "audio only" (or "no
motion, no audio"); a ``.bvh`` without a ``.wav`` is skipped as "motion only".

Other sources (``mocap``, ``joints9``; any number of files or folders each):

* a BVH of another skeleton with a same-named ``.wav`` is retargeted onto the BEAT
  skeleton (:mod:`facecapges.data.retarget`; joint map by name or detected), then
  resampled to the cache rate;
* a reduced-joint ``.npy`` with a same-named ``.wav`` is read by
  :mod:`facecapges.data.joints9`.

Their clips carry a joint ``mask``, the speaker id of their map (ZEGGS: 100; see
:mod:`facecapges.data.cache` for the id scheme) and no face, semantic or emotion.
The BEAT skeleton their poses are written on is the first BEAT BVH's, or ``target``.
After all clips, masked joints are given the cache's mean rotation of that joint
(:func:`~facecapges.data.retarget.fill_masked`; world rotations unchanged).

The cache is written to a hidden ``.<name>.part`` folder beside ``out`` and renamed at
the end, so an interrupted run never leaves a half cache that looks complete. An
existing ``out`` is only replaced with ``force``, and only when it is a facecapges
cache (has ``index.json``) or an empty folder.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path
from typing import Literal

import numpy as np

from facecapges import timing
from facecapges.arkit import N_BLENDSHAPES
from facecapges.data import beat
from facecapges.data.cache import (
    CACHE_VERSION,
    CLIP_DIR,
    FIRST_OTHER_SPEAKER,
    INDEX_NAME,
    RunningStats,
    holdout_frame,
)
from facecapges.errors import UserError, file_error, refuse_overwrite
from facecapges.io.audio import load_audio
from facecapges.io.bvh import read_bvh
from facecapges.io.face_json import read_face_json
from facecapges.skeleton import (
    N_JOINTS,
    UPPER_BODY,
    Skeleton,
    motion_to_pose,
    pose_head_rot6d,
    skeleton_to_dict,
)


def _fit_length(x: np.ndarray, n: int, pad: str = "edge") -> np.ndarray:
    """Cut (n, ...) or pad ``x`` to n rows: ``"edge"`` repeats the last row, ``"zero"`` adds zeros."""
    if len(x) >= n:
        return x[:n]
    extra = n - len(x)
    if pad == "edge" and len(x):
        tail = np.repeat(x[-1:], extra, axis=0)
    else:
        tail = np.zeros((extra,) + x.shape[1:], x.dtype)
    return np.concatenate([x, tail], axis=0)


def prepare_clip(
    files: beat.ClipFiles, fps: float, sr: int, reference: tuple[Skeleton, Path] | None
) -> tuple[dict[str, np.ndarray], dict, Skeleton, list[str]]:
    """Arrays, index entry, skeleton and warnings of one clip that has .bvh and .wav."""
    bvh_path = files.files["bvh"]  # callers pass only clips with .bvh and .wav
    bvh = read_bvh(bvh_path)
    beat.check_skeleton(bvh.skeleton, bvh_path, reference)
    motion = timing.resample(bvh.motion, bvh.fps, fps)
    pose, head = motion_to_pose(bvh.skeleton, motion)
    arrays, entry, warnings = _clip_arrays(files, pose, head, bvh.skeleton, fps, sr, bvh.fps)
    return arrays, entry, bvh.skeleton, warnings


def prepare_beat2_clip(
    files: beat.ClipFiles, fps: float, sr: int, target: Skeleton
) -> tuple[dict[str, np.ndarray], dict, list[str]]:
    """Arrays, index entry and warnings of a BEAT2 take (SMPL-X .npz + .wav; :mod:`facecapges.data.beat2`).

    Its pose is written on ``target`` (the run's BEAT skeleton); without a face JSON its
    face is the jawOpen track of the take's jaw.
    """
    from facecapges.data import beat2

    take = beat2.read_beat2(files.files["npz"])
    pose, jaw_face = beat2.convert_take(take, fps)
    arrays, entry, warnings = _clip_arrays(
        files, pose, pose_head_rot6d(target, pose), target, fps, sr, take.fps, jaw_face=jaw_face
    )
    entry.update(dataset="BEAT2", origin="beat2", joint_map=beat2.MAP_NAME)
    if len(pose) < beat2.MIN_USEFUL_S * fps:
        warnings.append(
            f"{files.files['npz']}: {len(pose) / fps:.1f} s, too short to use: a style (`styles build`) needs "
            f"{beat2.MIN_USEFUL_S:g} s of a take and training only its first 80 %"
        )
    return arrays, entry, warnings


def _check_audio_length(files: beat.ClipFiles, wav_path: Path, T: int, fps: float, audio_s: float, warnings) -> None:
    """Refuse audio far from its motion's length; warn when it is a little off."""
    mismatch = timing.length_mismatch(T, fps, audio_s)
    if mismatch is not None:
        text, refuse = mismatch
        if refuse:
            raise file_error(
                wav_path,
                f"does not match its motion {_motion_of(files)}: {text}; "
                f"more than {timing.MISMATCH_REFUSE_SHARE:.0%} apart (wrong file or wrong frame rate?)",
            )
        warnings.append(f"{wav_path}: {text}")


def _clip_face(
    files: beat.ClipFiles, T: int, fps: float, jaw_face: np.ndarray | None, warnings: list[str]
) -> tuple[np.ndarray, str | None]:
    """A clip's face weights (T, 52) and their source: its face JSON, else ``jaw_face``, else none (zeros)."""
    face = np.zeros((T, N_BLENDSHAPES), np.float32)
    face_path = files.get("json")
    face_source = None
    if face_path is not None:
        track = read_face_json(face_path)
        if track.unknown_names:
            warnings.append(f"{face_path}: ignored unknown blendshape names {track.unknown_names}")
        face = _fit_length(timing.resample(track.weights, track.fps, fps), T).astype(np.float32)
        face_source = "json"
    elif jaw_face is not None:
        face, face_source = jaw_face.astype(np.float32), "jaw"
    return face, face_source


def _clip_arrays(
    files: beat.ClipFiles,
    pose: np.ndarray,
    head: np.ndarray,
    skel: Skeleton,
    fps: float,
    sr: int,
    source_fps: float,
    jaw_face: np.ndarray | None = None,
) -> tuple[dict[str, np.ndarray], dict, list[str]]:
    """The arrays and index entry of a BEAT-named clip from its pose (T, 47, 6) and side files."""
    T = len(pose)
    wav_path = files.files["wav"]
    audio_full = load_audio(wav_path, sr)
    S = timing.audio_samples(T, fps, sr)
    audio = _fit_length(audio_full, S, pad="zero")

    warnings: list[str] = []
    _check_audio_length(files, wav_path, T, fps, len(audio_full) / sr, warnings)
    face, face_source = _clip_face(files, T, fps, jaw_face, warnings)

    sem_path, emo_path = files.get("txt"), files.get("csv")
    semantic = beat.read_semantic(sem_path, T, fps) if sem_path else np.zeros(T, np.float32)
    emotion = beat.read_emotion(emo_path, T, fps) if emo_path else np.zeros(T, np.int16)

    arrays = {
        "pose": pose.astype(np.float32),
        "head": head.astype(np.float32),
        "face": face,
        "face_present": np.array(face_source is not None),
        "semantic": semantic.astype(np.float32),
        "semantic_present": np.array(sem_path is not None),
        "emotion": emotion.astype(np.int16),
        "emotion_present": np.array(emo_path is not None),
        "audio": audio.astype(np.float32),
        "offsets": skel.offsets.astype(np.float64),
        "mask": np.ones(N_JOINTS, bool),
    }
    clip = files.clip
    entry = {
        "name": clip.stem,
        "speaker": clip.speaker,
        "split": beat.split_of(clip),
        "kind": clip.kind,
        "n_frames": T,
        "duration_s": round(T / fps, 6),
        "audio_s": round(len(audio_full) / sr, 6),
        "source_fps": source_fps,
        "file": f"{CLIP_DIR}/{clip.stem}.npz",
        "has_face": face_source is not None,
        "face_source": face_source,
        "has_semantic": sem_path is not None,
        "has_emotion": emo_path is not None,
        "dataset": "BEAT",
        "origin": "beat",
        "joint_map": None,
        "n_masked": 0,
        "holdout_from": holdout_frame(T),
    }
    return arrays, entry, warnings


def _motion_of(c: beat.ClipFiles) -> Path | None:
    """The clip's motion file: its BEAT .bvh, else its BEAT2 .npz."""
    return c.get("bvh") or c.get("npz")


def _with_beat2_takes(root: Path, warnings: list[str]) -> list[beat.ClipFiles]:
    """BEAT clips under ``root`` with BEAT2 takes (``smplxflame_30/*.npz``) added as their ``npz``.

    A clip with both a .bvh and a BEAT2 take uses the .bvh (a warning says so).
    """
    from facecapges.data import beat2

    found = beat.find_clips(root)
    takes = beat2.find_takes(root)
    if not found and not takes:
        return beat.require_beat_clips(root)  # its error
    by_name = {c.name: c for c in found}
    for stem, npz in takes.items():
        clip = beat.parse_clip_name(stem)
        if clip is None:
            warnings.append(f"{npz}: not a BEAT clip name ({{speaker}}_{{name}}_{{type}}_{{start}}_{{end}}); ignored")
            continue
        c = by_name.setdefault(stem, beat.ClipFiles(clip))
        c.files["npz"] = npz
        if c.get("bvh"):
            warnings.append(f"{stem}: has a BEAT .bvh and a BEAT2 .npz; the .bvh is used")
    return sorted(by_name.values(), key=lambda c: (c.clip.speaker, c.clip.type, c.clip.start, c.clip.end))


def needs_target(beat_root: Path | None) -> bool:
    """True when ``beat_root`` has BEAT2 takes but no BEAT .bvh to take the skeleton from."""
    if beat_root is None or not Path(beat_root).is_dir():
        return False
    from facecapges.data import beat2

    return bool(beat2.find_takes(beat_root)) and not any(c.get("bvh") for c in beat.find_clips(beat_root))


def _require_target(target: Skeleton | None, path: Path) -> Skeleton:
    if target is None:
        raise file_error(path, "a BEAT2 take needs the BEAT skeleton to write its pose on: give --target BVH")
    return target


# ------------------------------------------------------------ other sources
def _paired(paths: list[Path], suffix: str, what: str) -> list[tuple[Path, Path]]:
    """(motion file, wav) pairs from files or folders (searched recursively); a missing .wav is an error."""
    out = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            found = sorted(q for q in p.rglob(f"*{suffix}") if q.is_file())
            if not found:
                raise file_error(p, f"no {suffix} files in this folder ({what})")
        elif p.is_file():
            found = [p]
        else:
            raise file_error(p, f"not found ({what})")
        for m in found:
            wav = m.with_suffix(".wav")
            if not wav.is_file():
                raise file_error(m, f"no matching audio {wav.name} beside it")
            out.append((m, wav))
    return out


def _other_arrays(
    pose: np.ndarray, mask: np.ndarray, target: Skeleton, wav: Path, fps: float, sr: int
) -> tuple[dict[str, np.ndarray], float]:
    T = len(pose)
    audio_full = load_audio(wav, sr)
    S = timing.audio_samples(T, fps, sr)
    arrays = {
        "pose": pose.astype(np.float32),
        "head": pose_head_rot6d(target, pose),
        "face": np.zeros((T, N_BLENDSHAPES), np.float32),
        "face_present": np.array(False),
        "semantic": np.zeros(T, np.float32),
        "semantic_present": np.array(False),
        "emotion": np.zeros(T, np.int16),
        "emotion_present": np.array(False),
        "audio": _fit_length(audio_full, S, pad="zero").astype(np.float32),
        "offsets": target.offsets.astype(np.float64),
        "mask": mask.astype(bool),
    }
    return arrays, len(audio_full) / sr


def _speaker_of(given: int | None, declared: int | None, what: str) -> int:
    spk = given if given is not None else declared
    if spk is None:
        raise UserError(
            f"{what}: its joint map states no speaker id; give one with --mocap-speaker / "
            f"--joints9-speaker ({FIRST_OTHER_SPEAKER + 1} or more; {FIRST_OTHER_SPEAKER} is ZEGGS's)"
        )
    if spk < FIRST_OTHER_SPEAKER:
        raise UserError(
            f"{what}: speaker id {spk} is in BEAT's range; other performers take ids from {FIRST_OTHER_SPEAKER} on"
        )
    return spk


def prepare_other_clip(
    kind: str,
    path: Path,
    wav: Path,
    target: Skeleton,
    fps: float,
    sr: int,
    spec: str | Path | None,
    speaker: int | None,
) -> tuple[dict[str, np.ndarray], dict, dict]:
    """Arrays, index entry and speaker info of a take of another source.

    ``kind`` is ``"mocap"`` (a BVH, retargeted with joint map ``spec``, default: detected)
    or ``"joints9"`` (reduced-joint arrays, layout ``spec``, default ``zeggs9``).
    """
    from facecapges.data.joints9 import read_joints9
    from facecapges.data.retarget import retarget_bvh

    if kind == "mocap":
        r, origin = retarget_bvh(path, target, spec, fps=fps), "retarget"
    else:
        r, origin = read_joints9(path, target, spec or "zeggs9", fps=fps), "joints9"
    spk = _speaker_of(speaker, r.speaker, str(path))
    arrays, audio_s = _other_arrays(r.pose, r.mask, target, wav, fps, sr)
    name = f"{r.map_name}_{path.stem}"
    T = r.n_frames
    entry = {
        "name": name,
        "speaker": spk,
        "split": "train",
        "kind": beat.SPEECH,
        "n_frames": T,
        "duration_s": round(T / fps, 6),
        "audio_s": round(audio_s, 6),
        "source_fps": r.source_fps,
        "file": f"{CLIP_DIR}/{name}.npz",
        "has_face": False,
        "has_semantic": False,
        "has_emotion": False,
        "dataset": r.dataset,
        "origin": origin,
        "joint_map": r.map_name,
        "n_masked": int((~r.mask).sum()),
        "holdout_from": holdout_frame(T),
    }
    return arrays, entry, {"dataset": r.dataset, "licence": r.licence, "performer": str(spk)}


def _check_out(out: Path, force: bool) -> None:
    if not out.exists():
        return
    refuse_overwrite(out, force)
    if out.is_dir() and ((out / INDEX_NAME).is_file() or not any(out.iterdir())):
        return
    raise file_error(out, "exists and is not a facecapges cache; refusing to replace it even with --force")


def _stats_block(train: dict[str, RunningStats], every: dict[str, RunningStats], what: str) -> dict:
    use, source = (
        (train, f"train clips of {what}") if train["pose"].n else (every, f"all clips of {what} (it has no train clip)")
    )
    block: dict = {"source": source, "n_frames": use["pose"].n}
    for key in ("pose", "head", "face"):
        block[f"{key}_mean"], block[f"{key}_std"] = use[key].result()
    return block


def _new_acc() -> dict[str, RunningStats]:
    return {"pose": RunningStats(N_JOINTS * 6), "head": RunningStats(6), "face": RunningStats(N_BLENDSHAPES)}


def _choose_beat_clips(
    beat_root: Path, speakers: list[int] | None, warnings: list[str]
) -> tuple[list[beat.ClipFiles], list[dict]]:
    """The BEAT clips (of ``speakers``) with both motion and audio, and the incomplete ones skipped."""
    found = _with_beat2_takes(beat_root, warnings)
    if speakers:
        chosen = [c for c in found if c.clip.speaker in set(speakers)]
        if not chosen:
            have = sorted({c.clip.speaker for c in found})
            raise UserError(f"{beat_root}: no clips of speaker(s) {sorted(speakers)} (found speakers {have})")
    else:
        chosen = found
    usable = [c for c in chosen if _motion_of(c) and c.get("wav")]
    skipped: list[dict] = []
    for c in chosen:
        if _motion_of(c) and c.get("wav"):
            continue
        reason = (
            ("audio only" if c.get("wav") else "motion only")
            if (c.get("wav") or _motion_of(c))
            else "no motion, no audio"
        )
        skipped.append(
            {
                "name": c.name,
                "speaker": c.clip.speaker,
                "reason": reason,
                "files": sorted(p.name for p in c.files.values()),
            }
        )
    return usable, skipped


class _CacheWriter:
    """Writes clips into the cache being built (``tmp``) and gathers its index entries, joint masks,
    speakers and per-speaker running statistics (train clips and all clips)."""

    def __init__(self, tmp: Path, bar, task) -> None:
        self.tmp, self.bar, self.task = tmp, bar, task
        self.entries: list[dict] = []
        self.masks: dict[str, np.ndarray] = {}
        self.speaker_info: dict[str, dict] = {}
        self.acc_train: dict[int, dict[str, RunningStats]] = {}
        self.acc_all: dict[int, dict[str, RunningStats]] = {}
        self.reference: tuple[Skeleton, Path] | None = None

    def add(self, arrays: dict, entry: dict) -> None:
        if entry["name"] in self.masks:
            raise UserError(f"two clips are named {entry['name']!r}; rename one of the files")
        np.savez_compressed(self.tmp / entry["file"], **arrays)
        self.entries.append(entry)
        self.masks[entry["name"]] = arrays["mask"]
        spk = int(entry["speaker"])
        present = np.repeat(arrays["mask"], 6)
        for acc in [self.acc_all.setdefault(spk, _new_acc())] + (
            [self.acc_train.setdefault(spk, _new_acc())] if entry["split"] == "train" else []
        ):
            acc["pose"].add(arrays["pose"].reshape(len(arrays["pose"]), -1), present)
            acc["head"].add(arrays["head"])
            if entry["has_face"]:
                acc["face"].add(arrays["face"])
        self.bar.advance(self.task)

    def add_beat(self, usable: list[beat.ClipFiles], fps: float, sr: int, target: Skeleton | None, warnings) -> None:
        """The BEAT clips: BVH takes first (the first one's skeleton is the cache's), then BEAT2 takes,
        written on that skeleton or ``target``."""
        for files in [c for c in usable if c.get("bvh")] + [c for c in usable if not c.get("bvh")]:
            self.bar.update(self.task, description=files.name)
            if files.get("bvh"):
                arrays, entry, skel, warn = prepare_clip(files, fps, sr, self.reference)
                if self.reference is None:
                    self.reference = (skel, files.files["bvh"])
            else:  # a BEAT2 take, written on the first BVH's skeleton or ``target``
                if self.reference is None:
                    self.reference = (_require_target(target, files.files["npz"]), Path("target skeleton"))
                arrays, entry, warn = prepare_beat2_clip(files, fps, sr, self.reference[0])
            warnings.extend(warn)
            self.speaker_info.setdefault(
                str(entry["speaker"]),
                {"dataset": entry["dataset"], "licence": "CC BY-NC 4.0", "performer": files.clip.performer},
            )
            self.add(arrays, entry)

    def add_others(self, others: list, fps: float, sr: int, target: Skeleton | None, maps, speakers) -> None:
        """The ``--mocap`` / ``--joints9`` clips, on the BEAT skeleton (``maps`` and ``speakers``: the
        joint map / layout and the speaker id of each kind)."""
        if self.reference is None:
            if target is None:
                raise UserError(
                    "--mocap/--joints9 need the BEAT skeleton to write poses on: give a BEAT "
                    "folder or a target skeleton"
                )
            self.reference = (target, Path("target skeleton"))
        for kind, motion_path, wav in others:
            self.bar.update(self.task, description=motion_path.stem[:24])
            arrays, entry, info = prepare_other_clip(
                kind, motion_path, wav, self.reference[0], fps, sr, maps[kind], speakers[kind]
            )
            self.speaker_info.setdefault(str(entry["speaker"]), info)
            self.add(arrays, entry)

    def stats(self) -> tuple[dict, dict[str, RunningStats]]:
        """The index's ``stats`` (each speaker's and all speakers') and the pooled statistics of all clips."""
        stats: dict = {}
        pooled_train, pooled_all = _new_acc(), _new_acc()
        for spk in sorted(self.acc_all):
            train = self.acc_train.get(spk, _new_acc())
            stats[str(spk)] = _stats_block(train, self.acc_all[spk], f"speaker {spk}")
            for k in pooled_train:
                pooled_train[k].merge(train[k])
                pooled_all[k].merge(self.acc_all[spk][k])
        stats["all"] = _stats_block(pooled_train, pooled_all, "all speakers")
        return stats, pooled_all


def _progress_bar(progress: bool):
    """The ``prepare`` progress bar (one step per clip)."""
    from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn

    from facecapges.progress import Progress

    columns = (
        TextColumn("[bold]prepare[/bold] {task.description:<24}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
    )
    return Progress(*columns, disable=not progress, transient=False, prefix="prepare")


def _index(
    tmp: Path, w: _CacheWriter, fps: float, sr: int, beat_root: Path | None, skipped: list[dict], warnings: list[str]
) -> dict:
    """The cache's index: its clips, skeleton, speakers, statistics and the fill of masked joints
    (written into the clips in ``tmp``)."""
    stats, pooled_all = w.stats()
    reference = w.reference
    assert reference is not None  # set by the first clip or mocap source (none at all was refused above)
    fill = _fill_masked_clips(tmp, w.entries, w.masks, pooled_all["pose"], reference[0])
    index = {
        "version": CACHE_VERSION,
        "fps": fps,
        "sr": sr,
        "source": str(beat_root.resolve()) if beat_root is not None else None,
        "created": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "skeleton": skeleton_to_dict(reference[0]),
        "skeleton_source": reference[1].name,
        "upper_body": list(UPPER_BODY),
        "clips": w.entries,
        "skipped": skipped,
        "warnings": warnings,
        "speakers": w.speaker_info,
        "fill": fill.reshape(-1).tolist(),
        "stats": stats,
    }
    return index


def _other_sources(mocap, joints9, usable: list, beat_root: Path | None, skipped: list[dict]) -> list:
    """The ``--mocap`` and ``--joints9`` clips as (kind, motion file, wav); refuses a run with nothing to prepare."""
    others = [("mocap", m, w) for m, w in _paired(list(mocap), ".bvh", "--mocap")] + [
        ("joints9", m, w) for m, w in _paired(list(joints9), ".npy", "--joints9")
    ]
    if not usable and not others:
        if beat_root is None:
            raise UserError("nothing to prepare: give a BEAT folder, --mocap or --joints9")
        raise UserError(
            f"{beat_root}: no clip has both motion (.bvh, or a BEAT2 smplxflame_30/*.npz) and a .wav ({len(skipped)} incomplete clip(s): "
            f"{', '.join(s['name'] + ' ' + s['reason'] for s in skipped[:3])})"
        )
    return others


def prepare(
    beat_root: str | Path | None,
    out: str | Path,
    speakers: list[int] | None = None,
    fps: float = timing.MODEL_FPS,
    force: bool = False,
    progress: bool = True,
    sr: int = timing.AUDIO_SR,
    mocap: list[Path] | tuple = (),
    joints9: list[Path] | tuple = (),
    joint_map: str | Path | None = None,
    layout: str | Path | None = None,
    mocap_speaker: int | None = None,
    joints9_speaker: int | None = None,
    target: Skeleton | None = None,
) -> dict:
    """Build the cache ``out`` from the BEAT folder ``beat_root`` and other sources; return its index.

    ``speakers`` restricts BEAT to those speaker ids (None: all found). ``mocap``: BVH
    files/folders of other skeletons (retargeted with ``joint_map``, default: detected);
    ``joints9``: reduced-joint ``.npy`` files/folders (``layout``, default ``zeggs9``).
    ``target``: the BEAT skeleton for those when there is no BEAT BVH. Raises
    :class:`~facecapges.errors.UserError` for an empty folder, unknown speakers, bad
    files, or an existing ``out`` without ``force``.
    """
    out = Path(out)
    if fps <= 0:
        raise UserError(f"--fps must be positive, got {fps}")
    _check_out(out, force)
    usable: list[beat.ClipFiles] = []
    skipped: list[dict] = []
    warnings: list[str] = []
    if beat_root is not None:
        beat_root = Path(beat_root)
        usable, skipped = _choose_beat_clips(beat_root, speakers, warnings)
    others = _other_sources(mocap, joints9, usable, beat_root, skipped)

    tmp = out.parent / f".{out.name}.part"
    if tmp.exists():
        shutil.rmtree(tmp)
    (tmp / CLIP_DIR).mkdir(parents=True)
    try:
        with _progress_bar(progress) as bar:
            w = _CacheWriter(tmp, bar, bar.add_task("", total=len(usable) + len(others)))
            w.add_beat(usable, fps, sr, target, warnings)
            if others:
                maps = {"mocap": joint_map, "joints9": layout}
                w.add_others(others, fps, sr, target, maps, {"mocap": mocap_speaker, "joints9": joints9_speaker})
        index = _index(tmp, w, fps, sr, beat_root, skipped, warnings)
        (tmp / INDEX_NAME).write_text(json.dumps(index, indent=1), encoding="utf-8")
        if out.exists():
            shutil.rmtree(out)
        tmp.replace(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return index


def _fill_masked_clips(
    tmp: Path, entries: list[dict], masks: dict[str, np.ndarray], pose_acc: RunningStats, target: Skeleton
) -> np.ndarray:
    """Give masked joints the cache's mean rotation (identity where no clip has the joint); returns it (47, 6)."""
    from facecapges import rotations as rot
    from facecapges.data.retarget import fill_masked

    mean, _ = pose_acc.result()
    mean = np.asarray(mean).reshape(N_JOINTS, 6)
    seen = pose_acc.count.reshape(N_JOINTS, 6)[:, 0] > 0
    fill = np.where(seen[:, None], rot.normalize_rot6d(mean), rot.identity_rot6d((N_JOINTS,)))
    fill = fill.astype(np.float32)
    for e in entries:
        m = masks[e["name"]]
        if m.all():
            continue
        path = tmp / e["file"]
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        arrays["pose"] = fill_masked(target, arrays["pose"], m, fill)
        arrays["head"] = pose_head_rot6d(target, arrays["pose"])
        np.savez_compressed(path, **arrays)
    return fill


def summary_rows(index: dict) -> list[tuple[str, str, int, int, float]]:
    """(split, speaker, clips, frames, seconds) per split and speaker, then a total row."""
    groups: dict[tuple[str, int], list[dict]] = {}
    order = {"train": 0, "val": 1, "test": 2}
    for c in index["clips"]:
        groups.setdefault((c["split"], int(c["speaker"])), []).append(c)
    rows = []
    for split, spk in sorted(groups, key=lambda k: (order.get(k[0], 9), k[1])):
        cs = groups[(split, spk)]
        frames = sum(c["n_frames"] for c in cs)
        rows.append((split, str(spk), len(cs), frames, frames / index["fps"]))
    frames = sum(c["n_frames"] for c in index["clips"])
    rows.append(("total", "", len(index["clips"]), frames, frames / index["fps"]))
    return rows


def summary_table(index: dict):
    """A rich Table of :func:`summary_rows`, with skipped clips counted in the caption."""
    from rich.table import Table

    table = Table(title=f"Cache at {index['fps']:g} fps, {index['sr']} Hz")
    just: Literal["left", "right"]
    for col, just in (
        ("split", "left"),
        ("speaker", "left"),
        ("clips", "right"),
        ("frames", "right"),
        ("seconds", "right"),
    ):
        table.add_column(col, justify=just)
    rows = summary_rows(index)
    for i, (split, spk, n, frames, secs) in enumerate(rows):
        table.add_row(split, spk, str(n), str(frames), f"{secs:.1f}", end_section=(i == len(rows) - 2))
    reasons: dict[str, int] = {}
    for s in index.get("skipped", []):
        reasons[s["reason"]] = reasons.get(s["reason"], 0) + 1
    if reasons:
        table.caption = "skipped: " + ", ".join(f"{n} {r}" for r, n in sorted(reasons.items()))
    return table
