"""Validation figures of the matching engine (tuning only; not part of the package).

The database is built from each take's frames [0, 0.64·T); the engine then runs on the audio,
face and head of frames [0.64·T, 0.8·T) (the last 20 % of the training part) and is scored
against the real motion of those frames. ``--heldout`` instead builds from [0, 0.8·T) and runs
on the held-out [0.8·T, T) — only once the choices are final.

Figures (per take and pooled): wrist spread and jerk ratios to the real motion, BeatAlign gap
in sd of its shifted-audio control, pops a minute (:func:`facecapges.evaluation.realism.transitions`,
what ``facecapges eval`` reports: frames whose acceleration over all joints exceeds the real
training motion's 99.9th percentile) and those within 2 frames after a clip switch, spread in
pauses / spread in speech.

    PYTHONPATH=src python scripts/matching_validate.py --take BVH WAV [--take …] [--set k=v …]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from facecapges import timing
from facecapges.evaluation import beat_align as ba
from facecapges.evaluation import realism as rz
from facecapges.evaluation import synchrony as sy
from facecapges.matching.database import build_database
from facecapges.matching.matcher import MatchingConfig, MatchingStream
from facecapges.matching.speech import speech_track
from facecapges.matching.takes import load_take

FPS = timing.MODEL_FPS
SPF = timing.samples_per_frame()


def switch_pops(pop: np.ndarray, jumps: np.ndarray) -> int:
    """Pop frames (acceleration index t is frame t + 1) within 2 frames after a clip switch."""
    near = np.zeros(len(jumps), bool)
    for d in range(3):
        near[d:] |= jumps[: len(jumps) - d]
    return int((pop & near[1 : len(pop) + 1]).sum())


def spread(w: np.ndarray) -> float:
    return float(sy.wrist_spread(w)) if len(w) > 3 else float("nan")


def run(
    gen: MatchingStream, take, a: int, b: int, predictor=None, lead_in: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Poses of frames [a, b) and whether each frame starts a new clip; the stream starts ``lead_in``
    frames earlier (inputs only: different lead-ins give different paths through the database)."""
    gen.reset()
    head = take.head if predictor is None else predictor.camera_head(take.head).astype(np.float32)
    out = np.empty((b - a, 47, 6), np.float32)
    jumps = np.zeros(b - a, bool)
    prev = gen.playing_row
    for t in range(a - lead_in, b):
        p = gen.step(take.audio[t * SPF : (t + 1) * SPF], take.face[t], head[t])
        if t >= a:
            out[t - a] = p
            jumps[t - a] = gen.playing_row != prev + 1
        prev = gen.playing_row
    return out, jumps


def run_network(style: str, take, a: int, b: int, lead_in: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The network style's streaming poses of frames [a, b) (its camera-frame head as eval feeds it)."""
    from facecapges.capture.head_pose import skeleton_head_to_camera
    from facecapges.styles import load_style

    ck = load_style(style=style)
    ref = ck.meta.get("head_reference_rot6d")
    head = take.head if ref is None else skeleton_head_to_camera(take.head, ref).astype(np.float32)
    gen = ck.streaming()
    out = np.empty((b - a, 47, 6), np.float32)
    for t in range(a - lead_in, b):
        p = gen.step(take.audio[t * SPF : (t + 1) * SPF], take.face[t], head[t])
        if t >= a:
            out[t - a] = p
    return out, np.zeros(b - a, bool)


def cached_predictor(takes, stop: list[int], steps: int | None):
    """The speech predictor trained on frames [0, stop) of each take (cached in /tmp by takes and stops)."""
    import hashlib
    from dataclasses import replace

    from safetensors.torch import load_file, save_file

    from facecapges.matching.predictor import Predictor, PredictorSettings
    from facecapges.matching.predictor_training import train_predictor

    key = hashlib.sha1(json.dumps([[t.name for t in takes], stop, steps]).encode()).hexdigest()[:12]
    path = Path(f"/tmp/mm-predictor-{key}.safetensors")
    if path.is_file():
        meta = json.loads(path.with_suffix(".json").read_text())
        return Predictor.from_state(meta, load_file(str(path)))
    s = PredictorSettings() if steps is None else replace(PredictorSettings(), steps=steps)
    cut = [replace(t, train_until=b) for t, b in zip(takes, stop, strict=True)]
    pred = train_predictor(cut, seed=0, progress=False, settings=s)
    save_file({k: v.contiguous() for k, v in pred.state_dict().items()}, str(path))
    path.with_suffix(".json").write_text(json.dumps(pred.config))
    return pred


def figures(take, gen_pose: np.ndarray, a: int, b: int, real_train: list, jumps: np.ndarray, speaker=None) -> dict:
    skel = take.skeleton
    real = take.pose[a:b]
    wr_g, wr_r = sy.wrist_positions(skel, gen_pose), sy.wrist_positions(skel, real)
    audio = take.audio[a * SPF : b * SPF]
    dur = (b - a) / FPS
    offs = [float(x) for x in np.arange(1.0, dur - 0.99, 0.5)]
    ctl_g = ba.beat_align_control(gen_pose, audio, timing.AUDIO_SR, FPS, offsets_s=offs)
    ctl_r = ba.beat_align_control(real, audio, timing.AUDIO_SR, FPS, offsets_s=offs)
    sp = speech_track(audio, b - a).speaking
    pops = np.zeros(b - a, bool)
    pops[rz.transitions(gen_pose, real_train, FPS).frames] = True
    pops_r = rz.transitions(real, real_train, FPS)
    return {
        "take": take.name,
        "frames": [a, b],
        "spread_ratio": sy.ratio(sy.wrist_spread(wr_g), sy.wrist_spread(wr_r)),
        "jerk_ratio": sy.ratio(sy.wrist_jerk(wr_g, FPS), sy.wrist_jerk(wr_r, FPS)),
        "spread_ratio_speaker": sy.ratio(sy.wrist_spread(wr_g), speaker.spread) if speaker else float("nan"),
        "jerk_ratio_speaker": sy.ratio(sy.wrist_jerk(wr_g, FPS), speaker.jerk) if speaker else float("nan"),
        "ba_gap_sd": sy.beat_align_gap_sd(ctl_g),
        "ba_gap_sd_real": sy.beat_align_gap_sd(ctl_r),
        "pops_per_min": float(pops.sum() / (dur / 60.0)),
        "pops_per_min_real": float(pops_r.count / (dur / 60.0)),
        "switch_pops_per_min": float(switch_pops(pops[1:], jumps) / (dur / 60.0)),
        "switches_per_s": float(jumps[1:].sum() / dur),
        "pause_share": float(1.0 - sp.mean()),
        "pause_over_speech_spread": spread(wr_g[~sp]) / spread(wr_g[sp]),
        "pause_over_speech_spread_real": spread(wr_r[~sp]) / spread(wr_r[sp]),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--take", nargs=2, action="append", required=True, metavar=("MOTION", "WAV"))
    ap.add_argument("--skeleton-from", default=None, help="a BEAT BVH whose skeleton non-BEAT takes go onto")
    ap.add_argument("--set", nargs="*", default=[], help="engine config k=v")
    ap.add_argument("--weights", nargs="*", default=[], help="feature group weights k=v")
    ap.add_argument("--heldout", action="store_true")
    ap.add_argument("--no-mirror", action="store_true")
    ap.add_argument("--predictor", action="store_true", help="train (or reuse) the speech predictor on the same frames")
    ap.add_argument("--network", default=None, help="score this network style instead (same windows, same figures)")
    ap.add_argument("--starts", type=int, default=1, help="runs per window with lead-ins of 0, 1, 2 … s")
    ap.add_argument("--steps", type=int, default=None, help="predictor training steps")
    args = ap.parse_args(argv)
    target = load_take(*args.skeleton_from.split(",")).skeleton if args.skeleton_from else None
    takes = [load_take(m, w, target) for m, w in args.take]
    cfg = MatchingConfig.from_dict({k: float(v) if "." in v else int(v) for k, v in (s.split("=") for s in args.set)})
    weights = {k: float(v) for k, v in (s.split("=") for s in args.weights)} or None
    if args.heldout:
        ranges = [(0, t.train_until) for t in takes]
        evals = [(t.train_until, t.n_frames) for t in takes]
    else:
        ranges = [(0, int(0.64 * t.n_frames)) for t in takes]
        evals = [(int(0.64 * t.n_frames), t.train_until) for t in takes]
    db = build_database(takes, ranges, mirror=not args.no_mirror, **({"weights": weights} if weights else {}))
    real_train = [t.pose[a:b] for t, (a, b) in zip(takes, ranges)]
    speaker = sy.pooled_stats(
        [sy.motion_stats(sy.wrist_positions(t.skeleton, t.pose[a:b]), FPS) for t, (a, b) in zip(takes, ranges)]
    )  # the speaker's real motion in the database's frames: "moves like him"
    predictor = (
        cached_predictor(takes, [b for _, b in ranges], args.steps) if args.predictor and not args.network else None
    )
    gen = MatchingStream(db, cfg, predictor)
    rows = []
    for take, (a, b) in zip(takes, evals):
        for k in range(args.starts):
            if args.network:
                pose, jumps = run_network(args.network, take, a, b, lead_in=min(a, 15 * k))
            else:
                pose, jumps = run(gen, take, a, b, predictor, lead_in=min(a, 15 * k))
            rows.append(figures(take, pose, a, b, real_train, jumps, speaker))
    keys = [k for k in rows[0] if k not in ("take", "frames")]
    pooled = {k: float(np.nanmean([r[k] for r in rows])) for k in keys}
    json.dump({"config": cfg.as_dict(), "weights": db.weights, "rows": rows, "mean": pooled}, sys.stdout, indent=1)
    print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
