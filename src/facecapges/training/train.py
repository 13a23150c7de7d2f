"""Closed-loop sliding-window training (thesis ch. 4, 5.1).

* Segments (:mod:`facecapges.training.segments`): every clip is cut into L = 34-frame segments with stride 10 (eq. 4.1);
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
* Held-out frames (``holdout_from`` F, or ``holdout_fraction`` f: F = floor(T·(1 − f))
  of each clip of T frames, the cache's per-take rule): segments are taken from frames < F for
  training and from frames ≥ F (warm-up included) for the held-out losses logged
  every epoch.
* Head dropout (ours, ``head_dropout``, off by default): a share of the segments get a
  still head ("facing the camera") over their whole window (:func:`hold_head_still`),
  so a style also learns to gesture from the speech alone — what an audio file without
  a head track, or a user who keeps still, gives it at run time.
* Motion amplitude (ours, ``w_amp``, off by default): a loss on how far each generated
  segment swings against the real one, not when (:func:`~facecapges.training.masking.amplitude_loss`;
  logged as ``amp`` / ``held_amp``).
* Every epoch writes ``RUN/last.pt`` (full state) atomically; ``resume`` continues
  exactly (data order and dropout are seeded by epoch). ``RUN/log.csv`` has one line
  per epoch; ``RUN/model.safetensors`` is the inference checkpoint of the last epoch.
* Many processes (``torchrun --nproc_per_node=K facecapges …`` or multi-node):
  :mod:`facecapges.training.distributed` joins the process group; each rank trains
  its strided share of every global batch (``batch_size`` per process × K), the
  generator's training forward (:class:`TrainingForward`) and the discriminator are wrapped in
  DistributedDataParallel, the learning rates scale with the global batch, and only
  rank 0 writes the run folder. ``last.pt`` holds CPU tensors and no process count,
  so a run resumes with any K. ``amp`` = float16 mixed precision on GPU.
* Model variants: the loop above is the one trainer of the project. What differs
  between the closed-loop FaceCapGes generator and the ablation/baseline decoders is a
  :class:`Variant` — how to build the generator, its training forward (generated and
  real poses of a batch of segments), where its output heads are and how it is
  exported. :data:`CLOSED_LOOP` is FaceCapGes; :data:`facecapges.training.bidirectional.BIDIRECTIONAL`
  the offline-decoding ablation. Every variant gets DDP, AMP, resume, the held-out
  losses and the same learning-rate rule (:meth:`TrainConfig.learning_rates`).
"""

from __future__ import annotations

import contextlib
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Generic, TypeVar

import numpy as np
import torch
import torch.nn.functional as F

from facecapges.errors import UserError
from facecapges.network.config import ModelConfig, TrainConfig, model_config_from_dict, to_dict, train_config_from_dict
from facecapges.network.network import FaceCapGes, SegmentDiscriminator, input_standardisation, set_input_statistics
from facecapges.network.style import save_checkpoint
from facecapges.timing import frame_audio, frame_sample_bounds
from facecapges.training.distributed import DistContext
from facecapges.training.masking import discriminator_view, masked_reconstruction_losses
from facecapges.training.resume_file import RunFolderLock, load_state, save_state, write_log
from facecapges.training.segments import ClipArrays, SegmentSet, hold_head_still, holdout_frames, segment_sets


def encode_segments(model: FaceCapGes, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """Embeddings (B, L, E) of the segment frames, each from its own causal window."""
    z = model.encode(batch["audio"], batch["face"], batch["head"])
    return z[:, model.cfg.n_history :]


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
def neutral_window(clips: list[ClipArrays], n: int, frame_limit: int | list[int | None] | None) -> np.ndarray:
    """The calmest real N-frame window of the training frames (least pose motion)."""
    best, best_e = None, math.inf
    limits = frame_limit if isinstance(frame_limit, list) else [frame_limit] * len(clips)
    for c, lim in zip(clips, limits):
        T = len(c.pose) if lim is None else min(lim, len(c.pose))
        if n > T:
            continue
        v = np.abs(np.diff(c.pose[:T].reshape(T, -1), axis=0)).sum(1)  # (T-1,)
        energy = np.convolve(v, np.ones(n - 1), mode="valid")  # motion inside each window
        i = int(np.argmin(energy))
        if energy[i] < best_e:
            best, best_e = c.pose[i : i + n], energy[i]
    if best is None:
        raise UserError(f"no clip has the {n} frames needed for a cold-start window")
    return best.astype(np.float32)


def start_heads_at_mean(
    head_t: torch.nn.Sequential, head_u: torch.nn.Sequential, train_set: SegmentSet, mcfg: ModelConfig
) -> None:
    """Start the output heads at the training mean pose, so the first rollouts are sane."""
    real = train_set.pose.any(1)  # the zero frames padding each clip are not poses
    mean = torch.from_numpy(train_set.pose.reshape(-1, mcfg.pose_dim)[real].mean(0))
    with torch.no_grad():
        head_t[-1].get_parameter("bias").copy_(mean[: mcfg.n_torso * 6])
        head_u[-1].get_parameter("bias").copy_(mean[mcfg.n_torso * 6 :])


def input_statistics(
    clips: list[ClipArrays], mcfg: ModelConfig, tcfg: TrainConfig
) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], dict, np.ndarray | None]:
    """Normalisation of each input from the training frames (< ``holdout_from``) only.

    Returns ({input: (in_mean, in_scale)} for :func:`~facecapges.network.network.set_input_statistics`,
    the metadata saying what the style was trained with, and the head reference
    rotation ``R_ref`` (rot6d) or None). Held-out frames never enter a statistic.

    The head is mapped into the model's camera frame first (``head_to_camera``; the mapping and ``R_ref`` =
    the speaker's mean head rotation are defined in :mod:`facecapges.capture.head_pose`); the rule for each
    input is :func:`~facecapges.network.network.input_standardisation` (shared with the speech predictor).
    """
    from facecapges.capture.head_pose import skeleton_head_to_camera
    from facecapges.network.audio_features import AudioFeatures
    from facecapges.rotations import mean_rotation

    cut = [
        slice(0, len(c.pose) if lim is None else min(lim, len(c.pose)))
        for c, lim in zip(clips, holdout_frames(clips, tcfg))
    ]
    head = np.concatenate([c.head[s] for c, s in zip(clips, cut)]).astype(np.float64)
    face = np.concatenate([c.face[s] for c, s in zip(clips, cut)]).astype(np.float64)
    ref = mean_rotation(head) if tcfg.head_to_camera else None
    if ref is not None:
        head = skeleton_head_to_camera(head, ref).astype(np.float64)
    face_seen = bool(np.abs(face).max() > 0) if len(face) else False
    meta = {
        "face": face_seen,
        "audio": mcfg.audio_repr,
        "head_frame": "camera (speaker's mean head rotation = facing the camera)"
        if ref is not None
        else "skeleton (as in the data)",
    }
    if not tcfg.normalize_inputs:
        return {"face": (np.zeros(mcfg.n_face), np.full(mcfg.n_face, float(face_seen)))}, meta, ref
    audio = [c.audio[: int(frame_sample_bounds(s.stop, mcfg.fps, mcfg.sr)[0])] for c, s in zip(clips, cut)]
    if mcfg.audio_repr == "raw":
        audio_input = np.concatenate(audio)
    else:
        feats = AudioFeatures(mcfg.sr, mcfg.samples_per_frame)
        with torch.no_grad():
            audio_input = np.concatenate(
                [feats(torch.from_numpy(frame_audio(a, s.stop, mcfg.fps, mcfg.sr))).numpy() for a, s in zip(audio, cut)]
            )
    return input_standardisation(head, face, audio_input, mcfg.audio_repr, mcfg.n_face), meta, ref


def load_base_weights(model: torch.nn.Module, source: str, mcfg: ModelConfig) -> None:
    """Fine-tuning (``train.init_from``): ``model`` takes the weights of a trained style.

    ``source`` is a checkpoint file or an installed style's name. Its model settings
    must equal this run's (a clear error names the first that differs); its input
    normalisation buffers are not taken — the trainer sets this speaker's own next.
    """
    from dataclasses import asdict

    from facecapges.network.network import NORM_BUFFERS
    from facecapges.styles import load_style_or_file, network_only

    base = network_only(load_style_or_file(source), "train.init_from")
    theirs, ours = asdict(base.model.cfg), asdict(mcfg)
    diff = [k for k in ours if ours[k] != theirs.get(k)]
    if diff:
        k = diff[0]
        raise UserError(
            f"train.init_from {source!r}: its model.{k} is {theirs.get(k)!r}, this run's is {ours[k]!r} "
            "(fine-tuning needs the same model settings: use the base style's config)"
        )
    if not isinstance(model, FaceCapGes):
        raise UserError(
            f"train.init_from {source!r}: fine-tuning starts a FaceCapGes model, not a {type(model).__name__}"
        )
    weights = {k: v for k, v in base.model.state_dict().items() if k.rsplit(".", 1)[-1] not in NORM_BUFFERS}
    missing, unexpected = model.load_state_dict(weights, strict=False)
    assert not unexpected and all(k.rsplit(".", 1)[-1] in NORM_BUFFERS for k in missing)


def make_optimizer(module: torch.nn.Module, cfg: TrainConfig, lr: float) -> torch.optim.Optimizer:
    """SGD (thesis 5.1) or Adam, at the linearly scaled learning rate."""
    if cfg.optimizer == "sgd":
        return torch.optim.SGD(module.parameters(), lr=lr, momentum=cfg.momentum)
    if cfg.optimizer == "adam":
        return torch.optim.Adam(module.parameters(), lr=lr, betas=(0.5, 0.999))
    raise UserError(f"unknown optimizer {cfg.optimizer!r} (sgd or adam)")


M = TypeVar("M", bound=torch.nn.Module)  # the variant's model class


# the columns of a run's log.csv
LOG_FIELDS = (
    "epoch",
    "total",
    "rec",
    "vel",
    "acc",
    "amp",
    "adv",
    "d",
    "held_rec",
    "held_vel",
    "held_acc",
    "held_amp",
    "seconds",
    "processes",
    "global_batch",
)


@dataclass(frozen=True)
class Variant(Generic[M]):
    """What one kind of generator needs from the trainer (module docs, "Model variants").

    ``build(cfg)`` makes the generator; ``forward(G, batch)`` gives the generated and
    real poses (B, M, J·6) of a batch of segments (:meth:`SegmentSet.gather`);
    ``output_heads(G)`` are its (torso, limbs) output MLPs, started at the training
    mean pose; ``export(path, G, meta)`` writes its inference checkpoint; ``meta`` is
    added to that checkpoint's metadata.
    """

    name: str
    build: Callable[[ModelConfig], M]
    forward: Callable[[M, dict[str, torch.Tensor]], tuple[torch.Tensor, torch.Tensor]]
    output_heads: Callable[[M], tuple[torch.nn.Sequential, torch.nn.Sequential]]
    export: Callable[[Path, M, dict], Path]
    meta: dict = field(default_factory=dict)


CLOSED_LOOP = Variant(
    name="closed-loop",
    build=FaceCapGes,
    forward=rollout_batch,
    output_heads=lambda G: (G.decoder.head_t, G.decoder.head_u),
    export=save_checkpoint,
)


class TrainingForward(torch.nn.Module):
    """A variant's whole training forward as one module call (what DDP wraps).

    The closed-loop rollout calls ``FaceCapGes.step`` M times in a Python loop, so
    wrapping the generator itself would leave its ``forward`` unused; through this
    module one forward covers the batch and the gradients are all-reduced once per
    backward.
    """

    def __init__(self, variant: Variant, generator: torch.nn.Module):
        super().__init__()
        self.variant = variant
        self.g = generator

    def forward(self, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        return self.variant.forward(self.g, batch)


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

    def __init__(
        self,
        clips: list[ClipArrays],
        out: Path,
        model_cfg: ModelConfig,
        train_cfg: TrainConfig,
        meta: dict,
        log=print,
        dist: DistContext | None = None,
        amp: bool = False,
        variant: Variant = CLOSED_LOOP,
    ):
        self.out, self.mcfg, self.tcfg, self.meta, self.log = Path(out), model_cfg, train_cfg, meta, log
        self.variant = variant
        self.dist = dist or DistContext()
        self.device = self.dist.device
        if train_cfg.num_threads:
            torch.set_num_threads(train_cfg.num_threads)
        torch.manual_seed(train_cfg.seed)  # the same initial weights on every rank
        self.G = variant.build(model_cfg)
        self.D = SegmentDiscriminator(model_cfg)
        if train_cfg.init_from:
            load_base_weights(self.G, train_cfg.init_from, model_cfg)
        norms, self.inputs, ref = input_statistics(clips, model_cfg, train_cfg)
        set_input_statistics(self.G, norms)
        self.head_reference = ref
        if ref is not None:  # the model's head input is in the camera frame (capture.head_pose)
            from facecapges.capture.head_pose import skeleton_head_to_camera

            clips = [
                ClipArrays(c.name, c.pose, skeleton_head_to_camera(c.head, ref), c.face, c.audio, c.mask) for c in clips
            ]
        self.train_set, self.held_set = segment_sets(clips, model_cfg, train_cfg)
        self.neutral = neutral_window(clips, model_cfg.n_history, holdout_frames(clips, train_cfg))
        if not train_cfg.init_from:  # a fine-tuned model keeps the output heads it learned
            start_heads_at_mean(*variant.output_heads(self.G), self.train_set, model_cfg)
        self.G.to(self.device)
        self.D.to(self.device)
        self.precision = _Precision(amp, self.device)
        # what each training forward goes through: DDP wrappers when distributed
        self.G_fwd: torch.nn.Module = TrainingForward(variant, self.G)
        self.D_fwd: torch.nn.Module = self.D
        if self.dist.enabled:
            from torch.nn.parallel import DistributedDataParallel as DDP

            ids = [self.device.index] if self.device.type == "cuda" else None
            self.G_fwd = DDP(self.G_fwd, device_ids=ids)
            self.D_fwd = DDP(self.D, device_ids=ids)
        self.lr_g, self.lr_d = train_cfg.learning_rates(self.dist.world_size)
        self.opt_g = make_optimizer(self.G, train_cfg, self.lr_g)
        self.opt_d = make_optimizer(self.D, train_cfg, self.lr_d)
        self.epoch = 0  # epochs completed
        self.history: list[dict] = []

    @property
    def global_batch(self) -> int:
        return self.tcfg.batch_size * self.dist.world_size

    # ------------------------------------------------------------- state
    def state_dict(self) -> dict:
        sd = {
            "G": self.G.state_dict(),
            "D": self.D.state_dict(),
            "opt_g": self.opt_g.state_dict(),
            "opt_d": self.opt_d.state_dict(),
            "epoch": self.epoch,
            "history": self.history,
            "model_config": to_dict(self.mcfg),
            "train_config": to_dict(self.tcfg),
            "meta": self.meta,
            "neutral": self.neutral,
            "world_size": self.dist.world_size,
            "variant": self.variant.name,
        }
        if self.precision.on:
            sd["grad_scalers"] = self.precision.state_dict()
        return sd

    def load_state_dict(self, sd: dict) -> None:
        saved = sd.get("variant", CLOSED_LOOP.name)
        if saved != self.variant.name:
            raise UserError(f"{self.out}: the run holds a {saved} model, not a {self.variant.name} one")
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
        meta = dict(
            self.meta,
            **self.variant.meta,
            neutral_window=self.neutral.tolist(),
            train_config=to_dict(self.tcfg),
            inputs=self.inputs,
            head_reference_rot6d=None if self.head_reference is None else self.head_reference.tolist(),
            epochs_trained=self.epoch,
            global_batch=self.global_batch,
            final_losses={k: v for k, v in last.items() if k != "epoch"},
        )
        G = self.G
        if self.device.type != "cpu":
            import copy

            G = copy.deepcopy(self.G).cpu()
        return self.variant.export(path, G, meta)

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
        t, dist = self.tcfg, self.dist
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
            chunk = order[b * gb : (b + 1) * gb]
            idx = dist.shard(chunk)
            n_local = len(idx)
            # weight: DDP's gradient average becomes the mean over the whole global batch
            weight = n_local * dist.world_size / len(chunk)
            if n_local == 0:  # more ranks than segments left: join the all-reduce with weight 0
                idx = chunk[:1]
            batch = self._gather(self.train_set, idx)
            logs = self._train_step(batch, weight, adv_on)
            keys = list(logs)
            if dist.enabled:  # global-batch means: Σ_ranks n_local·mean_local / n_global
                vals = dist.all_sum([logs[k].item() * n_local for k in keys])
                values = {k: v / len(chunk) for k, v in zip(keys, vals)}
            else:
                values = {k: logs[k].item() for k in keys}
            if not math.isfinite(values["total"]):
                raise UserError(f"training diverged at epoch {epoch} (loss {values['total']}); lower the learning rate")
            for k, v in values.items():
                sums[k] = sums.get(k, 0.0) + v
            if progress is not None:
                progress(b + 1, n_batches, values)
        return {k: v / n_batches for k, v in sums.items()}

    def _train_step(self, batch: dict, weight: float, adv_on: bool) -> dict[str, torch.Tensor]:
        """One D step (when ``adv_on``) and one G step on ``batch``, losses scaled by ``weight``; the losses."""
        t, prec = self.tcfg, self.precision
        if t.head_dropout > 0:
            hold_head_still(batch["head"], t.head_dropout)
        with prec.autocast():
            gen, gt = self.G_fwd(batch)
        gen = gen.float()
        mask = batch["mask"][:, self.mcfg.n_history :]  # (B, M, 47): masked joints add no loss
        logs: dict[str, torch.Tensor] = {}
        if adv_on:  # D step on the generated frames only (4.3.1), one forward for real + fake
            with prec.autocast():
                d_out = self.D_fwd(torch.cat([gt, discriminator_view(gen.detach(), gt, mask)])).float()
            d_real, d_fake = d_out[: len(gt)], d_out[len(gt) :]
            loss_d = F.binary_cross_entropy_with_logits(
                d_real, torch.ones_like(d_real)
            ) + F.binary_cross_entropy_with_logits(d_fake, torch.zeros_like(d_fake))  # eq. 4.22
            self.opt_d.zero_grad(set_to_none=True)
            prec.backward("d", loss_d if weight == 1.0 else loss_d * weight)
            prec.step("d", self.opt_d)
            logs["d"] = loss_d.detach()
        rec = masked_reconstruction_losses(gen, gt, t.huber_beta, mask)
        loss = t.w_rec * rec["rec"] + t.w_vel * rec["vel"] + t.w_acc * rec["acc"]  # eq. 4.14
        if t.w_amp > 0:
            loss = loss + t.w_amp * rec["amp"]
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
        return logs

    @torch.no_grad()
    def evaluate(self, seg_set: SegmentSet, batch_size: int = 256) -> dict:
        """Mean reconstruction losses of a segment set (eval mode, closed loop), shared among ranks."""
        self.G.eval()
        keys = ("rec", "vel", "acc", "amp")
        sums = dict.fromkeys(keys, 0.0)
        n = 0
        mine = self.dist.shard(np.arange(len(seg_set)))
        for b in range(0, len(mine), batch_size):
            idx = mine[b : b + batch_size]
            batch = self._gather(seg_set, idx)
            with self.precision.autocast():
                gen, gt = self.variant.forward(self.G, batch)
            mask = batch["mask"][:, self.mcfg.n_history :]
            for k, v in masked_reconstruction_losses(gen.float(), gt, self.tcfg.huber_beta, mask).items():
                sums[k] += v.item() * len(idx)
            n += len(idx)
        if self.dist.enabled:
            *vals, n = self.dist.all_sum([sums[k] for k in keys] + [float(n)])
            sums = dict(zip(keys, vals))
        return {k: v / n for k, v in sums.items()}

    def fit(self, epochs: int | None = None, progress: bool = True) -> list[dict]:
        from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn

        from facecapges.progress import Progress

        total = epochs or self.tcfg.epochs
        main = self.dist.is_main
        log_path = self.out / "log.csv"
        fields = list(LOG_FIELDS)
        if main:
            self.out.mkdir(parents=True, exist_ok=True)
        label = "train" if self.variant is CLOSED_LOOP else f"train {self.variant.name}"
        lock = RunFolderLock(self.out) if main else contextlib.nullcontext()  # one training per run folder
        with (
            lock,
            Progress(
                TextColumn(f"[bold]{label}"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("{task.fields[info]}"),
                TimeRemainingColumn(),
                transient=False,
                disable=not (main and progress),
            ) as bar,
        ):
            if main and self.history:  # a row lost to a kill between last.pt and log.csv comes back
                write_log(log_path, self.history, fields)
            task = bar.add_task(label, total=total, completed=self.epoch, info="")
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
    return load_state(
        Path(out) / "last.pt",
        required=("G", "D", "opt_g", "opt_d", "epoch", "history", "model_config", "train_config", "meta"),
    )


def build_trainer(
    clips: list[ClipArrays],
    out: Path,
    model_over: dict,
    train_over: dict,
    meta: dict,
    resume: bool,
    state: dict | None = None,
    dist: DistContext | None = None,
    amp: bool = False,
    variant: Variant = CLOSED_LOOP,
) -> Trainer:
    """A new trainer, or (``resume``) one restored from ``state`` (default: OUT/last.pt)."""
    if resume:
        sd = state if state is not None else load_resume(out)
        mcfg = model_config_from_dict(sd["model_config"])
        tdict = dict(sd["train_config"], **{k: v for k, v in train_over.items() if k == "epochs"})
        tr = Trainer(clips, out, mcfg, train_config_from_dict(tdict), sd["meta"], dist=dist, amp=amp, variant=variant)
        tr.load_state_dict(sd)
        return tr
    mcfg = model_config_from_dict(model_over)
    tcfg = train_config_from_dict(train_over, mcfg)
    return Trainer(clips, out, mcfg, tcfg, meta, dist=dist, amp=amp, variant=variant)
