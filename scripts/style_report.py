"""Figures of a style's model card, on data it never trained on.

    python scripts/style_report.py --checkpoint RUN/model.safetensors --cache CACHE --speaker S \
        [--audio unseen.wav ...] --out report.json

* Paired takes: each take of the speaker from its first held-out frame on (the cache
  entry's ``holdout_from``, the last 20 %; or ``--holdout-from F`` for every take). The
  style runs from a cold start on the held-out inputs (head mapped into its camera
  frame). Per take, for the real and the generated motion: energy–wrist-speed
  correlation and its z against shifted audio, BeatAlign and its gap against shifted
  audio (in sd units), wrist jerk and spread as ratios to the real held-out motion;
  and the same for the style given the take's audio with the head held still
  (``generated_still_head``: the input an audio file without a head track gives it).
* All paired takes together: their energy–speed z and BeatAlign-gap z combined by
  Stouffer's method (:func:`facecapges.evaluation.synchrony.stouffer_z`).
* Unseen audio (no motion): the same figures, ratios to the real motion of the
  speaker's training frames (frames before each take's hold-out).
All metric code is :mod:`facecapges.evaluation.synchrony` and
:mod:`facecapges.evaluation.beat_align` (what ``facecapges eval`` reports).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np


def _row(skel, pose, audio, sr, fps, ref_stats):
    from facecapges.evaluation.beat_align import beat_align_control
    from facecapges.evaluation.synchrony import beat_align_gap_sd, synchrony_row, wrist_positions

    row = synchrony_row(wrist_positions(skel, pose), audio, sr, fps, ref_stats)
    ba = beat_align_control(pose, audio, sr, fps)
    row.update(BA=ba.matched, BA_gap=ba.matched - ba.shifted_mean, BA_gap_sd=beat_align_gap_sd(ba))
    return {k: (round(float(v), 4) if isinstance(v, (float, np.floating)) else v) for k, v in row.items()}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--checkpoint", type=Path, required=True)
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--speaker", type=int, required=True)
    ap.add_argument("--holdout-from", type=int)
    ap.add_argument("--until-frame", type=int, help="cut every take here first (a validation split's end)")
    ap.add_argument("--validation", action="store_true",
                    help="report on recipe_choice.py's validation part instead: each take cut at 80 %%, its last 20 %%")
    ap.add_argument("--audio", type=Path, action="append", default=[])
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()

    from facecapges.data.cache import Cache
    from facecapges.evaluation.run import heldout_inputs
    from facecapges.evaluation.synchrony import motion_stats, pooled_stats, wrist_positions
    from facecapges.model.checkpoint import load_checkpoint
    from facecapges.model.generate import generate_poses, prepare_inputs
    from facecapges.rotations import identity_rot6d

    ck = load_checkpoint(args.checkpoint)
    skel, fps, sr = ck.skeleton, ck.fps, ck.model.cfg.sr
    cache = Cache(args.cache)
    ref = ck.meta.get("head_reference_rot6d")
    out = {"checkpoint": str(args.checkpoint), "paired": {}, "unseen": {}}
    train_stats = []
    for e in cache.select(args.speaker, "all"):
        a = cache.load(e["name"])
        until = int(len(a["pose"]) * 0.8) if args.validation else args.until_frame
        if until:
            from facecapges.timing import frame_sample_bounds

            S = int(frame_sample_bounds(until, fps, sr)[0])
            a = {k: (v[:S] if k == "audio" else v[:until]) if k in ("pose", "head", "face", "audio")
                 else v for k, v in a.items()}
        if args.validation:
            start = int(len(a["pose"]) * 0.8)
        else:
            start = args.holdout_from or e.get("holdout_from") or int(len(a["pose"]) * 0.8)
        train_stats.append(motion_stats(wrist_positions(skel, a["pose"][:start]), fps))
        real, audio, inputs = heldout_inputs(a, start, fps, sr, ref)
        gen, _ = generate_poses(ck, inputs, progress=False)
        # the same audio with the head at rest (what an audio file without a head track gives)
        still = dataclasses.replace(inputs, head=np.broadcast_to(identity_rot6d(), inputs.head.shape).copy())
        gen_still, _ = generate_poses(ck, still, progress=False)
        real_stats = motion_stats(wrist_positions(skel, real), fps)
        out["paired"][e["name"]] = {"from_frame": int(start), "frames": len(real),
                                    "real": _row(skel, real, audio, sr, fps, real_stats),
                                    "generated": _row(skel, gen, audio, sr, fps, real_stats),
                                    "generated_still_head": _row(skel, gen_still, audio, sr, fps, real_stats)}
        print(e["name"], json.dumps(out["paired"][e["name"]]["generated"]))
    from facecapges.evaluation.synchrony import stouffer_z

    takes = out["paired"].values()
    out["paired_combined"] = {  # the takes' z-scores combined (Stouffer): all held-out audio as one test
        who: {k: round(stouffer_z([t[who][k] for t in takes]), 4) for k in ("ES_z", "BA_gap_sd")}
        for who in ("real", "generated")
    } if out["paired"] else {}
    print("combined", json.dumps(out["paired_combined"]))
    pooled = pooled_stats(train_stats)
    for p in args.audio:
        from facecapges.io.audio import load_audio

        inputs = prepare_inputs(p, fps=fps)
        gen, _ = generate_poses(ck, inputs, progress=False)
        out["unseen"][p.name] = _row(skel, gen, load_audio(p, sr), sr, fps, pooled)
        print(p.name, json.dumps(out["unseen"][p.name]))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
