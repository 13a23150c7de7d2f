"""Issue #38's figures of a style: the conversation test set and its held-out stretches.

    PYTHONPATH=src python scripts/conversation_report.py --checkpoint STYLE.safetensors [--shared ../shared/data] \
        [--validation] --out conversation.json
    python scripts/conversation_report.py --table LABEL=conversation.json [LABEL=…]   # Markdown for a card

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
* The wrist spread on the whole unseen take (``2_scott_0_4_4.wav``) at intensity 1 over his real motion's
  (the whole 1_1 BVH; his training frames of both takes).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def _f(x, fmt: str = "{:.2f}") -> str:
    return "–" if x is None or (isinstance(x, float) and x != x) else fmt.format(x)


def _settle(c: dict) -> str:
    """Settle by the trailing 1-s rule, and by the rule that looks ahead (``settle_ahead_s``) where reported."""
    ahead = c.get("settle_ahead_s")
    return _f(c["settle_s"], "{:.1f}") + ("" if ahead is None else f" ({_f(ahead, '{:.1f}')})")


def table(reports: list[tuple[str, dict]]) -> list[str]:
    """The model card's conversation section: one row per style and clip, then held-out stretches."""
    out = [
        "| style | clip | pops/min pause | pops/min speech | wrist speed pause/speech | still share (longest s) | "
        "both hands | wrist height × his | head speed × his | torso sway × his | settle s (ahead) | resume s | "
        "VAD: pause heard as pause | speech as speech |",
        "|---|---|" + "---|" * 12,
        "| target | | ≤ 1 | ≤ 1 | < 1 (idle) | low, < 2 s | his ±20 % | 0.8–1.2 | ≈ his (0.83) | ≈ his (0.75) | ≤ 1 | ≤ 0.3 | "
        "high | high |",
    ]
    for label, r in reports:
        for name, c in r["clips"].items():
            out.append(
                f"| {label} | {name} | {_f(c['pops_pause_per_min'], '{:.1f}')} | {_f(c['pops_speech_per_min'], '{:.1f}')} | "
                f"{_f(c['pause_over_speech_speed'])} | {_f(c['still_share'])} ({_f(c['longest_still_s'], '{:.1f}')}) | "
                f"{_f(c['both_hands'])} | {_f(c['wrist_height_ratio'])} | {_f(c['head_speed_ratio'])} | "
                f"{_f(c['torso_sway_ratio'])} | {_settle(c)} | {_f(c['resume_s'], '{:.2f}')} | "
                f"{_f(c.get('vad_pause_as_pause'))} | {_f(c.get('vad_speech_as_speech'))} |"
            )
    out += [
        "",
        "| style | held-out stretch | intensity | pops/min (his) | spread × his | jerk × his | both hands (his) | "
        "wrist height × his | head speed × his (°/s) | torso sway × his |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for label, r in reports:
        for take, rows in r["heldout"].items():
            for inten, h in rows.items():
                out.append(
                    f"| {label} | {take} | {inten.split()[-1]} | {_f(h['pops_per_min'], '{:.1f}')} "
                    f"({_f(h['pops_real_per_min'], '{:.1f}')}) | {_f(h['spread_ratio'])} | {_f(h['jerk_ratio'])} | "
                    f"{_f(h['both_hands'])} ({_f(h['both_hands_real'])}) | {_f(h['wrist_height_ratio'])} | "
                    f"{_f(h['head_speed_ratio'])} ({_f(h['head_speed_deg_s'], '{:.0f}')} vs "
                    f"{_f(h['head_speed_real_deg_s'], '{:.0f}')}) | {_f(h['torso_sway_ratio'])} |"
                )
    out += ["", "| style | repetition on the unseen clips | returns in 60 s (mirrors counted / not) | longest copy s | "
            "database used | spread at intensity 0 / 0.5 / 1 / 1.3 (cm) | unseen 0_4_4 spread × his (1_1 whole / training) |",
            "|---|---|---|---|---|---|---|"]
    for label, r in reports:
        m, p = r["repetition"]["with_mirrors"], r["repetition"]["without_mirrors"]
        sp = " / ".join(_f(v, "{:.1f}") for v in r["spread_by_intensity"].values())
        u = r.get("unseen_spread", {})
        us = f"{_f(u.get('over_1_1_whole'))} / {_f(u.get('over_training_frames'))}"
        out.append(f"| {label} | {_f(m['copied_share'])} of frames copied | {m['returns']} / {p['returns']} | "
                   f"{_f(m['longest_copy_s'], '{:.1f}')} | {_f(m['database_share_used'])} | {sp} | {us} |")
    return out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--table":
        reps = [(lab, json.loads(Path(p).read_text())) for lab, p in (a.split("=", 1) for a in argv[1:])]
        print("\n".join(table(reps)))
        return 0
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
    from facecapges.styles import load_style

    fps, spf = timing.MODEL_FPS, timing.samples_per_frame()
    ck = load_style(args.checkpoint)
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
            sc = cv.score(skel, gen, np.zeros(len(gen), bool), ref)
            fig = cv.stretch_figures(skel, gen, real, ref, fps)  # his figures by the same rule as the engine's
            key = f"intensity {inten:g}"
            row[key] = rnd({
                "pops_per_min": sc.pops_speech_per_min,
                **{k: fig[k] for k in ("spread_ratio", "jerk_ratio", "both_hands", "both_hands_real",
                                       "wrist_height_ratio", "head_speed_ratio", "head_speed_deg_s",
                                       "head_speed_real_deg_s", "torso_sway_ratio")},
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
        sc = cv.score(skel, gen, c.pause, ref, words=cv.word_frames(c.audio, len(gen), c.pause)).as_dict()
        sc.pop("pops")
        sc.pop("name")
        vad = speech_track(c.audio, c.n_frames).speaking
        sc["vad_pause_as_pause"] = float((~vad[c.pause]).mean()) if c.pause.any() else None
        sc["vad_speech_as_speech"] = float(vad[c.speech].mean()) if c.speech.any() else None
        out["clips"][c.name] = sc
        print(c.name, json.dumps(sc), flush=True)
    z = next(c for c in clips if c.name == "unseen-zeros")
    z13 = cv.generate(ck, z.audio, 1.3)
    sc13 = cv.score(skel, z13, z.pause, ref, words=cv.word_frames(z.audio, len(z13), z.pause)).as_dict()
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
    # the whole unseen take (2_scott_0_4_4.wav, 67 s, no pause inserted) at intensity 1: the wrist spread over
    # his real motion's — the whole 1_1 BVH (as docs/capture-body.md first measured it) and his training frames
    from facecapges.io.audio import load_audio

    g = cv.generate(ck, load_audio(beat / "2_scott_0_4_4.wav", timing.AUDIO_SR), 1.0)
    s_gen = sy.wrist_spread(sy.wrist_positions(skel, g))
    out["unseen_spread"] = {
        "over_1_1_whole": round(s_gen / sy.wrist_spread(sy.wrist_positions(skel, t1.pose)), 3),
        "over_training_frames": round(s_gen / sy.wrist_spread(sy.wrist_positions(skel, np.concatenate(train))), 3),
    }
    print("unseen 2_scott_0_4_4 spread over his", out["unseen_spread"], flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
