"""Multi-process training: the process group, data sharding and cross-rank sums.

``facecapges train`` runs unchanged under ``torchrun --nproc_per_node=K`` (and
multi-node ``torchrun --nnodes … --rdzv-endpoint …``). :func:`init_distributed` reads
the variables torchrun sets (``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``, ``MASTER_ADDR``,
``MASTER_PORT``); with ``WORLD_SIZE`` > 1 it joins the process group — NCCL when the
process trains on a GPU (``cuda:LOCAL_RANK``), gloo on CPU. Without those variables
the run is a single process and nothing here touches ``torch.distributed``.

Examples::

    torchrun --nproc_per_node=4 --no-python facecapges train --cache C --speaker 2 --out RUN
    torchrun --nnodes=2 --node-rank=0 --nproc_per_node=8 --rdzv-backend=c10d \
        --rdzv-endpoint=HOST:29500 --no-python facecapges train --cache C --speaker 2 --out RUN --amp

Every node needs the cache; the run folder is written by rank 0 only, and ``--resume``
reads it on rank 0 and broadcasts the state, so only rank 0's node needs it.

Conventions (ours, the thesis trains on one GPU):

* ``train.batch_size`` is the **per-process** batch; the global batch is
  ``batch_size × world_size`` and the learning rates follow the thesis's linear rule
  on the global batch (eq. 5.1: ``lr_g = lr_base · B_global / 128``, ``lr_d = 0.2·lr_g``).
  To keep a single-process recipe exactly, divide ``batch_size`` by K.
* Sharding (the DistributedSampler of this trainer): every rank draws the same seeded
  permutation of the segments each epoch, cuts it into global batches, and takes
  the strided share ``global_batch[rank::world_size]`` (:meth:`DistContext.shard`).
  With one process this is the whole global batch, so single-process runs are
  unchanged. Because the permutation depends only on the seed and the epoch, a run
  resumes exactly, and may resume with another process count (the global batch and
  the learning rates then follow the new count).
* Gradients: DistributedDataParallel averages them over ranks; the trainer weights
  each rank's loss by ``n_local · world_size / n_global`` so the average is the mean
  over the global batch even when the last batch does not split evenly (a rank with
  no segment left runs one with weight 0, so every rank joins every all-reduce).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from facecapges.errors import UserError


def _env_int(name: str, default: int) -> int:
    raw = os.environ.get(name)
    if raw is None or raw == "":
        return default
    try:
        return int(raw)
    except ValueError:
        raise UserError(f"environment variable {name}={raw!r} is not an integer") from None


def pick_device(device: str, local_rank: int = 0) -> torch.device:
    """``auto`` (GPU when there is one), ``cpu`` or ``cuda``: the device this process trains on."""
    if device not in ("auto", "cpu", "cuda"):
        raise UserError(f"--device must be auto, cpu or cuda, got {device!r}")
    if device == "cuda" and not torch.cuda.is_available():
        raise UserError("--device cuda: no CUDA GPU is visible to torch")
    if device == "cpu" or (device == "auto" and not torch.cuda.is_available()):
        return torch.device("cpu")
    n = torch.cuda.device_count()
    if local_rank >= n:
        raise UserError(
            f"LOCAL_RANK={local_rank} but only {n} GPU(s) are visible: start at most {n} processes "
            "per node (torchrun --nproc_per_node) or train with --device cpu"
        )
    return torch.device("cuda", local_rank)


@dataclass
class DistContext:
    """Who this process is in the training job (rank 0 of 1 when not distributed)."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))

    @property
    def enabled(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    def shard(self, idx: np.ndarray) -> np.ndarray:
        """This rank's share of a global batch: ``idx[rank::world_size]``."""
        return idx[self.rank :: self.world_size] if self.enabled else idx

    def all_sum(self, values: list[float]) -> list[float]:
        """Element-wise sum of a list of floats over all ranks (float64)."""
        if not self.enabled:
            return list(values)
        import torch.distributed as dist

        t = torch.tensor(values, dtype=torch.float64, device=self.device)
        dist.all_reduce(t, op=dist.ReduceOp.SUM)
        return t.cpu().tolist()

    def barrier(self) -> None:
        if self.enabled:
            import torch.distributed as dist

            dist.barrier()

    def run_on_main(self, fn: Callable[[], Any]) -> Any:
        """Run ``fn`` on rank 0 only and give its result (or its UserError) to every rank.

        For what only rank 0 may see or do (the run folder, a resume state on its disk),
        so every rank raises the same clear error instead of hanging in a collective.
        """
        if not self.enabled:
            return fn()
        import torch.distributed as dist

        box: list[Any] = [None]
        if self.is_main:
            try:
                box[0] = ("ok", fn())
            except UserError as exc:
                box[0] = ("error", str(exc))
        dist.broadcast_object_list(box, src=0, device=self.device if self.device.type == "cuda" else None)
        status, payload = box[0]
        if status == "error":
            raise UserError(payload)
        return payload


def init_distributed(device: str = "auto") -> DistContext:
    """Join the torchrun process group when ``WORLD_SIZE`` > 1, else a one-process context."""
    world = _env_int("WORLD_SIZE", 1)
    rank = _env_int("RANK", 0)
    local_rank = _env_int("LOCAL_RANK", rank)
    dev = pick_device(device, local_rank)
    if world <= 1:
        return DistContext(device=dev)
    import torch.distributed as dist

    if not 0 <= rank < world:
        raise UserError(f"RANK={rank} is outside WORLD_SIZE={world}")
    for var in ("MASTER_ADDR", "MASTER_PORT"):
        if not os.environ.get(var):
            raise UserError(f"WORLD_SIZE={world} but {var} is not set: start the job with torchrun")
    if dev.type == "cuda":
        torch.cuda.set_device(dev)
    if not dist.is_initialized():
        dist.init_process_group(
            backend="nccl" if dev.type == "cuda" else "gloo", init_method="env://", rank=rank, world_size=world
        )
    return DistContext(rank=rank, world_size=world, local_rank=local_rank, device=dev)


def shutdown(ctx: DistContext) -> None:
    """Leave the process group (all ranks reach this together)."""
    if ctx.enabled:
        import torch.distributed as dist

        if dist.is_initialized():
            dist.destroy_process_group()
