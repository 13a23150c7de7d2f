"""What the speech predicts and the database is searched by: arm positions and their near future.

Defined once here for both sides of the engine: the database annotates every real frame with
:func:`future_targets` of the motion that follows it, and the predictor learns to estimate the same
values causally from the speech (audio, face, head) of the last second.

* :func:`arm_positions` — wrists and elbows (right wrist, left wrist, right elbow, left elbow)
  relative to the chest, in the chest's own frame (so a turning torso does not move them), in the
  skeleton's unit (BEAT: cm). The chest is the parent of ``RightShoulder`` (BEAT: Spine3).
* :func:`future_targets` — for each frame t and each horizon h of :data:`HORIZONS_S`, over the
  frames t+1 … t+H (H = round(h·fps)): the mean wrist speed (unit/s, both wrists averaged) and the
  mean wrist height (the chest frame's y, both wrists averaged). Near the end of a take the
  window holds what frames remain (the last frame repeats).
"""

from __future__ import annotations

import numpy as np

from facecapges.skeleton import Skeleton, upper_body_transforms

HORIZONS_S: tuple[float, ...] = (0.3, 0.6)
ARM_JOINTS: tuple[str, ...] = ("RightHand", "LeftHand", "RightForeArm", "LeftForeArm")
TARGET_NAMES: tuple[str, ...] = tuple(f"{k}_{h:g}s" for h in HORIZONS_S for k in ("wrist_speed", "wrist_height"))


def chest_index(skel: Skeleton) -> int:
    """Index in ``skel`` of the chest: the parent of ``RightShoulder``."""
    return int(skel.parents[skel.index("RightShoulder")])


def arm_positions(skel: Skeleton, pose: np.ndarray) -> np.ndarray:
    """Upper-body rot6d poses (T, 47, 6) → positions (T, 4, 3) of :data:`ARM_JOINTS` in the chest frame."""
    G, P = upper_body_transforms(skel, pose)
    c = chest_index(skel)
    rel = P[:, [skel.index(n) for n in ARM_JOINTS]] - P[:, c, None]
    return np.einsum("tji,tkj->tki", G[:, c], rel)  # G_cᵀ · (p − p_c): into the chest's frame


def future_targets(arm: np.ndarray, fps: float) -> np.ndarray:
    """Arm positions (T, 4, 3) → (T, len(TARGET_NAMES)) float32: what each frame's next h seconds hold."""
    a = np.asarray(arm, np.float64)
    if a.ndim != 3 or a.shape[1:] != (len(ARM_JOINTS), 3):
        raise ValueError(f"arm positions must be (T, {len(ARM_JOINTS)}, 3), got {a.shape}")
    T = len(a)
    wr = a[:, :2]
    speed = np.zeros(T)
    if T > 1:
        speed[1:] = np.linalg.norm(np.diff(wr, axis=0), axis=-1).mean(axis=1) * fps
        speed[0] = speed[1]
    height = wr[:, :, 1].mean(axis=1)
    out = np.empty((T, len(TARGET_NAMES)), np.float32)
    for k, h in enumerate(HORIZONS_S):
        H = max(1, round(h * fps))
        idx = np.minimum(np.arange(T)[:, None] + np.arange(1, H + 1)[None, :], T - 1)  # frames t+1 … t+H
        out[:, 2 * k] = speed[idx].mean(axis=1)
        out[:, 2 * k + 1] = height[idx].mean(axis=1)
    return out
