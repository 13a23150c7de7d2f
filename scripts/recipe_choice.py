"""Recipe choices (optimizer, audio representation) on a validation split *inside* the training frames.

The last 20 % of every paired take is never used for a choice: each clip is cut at
``--train-until`` (default: 80 % of its frames), and of what is left the last
``--val-fraction`` (default 20 %) of each clip is the validation part the trainer reports as
``held_*``. Usage::

    python scripts/recipe_choice.py --cache build/cache-beat --speaker 2 --config configs/X.yaml \
        --out build/choice/X [--set train.optimizer=sgd --set model.audio_repr=mel ...] [--snapshots 40,60,100]

``--snapshots E1,E2,...`` also keeps the model after each of those epochs (OUT/epoch-E.safetensors) in
the one run: the recipes have no learning-rate schedule, so the model after E epochs of a longer run is
the model of an E-epoch run. Score them with ``scripts/style_report.py --validation``.

Writes OUT/log.csv (per-epoch losses) and OUT/choice.json (the validation losses of
the last epoch and the best epoch).
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import yaml


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--speaker", type=int, required=True)
    ap.add_argument("--config", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--train-until", type=float, default=0.8, help="fraction of each clip available at all")
    ap.add_argument("--val-fraction", type=float, default=0.2, help="of that, the validation part")
    ap.add_argument("--set", action="append", default=[], help="section.key=value (YAML value)")
    ap.add_argument("--snapshots", default="", help="comma-separated epochs whose model is kept as OUT/epoch-E")
    args = ap.parse_args()

    from facecapges.network.config import load_config_file
    from facecapges.training.segments import clip_head, load_clips
    from facecapges.training.train import build_trainer

    model_over, train_over = load_config_file(args.config)
    for item in args.set:
        key, value = item.split("=", 1)
        section, name = key.split(".", 1)
        (model_over if section == "model" else train_over)[name] = yaml.safe_load(value)
    cache, clips = load_clips(args.cache, args.speaker, "all")
    cut_clips = [clip_head(c, int(len(c.pose) * args.train_until), cache.fps, cache.sr) for c in clips]
    train_over["holdout_from"] = None  # per clip: frames >= floor(T_cut * (1 - val_fraction)) validate
    train_over["holdout_fraction"] = args.val_fraction
    meta = {"speaker": args.speaker, "clips": [c.name for c in clips], "split": "all",
            "skeleton": cache.index["skeleton"], "cache": str(args.cache), "choice_run": True}
    tr = build_trainer(cut_clips, args.out, model_over, train_over, meta, resume=False)
    for epoch in sorted(int(e) for e in args.snapshots.split(",") if e):
        tr.fit(epochs=epoch)
        shutil.copyfile(args.out / "model.safetensors", args.out / f"epoch-{epoch}.safetensors")
    hist = tr.fit()
    best = min(hist, key=lambda r: r.get("held_rec", float("inf")))
    val = {c.name: [int(len(c.pose) * (1 - args.val_fraction)), len(c.pose)] for c in cut_clips}
    result = {"settings": args.set, "config": str(args.config), "val_frames": val, "last": hist[-1], "best_epoch": best,
              "minutes": sum(r["seconds"] for r in hist) / 60}
    (args.out / "choice.json").write_text(json.dumps(result, indent=2))
    print(json.dumps({k: result[k] for k in ("settings", "minutes")}), hist[-1].get("held_rec"), best.get("held_rec"))


if __name__ == "__main__":
    main()
