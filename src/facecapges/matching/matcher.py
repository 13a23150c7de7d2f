"""The streaming motion matcher: per 15 fps frame, the speaker's real motion chosen by the speech.

:class:`BatchedMatchingStreams` runs independent causal streams over one
:class:`~facecapges.matching.database.Database` (one stream is a one-slot use of it:
:class:`MatchingStream`), so a served batch and a single stream give the same poses.

Per step and stream (only the current frame's inputs and the stream's own state are read):

1. **Speech cues** of the frame's samples (:class:`~facecapges.matching.speech.SpeechTracker`):
   speaking, onset, frames since the last onset. A muted or silent microphone (all-zero or no
   samples), room tone, keyboard clicks, music and a far voice are pauses (issue #38).
2. **Predictor** (if the style has one): the future wrist speed/height targets of
   :mod:`~facecapges.matching.targets` and a speaking probability from the last second of audio,
   face and head. Without one the query keeps the playing frame's own future (continue as is).
3. **Advance** the playing clip by one frame.
4. **Search** when ``search_interval`` frames have passed since the last search, at an onset,
   when speaking starts or stops, or when the clip runs out. The query is the playing frame's
   features (arm position and velocity) with the predicted future, the speaking state and the
   onset recency put in (each feature group's live part: :mod:`~facecapges.matching.features`); the
   cost of every database row is the squared distance of the normalised features
   (:meth:`Database.normalised`), brute force in NumPy (:func:`search`, a pure function of the
   queries, the database's arrays and the streams' memory and allowed rows), plus:

   * rows not ``searchable`` (a take end within reach) are excluded; while not speaking, or at
     ``intensity`` ≈ 0, only idle rows (pause frames and rest-phase frames) are searched;
   * **memory**: a row played within the last ``memory_s`` seconds costs ``memory_penalty`` more
     (a stretch does not come back while others fit); rows within ``near_frames`` of the playing
     one are not candidates (that is continuing);
   * **onset preference**: for ``onset_frames`` frames after an onset, a row's cost falls by
     ``onset_bonus · min(lead, 3)`` — a row whose wrist speed rises over the next 2–4 frames, a
     stroke that lands just after the onset;
   * **margin**: the stream switches only if the best row beats continuing by ``margin``;
   * a clip plays ``min_play_frames`` before a search may leave it (a clip's end or an idle run's end
     in a pause still switches);
   * **pauses**: the query's future targets move from the predictor's to his rest's (the median future
     of idle rest-phase rows) over ``settle_s`` after speech stops, so the search settles into his rest;
     a switch while not speaking blends with ``pause_halflife_s`` (an idle run's end switches to another
     idle row, blended and under the acceleration cap; ``idle_loop`` — play it back instead — was tried
     and is off).

5. **Blend** by inertialization (:mod:`~facecapges.matching.inertialize`) on all 47 joints'
   rotations, half-life ``halflife_s``; then an **acceleration cap**: the whole-body angular
   acceleration against the last two outputs stays below the ``accel_cap_percentile`` of the
   database's own (his real motion); a larger step is shortened and the inertialization offset takes up
   the difference (the clip continues from the limited pose: no seam pops).
6. **Intensity** (:func:`gain_of`, reached over ``intensity_tau_s``): the deviation ``d`` of each joint's
   rotation from the style's idle mean, and its exponential smoothing ``d̄`` over ``intensity_smooth_s``,
   give ``mean · exp(d + (gain − 1) d̄)``: the slow part of the motion grows or shrinks with the dial
   (spread rises with it), the frame-to-frame accelerations stay his (no pops at 1.3).
7. **A pause** (:mod:`~facecapges.matching.idle`, ``idle_layer``): once ``idle_after_s`` have passed since the
   last speech-like frame of the VAD (``since_voice``), what is shown eases (inertialization, half-life
   ``idle_enter_halflife_s``) from the matched motion into his rest pose (the database's rest row with both
   wrists low nearest the pose shown) with a procedural idle at his rest rows' amplitude and speed on the
   spine, shoulders and arms (``idle_torso``: the neck keeps the matched motion); at the next speech-like frame
   it eases back (half-life ``idle_release_halflife_s``), under the same acceleration cap. The search above runs
   on underneath, so speech resumes from a matched clip at once.

Memory (``memory_s``, 60 s) is kept per *canonical* row (:func:`~facecapges.matching.database.mirror_twins`):
a stretch and its mirror image are one stretch. A clip that would continue into a stretch played before its
own run began (within the memory) searches at once, and continuing pays the memory penalty too.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from typing import Any, NamedTuple

import numpy as np

from facecapges import timing
from facecapges.engine.inputs import finite
from facecapges.engine.intensity import MAX_INTENSITY, MIN_INTENSITY, check_intensity
from facecapges.engine.slots import SlotOwner, Slots
from facecapges.matching import inertialize as inz
from facecapges.matching.database import Database, idle_rows, mirror_twins, quaternions
from facecapges.matching.features import LiveFrames, group_slices, live_query
from facecapges.matching.idle import IdleLayer, IdleMotion
from facecapges.matching.speech import SpeechTracker
from facecapges.skeleton import N_JOINTS, TORSO, Skeleton


@dataclass
class MatchingConfig:
    """The matcher's knobs, chosen on validation frames only (how, with the figures: docs/matching.md)."""

    search_interval: int = 2  # frames between searches (133 ms at 15 fps)
    margin: float = 3.0  # a switch must beat continuing by this much cost
    halflife_s: float = 0.3  # inertialization half-life
    memory_s: float = 60.0  # issue #38: ≥ 60 s, a stretch and its mirror image count as one (mirror_twins)
    memory_penalty: float = 100.0
    near_frames: int = 8
    min_play_frames: int = 6  # a clip plays this long before a search may leave it (forced switches aside)
    pause_halflife_s: float = 0.6  # inertialization half-life of switches while not speaking (settling, idle)
    accel_cap_percentile: float = 99.0  # the output's whole-body acceleration stays below this of his (0: off)
    # in a pause an idle run's end plays it back (ping-pong) instead of a forced switch. Tried (issue #38) and
    # off: the stream then stays on the run it entered at the pause's start, often a moving one (wrists at
    # 0.9-1.2x their speech speed in 15 s of zeros, never settled, against 0.4-0.7x and settled in 1-5 s off)
    idle_loop: bool = False
    settle_s: float = 1.0  # after speech stops the query's future moves to his rest's over this
    # the dial's gain is multiplied by this once a pause has lasted settle_s (zeros pauses: 1.0 settles in
    # 2.5-4.9 s, 0.6 in 1.4-3.6 s; wrist speed pause / speech 0.40-0.57 -> 0.35-0.52)
    pause_gain: float = 0.6
    intensity_smooth_s: float = 0.3  # the dial scales the deviation from idle smoothed over this (gain_of)
    onset_bonus: float = 2.0
    onset_frames: int = 1  # frames after an onset (the onset frame is 0) that prefer strokes
    intensity_tau_s: float = 0.3
    use_predictor: bool = True
    # a pause eases into his rest pose with a procedural idle at his amplitude (matching/idle.py, issue #38):
    # idle_after_s after the last speech-like frame (the VAD's pause begins at 0.4 s), inertialized in
    # (half-life idle_enter_halflife_s) and out at the next speech-like frame (idle_release_halflife_s);
    # idle_rest "low" (his rest row with both wrists low nearest the pose), "nearest" (any rest row) or "mean"
    idle_layer: bool = True
    idle_after_s: float = 0.47  # 7 frames: 1 frame after the VAD's hangover ends (his in-speech breaths stay gestures)
    idle_enter_halflife_s: float = 0.2
    # the share of the matched motion's angular velocity carried into a pause (1: all, as a clip switch); 0 brakes
    # the arms at once, within the acceleration cap (docs/matching.md "Settling sooner")
    idle_enter_velocity: float = 0.0
    idle_release_halflife_s: float = 0.1
    idle_amplitude: float = 1.0
    idle_rest: str = "low"
    # which of the torso's joints idle procedurally in a pause: "neck" (the spine does, Neck and Neck1 keep his
    # matched motion: the head moves as his in a pause without a face track), "matched" (none), "procedural" (all
    # three: the head turned at 0.40-0.44x his speed in a pause, against 0.64-0.72x; docs/matching.md)
    idle_torso: str = "neck"

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> MatchingConfig:
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})


@functools.lru_cache(maxsize=16)
def _smoothing_rate(dt: float, tau_s: float) -> float:
    """A first-order smoothing's share per frame of ``dt`` s with time constant ``tau_s`` (the dial's intensity
    and deviation), computed once per frame length and constant (not on every step)."""
    return 1.0 - np.exp(-dt / max(tau_s, 1e-3))


def gain_of(intensity: float | np.ndarray) -> np.ndarray:
    """The rotation gain of an intensity: ``0.5 + 0.5·i`` below 1, ``i`` from 1 (0 → 0.5, 1 → 1, 1.3 → 1.3).

    The played rotation of each joint is ``m · (m⁻¹ q)^gain`` with ``m`` its idle mean rotation:
    at 1 the motion is as recorded, above it every joint swings further from the idle pose;
    below it the swing shrinks (at 0, where only idle rows play, to half the idle motion: still
    moving, never frozen).
    """
    # np.clip's bounds as two ufunc calls (without its Python layers): the same gains (a signed zero or a NaN's
    # sign bit, where the two may differ, gives 0.5 and NaN either way)
    i = np.minimum(np.maximum(np.asarray(intensity, np.float64), MIN_INTENSITY), MAX_INTENSITY)
    return np.where(i < 1.0, 0.5 + 0.5 * i, i)


IDLE_ONLY_BELOW = 0.05  # intensity below this searches idle rows only


class SearchResult(NamedTuple):
    """What :func:`search` finds per query."""

    best: np.ndarray  # (B,) int: the best row a stream may jump to
    cost: np.ndarray  # (B,): its cost (inf: no row allowed)
    continue_cost: np.ndarray  # (B,): the cost of continuing the playing row (inf: it must be left)
    switch: np.ndarray  # (B,) bool: the best row beats continuing by the margin


def search(
    row_features: np.ndarray,
    row_features_sq: np.ndarray,
    queries: np.ndarray,
    playing: np.ndarray,
    segment: np.ndarray,
    lead: np.ndarray,
    *,
    onset_now: np.ndarray,
    played_recently: np.ndarray,
    blocked: np.ndarray,
    forced: np.ndarray,
    stale: np.ndarray,
    config: MatchingConfig,
    compiled: bool = True,
) -> SearchResult:
    """The motion-matching search, a pure function of its inputs (step 4 of the module docs).

    ``row_features`` (N, features) the database's normalised features and ``row_features_sq`` (N,) their
    squared norms; ``queries`` (B, features) normalised; ``playing`` (B,) the row each stream plays next (what
    continuing means), ``segment`` (N,) each row's take segment, ``lead`` (N,) each row's stroke lead
    (capped). Per query: ``onset_now`` prefers rows whose stroke lands after this onset (cost − ``onset_bonus``
    · lead), ``played_recently`` (B, N) rows within the memory cost ``memory_penalty`` more, ``blocked``
    (B, N) rows may not be jumped to, rows within ``near_frames`` of ``playing`` in its segment are not
    candidates; ``forced`` streams must leave their row, ``stale`` ones pay the memory penalty to continue.
    The cost of a row is the squared distance of its features to the query plus those terms; a stream
    switches when the best row beats continuing by ``margin``. With float32 arrays and penalty everything after the
    products is one compiled pass (:func:`facecapges.matching.kernels.search_rows`, the same bits; ``compiled=False``:
    the NumPy formulas below, which it is tested against).
    """
    cfg = config
    n = len(playing)
    # one matrix-vector product per query: a BLAS matrix-matrix product of this size spawns threads
    # that cost 10-100 ms on a loaded machine (measured), the products 0.03 ms each
    q32, q_sq = queries.astype(np.float32, copy=False), np.einsum("bf,bf->b", queries, queries)
    if row_features.dtype == row_features_sq.dtype == q_sq.dtype == lead.dtype == np.float32:
        # the engine's float32 arrays, in place in one buffer: the same operations in the same order as below
        cost = np.empty((n, len(row_features)), np.float32)
        for i, query in enumerate(q32):
            np.matmul(row_features, query, out=cost[i])
        consts = np.array([cfg.onset_bonus, cfg.memory_penalty, cfg.memory_penalty, cfg.margin], np.float32)
        if compiled and float(consts[1]) == float(cfg.memory_penalty):  # the rest in one pass: the bits of below
            rows, masks = (row_features_sq, q_sq, playing, segment, lead), (onset_now, played_recently, blocked)
            return _search_rows(cost, rows, (*masks, forced, stale), cfg.near_frames, consts)
        np.multiply(cost, 2.0, out=cost)
        np.subtract(row_features_sq[None], cost, out=cost)
        cost += q_sq[:, None]  # (B, N)
    else:
        dots = np.stack([row_features @ query for query in q32])
        cost = row_features_sq[None] - 2.0 * dots + q_sq[:, None]  # (B, N)
    continue_cost = cost[np.arange(n), playing].copy()
    if onset_now.any():
        cost[onset_now] -= cfg.onset_bonus * lead[None]
        continue_cost[onset_now] -= cfg.onset_bonus * lead[playing[onset_now]]
    # in float32 when the penalty is a float32 number: the float64 sum rounded to float32 is the float32 sum
    # (53 ≥ 2·24 + 2 bits: rounding twice gives the correctly rounded result), without two casts of every cost
    pen = np.float64(cfg.memory_penalty)
    if cost.dtype == np.float32 and float(np.float32(pen)) == float(pen):
        pen = np.float32(pen)
    np.add(cost, pen, out=cost, where=played_recently)
    np.copyto(cost, np.inf, where=blocked)
    # rows within near_frames of the playing one, in its segment (continuing): (B, 2 near_frames - 1) only
    near = playing[:, None] + np.arange(1 - cfg.near_frames, cfg.near_frames)
    inside = (near >= 0) & (near < len(row_features))
    near = np.where(inside, near, playing[:, None])
    inside &= segment[near] == segment[playing][:, None]
    cost[np.nonzero(inside)[0], near[inside]] = np.inf
    best = np.argmin(cost, axis=1)
    best_cost = cost[np.arange(n), best]
    continue_cost = np.where(forced, np.inf, continue_cost)
    # continuing runs into a stretch played before this run: it pays the memory too
    continue_cost = np.where(stale, continue_cost + cfg.memory_penalty, continue_cost)
    switch = np.isfinite(best_cost) & (best_cost < continue_cost - cfg.margin)
    return SearchResult(best, best_cost, continue_cost, switch)


def _search_rows(cost: np.ndarray, rows: tuple, masks: tuple, near: int, consts: np.ndarray) -> SearchResult:
    """:func:`search`'s float32 rules after its products (``rows`` = the rows' squared norms, the queries', the
    playing rows, the segments, the leads; ``masks`` = onset, played recently, blocked, forced, stale) by the
    compiled :func:`facecapges.matching.kernels.search_rows` (imported here: loaded when an engine is built)."""
    from facecapges.matching import kernels

    n = len(rows[2])
    out = (np.empty(n, np.intp), np.empty(n, np.float32), np.empty(n, np.float32), np.empty(n, np.bool_))
    run: Any = kernels.search_rows  # (a Numba dispatcher: its arguments are checked when it compiles)
    run(cost, *rows[:2], np.asarray(rows[2], np.int64), *rows[3:], *masks, int(near), consts, out)
    return SearchResult(*out)


class BatchedMatchingStreams(SlotOwner):
    """Independent causal matching streams over one database (module docs)."""

    def __init__(
        self,
        db: Database,
        config: MatchingConfig | None = None,
        predictor=None,
        capacity: int = 8,
        skeleton: Skeleton | None = None,
    ):
        self.db = db
        self.skeleton = skeleton  # the style's: bounds the idle layer's wrist speed (matching/idle.py, wrist_bound)
        self.config = config or MatchingConfig()
        self.predictor = predictor.batched(max(1, capacity)) if (predictor is not None) else None
        self.fps = timing.MODEL_FPS
        self._lock = threading.RLock()
        self._prepare_db()
        self.speech = SpeechTracker(1)
        from facecapges.matching import kernels  # Numba: loaded when an engine is built, not with this module

        kernels.warm()  # the compiled loops' machine code now, not on a stream's first frame
        self._step_offsets, self._dial, self._rot6d32 = kernels.step_offsets, kernels.dial, kernels.rot6d32
        self._advance = kernels.advance
        self.capacity = 0
        self.slots = Slots()
        self._alloc(max(1, capacity))

    # ------------------------------------------------------------ database caches
    def _prepare_db(self) -> None:
        db = self.db
        self.row_features = db.normalised()  # (N, features): what a query is compared with
        self.row_features_sq = np.einsum("nf,nf->n", self.row_features, self.row_features)  # (N,) squared norms
        self.row_quaternions = quaternions(db.pose)  # (N, 47, 4) float64
        velocity = np.zeros(self.row_quaternions.shape[:-1] + (3,))  # (N, 47, 3) each row's angular velocity
        seg = db.segment
        for s in np.unique(seg):
            rows = np.flatnonzero(seg == s)
            velocity[rows] = inz.angular_velocity(self.row_quaternions[rows], self.fps)
        self.row_velocities = velocity
        acc = np.zeros(len(db))  # whole-body angular acceleration of his real motion (rad/s², root sum of squares)
        for s in np.unique(seg):
            rows = np.flatnonzero(seg == s)
            if len(rows) > 2:
                acc[rows[1:-1]] = np.linalg.norm(np.diff(velocity[rows], axis=0)[:-1], axis=(1, 2)) * self.fps
        self.acc_cap = float(np.percentile(acc, self.config.accel_cap_percentile))
        N = len(db)
        self.next_row = np.arange(1, N + 1)
        last = np.r_[seg[1:] != seg[:-1], True]
        self.next_row[last] = -1  # the clip ends here
        self.prev_row = np.arange(-1, N - 1)
        self.prev_row[np.r_[True, seg[1:] != seg[:-1]]] = -1  # the clip starts here
        self.idle_play = idle_rows(db)  # rows idle motion may play through
        self.idle = self.idle_play & db.searchable  # rows an idle search may jump to
        if not self.idle.any():
            self.idle = db.searchable.copy()
        self.idle_mean = np.ascontiguousarray(inz.quaternion_mean(self.row_quaternions[self.idle]))  # (47, 4)
        self.canon = mirror_twins(db)  # a row and its mirror image share one memory entry
        rest = self.idle & (db.phase == 0)  # his rest: idle rows in the rest phase (slow, wrists low)
        fut = db.features[rest if rest.any() else self.idle][:, group_slices()["future"]]
        self.rest_future = np.median(fut, axis=0).astype(np.float32)  # where a pause's query settles
        self._blocked = np.stack([~db.searchable, ~self.idle])  # rows a search may not jump to: [any, idle only]
        self.lead = np.minimum(db.lead, 3.0).astype(np.float32)
        self.feature_weights = db.feature_weights()  # (features,) the centred features' multipliers
        cfg = self.config
        self.idle_layer = (
            IdleLayer(
                IdleMotion.measure(
                    self.row_quaternions,
                    seg,
                    rest,
                    self.fps,
                    cfg.idle_rest,
                    wrist_height=db.features[:, group_slices()["position"]].reshape(len(db), 4, 3)[:, :2, 1],
                    skeleton=self.skeleton,
                ),
                self.fps,
                after_frames=int(round(cfg.idle_after_s * self.fps)),
                enter_halflife_s=cfg.idle_enter_halflife_s,
                release_halflife_s=cfg.idle_release_halflife_s,
                amplitude=cfg.idle_amplitude,
                acc_cap=self.acc_cap if cfg.accel_cap_percentile > 0 else 0.0,
                keep={"procedural": (), "neck": TORSO[1:], "matched": TORSO}[cfg.idle_torso],
                enter_velocity=cfg.idle_enter_velocity,
            )
            if cfg.idle_layer
            else None
        )

    # ---------------------------------------------------------------- storage
    def _alloc(self, capacity: int) -> None:
        old, N = self.capacity, len(self.db)

        def grow(name: str, shape: tuple, fill, dtype) -> np.ndarray:
            new = np.full((capacity, *shape), fill, dtype)
            if old:
                new[:old] = getattr(self, name)
            return new

        self.row = grow("row", (), 0, np.int64)
        self.t = grow("t", (), 0, np.int64)
        self.since_search = grow("since_search", (), 0, np.int64)
        self.was_speaking = grow("was_speaking", (), False, bool)
        self.off_x = grow("off_x", (N_JOINTS, 3), 0.0, np.float64)
        self.off_v = grow("off_v", (N_JOINTS, 3), 0.0, np.float64)
        self.last_used = grow("last_used", (N,), -(10**9), np.int64)
        self.intensity_target = grow("intensity_target", (), 1.0, np.float64)
        self.intensity_now = grow("intensity_now", (), 1.0, np.float64)
        self.switches = grow("switches", (), 0, np.int64)
        self.since_switch = grow("since_switch", (), 10**6, np.int64)
        self.quiet = grow("quiet", (), 0, np.int64)
        self.run_start = grow("run_start", (), 0, np.int64)  # t of the last switch: the playing run began
        self.direction = grow("direction", (), 1, np.int64)  # +1 forwards, −1 an idle run played back
        self.halflife = grow("halflife", (), self.config.halflife_s, np.float64)
        self.slow_dev = grow("slow_dev", (N_JOINTS, 3), 0.0, np.float64)
        self.prev_q = grow("prev_q", (2, N_JOINTS, 4), 0.0, np.float64)  # the last two blended outputs
        self._pred_slots = grow("_pred_slots", (), 0, np.intp)  # each open slot's predictor slot
        self.speech.ensure(capacity)
        if self.idle_layer is not None:
            self.idle_layer.grow(capacity)
        self.slots.grown(capacity)
        self.capacity = capacity

    def _opened(self, slot: int) -> None:
        if self.predictor is not None:
            self._pred_slots[slot] = self.predictor.open()

    def close(self, slot: int) -> None:
        with self._lock:
            if self.slots.release(slot) and self.predictor is not None:  # an open slot has a predictor slot
                self.predictor.close(int(self._pred_slots[slot]))

    def set_intensity(self, slot: int, value: float) -> None:
        """The stream's intensity (:mod:`facecapges.engine.intensity`: 0 … 1 … 1.3); reached smoothly (module docs)."""
        self.intensity_target[slot] = check_intensity(value)

    def reset(self, slot: int, initial_pose: np.ndarray | None = None) -> None:
        """Cold start: ``initial_pose`` (47, 6), (N, 47, 6) or None (the style's idle pose)."""
        with self._lock:
            self.slots.require(slot)
            self.speech.reset(slot)
            if self.predictor is not None:
                self.predictor.reset(int(self._pred_slots[slot]))
            self.t[slot], self.since_search[slot], self.switches[slot] = 0, 0, 0
            self.since_switch[slot], self.halflife[slot] = 10**6, self.config.halflife_s
            self.quiet[slot], self.direction[slot], self.run_start[slot] = 0, 1, 0
            self.was_speaking[slot] = False
            self.last_used[slot] = -(10**9)
            self.intensity_now[slot] = self.intensity_target[slot]
            self._start_at(slot, initial_pose)
            self._restart_history(np.array([slot]))

    def _start_at(self, slot: int, pose: np.ndarray | None) -> None:
        """Play from the idle row nearest ``pose`` with the offset that makes the output ``pose``."""
        rows = np.flatnonzero(self.idle)
        if pose is None:
            target = self.idle_mean
            cand = rows[
                np.argmin(np.sum(1.0 - np.abs(np.einsum("njk,jk->nj", self.row_quaternions[rows], target)), axis=1))
            ]
            self.row[slot], self.off_x[slot], self.off_v[slot] = cand, 0.0, 0.0
            return
        p = np.asarray(pose, np.float32)
        if p.ndim == 2:
            p = p[None]
        if p.ndim != 3 or p.shape[1:] != (N_JOINTS, 6):
            raise ValueError(f"initial pose must be ({N_JOINTS}, 6) or (N, {N_JOINTS}, 6), got {np.shape(pose)}")
        q = quaternions(p[-2:])
        cur = q[-1]
        cand = int(
            rows[np.argmin(np.sum(1.0 - np.abs(np.einsum("njk,jk->nj", self.row_quaternions[rows], cur)), axis=1))]
        )
        vel = inz.angular_velocity(q, self.fps)[0] if len(q) > 1 else np.zeros((N_JOINTS, 3))
        self.row[slot] = cand
        self.off_x[slot] = inz.qlog(inz.qabs(inz.qmul(cur, inz.qconj(self.row_quaternions[cand]))))
        self.off_v[slot] = vel - self.row_velocities[cand] if len(q) > 1 else 0.0

    # ------------------------------------------------------------- the step
    def _ids(self, slots: Sequence[int]) -> np.ndarray:
        return np.array(self.slots.check(np.asarray(slots).reshape(-1)), np.int64)

    def _inputs(self, audio, face, head, B: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        spf = timing.samples_per_frame()
        if isinstance(audio, np.ndarray) and audio.ndim == 2:
            a = np.asarray(audio, np.float32)
            if a.shape[0] != B or a.shape[1] > spf:
                raise ValueError(f"audio must be (B, ≤{spf}), got {a.shape}")
        else:
            a = np.zeros((B, spf), np.float32)
            for i, x in enumerate(audio):
                x = np.asarray(x, np.float32).reshape(-1)
                if len(x) > spf:
                    raise ValueError(f"a frame owns at most {spf} audio samples, got {len(x)}")
                a[i, : len(x)] = x
        f = np.asarray(face, np.float32).reshape(B, -1)
        h = np.asarray(head, np.float32).reshape(B, -1)
        if f.shape[1] != 52 or h.shape[1] != 6:
            raise ValueError(f"face must be (B, 52) and head (B, 6), got {f.shape} and {h.shape}")
        return finite(a), finite(f), finite(h)  # NaN and ±inf → 0 (the arrays are only read)

    def step(self, slots: Sequence[int], audio, face, head) -> np.ndarray:
        """One frame per stream: audio (B, ≤1067), face (B, 52), head (B, 6) → poses (B, 47, 6) rot6d."""
        with self._lock:
            ids = self._ids(slots)
            B = len(ids)
            if B == 0:
                return np.zeros((0, N_JOINTS, 6), np.float32)
            a, f, h = self._inputs(audio, face, head, B)
            cues = self.speech.step(ids, a)
            pred = None
            if self.predictor is not None and self.config.use_predictor:
                # the inputs are checked above: the predictor's own checks would change nothing
                if a.shape[1] == self.predictor.samples_per_frame:
                    pred = self.predictor.step_checked(self._pred_slots[ids], a, f, h)
                else:
                    pred = self.predictor.step(self._pred_slots[ids], a, f, h)
            self._advance_and_search(ids, cues, pred)
            q, gain = self._blend(ids)
            if self.idle_layer is not None:  # a pause: his rest pose and idle (matching/idle.py)
                q = self.idle_layer.apply(ids, q, cues.since_voice, self.t[ids], gain)
            self.last_used[ids, self.canon[self.row[ids]]] = self.t[ids]
            self.t[ids] += 1
            out = np.empty((B, N_JOINTS, 6), np.float32)
            self._rot6d32(np.ascontiguousarray(q, np.float64), out)  # rot.quaternion_to_rot6d(q) in float32's bits
            return out

    def _advance_and_search(self, ids: np.ndarray, cues, pred: np.ndarray | None) -> None:
        cfg = self.config
        B = len(ids)
        nxt, idle_only, forced, into_recent, need = out = tuple(np.empty(B, t) for t in (np.int64,) + (np.bool_,) * 4)
        state = (self.row, self.next_row, self.prev_row, self.direction, self.idle_play, self.since_search)
        state += (self.since_switch, self.was_speaking, self.quiet, self.last_used, self.canon, self.t, self.run_start)
        state += (self.intensity_target,)
        consts = (IDLE_ONLY_BELOW, bool(cfg.idle_loop), int(cfg.min_play_frames), int(cfg.search_interval))
        consts += (float(cfg.memory_s * self.fps),)  # (one compiled variant: the same comparisons of integers)
        # each stream's next row, its counters and whether it searches (module docs, 3-4): one compiled call
        if not self._advance(ids, cues.speaking, cues.onset, state, consts, out):
            return
        searching = np.flatnonzero(need)
        best, switch = self._search(
            ids[searching],
            nxt[searching],
            cues,
            searching,
            pred,
            idle_only[searching],
            forced[searching],
            into_recent[searching],
        )
        self.since_search[ids[searching]] = 0
        if switch.any():  # every switching stream at once (elementwise: the same values as one by one)
            k = searching[np.flatnonzero(switch)]
            self._switch(ids[k], nxt[k], best[switch], idle_only[k])

    def _switch(self, s: np.ndarray, src: np.ndarray, b: np.ndarray, idle: np.ndarray) -> None:
        """Streams ``s`` leave row ``src`` for row ``b``: the offsets carry the jump (inertialization), the new
        run starts there (``idle``: in a pause, with the pause's half-life)."""
        self.off_x[s], self.off_v[s] = inz.transition(
            self.off_x[s],
            self.off_v[s],
            self.row_quaternions[src],
            self.row_velocities[src],
            self.row_quaternions[b],
            self.row_velocities[b],
        )
        self.row[s] = b
        self.direction[s] = 1
        self.switches[s] += 1
        self.since_switch[s] = 0
        self.run_start[s] = self.t[s]
        self.halflife[s] = np.where(idle, self.config.pause_halflife_s, self.config.halflife_s)

    def _query(
        self, ids: np.ndarray, rows: np.ndarray, cues, searching: np.ndarray, pred: np.ndarray | None
    ) -> np.ndarray:
        """Normalised queries (Bs, F): each feature group's live part (:mod:`~facecapges.matching.features`)
        from the playing rows, the speech cues, the predictor and how far a pause has settled."""
        live = LiveFrames(
            speaking=cues.speaking[searching],
            since_onset=cues.since_onset[searching],
            predicted=None if pred is None else pred[searching],
            settled=self._settled(ids)[:, None],
            rest_future=self.rest_future,
        )
        return self.db.normalised(live_query(live, self.db.features[rows]), self.feature_weights)

    def _settled(self, ids: np.ndarray) -> np.ndarray:
        """How far each stream's pause has settled (B,): 0 while speaking, 1 once it has lasted ``settle_s``."""
        return np.minimum(self.quiet[ids] / max(self.config.settle_s * self.fps, 1.0), 1.0)  # quiet ≥ 0: np.clip's

    def _search(self, ids, rows, cues, searching, pred, idle_only, forced, stale) -> tuple[np.ndarray, np.ndarray]:
        """Best row (Bs,) and whether to switch to it (Bs,) for the searching streams: their queries, memory and
        allowed rows, then :func:`search`."""
        cfg = self.config
        queries = self._query(ids, rows, cues, searching, pred)
        # compared per canonical row, then spread to the rows (bytes, not int64, are gathered)
        played_recently = (self.last_used[ids] > (self.t[ids] - cfg.memory_s * self.fps)[:, None])[:, self.canon]
        result = search(
            self.row_features,
            self.row_features_sq,
            queries,
            rows,
            self.db.segment,
            self.lead,
            onset_now=cues.since_onset[searching] < cfg.onset_frames,
            played_recently=played_recently,
            blocked=self._blocked[idle_only.astype(np.intp)],
            forced=forced,
            stale=stale,
            config=cfg,
        )
        return result.best, result.switch

    def _blend(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Decay the offsets one frame and apply them and the intensity: quaternions (B, 47, 4), and the dial's
        gain now (B,) (:func:`gain_of` of the intensity reached)."""
        cfg = self.config
        dt = 1.0 / self.fps
        # the offsets decay one frame, then the acceleration cap: a larger step is shortened and the offset takes up
        # the difference, so the played clip continues from the limited pose (a seam never pops)
        q = np.empty((len(ids), N_JOINTS, 4))
        cap = self.acc_cap if cfg.accel_cap_percentile > 0 else -1.0
        base = self.row_quaternions[self.row[ids]]
        self._step_offsets(ids, self.off_x, self.off_v, self.halflife, base, self.prev_q, cap, float(self.fps), True, q)
        alpha = _smoothing_rate(dt, cfg.intensity_tau_s)
        now = self.intensity_now[ids] + alpha * (self.intensity_target[ids] - self.intensity_now[ids])
        self.intensity_now[ids] = now
        g = gain = gain_of(now)
        if cfg.pause_gain != 1.0:  # a settled pause: the slow deviation from idle shrinks (his rest, calmer)
            g = g * (1.0 - self._settled(ids) * (1.0 - cfg.pause_gain))
        # the dial: the deviation from the idle mean, smoothed, scaled by gain − 1 and added; the recorded
        # motion's accelerations stay his (only a slow part grows or shrinks), the spread follows the gain
        self._dial(ids, q, self.idle_mean, self.slow_dev, _smoothing_rate(dt, cfg.intensity_smooth_s), g)
        return q, gain

    def _restart_history(self, ids: np.ndarray) -> None:
        """The blend's history (last outputs, smoothed deviation) of restarted streams: their pose now, at rest."""
        q = inz.qmul(inz.qexp(self.off_x[ids]), self.row_quaternions[self.row[ids]])
        self.prev_q[ids] = q[:, None]
        self.slow_dev[ids] = 0.0  # then the deviation itself (the dial's first step with gain 1: q unchanged)
        self._dial(ids, np.ascontiguousarray(q), self.idle_mean, self.slow_dev, 1.0, np.ones(len(ids)))
        if self.idle_layer is not None:
            self.idle_layer.restart(ids, q)

    def warmup(self, slots: Sequence[int], audio, face, head, pose) -> None:
        """Push one frame whose pose is known per stream: the cues and predictor see its inputs, and
        the stream continues from ``pose`` (the idle row nearest it, offset to match)."""
        with self._lock:
            ids = self._ids(slots)
            a, f, h = self._inputs(audio, face, head, len(ids))
            cues = self.speech.step(ids, a)
            if self.predictor is not None and self.config.use_predictor:
                self.predictor.step(self._pred_slots[ids], a, f, h)
            p = np.asarray(pose, np.float32).reshape(len(ids), N_JOINTS, 6)
            for k, s in enumerate(ids):
                self._start_at(int(s), p[k])
            self._restart_history(ids)
            self.was_speaking[ids] = cues.speaking
            self.t[ids] += 1


class MatchingStream:
    """One causal matching stream: a one-slot :class:`BatchedMatchingStreams` (same poses)."""

    def __init__(
        self, db: Database, config: MatchingConfig | None = None, predictor=None, skeleton: Skeleton | None = None
    ):
        self.kernel = BatchedMatchingStreams(db, config, predictor, capacity=1, skeleton=skeleton)
        self._slot = [self.kernel.open()]

    @property
    def intensity(self) -> float:
        return float(self.kernel.intensity_target[self._slot[0]])

    @intensity.setter
    def intensity(self, value: float) -> None:
        self.kernel.set_intensity(self._slot[0], value)

    @property
    def frames(self) -> int:
        return int(self.kernel.t[self._slot[0]])

    @property
    def playing_row(self) -> int:
        """The database row the stream plays now (for tests and diagnostics)."""
        return int(self.kernel.row[self._slot[0]])

    def reset(self, initial_pose: np.ndarray | None = None) -> None:
        """Start a new stream. ``initial_pose``: (47, 6), (N, 47, 6) or None (idle)."""
        self.kernel.reset(self._slot[0], initial_pose)

    def warmup(self, audio: np.ndarray, face: np.ndarray, head: np.ndarray, pose: np.ndarray) -> None:
        """Push one frame whose pose is known (cheap: no search)."""
        self.kernel.warmup(self._slot, [audio], np.asarray(face)[None], np.asarray(head)[None], np.asarray(pose)[None])

    def step(self, audio: np.ndarray, face: np.ndarray, head: np.ndarray) -> np.ndarray:
        """The current frame's pose (47, 6) rot6d from this frame's inputs."""
        return self.kernel.step(self._slot, [audio], np.asarray(face)[None], np.asarray(head)[None])[0]
