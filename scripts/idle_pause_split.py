"""Why a style's pauses keep moving: its idle layer's measured amplitudes and one pause split by component.

For a matching style (a file or an installed name): per joint the procedural idle's amplitude (°) and frequency
(Hz) as measured from its rest runs *without* the wrist bound, the idle's wrist speed without / with the bound
against the rest runs' own (``IdleMotion.wrist_speed``); then one clip — ``--seconds`` of ``--wav`` from ``--start``
(use the style's own training speech, never the held-out or unseen clips) followed by 15 s of digital zeros —
generated with the idle layer on, at amplitude 0 (the rest frame alone) and off (the matched motion underneath),
and the wrist speed in the pause (cm/s; his idle level from his training frames, the settle rule's).

    PYTHONPATH=src python scripts/idle_pause_split.py /tmp/vstyle/vid11x.safetensors --wav /tmp/vstyle/train11.wav

Results: docs/capture-body.md, "Pauses that settle".
"""

from __future__ import annotations

import argparse
import dataclasses as dc
from pathlib import Path

import numpy as np

from facecapges import timing
from facecapges.evaluation import conversation as cv
from facecapges.evaluation import synchrony as sy
from facecapges.io.audio import load_audio
from facecapges.matching.idle import IDLE_JOINTS, _wrist_speed, rest_runs
from facecapges.matching.matcher import BatchedMatchingStreams
from facecapges.matching.takes import load_take
from facecapges.styles import load_style

FPS = float(timing.MODEL_FPS)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("style")
    ap.add_argument("--wav", type=Path, required=True)
    ap.add_argument("--start", type=float, default=30.0)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--shared", type=Path, default=Path("../shared/data"))
    args = ap.parse_args()
    sr, spf = timing.AUDIO_SR, timing.samples_per_frame()
    beat = args.shared / "beat"
    t1 = load_take(beat / "2_scott_0_1_1.bvh", beat / "2_scott_0_1_1.wav")
    t2 = load_take(args.shared / "beat2" / "2_scott_0_2_2.npz", beat / "2_scott_0_2_2.wav", t1.skeleton)
    takes = (t1, t2)
    ref = cv.reference(
        t1.skeleton, [t.pose[: t.train_until] for t in takes], [t.audio[: t.train_until * spf] for t in takes]
    )
    ck = load_style(args.style) if Path(args.style).exists() else load_style(style=args.style)
    skel = ck.skeleton
    plain = BatchedMatchingStreams(ck.db, ck.config, ck.predictor, capacity=1)  # no skeleton: no wrist bound
    bounded = ck.batched(1)
    assert plain.idle_layer is not None and bounded.idle_layer is not None, "the style's idle layer is off"
    mo = plain.idle_layer.motion
    print(f"{args.style}: {len(ck.db)} rows, {len(mo.rest)} rest poses")
    for j in ("Spine", "RightShoulder", "RightArm", "RightForeArm", "RightHand"):
        k = IDLE_JOINTS.index(j)
        print(f"  {j:14s} amplitude ° {np.round(np.degrees(mo.amplitude[k]), 2)}  Hz {np.round(mo.frequency[k], 2)}")
    rest = plain.idle & (ck.db.phase == 0)
    runs = rest_runs(ck.db.segment, rest)
    rows_speed = np.mean(np.concatenate([_wrist_speed(skel, plain.row_quaternions[r], FPS) for r in runs]))
    print(
        f"  wrist speed (cm/s): rest runs {rows_speed:.2f}; the idle at amplitude 1 "
        f"{mo.wrist_speed(skel, FPS):.2f} unbounded, {bounded.idle_layer.motion.wrist_speed(skel, FPS):.2f} bounded"
    )
    a = load_audio(args.wav, sr)
    i0 = int(args.start * sr)
    audio = np.r_[a[i0 : i0 + int(args.seconds * sr)], np.zeros(15 * sr)].astype(np.float32)
    T = len(audio) // spf
    pause = np.zeros(T, bool)
    pause[int(args.seconds * FPS) :] = True
    print(
        f"  pause of {pause.sum() / FPS:.0f} s after {args.seconds:g} s of {args.wav.name}; his idle level {ref.idle_speed:.2f} cm/s"
    )
    for label, kw, engine in (
        ("idle on (bounded)", {}, ck),
        ("idle amplitude 0", {"idle_amplitude": 0.0}, ck),
        ("idle layer off", {"idle_layer": False}, ck),
    ):
        g = cv.generate(dc.replace(engine, config=dc.replace(engine.config, **kw)), audio, 1.0)
        s = cv.wrist_speed(sy.wrist_positions(skel, g), FPS)
        sc = cv.score(skel, g, pause, ref)
        late = s[int((args.seconds + 2) * FPS) :]
        print(
            f"  {label:18s} pause mean {s[pause].mean():.2f}, median 2 s on {np.median(late):.2f} cm/s; "
            f"settle {sc.settle_s:.1f} s; pause/speech {sc.pause_over_speech_speed:.2f}"
        )


if __name__ == "__main__":
    main()
