"""The prepared cache: what ``facecapges prepare`` writes and the model reads.

Layout of a cache folder::

    CACHE/index.json          # everything but the per-frame arrays
    CACHE/clips/<name>.npz    # one compressed array file per clip

Per-clip arrays (``numpy.savez_compressed``; :meth:`Cache.load` returns them as a
dict). T is the number of motion frames at the cache's ``fps`` (15 by default).
:class:`FrameArrays` holds one take's per-frame arrays (``pose``, ``head``, ``face``, ``audio``)
with their shape checks; the trainer's clips and the matching engine's takes build on it:

=================== ============== ======= ==============================================
key                 shape          dtype   meaning
=================== ============== ======= ==============================================
``pose``            (T, 47, 6)     float32 local rot6d of the UPPER_BODY joints
``head``            (T, 6)         float32 global head rot6d (skeleton.head_rot6d)
``face``            (T, 52)        float32 ARKit weights (zeros when absent)
``face_present``    ()             bool    a face JSON was found
``semantic``        (T,)           float32 semantic relevance score per frame
``semantic_present`` ()            bool
``emotion``         (T,)           int16   emotion label per frame (beat.EMOTIONS)
``emotion_present`` ()             bool
``audio``           (S,)           float32 16 kHz mono, S = floor(T·sr/fps)
``offsets``         (J, 3)         float64 this clip's BVH joint offsets (cm)
``mask``            (47,)          bool    joints whose rotation the source carries
=================== ============== ======= ==============================================

**Masked joints.** A take retargeted from another skeleton (:mod:`facecapges.data.retarget`)
or read from 9-joint arrays (:mod:`facecapges.data.joints9`) lacks some of the 47
joints. ``mask[j]`` is False for those: their ``pose`` rows hold the cache's mean
rotation of that joint (``index["fill"]``, identity when no clip has it) so the
pose is still a plausible one for the model's history, the child joints' rotations
are adjusted so every world rotation stays the source's, and training adds no loss
for them. BEAT clips have every joint (mask all True).

``audio`` covers exactly the samples frames 0…T−1 own by
:func:`facecapges.timing.frame_sample_bounds` (frame i owns
``floor(i·sr/fps) … floor((i+1)·sr/fps) − 1``), so S = floor(T·sr/fps). The true
recording is kept sample for sample: a longer recording is cut at S, a shorter one
is padded with zeros (the clip entry records the original length as ``audio_s``).

``index.json`` holds ``version``, ``fps``, ``sr``, ``source`` (the BEAT root), the
``skeleton`` header of the first BVH (names, parents, offsets, channels, end_sites —
the full 75-joint hierarchy; clips of other performers differ only in offsets, kept
per clip in the npz), ``upper_body`` (the 47 names), ``clips`` (one entry per clip:
``name, speaker, split, kind, n_frames, duration_s, audio_s, file, has_face,
has_semantic, has_emotion, dataset, origin, joint_map, n_masked, holdout_from``),
``speakers`` (per speaker id: ``dataset``, ``licence``, ``performer``), ``skipped``
(files that are not training clips, with the reason, e.g. audio without motion),
``fill`` (47·6 values: the rotation masked joints hold) and ``stats``.

``origin`` is ``"beat"`` (a BEAT BVH), ``"retarget"`` (a BVH of another skeleton,
retargeted with ``joint_map``) or ``"joints9"`` (9-joint arrays). ``holdout_from`` is
the first frame of the clip's last 20 %, the part to keep out of training and of every
choice made on it.

**Speaker ids.** BEAT's own ids (1–30) are kept. Every other performer gets an id of
100 or more (:data:`FIRST_OTHER_SPEAKER`), so the two can never collide: the ZEGGS
speaker is 100 (stated in its joint map); a user's own performers take 101, 102, …
(``prepare --mocap-speaker``). Clips from another source are named
``<joint map>_<file stem>`` (e.g. ``zeggs_067_Speech_2_x_1_0``) and are all in the
``train`` split: hold out their last 20 % by ``holdout_from``.

``stats[str(speaker)]`` (and ``stats["all"]`` pooled over every speaker) has
``pose_mean``/``pose_std`` (47·6 values, reshape to (47, 6)), ``head_mean``/``head_std``
(6), ``face_mean``/``face_std`` (52), ``n_frames`` and ``source``. They are computed
over the speaker's **train** clips (face only over clips that have face, each pose
joint only over the clips that have it — masked joints do not count); a speaker
with no train clip in the cache (e.g. the shared sample, whose only clip is a test
clip) falls back to all of its clips and says so in ``source``. Standard deviations
are floored at :data:`STD_FLOOR` so dividing by them is always safe; channels with no
data at all get mean 0, std 1.
"""

from __future__ import annotations

import json
import math
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facecapges.arkit import N_BLENDSHAPES
from facecapges.errors import UserError, file_error
from facecapges.skeleton import N_JOINTS, Skeleton, skeleton_from_dict

CACHE_VERSION = 2
FIRST_OTHER_SPEAKER = 100  # ids below are BEAT's; other performers start here
INDEX_NAME = "index.json"
CLIP_DIR = "clips"
STD_FLOOR = 1e-3
PRESENCE_KEYS = ("face_present", "semantic_present", "emotion_present")
HOLDOUT_FRACTION = 0.2  # the last 20 % of every take is held out


def holdout_frame(T: int) -> int:
    """First frame of a take's last 20 % (:data:`HOLDOUT_FRACTION`): floor(0.8 · T)."""
    return int(math.floor(T * (1.0 - HOLDOUT_FRACTION)))


@dataclass
class FrameArrays:
    """One take's per-frame arrays at the model rate (the clip keys of the module table).

    Shapes are checked on construction (T from ``pose``); a mismatch is a :class:`UserError`
    naming the take. The subclasses add what their users need: the trainer's
    :class:`facecapges.training.segments.ClipArrays` a joint mask, the matching engine's
    :class:`facecapges.matching.takes.Take` the skeleton and its held-out frames.
    """

    name: str
    pose: np.ndarray  # (T, 47, 6) local rot6d of the UPPER_BODY joints
    head: np.ndarray  # (T, 6) global head rot6d
    face: np.ndarray  # (T, 52) ARKit weights (zeros where unknown)
    audio: np.ndarray  # (S,) 16 kHz mono

    def __post_init__(self) -> None:
        T = self.n_frames
        for key, want in (("pose", (T, N_JOINTS, 6)), ("head", (T, 6)), ("face", (T, N_BLENDSHAPES))):
            got = tuple(np.shape(getattr(self, key)))
            if got != want:
                raise UserError(f"{self.name}: {key} has shape {got}, expected {want} (T = the pose's frames)")
        if np.ndim(self.audio) != 1:
            raise UserError(f"{self.name}: audio has shape {np.shape(self.audio)}, expected (S,) samples")

    @property
    def n_frames(self) -> int:
        return int(len(self.pose))

    def mirror_arrays(self) -> dict:
        """The left/right mirror image's name (suffixed ``~mirror``), pose, head and face (the same audio);
        ``dataclasses.replace(arrays, **arrays.mirror_arrays())`` makes the mirrored copy."""
        from facecapges.data.mirror import mirror_face, mirror_head, mirror_pose

        return {
            "name": f"{self.name}~mirror",
            "pose": mirror_pose(self.pose),
            "head": mirror_head(self.head),
            "face": mirror_face(self.face),
        }


# -------------------------------------------------------------------- statistics
class RunningStats:
    """Mean and standard deviation of (N, D) batches, accumulated in float64."""

    def __init__(self, dim: int):
        self.n = 0  # rows added
        self.count = np.zeros(dim)  # rows that had each dimension (a mask can leave some out)
        self.sum = np.zeros(dim)
        self.sumsq = np.zeros(dim)

    def add(self, x: np.ndarray, present: np.ndarray | None = None) -> None:
        """Add rows (N, D); ``present`` (D,) bool leaves the False dimensions out."""
        x = np.asarray(x, dtype=np.float64).reshape(len(x), -1)
        w = np.ones(x.shape[1]) if present is None else np.asarray(present, np.float64).reshape(-1)
        self.n += len(x)
        self.count += len(x) * w
        self.sum += x.sum(0) * w
        self.sumsq += (x * x).sum(0) * w

    def merge(self, other: RunningStats) -> None:
        self.n += other.n
        self.count += other.count
        self.sum += other.sum
        self.sumsq += other.sumsq

    def result(self) -> tuple[list[float], list[float]]:
        """Mean and std per dimension; a dimension no row had gets mean 0, std 1."""
        seen = self.count > 0
        n = np.maximum(self.count, 1)
        mean = np.where(seen, self.sum / n, 0.0)
        var = np.maximum(self.sumsq / n - mean * mean, 0.0)
        std = np.where(seen, np.maximum(np.sqrt(var), STD_FLOOR), 1.0)
        return mean.tolist(), std.tolist()


# ------------------------------------------------------------------------ loader
def _index_problem(index: dict) -> str | None:
    """What is wrong with a cache index's structure (a file from outside: types, and clip files
    that stay inside the cache folder), or None."""
    import math

    clips = index.get("clips")
    if not isinstance(clips, list) or not all(isinstance(c, dict) for c in clips):
        return "'clips' is not a list of objects"
    for c in clips:
        name, file = c.get("name"), c.get("file")
        if not isinstance(name, str) or not isinstance(file, str):
            return "a clip without a 'name' and 'file'"
        parts = Path(file).parts
        if not parts or Path(file).is_absolute() or ".." in parts or "\0" in file:
            return f"clip {name[:40]!r}: its file {file[:60]!r} is not inside the cache folder"
        sp = c.get("speaker")
        if isinstance(sp, bool) or not isinstance(sp, (int, str)) or not str(sp).strip().lstrip("-").isdigit():
            return f"clip {name[:40]!r}: speaker {str(sp)[:20]!r} is not a number"
        if not isinstance(c.get("split", ""), str):
            return f"clip {name[:40]!r}: split is not a name"
    for key in ("fps", "sr"):
        v = index.get(key)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            return f"'{key}' is not a positive number"
    for key in ("skeleton", "stats"):
        if not isinstance(index.get(key, {}), dict):
            return f"'{key}' is not an object"
    return None


class Cache:
    """Read access to a prepared cache folder.

    >>> cache = Cache("/tmp/c")                         # doctest: +SKIP
    >>> [c["name"] for c in cache.clips(split="train")] # doctest: +SKIP
    >>> clip = cache.load("2_scott_0_1_1"); clip["pose"].shape   # (T, 47, 6)  # doctest: +SKIP
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        index_path = self.path / INDEX_NAME
        if not self.path.is_dir():
            raise file_error(self.path, "cache folder not found (run `facecapges prepare` first)")
        if not index_path.is_file():
            raise file_error(self.path, f"not a facecapges cache (no {INDEX_NAME})")
        try:
            self.index: dict = json.loads(index_path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise file_error(index_path, f"malformed cache index ({exc})") from None
        except RecursionError:
            raise file_error(index_path, "malformed cache index (nested too deeply)") from None
        if not isinstance(self.index, dict) or self.index.get("version") != CACHE_VERSION:
            v = self.index.get("version") if isinstance(self.index, dict) else None
            raise file_error(
                index_path, f"cache version {str(v)[:40]} is not {CACHE_VERSION}; prepare it again with --force"
            )
        problem = _index_problem(self.index)
        if problem:
            raise file_error(index_path, f"malformed cache index ({problem}); prepare it again with --force")
        self._by_name = {c["name"]: c for c in self.index["clips"]}

    @property
    def fps(self) -> float:
        return float(self.index["fps"])

    @property
    def sr(self) -> int:
        return int(self.index["sr"])

    def speaker_info(self, speaker: int) -> dict:
        """Dataset, licence and performer of ``speaker`` (``index["speakers"]``; BEAT when unstated)."""
        return dict(
            self.index.get("speakers", {}).get(str(int(speaker)), {"dataset": "BEAT", "licence": "CC BY-NC 4.0"})
        )

    @property
    def speakers(self) -> list[int]:
        return sorted({int(c["speaker"]) for c in self.index["clips"]})

    def __len__(self) -> int:
        return len(self.index["clips"])

    def __contains__(self, name: str) -> bool:
        return name in self._by_name

    def clips(self, speaker: int | None = None, split: str | None = None) -> list[dict]:
        """Index entries of the clips, optionally of one speaker and/or split (train/val/test)."""
        return [
            c
            for c in self.index["clips"]
            if (speaker is None or int(c["speaker"]) == int(speaker)) and (split is None or c["split"] == split)
        ]

    def select(self, speaker: int, split: str) -> list[dict]:
        """Clips of ``speaker`` in ``split`` (``"all"``: every split); a UserError when there are none.

        The message lists the speaker/split pairs the cache does have, so the user
        can pick ``--split all`` (with ``--holdout-from FRAME``) for a single-clip cache.
        """
        entries = self.clips(speaker=speaker, split=None if split == "all" else split)
        if not entries:
            own = self.clips(speaker=speaker)
            if own:  # e.g. BEAT's split puts the only take of ../shared in "test"
                where = ", ".join(
                    f"{sum(c['split'] == s for c in own)} in {s!r}" for s in sorted({c["split"] for c in own})
                )
                frame = int(0.8 * min(int(c.get("n_frames", 0)) for c in own))
                raise UserError(
                    f"{self.path}: no {split!r} clips of speaker {speaker}: its {len(own)} clip(s) are {where}; "
                    f"use --split all, with --holdout-from FRAME to keep frames for evaluation (e.g. "
                    f"--holdout-from {frame}: the last 20 % of its shortest clip)"
                )
            have = sorted({(int(c["speaker"]), c["split"]) for c in self.clips()})
            raise UserError(
                f"{self.path}: no {split!r} clips of speaker {speaker} (speaker/split pairs in the cache: "
                f"{have}); use --split all, with --holdout-from FRAME to keep frames for evaluation"
            )
        return entries

    def entry(self, name: str) -> dict:
        """The index entry of clip ``name``."""
        try:
            return self._by_name[name]
        except KeyError:
            some = ", ".join(list(self._by_name)[:5])
            raise UserError(
                f"{self.path}: no clip {name!r} in this cache (it has: {some}{', …' if len(self._by_name) > 5 else ''})"
            ) from None

    def load(self, name: str) -> dict:
        """All arrays of clip ``name`` (keys in the module docstring); ``*_present`` as Python bools."""
        entry = self.entry(name)
        path = self.path / entry["file"]
        try:
            with np.load(path, allow_pickle=False) as z:
                out = {k: z[k] for k in z.files}
        except FileNotFoundError:
            raise file_error(path, "clip file missing from the cache") from None
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:  # truncated or damaged .npz
            raise file_error(path, f"corrupt clip file ({exc.__class__.__name__}: {str(exc)[:120]})") from None
        missing = [k for k in PRESENCE_KEYS if k not in out]
        if missing:
            raise file_error(path, f"corrupt clip file (no {', '.join(missing)})")
        for k in PRESENCE_KEYS:
            out[k] = bool(out[k])
        if "mask" not in out:
            out["mask"] = np.ones(N_JOINTS, bool)
        out["mask"] = out["mask"].astype(bool)
        return out

    def skeleton(self, name: str | None = None) -> Skeleton:
        """The full BVH hierarchy; with a clip ``name``, carrying that clip's own offsets."""
        skel = skeleton_from_dict(self.index["skeleton"])
        if name is not None:
            self.entry(name)
            f = self.path / self._by_name[name]["file"]
            try:
                with np.load(f, allow_pickle=False) as z:
                    skel.offsets = z["offsets"].astype(np.float64)
            except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
                raise file_error(f, f"corrupt clip file ({exc.__class__.__name__})") from None
        return skel

    def stats(self, speaker: int | str | None = None) -> dict[str, np.ndarray]:
        """Mean/std arrays of ``speaker`` (None: pooled over all): pose_* (47, 6), head_* (6,), face_* (52,)."""
        key = "all" if speaker is None else str(int(speaker))
        try:
            s = self.index["stats"][key]
        except KeyError:
            raise UserError(f"{self.path}: no statistics for speaker {key} (speakers: {self.speakers})") from None
        out = {k: np.asarray(v, dtype=np.float32) for k, v in s.items() if k.endswith(("_mean", "_std"))}
        out["pose_mean"] = out["pose_mean"].reshape(N_JOINTS, 6)
        out["pose_std"] = out["pose_std"].reshape(N_JOINTS, 6)
        return out
