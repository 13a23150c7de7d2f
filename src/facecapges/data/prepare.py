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

Clips of the selected speakers without a ``.bvh`` are not training clips: they are
listed in ``index["skipped"]`` and counted in the summary as "audio only" (or "no
motion, no audio"); a ``.bvh`` without a ``.wav`` is skipped as "motion only".

The cache is written to a hidden ``.<name>.part`` folder beside ``out`` and renamed at
the end, so an interrupted run never leaves a half cache that looks complete. An
existing ``out`` is only replaced with ``force``, and only when it is a facecapges
cache (has ``index.json``) or an empty folder.
"""

from __future__ import annotations

import json
import math
import shutil
import time
from pathlib import Path

import numpy as np

from facecapges import timing
from facecapges.data import beat
from facecapges.data.cache import (CACHE_VERSION, CLIP_DIR, INDEX_NAME, RunningStats, skeleton_to_dict)
from facecapges.errors import UserError, file_error, refuse_overwrite
from facecapges.io.audio import load_audio
from facecapges.io.bvh import read_bvh
from facecapges.io.face_json import read_face_json
from facecapges.skeleton import N_JOINTS, UPPER_BODY, Skeleton, motion_to_pose


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


def check_skeleton(skel: Skeleton, path: Path, reference: tuple[Skeleton, Path] | None) -> None:
    """Raise a UserError naming ``path`` if ``skel`` is not a usable BEAT skeleton."""
    missing = skel.missing(UPPER_BODY)
    if missing:
        shown = ", ".join(missing[:6]) + (", …" if len(missing) > 6 else "")
        raise file_error(path, f"wrong skeleton: missing {len(missing)} of the {N_JOINTS} BEAT upper-body "
                               f"joints ({shown})")
    if reference is not None:
        ref, ref_path = reference
        if not ref.is_same_tree(skel) or ref.channels != skel.channels:
            raise file_error(path, f"wrong skeleton: joint tree or channel layout differs from {ref_path.name}")


def prepare_clip(files: beat.ClipFiles, fps: float, sr: int, reference: tuple[Skeleton, Path] | None
                 ) -> tuple[dict[str, np.ndarray], dict, Skeleton, list[str]]:
    """Arrays, index entry, skeleton and warnings of one clip that has .bvh and .wav."""
    bvh_path, wav_path = files.get("bvh"), files.get("wav")
    bvh = read_bvh(bvh_path)
    check_skeleton(bvh.skeleton, bvh_path, reference)
    motion = timing.resample(bvh.motion, bvh.fps, fps)
    T = len(motion)
    pose, head = motion_to_pose(bvh.skeleton, motion)

    audio_full = load_audio(wav_path, sr)
    S = int(math.floor(T * sr / fps + 1e-6))
    audio = _fit_length(audio_full, S, pad="zero")

    warnings: list[str] = []
    face = np.zeros((T, 52), np.float32)
    face_path = files.get("json")
    if face_path is not None:
        track = read_face_json(face_path)
        if track.unknown_names:
            warnings.append(f"{face_path}: ignored unknown blendshape names {track.unknown_names}")
        face = _fit_length(timing.resample(track.weights, track.fps, fps), T).astype(np.float32)

    sem_path, emo_path = files.get("txt"), files.get("csv")
    semantic = beat.read_semantic(sem_path, T, fps) if sem_path else np.zeros(T, np.float32)
    emotion = beat.read_emotion(emo_path, T, fps) if emo_path else np.zeros(T, np.int16)

    arrays = {
        "pose": pose.astype(np.float32), "head": head.astype(np.float32), "face": face,
        "face_present": np.array(face_path is not None),
        "semantic": semantic.astype(np.float32), "semantic_present": np.array(sem_path is not None),
        "emotion": emotion.astype(np.int16), "emotion_present": np.array(emo_path is not None),
        "audio": audio.astype(np.float32), "offsets": bvh.skeleton.offsets.astype(np.float64),
    }
    clip = files.clip
    entry = {
        "name": clip.stem, "speaker": clip.speaker, "split": beat.split_of(clip), "kind": clip.kind,
        "n_frames": T, "duration_s": round(T / fps, 6), "audio_s": round(len(audio_full) / sr, 6),
        "source_fps": bvh.fps, "file": f"{CLIP_DIR}/{clip.stem}.npz",
        "has_face": face_path is not None, "has_semantic": sem_path is not None, "has_emotion": emo_path is not None,
    }
    return arrays, entry, bvh.skeleton, warnings


def _check_out(out: Path, force: bool) -> None:
    if not out.exists():
        return
    refuse_overwrite(out, force)
    if out.is_dir() and ((out / INDEX_NAME).is_file() or not any(out.iterdir())):
        return
    raise file_error(out, "exists and is not a facecapges cache; refusing to replace it even with --force")


def _stats_block(train: dict[str, RunningStats], every: dict[str, RunningStats], what: str) -> dict:
    use, source = (train, f"train clips of {what}") if train["pose"].n else (every, f"all clips of {what} "
                                                                                     "(it has no train clip)")
    block: dict = {"source": source, "n_frames": use["pose"].n}
    for key in ("pose", "head", "face"):
        block[f"{key}_mean"], block[f"{key}_std"] = use[key].result()
    return block


def _new_acc() -> dict[str, RunningStats]:
    return {"pose": RunningStats(N_JOINTS * 6), "head": RunningStats(6), "face": RunningStats(52)}


def prepare(beat_root: str | Path, out: str | Path, speakers: list[int] | None = None,
            fps: float = timing.MODEL_FPS, force: bool = False, progress: bool = True,
            sr: int = timing.AUDIO_SR) -> dict:
    """Build the cache ``out`` from the BEAT folder ``beat_root``; return its index.

    ``speakers`` restricts to those speaker ids (None: all found). Raises
    :class:`~facecapges.errors.UserError` for an empty folder, unknown speakers, bad
    files, or an existing ``out`` without ``force``.
    """
    beat_root, out = Path(beat_root), Path(out)
    if fps <= 0:
        raise UserError(f"--fps must be positive, got {fps}")
    _check_out(out, force)
    found = beat.require_beat_clips(beat_root)
    if speakers:
        chosen = [c for c in found if c.clip.speaker in set(speakers)]
        if not chosen:
            have = sorted({c.clip.speaker for c in found})
            raise UserError(f"{beat_root}: no clips of speaker(s) {sorted(speakers)} (found speakers {have})")
    else:
        chosen = found
    usable = [c for c in chosen if c.get("bvh") and c.get("wav")]
    skipped = []
    for c in chosen:
        if c.get("bvh") and c.get("wav"):
            continue
        reason = ("audio only" if c.get("wav") else "motion only") if (c.get("wav") or c.get("bvh")) \
            else "no motion, no audio"
        skipped.append({"name": c.name, "speaker": c.clip.speaker, "reason": reason,
                        "files": sorted(p.name for p in c.files.values())})
    if not usable:
        raise UserError(f"{beat_root}: no clip has both a .bvh and a .wav ({len(skipped)} incomplete clip(s): "
                        f"{', '.join(s['name'] + ' ' + s['reason'] for s in skipped[:3])})")

    tmp = out.parent / f".{out.name}.part"
    if tmp.exists():
        shutil.rmtree(tmp)
    (tmp / CLIP_DIR).mkdir(parents=True)
    entries, warnings = [], []
    reference: tuple[Skeleton, Path] | None = None
    acc_train: dict[int, dict[str, RunningStats]] = {}
    acc_all: dict[int, dict[str, RunningStats]] = {}
    try:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        columns = (TextColumn("[bold]prepare[/bold] {task.description:<24}"), BarColumn(), MofNCompleteColumn(),
                   TimeRemainingColumn())
        with Progress(*columns, disable=not progress, transient=False) as bar:
            task = bar.add_task("", total=len(usable))
            for files in usable:
                bar.update(task, description=files.name)
                arrays, entry, skel, warn = prepare_clip(files, fps, sr, reference)
                if reference is None:
                    reference = (skel, files.get("bvh"))
                np.savez_compressed(tmp / entry["file"], **arrays)
                entries.append(entry)
                warnings.extend(warn)
                spk = files.clip.speaker
                for acc in ([acc_all.setdefault(spk, _new_acc())]
                            + ([acc_train.setdefault(spk, _new_acc())] if entry["split"] == "train" else [])):
                    acc["pose"].add(arrays["pose"].reshape(len(arrays["pose"]), -1))
                    acc["head"].add(arrays["head"])
                    if entry["has_face"]:
                        acc["face"].add(arrays["face"])
                bar.advance(task)

        stats: dict = {}
        pooled_train, pooled_all = _new_acc(), _new_acc()
        for spk in sorted(acc_all):
            train = acc_train.get(spk, _new_acc())
            stats[str(spk)] = _stats_block(train, acc_all[spk], f"speaker {spk}")
            for k in pooled_train:
                pooled_train[k].merge(train[k])
                pooled_all[k].merge(acc_all[spk][k])
        stats["all"] = _stats_block(pooled_train, pooled_all, "all speakers")

        index = {
            "version": CACHE_VERSION, "fps": fps, "sr": sr, "source": str(beat_root.resolve()),
            "created": time.strftime("%Y-%m-%dT%H:%M:%S"),
            "skeleton": skeleton_to_dict(reference[0]), "skeleton_source": reference[1].name,
            "upper_body": list(UPPER_BODY), "clips": entries, "skipped": skipped, "warnings": warnings,
            "stats": stats,
        }
        (tmp / INDEX_NAME).write_text(json.dumps(index, indent=1), encoding="utf-8")
        if out.exists():
            shutil.rmtree(out)
        tmp.replace(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return index


def summary_rows(index: dict) -> list[tuple[str, str, int, int, float]]:
    """(split, speaker, clips, frames, seconds) per split and speaker, then a total row."""
    groups: dict[tuple[str, int], list[dict]] = {}
    order = {"train": 0, "val": 1, "test": 2}
    for c in index["clips"]:
        groups.setdefault((c["split"], int(c["speaker"])), []).append(c)
    rows = []
    for (split, spk) in sorted(groups, key=lambda k: (order.get(k[0], 9), k[1])):
        cs = groups[(split, spk)]
        frames = sum(c["n_frames"] for c in cs)
        rows.append((split, str(spk), len(cs), frames, frames / index["fps"]))
    frames = sum(c["n_frames"] for c in index["clips"])
    rows.append(("total", "", len(index["clips"]), frames, frames / index["fps"]))
    return rows


def summary_table(index: dict):
    """A rich Table of :func:`summary_rows`, with skipped clips counted in the caption."""
    from rich.table import Table

    table = Table(title=f"BEAT cache at {index['fps']:g} fps, {index['sr']} Hz")
    for col, just in (("split", "left"), ("speaker", "left"), ("clips", "right"), ("frames", "right"),
                      ("seconds", "right")):
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
