"""How much temporal smoothing the motion ``styles build --video`` puts in a style's database needs, on the
development stretch only (docs/capture-body.md "A smoother capture for a style").

The video is the avatar rendered with his real motion of the first 80 % of ``2_scott_0_1_1`` (the rendered
whole take cut to frames 0–766, as ``train11.mp4`` in the docs); its landmarks are collected once (or read
from ``--landmarks``, a pickle this script writes), solved once, then each setting of
:func:`facecapges.capture.body_solve.smooth_for_style` (σ of every joint but the fingers, the fingers' σ,
the per-joint acceleration limit; ``inf``: no limiter) is measured against the truth: the pop rule's rate
(:func:`evaluation.realism.transitions` against his training frames of 1_1), the median joint acceleration
over his (arms and shoulders, hands, fingers) and the arm directions (:func:`evaluation.body_capture.compare`).

    PYTHONPATH=src python scripts/capture_smoothing_sweep.py train11.mp4 --landmarks train11.landmarks.pkl
"""

from __future__ import annotations

import argparse
import json
import pickle
from pathlib import Path

import numpy as np

from facecapges.capture.body_solve import ACCEL_LIMIT, FINGER_SIGMA, STYLE_SIGMA, smooth_for_style, solve
from facecapges.evaluation import realism as rz
from facecapges.evaluation.body_capture import compare
from facecapges.matching.takes import load_take
from facecapges.skeleton import UPPER_BODY, pose_to_motion

BEAT = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "beat"
SETTINGS = [(0.0, 0.0, np.inf)] + [(s, f, np.inf) for s in (1.0, 2.0, 3.0) for f in (1.0, 2.0, 4.0, 6.0)]
SETTINGS += [(1.0, f, ACCEL_LIMIT) for f in (1.0, 2.0, 4.0)] + [(0.0, 2.0, ACCEL_LIMIT), (2.0, 2.0, ACCEL_LIMIT)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("video", help="the rendered development stretch (first 80 % of 2_scott_0_1_1)")
    ap.add_argument("--landmarks", help="a pickle of the video's landmarks: read if it exists, else written")
    args = ap.parse_args()
    from facecapges.capture.body import collect_landmarks

    cache = Path(args.landmarks) if args.landmarks else None
    if cache is not None and cache.exists():
        lms, _ = pickle.loads(cache.read_bytes())  # our own cache file, written below
    else:
        lms = collect_landmarks(args.video)
        if cache is not None:
            cache.write_bytes(pickle.dumps(lms))
        lms = lms[0]
    take = load_take(BEAT / "2_scott_0_1_1.bvh", BEAT / "2_scott_0_1_1.wav")
    skel, real = take.skeleton, np.asarray(take.pose[: take.train_until])
    truth = pose_to_motion(skel, real)[: lms.n_frames]
    thr = rz.transition_threshold([real], 15.0)
    his = rz.joint_acceleration(real, 15.0, per_joint=True)[1:-1]
    fingers = [
        j for j, n in enumerate(UPPER_BODY) if any(k in n for k in ("Thumb", "Index", "Middle", "Ring", "Pinky"))
    ]
    groups = {
        "arms": [j for j, n in enumerate(UPPER_BODY) if n.endswith(("Arm", "Shoulder"))],
        "hands": [UPPER_BODY.index("RightHand"), UPPER_BODY.index("LeftHand")],
        "fingers": fingers,
    }
    print(json.dumps({"his_pops_per_min": rz.transitions(real, [real], 15.0, threshold=thr).per_minute}))
    raw = solve(skel, lms).pose
    for sigma, finger_sigma, limit in SETTINGS:
        pose = smooth_for_style(raw, 15.0, sigma, finger_sigma, limit)
        acc = rz.joint_acceleration(pose, 15.0, per_joint=True)[1:-1]
        c = compare(skel, truth, pose_to_motion(skel, pose))
        row = {
            "sigma": sigma,
            "finger_sigma": finger_sigma,
            "limit": None if np.isinf(limit) else limit,
            "pops_per_min": round(rz.transitions(pose, [real], 15.0, threshold=thr).per_minute, 1),
            **{
                f"{g}_accel_x_his": round(float(np.median(acc[:, j]) / np.median(his[:, j])), 2)
                for g, j in groups.items()
            },
            "median_deg": round(c["median_deg"], 2),
            "p90_deg": round(c["p90_deg"], 2),
            "spread": round(c["wrist_spread_ratio"], 3),
            "shipped": (sigma, finger_sigma, limit) == (STYLE_SIGMA, FINGER_SIGMA, ACCEL_LIMIT),
        }
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
