"""Metrics as the peers' scripts compute them (BEAT/CaMN, EMAGE), for comparisons with published numbers.

Our tables use the thesis's definitions on rot6d (:mod:`~facecapges.evaluation.srgr`,
:mod:`~facecapges.evaluation.beat_align` ``mode="mean"``, :mod:`~facecapges.evaluation.l1div`).
The peers' evaluation scripts (PantoMatrix: ``scripts/BEAT_2022/utils/metric.py`` as its
CaMN trainer calls it, and EMAGE's ``alignment`` class) differ in data representation,
thresholds and details; the functions here reproduce those choices on our arrays — our
own code, written from reading theirs. Poses are (T, 47, 6) rot6d in
:data:`facecapges.skeleton.UPPER_BODY` order (which is CaMN's 47-joint order); the
peers' Euler representation is recovered as BEAT's BVH channels, Euler ``XYZ`` in
degrees (:func:`beat_euler`).

**BEAT/CaMN** (:func:`beat_align_beat`, :func:`srgr_beat`, :func:`l1div_beat`):

* BeatAlign — speech beats: onset strength at the true rate, peak picking with
  librosa's defaults, each onset backtracked to the preceding minimum of the RMS of a
  2048-point STFT, duplicates kept; times from ``librosa.frames_to_time`` *without*
  the sample rate, i.e. at librosa's default 22 050 Hz. On 16 kHz audio every speech
  beat is therefore placed at 0.726 × its true time (``true_times=True`` fixes only
  that). Motion beats: minima (order 2) of the L2 norm of the frame-to-frame change of
  one joint's three Euler angles in degrees — the channel slice 36:39, which on the
  141-channel arrays is **RightHandRing2** (the "wrist" of full BVH lines) — at time
  ``index / fps``. Score: the mean over speech beats of exp(−Δt²/2σ²), σ = 0.3 s (the
  average over six arm joints is commented out in their code).
* SRGR — per joint, the L1 distance of the three Euler angles in degrees below a
  threshold of **4°** (``SRGR(4, 47)`` in their trainer); each hit weighted by the
  frame's semantic score × 1/0.165. Without semantic scores we weight every frame 1
  and do not rescale. Under this threshold a frozen mean pose scores near 0, while our
  δ = 0.5 on rot6d gives it 0.886 on 2_scott_0_1_1.
* L1div — per frame, Σ over the 141 Euler channels (degrees) of |x − mean over the
  sequence|, averaged over frames: the same formula as our ``l1div_temporal`` but on
  Euler degrees, so it gives 590–990 on our clip where rot6d gives 7–13.

**EMAGE** (:func:`beat_align_emage`): speech beats = ``librosa.onset.onset_detect``
in seconds at the true rate, no backtracking; motion beats per joint from the speed of
joint *positions* (central differences), divided by a per-joint reference speed
(``mmae`` in their code, a dataset constant; here the real motion's mean speed per
joint, or the motion's own), minima (order 2) kept only where that normalised speed
exceeds 0.3; each joint scored separately and the scores averaged over EMAGE's
upper-body joints (SMPL-X spine1–3, neck, collars, head, shoulders, elbows, wrists),
mapped to BEAT's names in :data:`EMAGE_JOINTS`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from facecapges import rotations as rot
from facecapges.evaluation.beat_align import SIGMA_S, beat_align_score
from facecapges.skeleton import N_JOINTS, UPPER_BODY

BEAT_EULER_ORDER = "XYZ"
BEAT_LIBROSA_SR = 22050  # the rate BEAT's frames_to_time assumes
BEAT_JOINT = "RightHandRing2"  # channels 36:39 of a 141-channel frame
BEAT_SRGR_THRESHOLD_DEG = 4.0
EMAGE_SPEED_THRESHOLD = 0.3
#: EMAGE's SMPL-X upper-body joints (3, 6, 9, 12–21) by their BEAT counterparts.
EMAGE_JOINTS: tuple[str, ...] = (
    "Spine1",
    "Spine2",
    "Spine3",
    "Neck",
    "LeftShoulder",
    "RightShoulder",
    "Head",
    "LeftArm",
    "RightArm",
    "LeftForeArm",
    "RightForeArm",
    "LeftHand",
    "RightHand",
)


def _pose(pose: np.ndarray) -> np.ndarray:
    p = np.asarray(pose, np.float64)
    if p.ndim != 3 or p.shape[1:] != (N_JOINTS, 6):
        raise ValueError(f"pose must be (T, {N_JOINTS}, 6) rot6d, got {p.shape}")
    return p


def beat_euler(pose: np.ndarray) -> np.ndarray:
    """BEAT's BVH channels (T, 47, 3): Euler ``XYZ`` degrees in (−180, 180], not unwrapped."""
    return rot.rot6d_to_euler(_pose(pose), BEAT_EULER_ORDER, degrees=True)


# ------------------------------------------------------------------ BEAT / CaMN
def beat_speech_beats(audio: np.ndarray, sr: int, true_times: bool = False) -> np.ndarray:
    """Speech beat times (s) as BEAT's ``alignment.load_audio`` + ``calculate_align`` give them.

    Duplicates are kept. ``true_times=False`` (their script): times at librosa's default
    22 050 Hz, i.e. scaled by ``sr / 22050``; ``True``: at the real ``sr``.
    """
    import librosa

    y = np.asarray(audio, np.float32)
    if y.ndim != 1 or len(y) < 2048 or not np.any(y):
        return np.zeros(0)
    oenv = librosa.onset.onset_strength(y=y, sr=sr)
    raw = librosa.onset.onset_detect(onset_envelope=oenv, backtrack=False)
    rms = librosa.feature.rms(S=np.abs(librosa.stft(y=y)))[0]
    frames = librosa.onset.onset_backtrack(raw, rms)
    return np.sort(librosa.frames_to_time(frames, sr=sr if true_times else BEAT_LIBROSA_SR))


def beat_motion_beats(pose: np.ndarray, fps: float, joint: str = BEAT_JOINT, order: int = 2) -> np.ndarray:
    """Motion beat times (s): minima of one joint's Euler-degree change per frame, at ``index / fps``."""
    from scipy.signal import argrelextrema

    e = beat_euler(pose)[:, UPPER_BODY.index(joint)]
    if len(e) < 3:
        return np.zeros(0)
    vel = np.linalg.norm(np.diff(e, axis=0), axis=-1)
    return argrelextrema(vel, np.less, order=order)[0].astype(np.float64) / fps


def beat_align_beat(
    pose: np.ndarray,
    audio: np.ndarray,
    sr: int,
    fps: float,
    sigma_s: float = SIGMA_S,
    true_times: bool = False,
    speech_s: np.ndarray | None = None,
) -> float:
    """BeatAlign as BEAT/CaMN's script computes it (see the module doc)."""
    sb = beat_speech_beats(audio, sr, true_times) if speech_s is None else speech_s
    return beat_align_score(sb, beat_motion_beats(pose, fps), sigma_s)


def srgr_beat(
    real: np.ndarray,
    generated: np.ndarray,
    weights: np.ndarray | None = None,
    threshold_deg: float = BEAT_SRGR_THRESHOLD_DEG,
) -> float:
    """SRGR as BEAT/CaMN's trainer computes it: Euler-degree L1 per joint < 4°, weights × 1/0.165."""
    r, g = beat_euler(real), beat_euler(generated)
    if r.shape != g.shape:
        raise ValueError(f"real and generated must have one shape, got {r.shape} and {g.shape}")
    hits = (np.abs(r - g).sum(-1) < threshold_deg).astype(np.float64)
    if weights is None:
        return float(hits.mean())
    lam = np.asarray(weights, np.float64)
    if lam.shape != (len(r),):
        raise ValueError(f"weights must be ({len(r)},), got {lam.shape}")
    return float((hits * lam[:, None] / 0.165).mean())


def l1div_beat(pose: np.ndarray) -> float:
    """BEAT/CaMN's L1div of one sequence: mean over frames of Σ_141 |Euler° − sequence mean|."""
    e = beat_euler(pose).reshape(len(pose), -1)
    return float(np.abs(e - e.mean(0, keepdims=True)).sum(1).mean())


# ------------------------------------------------------------------ EMAGE
def emage_speech_beats(audio: np.ndarray, sr: int) -> np.ndarray:
    """Speech beat times (s) as EMAGE's ``alignment.load_audio``: onsets at the true rate, no backtracking."""
    import librosa

    y = np.asarray(audio, np.float32)
    if y.ndim != 1 or len(y) < 1024 or not np.any(y):
        return np.zeros(0)
    return np.asarray(librosa.onset.onset_detect(y=y, sr=sr, hop_length=512, units="time"), np.float64)


def emage_joint_speed(positions: np.ndarray, fps: float) -> np.ndarray:
    """Speed (T, J) of joint positions (T, J, 3): forward, central, backward differences."""
    p = np.asarray(positions, np.float64)
    if len(p) < 2:
        return np.zeros(p.shape[:2])
    v = np.empty_like(p)
    v[0] = (p[1] - p[0]) * fps
    v[-1] = (p[-1] - p[-2]) * fps
    v[1:-1] = (p[2:] - p[:-2]) * fps / 2.0
    return np.linalg.norm(v, axis=-1)


def emage_positions(skel, pose: np.ndarray, joints: Sequence[str] = EMAGE_JOINTS) -> np.ndarray:
    """World positions (T, J, 3) of ``joints`` for rot6d poses on a BEAT skeleton (others at rest)."""
    from facecapges.skeleton import upper_body_transforms

    return upper_body_transforms(skel, _pose(pose))[1][:, [skel.index(n) for n in joints]]


def beat_align_emage(
    positions: np.ndarray,
    audio: np.ndarray,
    sr: int,
    fps: float,
    reference_speed: np.ndarray | None = None,
    sigma_s: float = SIGMA_S,
    order: int = 2,
    threshold: float = EMAGE_SPEED_THRESHOLD,
    speech_s: np.ndarray | None = None,
) -> float:
    """BeatAlign as EMAGE computes it from joint positions (T, J, 3): the mean of per-joint scores.

    ``reference_speed`` (J,) stands for EMAGE's ``mmae`` (default: this motion's own mean
    speed per joint). A joint with no beat scores 0, as in their code.
    """
    from scipy.signal import argrelextrema

    speed = emage_joint_speed(positions, fps)
    ref = speed.mean(0) if reference_speed is None else np.asarray(reference_speed, np.float64)
    norm = speed / np.maximum(ref, 1e-9)
    sb = emage_speech_beats(audio, sr) if speech_s is None else speech_s
    scores = []
    for j in range(speed.shape[1]):
        idx = argrelextrema(norm[:, j], np.less, order=order)[0] if len(norm) >= 3 else np.zeros(0, np.int64)
        idx = idx[norm[idx, j] > threshold]
        scores.append(beat_align_score(sb, idx.astype(np.float64) / fps, sigma_s))
    return float(np.mean(scores)) if scores else float("nan")


def peer_metrics(
    real: np.ndarray | None,
    generated: np.ndarray,
    audio: np.ndarray,
    sr: int,
    fps: float,
    skel,
    weights: np.ndarray | None = None,
    speech: dict | None = None,
) -> dict:
    """Every peer-computed figure for one motion (JSON-able); ``speech`` caches the speech beats."""
    sp = speech if speech is not None else peer_speech(audio, sr)
    ref_speed = None
    if real is not None:
        ref_speed = emage_joint_speed(emage_positions(skel, real), fps).mean(0)
    return {
        "BA_BEAT": beat_align_beat(generated, audio, sr, fps, speech_s=sp["beat"]),
        "BA_BEAT_true_times": beat_align_beat(generated, audio, sr, fps, speech_s=sp["beat_true"]),
        "BA_EMAGE": beat_align_emage(emage_positions(skel, generated), audio, sr, fps, ref_speed, speech_s=sp["emage"]),
        "SRGR_BEAT": srgr_beat(real, generated, weights) if real is not None else None,
        "L1DIV_BEAT": l1div_beat(generated),
    }


def peer_speech(audio: np.ndarray, sr: int) -> dict:
    """The peers' speech beats of one audio, computed once for several motions."""
    return {
        "beat": beat_speech_beats(audio, sr),
        "beat_true": beat_speech_beats(audio, sr, True),
        "emage": emage_speech_beats(audio, sr),
    }
