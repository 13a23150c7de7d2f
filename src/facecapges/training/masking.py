"""Joint masks and mirroring in training: masked losses, the discriminator's view, mirrored clips.

A clip retargeted from a skeleton that lacks some BEAT joints carries a joint mask
(``ClipArrays.mask``, (47,) or (T, 47) bool; see :mod:`facecapges.data.cache`). Masked
joints add **no loss**:

* reconstruction (eq. 4.16, 4.19, 4.20): the Huber terms are averaged over the
  present entries only — ``Σ m·huber / Σ m`` per term, where a velocity needs both
  frames present and an acceleration all three. With every joint present this is the
  plain mean, so BEAT-only training is unchanged;
* adversarial (eq. 4.22–4.23): before the discriminator sees a generated segment,
  its masked joints are replaced by the real segment's values
  (:func:`discriminator_view`), so they can neither tell real from fake nor pass a
  gradient into the generator.

Mirroring (``TrainConfig.mirror``) adds a left/right mirrored copy of every training
clip (:mod:`facecapges.data.mirror`); held-out frames are never mirrored into training.
"""

from __future__ import annotations

import dataclasses

import torch
import torch.nn.functional as F

from facecapges.data.mirror import mirror_mask

AMP_SMOOTH = 5  # frames of amplitude_loss's moving average (1/3 s at 15 fps)


def channel_mask(mask: torch.Tensor | None, dim: int) -> torch.Tensor | None:
    """A joint mask (B, M, J) → a channel mask (B, M, D) with D = J·(D // J) (6 per rot6d joint)."""
    if mask is None:
        return None
    return mask.float().repeat_interleave(dim // mask.shape[-1], dim=-1)


def masked_huber(x: torch.Tensor, y: torch.Tensor, beta: float, mask: torch.Tensor | None) -> torch.Tensor:
    """``smooth_l1_loss(beta=β)`` averaged over the entries where ``mask`` (same shape, 0/1) is 1."""
    if mask is None:
        return F.smooth_l1_loss(x, y, beta=beta)
    per = F.smooth_l1_loss(x, y, beta=beta, reduction="none")
    return (per * mask).sum() / mask.sum().clamp(min=1.0)


def masked_reconstruction_losses(
    gen: torch.Tensor, gt: torch.Tensor, beta: float, mask: torch.Tensor | None = None
) -> dict[str, torch.Tensor]:
    """Pose, velocity and acceleration Huber losses over (B, M, D), masked by (B, M, J) joints,
    and the motion-amplitude term ``amp`` (:func:`amplitude_loss`)."""
    m = channel_mask(mask, gen.shape[-1])
    vg, vt = gen[:, 1:] - gen[:, :-1], gt[:, 1:] - gt[:, :-1]
    mv = None if m is None else m[:, 1:] * m[:, :-1]
    ma = None if mv is None else mv[:, 1:] * mv[:, :-1]
    return {
        "rec": masked_huber(gen, gt, beta, m),
        "vel": masked_huber(vg, vt, beta, mv),
        "acc": masked_huber(vg[:, 1:] - vg[:, :-1], vt[:, 1:] - vt[:, :-1], beta, ma),
        "amp": amplitude_loss(gen, gt, m),
    }


def amplitude_loss(gen: torch.Tensor, gt: torch.Tensor, m: torch.Tensor | None = None) -> torch.Tensor:
    """(ours, ``TrainConfig.w_amp``) how far the motion swings, not when: per channel, the
    sd over a segment's frames of its slow part (a moving average over ``AMP_SMOOTH``
    frames, 1/3 s at 15 fps: below ~2 Hz, where a speaker's arm motion lives) and of
    its fast rest, each against the real segment's, L1. The pose and velocity terms
    charge a stroke made slightly off time twice (where it is, and where it should
    have been), so on ambiguous data they prefer small motion; this term does not
    care about timing. Matching the fast part's sd too keeps the swing from being
    bought with jitter. ``m`` is a channel mask (B, M, D): a channel counts in a segment
    only when present in all its frames."""
    k = min(AMP_SMOOTH, gen.shape[1])

    def bands(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        slow = F.avg_pool1d(x.transpose(1, 2), k, stride=1).transpose(1, 2)  # (B, M - k + 1, D)
        fast = x[:, k // 2 : k // 2 + slow.shape[1]] - slow
        return slow, fast

    def sd(x: torch.Tensor) -> torch.Tensor:
        return (x.var(dim=1, unbiased=False) + 1e-8).sqrt()  # (B, D); eps: a finite gradient at rest

    full = None if m is None else m.amin(dim=1)
    (slow_g, fast_g), (slow_t, fast_t) = bands(gen), bands(gt)
    return masked_huber(sd(slow_g), sd(slow_t), 0.0, full) + masked_huber(sd(fast_g), sd(fast_t), 0.0, full)


def discriminator_view(gen: torch.Tensor, gt: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """The generated segment (B, M, D) with its masked joints taken from the real one."""
    m = channel_mask(mask, gen.shape[-1])
    if m is None:
        return gen
    return gen * m + gt.detach() * (1.0 - m)


def mirrored(clip):
    """A left/right mirrored copy of a ``ClipArrays`` (name suffixed ``~mirror``)."""
    return dataclasses.replace(
        clip,
        **clip.mirror_arrays(),
        mask=None if getattr(clip, "mask", None) is None else mirror_mask(clip.mask),
    )
