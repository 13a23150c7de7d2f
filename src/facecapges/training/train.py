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
* Many processes (``torchrun --nproc_per_node=K facecapges …`` or multi-node):
  :mod:`facecapges.training.distributed` joins the process group; each rank trains
  its strided share of every global batch (``batch_size`` per process × K), the
  generator's rollout (:class:`RolloutModule`) and the discriminator are wrapped in
  DistributedDataParallel, the learning rates scale with the global batch, and only
  rank 0 writes the run folder. ``last.pt`` holds CPU tensors and no process count,
  so a run resumes with any K. ``amp`` = float16 mixed precision on GPU.
"""

from __future__ import annotations

import contextlib
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
from facecapges.training.distributed import DistContext
from facecapges.training.masking import discriminator_view, masked_reconstruction_losses, mirrored
from facecapges.training.resume_file import RunFolderLock, load_state, save_state, write_log
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
    mask: np.ndarray | None = None  # (47,) or (T, 47) bool: joints with real motion (None: all)


class SegmentSet:
    """All clips concatenated (each preceded by N zero frames) + segment start indices.

    ``gather(idx)`` returns batched tensors for segments ``idx``: inputs of
    N + L frames (each segment frame's causal window) and the L poses.
    """

    def __init__(self, clips: list[ClipArrays], cfg: ModelConfig, clip_len: int, stride: int,
                 frame_range: tuple[int, int | None] = (0, None)):
        N = cfg.n_history
        self.N, self.L = N, clip_len
        audio, face, head, pose, starts, mask = [], [], [], [], [], []
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
            m = np.ones(c.pose.shape[1], bool) if c.mask is None else np.asarray(c.mask, bool)
            mask.append(pad(np.broadcast_to(m, (T, c.pose.shape[1]))))
            for s in range(lo, hi - clip_len + 1, stride):
                starts.append(offset + N + s)  # index of the segment's first frame
            offset += T + N
        if not starts:
            raise UserError(f"no {clip_len}-frame segment fits in the selected frames of {len(clips)} clip(s)")
        self.audio = np.concatenate(audio)
        self.face = np.concatenate(face)
        self.head = np.concatenate(head)
        self.pose = np.concatenate(pose)
        self.mask = np.concatenate(mask)  # (frames, 47) float32, 1 = joint present
        self.starts = np.array(starts)

    def __len__(self) -> int:
        return len(self.starts)

    def gather(self, idx: np.ndarray) -> dict[str, torch.Tensor]:
        s = self.starts[idx]
        win = s[:, None] + np.arange(-self.N, self.L)[None]  # (B, N + L)
        seg = s[:, None] + np.arange(self.L)[None]
        return {"audio": torch.from_numpy(self.audio[win]), "face": torch.from_numpy(self.face[win]),
                "head": torch.from_numpy(self.head[win]), "pose": torch.from_numpy(self.pose[seg]),
                "mask": torch.from_numpy(self.mask[seg])}


def encode_segments(model: FaceCapGes, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """Embeddings (B, L, E) of the segment frames, each from its own causal window."""
    z = model.encode(batch["audio"], batch["face"], batch["head"])
    return z[:, model.cfg.n_history:]


# ----------------------------------------------------------------------- losses
def huber(x: torch.Tensor, y: torch.Tensor, beta: float) -> torch.Tensor:
    """β·SmoothL1(X/β, X̂/β) of eq. 4.15 (identical to smooth_l1_loss with beta=β)."""
    return F.smooth_l1_loss(x, y, beta=beta)


def reconstruction_losses(gen: torch.Tensor, gt: torch.Tensor, beta: float) -> dict[str, torch.Tensor]:
    """Pose, velocity and acceleration Huber losses (eq. 4.16, 4.19, 4.20) over (B, M, D), every joint counted."""
    return masked_reconstruction_losses(gen, gt, beta, None)


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


def segment_sets(clips: list[ClipArrays], mcfg: ModelConfig, tcfg: TrainConfig
                 ) -> tuple[SegmentSet, SegmentSet | None]:
    """Training segments (frames < holdout_from) and held-out ones (frames ≥ it, or None)."""
    F_ = tcfg.holdout_from
    train_clips = clips + [mirrored(c) for c in clips] if getattr(tcfg, "mirror", False) else clips
    train_set = SegmentSet(train_clips, mcfg, tcfg.clip_len, tcfg.stride, (0, F_))
    held_set = None
    if F_ is not None:
        try:
            held_set = SegmentSet(clips, mcfg, tcfg.clip_len, tcfg.stride, (F_, None))
        except UserError:  # too few held-out frames for one segment
            held_set = None
    return train_set, held_set


def start_heads_at_mean(head_t: torch.nn.Sequential, head_u: torch.nn.Sequential, train_set: SegmentSet,
                        mcfg: ModelConfig) -> None:
    """Start the output heads at the training mean pose, so the first rollouts are sane."""
    real = train_set.pose.any(1)  # the zero frames padding each clip are not poses
    mean = torch.from_numpy(train_set.pose.reshape(-1, mcfg.pose_dim)[real].mean(0))
    with torch.no_grad():
        head_t[-1].bias.copy_(mean[: mcfg.n_torso * 6])
        head_u[-1].bias.copy_(mean[mcfg.n_torso * 6:])


def make_optimizer(module: torch.nn.Module, cfg: TrainConfig, lr: float) -> torch.optim.Optimizer:
    """SGD (thesis 5.1) or Adam, at the linearly scaled learning rate."""
    if cfg.optimizer == "sgd":
        return torch.optim.SGD(module.parameters(), lr=lr, momentum=cfg.momentum)
    if cfg.optimizer == "adam":
        return torch.optim.Adam(module.parameters(), lr=lr, betas=(0.5, 0.999))
    raise UserError(f"unknown optimizer {cfg.optimizer!r} (sgd or adam)")


class RolloutModule(torch.nn.Module):
    """The generator's whole training forward as one call: encode the segments, roll out.

    This is what DistributedDataParallel wraps: the M closed-loop steps call
    ``FaceCapGes.step`` in a Python loop, so wrapping the generator itself would leave
    its ``forward`` unused; through this module one forward covers the rollout and the
    gradients are all-reduced once per backward.
    """

    def __init__(self, generator: FaceCapGes):
        super().__init__()
        self.g = generator

    def forward(self, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        return rollout_batch(self.g, batch)


def scaled_lrs(cfg: TrainConfig, world_size: int) -> tuple[float, float]:
    """(lr_g, lr_d) by the linear rule on the global batch (eq. 5.1–5.2)."""
    lr_g = cfg.lr_base * (cfg.batch_size * world_size) / 128.0
    return lr_g, cfg.d_lr_ratio * lr_g


class _Precision:
    """float16 autocast + a gradient scaler per optimizer on GPU (``amp``); plain float32 otherwise."""

    def __init__(self, amp: bool, device: torch.device):
        self.on = bool(amp) and device.type == "cuda"
        self.device = device
        self.scalers = {k: torch.amp.GradScaler("cuda") for k in ("g", "d")} if self.on else {}

    def autocast(self):
        import contextlib

        if not self.on:
            return contextlib.nullcontext()
        return torch.autocast(device_type="cuda", dtype=torch.float16)

    def backward(self, which: str, loss: torch.Tensor) -> None:
        (self.scalers[which].scale(loss) if self.on else loss).backward()

    def unscale(self, which: str, opt: torch.optim.Optimizer) -> None:
        if self.on:
            self.scalers[which].unscale_(opt)

    def step(self, which: str, opt: torch.optim.Optimizer) -> None:
        if self.on:
            self.scalers[which].step(opt)
            self.scalers[which].update()
        else:
            opt.step()

    def state_dict(self) -> dict:
        return {k: s.state_dict() for k, s in self.scalers.items()}

    def load_state_dict(self, sd: dict) -> None:
        for k, s in self.scalers.items():
            if k in sd:
                s.load_state_dict(sd[k])


class Trainer:
    """Closed-loop trainer; one per process (see :mod:`facecapges.training.distributed`).

    ``dist`` says which rank of how many this process is and on which device it
    trains; only rank 0 writes files and shows progress. ``amp`` turns on float16
    mixed precision on a GPU (no effect on CPU).
    """

    def __init__(self, clips: list[ClipArrays], out: Path, model_cfg: ModelConfig, train_cfg: TrainConfig,
                 meta: dict, log=print, dist: DistContext | None = None, amp: bool = False):
        self.out, self.mcfg, self.tcfg, self.meta, self.log = Path(out), model_cfg, train_cfg, meta, log
        self.dist = dist or DistContext()
        self.device = self.dist.device
        if train_cfg.num_threads:
            torch.set_num_threads(train_cfg.num_threads)
        torch.manual_seed(train_cfg.seed)  # the same initial weights on every rank
        self.G = FaceCapGes(model_cfg)
        self.D = SegmentDiscriminator(model_cfg)
        self.train_set, self.held_set = segment_sets(clips, model_cfg, train_cfg)
        self.neutral = neutral_window(clips, model_cfg.n_history, train_cfg.holdout_from)
        start_heads_at_mean(self.G.decoder.head_t, self.G.decoder.head_u, self.train_set, model_cfg)
        self.G.to(self.device)
        self.D.to(self.device)
        self.precision = _Precision(amp, self.device)
        # what each training forward goes through: DDP wrappers when distributed
        self.G_fwd: torch.nn.Module = RolloutModule(self.G)
        self.D_fwd: torch.nn.Module = self.D
        if self.dist.enabled:
            from torch.nn.parallel import DistributedDataParallel as DDP

            ids = [self.device.index] if self.device.type == "cuda" else None
            self.G_fwd = DDP(self.G_fwd, device_ids=ids)
            self.D_fwd = DDP(self.D, device_ids=ids)
        self.lr_g, self.lr_d = scaled_lrs(train_cfg, self.dist.world_size)
        self.opt_g = make_optimizer(self.G, train_cfg, self.lr_g)
        self.opt_d = make_optimizer(self.D, train_cfg, self.lr_d)
        self.epoch = 0  # epochs completed
        self.history: list[dict] = []

    @property
    def global_batch(self) -> int:
        return self.tcfg.batch_size * self.dist.world_size

    # ------------------------------------------------------------- state
    def state_dict(self) -> dict:
        sd = {"G": self.G.state_dict(), "D": self.D.state_dict(), "opt_g": self.opt_g.state_dict(),
              "opt_d": self.opt_d.state_dict(), "epoch": self.epoch, "history": self.history,
              "model_config": to_dict(self.mcfg), "train_config": to_dict(self.tcfg), "meta": self.meta,
              "neutral": self.neutral, "world_size": self.dist.world_size}
        if self.precision.on:
            sd["grad_scalers"] = self.precision.state_dict()
        return sd

    def load_state_dict(self, sd: dict) -> None:
        self.G.load_state_dict(sd["G"])
        self.D.load_state_dict(sd["D"])
        self.opt_g.load_state_dict(sd["opt_g"])
        self.opt_d.load_state_dict(sd["opt_d"])
        # the learning rates follow this run's global batch (another process count may resume)
        for opt, lr in ((self.opt_g, self.lr_g), (self.opt_d, self.lr_d)):
            for group in opt.param_groups:
                group["lr"] = lr
        if self.precision.on and "grad_scalers" in sd:
            self.precision.load_state_dict(sd["grad_scalers"])
        self.epoch, self.history = int(sd["epoch"]), list(sd["history"])

    def save(self) -> None:
        """last.pt (atomically) and model.safetensors — rank 0 only."""
        if not self.dist.is_main:
            return
        self.out.mkdir(parents=True, exist_ok=True)
        save_state(self.out / "last.pt", self.state_dict())  # data only (facecapges.training.resume_file)
        self.export(self.out / "model.safetensors")

    def export(self, path: Path) -> Path:
        last = self.history[-1] if self.history else {}
        meta = dict(self.meta, neutral_window=self.neutral.tolist(), train_config=to_dict(self.tcfg),
                    epochs_trained=self.epoch, global_batch=self.global_batch,
                    final_losses={k: v for k, v in last.items() if k != "epoch"})
        G = self.G
        if self.device.type != "cpu":
            import copy

            G = copy.deepcopy(self.G).cpu()
        return save_checkpoint(path, G, meta)

    # -------------------------------------------------------------- loop
    def _adv_on(self, epoch: int) -> bool:
        return self.tcfg.w_adv > 0 and epoch >= self.tcfg.adv_start_epoch

    def _gather(self, seg_set: SegmentSet, idx: np.ndarray) -> dict[str, torch.Tensor]:
        batch = seg_set.gather(idx)
        if self.device.type != "cpu":
            batch = {k: v.to(self.device, non_blocking=True) for k, v in batch.items()}
        return batch

    def train_epoch(self, epoch: int, progress=None) -> dict:
        """One epoch (1-based ``epoch``); returns mean losses over the global batches."""
        t, dist, prec = self.tcfg, self.dist, self.precision
        self.G.train()
        self.D.train()
        rng = np.random.default_rng(t.seed * 100_003 + epoch)  # the same order on every rank
        torch.manual_seed(t.seed * 100_003 + epoch + 1_000_003 * dist.rank)  # dropout: own masks per rank
        order = rng.permutation(len(self.train_set))
        gb = self.global_batch
        n_batches = math.ceil(len(order) / gb)
        adv_on = self._adv_on(epoch)
        sums: dict[str, float] = {}
        for b in range(n_batches):
            chunk = order[b * gb:(b + 1) * gb]
            idx = dist.shard(chunk)
            n_local = len(idx)
            # weight: DDP's gradient average becomes the mean over the whole global batch
            weight = n_local * dist.world_size / len(chunk)
            if n_local == 0:  # more ranks than segments left: join the all-reduce with weight 0
                idx = chunk[:1]
            batch = self._gather(self.train_set, idx)
            with prec.autocast():
                gen, gt = self.G_fwd(batch)
            gen = gen.float()
            mask = batch["mask"][:, self.mcfg.n_history:]  # (B, M, 47): masked joints add no loss
            logs: dict[str, torch.Tensor] = {}
            if adv_on:  # D step on the generated frames only (4.3.1), one forward for real + fake
                with prec.autocast():
                    d_out = self.D_fwd(torch.cat([gt, discriminator_view(gen.detach(), gt, mask)])).float()
                d_real, d_fake = d_out[: len(gt)], d_out[len(gt):]
                loss_d = F.binary_cross_entropy_with_logits(d_real, torch.ones_like(d_real)) + \
                    F.binary_cross_entropy_with_logits(d_fake, torch.zeros_like(d_fake))  # eq. 4.22
                self.opt_d.zero_grad(set_to_none=True)
                prec.backward("d", loss_d if weight == 1.0 else loss_d * weight)
                prec.step("d", self.opt_d)
                logs["d"] = loss_d.detach()
            rec = masked_reconstruction_losses(gen, gt, t.huber_beta, mask)
            loss = t.w_rec * rec["rec"] + t.w_vel * rec["vel"] + t.w_acc * rec["acc"]  # eq. 4.14
            if adv_on:
                # the plain D (not its DDP wrapper, frozen): the G step never reduces or keeps D gradients
                self.D.requires_grad_(False)
                with prec.autocast():
                    d_gen = self.D(discriminator_view(gen, gt, mask)).float()
                self.D.requires_grad_(True)
                adv = F.binary_cross_entropy_with_logits(d_gen, torch.ones_like(d_gen))  # eq. 4.23
                loss = loss + t.w_adv * adv
                logs["adv"] = adv.detach()
            self.opt_g.zero_grad(set_to_none=True)
            prec.backward("g", loss if weight == 1.0 else loss * weight)
            if t.grad_clip > 0:
                prec.unscale("g", self.opt_g)
                torch.nn.utils.clip_grad_norm_(self.G.parameters(), t.grad_clip)
            prec.step("g", self.opt_g)
            logs.update({k: v.detach() for k, v in rec.items()}, total=loss.detach())
            keys = list(logs)
            if dist.enabled:  # global-batch means: Σ_ranks n_local·mean_local / n_global
                vals = dist.all_sum([logs[k].item() * n_local for k in keys])
                values = {k: v / len(chunk) for k, v in zip(keys, vals)}
            else:
                values = {k: logs[k].item() for k in keys}
            if not math.isfinite(values["total"]):
                raise UserError(f"training diverged at epoch {epoch} (loss {values['total']}); "
                                "lower the learning rate")
            for k, v in values.items():
                sums[k] = sums.get(k, 0.0) + v
            if progress is not None:
                progress(b + 1, n_batches, values)
        return {k: v / n_batches for k, v in sums.items()}

    @torch.no_grad()
    def evaluate(self, seg_set: SegmentSet, batch_size: int = 256) -> dict:
        """Mean reconstruction losses of a segment set (eval mode, closed loop), shared among ranks."""
        self.G.eval()
        keys = ("rec", "vel", "acc")
        sums = dict.fromkeys(keys, 0.0)
        n = 0
        mine = self.dist.shard(np.arange(len(seg_set)))
        for b in range(0, len(mine), batch_size):
            idx = mine[b:b + batch_size]
            batch = self._gather(seg_set, idx)
            with self.precision.autocast():
                gen, gt = rollout_batch(self.G, batch)
            mask = batch["mask"][:, self.mcfg.n_history:]
            for k, v in masked_reconstruction_losses(gen.float(), gt, self.tcfg.huber_beta, mask).items():
                sums[k] += v.item() * len(idx)
            n += len(idx)
        if self.dist.enabled:
            *vals, n = self.dist.all_sum([sums[k] for k in keys] + [float(n)])
            sums = dict(zip(keys, vals))
        return {k: v / n for k, v in sums.items()}

    def fit(self, epochs: int | None = None) -> list[dict]:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        total = epochs or self.tcfg.epochs
        main = self.dist.is_main
        log_path = self.out / "log.csv"
        fields = ["epoch", "total", "rec", "vel", "acc", "adv", "d", "held_rec", "held_vel", "held_acc", "seconds",
                  "processes", "global_batch"]
        lock = RunFolderLock(self.out) if main else contextlib.nullcontext()  # one training per run folder
        with lock, Progress(TextColumn("[bold]train"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[info]}"),
                      TimeRemainingColumn(), transient=False, disable=not main) as bar:
            if main and self.history:  # a row lost to a kill between last.pt and log.csv comes back
                write_log(log_path, self.history, fields)
            task = bar.add_task("epochs", total=total, completed=self.epoch, info="")
            while self.epoch < total:
                epoch = self.epoch + 1
                t0 = time.perf_counter()
                row = {"epoch": epoch, **self.train_epoch(epoch)}
                if self.held_set is not None:
                    row.update({f"held_{k}": v for k, v in self.evaluate(self.held_set).items()})
                row["seconds"] = round(time.perf_counter() - t0, 3)
                row["processes"], row["global_batch"] = self.dist.world_size, self.global_batch
                self.epoch = epoch
                self.history.append(row)
                if main:
                    self.save()
                    write_log(log_path, self.history, fields)
                info = f"loss {row['total']:.3f} rec {row['rec']:.4f}"
                if "held_rec" in row:
                    info += f" held {row['held_rec']:.4f}"
                bar.update(task, completed=epoch, info=info)
        if main:
            (self.out / "summary.json").write_text(json.dumps(self.history[-1] if self.history else {}, indent=2))
        return self.history


def load_resume(out: Path) -> dict:
    return load_state(Path(out) / "last.pt", required=("G", "D", "opt_g", "opt_d", "epoch", "history",
                                                      "model_config", "train_config", "meta"))


def build_trainer(clips: list[ClipArrays], out: Path, model_over: dict, train_over: dict, meta: dict,
                  resume: bool, state: dict | None = None, dist: DistContext | None = None,
                  amp: bool = False) -> Trainer:
    """A new trainer, or (``resume``) one restored from ``state`` (default: OUT/last.pt)."""
    if resume:
        sd = state if state is not None else load_resume(out)
        mcfg = model_config_from_dict(sd["model_config"])
        tdict = dict(sd["train_config"], **{k: v for k, v in train_over.items() if k == "epochs"})
        tr = Trainer(clips, out, mcfg, train_config_from_dict(tdict), sd["meta"], dist=dist, amp=amp)
        tr.load_state_dict(sd)
        return tr
    mcfg = model_config_from_dict(model_over)
    tcfg = train_config_from_dict(train_over, mcfg)
    return Trainer(clips, out, mcfg, tcfg, meta, dist=dist, amp=amp)
