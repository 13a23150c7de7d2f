"""How well ``capture-body`` recovers known motion: arm directions and wrist spread.

Both motions (the truth BVH the avatar was rendered with, and what capture-body
recovered from the video) go through the same forward kinematics on the same
skeleton. Each arm's bone directions — shoulder→elbow (``Arm``→``ForeArm``) and
elbow→wrist (``ForeArm``→``Hand``) — are expressed in the body's frame (the global
rotation of ``Spine3``), so a lean or turn of the whole body is not counted as an
arm error. The angle between true and recovered direction is pooled over both
arms, both bones and all frames (median, 90th percentile, degrees). The wrist
spread ratio is :func:`facecapges.evaluation.synchrony.wrist_spread` of the
recovered wrists (in the body frame) over the truth's.
"""

from __future__ import annotations

import numpy as np

from facecapges.evaluation.synchrony import wrist_spread
from facecapges.skeleton import Skeleton, global_transforms, local_matrices, motion_to_euler

BONES = (("Arm", "ForeArm"), ("ForeArm", "Hand"))
SIDES = ("Right", "Left")


def _body_frame_points(skel: Skeleton, motion: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    _, euler = motion_to_euler(skel, motion)
    G, P = global_transforms(skel, local_matrices(skel, euler))
    body = G[:, skel.index("Spine3")]  # (T, 3, 3)
    local = np.einsum("tji,tkj->tki", body, P - P[:, skel.index("Spine3")][:, None])  # body.T @ p
    return local, body


def arm_direction_errors(skel: Skeleton, truth: np.ndarray, captured: np.ndarray) -> np.ndarray:
    """Angles (degrees) between true and recovered arm bone directions, (T, 4): R upper, R fore, L upper, L fore."""
    n = min(len(truth), len(captured))
    pt, _ = _body_frame_points(skel, truth[:n])
    pc, _ = _body_frame_points(skel, captured[:n])
    out = []
    for side in SIDES:
        for a, b in BONES:
            ia, ib = skel.index(f"{side}{a}"), skel.index(f"{side}{b}")
            dt, dc = pt[:, ib] - pt[:, ia], pc[:, ib] - pc[:, ia]
            cos = (dt * dc).sum(-1) / np.maximum(np.linalg.norm(dt, axis=-1) * np.linalg.norm(dc, axis=-1), 1e-9)
            out.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.stack(out, axis=1)


def compare(skel: Skeleton, truth: np.ndarray, captured: np.ndarray) -> dict:
    """Median / p90 arm-direction angle (degrees), per bone medians and the wrist spread ratio."""
    err = arm_direction_errors(skel, truth, captured)
    n = len(err)
    pt, _ = _body_frame_points(skel, truth[:n])
    pc, _ = _body_frame_points(skel, captured[:n])
    wr = [skel.index(f"{s}Hand") for s in SIDES]
    spread = wrist_spread(pc[:, wr]) / wrist_spread(pt[:, wr])
    names = [f"{s} {'upper arm' if a == 'Arm' else 'forearm'}" for s in SIDES for a, _ in BONES]
    return {
        "frames": int(n),
        "median_deg": float(np.median(err)),
        "p90_deg": float(np.percentile(err, 90)),
        "per_bone_median_deg": {k: float(np.median(err[:, i])) for i, k in enumerate(names)},
        "wrist_spread_ratio": float(spread),
    }
