"""Training of the "offline decoding" ablation (:mod:`facecapges.model.offline`).

Same data, budget and objective as the closed-loop trainer
(:mod:`facecapges.training.train`), only the decoding paradigm differs:

* Segments: the same :class:`~facecapges.training.train.SegmentSet` — L = 34 frames,
  stride 10, frames < ``holdout_from`` for training and ≥ it for the held-out losses;
  each segment frame's encoder input is its own causal window, as in the full model.
* Seed and mask: the first N = 16 real poses of a segment are given as seed poses
  (mask bit 1); the pose slot of the other M = 18 frames is zero (mask bit 0). The
  bidirectional decoder outputs all L frames in one pass — no rollout, no feedback of
  its own predictions, LSTM state zero at every segment.
* Losses on the M = 18 frames after the seed only (the same frames the closed-loop
  trainer generates): Huber β = 0.1 on pose, velocity and acceleration
  (:func:`~facecapges.training.train.reconstruction_losses`), weights ``w_rec``,
  ``w_vel``, ``w_acc`` of the :class:`TrainConfig`; the same
  :class:`~facecapges.model.network.SegmentDiscriminator` on those M frames with the
  non-saturating loss, weight ``w_adv``, from ``adv_start_epoch`` on; D and G updated
  alternately by :func:`~facecapges.training.train.make_optimizer` at lr_g and
  lr_d = ``d_lr_ratio``·lr_g; gradient clipping ``grad_clip``; output heads start at
  the training mean pose; data order seeded by epoch. Batch size, epochs, optimizer
  and seeds come from the same :class:`TrainConfig`.
* Single process, no resume (the ablation trains it in one go); the run folder gets
  ``model.safetensors`` (:func:`facecapges.model.offline.save_offline`), ``log.csv``
  (one line per epoch, the same columns as the closed-loop trainer) and
  ``summary.json``. The metadata keeps the cold-start ``neutral_window`` chosen exactly
  as the closed-loop trainer chooses it, so both are seeded alike at evaluation.
"""

from __future__ import annotations

import csv
import json
import math
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from facecapges.errors import UserError
from facecapges.model.config import ModelConfig, TrainConfig, model_config_from_dict, to_dict, train_config_from_dict
from facecapges.model.network import SegmentDiscriminator
from facecapges.model.offline import OfflineDecoder, save_offline
from facecapges.training.train import (ClipArrays, SegmentSet, make_optimizer, neutral_window, reconstruction_losses,
                                       segment_sets, start_heads_at_mean)

LOG_FIELDS = ["epoch", "total", "rec", "vel", "acc", "adv", "d", "held_rec", "held_vel", "held_acc", "seconds"]


def offline_batch(model: OfflineDecoder, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """Decoded (B, M, D) and real (B, M, D) poses of the frames after the N-frame seed."""
    N = model.cfg.n_history
    z = model.encode(batch["audio"], batch["face"], batch["head"])[:, N:]  # (B, L, E), own causal windows
    out = model.decode(z, batch["pose"][:, :N])  # (B, L, D)
    return out[:, N:], batch["pose"][:, N:]


class OfflineTrainer:
    """Trains :class:`OfflineDecoder` with the closed-loop trainer's recipe (module docs)."""

    def __init__(self, clips: list[ClipArrays], out: Path, model_cfg: ModelConfig, train_cfg: TrainConfig,
                 meta: dict, log=print):
        self.out, self.mcfg, self.tcfg, self.meta, self.log = Path(out), model_cfg, train_cfg, meta, log
        if train_cfg.num_threads:
            torch.set_num_threads(train_cfg.num_threads)
        torch.manual_seed(train_cfg.seed)
        self.G = OfflineDecoder(model_cfg)
        self.D = SegmentDiscriminator(model_cfg)
        self.train_set, self.held_set = segment_sets(clips, model_cfg, train_cfg)
        self.neutral = neutral_window(clips, model_cfg.n_history, train_cfg.holdout_from)
        start_heads_at_mean(self.G.head_t, self.G.head_u, self.train_set, model_cfg)
        self.opt_g = make_optimizer(self.G, train_cfg, train_cfg.lr_g())
        self.opt_d = make_optimizer(self.D, train_cfg, train_cfg.lr_d())
        self.epoch = 0
        self.history: list[dict] = []

    def train_epoch(self, epoch: int) -> dict:
        t = self.tcfg
        self.G.train()
        self.D.train()
        rng = np.random.default_rng(t.seed * 100_003 + epoch)
        torch.manual_seed(t.seed * 100_003 + epoch)
        order = rng.permutation(len(self.train_set))
        n_batches = math.ceil(len(order) / t.batch_size)
        adv_on = t.w_adv > 0 and epoch >= t.adv_start_epoch
        sums: dict[str, float] = {}
        for b in range(n_batches):
            batch = self.train_set.gather(order[b * t.batch_size:(b + 1) * t.batch_size])
            gen, gt = offline_batch(self.G, batch)
            logs: dict[str, float] = {}
            if adv_on:  # D on the generated frames only, as in the closed-loop trainer
                d_out = self.D(torch.cat([gt, gen.detach()]))
                d_real, d_fake = d_out[: len(gt)], d_out[len(gt):]
                loss_d = F.binary_cross_entropy_with_logits(d_real, torch.ones_like(d_real)) + \
                    F.binary_cross_entropy_with_logits(d_fake, torch.zeros_like(d_fake))
                self.opt_d.zero_grad(set_to_none=True)
                loss_d.backward()
                self.opt_d.step()
                logs["d"] = loss_d.item()
            rec = reconstruction_losses(gen, gt, t.huber_beta)
            loss = t.w_rec * rec["rec"] + t.w_vel * rec["vel"] + t.w_acc * rec["acc"]
            if adv_on:
                self.D.requires_grad_(False)
                d_gen = self.D(gen)
                self.D.requires_grad_(True)
                adv = F.binary_cross_entropy_with_logits(d_gen, torch.ones_like(d_gen))
                loss = loss + t.w_adv * adv
                logs["adv"] = adv.item()
            self.opt_g.zero_grad(set_to_none=True)
            loss.backward()
            if t.grad_clip > 0:
                torch.nn.utils.clip_grad_norm_(self.G.parameters(), t.grad_clip)
            self.opt_g.step()
            logs.update({k: v.item() for k, v in rec.items()}, total=loss.item())
            if not math.isfinite(logs["total"]):
                raise UserError(f"offline-decoding training diverged at epoch {epoch} (loss {logs['total']})")
            for k, v in logs.items():
                sums[k] = sums.get(k, 0.0) + v
        return {k: v / n_batches for k, v in sums.items()}

    @torch.no_grad()
    def evaluate(self, seg_set: SegmentSet, batch_size: int = 256) -> dict:
        """Mean reconstruction losses on the M frames after the seed (eval mode)."""
        self.G.eval()
        sums = {"rec": 0.0, "vel": 0.0, "acc": 0.0}
        idx = np.arange(len(seg_set))
        for b in range(0, len(idx), batch_size):
            chunk = idx[b:b + batch_size]
            gen, gt = offline_batch(self.G, seg_set.gather(chunk))
            for k, v in reconstruction_losses(gen, gt, self.tcfg.huber_beta).items():
                sums[k] += v.item() * len(chunk)
        return {k: v / len(idx) for k, v in sums.items()}

    def export(self, path: Path) -> Path:
        last = self.history[-1] if self.history else {}
        meta = dict(self.meta, variant="offline decoding", neutral_window=self.neutral.tolist(),
                    train_config=to_dict(self.tcfg), epochs_trained=self.epoch,
                    final_losses={k: v for k, v in last.items() if k != "epoch"})
        return save_offline(path, self.G, meta)

    def fit(self, epochs: int | None = None, progress: bool = True) -> list[dict]:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        total = epochs or self.tcfg.epochs
        self.out.mkdir(parents=True, exist_ok=True)
        log_path = self.out / "log.csv"
        with log_path.open("w", newline="") as f:
            csv.DictWriter(f, fieldnames=LOG_FIELDS).writeheader()
        with Progress(TextColumn("[bold]train offline"), BarColumn(), MofNCompleteColumn(),
                      TextColumn("{task.fields[info]}"), TimeRemainingColumn(), disable=not progress) as bar:
            task = bar.add_task("epochs", total=total, info="")
            while self.epoch < total:
                epoch = self.epoch + 1
                t0 = time.perf_counter()
                row = {"epoch": epoch, **self.train_epoch(epoch)}
                if self.held_set is not None:
                    row.update({f"held_{k}": v for k, v in self.evaluate(self.held_set).items()})
                row["seconds"] = round(time.perf_counter() - t0, 3)
                self.epoch = epoch
                self.history.append(row)
                with log_path.open("a", newline="") as f:
                    csv.DictWriter(f, fieldnames=LOG_FIELDS, extrasaction="ignore").writerow(row)
                info = f"loss {row['total']:.3f} rec {row['rec']:.4f}"
                if "held_rec" in row:
                    info += f" held {row['held_rec']:.4f}"
                bar.update(task, completed=epoch, info=info)
        self.export(self.out / "model.safetensors")
        (self.out / "summary.json").write_text(json.dumps(self.history[-1] if self.history else {}, indent=2))
        return self.history


def build_offline_trainer(clips: list[ClipArrays], out: Path, model_over: dict, train_over: dict,
                          meta: dict) -> OfflineTrainer:
    """An offline-decoding trainer from the same override dicts as ``build_trainer``."""
    return OfflineTrainer(clips, out, model_config_from_dict(model_over), train_config_from_dict(train_over), meta)
