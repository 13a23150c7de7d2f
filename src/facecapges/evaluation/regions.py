"""The two evaluation regions of thesis 5.5.5.

FaceCapGes receives the real head pose as input and outputs the head-carrying
joints, so every metric is reported twice:

* ``"with_head"`` — upper body with head: all 47 joints of
  :data:`facecapges.skeleton.UPPER_BODY`.
* ``"without_head"`` — upper body without head: the same minus the joints of
  :data:`facecapges.skeleton.HEAD_REGION`, i.e. **Neck and Neck1** (the neck chain
  that turns the head; BEAT's ``Head`` joint itself is not driven in the CaMN/BEAT
  47-joint set). 45 joints remain: Spine and the 44 arm/hand joints.

"Removing the head joints' rotation dimensions" (5.5.5) is done by selecting joints:
per-joint metrics (SRGR, L1DIV, BeatAlign's angular speed) simply skip them, and
FGD uses an autoencoder trained on the 45-joint graph (see
:mod:`facecapges.evaluation.fgd`).
"""

from __future__ import annotations

import numpy as np

from facecapges.skeleton import HEAD_REGION, N_JOINTS, UPPER_BODY

WITH_HEAD = "with_head"
WITHOUT_HEAD = "without_head"
REGIONS: tuple[str, ...] = (WITH_HEAD, WITHOUT_HEAD)
REGION_TITLES = {WITH_HEAD: "Upper body (with head)", WITHOUT_HEAD: "Upper body (without head)"}


def region_joints(region: str) -> tuple[str, ...]:
    """Joint names of ``region``, in UPPER_BODY order."""
    if region == WITH_HEAD:
        return UPPER_BODY
    if region == WITHOUT_HEAD:
        return tuple(n for n in UPPER_BODY if n not in HEAD_REGION)
    raise ValueError(f"unknown region {region!r}; known: {REGIONS}")


def region_indices(region: str) -> np.ndarray:
    """Indices into the 47 UPPER_BODY joints of ``region``'s joints."""
    names = region_joints(region)
    return np.array([UPPER_BODY.index(n) for n in names], dtype=np.int64)


def select(pose: np.ndarray, region: str) -> np.ndarray:
    """The joints of ``region`` from poses (..., 47, 6) → (..., J_region, 6)."""
    pose = np.asarray(pose)
    if pose.ndim < 2 or pose.shape[-2:] != (N_JOINTS, 6):
        raise ValueError(f"pose must have shape (..., {N_JOINTS}, 6), got {pose.shape}")
    return pose[..., region_indices(region), :]
