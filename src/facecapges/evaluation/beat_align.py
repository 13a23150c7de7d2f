"""BeatAlign (thesis 5.5.3, eq. 5.9–5.10) and its shifted-audio control.

**Speech beats** B_s (seconds), :func:`speech_beats`: librosa's onset strength
(spectral flux of the log-power mel spectrogram, ``hop_length`` = 512 samples =
32 ms at 16 kHz), peak-picked by ``librosa.onset.onset_detect``, then each onset
is moved back to the preceding local minimum of the RMS curve (``backtrack=True,
energy=rms``) — where the energy really starts to rise. Several onsets often
backtrack to the same RMS minimum; **we merge such duplicates** (``unique=True``,
the default): on 2_scott_0_1_1 the 358 raw peaks become 183 beats. BEAT/CaMN's and
EMAGE's scripts keep duplicates, so a duplicated beat counts twice in their mean;
``unique=False`` keeps them as they do.

**Motion beats** B_g (seconds), :func:`motion_beats`: local minima of joint angular
speed. For each joint of the region the local rotation matrices of consecutive
frames give the geodesic angle ``θ_tj = angle(R_t,j, R_{t+1},j)`` (radians, computed
as ``atan2(‖vee(Q − Qᵀ)‖/2, (tr Q − 1)/2)`` of ``Q = R_tᵀ R_{t+1}``, which stays
accurate for small angles where ``arccos`` does not); the angular speed is
``θ_tj · fps`` (rad/s), timed at the midpoint ``(t + ½)/fps``. Speeds are rounded to
1e-9 rad/s before minima are searched, so round-off ripples on a plateau (a joint
turning at constant speed, or not at all) are not beats. Minima are strict local
minima (``scipy.signal.argrelextrema(np.less, order)``, default order 2 frames as in
BEAT/CaMN and EMAGE).

**Modes** — how the joints of the region are combined:

* ``mode="mean"`` (default; **every table of this project uses it**): the speed curve
  is the mean over the region's joints; its minima are the motion beats.
* ``mode="single"``: the minima of one joint's speed (``joint`` = its index in the
  pose). This is what BEAT/CaMN's script really scores: its ``calculate_align``
  returns the right-"wrist" score only (the average over six arm joints and three
  onset variants is commented out), and the "wrist" is an index slice (channels
  36:39) meant for full 228-channel BVH lines; on the 141-channel (47-joint) arrays
  its trainer passes, that slice is joint 12 of the CaMN order, **RightHandRing2**
  (:data:`BEAT_JOINT`).
* ``mode="per_joint"``: each joint's own minima are scored separately against the
  speech beats and the scores averaged — EMAGE's ``calculate_align`` (it does so over
  its SMPL-X spine, neck, head, collar, shoulder, elbow and wrist joints, with joint
  *position* speed; see :mod:`facecapges.evaluation.peers` for the whole recipe).
* ``mode="union"``: minima of every joint's own speed curve, pooled (duplicates
  removed). No peer uses this; it yields many more beats and hence a higher, less
  selective score, and is kept only as a diagnostic.

:mod:`facecapges.evaluation.peers` computes BeatAlign exactly as BEAT/CaMN's and
EMAGE's scripts do (their speech-beat detection, Euler/position speeds, time stamps),
for comparisons with published numbers. Note that BEAT's script takes speech-beat
times from ``librosa.frames_to_time`` at librosa's default 22 050 Hz while the audio
is 16 kHz, so its speech beats sit at 16 000/22 050 = 0.726 × their true times; its
published BA values carry that error, ours do not.

**Score** (eq. 5.9–5.10): ``BA = mean_k exp(−Δt_k² / (2σ²))`` with
``Δt_k = min_m |t_k^s − t_m^g|`` and σ = 0.3 s. No speech beat → NaN; speech beats
but no motion beat → 0.

**Control** (:func:`beat_align_control`): the same motion scored against its own
audio cyclically shifted (``np.roll``) by many offsets (default 2, 4, …, 60 s,
each taken modulo the clip duration; offsets within ``min_gap_s`` of a multiple of
the duration are skipped because they are no shift). Reported: matched score,
shifted mean ± sd, and gap = matched − shifted mean. The audio is cut or
zero-padded to the motion's duration before shifting, so the cycle matches.
:func:`speech_beat_sets` computes the speech beats of all shifts once, so several
motions (methods, regions) scored against one audio share the onset detection.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from facecapges import rotations as rot

SIGMA_S = 0.3
HOP_LENGTH = 512
MODES: tuple[str, ...] = ("mean", "single", "per_joint", "union")
#: The joint BEAT/CaMN's BeatAlign script scores on 47-joint arrays (index in UPPER_BODY).
BEAT_JOINT = "RightHandRing2"


def speech_beats(audio: np.ndarray, sr: int, hop_length: int = HOP_LENGTH, unique: bool = True) -> np.ndarray:
    """Speech beat times in seconds (K,), sorted, from mono audio (S,) at ``sr`` Hz.

    ``unique=False`` keeps onsets that backtrack to the same RMS minimum (as the peers do).
    """
    import librosa

    y = np.asarray(audio, dtype=np.float32)
    if y.ndim != 1:
        raise ValueError(f"audio must be mono (S,), got {y.shape}")
    if len(y) < hop_length * 2 or not np.any(y):
        return np.zeros(0)
    oenv = librosa.onset.onset_strength(y=y, sr=sr, hop_length=hop_length)
    rms = librosa.feature.rms(y=y, hop_length=hop_length)[0]
    n = min(len(oenv), len(rms))
    frames = librosa.onset.onset_detect(
        onset_envelope=oenv[:n], sr=sr, hop_length=hop_length, backtrack=True, energy=rms[:n], units="frames"
    )
    times = librosa.frames_to_time(frames, sr=sr, hop_length=hop_length)
    return np.unique(times) if unique else np.sort(times)


def joint_angular_speed(pose: np.ndarray, fps: float) -> np.ndarray:
    """Angular speed (T−1, J) in rad/s of rot6d poses (T, J, 6); row t is frames t → t+1."""
    p = np.asarray(pose, np.float64)
    if p.ndim != 3 or p.shape[-1] != 6:
        raise ValueError(f"pose must be (T, J, 6) rot6d, got {p.shape}")
    R = rot.rot6d_to_matrix(p)
    return rot.geodesic_angle(R[:-1], R[1:]) * fps


def _minima(curve: np.ndarray, order: int) -> np.ndarray:
    from scipy.signal import argrelextrema

    if len(curve) < 3:
        return np.zeros(0, np.int64)
    return argrelextrema(np.round(curve, 9), np.less, order=order)[0]


def _check_mode(mode: str, joint: int | None) -> None:
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    if mode == "single" and joint is None:
        raise ValueError("mode='single' needs the index of the joint to score (joint=...)")


def motion_beats(
    pose: np.ndarray, fps: float, order: int = 2, mode: str = "mean", joint: int | None = None
) -> np.ndarray:
    """Motion beat times in seconds (M,), sorted, from rot6d poses (T, J, 6) (see module doc).

    ``mode="per_joint"`` has one beat set per joint: use :func:`motion_beats_per_joint`.
    """
    _check_mode(mode, joint)
    speed = joint_angular_speed(pose, fps)  # (T-1, J)
    if mode == "mean":
        idx = _minima(speed.mean(1), order)
    elif mode == "single":
        idx = _minima(speed[:, joint], order)
    elif mode == "union":
        idx = np.unique(
            np.concatenate([_minima(speed[:, j], order) for j in range(speed.shape[1])] or [np.empty(0, np.int64)])
        )
    else:
        raise ValueError("mode='per_joint' has one beat set per joint: use motion_beats_per_joint")
    return (idx.astype(np.float64) + 0.5) / fps


def motion_beats_per_joint(pose: np.ndarray, fps: float, order: int = 2) -> list[np.ndarray]:
    """Each joint's own motion beat times in seconds (list of J arrays)."""
    speed = joint_angular_speed(pose, fps)
    return [(_minima(speed[:, j], order).astype(np.float64) + 0.5) / fps for j in range(speed.shape[1])]


def _beat_sets(pose: np.ndarray, fps: float, order: int, mode: str, joint: int | None) -> list[np.ndarray]:
    """The motion beat set(s) a mode scores: one set, or one per joint for ``per_joint``."""
    _check_mode(mode, joint)
    if mode == "per_joint":
        return motion_beats_per_joint(pose, fps, order)
    return [motion_beats(pose, fps, order, mode, joint)]


def score_sets(speech_s: np.ndarray, beat_sets: Sequence[np.ndarray], sigma_s: float = SIGMA_S) -> float:
    """Mean over motion beat sets of :func:`beat_align_score` (one set: its score)."""
    if not len(beat_sets):
        return float("nan")
    return float(np.mean([beat_align_score(speech_s, m, sigma_s) for m in beat_sets]))


def beat_align_score(speech_s: np.ndarray, motion_s: np.ndarray, sigma_s: float = SIGMA_S) -> float:
    """Eq. 5.9–5.10: mean over speech beats of exp(−Δt²/2σ²) to the nearest motion beat."""
    s, m = np.asarray(speech_s, np.float64).ravel(), np.sort(np.asarray(motion_s, np.float64).ravel())
    if len(s) == 0:
        return float("nan")
    if len(m) == 0:
        return 0.0
    pos = np.clip(np.searchsorted(m, s), 1, len(m) - 1) if len(m) > 1 else np.zeros(len(s), np.int64)
    dt = np.abs(s - m[pos]) if len(m) == 1 else np.minimum(np.abs(s - m[pos - 1]), np.abs(s - m[pos]))
    return float(np.mean(np.exp(-(dt**2) / (2.0 * sigma_s**2))))


def beat_align(
    pose: np.ndarray,
    audio: np.ndarray,
    sr: int,
    fps: float,
    sigma_s: float = SIGMA_S,
    order: int = 2,
    mode: str = "mean",
    joint: int | None = None,
) -> float:
    """BeatAlign of motion (T, J, 6) at ``fps`` against its audio (S,) at ``sr`` (``mode``: module doc)."""
    return score_sets(speech_beats(audio, sr), _beat_sets(pose, fps, order, mode, joint), sigma_s)


@dataclass
class BeatAlignControl:
    """Matched vs shifted-audio BeatAlign of one motion."""

    matched: float
    shifted_mean: float
    shifted_sd: float
    gap: float  # matched − shifted_mean
    offsets_s: list[float]
    shifted: list[float]
    n_speech_beats: int
    n_motion_beats: int  # per_joint: summed over the joints

    def as_dict(self) -> dict:
        return asdict(self)


def fit_audio(audio: np.ndarray, n_frames: int, fps: float, sr: int) -> np.ndarray:
    """Audio cut or zero-padded to the duration of ``n_frames`` motion frames."""
    n = int(round(n_frames / fps * sr))
    a = np.asarray(audio, np.float32)[:n]
    return np.pad(a, (0, n - len(a))) if len(a) < n else a


@dataclass
class SpeechBeatSets:
    """Speech beats of one audio, matched and for each shift (reusable across motions)."""

    matched: np.ndarray
    offsets_s: list[float]
    shifted: list[np.ndarray]


def speech_beat_sets(
    audio: np.ndarray,
    sr: int,
    n_frames: int,
    fps: float,
    offsets_s: Sequence[float] = tuple(range(2, 61, 2)),
    min_gap_s: float = 1.0,
) -> SpeechBeatSets:
    """Speech beats of the audio fitted to ``n_frames`` frames, unshifted and rolled by each usable offset."""
    a = fit_audio(audio, n_frames, fps, sr)
    dur = len(a) / sr
    used, sets = [], []
    for off in offsets_s:
        o = float(off) % dur if dur > 0 else 0.0
        if min(o, dur - o) < min_gap_s:
            continue
        sets.append(speech_beats(np.roll(a, int(round(o * sr))), sr))
        used.append(float(off))
    return SpeechBeatSets(speech_beats(a, sr), used, sets)


def beat_align_control(
    pose: np.ndarray,
    audio: np.ndarray,
    sr: int,
    fps: float,
    offsets_s: Sequence[float] = tuple(range(2, 61, 2)),
    sigma_s: float = SIGMA_S,
    order: int = 2,
    mode: str = "mean",
    min_gap_s: float = 1.0,
    speech: SpeechBeatSets | None = None,
    joint: int | None = None,
) -> BeatAlignControl:
    """Matched BeatAlign and BeatAlign against the audio rolled by each offset (wrapping).

    ``speech`` (from :func:`speech_beat_sets` for this audio and ``len(pose)``) skips the
    onset detection when several motions are scored against the same audio.
    """
    if speech is None:
        speech = speech_beat_sets(audio, sr, len(pose), fps, offsets_s, min_gap_s)
    sets = _beat_sets(pose, fps, order, mode, joint)
    matched = score_sets(speech.matched, sets, sigma_s)
    arr = np.array([score_sets(sb, sets, sigma_s) for sb in speech.shifted], np.float64)
    mean = float(np.nanmean(arr)) if len(arr) else float("nan")
    sd = float(np.nanstd(arr)) if len(arr) else float("nan")
    return BeatAlignControl(
        matched,
        mean,
        sd,
        matched - mean,
        list(speech.offsets_s),
        [float(x) for x in arr],
        len(speech.matched),
        int(sum(len(m) for m in sets)),
    )
