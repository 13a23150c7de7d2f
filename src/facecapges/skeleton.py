"""The skeleton: joint tree, the BEAT joint sets, forward kinematics, head rotation.

Conventions (see :mod:`facecapges.rotations` for the rotation ones):

* A :class:`Skeleton` is a joint tree in BVH file order: ``names``, ``parents`` (−1
  for the root), rest ``offsets`` (J, 3) in the file's unit (BEAT: centimetres) and
  each joint's ``channels`` as the BVH declares them.
* **The 47 upper-body joints** (``UPPER_BODY``) are CaMN/BEAT's driven set, in this
  order: Spine, Neck, Neck1, the 22 right-arm joints, the 22 left-arm joints. The
  first 3 are the **torso** (``TORSO``), the other 44 the **upper limbs**. A pose is
  (47, 6) rot6d of these joints' *local* rotations, in this order.
* All other joints (Hips, Spine1–3, Head, HeadEnd, fingertips ``*4``, legs) are not
  driven: their rotation is the identity (BVH channels 0) when a pose is written out.
* **Head rotation** (thesis eq. 2.2–2.4) is the *global* rotation of ``Head``: the
  product of the local rotations from the root to Head. BEAT carries no separate head
  motion in the CaMN cache (the shared sample's Head and Spine1–3 channels are 0), so
  for such files this is the orientation of the end of the Spine→Neck→Neck1 chain —
  the direction the head would face if it did not turn on its own.
* The model runs at 15 fps (``MODEL_FPS``) with 16 kHz audio (``AUDIO_SR``):
  :mod:`facecapges.timing` owns frame/sample alignment.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facecapges import rotations as rot

_HAND = [
    "Middle1",
    "Middle2",
    "Middle3",
    "Ring",
    "Ring1",
    "Ring2",
    "Ring3",
    "Pinky",
    "Pinky1",
    "Pinky2",
    "Pinky3",
    "Index",
    "Index1",
    "Index2",
    "Index3",
    "Thumb1",
    "Thumb2",
    "Thumb3",
]


def _arm(side: str) -> list[str]:
    return [f"{side}Shoulder", f"{side}Arm", f"{side}ForeArm", f"{side}Hand"] + [f"{side}Hand{h}" for h in _HAND]


TORSO: tuple[str, ...] = ("Spine", "Neck", "Neck1")
UPPER_LIMBS: tuple[str, ...] = tuple(_arm("Right") + _arm("Left"))
UPPER_BODY: tuple[str, ...] = TORSO + UPPER_LIMBS
N_JOINTS = len(UPPER_BODY)  # 47
N_TORSO = len(TORSO)  # 3
HEAD_JOINT = "Head"
# The joints of UPPER_BODY that carry the head: they are excluded in the "without
# head" evaluation region (thesis 5.5.5): the neck chain that turns the head.
HEAD_REGION: tuple[str, ...] = ("Neck", "Neck1")

assert N_JOINTS == 47 and len(UPPER_LIMBS) == 44


@dataclass
class Skeleton:
    """A joint tree in BVH order. Offsets in the file unit; channels as declared."""

    names: list[str]
    parents: np.ndarray
    offsets: np.ndarray
    channels: list[list[str]]
    end_sites: dict[int, np.ndarray] = field(default_factory=dict)

    @property
    def n_joints(self) -> int:
        return len(self.names)

    @property
    def n_channels(self) -> int:
        return sum(len(c) for c in self.channels)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"joint {name!r} is not in this skeleton") from None

    def children(self) -> list[list[int]]:
        kids: list[list[int]] = [[] for _ in self.names]
        for j, p in enumerate(self.parents):
            if p >= 0:
                kids[p].append(j)
        return kids

    def channel_offsets(self) -> np.ndarray:
        """Index of each joint's first channel in a motion row (J,)."""
        return np.cumsum([0] + [len(c) for c in self.channels[:-1]])

    def rotation_order(self, j: int) -> str:
        """Euler order of joint ``j``, e.g. ``"XYZ"``; ``"XYZ"`` for a joint without rotation channels."""
        order = "".join(c[0] for c in self.channels[j] if c.endswith("rotation"))
        return order if len(order) == 3 else "XYZ"

    def chain_to(self, name: str) -> list[int]:
        """Joint indices from the root down to ``name`` (both included)."""
        j = self.index(name)
        chain = []
        while j >= 0:
            chain.append(j)
            j = int(self.parents[j])
        return chain[::-1]

    def missing(self, names: tuple[str, ...] = UPPER_BODY) -> list[str]:
        """The names of ``names`` this skeleton lacks."""
        have = set(self.names)
        return [n for n in names if n not in have]

    def is_same_tree(self, other: Skeleton) -> bool:
        return self.names == other.names and np.array_equal(self.parents, other.parents)


# ------------------------------------------------------------ skeleton ↔ JSON
def skeleton_to_dict(skel: Skeleton) -> dict:
    """A JSON-able description of a full BVH hierarchy."""
    return {
        "names": list(skel.names),
        "parents": [int(p) for p in skel.parents],
        "offsets": np.asarray(skel.offsets, dtype=np.float64).tolist(),
        "channels": [list(c) for c in skel.channels],
        "end_sites": {str(int(j)): np.asarray(v, dtype=np.float64).tolist() for j, v in skel.end_sites.items()},
    }


def skeleton_from_dict(d: dict) -> Skeleton:
    """Inverse of :func:`skeleton_to_dict`."""
    return Skeleton(
        names=list(d["names"]),
        parents=np.asarray(d["parents"], dtype=np.int64),
        offsets=np.asarray(d["offsets"], dtype=np.float64),
        channels=[list(c) for c in d["channels"]],
        end_sites={int(j): np.asarray(v, dtype=np.float64) for j, v in d.get("end_sites", {}).items()},
    )


# ------------------------------------------------------------------ motion ↔ angles
def motion_to_euler(skel: Skeleton, motion: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split BVH motion (T, C) into root position (T, 3) and local Euler degrees (T, J, 3).

    Angles are in each joint's own channel order (``skel.rotation_order(j)``); joints
    without rotation channels get zeros.
    """
    T = motion.shape[0]
    euler = np.zeros((T, skel.n_joints, 3))
    root_pos = np.zeros((T, 3))
    _, joint, angle, column, pos_col, pos_axis = _channel_layout(skel)
    euler[:, joint, angle] = motion[:, column]
    root_pos[:, pos_axis] = motion[:, pos_col]
    return root_pos, euler


def euler_to_motion(skel: Skeleton, euler: np.ndarray, root_pos: np.ndarray | None = None) -> np.ndarray:
    """Inverse of :func:`motion_to_euler`: (T, J, 3) degrees (+ root (T, 3)) → (T, C)."""
    T = euler.shape[0]
    motion = np.zeros((T, skel.n_channels))
    _, joint, angle, column, pos_col, pos_axis = _channel_layout(skel)
    motion[:, column] = euler[:, joint, angle]
    if root_pos is not None:
        motion[:, pos_col] = root_pos[:, pos_axis]
    return motion


def _channel_layout(skel: Skeleton) -> tuple:
    """Each joint's Euler order, and where rotation angles / root position go in a motion row.

    Returns (orders, joint, angle, column, pos_col, pos_axis): motion column ``column[n]``
    holds angle ``angle[n]`` of joint ``joint[n]``; ``pos_col[n]`` the root position's
    axis ``pos_axis[n]``. Computed once per skeleton (skeletons are not edited in place).
    """
    key = (id(skel.channels), len(skel.channels), id(skel.parents))
    cached = skel.__dict__.get("_layout")
    if cached is not None and cached[0] == key:
        return cached[1]
    joint, angle, column, pos_col, pos_axis = [], [], [], [], []
    for j, (start, chans) in enumerate(zip(skel.channel_offsets(), skel.channels)):
        r = 0
        for k, c in enumerate(chans):
            if c.endswith("rotation"):
                joint.append(j)
                angle.append(r)
                column.append(start + k)
                r += 1
            elif skel.parents[j] < 0:
                pos_col.append(start + k)
                pos_axis.append("XYZ".index(c[0]))
    layout = (
        [skel.rotation_order(j) for j in range(skel.n_joints)],
        *(np.array(x, np.int64) for x in (joint, angle, column, pos_col, pos_axis)),
    )
    skel.__dict__["_layout"] = (key, layout)
    return layout


def local_matrices(skel: Skeleton, euler_deg: np.ndarray) -> np.ndarray:
    """Local rotation matrices (T, J, 3, 3) from Euler degrees (T, J, 3)."""
    mats = np.empty(euler_deg.shape[:-1] + (3, 3))
    for order in {skel.rotation_order(j) for j in range(skel.n_joints)}:
        idx = [j for j in range(skel.n_joints) if skel.rotation_order(j) == order]
        mats[:, idx] = rot.euler_to_matrix(euler_deg[:, idx], order, degrees=True)
    return mats


def matrices_to_euler(skel: Skeleton, mats: np.ndarray, unwrap: bool = True) -> np.ndarray:
    """Local matrices (T, J, 3, 3) → Euler degrees (T, J, 3) in each joint's order.

    With ``unwrap`` each angle track is made continuous over time (no ±180° jumps),
    which keeps keyframe interpolation in Blender and three.js smooth.
    """
    out = rot.matrix_to_euler(mats, _channel_layout(skel)[0], degrees=True)
    if unwrap and out.shape[0] > 1:
        out = np.unwrap(out, period=360.0, axis=0)
    return out


def rest_positions(skel: Skeleton) -> np.ndarray:
    """Joint positions (J, 3) of the rest pose (every rotation 0): the offsets summed from the root down."""
    P = np.zeros((skel.n_joints, 3))
    for j in range(skel.n_joints):
        p = skel.parents[j]
        P[j] = skel.offsets[j] + (P[p] if p >= 0 else 0.0)
    return P


def global_transforms(
    skel: Skeleton, local_mats: np.ndarray, root_pos: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Forward kinematics: global rotations (T, J, 3, 3) and positions (T, J, 3).

    ``G_j = G_parent(j) @ R_j`` (eq. 2.2); ``p_j = p_parent + G_parent @ offset_j``.
    Positions are in the skeleton's unit (BEAT: cm).
    """
    T, J = local_mats.shape[:2]
    G = np.empty_like(local_mats)
    P = np.empty((T, J, 3))
    for j in range(J):
        p = skel.parents[j]
        if p < 0:
            G[:, j] = local_mats[:, j]
            P[:, j] = skel.offsets[j] + (root_pos if root_pos is not None else 0.0)
        else:
            G[:, j] = G[:, p] @ local_mats[:, j]
            P[:, j] = P[:, p] + G[:, p] @ skel.offsets[j]
    return G, P


def joint_positions(skel: Skeleton, motion: np.ndarray) -> np.ndarray:
    """Joint positions (T, J, 3) of BVH motion (T, C) on ``skel``."""
    root_pos, euler = motion_to_euler(skel, motion)
    return global_transforms(skel, local_matrices(skel, euler), root_pos)[1]


def head_rot6d(skel: Skeleton, local_mats: np.ndarray, head: str = HEAD_JOINT) -> np.ndarray:
    """Global head rotation as rot6d (T, 6): the chained product root → ``head`` (eq. 2.3–2.4)."""
    chain = skel.chain_to(head)
    G = local_mats[:, chain[0]]
    for j in chain[1:]:
        G = G @ local_mats[:, j]
    return rot.matrix_to_rot6d(G).astype(np.float32)


# --------------------------------------------------------------- pose (47 rot6d)
def upper_body_indices(skel: Skeleton) -> np.ndarray:
    """Indices in ``skel`` of the 47 UPPER_BODY joints, in UPPER_BODY order."""
    key = (id(skel.names), len(skel.names))
    cached = skel.__dict__.get("_upper_body")
    if cached is None or cached[0] != key:
        cached = skel.__dict__["_upper_body"] = (key, np.array([skel.index(n) for n in UPPER_BODY]))
    return cached[1]


def motion_to_pose(skel: Skeleton, motion: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """BVH motion (T, C) → upper-body pose rot6d (T, 47, 6) and head rot6d (T, 6), float32."""
    _, euler = motion_to_euler(skel, motion)
    mats = local_matrices(skel, euler)
    pose = rot.matrix_to_rot6d(mats[:, upper_body_indices(skel)]).astype(np.float32)
    return pose, head_rot6d(skel, mats)


def pose_locals(skel: Skeleton, pose: np.ndarray) -> np.ndarray:
    """Local rotations (T, J, 3, 3) of every joint of ``skel`` for upper-body rot6d poses (T, 47, 6),
    the joints outside the 47 at rest."""
    p = np.asarray(pose, np.float64)
    if p.ndim != 3 or p.shape[1:] != (N_JOINTS, 6):
        raise ValueError(f"pose must be (T, {N_JOINTS}, 6), got {p.shape}")
    mats = np.broadcast_to(np.eye(3), (len(p), skel.n_joints, 3, 3)).copy()
    mats[:, upper_body_indices(skel)] = rot.rot6d_to_matrix(p)
    return mats


def upper_body_transforms(skel: Skeleton, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward kinematics of upper-body rot6d poses (T, 47, 6): global rotations (T, J, 3, 3) and
    positions (T, J, 3) of every joint of ``skel``, the others at rest and the root at its rest offset
    (the motion :func:`pose_to_motion` writes)."""
    return global_transforms(skel, pose_locals(skel, pose))


def pose_head_rot6d(skel: Skeleton, pose: np.ndarray) -> np.ndarray:
    """Global head rot6d (T, 6) of upper-body rot6d poses (T, 47, 6) (:func:`head_rot6d`)."""
    return head_rot6d(skel, pose_locals(skel, pose))


def pose_to_motion(skel: Skeleton, pose: np.ndarray, root_pos: np.ndarray | None = None) -> np.ndarray:
    """Upper-body pose rot6d (T, 47, 6) → BVH motion (T, C); other joints at rest (0°)."""
    if pose.ndim != 3 or pose.shape[1:] != (N_JOINTS, 6):
        raise ValueError(f"pose must be (T, {N_JOINTS}, 6), got {pose.shape}")
    # only the 47 generated joints are converted (the rest stay at 0°): once per frame when streaming
    idx, layout = upper_body_indices(skel), _channel_layout(skel)
    cached = skel.__dict__.get("_upper_body_motion")  # kept beside what they come from:
    if cached is None or cached[0] is not layout or cached[1] is not idx:
        # their Euler orders, and the motion columns of their angles with where each sits in (47·3)
        where = {(int(j), r): n for n, (j, r) in enumerate((j, r) for j in idx for r in range(3))}
        cols = [(int(c), where[int(j), int(a)]) for j, a, c in zip(*layout[1:4]) if (int(j), int(a)) in where]
        dst, src = (np.array(x, np.int64) for x in zip(*cols))
        cached = skel.__dict__["_upper_body_motion"] = (layout, idx, tuple(layout[0][j] for j in idx), dst, src)
    angles = rot.matrix_to_euler(rot.rot6d_to_matrix(pose.astype(np.float64)), cached[2], degrees=True)
    if angles.shape[0] > 1:
        angles = np.unwrap(angles, period=360.0, axis=0)  # as matrices_to_euler
    # = euler_to_motion of the (T, J, 3) angles with the other joints at 0°, without building them
    motion = np.zeros((pose.shape[0], skel.n_channels))
    motion[:, cached[3]] = angles.reshape(pose.shape[0], -1)[:, cached[4]]
    if root_pos is not None:
        motion[:, layout[4]] = root_pos[:, layout[5]]
    return motion
