"""The figures of the packaged FGD autoencoder's card (src/facecapges/assets/fgd/beat-upper-body/README.md).

    python scripts/fgd_card_figures.py --cache CACHE [--fgd DIR] --out card.json

On the prepared cache of BEAT speaker 2's two paired takes (scripts/train-fgd-autoencoder.sh makes it):
each take's first 80 % (frames before its ``holdout_from``: what the autoencoder trained on) and its last
20 % (held out, never seen). Per region:

* reconstruction error (eq. 5.4's MSE of rot6d values, and the mean angle between each joint's
  reconstructed and real rotation, degrees) on the training windows and on the held-out windows;
* FGD (eq. 5.3) against the training frames of: the held-out real frames (should be small), and three
  controls that should be far: the held-out frames shuffled in time, the mean training pose held still
  (a 1e-3 jitter keeps its covariance finite), and the held-out frames plus Gaussian noise (sd 0.1 in
  rot6d, about 6°).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    from facecapges import rotations as rot

    Ra, Rb = rot.rot6d_to_matrix(a), rot.rot6d_to_matrix(b)
    tr = np.einsum("...ij,...ij->...", Ra, Rb)  # trace(Raᵀ Rb)
    return float(np.degrees(np.arccos(np.clip((tr - 1) / 2, -1, 1))).mean())


def main() -> None:
    import torch

    from facecapges.data.cache import Cache
    from facecapges.evaluation.fgd import load_fgd, make_windows, packaged_fgd_dir, reconstruction_loss
    from facecapges.evaluation.regions import region_indices

    ap = argparse.ArgumentParser()
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--fgd", type=Path, default=None)
    ap.add_argument("--speaker", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    fgd_dir = args.fgd or packaged_fgd_dir()
    ev = load_fgd(fgd_dir)
    c = Cache(args.cache)
    train, held = [], []
    for e in c.clips(speaker=args.speaker):
        pose = c.load(e["name"])["pose"].astype(np.float32)
        h = int(e["holdout_from"])
        train.append(pose[:h])
        held.append(pose[h:])
    rng = np.random.default_rng(args.seed)
    mean_pose = np.concatenate(train).mean(0)
    still = [np.broadcast_to(mean_pose, x.shape) + rng.normal(0, 1e-3, x.shape).astype(np.float32) for x in held]
    shuffled = [x[rng.permutation(len(x))] for x in held]
    noisy = [x + rng.normal(0, 0.1, x.shape).astype(np.float32) for x in held]
    out: dict = {
        "fgd": str(fgd_dir),
        "cache": str(args.cache),
        "train_frames": [len(x) for x in train],
        "heldout_frames": [len(x) for x in held],
        "regions": {},
    }
    cfg = ev.config
    for region, model in ev.models.items():
        idx = region_indices(region)
        rec = {}
        for name, clips in (("train", train), ("heldout", held)):
            w = torch.from_numpy(make_windows([x[:, idx] for x in clips], cfg.window, cfg.window))
            with torch.no_grad():
                r = model(w)
            rec[name] = {
                "windows": len(w),
                "mse": float(torch.mean((r - w) ** 2)),
                "loss_eq_5_4": float(reconstruction_loss(r, w, cfg.lambda_pos, cfg.lambda_vel)),
                "angle_deg": _angle_deg(r.numpy(), w.numpy()),
            }
        fgd = {
            name: ev.fgd(train, clips, region)
            for name, clips in (
                ("heldout_real", held),
                ("shuffled_heldout", shuffled),
                ("still_mean_pose", still),
                ("noisy_heldout", noisy),
            )
        }
        out["regions"][region] = {
            "reconstruction": rec,
            "fgd_vs_train": fgd,
            "final_train_loss": ev.history.loss.get(region, [None])[-1],
        }
        print(region, json.dumps(out["regions"][region]))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
