"""Gesture timing against speech onsets, each figure beside the same figure at random times (issue #38).

Plain functions over a wrist-speed curve and onset frames (any engine, real takes alike);
:func:`timing_row` takes rot6d poses (T, 47, 6) with their skeleton and audio.

**Onsets** (:func:`speech_onsets`): the frames where the project's causal speech tracker
(:func:`facecapges.matching.speech.speech_track`, the cue the matching engine reacts to: spectral
flux while speaking, at most one every 0.2 s) fires. Not reimplemented here.

**Wrist speed** (:func:`facecapges.evaluation.synchrony.wrist_speed`): the mean over both
wrists of their world speed, skeleton units per second (BEAT: cm/s). **Peaks**
(:func:`speed_peaks`): local maxima of that curve (``scipy.signal.find_peaks``) with a
prominence of at least ``PEAK_PROMINENCE`` (0.5) times the curve's own standard deviation, so
ripples are not peaks while a low-amplitude motion's strokes still are (his real takes: 1.4 peaks a
second, about as many as onsets: 1.6–1.8 a second).

**Onset → next peak lag** (:func:`onset_lag`): for each onset, the time to the first peak at or
after it (onsets with no peak within ``MAX_LAG_S`` = 2 s are dropped); the figure is the
mean over onsets (``value``; the median, ``median``, is reported too but moves in 1/15-s steps).
**Chance**: the same statistic for ``n_random`` (500) sets of as many random frames as there are
onsets, drawn uniformly over each clip's frames (as many per clip as the clip has onsets):
``chance`` is the median of those sets' means (``chance_median``: of their medians), ``chance_sd``
their sd, ``z`` = (lag − chance) / chance_sd (negative: peaks follow onsets sooner than at random)
and ``p`` the share of random sets whose mean lag is at most the onsets'.

**Event-related rise** (:func:`onset_rise`): per onset, the mean wrist speed in
``[t, t + window)`` minus the mean in ``[t − window, t)`` (``window`` = ``RISE_WINDOW_S`` = 0.5 s;
onsets too near a clip's ends to have both windows are dropped), averaged over onsets (units/s).
The same for the random sets gives ``chance`` and ``chance_sd``; ``z`` = (rise − chance) /
chance_sd is the rise in units of its random-time spread (positive: the hands speed up after
onsets more than after random times).

Both statistics are computed per clip and pooled over clips (nothing crosses a clip border).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from facecapges.evaluation import synchrony as sy

PEAK_PROMINENCE = 0.5
MAX_LAG_S = 2.0
RISE_WINDOW_S = 0.5
N_RANDOM = 500


def speech_onsets(audio: np.ndarray, sr: int, fps: float, n_frames: int) -> np.ndarray:
    """Onset frames (K,) of ``audio`` over ``n_frames`` motion frames, by the matching engine's causal
    speech tracker (:func:`facecapges.matching.speech.speech_track`; 16 kHz, 15 fps)."""
    from facecapges import timing
    from facecapges.matching.speech import speech_track

    if sr != timing.AUDIO_SR or abs(fps - timing.MODEL_FPS) > 1e-6:
        raise ValueError(f"speech onsets need {timing.AUDIO_SR} Hz audio and {timing.MODEL_FPS} fps, got {sr}, {fps}")
    if n_frames <= 0:
        return np.zeros(0, int)
    return np.flatnonzero(speech_track(np.asarray(audio, np.float32), n_frames).onset).astype(int)


def speed_peaks(speed: np.ndarray, prominence: float = PEAK_PROMINENCE) -> np.ndarray:
    """Frames (P,) of the local maxima of a speed curve with a prominence ≥ ``prominence`` × its sd."""
    from scipy.signal import find_peaks

    s = np.asarray(speed, np.float64)
    sd = float(np.std(s)) if len(s) else 0.0
    if sd <= 0:
        return np.zeros(0, int)
    return find_peaks(s, prominence=prominence * sd)[0].astype(int)


def _lags(events: np.ndarray, peaks: np.ndarray, fps: float, max_lag_s: float) -> np.ndarray:
    """Seconds from each event to the first peak at or after it (events without one within max_lag_s dropped)."""
    if not len(events) or not len(peaks):
        return np.zeros(0)
    i = np.searchsorted(peaks, events, side="left")
    ok = i < len(peaks)
    lag = (peaks[np.minimum(i, len(peaks) - 1)] - events) / fps
    return lag[ok & (lag <= max_lag_s)]


def _rises(speed: np.ndarray, events: np.ndarray, w: int) -> np.ndarray:
    """Mean speed in [t, t + w) minus in [t − w, t) for each event with both windows inside the clip."""
    ev = events[(events >= w) & (events + w <= len(speed))]
    if not len(ev):
        return np.zeros(0)
    c = np.concatenate([[0.0], np.cumsum(speed)])
    return ((c[ev + w] - c[ev]) - (c[ev] - c[ev - w])) / w


@dataclass
class TimingFigure:
    """One statistic at the onsets beside the same statistic at random times."""

    value: float  # at the onsets (lag: mean seconds; rise: units/s)
    chance: float  # median over the random sets
    chance_sd: float
    z: float  # (value − chance) / chance_sd
    p: float  # share of random sets at most (lag) / at least (rise) the onsets' value
    n_events: int  # onsets that entered the statistic
    median: float = float("nan")  # lag only: the median over onsets …
    chance_median: float = float("nan")  # … and the median of the random sets' medians

    def as_dict(self) -> dict:
        return asdict(self)


def _figure(value: float, rand: np.ndarray, n: int, lower_is_better: bool) -> TimingFigure:
    rand = rand[np.isfinite(rand)]
    if not np.isfinite(value) or len(rand) < 2:
        return TimingFigure(value, float("nan"), float("nan"), float("nan"), float("nan"), n)
    chance, sd = float(np.median(rand)), float(np.std(rand))
    z = (value - chance) / sd if sd > 0 else float("nan")
    p = float(np.mean(rand <= value)) if lower_is_better else float(np.mean(rand >= value))
    return TimingFigure(float(value), chance, sd, float(z), p, n)


def _random_sets(lengths: Sequence[int], counts: Sequence[int], n_random: int, rng: np.random.Generator):
    """Per random set, per clip: as many uniformly random frames as the clip has onsets (sorted)."""
    for _ in range(n_random):
        yield [np.sort(rng.integers(0, max(L, 1), k)) for L, k in zip(lengths, counts)]


def onset_lag(
    speeds: Sequence[np.ndarray],
    onsets: Sequence[np.ndarray],
    fps: float,
    max_lag_s: float = MAX_LAG_S,
    n_random: int = N_RANDOM,
    seed: int = 0,
    prominence: float = PEAK_PROMINENCE,
) -> TimingFigure:
    """Median onset → next wrist-speed-peak lag (s) over clips, beside random times (module docstring)."""
    peaks = [speed_peaks(s, prominence) for s in speeds]
    on = [np.asarray(o, int) for o in onsets]
    lags = np.concatenate([_lags(o, p, fps, max_lag_s) for o, p in zip(on, peaks)] + [np.zeros(0)])
    value = float(np.mean(lags)) if len(lags) else float("nan")
    rng = np.random.default_rng(seed)
    rand, rand_median = [], []
    for sets in _random_sets([len(s) for s in speeds], [len(o) for o in on], n_random, rng):
        lr = np.concatenate([_lags(r, p, fps, max_lag_s) for r, p in zip(sets, peaks)] + [np.zeros(0)])
        rand.append(np.mean(lr) if len(lr) else np.nan)
        rand_median.append(np.median(lr) if len(lr) else np.nan)
    fig = _figure(value, np.array(rand, float), len(lags), lower_is_better=True)
    fig.median = float(np.median(lags)) if len(lags) else float("nan")
    fig.chance_median = float(np.nanmedian(rand_median)) if np.isfinite(rand_median).any() else float("nan")
    return fig


def onset_rise(
    speeds: Sequence[np.ndarray],
    onsets: Sequence[np.ndarray],
    fps: float,
    window_s: float = RISE_WINDOW_S,
    n_random: int = N_RANDOM,
    seed: int = 0,
) -> TimingFigure:
    """Mean wrist speed after onsets minus before (units/s), beside random times (module docstring)."""
    w = max(int(round(window_s * fps)), 1)
    sp = [np.asarray(s, np.float64) for s in speeds]
    on = [np.asarray(o, int) for o in onsets]
    r = np.concatenate([_rises(s, o, w) for s, o in zip(sp, on)] + [np.zeros(0)])
    value = float(np.mean(r)) if len(r) else float("nan")
    rng = np.random.default_rng(seed)
    rand = []
    for sets in _random_sets([len(s) for s in sp], [len(o) for o in on], n_random, rng):
        rr = np.concatenate([_rises(s, x, w) for s, x in zip(sp, sets)] + [np.zeros(0)])
        rand.append(np.mean(rr) if len(rr) else np.nan)
    return _figure(value, np.array(rand, float), len(r), lower_is_better=False)


def timing_row(
    clips: Sequence[np.ndarray],
    audios: Sequence[np.ndarray],
    sr: int,
    fps: float,
    skeleton,
    seed: int = 0,
    onsets: Sequence[np.ndarray] | None = None,
) -> dict:
    """Both figures for rot6d clips (T, 47, 6) on ``skeleton``, each with its audio (JSON-able);
    ``onsets``: each clip's onset frames when already computed."""
    speeds = [sy.wrist_speed(sy.wrist_positions(skeleton, np.asarray(c)), fps) for c in clips]
    if onsets is None:
        onsets = [speech_onsets(a, sr, fps, len(s)) for a, s in zip(audios, speeds)]
    onsets = [np.asarray(o, int)[np.asarray(o, int) < len(s)] for o, s in zip(onsets, speeds)]
    lag, rise = onset_lag(speeds, onsets, fps, seed=seed), onset_rise(speeds, onsets, fps, seed=seed)
    return {
        "onsets": int(sum(len(o) for o in onsets)),
        "onset_lag_s": lag.value,
        "onset_lag_chance_s": lag.chance,
        "onset_lag_median_s": lag.median,
        "onset_lag_median_chance_s": lag.chance_median,
        "onset_lag_z": lag.z,
        "onset_lag_p": lag.p,
        "onset_rise": rise.value,
        "onset_rise_chance": rise.chance,
        "onset_rise_z": rise.z,
        "onset_rise_p": rise.p,
    }


def timing_section(
    methods: Mapping[str, Sequence[np.ndarray]],
    audios: Sequence[np.ndarray],
    sr: int,
    fps: float,
    skeleton,
    seed: int = 0,
) -> dict:
    """:func:`timing_row` of every method's clips (each clip with the audio of the same index); onsets once."""
    n = [max(len(c) for c in col) for col in zip(*methods.values())] if methods else []
    onsets = [speech_onsets(a, sr, fps, k) for a, k in zip(audios, n)]
    return {name: timing_row(clips, audios, sr, fps, skeleton, seed, onsets) for name, clips in methods.items()}


def timing_markdown(section: dict, where: str = "") -> list[str]:
    """The timing section as Markdown lines (one row per method)."""
    if not section:
        return []

    def f(v, fmt):
        return "–" if v is None or not np.isfinite(v) else fmt.format(v)

    lines = [
        "",
        f"### Timing against speech onsets{' — ' + where if where else ''}",
        "",
        "| Method | onsets | onset → wrist peak, mean s (chance; z) | median s (chance) | "
        "wrist-speed rise after onsets (chance; z) |",
        "|---|---|---|---|---|",
    ]
    for name, r in section.items():
        lines.append(
            f"| {name} | {r['onsets']} | {f(r['onset_lag_s'], '{:.3f}')} ({f(r['onset_lag_chance_s'], '{:.3f}')}; "
            f"{f(r['onset_lag_z'], '{:+.2f}')}) | {f(r['onset_lag_median_s'], '{:.3f}')} "
            f"({f(r['onset_lag_median_chance_s'], '{:.3f}')}) | {f(r['onset_rise'], '{:+.2f}')} "
            f"({f(r['onset_rise_chance'], '{:+.2f}')}; {f(r['onset_rise_z'], '{:+.2f}')}) |"
        )
    lines += [
        "",
        "Onsets: the causal speech tracker's (`matching.speech`); peaks: local maxima of the mean wrist speed "
        f"(prominence ≥ {PEAK_PROMINENCE:g} sd); chance: the same statistic at {N_RANDOM} sets of random times; "
        f"rise: mean wrist speed {RISE_WINDOW_S:g} s after minus before, units/s (`facecapges.evaluation.timing`).",
    ]
    return lines


__all__ = [
    "TimingFigure",
    "onset_lag",
    "onset_rise",
    "speech_onsets",
    "speed_peaks",
    "timing_markdown",
    "timing_row",
    "timing_section",
]
