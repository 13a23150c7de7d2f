"""Reference held-out losses for a run: the mean training pose and the last warm-up pose held.

``python scripts/loss_references.py --cache C --speaker S (--holdout-from F | --holdout-fraction f) [--until-fraction u]``
prints the closed-loop Huber losses (pose, velocity, acceleration; masked joints
excluded) of the two references on the held-out segments, the same segments and
loss the trainer reports as ``held_*``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--speaker", type=int, required=True)
    ap.add_argument("--holdout-from", type=int)
    ap.add_argument("--holdout-fraction", type=float)
    ap.add_argument("--until-fraction", type=float, default=1.0, help="cut every clip to this fraction first")
    args = ap.parse_args()
    from facecapges.network.config import ModelConfig, TrainConfig
    from facecapges.training.masking import masked_reconstruction_losses
    from facecapges.training.segments import clip_head, load_clips, segment_sets

    cache, clips = load_clips(args.cache, args.speaker, "all")
    if args.until_fraction < 1:
        clips = [clip_head(c, int(len(c.pose) * args.until_fraction), cache.fps, cache.sr) for c in clips]
    tcfg = TrainConfig(holdout_from=args.holdout_from, holdout_fraction=args.holdout_fraction)
    mcfg = ModelConfig()
    train, held = segment_sets(clips, mcfg, tcfg)
    real = train.pose.any(1)
    mean = torch.from_numpy(train.pose[real].mean(0))
    b = held.gather(np.arange(len(held)))
    N = mcfg.n_history
    gt, mask = b["pose"][:, N:], b["mask"][:, N:]
    out = {}
    for name, gen in (("mean_pose", mean.expand_as(gt)), ("hold_last_warmup", b["pose"][:, N - 1:N].expand_as(gt))):
        out[name] = {k: round(float(v), 5) for k, v in masked_reconstruction_losses(gen, gt, 0.1, mask).items()}
    out["segments"] = len(held)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
