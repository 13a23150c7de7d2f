"""The search features of the matching engine: each group once, filling both the database and the query.

A database row and a live query are one vector: the groups of :data:`FEATURE_GROUPS`, one after another
(:func:`group_slices`). Each group is one :class:`FeatureGroup` that knows its name, width, default
weight, whether it is already in [0, 1] (``unit``: centred but not rescaled by its sd, see
:meth:`~facecapges.matching.database.Database.normalised`), how a take's frames fill it
(:meth:`FeatureGroup.rows`, from :class:`TakeFrames`: the range's own arm positions and speech track) and how
a search fills it live (:meth:`FeatureGroup.query`, from :class:`LiveFrames`: the playing row, the
predictor, the speech cues, the pause):

========  ===========================================  ==============================================
group     database row (frame t of a take range)       live query (a searching stream now)
========  ===========================================  ==============================================
position  wrists + elbows in the chest frame (12)      the playing row's
velocity  their backward difference × fps (12)         the playing row's
future    what the next 0.3 / 0.6 s hold (4,           the predictor's estimate (without one the
          :func:`~.targets.future_targets`)            playing row's), moved to his rest's over
                                                       ``settle_s`` after speech stops
speaking  the VAD of the range's audio (1, unit)       the speech cues' VAD
onset     :func:`onset_recency` of its onsets (1,      the same of the speech cues
          unit)
========  ===========================================  ==============================================

The default weights are the groups' ``weight`` (:data:`DEFAULT_WEIGHTS`); a style stores its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facecapges.matching.speech import SpeechFrame
from facecapges.matching.targets import ARM_JOINTS, TARGET_NAMES, future_targets

ONSET_DECAY = 3.0  # frames: the onset feature falls to 1/e this long after an onset


@dataclass(frozen=True)
class TakeFrames:
    """What the database rows of one take range are made of (n frames; nothing outside the range)."""

    arm: np.ndarray  # (n, 4, 3) float32: arm positions (facecapges.matching.targets.arm_positions)
    speech: SpeechFrame  # (n,) each: the speech track of the range's own audio
    fps: float


@dataclass(frozen=True)
class LiveFrames:
    """What a search knows of its Bs streams now (only the current frame's inputs and the streams' state)."""

    speaking: np.ndarray  # (Bs,) bool: the speech cues' VAD
    since_onset: np.ndarray  # (Bs,) int: frames since the last onset
    predicted: np.ndarray | None  # (Bs, K + 1) the predictor's outputs (None: no predictor)
    settled: np.ndarray  # (Bs, 1) in [0, 1]: how far a pause has moved the future to his rest (0 speaking)
    rest_future: np.ndarray  # (K,) his rest's future targets (the median of idle rest-phase rows)


class FeatureGroup:
    """One group of search features (module docs); the default :meth:`query` keeps the playing row's."""

    name: str
    width: int
    weight: float  # the default weight of the group's squared distance
    unit: bool = False  # already in [0, 1]: not rescaled by its sd

    def rows(self, take: TakeFrames) -> np.ndarray:
        """The database rows (n, width) of a take range."""
        raise NotImplementedError

    def query(self, live: LiveFrames, playing: np.ndarray) -> np.ndarray:
        """The live query (Bs, width), given the group's features of the rows the streams play (Bs, width)."""
        return playing


class Position(FeatureGroup):
    """Wrists and elbows (right wrist, left wrist, right elbow, left elbow) in the chest frame; live the
    playing row's (a jump starts from where the arms are)."""

    name, width, weight = "position", 3 * len(ARM_JOINTS), 1.0

    def rows(self, take: TakeFrames) -> np.ndarray:
        return take.arm.reshape(len(take.arm), -1)


class Velocity(FeatureGroup):
    """The positions' backward difference × fps (frame 0 repeats frame 1); live the playing row's."""

    name, width, weight = "velocity", 3 * len(ARM_JOINTS), 1.0

    def rows(self, take: TakeFrames) -> np.ndarray:
        arm = take.arm
        vel = np.zeros_like(arm)
        vel[1:] = np.diff(arm, axis=0) * take.fps
        vel[0] = vel[1] if len(arm) > 1 else 0.0
        return vel.reshape(len(arm), -1)


class Future(FeatureGroup):
    """Mean wrist speed and height over the next 0.3 and 0.6 s (:data:`~.targets.TARGET_NAMES`).

    Live the predictor estimates them from the speech (without one the playing row's own: continue as
    is); in a pause they move to his rest's over ``settle_s`` (``settled`` 0 → 1), so the search settles
    into his rest."""

    name, width, weight = "future", len(TARGET_NAMES), 1.0

    def rows(self, take: TakeFrames) -> np.ndarray:
        return future_targets(take.arm, take.fps)

    def query(self, live: LiveFrames, playing: np.ndarray) -> np.ndarray:
        future = playing if live.predicted is None else live.predicted[:, : self.width].astype(np.float32)
        return (1.0 - live.settled) * future + live.settled * live.rest_future


class Speaking(FeatureGroup):
    """1 while speaking, 0 in a pause (the VAD of :mod:`~.speech`: of the take's audio, live of the cues)."""

    name, width, weight, unit = "speaking", 1, 4.0, True

    def rows(self, take: TakeFrames) -> np.ndarray:
        return take.speech.speaking[:, None].astype(np.float32)

    def query(self, live: LiveFrames, playing: np.ndarray) -> np.ndarray:
        return live.speaking[:, None].astype(np.float32)


def onset_recency(since_onset: np.ndarray) -> np.ndarray:
    """``exp(−frames since the last onset / ONSET_DECAY)`` (…, 1): 1 at an onset, falling after it."""
    return np.exp(-np.asarray(since_onset)[..., None] / ONSET_DECAY)


class Onset(FeatureGroup):
    """How recent the last speech onset is (:func:`onset_recency` of the take's onsets, live of the cues')."""

    name, width, weight, unit = "onset", 1, 0.25, True

    def rows(self, take: TakeFrames) -> np.ndarray:
        return onset_recency(take.speech.since_onset).astype(np.float32)

    def query(self, live: LiveFrames, playing: np.ndarray) -> np.ndarray:
        return onset_recency(live.since_onset)


FEATURE_GROUPS: tuple[FeatureGroup, ...] = (Position(), Velocity(), Future(), Speaking(), Onset())
GROUP_NAMES: tuple[str, ...] = tuple(g.name for g in FEATURE_GROUPS)
DEFAULT_WEIGHTS: dict[str, float] = {g.name: g.weight for g in FEATURE_GROUPS}
N_FEATURES = sum(g.width for g in FEATURE_GROUPS)


def group_slices() -> dict[str, slice]:
    """Each group's columns in a feature vector."""
    out, at = {}, 0
    for g in FEATURE_GROUPS:
        out[g.name] = slice(at, at + g.width)
        at += g.width
    return out


def take_rows(take: TakeFrames) -> np.ndarray:
    """The raw database features (n, :data:`N_FEATURES`) float32 of a take range."""
    return np.concatenate([g.rows(take) for g in FEATURE_GROUPS], axis=1).astype(np.float32)


def live_query(live: LiveFrames, playing: np.ndarray) -> np.ndarray:
    """The raw live queries (Bs, :data:`N_FEATURES`) float32, given the raw features of the playing rows."""
    raw = np.array(playing, np.float32)
    for g, sl in _LIVE_GROUPS:
        raw[:, sl] = g.query(live, raw[:, sl])
    return raw


# the groups whose live part is not the playing row's own (the others' columns stay as copied)
_LIVE_GROUPS = tuple(
    (g, sl)
    for g, sl in zip(FEATURE_GROUPS, group_slices().values(), strict=True)
    if type(g).query is not FeatureGroup.query
)
