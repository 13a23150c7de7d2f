"""A conversation test set and its figures (issue #38): speech, pauses of every kind, other voices.

Every evaluation clip of BEAT is a monologue; a user talks, stops, talks again, with a mic that a
noise gate or a mute button sets to zero. :func:`make_clips` builds such clips **at run time** from
the shared recordings (nothing derived from ZEGGS is ever written into the project):

* ``heldout-zeros`` — each paired take's held-out 20 % of his speech with 15 s of digital zeros
  (a muted mic) in the middle;
* ``unseen-<kind>`` — unseen speech of his (``2_scott_0_4_4.wav``): 10 s of speech, a 15 s pause of
  one :data:`PAUSE_KINDS`, 10 s more speech (each kind from other parts of the wav):
  ``zeros``; ``room_tone`` (noise low-passed at 1 kHz, −50 dBFS RMS); ``keyboard`` (5–15 ms
  high-passed noise bursts, ~6 a second, peaks ≈ −20 dBFS, over room tone at −60 dBFS);
  ``music`` (tones of 3 harmonics on a pentatonic scale, 0.2–0.6 s notes with an envelope,
  6 dB below his speech level); ``far_voice`` (the ZEGGS speaker's voice 25 dB below his level);
* ``zeggs-half-silent`` — the ZEGGS take's speech (another speaker, level-matched to his), every
  other 4 s block set to zeros.

Each :class:`ConversationClip` carries its truth per 15 fps frame: ``pause`` (inside an inserted
pause or silent block) and ``speech`` (outside them, where the clean speech is voiced by
:func:`facecapges.evaluation.realism.speech_frames`).

:func:`score` measures a generated motion of a clip against :class:`Reference` figures of his real
motion (his training frames), per clip:

* **pops** a minute in the pauses and in the speech: frames of :func:`facecapges.evaluation.realism.transitions`
  (the whole-body joint acceleration above the 99.9th percentile of his real motion: 0.9 a minute
  on his own takes);
* **wrist speed** pause / speech (mean of both wrists' speed);
* **still share**: frames whose faster wrist moves below :data:`STILL_CM_S`; the longest still stretch;
* **both-hands share**: frames with both wrists raised — a wrist is *raised* when its height is
  more than :data:`RAISE_CM` above his rest height (the :data:`REST_PERCENTILE` th percentile of
  that wrist's height over his training frames: his arms hanging). :func:`both_hands_share` is the one
  rule, for generated motion and for his real motion of the same stretch alike (:func:`stretch_figures`):
  a stretch's own 5th percentile is not his rest — where he holds both hands up for 10 s it sits 11–14 cm
  above it, and his share of that stretch came out 0.18 instead of 0.98 (issue #38, docs/matching.md);
* **wrist height** above his rest height, in speech, as a ratio to his (training frames' speech);
* **head speed** (°/s, the global rotation of the head: Neck1's chain) and **torso sway** (RMS
  angle of the spine's rotation from its mean, °) in speech, as ratios to his;
* **settle**: seconds from a pause's start until the wrist speed (averaged over the last 1 s) first
  falls to his idle level (:attr:`Reference.idle_speed`: half his median wrist speed in speech — his own
  pauses inside a monologue are breaths mid-gesture, faster than that, so they cannot set it). The trailing
  mean remembers the speech before the pause: arms that stopped dead on the pause's first frame after a
  second of gesturing at 2× his idle speed score 0.47 s. **settle ahead** is what a viewer calls settled: the
  first frame of the pause from which the wrist speed averaged over the *next* 1 s (within the pause) is at
  his idle level (0 for arms that stop dead at the pause's start; both are reported, docs/matching.md);
  **resume**: seconds from
  the first word after a pause — the first frame after it that :func:`word_frames` marks (``words``: within
  :data:`WORD_DB` of the clip's speech level, non-causal, on the clean audio) — until the wrist speed first
  exceeds his median speed in speech (capped at the clip's end). Without ``words`` it counts from the pause's
  end, which charges the engine with whatever a cut leaves before the first word: on ZEGGS's half-silent clip
  one block's speech starts 1.5 s after the block; in the soak's random stretches a breath or his room's noise
  (−40 to −50 dBFS, 20–40 dB under his words, which the energy truth :func:`facecapges.evaluation.realism.speech_frames`
  still calls speech) runs up to 0.9 s before the first word (issue #38, docs/matching.md "When resume is late").

Repetition with mirrored copies counted as the same stretch is
:func:`facecapges.evaluation.realism.repetition` with ``same_as``
(:func:`facecapges.matching.database.mirror_twins`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from facecapges import rotations as rot
from facecapges import timing
from facecapges.evaluation import realism as rz
from facecapges.evaluation import synchrony as sy
from facecapges.skeleton import UPPER_BODY, upper_body_transforms

PAUSE_KINDS: tuple[str, ...] = ("zeros", "room_tone", "keyboard", "music", "far_voice")
PAUSE_S = 15.0
SPEECH_S = 10.0
ZEGGS_BLOCK_S = 4.0
ROOM_TONE_DB = -50.0
FAR_VOICE_DB = -25.0
MUSIC_DB = -6.0
STILL_CM_S = 1.0
RAISE_CM = 10.0
REST_PERCENTILE = 5.0
SETTLE_WINDOW_S = 1.0
WORD_DB = 20.0  # a word: a frame's level within this of the clip's speech level (its 95th percentile)
WORD_PERCENTILE = 95.0
SR = timing.AUDIO_SR
FPS = timing.MODEL_FPS


@dataclass
class ConversationClip:
    """One test clip: audio (16 kHz) and its truth per frame (module docs)."""

    name: str
    audio: np.ndarray
    pause: np.ndarray  # (T,) bool: an inserted pause / silent block
    speech: np.ndarray  # (T,) bool: voiced speech outside the pauses
    kind: str

    @property
    def n_frames(self) -> int:
        return len(self.pause)


def _rms_db(x: np.ndarray) -> float:
    return float(20 * np.log10(np.sqrt(np.mean(np.square(x, dtype=np.float64))) + 1e-12))


def _at_db(x: np.ndarray, db: float) -> np.ndarray:
    return (x * 10 ** ((db - _rms_db(x)) / 20)).astype(np.float32)


def _speech_db(audio: np.ndarray) -> float:
    """The RMS level (dBFS) of the voiced frames of a speech recording."""
    n = len(audio) // timing.samples_per_frame()
    v = rz.speech_frames(audio, SR, FPS, n)
    spf = timing.samples_per_frame()
    frames = audio[: n * spf].reshape(n, spf)[v]
    return _rms_db(frames) if len(frames) else _rms_db(audio)


def room_tone(n: int, rng: np.random.Generator, db: float = ROOM_TONE_DB) -> np.ndarray:
    from scipy.signal import butter, sosfilt

    sos = butter(2, 1000, "low", fs=SR, output="sos")
    return _at_db(sosfilt(sos, rng.standard_normal(n)), db)


def keyboard(n: int, rng: np.random.Generator) -> np.ndarray:
    from scipy.signal import butter, sosfilt

    out = room_tone(n, rng, -60.0).astype(np.float64)
    sos = butter(2, 1500, "high", fs=SR, output="sos")
    t = 0.1
    while t < n / SR - 0.05:
        m = int(rng.uniform(0.005, 0.015) * SR)
        burst = sosfilt(sos, rng.standard_normal(m)) * np.exp(-np.arange(m) / (m / 4))
        burst *= 10 ** (rng.uniform(-24, -16) / 20) / (np.abs(burst).max() + 1e-12)
        s = int(t * SR)
        out[s : s + m] += burst[: n - s]
        t += rng.exponential(1 / 6.0) + 0.03
    return out.astype(np.float32)


def music(n: int, rng: np.random.Generator, db: float) -> np.ndarray:
    scale = 220.0 * 2 ** (np.array([0, 2, 4, 7, 9, 12, 14, 16]) / 12)
    out = np.zeros(n)
    s = 0
    while s < n:
        m = min(int(rng.uniform(0.2, 0.6) * SR), n - s)
        f = rng.choice(scale)
        t = np.arange(m) / SR
        tone = sum(np.sin(2 * np.pi * f * k * t) / k for k in (1, 2, 3))
        env = np.minimum(1.0, t / 0.02) * np.exp(-t / 0.4)
        out[s : s + m] += tone * env
        s += m
    return _at_db(out, db)


def _insert(a: np.ndarray, b: np.ndarray, pause: np.ndarray, name: str, kind: str) -> ConversationClip:
    """Speech ``a``, the pause, speech ``b`` (each cut to whole frames) → a clip with its truth."""
    spf = timing.samples_per_frame()
    parts = [x[: len(x) // spf * spf].astype(np.float32) for x in (a, pause, b)]
    audio = np.concatenate(parts)
    n = [len(x) // spf for x in parts]
    is_pause = np.zeros(sum(n), bool)
    is_pause[n[0] : n[0] + n[1]] = True
    speech = np.zeros(sum(n), bool)
    speech[: n[0]] = rz.speech_frames(parts[0], SR, FPS, n[0])
    speech[n[0] + n[1] :] = rz.speech_frames(parts[2], SR, FPS, n[2])
    return ConversationClip(name, audio, is_pause, speech, kind)


def make_clips(
    shared: str | Path, heldout: Sequence[tuple[str, np.ndarray]] = (), seed: int = 0
) -> list[ConversationClip]:
    """The conversation test set (module docs) from ``shared`` (the ``../shared/data`` folder) and the
    held-out speech of the paired takes (``(name, audio)``; their last 20 %)."""
    from facecapges.io.audio import load_audio

    shared = Path(shared)
    rng = np.random.default_rng(seed)
    clips = []
    for name, a in heldout:
        half = len(a) // 2
        clips.append(
            _insert(a[:half], a[half:], np.zeros(int(PAUSE_S * SR), np.float32), f"heldout-zeros {name}", "zeros")
        )
    unseen = load_audio(shared / "beat" / "2_scott_0_4_4.wav", SR)
    zeggs = load_audio(shared / "zeggs" / "067_Speech_2_x_1_0.wav", SR)
    his_db = _speech_db(unseen)
    zeggs = _at_db(zeggs, _rms_db(zeggs) + his_db - _speech_db(zeggs))
    P, S = int(PAUSE_S * SR), int(SPEECH_S * SR)
    for k, kind in enumerate(PAUSE_KINDS):
        a0 = (k * 2 * S) % max(len(unseen) - 2 * S, 1)
        a, b = unseen[a0 : a0 + S], unseen[a0 + S : a0 + 2 * S]
        if kind == "zeros":
            pause = np.zeros(P, np.float32)
        elif kind == "room_tone":
            pause = room_tone(P, rng)
        elif kind == "keyboard":
            pause = keyboard(P, rng)
        elif kind == "music":
            pause = music(P, rng, his_db + MUSIC_DB)
        else:
            z0 = int(rng.integers(0, len(zeggs) - P))
            pause = _at_db(zeggs[z0 : z0 + P], _rms_db(zeggs[z0 : z0 + P]) + FAR_VOICE_DB)
        clips.append(_insert(a, b, pause, f"unseen-{kind}", kind))
    spf = timing.samples_per_frame()
    n = len(zeggs) // spf
    z = zeggs[: n * spf].copy()
    blk = int(ZEGGS_BLOCK_S * FPS)
    silent = (np.arange(n) // blk) % 2 == 1
    z.reshape(n, spf)[silent] = 0.0
    voiced = rz.speech_frames(zeggs[: n * spf], SR, FPS, n) & ~silent
    clips.append(ConversationClip("zeggs-half-silent", z, silent, voiced, "other_speaker"))
    return clips


# ------------------------------------------------------------------------------------ his reference
def _head_spine(skel, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Global rotations (T, 3, 3) of the head (``Head``, else ``Neck1``) and the spine's (``Spine``)."""
    G, _ = upper_body_transforms(skel, pose)
    head = skel.index("Head") if "Head" in skel.names else skel.index(UPPER_BODY[2])
    return G[:, head], G[:, skel.index("Spine")]


def head_speed_deg_s(skel, pose: np.ndarray, fps: float = FPS) -> float:
    """Mean angular speed (°/s) of the head's global rotation."""
    H, _ = _head_spine(skel, pose)
    if len(H) < 2:
        return float("nan")
    rel = np.einsum("tji,tjk->tik", H[:-1], H[1:])
    ang = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1))
    return float(np.degrees(ang).mean() * fps)


def torso_sway_deg(skel, pose: np.ndarray) -> float:
    """RMS angle (°) of the spine's global rotation from its chordal mean."""
    _, S = _head_spine(skel, pose)
    if not len(S):
        return float("nan")
    m = rot.mean_rotation_matrix(S)
    rel = np.einsum("ji,tjk->tik", m, S)
    ang = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1))
    return float(np.degrees(np.sqrt(np.mean(ang**2))))


def wrist_speed(w: np.ndarray, fps: float = FPS) -> np.ndarray:
    """Per frame (T,) the mean speed of the wrists (T, W, 3); frame 0 repeats frame 1."""
    s = np.zeros(len(w))
    if len(w) > 1:
        s[1:] = np.linalg.norm(np.diff(w, axis=0), axis=-1).mean(1) * fps
        s[0] = s[1]
    return s


def _ahead(x: np.ndarray, n: int) -> np.ndarray:
    """Leading mean over ``n`` frames: frame t averages ``x[t : t + n]`` (fewer at the end)."""
    c = np.cumsum(np.r_[0.0, x])
    i = np.arange(len(x))
    j = np.minimum(i + n, len(x))
    return (c[j] - c[i]) / np.maximum(j - i, 1)


def _smooth(x: np.ndarray, n: int) -> np.ndarray:
    """Trailing mean over ``n`` frames (causal)."""
    c = np.cumsum(np.r_[0.0, x])
    i = np.arange(1, len(x) + 1)
    return (c[i] - c[np.maximum(i - n, 0)]) / np.minimum(i, n)


@dataclass
class Reference:
    """His real motion's figures (training frames) that :func:`score` compares with (module docs)."""

    threshold: float  # pop: whole-body acceleration, 99.9th percentile
    rest_height: np.ndarray  # (2,) per wrist, cm
    idle_speed: float  # cm/s: half his median wrist speed in speech
    speech_speed: float  # cm/s, median wrist speed in speech
    both_hands: float
    wrist_height: float  # mean height above rest in speech, cm
    head_speed: float
    torso_sway: float
    pause_over_speech_speed: float

    def as_dict(self) -> dict:
        d = asdict(self)
        d["rest_height"] = [float(x) for x in self.rest_height]
        return d


def reference(skel, poses: Sequence[np.ndarray], audios: Sequence[np.ndarray]) -> Reference:
    """:class:`Reference` of his real clips (poses (T, 47, 6) with their audio)."""
    ws = [sy.wrist_positions(skel, p) for p in poses]
    heights = np.concatenate([w[:, :, 1] for w in ws])
    rest = np.percentile(heights, REST_PERCENTILE, axis=0)
    sp_all, idle_all, speech_m, h_all, both_all, head_all, sway_all = [], [], [], [], [], [], []
    pause_sp = []
    for p, w, a in zip(poses, ws, audios, strict=True):
        v = rz.speech_frames(a, SR, FPS, len(p))
        s = wrist_speed(w)
        sm = _smooth(s, int(SETTLE_WINDOW_S * FPS))
        idle_all.append(sm[~v])
        pause_sp.append(s[~v])
        sp_all.append(s[v])
        both_all.append(_both_raised(w, rest)[v])
        h_all.append((w[:, :, 1] - rest).mean(1)[v])
        head_all.append(head_speed_deg_s(skel, p))
        sway_all.append(torso_sway_deg(skel, p))
        speech_m.append(s[v])
    sp = np.concatenate(sp_all)
    return Reference(
        threshold=rz.transition_threshold(list(poses), FPS),
        rest_height=rest,
        idle_speed=0.5 * float(np.median(sp)),
        speech_speed=float(np.median(sp)),
        both_hands=float(np.concatenate(both_all).mean()),
        wrist_height=float(np.concatenate(h_all).mean()),
        head_speed=float(np.mean(head_all)),
        torso_sway=float(np.mean(sway_all)),
        pause_over_speech_speed=float(np.concatenate(pause_sp).mean() / sp.mean()),
    )


def _both_raised(w: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """Frames (T,) whose two wrists (w: (T, 2, 3) cm) are both more than :data:`RAISE_CM` above ``rest`` (2,)."""
    return np.asarray((w[:, :, 1] > np.asarray(rest) + RAISE_CM).all(axis=1))


def both_hands_share(skel, pose: np.ndarray, ref: Reference, frames: np.ndarray | None = None) -> float:
    """Share of ``frames`` (T,) bool (default: all) of ``pose`` (T, 47, 6) with both wrists raised above **his**
    rest height (``ref.rest_height``, his training frames) — the rule for generated and real motion alike."""
    both = _both_raised(sy.wrist_positions(skel, np.asarray(pose)), ref.rest_height)
    if frames is not None:
        both = both[np.asarray(frames, bool)[: len(both)]]
    return float(both.mean()) if len(both) else float("nan")


def stretch_figures(skel, gen: np.ndarray, real: np.ndarray, ref: Reference, fps: float = FPS) -> dict[str, float]:
    """Generated motion ``gen`` of a stretch against his real motion ``real`` of the same frames (both (T, 47, 6),
    cut to the shorter), each measured by the same rule against his training reference ``ref``: both-hands share
    (``both_hands``, his ``both_hands_real``: :func:`both_hands_share`), wrist height above his rest as a ratio,
    wrist spread and jerk ratios (:mod:`facecapges.evaluation.synchrony`), head speed (also in °/s) and torso sway
    ratios."""
    n = min(len(gen), len(real))
    gen, real = np.asarray(gen)[:n], np.asarray(real)[:n]
    wg, wr = sy.wrist_positions(skel, gen), sy.wrist_positions(skel, real)
    head_g, head_r = head_speed_deg_s(skel, gen, fps), head_speed_deg_s(skel, real, fps)
    return {
        "both_hands": float(_both_raised(wg, ref.rest_height).mean()),
        "both_hands_real": float(_both_raised(wr, ref.rest_height).mean()),
        "wrist_height_ratio": float(
            np.mean((wg[:, :, 1] - ref.rest_height).mean(1)) / np.mean((wr[:, :, 1] - ref.rest_height).mean(1))
        ),
        "spread_ratio": float(sy.ratio(sy.wrist_spread(wg), sy.wrist_spread(wr))),
        "jerk_ratio": float(sy.ratio(sy.wrist_jerk(wg, fps), sy.wrist_jerk(wr, fps))),
        "head_speed_ratio": head_g / head_r,
        "head_speed_deg_s": head_g,
        "head_speed_real_deg_s": head_r,
        "torso_sway_ratio": torso_sway_deg(skel, gen) / torso_sway_deg(skel, real),
    }


# ------------------------------------------------------------------------------------ scoring
def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


@dataclass
class ClipScore:
    """The figures of one generated clip (module docs)."""

    name: str
    pops_pause_per_min: float
    pops_speech_per_min: float
    pause_over_speech_speed: float
    still_share: float
    longest_still_s: float
    both_hands: float  # share of speech frames
    wrist_height_ratio: float
    head_speed_ratio: float
    torso_sway_ratio: float
    settle_s: float
    resume_s: float
    pops: list[int] = field(default_factory=list)
    settle_ahead_s: float = float("nan")

    def as_dict(self) -> dict:
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in asdict(self).items()}


def word_frames(audio: np.ndarray, n_frames: int, pause: np.ndarray | None = None, fps: float = FPS) -> np.ndarray:
    """Frames (n_frames,) of words: outside ``pause`` (n_frames,) and with a level (RMS, dB) within :data:`WORD_DB`
    of the :data:`WORD_PERCENTILE` th percentile of the level over the frames outside ``pause`` (non-causal; a
    breath or room noise 20–40 dB under his words is not one). A frame's level is that of the samples the engine
    reads at that frame (``[t·spf, (t+1)·spf)``, as :class:`facecapges.matching.speech.SpeechTracker`), so a word
    and the VAD's decision on it fall on the same frame."""
    spf = timing.samples_per_frame(fps)
    a = np.zeros(n_frames * spf, np.float64)
    m = min(len(audio), len(a))
    a[:m] = np.asarray(audio, np.float64)[:m]
    level = 10.0 * np.log10(np.mean(a.reshape(n_frames, spf) ** 2, axis=1) + 1e-20)
    out = np.ones(n_frames, bool) if pause is None else ~np.asarray(pause, bool)[:n_frames]
    if not out.any():
        return out
    return out & (level > np.percentile(level[out], WORD_PERCENTILE) - WORD_DB)


def score(
    skel, pose: np.ndarray, clip_pause: np.ndarray, ref: Reference, fps: float = FPS, words: np.ndarray | None = None
) -> ClipScore:
    """Figures of generated ``pose`` (T, 47, 6) of a clip whose frames ``clip_pause`` (T,) are inserted pauses;
    ``words`` (T,, :func:`word_frames`) sets where resume counts from (module docs)."""
    pose = np.asarray(pose)
    pause = np.asarray(clip_pause, bool)[: len(pose)]
    talk = None if words is None else np.asarray(words, bool)[: len(pose)]
    pops = np.zeros(len(pose), bool)
    pops[rz.transitions(pose, [pose[:3]], fps, threshold=ref.threshold).frames] = True
    w = sy.wrist_positions(skel, pose)
    s = wrist_speed(w, fps)
    mins_p, mins_s = pause.sum() / fps / 60, (~pause).sum() / fps / 60
    still = np.linalg.norm(np.diff(w, axis=0, prepend=w[:1]), axis=-1).max(1) * fps < STILL_CM_S
    still[0] = still[1] if len(still) > 1 else still[0]
    longest = max((b - a for a, b in _runs(still)), default=0) / fps
    both = _both_raised(w, ref.rest_height)
    sp = ~pause
    height = (w[:, :, 1] - ref.rest_height).mean(1)
    sm = _smooth(s, int(SETTLE_WINDOW_S * fps))
    settle, ahead, resume = [], [], []
    for a, b in _runs(pause):
        below = np.flatnonzero(sm[a:b] <= ref.idle_speed)
        settle.append((below[0] if len(below) else b - a) / fps)
        calm = np.flatnonzero(_ahead(s[a:b], int(SETTLE_WINDOW_S * fps)) <= ref.idle_speed)
        ahead.append((calm[0] if len(calm) else b - a) / fps)
        if b < len(pose):
            if talk is not None:  # the first word before the next pause (none: no onset to resume on)
                nxt = np.flatnonzero(pause[b:])
                said = np.flatnonzero(talk[b : b + (nxt[0] if len(nxt) else len(pose) - b)])
                if not len(said):
                    continue
                b += int(said[0])
            up = np.flatnonzero(s[b:] > ref.speech_speed)
            resume.append((up[0] if len(up) else len(pose) - b) / fps)
    speech_poses = [pose[a:b] for a, b in _runs(sp) if b - a > 2]
    head = np.average([head_speed_deg_s(skel, p) for p in speech_poses], weights=[len(p) for p in speech_poses])
    sway = np.average([torso_sway_deg(skel, p) for p in speech_poses], weights=[len(p) for p in speech_poses])
    nan = float("nan")
    return ClipScore(
        name="",
        pops_pause_per_min=float(pops[pause].sum() / mins_p) if mins_p else nan,
        pops_speech_per_min=float(pops[sp].sum() / mins_s) if mins_s else nan,
        pause_over_speech_speed=float(s[pause].mean() / max(s[sp].mean(), 1e-9)) if pause.any() else nan,
        still_share=float(still.mean()),
        longest_still_s=float(longest),
        both_hands=float(both[sp].mean()),
        wrist_height_ratio=float(height[sp].mean() / ref.wrist_height),
        head_speed_ratio=float(head / ref.head_speed),
        torso_sway_ratio=float(sway / ref.torso_sway),
        settle_s=float(np.mean(settle)) if settle else nan,
        resume_s=float(np.mean(resume)) if resume else nan,
        pops=np.flatnonzero(pops).tolist(),
        settle_ahead_s=float(np.mean(ahead)) if ahead else nan,
    )


def generate(engine, audio: np.ndarray, intensity: float = 1.0, face: np.ndarray | None = None) -> np.ndarray:
    """Poses (T, 47, 6) of ``engine`` for ``audio`` alone (no face track: neutral face, head at rest), cold start."""
    from facecapges.engine.generate import generate_blocks
    from facecapges.rotations import identity_rot6d

    T = len(audio) // timing.samples_per_frame()
    a = timing.frame_audio(audio, T, FPS, SR)
    f = np.zeros((T, 52), np.float32) if face is None else np.asarray(face, np.float32)[:T]
    h = np.broadcast_to(identity_rot6d(), (T, 6)).astype(np.float32)
    return np.concatenate(list(generate_blocks(engine, [(a, f, h)], T, False, intensity=intensity)))
