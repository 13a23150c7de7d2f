"""Issue #38's figures of a style: the conversation test set and its held-out stretches.

    PYTHONPATH=src python scripts/conversation_report.py --checkpoint STYLE.safetensors [--shared ../shared/data] \
        [--validation] --out conversation.json

* His real motion (the training frames [0, 0.8 T) of both paired takes, BEAT 2_scott_0_1_1 and BEAT2
  2_scott_0_2_2) gives the :class:`facecapges.evaluation.conversation.Reference`.
* Held-out stretches: each take's last 20 % (``--validation``: [0.64 T, 0.8 T) instead, the reference then
  from [0, 0.64 T)) run from a cold start on its audio and face with the head at rest (no face track),
  scored against his real motion of the same frames: pops a minute, both-hands share, wrist height,
  head speed and torso sway as ratios to the real stretch, wrist spread and jerk ratios; at intensity
  1 and 1.3.
* The conversation clips (:func:`facecapges.evaluation.conversation.make_clips`) at intensity 1 and the
  unseen zeros clip at 1.3; per clip :func:`~facecapges.evaluation.conversation.score`; and the VAD's
  frame accuracy on them (the engine's :class:`facecapges.matching.speech.SpeechTracker` against the truth).
* Repetition with mirrored copies counted as the same stretch
  (:func:`facecapges.evaluation.realism.repetition` with ``same_as``, returns within 60 s) on the
  unseen clips laid end to end, and the wrist spread at intensity 0, 0.5, 1, 1.3 (monotone?).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", type=Path, required=True)
    ap.add_argument("--shared", type=Path, default=Path("../shared/data"))
    ap.add_argument("--validation", action="store_true")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--quick", action="store_true", help="held-out zeros and unseen zeros/room tone only")
    args = ap.parse_args(argv)

    from facecapges import timing
    from facecapges.evaluation import conversation as cv
    from facecapges.evaluation import realism as rz
    from facecapges.evaluation import synchrony as sy
    from facecapges.matching.database import mirror_twins
    from facecapges.matching.speech import speech_track
    from facecapges.matching.takes import load_take
    from facecapges.model.checkpoint import load_checkpoint

    fps, sr, spf = timing.MODEL_FPS, timing.AUDIO_SR, timing.samples_per_frame()
    ck = load_checkpoint(args.checkpoint)
    beat = args.shared / "beat"
    t1 = load_take(beat / "2_scott_0_1_1.bvh", beat / "2_scott_0_1_1.wav")
    t2 = load_take(args.shared / "beat2" / "2_scott_0_2_2.npz", beat / "2_scott_0_2_2.wav", t1.skeleton)
    skel = ck.skeleton
    takes = [t1, t2]
    if args.validation:
        cuts = [(int(0.64 * t.n_frames), t.train_until) for t in takes]
    else:
        cuts = [(t.train_until, t.n_frames) for t in takes]
    train = [t.pose[: a] for t, (a, _) in zip(takes, cuts)]
    ref = cv.reference(skel, train, [t.audio[: a * spf] for t, (a, _) in zip(takes, cuts)])
    out: dict = {"checkpoint": str(args.checkpoint), "reference": ref.as_dict(), "heldout": {}, "clips": {}}
    db = ck.database_poses()
    if db is not None:
        database, same_as = [np.asarray(db)], mirror_twins(ck.db)
    else:  # the network: his training frames and their mirror images
        from facecapges.data.mirror import mirror_pose

        flat = np.concatenate(train)
        database, same_as = [np.concatenate([flat, mirror_pose(flat)])], np.r_[np.arange(len(flat)), np.arange(len(flat))]

    def rnd(d):
        return {k: (round(float(v), 4) if isinstance(v, (float, np.floating)) else v) for k, v in d.items()}

    heldout_audio = []
    for t, (a, b) in zip(takes, cuts):
        real = t.pose[a:b]
        audio = t.audio[a * spf : b * spf]
        heldout_audio.append((t.name, audio))
        row = {}
        for inten in (1.0, 1.3):
            gen = cv.generate(ck, audio, inten, face=t.face[a:b])
            wg, wr = sy.wrist_positions(skel, gen), sy.wrist_positions(skel, real)
            real_ref = cv.reference(skel, [real], [audio])
            sc = cv.score(skel, gen, np.zeros(len(gen), bool), ref)
            key = f"intensity {inten:g}"
            row[key] = rnd({
                "pops_per_min": sc.pops_speech_per_min,
                "spread_ratio": sy.ratio(sy.wrist_spread(wg), sy.wrist_spread(wr)),
                "jerk_ratio": sy.ratio(sy.wrist_jerk(wg, fps), sy.wrist_jerk(wr, fps)),
                "both_hands": sc.both_hands,
                "both_hands_real": real_ref.both_hands,
                "wrist_height_ratio": float(np.mean((wg[:, :, 1] - ref.rest_height).mean(1)) /
                                            np.mean((wr[:, :, 1] - ref.rest_height).mean(1))),
                "head_speed_ratio": cv.head_speed_deg_s(skel, gen) / cv.head_speed_deg_s(skel, real),
                "head_speed_deg_s": cv.head_speed_deg_s(skel, gen),
                "head_speed_real_deg_s": cv.head_speed_deg_s(skel, real),
                "torso_sway_ratio": cv.torso_sway_deg(skel, gen) / cv.torso_sway_deg(skel, real),
                "still_share": sc.still_share,
                "pops_real_per_min": rz.transitions(real, train, fps, threshold=ref.threshold).per_minute,
            })
        out["heldout"][t.name] = row
        print(t.name, json.dumps(row), flush=True)

    clips = cv.make_clips(args.shared, heldout_audio)
    if args.quick:
        clips = [c for c in clips if c.kind == "zeros" or c.name == "unseen-room_tone"]
    gens = {}
    for c in clips:
        gen = cv.generate(ck, c.audio, 1.0)
        gens[c.name] = gen
        sc = cv.score(skel, gen, c.pause, ref).as_dict()
        sc.pop("pops")
        sc.pop("name")
        vad = speech_track(c.audio, c.n_frames).speaking
        sc["vad_pause_as_pause"] = float((~vad[c.pause]).mean()) if c.pause.any() else None
        sc["vad_speech_as_speech"] = float(vad[c.speech].mean()) if c.speech.any() else None
        out["clips"][c.name] = sc
        print(c.name, json.dumps(sc), flush=True)
    z = next(c for c in clips if c.name == "unseen-zeros")
    sc13 = cv.score(skel, cv.generate(ck, z.audio, 1.3), z.pause, ref).as_dict()
    sc13.pop("pops")
    out["clips"]["unseen-zeros @1.3"] = sc13
    print("unseen-zeros @1.3", json.dumps(sc13), flush=True)
    uns = [gens[k] for k in gens if k.startswith("unseen")]
    rep = rz.repetition(uns, database, fps, within_s=60.0, same_as=same_as)
    rep_plain = rz.repetition(uns, database, fps, within_s=60.0)
    out["repetition"] = {"with_mirrors": rnd(rep.as_dict()), "without_mirrors": rnd(rep_plain.as_dict())}
    print("repetition", json.dumps(out["repetition"]), flush=True)
    spreads = {}
    u = next(c for c in clips if c.name == "unseen-zeros")
    for inten in (0.0, 0.5, 1.0, 1.3):
        g = cv.generate(ck, u.audio, inten)
        spreads[f"{inten:g}"] = round(sy.wrist_spread(sy.wrist_positions(skel, g[~u.pause])), 3)
    out["spread_by_intensity"] = spreads
    print("spread by intensity", spreads, flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
