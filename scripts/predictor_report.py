"""Figures of the motion-matching engine's speech predictor (matching/predictor.py), for its choices and docs.

    PYTHONPATH=src .venv/bin/python scripts/predictor_report.py --data ../shared/data [--audio mel|raw]
        [--steps N] [--seeds 0 1 2] [--heldout] [--out report.json]

Trains a predictor per speaker on the shared takes — speaker 2 (BEAT 2_scott_0_1_1, plus BEAT2
2_scott_0_2_2 when ``facecapges.data.beat2`` exists) and ZEGGS 067_Speech_2_x_1_0 (retargeted at
run time; nothing derived from ZEGGS is written unless ``--out`` is given, and then only figures) —
each with its mirror images, as the engine trains it, and prints the validation figures (inside the
training frames: the only ones choices are made on). ``--heldout`` adds the held-out 20 % figures:
run it once, after the choices.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np


def speaker_takes(data: Path) -> dict[str, list]:
    from facecapges.io.bvh import read_bvh
    from facecapges.matching.takes import load_take

    beat_bvh = data / "beat" / "2_scott_0_1_1.bvh"
    target = read_bvh(beat_bvh).skeleton
    scott = [load_take(beat_bvh, data / "beat" / "2_scott_0_1_1.wav")]
    try:
        import facecapges.data.beat2  # noqa: F401

        scott.append(load_take(data / "beat2" / "2_scott_0_2_2.npz", data / "beat" / "2_scott_0_2_2.wav", target))
    except ImportError:
        pass
    zeggs = [load_take(data / "zeggs" / "067_Speech_2_x_1_0.bvh", data / "zeggs" / "067_Speech_2_x_1_0.wav", target)]
    return {"speaker2": scott, "zeggs": zeggs}


def main() -> None:
    from facecapges.matching.predictor import PredictorSettings
    from facecapges.matching.predictor_training import evaluate_predictor, train_predictor
    from facecapges.matching.takes import mirror_take

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=Path("../shared/data"))
    ap.add_argument("--audio", choices=("mel", "raw"), default=None)
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--speakers", nargs="+", default=["speaker2", "zeggs"])
    ap.add_argument("--set", nargs="*", default=[], help="other PredictorSettings fields, NAME=VALUE")
    ap.add_argument("--heldout", action="store_true", help="also the held-out 20 %% (once, after the choices)")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    s = PredictorSettings()
    over: dict = {} if args.audio is None else {"audio_repr": args.audio}
    if args.steps is not None:
        over["steps"] = args.steps
    for kv in args.set:
        k, v = kv.split("=", 1)
        over[k] = type(getattr(s, k))(v)
    s = replace(s, **over)
    report: dict = {"settings": s.__dict__, "runs": []}
    takes = speaker_takes(args.data)
    for name in args.speakers:
        for seed in args.seeds:
            t0 = time.perf_counter()
            own = takes[name]
            pred = train_predictor(own + [mirror_take(t) for t in own], seed=seed, settings=s)
            run = {"speaker": name, "seed": seed, "train_s": round(time.perf_counter() - t0, 1)}
            run["training"] = pred.config["training"]
            run["validation"] = evaluate_predictor(pred, own, "validation")
            if args.heldout:
                run["heldout"] = evaluate_predictor(pred, own, "heldout")
            report["runs"].append(run)
            print(summary(run), flush=True)
    for line in aggregate(report["runs"]):
        print(line)
    if args.out:
        args.out.write_text(json.dumps(report, indent=1))


def aggregate(runs: list[dict]) -> list[str]:
    """Mean ± sd over seeds, per speaker, part and head input: r and R² (vs the training mean) per target, AUC."""
    lines = []
    for name in dict.fromkeys(r["speaker"] for r in runs):
        own = [r for r in runs if r["speaker"] == name]
        for part in ("validation", "heldout"):
            for which in ("real_head", "head_still"):
                if part not in own[0]:
                    continue
                figs = [r[part][which] for r in own]
                cells = []
                for k in figs[0]["targets"]:
                    r_ = np.array([f["targets"][k]["r"] for f in figs])
                    r2 = np.array([f["targets"][k]["r2_vs_training_mean"] for f in figs])
                    cells.append(f"{k}: r {r_.mean():+.2f}±{r_.std():.2f} R² {r2.mean():+.2f}±{r2.std():.2f}")
                auc = np.array([f["speaking_auc"] for f in figs])
                lines.append(
                    f"{name} {part} {which} ({len(own)} seeds): " + "  ".join(cells) + f"  AUC {auc.mean():.2f}"
                )
    return lines


def summary(run: dict) -> str:
    lines = [f"{run['speaker']} seed {run['seed']}: {run['train_s']} s, {run['training']}"]
    for part in ("validation", "heldout"):
        if part not in run:
            continue
        for which in ("real_head", "head_still"):
            f = run[part][which]
            cells = "  ".join(
                f"{k[6:]}: r {v['r']:+.2f} R² {v['r2']:+.2f}/{v['r2_vs_training_mean']:+.2f}"
                for k, v in f["targets"].items()
            )
            lines.append(f"  {part:10s} {which:10s} {cells}  speaking AUC {f['speaking_auc']:.2f}")
        lines.append(f"  {part} speaking share {run[part]['speaking_share']:.2f}, {run[part]['frames']} frames")
    return "\n".join(lines)


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()
