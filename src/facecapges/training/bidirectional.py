"""The "offline decoding" ablation (:mod:`facecapges.network.bidirectional`) as a training variant.

It is trained by the one trainer (:mod:`facecapges.training.train`) — the same data,
budget, objective, optimizers, DDP, AMP and resume as the closed-loop model; only
the :class:`~facecapges.training.train.Variant` differs:

* Segments: the same :class:`~facecapges.training.segments.SegmentSet` — L = 34 frames,
  stride 10, frames < ``holdout_from`` for training and ≥ it for the held-out losses;
  each segment frame's encoder input is its own causal window, as in the full model.
* Seed and mask: the first N = 16 real poses of a segment are given as seed poses
  (mask bit 1); the pose slot of the other M = 18 frames is zero (mask bit 0). The
  bidirectional decoder outputs all L frames in one pass — no rollout, no feedback of
  its own predictions, LSTM state zero at every segment.
* Losses on the M = 18 frames after the seed only (the same frames the closed-loop
  trainer generates), with the closed-loop trainer's weights, discriminator and
  schedule. The checkpoint is ``model.safetensors`` in format ``facecapges-offline-1``
  (:func:`facecapges.network.bidirectional.save_bidirectional`) with ``variant: "offline decoding"``
  and the cold-start ``neutral_window`` chosen exactly as for the closed-loop model,
  so both are seeded alike at evaluation.
"""

from __future__ import annotations

from pathlib import Path

import torch

from facecapges.network.bidirectional import BidirectionalDecoder, save_bidirectional
from facecapges.training.segments import ClipArrays
from facecapges.training.train import Trainer, Variant, build_trainer


def bidirectional_batch(
    model: BidirectionalDecoder, batch: dict[str, torch.Tensor]
) -> tuple[torch.Tensor, torch.Tensor]:
    """Decoded (B, M, D) and real (B, M, D) poses of the frames after the N-frame seed."""
    N = model.cfg.n_history
    z = model.encode(batch["audio"], batch["face"], batch["head"])[:, N:]  # (B, L, E), own causal windows
    out = model.decode(z, batch["pose"][:, :N])  # (B, L, D)
    return out[:, N:], batch["pose"][:, N:]


BIDIRECTIONAL = Variant(
    name="offline",
    build=BidirectionalDecoder,
    forward=bidirectional_batch,
    output_heads=lambda G: (G.head_t, G.head_u),
    export=save_bidirectional,
    meta={"variant": "offline decoding"},
)


def build_bidirectional_trainer(
    clips: list[ClipArrays], out: Path, model_over: dict, train_over: dict, meta: dict
) -> Trainer:
    """A new offline-decoding trainer from the same override dicts as ``build_trainer``."""
    return build_trainer(clips, out, model_over, train_over, meta, resume=False, variant=BIDIRECTIONAL)
