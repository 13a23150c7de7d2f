"""A pause like a person's (issue #38): the idle layer's settings on validation (tuning only).

Database, speech predictor (cached in /tmp by matching_validate.cached_predictor) and his reference motion from
[0, 0.64 T) of his two paired takes (BEAT 2_scott_0_1_1, BEAT2 2_scott_0_2_2):

* **validation clips**: each take's [0.64 T, 0.8 T) speech cut in half around 15 s of digital zeros or of room
  tone (``conversation.room_tone``), no face track, head at rest; per clip ``conversation.score``: settle,
  resume, pops a minute in the pause and in speech, wrist speed pause / speech, head speed × his in speech
  and in the pause, the longest still stretch;
* **validation stretches**: [0.64 T, 0.8 T) with his face, head at rest, lead-ins of 0, 1, 2 s averaged,
  against his real motion of the same frames: spread ×, jerk ×, head speed ×, torso sway ×, pops a minute;
* **unseen** (reported, never chosen on): the conversation set's ``unseen-zeros`` and ``unseen-room_tone``.

    PYTHONPATH=src python scripts/matching_pause_sweep.py '{"off": {"idle_layer": false}, "on": {}}'

Each variant is a set of ``MatchingConfig`` settings over the engine's defaults. ``--heldout`` builds from
[0, 0.8 T) and scores [0.8 T, T) instead: only once a choice is made. Results: docs/matching.md.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from matching_validate import cached_predictor

from facecapges import timing
from facecapges.evaluation import conversation as cv
from facecapges.evaluation import synchrony as sy
from facecapges.matching.database import build_database
from facecapges.matching.matcher import MatchingConfig, MatchingStream
from facecapges.matching.takes import load_take
from facecapges.rotations import identity_rot6d

FPS, SPF, SR = timing.MODEL_FPS, timing.samples_per_frame(), timing.AUDIO_SR
SHARED = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
HEAD = identity_rot6d().astype(np.float32)


def run(gen: MatchingStream, audio: np.ndarray, face: np.ndarray | None = None) -> np.ndarray:
    """Poses (T, 47, 6) of a cold-started stream over ``audio`` (and ``face`` (T, 52); else neutral)."""
    gen.reset()
    n = len(audio) // SPF
    zero = np.zeros(52, np.float32)
    return np.stack(
        [gen.step(audio[t * SPF : (t + 1) * SPF], zero if face is None else face[t], HEAD) for t in range(n)]
    )


def head_in(skel, pose: np.ndarray, mask: np.ndarray) -> float:
    runs = [pose[a:b] for a, b in cv._runs(mask) if b - a > 2]
    if not runs:
        return float("nan")
    return float(np.average([cv.head_speed_deg_s(skel, p) for p in runs], weights=[len(p) for p in runs]))


def clip_figures(skel, gen, clip, ref) -> dict:
    pose = run(gen, clip.audio)
    sc = cv.score(skel, pose, clip.pause, ref, words=cv.word_frames(clip.audio, len(pose), clip.pause))
    return dict(
        settle=round(sc.settle_s, 2),
        ahead=round(sc.settle_ahead_s, 2),
        resume=round(sc.resume_s, 2),
        pops_pause=round(sc.pops_pause_per_min, 1),
        pops_speech=round(sc.pops_speech_per_min, 1),
        speed_ratio=round(sc.pause_over_speech_speed, 2),
        head=round(sc.head_speed_ratio, 2),
        head_pause=round(head_in(skel, pose, clip.pause) / ref.head_speed, 2),
        still=round(sc.longest_still_s, 1),
    )


def main() -> None:
    heldout = "--heldout" in sys.argv
    variants = json.loads(next(a for a in sys.argv[1:] if not a.startswith("--")))
    t1 = load_take(SHARED / "beat/2_scott_0_1_1.bvh", SHARED / "beat/2_scott_0_1_1.wav")
    t2 = load_take(SHARED / "beat2/2_scott_0_2_2.npz", SHARED / "beat/2_scott_0_2_2.wav", t1.skeleton)
    takes = [t1, t2]
    if heldout:
        ranges = [(0, t.train_until) for t in takes]
        evals = [(t.train_until, t.n_frames) for t in takes]
    else:
        ranges = [(0, int(0.64 * t.n_frames)) for t in takes]
        evals = [(int(0.64 * t.n_frames), t.train_until) for t in takes]
    pred = cached_predictor(takes, [b for _, b in ranges], None)
    skel = t1.skeleton
    ref = cv.reference(
        skel, [t.pose[:b] for t, (_, b) in zip(takes, ranges)], [t.audio[: b * SPF] for t, (_, b) in zip(takes, ranges)]
    )
    db = build_database(takes, ranges)
    rng = np.random.default_rng(0)
    P = int(cv.PAUSE_S * SR)
    clips = []
    for t, (a, b) in zip(takes, evals):
        audio = t.audio[a * SPF : b * SPF]
        half = len(audio) // 2
        for kind, pause in (("zeros", np.zeros(P, np.float32)), ("room_tone", cv.room_tone(P, rng))):
            clips.append(cv._insert(audio[:half], audio[half:], pause, f"{t.name[-3:]} {kind}", kind))
    unseen = [c for c in cv.make_clips(SHARED) if c.name in ("unseen-zeros", "unseen-room_tone")]
    for name, over in variants.items():
        cfg = MatchingConfig.from_dict({**MatchingConfig().as_dict(), **over})
        gen = MatchingStream(db, cfg, pred)
        out: dict = {"clips": {}, "stretches": {}, "unseen": {}}
        for c in clips:
            out["clips"][c.name] = clip_figures(skel, gen, c, ref)
        for t, (a, b) in zip(takes, evals):
            rows = []
            for lead in (0, 15, 30):
                pose = run(gen, t.audio[(a - lead) * SPF : b * SPF], t.face[a - lead : b])[lead:]
                real = t.pose[a:b]
                wg, wr = sy.wrist_positions(skel, pose), sy.wrist_positions(skel, real)
                sc = cv.score(skel, pose, np.zeros(len(pose), bool), ref)
                rows.append(
                    [
                        sy.ratio(sy.wrist_spread(wg), sy.wrist_spread(wr)),
                        sy.ratio(sy.wrist_jerk(wg, FPS), sy.wrist_jerk(wr, FPS)),
                        cv.head_speed_deg_s(skel, pose) / cv.head_speed_deg_s(skel, real),
                        cv.torso_sway_deg(skel, pose) / cv.torso_sway_deg(skel, real),
                        sc.pops_speech_per_min,
                    ]
                )
            m = np.mean(rows, axis=0)
            out["stretches"][t.name[-3:]] = dict(
                zip(("spread", "jerk", "head", "sway", "pops"), np.round(m, 2).tolist())
            )
        for c in unseen:
            out["unseen"][c.name] = clip_figures(skel, gen, c, ref)
        print(name, json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
