"""Synchrony controls: does the motion follow *this* speech, and does it move like the real speaker?

Plain functions over arrays (librosa style: arrays in, ``fps``/``sr`` in the signature).
BeatAlign alone cannot tell a model that follows speech from one that moves a lot (more
motion beats → higher BA); these controls compare every figure with the same figure
for the audio shifted in time, and the motion's statistics with the real motion's.

**Energy–speed correlation** (:func:`energy_speed_control`):

* audio energy envelope — the RMS of the samples each motion frame owns
  (:func:`facecapges.timing.frame_sample_bounds`), one value per frame
  (:func:`energy_envelope`);
* wrist speed — the mean over the wrists of ``‖p_{t+1} − p_t‖·fps`` of their world
  positions (skeleton units per second; frame 0 repeats frame 1's value)
  (:func:`wrist_speed`);
* both smoothed by a centred moving average of ``round(smooth_s·fps)`` frames
  (default 0.5 s; edges repeat the end value) (:func:`smooth`);
* ``r`` = Pearson correlation of the two smoothed curves; the control rolls the raw
  energy envelope cyclically by each offset (default 2, 4, …, 60 s, modulo the
  duration; offsets within ``min_gap_s`` of a multiple of the duration are skipped),
  smooths it again and correlates; ``z = (r − mean_shift) / sd_shift``.

  On real motion this is the speaker's own coupling of loudness and hand speed: the
  ZEGGS take 067_Speech_2_x_1_0 gives r ≈ 0.67, z ≈ 5; BEAT speaker 2's
  2_scott_0_1_1 gives r ≈ −0.1 (its beats are not loudness-driven). So a model is
  judged against its own speaker's real figure, not against 0.

**BeatAlign gap in sd units** (:func:`beat_align_gap_sd`): ``(BA − mean_shift) /
sd_shift`` of a :class:`facecapges.evaluation.beat_align.BeatAlignControl` — the
shifted-audio gap expressed as a z-score.

**Wrist jerk and spread** (:func:`wrist_jerk`, :func:`wrist_spread`): mean magnitude
of the third finite difference of the wrist positions times fps³ (units/s³), and the
RMS distance of each wrist from its own mean position (units), averaged over the
wrists. Reported as ratios to the real motion of the same speaker at the same frame
rate (:func:`ratio`): jerk 1.0 and spread 1.0 mean "moves like the real speaker".

**Wrist positions** of upper-body poses (T, 47, 6) on a BEAT skeleton:
:func:`wrist_positions` (forward kinematics with the other joints at rest and the root
fixed, as :func:`facecapges.skeleton.pose_to_motion` writes them). For any BVH on its
own skeleton (e.g. ZEGGS): ``facecapges.skeleton.joint_positions`` of the file's
motion and :data:`WRISTS`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from facecapges import timing

SMOOTH_S = 0.5
WRISTS: tuple[str, ...] = ("RightHand", "LeftHand")
DEFAULT_OFFSETS_S: tuple[float, ...] = tuple(float(x) for x in range(2, 61, 2))


def energy_envelope(audio: np.ndarray, sr: int, fps: float, n_frames: int | None = None) -> np.ndarray:
    """RMS (n_frames,) of the samples each frame owns; frames past the audio's end get 0."""
    a = np.asarray(audio, np.float64)
    if a.ndim != 1:
        raise ValueError(f"audio must be mono (S,), got {a.shape}")
    n = timing.n_frames_for(len(a) / sr, fps) if n_frames is None else int(n_frames)
    start, end = timing.frame_sample_bounds(np.arange(n), fps, sr)
    csum = np.concatenate([[0.0], np.cumsum(a * a)])
    s, e = np.clip(start, 0, len(a)), np.clip(end, 0, len(a))
    cnt = np.maximum(end - start, 1)
    return np.sqrt(np.maximum(csum[e] - csum[s], 0.0) / cnt)


def smooth(x: np.ndarray, fps: float, seconds: float = SMOOTH_S) -> np.ndarray:
    """Centred moving average over ``round(seconds·fps)`` frames along axis 0 (edges: nearest)."""
    from scipy.ndimage import uniform_filter1d

    w = max(int(round(seconds * fps)), 1)
    return uniform_filter1d(np.asarray(x, np.float64), w, axis=0, mode="nearest")


def _check_wrists(wrists: np.ndarray) -> np.ndarray:
    w = np.asarray(wrists, np.float64)
    if w.ndim == 2 and w.shape[-1] == 3:
        w = w[:, None]
    if w.ndim != 3 or w.shape[-1] != 3:
        raise ValueError(f"wrist positions must be (T, W, 3) or (T, 3), got {w.shape}")
    return w


def wrist_speed(wrists: np.ndarray, fps: float) -> np.ndarray:
    """Mean wrist speed (T,) in units/s of positions (T, W, 3); frame 0 repeats frame 1."""
    w = _check_wrists(wrists)
    if len(w) < 2:
        return np.zeros(len(w))
    v = np.linalg.norm(np.diff(w, axis=0), axis=-1).mean(1) * fps
    return np.concatenate([v[:1], v])


def wrist_jerk(wrists: np.ndarray, fps: float) -> float:
    """Mean ‖Δ³p‖·fps³ (units/s³) over frames and wrists; NaN below 4 frames."""
    w = _check_wrists(wrists)
    if len(w) < 4:
        return float("nan")
    return float(np.linalg.norm(np.diff(w, n=3, axis=0), axis=-1).mean() * fps**3)


def wrist_spread(wrists: np.ndarray) -> float:
    """RMS distance of each wrist from its own mean position (units), averaged over wrists."""
    w = _check_wrists(wrists)
    if len(w) == 0:
        return float("nan")
    d2 = ((w - w.mean(0, keepdims=True)) ** 2).sum(-1)  # (T, W)
    return float(np.sqrt(d2.mean(0)).mean())


def ratio(value: float, reference: float) -> float:
    """``value / reference``; NaN when either is not finite or the reference is 0."""
    if not (np.isfinite(value) and np.isfinite(reference)) or reference == 0:
        return float("nan")
    return float(value / reference)


def _pearson(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    den = np.sqrt((a * a).sum() * (b * b).sum())
    return float((a * b).sum() / den) if den > 1e-12 else float("nan")


def usable_offsets(offsets_s: Sequence[float], duration_s: float, min_gap_s: float = 1.0) -> list[float]:
    """The offsets that are a real shift of a cyclic signal of ``duration_s`` seconds."""
    used = []
    for off in offsets_s:
        o = float(off) % duration_s if duration_s > 0 else 0.0
        if min(o, duration_s - o) >= min_gap_s:
            used.append(float(off))
    return used


@dataclass
class EnergySpeedControl:
    """Correlation of smoothed audio energy with smoothed wrist speed, matched vs shifted."""

    r: float
    shifted_mean: float
    shifted_sd: float
    z: float  # (r − shifted_mean) / shifted_sd
    offsets_s: list[float]
    shifted: list[float]

    def as_dict(self) -> dict:
        return asdict(self)


def energy_speed_control(
    wrists: np.ndarray,
    audio: np.ndarray,
    sr: int,
    fps: float,
    offsets_s: Sequence[float] = DEFAULT_OFFSETS_S,
    smooth_s: float = SMOOTH_S,
    min_gap_s: float = 1.0,
) -> EnergySpeedControl:
    """Energy–speed correlation of wrist positions (T, W, 3) at ``fps`` with audio (S,) at ``sr``.

    The audio is cut or zero-padded to the motion's duration (frame i owns the samples
    of :func:`facecapges.timing.frame_sample_bounds`). A motion that does not move (or
    silent audio) gives NaN for ``r`` and ``z``.
    """
    w = _check_wrists(wrists)
    n = len(w)
    speed = smooth(wrist_speed(w, fps), fps, smooth_s)
    energy = energy_envelope(audio, sr, fps, n)
    r = _pearson(smooth(energy, fps, smooth_s), speed)
    used = usable_offsets(offsets_s, n / fps, min_gap_s)
    shifted = [
        _pearson(smooth(np.roll(energy, int(round(off * fps)) % max(n, 1)), fps, smooth_s), speed) for off in used
    ]
    arr = np.array(shifted, np.float64)
    ok = arr[np.isfinite(arr)]
    mean = float(ok.mean()) if len(ok) else float("nan")
    sd = float(ok.std()) if len(ok) else float("nan")
    z = (r - mean) / sd if np.isfinite(r) and np.isfinite(sd) and sd > 0 else float("nan")
    return EnergySpeedControl(r, mean, sd, float(z), used, [float(x) for x in arr])


def stouffer_z(zs: Sequence[float]) -> float:
    """The z-scores of independent takes combined as one: ``Σ z_i / √k`` (Stouffer's method).

    Each take's z is already in units of its own shifted-audio spread; their sum over
    √k is what one z over all k takes' audio would be if each take were an independent
    test. Unlike the mean of the z's it grows with the amount of audio, as evidence
    does (three takes at z 2 each: combined 3.5). NaNs are left out.
    """
    z = np.asarray([v for v in zs if np.isfinite(v)], np.float64)
    return float(z.sum() / np.sqrt(len(z))) if len(z) else float("nan")


def beat_align_gap_sd(control) -> float:
    """BeatAlign gap in sd units: ``(matched − shifted_mean) / shifted_sd`` of a BeatAlignControl."""
    sd = control.shifted_sd
    if not (np.isfinite(control.matched) and np.isfinite(sd)) or sd <= 0:
        return float("nan")
    return float((control.matched - control.shifted_mean) / sd)


def wrist_positions(skel, pose: np.ndarray, wrists: Sequence[str] = WRISTS) -> np.ndarray:
    """World positions (T, W, 3) of ``wrists`` for upper-body rot6d poses (T, 47, 6) on ``skel``.

    The 47 UPPER_BODY joints take the pose's local rotations, every other joint is at
    rest (identity) and the root stays at its rest offset — the motion
    :func:`facecapges.skeleton.pose_to_motion` writes. Units: the skeleton's (BEAT: cm).
    """
    from facecapges.skeleton import upper_body_transforms

    _, P = upper_body_transforms(skel, pose)
    return P[:, [skel.index(n) for n in wrists]]


@dataclass
class MotionStats:
    """Jerk and spread of one motion's wrists (the reference for ratios)."""

    jerk: float
    spread: float
    n_frames: int


def motion_stats(wrists: np.ndarray, fps: float) -> MotionStats:
    w = _check_wrists(wrists)
    return MotionStats(wrist_jerk(w, fps), wrist_spread(w), len(w))


def pooled_stats(stats: Sequence[MotionStats]) -> MotionStats:
    """Frame-weighted mean jerk and spread of several motions (e.g. every real clip of a speaker)."""
    ok = [s for s in stats if s.n_frames > 0]
    n = sum(s.n_frames for s in ok)
    if not n:
        return MotionStats(float("nan"), float("nan"), 0)

    def avg(k):
        vals = [(getattr(s, k), s.n_frames) for s in ok if np.isfinite(getattr(s, k))]
        tot = sum(w for _, w in vals)
        return float(sum(v * w for v, w in vals) / tot) if tot else float("nan")

    return MotionStats(avg("jerk"), avg("spread"), n)


def synchrony_row(
    wrists: np.ndarray,
    audio: np.ndarray,
    sr: int,
    fps: float,
    reference: MotionStats | None,
    offsets_s: Sequence[float] = DEFAULT_OFFSETS_S,
    smooth_s: float = SMOOTH_S,
) -> dict:
    """Energy–speed control, jerk, spread and their ratios to ``reference`` for one motion (JSON-able)."""
    es = energy_speed_control(wrists, audio, sr, fps, offsets_s, smooth_s)
    st = motion_stats(wrists, fps)
    ref = reference if reference is not None else MotionStats(float("nan"), float("nan"), 0)
    return {
        "ES_r": es.r,
        "ES_shifted_mean": es.shifted_mean,
        "ES_shifted_sd": es.shifted_sd,
        "ES_z": es.z,
        "jerk": st.jerk,
        "spread": st.spread,
        "jerk_ratio": ratio(st.jerk, ref.jerk),
        "spread_ratio": ratio(st.spread, ref.spread),
        "n_frames": st.n_frames,
    }
