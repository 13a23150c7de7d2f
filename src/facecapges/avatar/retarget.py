"""BEAT motion → the normalised humanoid bones of any VRM (three-vrm's convention).

The one retargeting algorithm of the project, used by ``render``/``run``/``live --web``/
the study on a VRM (the browser sets the result on ``vrm.humanoid``'s normalised bones)
and by the ``.vrma`` writer.

Frames and conventions
----------------------
* The **canonical frame**: right-handed, Y up, the model facing +Z, its left hand at
  +X — BEAT's and VRM 1.0's model space. VRM 0.x faces −Z: its rest positions are
  turned 180° about Y on reading (:mod:`facecapges.avatar.vrm`) and its output
  rotations turned back (``q → (w, −x, y, −z)``), which is what three-vrm expects of a
  VRM 0.x normalised bone before ``VRMUtils.rotateVRM0``.
* A **normalised bone** (three-vrm, VRM 1.0 "normalized pose") has the identity as its
  rest rotation in model space; setting local rotations ``L_b`` gives the bone the
  world rotation ``W_b = W_parent(b) · L_b`` relative to its rest, where parent(b) is
  the nearest humanoid ancestor the model has.

Algorithm, per frame
--------------------
1. BEAT forward kinematics: world rotation ``S_j`` of every BEAT joint (BEAT's rest
   rotations are the identity, so ``S_j`` *is* the change from its rest).
2. **Rest-pose correction**: a model's rest pose is only roughly BEAT's T-pose (A-pose
   GLBs, VRoid thumbs, bent fingers). For each humanoid bone ``b`` the direction to its
   child bone at rest is ``d_b`` on the model and ``s_b`` on BEAT; ``C_b`` is the
   shortest rotation taking ``d_b`` to ``s_b``. The model's bone gets ``W_b = S_b · C_b``,
   so it points along ``S_b s_b`` — exactly where the BEAT bone points — whatever the
   model's rest direction and bone lengths. A bone with no child bone (head, finger
   tips) takes its parent's correction.
3. ``L_b = W_parent(b)⁻¹ · W_b``. BEAT joints that are not humanoid bones (Spine2,
   Neck1, metacarpals) fold into the next humanoid bone below them, because step 1
   works with world rotations.

Only rotations are retargeted: BEAT's upper-body motion keeps the hips in place.
Fingers are driven where both skeletons have them.
"""

from __future__ import annotations

import numpy as np

from facecapges import rotations as rot
from facecapges.avatar.vrm.humanoid import BEAT_BONES, BONE_NAMES, BONE_PARENT
from facecapges.avatar.vrm.read import VrmModel
from facecapges.errors import UserError
from facecapges.skeleton import N_JOINTS, Skeleton, global_transforms

# the child bones that give a bone its direction, in order of preference
_FINGER_PARTS = {
    "Thumb": ("Metacarpal", "Proximal", "Distal"),
    "Index": ("Proximal", "Intermediate", "Distal"),
    "Middle": ("Proximal", "Intermediate", "Distal"),
    "Ring": ("Proximal", "Intermediate", "Distal"),
    "Little": ("Proximal", "Intermediate", "Distal"),
}


def _direction_children() -> dict[str, tuple[str, ...]]:
    d: dict[str, tuple[str, ...]] = {
        "hips": ("spine",),
        "spine": ("chest", "upperChest", "neck", "head"),
        "chest": ("upperChest", "neck", "head"),
        "upperChest": ("neck", "head"),
        "neck": ("head",),
    }
    for s in ("left", "right"):
        d.update(
            {
                f"{s}Shoulder": (f"{s}UpperArm",),
                f"{s}UpperArm": (f"{s}LowerArm",),
                f"{s}LowerArm": (f"{s}Hand",),
                f"{s}Hand": (f"{s}MiddleProximal", f"{s}IndexProximal", f"{s}RingProximal"),
                f"{s}UpperLeg": (f"{s}LowerLeg",),
                f"{s}LowerLeg": (f"{s}Foot",),
                f"{s}Foot": (f"{s}Toes",),
            }
        )
        for f, parts in _FINGER_PARTS.items():
            for k in range(len(parts) - 1):
                d[f"{s}{f}{parts[k]}"] = tuple(f"{s}{f}{p}" for p in parts[k + 1 :])
    return d


DIRECTION_CHILDREN = _direction_children()


def humanoid_parent(bone: str, have) -> str | None:
    """The nearest ancestor of ``bone`` (VRM humanoid tree) among the bones in ``have``."""
    p = BONE_PARENT[bone]
    while p is not None and p not in have:
        p = BONE_PARENT[p]
    return p


class Retargeter:
    """BEAT skeleton ``skel`` → ``model``'s normalised humanoid bones (module docstring)."""

    def __init__(self, skel: Skeleton, model: VrmModel):
        from facecapges.skeleton import rest_positions

        self.model = model
        self.skel = skel
        src = {b: skel.names.index(j) for b, j in BEAT_BONES.items() if j in skel.names}
        missing = [
            b
            for b in (
                "hips",
                "spine",
                "head",
                "leftUpperArm",
                "leftLowerArm",
                "leftHand",
                "rightUpperArm",
                "rightLowerArm",
                "rightHand",
            )
            if b not in src
        ]
        if missing:
            raise UserError(f"the motion's skeleton is not a BEAT skeleton (no joints for {missing})")
        # bones driven: the model's, in VRM table order, that BEAT has too
        self.bones = [b for b in BONE_NAMES if b in model.bones and b in src]
        self.source = np.array([src[b] for b in self.bones])
        have = set(self.bones)
        self.parent = [self.bones.index(p) if (p := humanoid_parent(b, have)) is not None else -1 for b in self.bones]
        P = rest_positions(skel)
        C = np.broadcast_to(np.eye(3), (len(self.bones), 3, 3)).copy()
        known = np.zeros(len(self.bones), bool)
        for i, b in enumerate(self.bones):
            child = next((c for c in DIRECTION_CHILDREN.get(b, ()) if c in have), None)
            if child is None:
                continue
            d = model.rest[child] - model.rest[b]
            s = P[src[child]] - P[src[b]]
            if np.linalg.norm(d) > 1e-6 and np.linalg.norm(s) > 1e-6:
                C[i] = rot.rotation_between(d, s)
                known[i] = True
        for i in range(len(self.bones)):  # bones without a child bone follow their parent
            if not known[i] and self.parent[i] >= 0:
                C[i] = C[self.parent[i]]
        self.correction = C

    def world(self, local_mats: np.ndarray) -> np.ndarray:
        """(T, J, 3, 3) BEAT local rotations → (T, B, 3, 3) model bone world rotations (canonical frame)."""
        G, _ = global_transforms(self.skel, local_mats)
        return G[:, self.source] @ self.correction[None]

    def local_matrices(self, local_mats: np.ndarray) -> np.ndarray:
        """(T, J, 3, 3) BEAT local rotations → (T, B, 3, 3) normalised local rotations (canonical frame)."""
        W = self.world(local_mats)
        L = np.empty_like(W)
        for i, p in enumerate(self.parent):
            L[:, i] = W[:, i] if p < 0 else np.swapaxes(W[:, p], -1, -2) @ W[:, i]
        return L

    def __call__(self, local_mats: np.ndarray) -> np.ndarray:
        """(T, J, 3, 3) BEAT local rotations → (T, B, 4) (w, x, y, z) for three-vrm's normalised bones."""
        q = rot.matrix_to_quaternion(self.local_matrices(local_mats))
        if self.model.faces_minus_z:
            q = q * np.array([1.0, -1.0, 1.0, -1.0])
        return np.ascontiguousarray(q, dtype=np.float32)


def upper_body_locals(skel: Skeleton, quats47: np.ndarray) -> np.ndarray:
    """(T, 47, 4) upper-body local quaternions (runtime frames) → (T, J, 3, 3) on ``skel``, others at rest."""
    from facecapges.skeleton import upper_body_indices

    q = np.asarray(quats47, np.float64).reshape(-1, N_JOINTS, 4)
    mats = np.broadcast_to(np.eye(3), (len(q), skel.n_joints, 3, 3)).copy()
    mats[:, upper_body_indices(skel)] = rot.quaternion_to_matrix(q)
    return mats
