"""Timing and both hands (issue #38): the trials never tried before, on validation (tuning only).

Trials, each a knob of :class:`TrialConfig` (the engine's :class:`MatchingConfig` plus the trial's own), all
living in this script (an experiment that has not won does not run through the product, issue #35):

* ``stroke_aware``: at an onset the search prefers *preparation* rows whose stroke peak (the centre of a
  ``stroke`` phase run, ``Database.phase``) lands ``stroke_lo_s``–``stroke_hi_s`` (150–300 ms) ahead: the
  onset bonus's ``lead`` becomes that row's lead if it qualifies, else 0 (:func:`stroke_lead`).
* ``rate_max`` > 0: a causal playback-rate adjustment of the playing clip (fractional row advance, the
  output slerped between a row and the next): while speaking, the rate eases (``rate_tau_s``) toward the
  one that lands the clip's next stroke peak ``rate_lag_s`` after the predicted next stressed syllable
  (the last onset if it is younger than the lag, else the last onset plus the running mean inter-onset
  interval), within 1 ± ``rate_max``; in a pause 1.
* ``targets`` ``"per_wrist"``: the ``future`` group (and the predictor's outputs) hold each wrist's height
  over the next 0.3 / 0.6 s instead of their mean (6 targets; a new predictor is trained); ``"asym"``: the
  mean heights plus |right − left| height over each horizon (6 targets).
* ``both_weight`` > 0: a search feature ``both`` — the share of the next 0.6 s with both wrists raised
  (10 cm above each wrist's 5th-percentile height in the range) — whose live query is his speech frames'
  share of two-handed frames, pushed by ``both_gain`` × (his share − the stream's own share over the last
  ``both_window_s``) and clipped to [0, 1]; in a pause his pause frames' share.

Database and speech predictor from [0, 0.64 T) of his two paired takes, the engine run on [0.64 T, 0.8 T)
with his face and the head at rest (as ``matching_both_hands_sweep.py``), starting ``--lead-in`` seconds
earlier (inputs only). Figures per take: both-hands share (his), wrist height ×, spread ×, jerk ×, pops a
minute in speech, head speed ×, torso sway × (``facecapges.evaluation.conversation``); pooled over both
takes: onset → next wrist-speed peak lag and the event-related rise, each beside random times
(``facecapges.evaluation.timing``), and repetition with mirrors counted (returns within 60 s a minute,
longest copy). ``--heldout`` builds from [0, 0.8 T) and scores [0.8 T, T); ``--unseen`` adds BEAT
2_scott_0_4_4 (audio only, no face, head at rest) against his training reference. Those two are reported,
never chosen on.

    PYTHONPATH=src python scripts/matching_timing_hands_sweep.py '{"base": {}, "stroke": {"stroke_aware": true}}'

Results: docs/matching.md.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import sys
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from facecapges import timing
from facecapges.evaluation import conversation as cv
from facecapges.evaluation import realism as rz
from facecapges.evaluation import synchrony as sy
from facecapges.evaluation import timing as tm
from facecapges.matching import database as mdb
from facecapges.matching import features as mf
from facecapges.matching import inertialize as inz
from facecapges.matching import predictor as mp
from facecapges.matching import predictor_training as mpt
from facecapges.matching import targets as mt
from facecapges.matching.database import PHASES, build_database, mirror_twins
from facecapges.matching.features import LiveFrames, group_slices, live_query
from facecapges.matching.matcher import BatchedMatchingStreams, MatchingConfig, MatchingStream
from facecapges.matching.takes import load_take
from facecapges.rotations import identity_rot6d

FPS, SPF = timing.MODEL_FPS, timing.samples_per_frame()
SH = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


@dataclass
class TrialConfig(MatchingConfig):
    stroke_aware: bool = False
    stroke_lo_s: float = 0.15
    stroke_hi_s: float = 0.30
    rate_max: float = 0.0
    rate_tau_s: float = 0.2
    rate_lag_s: float = 0.2
    rate_reach_s: float = 1.0  # only a stroke peak this near is steered toward the syllable
    both_gain: float = 2.0
    both_window_s: float = 3.0

    @classmethod
    def from_dict(cls, d: dict) -> TrialConfig:
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})


# ------------------------------------------------------------------------------- stroke-aware search
def stroke_peaks(db) -> np.ndarray:
    """Per row (N,) frames to the next stroke peak (centre of a stroke-phase run) in its segment (≥ 1; 10⁶: none)."""
    n = len(db)
    out = np.full(n, 10**6, np.int64)
    stroke = db.phase == PHASES.index("stroke")
    for s in np.unique(db.segment):
        rows = np.flatnonzero(db.segment == s)
        centres = np.array([rows[(a + b - 1) // 2] for a, b in mdb.runs(stroke[rows])], np.int64)
        if not len(centres):
            continue
        i = np.searchsorted(centres, rows, side="right")  # the first centre after the row
        ok = i < len(centres)
        out[rows[ok]] = centres[i[ok]] - rows[ok]
    return out


def stroke_lead(db, lo_s: float, hi_s: float) -> np.ndarray:
    """The onset bonus's lead (N,) for stroke-aware search: a preparation row whose next stroke peak is
    ``lo_s``–``hi_s`` ahead keeps its lead (≥ 1, capped at 3), every other row 0."""
    d = stroke_peaks(db)
    lo, hi = int(np.ceil(lo_s * FPS - 1e-9)), int(np.floor(hi_s * FPS + 1e-9))
    ok = (db.phase == PHASES.index("preparation")) & (d >= lo) & (d <= hi)
    return np.where(ok, np.clip(db.lead, 1.0, 3.0), 0.0).astype(np.float32)


# ------------------------------------------------------------------------------- the both-hands feature
RAISE_CM = cv.RAISE_CM
BOTH_H = round(0.6 * FPS)


def both_raised(arm: np.ndarray) -> np.ndarray:
    """(n,) both wrists raised (chest frame y 10 cm above each wrist's 5th percentile in the range)."""
    y = arm[:, :2, 1]
    rest = np.percentile(y, cv.REST_PERCENTILE, axis=0)
    return (y > rest + RAISE_CM).all(axis=1)


class Both(mf.FeatureGroup):
    name, width, weight, unit = "both", 1, 1.0, True

    def rows(self, take: mf.TakeFrames) -> np.ndarray:
        r = both_raised(take.arm).astype(np.float64)
        T = len(r)
        idx = np.minimum(np.arange(T)[:, None] + np.arange(1, BOTH_H + 1)[None, :], T - 1)
        return r[idx].mean(axis=1)[:, None].astype(np.float32)


# ------------------------------------------------------------------------------- per-wrist future targets
def per_wrist_targets(arm: np.ndarray, fps: float) -> np.ndarray:
    """(T, 6): speed 0.3, right height 0.3, speed 0.6, right height 0.6, left height 0.3, left height 0.6
    (column 2 stays the 0.6-s speed, what ``idle_rows`` reads)."""
    a = np.asarray(arm, np.float64)
    base = mt.future_targets(a, fps)  # speed / mean height
    out = np.empty((len(a), 6), np.float32)
    out[:, [0, 2]] = base[:, [0, 2]]
    T = len(a)
    for k, h in enumerate(mt.HORIZONS_S):
        H = max(1, round(h * fps))
        idx = np.minimum(np.arange(T)[:, None] + np.arange(1, H + 1)[None, :], T - 1)
        right, left = a[:, 0, 1][idx].mean(axis=1), a[:, 1, 1][idx].mean(axis=1)
        out[:, 1 + 2 * k] = right
        out[:, 4 + k] = left
    return out


def asym_targets(arm: np.ndarray, fps: float) -> np.ndarray:
    """(T, 6): the four targets plus |right − left| wrist height over the next 0.3 / 0.6 s."""
    a = np.asarray(arm, np.float64)
    base = mt.future_targets(a, fps)
    T = len(a)
    extra = []
    for h in mt.HORIZONS_S:
        H = max(1, round(h * fps))
        idx = np.minimum(np.arange(T)[:, None] + np.arange(1, H + 1)[None, :], T - 1)
        extra.append(np.abs(a[:, 0, 1] - a[:, 1, 1])[idx].mean(axis=1))
    return np.concatenate([base, np.stack(extra, 1)], axis=1).astype(np.float32)


@contextlib.contextmanager
def feature_layout(targets: str, both: bool):
    """Patch the modules' target function and feature groups for a trial (restored on exit)."""
    saved = []

    def patch(mod, name, value):
        saved.append((mod, name, getattr(mod, name)))
        setattr(mod, name, value)

    fn = {"per_wrist": per_wrist_targets, "asym": asym_targets}.get(targets)
    if fn is not None:
        k = 6
        names = tuple(f"target_{i}" for i in range(k))
        for mod in (mpt, mf):
            patch(mod, "future_targets", fn)
        patch(mpt, "TARGET_NAMES", names)
        patch(mp, "K", k)
        patch(mpt, "K", k)
        patch(mp, "OUTPUT_NAMES", (*names, "speaking"))
        patch(mf.Future, "width", k)
    if both:
        groups = (*mf.FEATURE_GROUPS, Both())
        for mod in (mf, mdb):
            patch(mod, "FEATURE_GROUPS", groups)
    n = sum(g.width for g in mf.FEATURE_GROUPS)
    for mod in (mf, mdb):
        patch(mod, "N_FEATURES", n)
    try:
        yield
    finally:
        for mod, name, value in reversed(saved):
            setattr(mod, name, value)


# ------------------------------------------------------------------------------- the trial engine
class TrialStreams(BatchedMatchingStreams):
    """The product's streams plus the trial knobs (module docs); with every knob off it is the product."""

    config: TrialConfig
    rate_log: list

    def _prepare_db(self) -> None:
        super()._prepare_db()
        self.rate_log = []  # (rate, speaking) of every speech frame: how much the playback rate works
        cfg = self.config
        if getattr(cfg, "stroke_aware", False):
            self.lead = stroke_lead(self.db, cfg.stroke_lo_s, cfg.stroke_hi_s)
        self.next_peak = stroke_peaks(self.db)
        sl = group_slices()
        self.has_both = "both" in sl
        if self.has_both:
            pos = self.db.features[:, sl["position"]]
            y = pos[:, [1, 4]]
            rest = np.percentile(y, cv.REST_PERCENTILE, axis=0)
            self.both_now = (y > rest + RAISE_CM).all(axis=1)
            sp = ~self.db.pause
            self.both_speech = float(self.both_now[sp].mean())
            self.both_pause = float(self.both_now[~sp].mean()) if (~sp).any() else self.both_speech

    def _alloc(self, capacity: int) -> None:
        old = self.capacity
        super()._alloc(capacity)
        for name, fill in (("frac", 0.0), ("rate", 1.0), ("ioi", 9.0), ("since_on", 30.0), ("both_share", -1.0)):
            new = np.full(capacity, fill, np.float64)
            if old:
                new[:old] = getattr(self, name)[:old]
            setattr(self, name, new)

    def reset(self, slot: int, initial_pose=None) -> None:
        super().reset(slot, initial_pose)
        self.frac[slot], self.rate[slot], self.ioi[slot], self.since_on[slot] = 0.0, 1.0, 9.0, 30.0
        self.both_share[slot] = -1.0

    # ---- the playback rate: which rows this frame advances by, then the product's advance and search
    def _advance_and_search(self, ids, cues, pred) -> None:
        cfg = self.config
        on = np.asarray(cues.onset, bool)
        since = self.since_on[ids]
        self.ioi[ids] = np.where(on & (since < 30), 0.7 * self.ioi[ids] + 0.3 * (since + 1), self.ioi[ids])
        self.since_on[ids] = np.where(on, 0.0, since + 1)
        if cfg.rate_max <= 0:
            return super()._advance_and_search(ids, cues, pred)
        row = self.row[ids]
        speaking = np.asarray(cues.speaking, bool)
        lag = cfg.rate_lag_s * self.fps
        s = self.since_on[ids]
        # frames until the predicted stressed syllable's stroke should land: this onset's, or the next one's
        until = np.where(s < lag, lag - s, self.ioi[ids] - s + lag)
        until = np.maximum(until, 1.0)
        d = self.next_peak[row] - self.frac[ids]  # frames until the playing clip's next stroke peak
        steer = speaking & (d > 0) & (d <= cfg.rate_reach_s * self.fps)
        target = np.where(steer, np.clip(d / until, 1 - cfg.rate_max, 1 + cfg.rate_max), 1.0)
        alpha = 1.0 - np.exp(-1.0 / (self.fps * max(cfg.rate_tau_s, 1e-3)))
        rate = np.where(speaking, self.rate[ids] + alpha * (target - self.rate[ids]), 1.0)
        self.rate[ids] = rate
        self.rate_log.extend(zip(rate[speaking].tolist(), [True] * int(speaking.sum()), strict=True))
        frac = np.where(speaking, self.frac[ids], 0.0) + rate
        steps = np.floor(frac).astype(np.int64)
        frac -= steps
        # hold: step back one row first so the product's one-row advance lands on the same row
        hold = (steps == 0) & (self.prev_row[row] >= 0)
        frac = np.where((steps == 0) & ~hold, 0.0, frac)
        nxt = self.next_row[row]
        skip = (steps >= 2) & (nxt >= 0)
        skip &= self.next_row[np.where(nxt >= 0, nxt, 0)] >= 0
        r = row.copy()
        r[hold] = self.prev_row[row[hold]]
        r[skip] = nxt[skip]
        self.row[ids] = r
        self.frac[ids] = frac
        before = self.switches[ids].copy()
        super()._advance_and_search(ids, cues, pred)
        switched = self.switches[ids] != before
        self.frac[ids[switched]] = 0.0

    def _blend(self, ids):
        """The product's blend, the playing row's rotations slerped toward the next row by ``frac``."""
        row = self.row[ids]
        nxt = self.next_row[row]
        k = np.flatnonzero((self.frac[ids] > 1e-9) & (nxt >= 0))
        if not len(k):
            return super()._blend(ids)
        q0 = self.row_quaternions[row[k]].copy()
        q1 = self.row_quaternions[nxt[k]]
        f = self.frac[ids[k]][:, None, None]
        self.row_quaternions[row[k]] = inz.qmul(q0, inz.qexp(f * inz.qlog(inz.qabs(inz.qmul(inz.qconj(q0), q1)))))
        try:
            return super()._blend(ids)
        finally:
            self.row_quaternions[row[k]] = q0

    # ---- the both-hands query term
    def step(self, slots, audio, face, head):
        out = super().step(slots, audio, face, head)
        if self.has_both:
            ids = self._ids(slots)
            a = 1.0 - np.exp(-1.0 / (self.fps * self.config.both_window_s))
            now = self.both_now[self.row[ids]].astype(np.float64)
            prev = self.both_share[ids]
            self.both_share[ids] = np.where(prev < 0, now, prev + a * (now - prev))
        return out

    def _query(self, ids, rows, cues, searching, pred):
        live = LiveFrames(
            speaking=cues.speaking[searching],
            since_onset=cues.since_onset[searching],
            predicted=None if pred is None else pred[searching],
            settled=self._settled(ids)[:, None],
            rest_future=self.rest_future,
        )
        raw = live_query(live, self.db.features[rows])
        if self.has_both:
            own = self.both_share[ids]
            want = np.where(live.speaking, self.both_speech, self.both_pause)
            push = np.where(own < 0, want, want + self.config.both_gain * (want - own))
            raw[:, group_slices()["both"]] = np.clip(push, 0.0, 1.0)[:, None]
        return self.db.normalised(raw, self.feature_weights)


class TrialStream(MatchingStream):
    def __init__(self, db, config: TrialConfig, predictor=None):
        self.kernel = TrialStreams(db, config, predictor, capacity=1)
        self._slot = [self.kernel.open()]


# ------------------------------------------------------------------------------- runs and figures
def trained_predictor(takes, stop: list[int], tag: str):
    """The speech predictor on frames [0, stop) of each take under the current target layout (cached)."""
    from safetensors.torch import load_file, save_file

    key = hashlib.sha1(json.dumps([[t.name for t in takes], stop, None, tag]).encode()).hexdigest()[:12]
    if tag == "mean":  # the same cache as matching_validate.cached_predictor
        key = hashlib.sha1(json.dumps([[t.name for t in takes], stop, None]).encode()).hexdigest()[:12]
    path = Path(f"/tmp/mm-predictor-{key}.safetensors")
    if path.is_file():
        return mp.Predictor.from_state(json.loads(path.with_suffix(".json").read_text()), load_file(str(path)))
    cut = [replace(t, train_until=b) for t, b in zip(takes, stop, strict=True)]
    pred = mpt.train_predictor(cut, seed=0, progress=False)
    save_file({k: v.contiguous() for k, v in pred.state_dict().items()}, str(path))
    path.with_suffix(".json").write_text(json.dumps(pred.config))
    return pred


def play(gen, audio: np.ndarray, face: np.ndarray, a: int, b: int, lead_in: int) -> np.ndarray:
    gen.reset()
    h = identity_rot6d().astype(np.float32)
    out = []
    for k in range(a - lead_in, b):
        p = gen.step(audio[k * SPF : (k + 1) * SPF], face[k], h)
        if k >= a:
            out.append(p)
    return np.stack(out)


def r2(x) -> float:
    return round(float(x), 3)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("variants")
    ap.add_argument("--heldout", action="store_true")
    ap.add_argument("--unseen", action="store_true")
    ap.add_argument("--lead-in", type=float, default=0.0, help="seconds of inputs before the scored stretch")
    args = ap.parse_args()
    t1 = load_take(SH / "beat/2_scott_0_1_1.bvh", SH / "beat/2_scott_0_1_1.wav")
    t2 = load_take(SH / "beat2/2_scott_0_2_2.npz", SH / "beat/2_scott_0_2_2.wav", t1.skeleton)
    takes = [t1, t2]
    if args.heldout:
        ranges = [(0, t.train_until) for t in takes]
        evals = [(t.train_until, t.n_frames) for t in takes]
    else:
        ranges = [(0, int(0.64 * t.n_frames)) for t in takes]
        evals = [(int(0.64 * t.n_frames), t.train_until) for t in takes]
    skel = t1.skeleton
    ref = cv.reference(
        skel, [t.pose[:b] for t, (_, b) in zip(takes, ranges)], [t.audio[: b * SPF] for t, (_, b) in zip(takes, ranges)]
    )
    speaker = sy.pooled_stats(
        [sy.motion_stats(sy.wrist_positions(skel, t.pose[a:b]), FPS) for t, (a, b) in zip(takes, ranges)]
    )
    lead = int(round(args.lead_in * FPS))
    real_clips = [t.pose[a:b] for t, (a, b) in zip(takes, evals)]
    audios = [t.audio[a * SPF : b * SPF] for t, (a, b) in zip(takes, evals)]
    real_timing = tm.timing_row(real_clips, audios, timing.AUDIO_SR, FPS, skel)
    print(
        "his",
        json.dumps(
            {
                k: r2(real_timing[k])
                for k in (
                    "onset_lag_s",
                    "onset_lag_chance_s",
                    "onset_lag_z",
                    "onset_rise",
                    "onset_rise_chance",
                    "onset_rise_z",
                )
            }
        ),
        flush=True,
    )
    unseen = None
    if args.unseen:
        from facecapges.io.audio import load_audio

        wav = load_audio(SH / "beat/2_scott_0_4_4.wav")
        n = len(wav) // SPF
        unseen = (wav[: n * SPF], np.zeros((n, 52), np.float32), n)
    for name, v in json.loads(args.variants).items():
        cfg = TrialConfig.from_dict(v)
        kind = v.get("targets", "mean")
        both_w = float(v.get("both_weight", 0.0))
        with feature_layout(kind, both_w > 0):
            weights = dict(mf.DEFAULT_WEIGHTS)
            weights.update(v.get("weights", {}))
            if both_w > 0:
                weights["both"] = both_w
            db = build_database(takes, ranges, weights=weights)
            pred = trained_predictor(takes, [b for _, b in ranges], kind)
            gen = TrialStream(db, cfg, pred)
            out: dict = {}
            clips = []
            for t, (a, b) in zip(takes, evals):
                pose = play(gen, t.audio, t.face, a, b, min(a, lead))
                clips.append(pose)
                real = t.pose[a:b]
                sc = cv.score(skel, pose, np.zeros(len(pose), bool), ref)
                f = cv.stretch_figures(skel, pose, real, ref, FPS)  # his share by the engine's rule
                out[t.name[-3:]] = dict(
                    both=r2(f["both_hands"]),
                    both_his=r2(f["both_hands_real"]),
                    height=r2(f["wrist_height_ratio"]),
                    spread=r2(f["spread_ratio"]),
                    jerk=r2(f["jerk_ratio"]),
                    pops=r2(sc.pops_speech_per_min),
                    head=r2(f["head_speed_ratio"]),
                    sway=r2(f["torso_sway_ratio"]),
                )
            tr = tm.timing_row(clips, audios, timing.AUDIO_SR, FPS, skel)
            out["timing"] = {
                k: r2(tr[k])
                for k in (
                    "onset_lag_s",
                    "onset_lag_chance_s",
                    "onset_lag_z",
                    "onset_rise",
                    "onset_rise_chance",
                    "onset_rise_z",
                )
            }
            log = np.array([r for r, _ in gen.kernel.rate_log])
            if len(log):  # the playback rate over the validation clips' speech frames
                out["rate"] = dict(
                    off5=r2(np.mean(np.abs(log - 1) > 0.05)),
                    faster=r2(np.mean(log > 1.05)),
                    slower=r2(np.mean(log < 0.95)),
                )
            rep = rz.repetition(clips, [db.pose], FPS, within_s=60.0, same_as=mirror_twins(db))
            out["repetition"] = dict(
                returns_per_min=r2(rep.returns_per_minute),
                longest_s=r2(rep.longest_copy_s),
                copied=r2(rep.copied_share),
            )
            if unseen is not None:
                wav, face, n = unseen
                pose = play(gen, wav, face, 0, n, 0)
                sc = cv.score(skel, pose, np.zeros(n, bool), ref)
                wg = sy.wrist_positions(skel, pose)
                tu = tm.timing_row([pose], [wav], timing.AUDIO_SR, FPS, skel)
                out["unseen"] = dict(
                    both=r2(sc.both_hands),
                    both_his=r2(ref.both_hands),
                    height=r2(sc.wrist_height_ratio),
                    spread=r2(sy.ratio(sy.wrist_spread(wg), speaker.spread)),
                    jerk=r2(sy.ratio(sy.wrist_jerk(wg, FPS), speaker.jerk)),
                    pops=r2(sc.pops_speech_per_min),
                    head=r2(sc.head_speed_ratio),
                    lag=r2(tu["onset_lag_s"]),
                    lag_chance=r2(tu["onset_lag_chance_s"]),
                    lag_z=r2(tu["onset_lag_z"]),
                    rise=r2(tu["onset_rise"]),
                    rise_chance=r2(tu["onset_rise_chance"]),
                    rise_z=r2(tu["onset_rise_z"]),
                )
        print(name, json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
