"""Left/right mirroring of poses, head rotations, face weights and joint masks (a training augmentation).

The mirror is the reflection ``S = diag(−1, 1, 1)`` across the body's sagittal plane
(BEAT: x is the performer's left–right axis, Y up, +Z forward). A reflected body is
again a body whose left side is the original's right, so mirroring

* swaps every ``Right*`` joint with its ``Left*`` twin (:data:`MIRROR_JOINTS`), the
  torso joints map to themselves;
* conjugates every rotation by S: ``R' = S R S`` — for local and global rotations
  alike, since ``S S = I`` makes ``(S A S)(S B S) = S (A B) S``;
* swaps the ARKit ``…Left``/``…Right`` blendshapes (``jawLeft`` ↔ ``jawRight`` too).

So mirroring twice is the identity, and on a left/right symmetric skeleton (BEAT's is,
to 0.1 cm) the forward kinematics of a mirrored pose is the reflected FK:
``P'[m(j)] = S P[j]``. Audio is unchanged.
"""

from __future__ import annotations

import numpy as np

from facecapges.arkit import ARKIT_NAMES
from facecapges.skeleton import UPPER_BODY

REFLECT = np.diag([-1.0, 1.0, 1.0])


def _swap(name: str) -> str:
    if "Right" in name:
        return name.replace("Right", "Left")
    if "Left" in name:
        return name.replace("Left", "Right")
    return name


#: MIRROR_JOINTS[j] is the UPPER_BODY index of joint j's mirror twin.
MIRROR_JOINTS = np.array([UPPER_BODY.index(_swap(n)) for n in UPPER_BODY])
#: MIRROR_FACE[k] is the ARKIT_NAMES index of blendshape k's mirror twin.
MIRROR_FACE = np.array([ARKIT_NAMES.index(_swap(n)) for n in ARKIT_NAMES])


def mirror_rotations(mats: np.ndarray) -> np.ndarray:
    """``S R S`` of rotation matrices (..., 3, 3)."""
    return REFLECT @ mats @ REFLECT


def mirror_rot6d(r6: np.ndarray) -> np.ndarray:
    """``S R S`` in rot6d (..., 6): entry (i, k) of the matrix changes sign when exactly one of i, k is x."""
    r6 = np.asarray(r6)
    sign = np.array([1.0, -1.0, -1.0, -1.0, 1.0, 1.0], dtype=r6.dtype)
    return r6 * sign


def mirror_pose(pose: np.ndarray) -> np.ndarray:
    """Mirror a pose rot6d (T, 47, 6): swap left/right joints, reflect each rotation."""
    return mirror_rot6d(np.asarray(pose)[..., MIRROR_JOINTS, :])


def mirror_head(head: np.ndarray) -> np.ndarray:
    """Mirror a global head rotation rot6d (T, 6)."""
    return mirror_rot6d(head)


def mirror_face(face: np.ndarray) -> np.ndarray:
    """Mirror ARKit weights (T, 52): swap left/right blendshapes."""
    return np.asarray(face)[..., MIRROR_FACE]


def mirror_mask(mask: np.ndarray) -> np.ndarray:
    """Mirror a joint mask (47,) or (T, 47)."""
    return np.asarray(mask)[..., MIRROR_JOINTS]
