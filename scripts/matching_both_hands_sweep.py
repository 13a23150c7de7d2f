"""Both hands at his height (issue #38): engine settings and feature weights on validation (tuning only).

Database and speech predictor from [0, 0.64 T) of his two paired takes (the predictor cached in /tmp by
matching_validate.cached_predictor), the engine run from a cold start on [0.64 T, 0.8 T) with his face and
the head at rest (as scripts/conversation_report.py runs the held-out stretches), scored against his real
motion of the same frames: both-hands share (his), wrist height ×, spread ×, jerk ×, pops a minute, head
speed ×, torso sway × (facecapges.evaluation.conversation). ``--heldout`` builds from [0, 0.8 T) and scores
[0.8 T, T): only once a choice is made.

    PYTHONPATH=src python scripts/matching_both_hands_sweep.py \
        '{"base": {}, "onset1": {"config": {"onset_bonus": 1.0}}, "future2": {"weights": {...}}}'

Results: docs/matching.md.
"""

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from matching_validate import cached_predictor

from facecapges import timing
from facecapges.evaluation import conversation as cv
from facecapges.matching.database import build_database
from facecapges.matching.matcher import MatchingConfig, MatchingStream
from facecapges.matching.takes import load_take
from facecapges.rotations import identity_rot6d

FPS, SPF = timing.MODEL_FPS, timing.samples_per_frame()
sh = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
t1 = load_take(sh / "beat/2_scott_0_1_1.bvh", sh / "beat/2_scott_0_1_1.wav")
t2 = load_take(sh / "beat2/2_scott_0_2_2.npz", sh / "beat/2_scott_0_2_2.wav", t1.skeleton)
takes = [t1, t2]
heldout = "--heldout" in sys.argv
if heldout:
    ranges = [(0, t.train_until) for t in takes]
    evals = [(t.train_until, t.n_frames) for t in takes]
else:
    ranges = [(0, int(0.64 * t.n_frames)) for t in takes]
    evals = [(int(0.64 * t.n_frames), t.train_until) for t in takes]
pred = cached_predictor(takes, [b for _, b in ranges], None)
skel = t1.skeleton
ref = cv.reference(
    skel, [t.pose[:a] for t, (_, a) in zip(takes, ranges)], [t.audio[: a * SPF] for t, (_, a) in zip(takes, ranges)]
)
variants = json.loads(sys.argv[1])
for name, v in variants.items():
    db = build_database(takes, ranges, weights=v.get("weights")) if v.get("weights") else build_database(takes, ranges)
    cfg = MatchingConfig.from_dict(v.get("config", {}))
    gen = MatchingStream(db, cfg, pred)
    out = {}
    for t, (a, b) in zip(takes, evals):
        gen.reset()
        h = identity_rot6d().astype(np.float32)
        pose = np.stack([gen.step(t.audio[k * SPF : (k + 1) * SPF], t.face[k], h) for k in range(a, b)])
        real = t.pose[a:b]
        sc = cv.score(skel, pose, np.zeros(len(pose), bool), ref)
        f = cv.stretch_figures(skel, pose, real, ref, FPS)  # his share by the engine's rule (his training rest)
        out[t.name[-3:]] = dict(
            both=round(f["both_hands"], 2),
            both_real=round(f["both_hands_real"], 2),
            height=round(f["wrist_height_ratio"], 2),
            spread=round(f["spread_ratio"], 2),
            jerk=round(f["jerk_ratio"], 2),
            pops=round(sc.pops_speech_per_min, 1),
            head=round(f["head_speed_ratio"], 2),
            sway=round(f["torso_sway_ratio"], 2),
        )
    print(name, json.dumps(out), flush=True)
