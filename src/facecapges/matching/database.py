"""The database of a matching style: every training frame of its takes (and their mirrors), annotated.

Rows are frames at the model rate (15 fps) of each take's range (default: its training part
``[0, train_until)``; held-out frames never enter), then the same of the take's mirror image.
Per row:

* ``pose`` (47, 6) rot6d — what plays;
* the search features: the groups of :mod:`facecapges.matching.features` (``position``, ``velocity``,
  ``future``, ``speaking``, ``onset``; each defined there once, for these rows and the live query),
  from :func:`facecapges.matching.targets.arm_positions` of the range's own poses and
  :func:`~facecapges.matching.speech.speech_track` of its own audio;
* annotations: ``pause`` (not speaking), ``phase`` (:data:`PHASES`, from the wrist-speed
  extremes: :func:`gesture_phases`), ``lead`` (how much the wrist speed rises over the next 2–4 frames,
  in sd of the take's speed: a stroke about to land), ``searchable`` (false for the last
  :data:`END_MARGIN` frames of each range: a jump there would run off the take's end).

Normalisation (one place: :meth:`Database.normalised`): each feature is centred on its mean;
each group but the [0, 1] ones (``unit``) is divided by the mean of its features' sd
(so the group's inner proportions stay)
and multiplied by ``sqrt(weight)`` of its group, so a squared Euclidean distance of normalised
rows is the weighted sum of the groups' squared distances.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facecapges import rotations as rot
from facecapges import timing
from facecapges.matching.features import (
    DEFAULT_WEIGHTS,
    FEATURE_GROUPS,
    N_FEATURES,
    TakeFrames,
    group_slices,
    take_rows,
)
from facecapges.matching.speech import speech_track
from facecapges.matching.takes import Take, mirror_take
from facecapges.matching.targets import arm_positions

PHASES: tuple[str, ...] = ("rest", "preparation", "stroke", "hold", "retraction")
END_MARGIN = 10  # frames: 0.6 s of future targets + one, so every searchable row's future is real
IDLE_MIN_RUN = 10
IDLE_BRIDGE = 4
IDLE_MIN_SHARE = 0.2


def wrist_speed(arm: np.ndarray, fps: float) -> np.ndarray:
    """Mean wrist speed (T,) of arm positions (T, 4, 3); frame 0 repeats frame 1."""
    s = np.zeros(len(arm))
    if len(arm) > 1:
        s[1:] = np.linalg.norm(np.diff(arm[:, :2], axis=0), axis=-1).mean(axis=1) * fps
        s[0] = s[1]
    return s


def gesture_phases(speed: np.ndarray, height: np.ndarray) -> np.ndarray:
    """Per-frame phase index into :data:`PHASES` from wrist speed (T,) and height (T,).

    The speed is smoothed over 3 frames. A stroke is a local speed maximum above the take's
    60th percentile (and its neighbours); slow frames (below the 25th percentile) are rest if
    the wrists sit low (below the 40th percentile of height), else hold; the remaining frames are
    preparation while the speed rises, retraction while it falls.
    """
    s = np.convolve(np.pad(speed, 1, mode="edge"), np.ones(3) / 3, mode="valid")
    lo, hi = np.percentile(s, 25), np.percentile(s, 60)
    low_h = np.percentile(height, 40)
    ds = np.gradient(s)
    phase = np.where(ds > 0, 1, 4).astype(np.int8)
    slow = s < lo
    phase[slow & (height < low_h)] = 0
    phase[slow & (height >= low_h)] = 3
    peaks = np.flatnonzero((s[1:-1] >= s[:-2]) & (s[1:-1] > s[2:]) & (s[1:-1] > hi)) + 1
    for d in (-1, 0, 1):
        phase[np.clip(peaks + d, 0, len(s) - 1)] = 2
    return phase


def lead_score(speed: np.ndarray) -> np.ndarray:
    """How far the wrist speed rises 2–4 frames ahead, in sd of the speed (≥ 0; 0 near the end)."""
    T = len(speed)
    sd = speed.std() + 1e-6
    ahead = np.full(T, -np.inf)
    for d in (2, 3, 4):
        ahead[: T - d] = np.maximum(ahead[: T - d], speed[d:])
    return np.clip(np.where(np.isfinite(ahead), ahead - speed, 0.0) / sd, 0.0, None).astype(np.float32)


@dataclass
class Segment:
    """Rows of one take range in the database."""

    name: str
    source: str
    start: int  # first frame of the take used
    stop: int  # one past the last frame
    mirrored: bool
    row: int  # first row in the database

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class Database:
    """A style's frames, features and annotations (module docs)."""

    pose: np.ndarray  # (N, 47, 6) float32
    features: np.ndarray  # (N, F) float32, raw
    pause: np.ndarray  # (N,) bool
    phase: np.ndarray  # (N,) int8
    lead: np.ndarray  # (N,) float32
    searchable: np.ndarray  # (N,) bool
    segment: np.ndarray  # (N,) int32: index into segments
    segments: list[Segment]
    weights: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_WEIGHTS))
    mean: np.ndarray | None = None  # (F,)
    scale: np.ndarray | None = None  # (F,): per feature, 1 / (group sd)

    def __post_init__(self) -> None:
        if self.mean is None or self.scale is None:
            self.mean, self.scale = normalisation(self.features, self.pause)

    def __len__(self) -> int:
        return int(len(self.pose))

    def feature_weights(self) -> np.ndarray:
        """(F,) multiplier of the centred features: scale · sqrt(group weight)."""
        assert self.scale is not None
        w = np.empty(N_FEATURES, np.float32)
        for g, sl in group_slices().items():
            w[sl] = np.sqrt(max(float(self.weights.get(g, 0.0)), 0.0))
        return (self.scale * w).astype(np.float32)

    def normalised(self, raw: np.ndarray | None = None, feature_weights: np.ndarray | None = None) -> np.ndarray:
        """Centred, scaled and weighted features of ``raw`` (…, F) (default: the database's own);
        ``feature_weights``: :meth:`feature_weights` if the caller keeps them (the matcher, per search)."""
        raw = self.features if raw is None else raw
        weights = self.feature_weights() if feature_weights is None else feature_weights
        return ((raw - self.mean) * weights).astype(np.float32)

    def tensors(self) -> dict[str, np.ndarray]:
        assert self.mean is not None and self.scale is not None
        return {
            "db.pose": self.pose,
            "db.features": self.features,
            "db.pause": self.pause.astype(np.uint8),
            "db.phase": self.phase,
            "db.lead": self.lead,
            "db.searchable": self.searchable.astype(np.uint8),
            "db.segment": self.segment,
            "db.mean": self.mean,
            "db.scale": self.scale,
        }

    def meta(self) -> dict:
        return {"weights": dict(self.weights), "segments": [s.as_dict() for s in self.segments]}

    @classmethod
    def from_tensors(cls, t: dict[str, np.ndarray], meta: dict) -> Database:
        return cls(
            pose=np.asarray(t["db.pose"], np.float32),
            features=np.asarray(t["db.features"], np.float32),
            pause=np.asarray(t["db.pause"]).astype(bool),
            phase=np.asarray(t["db.phase"], np.int8),
            lead=np.asarray(t["db.lead"], np.float32),
            searchable=np.asarray(t["db.searchable"]).astype(bool),
            segment=np.asarray(t["db.segment"], np.int32),
            segments=[Segment(**s) for s in meta["segments"]],
            weights={k: float(v) for k, v in meta["weights"].items()},
            mean=np.asarray(t["db.mean"], np.float32),
            scale=np.asarray(t["db.scale"], np.float32),
        )


def normalisation(features: np.ndarray, pause: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-feature mean and per-group scale 1/mean(sd) (module docs)."""
    mean = features.mean(axis=0).astype(np.float32)
    sd = features.std(axis=0)
    scale = np.empty(N_FEATURES, np.float32)
    for g, sl in zip(FEATURE_GROUPS, group_slices().values(), strict=True):
        scale[sl] = 1.0 if g.unit else 1.0 / max(float(sd[sl].mean()), 1e-3)
    return mean, scale


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of the runs of True in a boolean array."""
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


def idle_rows(db: Database, min_run: int = IDLE_MIN_RUN, bridge: int = IDLE_BRIDGE) -> np.ndarray:
    """Rows that idle motion plays (N,) bool (module docs of the engine: silence).

    Pause frames, rest-phase frames and the slowest frames (future 0.6 s wrist speed below a
    quantile) are idle; gaps of ≤ ``bridge`` frames inside a segment are filled, then only runs of
    ≥ ``min_run`` frames are kept, so idle plays stretches, not single frames. The quantile starts
    at 0.2 and grows until the idle rows make :data:`IDLE_MIN_SHARE` of the database.
    """
    speed = db.features[:, group_slices()["future"]][:, 2]  # wrist speed over the next 0.6 s
    out = np.zeros(len(db), bool)
    for quant in (0.2, 0.3, 0.4, 0.5):
        base = db.pause | (db.phase == PHASES.index("rest")) | (speed <= np.quantile(speed, quant))
        out[:] = False
        for s in np.unique(db.segment):
            rows = np.flatnonzero(db.segment == s)
            m = base[rows].copy()
            for a, b in runs(~m):
                if b - a <= bridge and a > 0 and b < len(m):
                    m[a:b] = True
            for a, b in runs(m):
                if b - a >= min_run:
                    out[rows[a:b]] = True
        if out.mean() >= IDLE_MIN_SHARE:
            break
    return out


def mirror_twins(db: Database) -> np.ndarray:
    """Each row's canonical row (N,): a mirrored segment's rows map to the rows of its unmirrored twin (the
    same take and frames: one stretch and its mirror image are the same stretch); other rows to themselves.
    Derived from the segments the style file already holds."""
    out = np.arange(len(db))
    twin = {(s.name.removesuffix("~mirror"), s.start, s.stop): s for s in db.segments if not s.mirrored}
    for s in db.segments:
        t = twin.get((s.name.removesuffix("~mirror"), s.start, s.stop)) if s.mirrored else None
        if t is not None:
            k = s.stop - s.start
            out[s.row : s.row + k] = np.arange(t.row, t.row + k)
    return out


def frame_features(take: Take, start: int, stop: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Raw features (n, F) (:func:`~facecapges.matching.features.take_rows`) and annotations of frames
    [start, stop) of ``take`` (module docs).

    Only the range's own poses and audio are read, so nothing outside it leaks in.
    """
    fps = timing.MODEL_FPS
    pose = take.pose[start:stop]
    spf = timing.samples_per_frame()
    audio = take.audio[start * spf : stop * spf]
    arm = arm_positions(take.skeleton, pose).astype(np.float32)
    sp = speech_track(audio, len(pose))
    feats = take_rows(TakeFrames(arm, sp, fps))
    speed = wrist_speed(arm, fps)
    height = arm[:, :2, 1].mean(axis=1)
    ann = {
        "pause": ~sp.speaking,
        "phase": gesture_phases(speed, height),
        "lead": lead_score(speed),
    }
    return feats, ann


def build_database(
    takes: list[Take],
    ranges: list[tuple[int, int]] | None = None,
    mirror: bool = True,
    weights: dict[str, float] | None = None,
) -> Database:
    """The database of ``takes`` over ``ranges`` (default: each take's ``[0, train_until)``), plus mirrors."""
    if ranges is None:
        ranges = [(0, t.train_until) for t in takes]
    parts: list[tuple[Take, int, int]] = []
    for take, (a, b) in zip(takes, ranges, strict=True):
        if a < 0 or b > take.train_until or b - a <= END_MARGIN:
            raise ValueError(f"{take.name}: range [{a}, {b}) is not inside its training part [0, {take.train_until})")
        parts.append((take, a, b))
        if mirror:
            parts.append((mirror_take(take), a, b))
    cols: dict[str, list[np.ndarray]] = {k: [] for k in ("pose", "feat", "pause", "phase", "lead", "srch", "seg")}
    segments: list[Segment] = []
    row = 0
    for k, (take, a, b) in enumerate(parts):
        feats, ann = frame_features(take, a, b)
        n = b - a
        srch = np.ones(n, bool)
        srch[n - END_MARGIN :] = False
        for key, val in (
            ("pose", take.pose[a:b]),
            ("feat", feats),
            ("pause", ann["pause"]),
            ("phase", ann["phase"]),
            ("lead", ann["lead"]),
            ("srch", srch),
            ("seg", np.full(n, k, np.int32)),
        ):
            cols[key].append(val)
        segments.append(Segment(take.name, take.source, a, b, take.mirrored, row))
        row += n
    return Database(
        pose=np.concatenate(cols["pose"]).astype(np.float32),
        features=np.concatenate(cols["feat"]),
        pause=np.concatenate(cols["pause"]).astype(bool),
        phase=np.concatenate(cols["phase"]).astype(np.int8),
        lead=np.concatenate(cols["lead"]).astype(np.float32),
        searchable=np.concatenate(cols["srch"]),
        segment=np.concatenate(cols["seg"]),
        segments=segments,
        weights=dict(DEFAULT_WEIGHTS if weights is None else weights),
    )


def quaternions(pose: np.ndarray) -> np.ndarray:
    """rot6d (…, 47, 6) → unit quaternions (…, 47, 4) (w, x, y, z), w ≥ 0."""
    q = rot.rot6d_to_quaternion(np.asarray(pose, np.float64))
    return np.where(q[..., :1] < 0, -q, q)
