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
* Issue #25 §3 (``realism``, :mod:`facecapges.evaluation.realism`), per take, for all takes'
  held-out frames together and per unseen audio: transitions against the training frames'
  acceleration, repetition against the engine's database (a matching style's own, else the
  training frames), the silence ratio, and the real-vs-generated classifier against the
  held-out real windows beside its control (held-out real vs the training frames).
* ``extra``: FGD against the training frames (the style's own autoencoder, else the package's:
  :func:`facecapges.evaluation.fgd.find_fgd`) and the onset timing of :mod:`facecapges.evaluation.timing`,
  for the real held-out motion and the style's (head held still; unseen speech: the style's only).
All metric code is :mod:`facecapges.evaluation.synchrony` and
:mod:`facecapges.evaluation.beat_align` and :mod:`facecapges.evaluation.realism` (what
``facecapges eval`` reports). The style runs through ``ckpt.streaming()`` (any engine).
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


def _realism(rows_in, skel, fps, sr, heldout, training, database, db_source, seed=0):
    """Issue #25 §3's figures (:func:`facecapges.evaluation.realism.realism_row`) of several methods' clips,
    with the classifier's real-vs-real control (held-out real against the training frames)."""
    from facecapges.evaluation.realism import real_vs_real_control, realism_row

    def rnd(v):  # NaN (e.g. no pause to measure) → null: the file stays standard JSON
        if isinstance(v, (float, np.floating)):
            return round(float(v), 4) if np.isfinite(v) else None
        return v

    out = {}
    for name, (clips, audios, classify) in rows_in.items():
        row = realism_row(clips, audios, sr, fps, skel, heldout, training, database, classify, seed)
        out[name] = {k: rnd(v) for k, v in row.items()}
    ctl = real_vs_real_control(heldout, training, fps, skel, seed=seed)
    out["control"] = {"classifier": rnd(ctl.accuracy), "classifier_sd": rnd(ctl.sd),
                      "classifier_windows": ctl.n_windows, "what": "held-out real vs the training frames"}
    out["database"] = {"source": db_source, "frames": sum(len(d) for d in database) if database else None}
    return out


def _round(v):
    return (round(float(v), 4) if np.isfinite(v) else None) if isinstance(v, (float, np.floating)) else v


def _takes(cache, args, fps, sr):
    """Each take of the speaker, cut as the options say, with its first held-out frame."""
    from facecapges.timing import frame_sample_bounds

    takes = []
    for e in cache.select(args.speaker, "all"):
        a = cache.load(e["name"])
        until = int(len(a["pose"]) * 0.8) if args.validation else args.until_frame
        if until:
            S = int(frame_sample_bounds(until, fps, sr)[0])
            a = {k: (v[:S] if k == "audio" else v[:until]) if k in ("pose", "head", "face", "audio")
                 else v for k, v in a.items()}
        if args.validation:
            start = int(len(a["pose"]) * 0.8)
        else:
            start = args.holdout_from or e.get("holdout_from") or int(len(a["pose"]) * 0.8)
        takes.append((e["name"], a, int(start)))
    return takes


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
    from facecapges.engine.generate import generate_poses
    from facecapges.evaluation.fgd import find_fgd, load_fgd
    from facecapges.evaluation.run import engine_database, heldout_inputs
    from facecapges.evaluation.synchrony import motion_stats, pooled_stats, stouffer_z, wrist_positions
    from facecapges.evaluation.timing import timing_row
    from facecapges.rotations import identity_rot6d
    from facecapges.styles import load_style
    from facecapges.timing import AUDIO_SR

    ck = load_style(args.checkpoint)
    skel, fps = ck.skeleton, ck.fps
    sr = int(ck.meta.get("model_config", {}).get("sr", AUDIO_SR))
    cache = Cache(args.cache)
    ref = ck.meta.get("head_reference_rot6d")
    out = {"checkpoint": str(args.checkpoint), "paired": {}, "unseen": {}}
    takes = _takes(cache, args, fps, sr)
    training = [a["pose"][:start] for _, a, start in takes]
    database, db_source = engine_database(ck, training)
    fgd_loc, out["fgd_autoencoder"] = find_fgd(args.checkpoint)  # the style's own, else the package's
    fgd = load_fgd(fgd_loc) if fgd_loc is not None else None

    def extra(clips, audios):  # FGD against the training frames and the onset timing (evaluation.timing)
        f = {"FGD": round(fgd.fgd(training, clips, "with_head"), 4)} if fgd is not None else {}
        return {**f, **{k: _round(v) for k, v in timing_row(clips, audios, sr, fps, skel).items()}}

    train_stats = [motion_stats(wrist_positions(skel, t), fps) for t in training]
    heldout, pooled_gen = [], ([], [])
    for name, a, start in takes:
        real, audio, inputs = heldout_inputs(a, start, fps, sr, ref)
        gen, _ = generate_poses(ck, inputs, progress=False)
        # the same audio with the head at rest (what an audio file without a head track gives)
        still = dataclasses.replace(inputs, head=np.broadcast_to(identity_rot6d(), inputs.head.shape).copy())
        gen_still, _ = generate_poses(ck, still, progress=False)
        real_stats = motion_stats(wrist_positions(skel, real), fps)
        out["paired"][name] = {"from_frame": int(start), "frames": len(real),
                               "real": _row(skel, real, audio, sr, fps, real_stats),
                               "generated": _row(skel, gen, audio, sr, fps, real_stats),
                               "generated_still_head": _row(skel, gen_still, audio, sr, fps, real_stats)}
        rows = {"real": ([real], [audio], False), "generated": ([gen], [audio], True),
                "generated_still_head": ([gen_still], [audio], True)}
        out["paired"][name]["realism"] = _realism(rows, skel, fps, sr, [real], training, database, db_source)
        out["paired"][name]["extra"] = {"real": extra([real], [audio]), "generated": extra([gen_still], [audio])}
        heldout.append(real)
        pooled_gen[0].append(gen)
        pooled_gen[1].append(audio)
        print(name, json.dumps(out["paired"][name]["generated"]))
        print(name, "realism", json.dumps(out["paired"][name]["realism"]["generated"]))

    takes_out = out["paired"].values()
    out["paired_combined"] = {  # the takes' z-scores combined (Stouffer): all held-out audio as one test
        who: {k: round(stouffer_z([t[who][k] for t in takes_out]), 4) for k in ("ES_z", "BA_gap_sd")}
        for who in ("real", "generated")
    } if out["paired"] else {}
    if heldout:  # every take's held-out frames together: one transitions/repetition/classifier figure
        rows = {"generated": (pooled_gen[0], pooled_gen[1], True)}
        out["paired_combined"]["realism"] = _realism(rows, skel, fps, sr, heldout, training, database, db_source)
        out["paired_combined"]["extra"] = {"real": extra(heldout, pooled_gen[1]),
                                           "generated": extra(pooled_gen[0], pooled_gen[1])}
    print("combined", json.dumps(out["paired_combined"]))
    pooled = pooled_stats(train_stats)
    for p in args.audio:
        from facecapges.io.audio import load_audio

        inputs = ck.prepare_inputs(p)
        gen, _ = generate_poses(ck, inputs, progress=False)
        wav = load_audio(p, sr)
        out["unseen"][p.name] = _row(skel, gen, wav, sr, fps, pooled)
        out["unseen"][p.name]["extra"] = {"generated": extra([gen], [wav])}
        if heldout:  # ratios to the training frames; the classifier against the held-out real windows
            rows = {"generated": ([gen], [wav], True)}
            out["unseen"][p.name]["realism"] = _realism(rows, skel, fps, sr, heldout, training, database, db_source)
        print(p.name, json.dumps(out["unseen"][p.name]))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
