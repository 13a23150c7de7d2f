"""Retargeting: motion on another skeleton → the BEAT 47-joint pose, by joint names and rest corrections.

A **joint map** (``facecapges/data/maps/<name>.json``, or any JSON file of the same
layout) says which source joint drives each BEAT joint and how their rest poses
differ::

    {"name": "zeggs", "dataset": "ZEGGS", "licence": "CC BY-NC-ND 4.0", "speaker": 100,
     "detect": ["RightForeArmEnd"],                  # joints that identify the skeleton
     "joints": {"Spine": "Spine3", "RightArm": "RightArm", ...},   # BEAT name: source name
     "corrections": {"Spine": [w, x, y, z], ...}}  # optional rest corrections (quaternions)

The method (every rotation in world space, matrices act on column vectors):

1. **Source world rotations** ``S_s`` (T, 3, 3) by forward kinematics. In a BVH the rest
   pose is all channels 0, where every joint's world rotation is the identity; the rest
   *bone directions* are what differ between skeletons (a T-pose vs an A-pose, other
   proportions, a spine of another length).
2. **Rest correction** of BEAT joint t driven by source joint s: ``Q_t`` is the
   shortest-arc rotation taking t's rest bone direction to s's. A joint's bone
   direction points to its *direction child*: the nearest mapped joint below it
   (breadth first, file order; a hand points at its middle finger, a chest at the
   neck), on each skeleton to that child's counterpart. With ``G_t = S_s Q_t`` the BEAT
   bone points where the source bone points in every frame:
   ``G_t d_t = S_s Q_t d_t = S_s d_s``. The correction turns no more than it must, so
   skeletons facing the same way with the same up axis (BEAT, ZEGGS: Y up, facing +Z)
   keep the source's twist about each bone. A map may state ``corrections``
   explicitly (the ZEGGS map does: the 9-joint takes have no skeleton to compute them
   from); a stated one is used as it is.
3. **Root**: BEAT's pose has no root motion (the CaMN cache holds Hips at rest), so
   every world rotation is taken relative to the hips: the pose is the upper body as
   seen from the pelvis, as in BEAT's own data. Root translation is dropped. The hips
   get no correction (their rest frame is the world frame on both skeletons; a map
   may state one for a source with other axes).
4. **The 47 local rotations**: ``L_j = G_p^T G_j`` with p the nearest driven ancestor
   of j (the undriven Spine1–3 stay at rest, as in BEAT). A driven joint the source
   does not have follows its parent (``L_j = I``) and is **masked** out: the mask
   (47,) says which joints carry real motion, and training adds no loss for the others.

BEAT's ``Spine`` is the only driven trunk joint, so a source with a bending spine gives
it the *chest's* world rotation (``"Spine": "Spine3"`` in the ZEGGS map): the shoulders
and neck then sit where the source's do, and the arms keep their own world rotations.
Retargeting a BEAT file with the ``beat`` map gives it back unchanged.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from facecapges import rotations as rot
from facecapges.errors import UserError, file_error
from facecapges.skeleton import (
    N_JOINTS,
    UPPER_BODY,
    Skeleton,
    global_transforms,
    local_matrices,
    motion_to_euler,
    rest_positions,
)

#: BEAT joints every source must drive; the others (neck, clavicles, fingers) are masked when absent.
REQUIRED: tuple[str, ...] = (
    "Hips",
    "Spine",
    "RightArm",
    "RightForeArm",
    "RightHand",
    "LeftArm",
    "LeftForeArm",
    "LeftHand",
)
ROOT = "Hips"
#: The shipped maps, tried in this order by :func:`auto_map` (``beat``, names as they are, last).
SHIPPED_MAPS: tuple[str, ...] = ("zeggs", "beat")


# ------------------------------------------------------------------- joint maps
@dataclass
class JointMap:
    """BEAT joint ← source joint names, optional rest corrections and the source's metadata."""

    name: str
    joints: dict[str, str]
    corrections: dict[str, np.ndarray] = field(default_factory=dict)
    detect: list[str] = field(default_factory=list)
    dataset: str = ""
    licence: str = ""
    speaker: int | None = None
    description: str = ""

    @classmethod
    def from_dict(cls, d: dict, origin: str = "joint map") -> JointMap:
        try:
            joints = {str(k): str(v) for k, v in d["joints"].items()}
            corr = {}
            for k, q in (d.get("corrections") or {}).items():
                q = np.asarray(q, np.float64)
                if q.shape != (4,) or not np.isfinite(q).all() or np.linalg.norm(q) < 1e-6:
                    raise ValueError(f"correction of {k!r} must be a quaternion [w, x, y, z]")
                corr[str(k)] = rot.quaternion_to_matrix(q)
            speaker = d.get("speaker")
            return cls(
                name=str(d.get("name", origin)),
                joints=joints,
                corrections=corr,
                detect=[str(n) for n in d.get("detect", [])],
                dataset=str(d.get("dataset", "")),
                licence=str(d.get("licence", "")),
                speaker=None if speaker is None else int(speaker),
                description=str(d.get("description", "")),
            )
        except (KeyError, TypeError, AttributeError, ValueError) as exc:
            raise UserError(f"{origin}: not a joint map ({exc}); see docs/bring-your-own-mocap.md") from None

    def unknown_targets(self, target: Skeleton) -> list[str]:
        return [t for t in self.joints if t not in target.names]


def shipped_map_path(name: str) -> Path:
    return Path(str(resources.files("facecapges.data") / "maps" / f"{name}.json"))


def load_map(spec: str | Path) -> JointMap:
    """A joint map by shipped name (``zeggs``, ``beat``) or from a JSON file."""
    p = Path(spec)
    if p.suffix.lower() != ".json" and shipped_map_path(str(spec)).is_file():
        p = shipped_map_path(str(spec))
    if not p.is_file():
        raise UserError(f"unknown joint map {str(spec)!r}: give a JSON file or one of {', '.join(SHIPPED_MAPS)}")
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise file_error(p, f"malformed joint map JSON ({exc})") from None
    if not isinstance(d, dict):
        raise file_error(p, "a joint map is a JSON object with a 'joints' table")
    return JointMap.from_dict(d, origin=str(p))


def missing_sources(jmap: JointMap, source: Skeleton) -> list[str]:
    """Source joints the map needs for the REQUIRED BEAT joints that ``source`` lacks."""
    have = set(source.names)
    out = []
    for t in REQUIRED:
        s = jmap.joints.get(t)
        if s is None or s not in have:
            out.append(s or f"(nothing mapped to BEAT {t})")
    return out


def auto_map(source: Skeleton, where: str = "source") -> JointMap:
    """The first shipped map whose ``detect`` joints and required joints ``source`` has.

    Raises a UserError naming the required joints the skeleton lacks.
    """
    have = set(source.names)
    best: tuple[JointMap, list[str]] | None = None
    for name in SHIPPED_MAPS:
        jmap = load_map(name)
        if not all(d in have for d in jmap.detect):
            continue
        missing = missing_sources(jmap, source)
        if not missing:
            return jmap
        if best is None or len(missing) < len(best[1]):
            best = (jmap, missing)
    assert best is not None  # the beat map has no detect list
    jmap, missing = best
    raise UserError(
        f"{where}: cannot map this skeleton onto BEAT: it lacks {', '.join(missing)} "
        f"(joint map {jmap.name!r}); write a joint map JSON for it and pass --map "
        "(see docs/bring-your-own-mocap.md)"
    )


# ----------------------------------------------------------- rest corrections
def direction_child(target: Skeleton, t: int, mapped: set[str]) -> int | None:
    """The nearest mapped joint below ``t`` (breadth first, file order), or None."""
    kids = target.children()
    frontier = list(kids[t])
    while frontier:
        for c in frontier:
            if target.names[c] in mapped:
                return c
        frontier = [g for c in frontier for g in kids[c]]
    return None


def rest_corrections(jmap: JointMap, source: Skeleton, target: Skeleton) -> dict[str, np.ndarray]:
    """``Q_t`` (3, 3) of every mapped BEAT joint (method step 2); stated ones are kept."""
    mapped = {t for t, s in jmap.joints.items() if s in source.names and t in target.names}
    pt, ps = rest_positions(target), rest_positions(source)
    out: dict[str, np.ndarray] = {}
    for t in mapped:
        if t in jmap.corrections:
            out[t] = jmap.corrections[t]
            continue
        if t == ROOT:  # the root's rest frame is the world frame on both skeletons
            out[t] = np.eye(3)
            continue
        ti, si = target.index(t), source.index(jmap.joints[t])
        c = direction_child(target, ti, mapped)
        if c is not None:
            d_t = pt[c] - pt[ti]
            d_s = ps[source.index(jmap.joints[target.names[c]])] - ps[si]
        elif ti in target.end_sites and si in source.end_sites:
            d_t, d_s = target.end_sites[ti], source.end_sites[si]
        else:
            d_t = d_s = np.zeros(3)
        out[t] = rot.rotation_between(d_t, d_s)
    return out


def corrections_as_quaternions(corr: dict[str, np.ndarray], digits: int = 6) -> dict[str, list[float]]:
    """JSON-able ``corrections`` table ([w, x, y, z], rounded) of :func:`rest_corrections`."""
    return {t: [round(float(v), digits) for v in rot.matrix_to_quaternion(m)] for t, m in sorted(corr.items())}


# ------------------------------------------------------------- the retarget
@dataclass
class Retargeted:
    """A retargeted take: BEAT pose rot6d (T, 47, 6) float32, the joint mask (47,), its fps and source."""

    pose: np.ndarray
    mask: np.ndarray
    fps: float
    map_name: str
    source_fps: float
    dataset: str = ""
    licence: str = ""
    speaker: int | None = None

    @property
    def n_frames(self) -> int:
        return int(len(self.pose))


def driven_parents(target: Skeleton) -> list[int]:
    """For each UPPER_BODY joint, its nearest driven ancestor as an index into UPPER_BODY, −1 for the root."""
    pos = {n: k for k, n in enumerate(UPPER_BODY)}
    out = []
    for name in UPPER_BODY:
        p = int(target.parents[target.index(name)])
        while p >= 0 and target.names[p] not in pos:
            p = int(target.parents[p])
        out.append(pos[target.names[p]] if p >= 0 else -1)
    return out


def pose_from_world(
    target: Skeleton, world: dict[str, np.ndarray], root: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """BEAT pose from world rotations of BEAT joints (method steps 3–4).

    ``world[name]`` (T, 3, 3) are the corrected world rotations ``G_t`` of the BEAT joints
    the source drives; ``root`` (T, 3, 3) the corrected hips (None: world frame). Returns
    rot6d (T, 47, 6) float32 and the mask (47,) bool.
    """
    T = len(next(iter(world.values())))
    inv_root = None if root is None else np.swapaxes(root, -1, -2)
    dparent = driven_parents(target)
    G = np.empty((T, N_JOINTS, 3, 3))
    local = np.empty((T, N_JOINTS, 3, 3))
    mask = np.zeros(N_JOINTS, bool)
    for k, name in enumerate(UPPER_BODY):  # parents come first in UPPER_BODY order
        p = dparent[k]
        parent_g = np.broadcast_to(np.eye(3), (T, 3, 3)) if p < 0 else G[:, p]
        if name in world:
            G[:, k] = world[name] if inv_root is None else inv_root @ world[name]
            local[:, k] = np.swapaxes(parent_g, -1, -2) @ G[:, k]
            mask[k] = True
        else:
            G[:, k] = parent_g
            local[:, k] = np.eye(3)
    return rot.matrix_to_rot6d(local).astype(np.float32), mask


def retarget_motion(
    source: Skeleton, motion: np.ndarray, target: Skeleton, jmap: JointMap
) -> tuple[np.ndarray, np.ndarray]:
    """Source BVH motion (T, C) → BEAT pose rot6d (T, 47, 6) float32 and mask (47,)."""
    unknown = jmap.unknown_targets(target)
    if unknown:
        raise UserError(
            f"joint map {jmap.name!r} names joints the BEAT skeleton does not have: {', '.join(unknown[:6])}"
        )
    missing = missing_sources(jmap, source)
    if missing:
        raise UserError(
            f"cannot map this skeleton onto BEAT with joint map {jmap.name!r}: it lacks {', '.join(missing)}"
        )
    _, euler = motion_to_euler(source, motion)
    S = global_transforms(source, local_matrices(source, euler))[0]  # (T, Js, 3, 3)
    corr = rest_corrections(jmap, source, target)
    world = {t: S[:, source.index(jmap.joints[t])] @ q for t, q in corr.items()}
    root = world.get(ROOT)
    return pose_from_world(target, {t: g for t, g in world.items() if t in UPPER_BODY}, root)


def retarget_bvh(
    path: str | Path, target: Skeleton, jmap: JointMap | str | Path | None = None, fps: float | None = None
) -> Retargeted:
    """Read a BVH of any skeleton and retarget it (at its own rate, or resampled to ``fps``)."""
    from facecapges import timing
    from facecapges.io.bvh import read_bvh

    bvh = read_bvh(path)
    if jmap is None:
        jmap = auto_map(bvh.skeleton, where=str(path))
    elif not isinstance(jmap, JointMap):
        jmap = load_map(jmap)
    motion = bvh.motion if fps is None else timing.resample(bvh.motion, bvh.fps, fps)
    try:
        pose, mask = retarget_motion(bvh.skeleton, motion, target, jmap)
    except UserError as exc:
        raise UserError(f"{path}: {exc}") from None
    return Retargeted(
        pose=pose,
        mask=mask,
        fps=bvh.fps if fps is None else fps,
        map_name=jmap.name,
        source_fps=bvh.fps,
        dataset=jmap.dataset or jmap.name,
        licence=jmap.licence,
        speaker=jmap.speaker,
    )


def fill_masked(target: Skeleton, pose: np.ndarray, mask: np.ndarray, fill: np.ndarray) -> np.ndarray:
    """Give masked joints the rotation ``fill`` (47, 6) and keep every world rotation.

    A masked joint follows its parent (local identity) after :func:`pose_from_world`;
    here it takes ``fill[j]`` instead and each driven child ``c`` of it is turned back by
    it (``L_c ← F_j^T L_c``), so the children's world rotations — what the source
    measured — do not change. Returns a new pose (T, 47, 6) float32.
    """
    mats = rot.rot6d_to_matrix(pose.astype(np.float64))
    F = rot.rot6d_to_matrix(np.asarray(fill, np.float64))
    dparent = driven_parents(target)
    for k in range(N_JOINTS):
        if mask[k]:
            continue
        old = mats[:, k].copy()
        mats[:, k] = F[k]
        turn = np.swapaxes(mats[:, k], -1, -2) @ old  # new local^T old local
        for c in range(N_JOINTS):
            if dparent[c] == k:
                mats[:, c] = turn @ mats[:, c]
    return rot.matrix_to_rot6d(mats).astype(np.float32)
