"""Closed-loop sliding-window training (thesis ch. 4, 5.1).

* Segments: every clip is cut into L = 34-frame segments with stride 10 (eq. 4.1);
  the first N = 16 frames are ground-truth warm-up (eq. 4.5), the other M = 18 are
  generated (eq. 4.6). A segment's encoder inputs reach N frames further back (each
  frame's own causal window); before a clip's start they are zero, exactly as the
  streaming generator sees the start of a stream.
* Rollout: :meth:`FaceCapGes.rollout`, batched over segments — each of the M steps is
  one batched call that writes its prediction back into the history (4.1.2–4.1.3);
  LSTM states start at zero and are carried (4.1.4).
* Losses on the M generated frames only: Huber (β = 0.1, eq. 4.15 — which equals
  ``smooth_l1_loss(beta=β)``) on pose, velocity and acceleration, weights
  500/1000/1000 (4.2.4), plus the non-saturating adversarial loss of a segment
  discriminator (eq. 4.22–4.23), weight 0.1, from epoch 11; D and G updated
  alternately, each by SGD, lr_g = 2.5e-4·B/128 and lr_d = 0.2·lr_g (eq. 5.1–5.2).
* Held-out frames (``holdout_from``): segments are taken from frames < F for
  training and from frames ≥ F (warm-up included) for the held-out losses logged
  every epoch.
* Every epoch writes ``RUN/last.pt`` (full state) atomically; ``resume`` continues
  exactly (data order and dropout are seeded by epoch). ``RUN/log.csv`` has one line
  per epoch; ``RUN/model.safetensors`` is the inference checkpoint of the last epoch.
"""

from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from facecapges.errors import UserError
from facecapges.model.checkpoint import save_checkpoint
from facecapges.model.config import ModelConfig, TrainConfig, model_config_from_dict, to_dict, train_config_from_dict
from facecapges.model.network import FaceCapGes, SegmentDiscriminator
from facecapges.timing import frame_audio


# ------------------------------------------------------------------------ data
@dataclass
class ClipArrays:
    """One recording's model inputs and targets at the model rate."""

    name: str
    pose: np.ndarray  # (T, 47, 6)
    head: np.ndarray  # (T, 6)
    face: np.ndarray  # (T, 52)
    audio: np.ndarray  # (S,) 16 kHz


class SegmentSet:
    """All clips concatenated (each preceded by N zero frames) + segment start indices.

    ``gather(idx)`` returns batched tensors for segments ``idx``: inputs of
    N + L frames (each segment frame's causal window) and the L poses.
    """

    def __init__(self, clips: list[ClipArrays], cfg: ModelConfig, clip_len: int, stride: int,
                 frame_range: tuple[int, int | None] = (0, None)):
        N = cfg.n_history
        self.N, self.L = N, clip_len
        audio, face, head, pose, starts = [], [], [], [], []
        offset = 0
        for c in clips:
            T = len(c.pose)
            lo, hi = frame_range[0], T if frame_range[1] is None else min(frame_range[1], T)
            a = frame_audio(c.audio, T, cfg.fps, cfg.sr)
            pad = lambda x: np.concatenate([np.zeros((N,) + x.shape[1:], np.float32), x.astype(np.float32)])
            audio.append(pad(a))
            face.append(pad(c.face))
            head.append(pad(c.head))
            pose.append(pad(c.pose.reshape(T, -1)))
            for s in range(lo, hi - clip_len + 1, stride):
                starts.append(offset + N + s)  # index of the segment's first frame
            offset += T + N
        if not starts:
            raise UserError(f"no {clip_len}-frame segment fits in the selected frames of {len(clips)} clip(s)")
        self.audio = np.concatenate(audio)
        self.face = np.concatenate(face)
        self.head = np.concatenate(head)
        self.pose = np.concatenate(pose)
        self.starts = np.array(starts)

    def __len__(self) -> int:
        return len(self.starts)

    def gather(self, idx: np.ndarray) -> dict[str, torch.Tensor]:
        s = self.starts[idx]
        win = s[:, None] + np.arange(-self.N, self.L)[None]  # (B, N + L)
        seg = s[:, None] + np.arange(self.L)[None]
        return {"audio": torch.from_numpy(self.audio[win]), "face": torch.from_numpy(self.face[win]),
                "head": torch.from_numpy(self.head[win]), "pose": torch.from_numpy(self.pose[seg])}


def encode_segments(model: FaceCapGes, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """Embeddings (B, L, E) of the segment frames, each from its own causal window."""
    z = model.encode(batch["audio"], batch["face"], batch["head"])
    return z[:, model.cfg.n_history:]


# ----------------------------------------------------------------------- losses
def huber(x: torch.Tensor, y: torch.Tensor, beta: float) -> torch.Tensor:
    """β·SmoothL1(X/β, X̂/β) of eq. 4.15 (identical to smooth_l1_loss with beta=β)."""
    return F.smooth_l1_loss(x, y, beta=beta)


def reconstruction_losses(gen: torch.Tensor, gt: torch.Tensor, beta: float) -> dict[str, torch.Tensor]:
    """Pose, velocity and acceleration Huber losses (eq. 4.16, 4.19, 4.20) over (B, M, D)."""
    vg, vt = gen[:, 1:] - gen[:, :-1], gt[:, 1:] - gt[:, :-1]
    return {"rec": huber(gen, gt, beta), "vel": huber(vg, vt, beta),
            "acc": huber(vg[:, 1:] - vg[:, :-1], vt[:, 1:] - vt[:, :-1], beta)}


def rollout_batch(model: FaceCapGes, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """Generated (B, M, D) and ground-truth (B, M, D) poses of a batch of segments."""
    N = model.cfg.n_history
    z = encode_segments(model, batch)
    gen = model.rollout(z, batch["pose"][:, :N])
    return gen, batch["pose"][:, N:]


# ---------------------------------------------------------------------- trainer
def neutral_window(clips: list[ClipArrays], n: int, frame_limit: int | None) -> np.ndarray:
    """The calmest real N-frame window of the training frames (least pose motion)."""
    best, best_e = None, math.inf
    for c in clips:
        T = len(c.pose) if frame_limit is None else min(frame_limit, len(c.pose))
        if T < n:
            continue
        v = np.abs(np.diff(c.pose[:T].reshape(T, -1), axis=0)).sum(1)  # (T-1,)
        energy = np.convolve(v, np.ones(n - 1), mode="valid")  # motion inside each window
        i = int(np.argmin(energy))
        if energy[i] < best_e:
            best, best_e = c.pose[i:i + n], energy[i]
    if best is None:
        raise UserError(f"no clip has the {n} frames needed for a cold-start window")
    return best.astype(np.float32)


class Trainer:
    def __init__(self, clips: list[ClipArrays], out: Path, model_cfg: ModelConfig, train_cfg: TrainConfig,
                 meta: dict, log=print):
        self.out, self.mcfg, self.tcfg, self.meta, self.log = Path(out), model_cfg, train_cfg, meta, log
        if train_cfg.num_threads:
            torch.set_num_threads(train_cfg.num_threads)
        torch.manual_seed(train_cfg.seed)
        self.G = FaceCapGes(model_cfg)
        self.D = SegmentDiscriminator(model_cfg)
        N, F_ = model_cfg.n_history, train_cfg.holdout_from
        self.train_set = SegmentSet(clips, model_cfg, train_cfg.clip_len, train_cfg.stride, (0, F_))
        self.held_set = None
        if F_ is not None:
            try:
                self.held_set = SegmentSet(clips, model_cfg, train_cfg.clip_len, train_cfg.stride, (F_, None))
            except UserError:
                self.held_set = None
        self.neutral = neutral_window(clips, N, F_)
        # start the output heads at the training mean pose: the first rollouts are sane
        mean = torch.from_numpy(self.train_set.pose.reshape(-1, model_cfg.pose_dim)[self.train_set.pose.any(1)]
                                .mean(0))
        with torch.no_grad():
            self.G.decoder.head_t[-1].bias.copy_(mean[: model_cfg.n_torso * 6])
            self.G.decoder.head_u[-1].bias.copy_(mean[model_cfg.n_torso * 6:])
        self.opt_g = torch.optim.SGD(self.G.parameters(), lr=train_cfg.lr_g(), momentum=train_cfg.momentum)
        self.opt_d = torch.optim.SGD(self.D.parameters(), lr=train_cfg.lr_d(), momentum=train_cfg.momentum)
        self.epoch = 0  # epochs completed
        self.history: list[dict] = []

    # ------------------------------------------------------------- state
    def state_dict(self) -> dict:
        return {"G": self.G.state_dict(), "D": self.D.state_dict(), "opt_g": self.opt_g.state_dict(),
                "opt_d": self.opt_d.state_dict(), "epoch": self.epoch, "history": self.history,
                "model_config": to_dict(self.mcfg), "train_config": to_dict(self.tcfg), "meta": self.meta,
                "neutral": self.neutral}

    def load_state_dict(self, sd: dict) -> None:
        self.G.load_state_dict(sd["G"])
        self.D.load_state_dict(sd["D"])
        self.opt_g.load_state_dict(sd["opt_g"])
        self.opt_d.load_state_dict(sd["opt_d"])
        self.epoch, self.history = int(sd["epoch"]), list(sd["history"])

    def save(self) -> None:
        self.out.mkdir(parents=True, exist_ok=True)
        tmp = self.out / "last.pt.part"
        torch.save(self.state_dict(), tmp)
        tmp.replace(self.out / "last.pt")
        self.export(self.out / "model.safetensors")

    def export(self, path: Path) -> Path:
        last = self.history[-1] if self.history else {}
        meta = dict(self.meta, neutral_window=self.neutral.tolist(), train_config=to_dict(self.tcfg),
                    epochs_trained=self.epoch, final_losses={k: v for k, v in last.items() if k != "epoch"})
        return save_checkpoint(path, self.G, meta)

    # -------------------------------------------------------------- loop
    def _adv_on(self, epoch: int) -> bool:
        return self.tcfg.w_adv > 0 and epoch >= self.tcfg.adv_start_epoch

    def train_epoch(self, epoch: int, progress=None) -> dict:
        """One epoch (1-based ``epoch``); returns mean losses."""
        t = self.tcfg
        self.G.train()
        self.D.train()
        rng = np.random.default_rng(t.seed * 100_003 + epoch)
        torch.manual_seed(t.seed * 100_003 + epoch)
        order = rng.permutation(len(self.train_set))
        n_batches = math.ceil(len(order) / t.batch_size)
        sums: dict[str, float] = {}
        for b in range(n_batches):
            batch = self.train_set.gather(order[b * t.batch_size:(b + 1) * t.batch_size])
            gen, gt = rollout_batch(self.G, batch)
            logs = {}
            if self._adv_on(epoch):  # D step on the generated frames only (4.3.1)
                d_real, d_fake = self.D(gt), self.D(gen.detach())
                loss_d = F.binary_cross_entropy_with_logits(d_real, torch.ones_like(d_real)) + \
                    F.binary_cross_entropy_with_logits(d_fake, torch.zeros_like(d_fake))  # eq. 4.22
                self.opt_d.zero_grad(set_to_none=True)
                loss_d.backward()
                self.opt_d.step()
                logs["d"] = loss_d.item()
            rec = reconstruction_losses(gen, gt, t.huber_beta)
            loss = t.w_rec * rec["rec"] + t.w_vel * rec["vel"] + t.w_acc * rec["acc"]  # eq. 4.14
            if self._adv_on(epoch):
                d_gen = self.D(gen)
                adv = F.binary_cross_entropy_with_logits(d_gen, torch.ones_like(d_gen))  # eq. 4.23
                loss = loss + t.w_adv * adv
                logs["adv"] = adv.item()
            self.opt_g.zero_grad(set_to_none=True)
            loss.backward()
            if t.grad_clip > 0:
                torch.nn.utils.clip_grad_norm_(self.G.parameters(), t.grad_clip)
            self.opt_g.step()
            logs.update({k: v.item() for k, v in rec.items()}, total=loss.item())
            if not math.isfinite(logs["total"]):
                raise UserError(f"training diverged at epoch {epoch} (loss {logs['total']}); lower the learning rate")
            for k, v in logs.items():
                sums[k] = sums.get(k, 0.0) + v
            if progress is not None:
                progress(b + 1, n_batches, logs)
        return {k: v / n_batches for k, v in sums.items()}

    @torch.no_grad()
    def evaluate(self, seg_set: SegmentSet, batch_size: int = 256) -> dict:
        """Mean reconstruction losses of a segment set (eval mode, closed loop)."""
        self.G.eval()
        sums = {"rec": 0.0, "vel": 0.0, "acc": 0.0}
        n = 0
        for b in range(0, len(seg_set), batch_size):
            idx = np.arange(b, min(b + batch_size, len(seg_set)))
            gen, gt = rollout_batch(self.G, seg_set.gather(idx))
            for k, v in reconstruction_losses(gen, gt, self.tcfg.huber_beta).items():
                sums[k] += v.item() * len(idx)
            n += len(idx)
        return {k: v / n for k, v in sums.items()}

    def fit(self, epochs: int | None = None) -> list[dict]:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        total = epochs or self.tcfg.epochs
        log_path = self.out / "log.csv"
        fields = ["epoch", "total", "rec", "vel", "acc", "adv", "d", "held_rec", "held_vel", "held_acc", "seconds"]
        self.out.mkdir(parents=True, exist_ok=True)
        with Progress(TextColumn("[bold]train"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[info]}"),
                      TimeRemainingColumn(), transient=False) as bar:
            task = bar.add_task("epochs", total=total, completed=self.epoch, info="")
            while self.epoch < total:
                epoch = self.epoch + 1
                t0 = time.perf_counter()
                row = {"epoch": epoch, **self.train_epoch(epoch)}
                if self.held_set is not None:
                    row.update({f"held_{k}": v for k, v in self.evaluate(self.held_set).items()})
                row["seconds"] = round(time.perf_counter() - t0, 3)
                self.epoch = epoch
                self.history.append(row)
                self.save()
                new = not log_path.exists() or epoch == 1
                with log_path.open("w" if new else "a", newline="") as f:
                    w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
                    if new:
                        w.writeheader()
                    w.writerow(row)
                info = f"loss {row['total']:.3f} rec {row['rec']:.4f}"
                if "held_rec" in row:
                    info += f" held {row['held_rec']:.4f}"
                bar.update(task, completed=epoch, info=info)
        (self.out / "summary.json").write_text(json.dumps(self.history[-1] if self.history else {}, indent=2))
        return self.history


def load_resume(out: Path) -> dict:
    p = Path(out) / "last.pt"
    if not p.is_file():
        raise UserError(f"{p}: nothing to resume (no last.pt in the run folder)")
    try:
        return torch.load(p, map_location="cpu", weights_only=False)
    except Exception as exc:  # a corrupt or foreign file
        raise UserError(f"{p}: cannot read the training state ({exc.__class__.__name__})") from None


def build_trainer(clips: list[ClipArrays], out: Path, model_over: dict, train_over: dict, meta: dict,
                  resume: bool) -> Trainer:
    if resume:
        sd = load_resume(out)
        mcfg = model_config_from_dict(sd["model_config"])
        tdict = dict(sd["train_config"], **{k: v for k, v in train_over.items() if k == "epochs"})
        tr = Trainer(clips, out, mcfg, train_config_from_dict(tdict), sd["meta"])
        tr.load_state_dict(sd)
        return tr
    mcfg = model_config_from_dict(model_over)
    tcfg = train_config_from_dict(train_over)
    return Trainer(clips, out, mcfg, tcfg, meta)
