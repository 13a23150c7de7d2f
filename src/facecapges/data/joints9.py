"""Reduced-joint takes (9 joints: hips, 2 spine, each arm's shoulder/elbow/wrist) → BEAT poses with a mask.

The arrays (``.npy``, (T, J, 7) float) hold per joint a **global position** (metres,
Y up) then a **global unit quaternion (x, y, z, w)** — scalar last, unlike
:mod:`facecapges.rotations`, which is (w, x, y, z). A *layout* JSON
(``facecapges/data/maps/zeggs9.json``) names the joints, their frame rate and how each
stored frame sits on the source skeleton:

* ``joints`` / ``parents``: the source skeleton's joint names in array order;
* ``frames[name]`` (quaternion ``A``): the stored rotation is the source joint's
  world rotation (BVH convention: identity at rest) times ``A``, so
  ``S = G_stored A^T``;
* ``skeleton_map``: the joint map (:mod:`facecapges.data.retarget`) whose stated rest
  corrections turn source world rotations into BEAT ones — the arrays have no rest
  skeleton to compute them from;
* ``clavicles``: BEAT shoulder joints the arrays do not store, solved from positions.
  The chest→upper-arm direction ``c`` in the chest's frame is turned onto BEAT by the
  stated correction ``K`` (ZEGGS's rest chest→arm direction to BEAT's), and the BEAT
  clavicle is turned (shortest arc, about its own joint) until BEAT's upper arm lies
  along ``K c`` (:func:`clavicle_rotation`): the shoulder swings as the source's, its
  twist about the collarbone stays at rest.

:func:`read_joints9` resamples to the model rate (60 → 15 fps keeps every 4th frame)
and returns the BEAT pose (T, 47, 6) with ``mask`` (47,): True for the joints the
arrays determine (Spine from the chest, both clavicles, upper arms, forearms, hands);
the neck and the fingers are masked. Masked joints follow their parent; the cache
fills them (:func:`facecapges.data.retarget.fill_masked`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facecapges import rotations as rot
from facecapges import timing
from facecapges.data.retarget import (
    ROOT,
    JointMap,
    Retargeted,
    load_map,
    pose_from_world,
    shipped_map_path,
)
from facecapges.errors import UserError, file_error, require_file
from facecapges.skeleton import UPPER_BODY, Skeleton, rest_positions


@dataclass
class Joints9Layout:
    """How a reduced-joint array maps onto a source skeleton (module docstring)."""

    name: str
    joints: list[str]
    parents: list[int]
    fps: float
    frames: dict[str, np.ndarray]
    skeleton_map: JointMap
    clavicles: dict[str, dict] = field(default_factory=dict)
    dataset: str = ""
    licence: str = ""
    speaker: int | None = None


def load_layout(spec: str | Path = "zeggs9") -> Joints9Layout:
    """A layout by shipped name (``zeggs9``) or from a JSON file."""
    p = Path(spec)
    if p.suffix.lower() != ".json":
        p = shipped_map_path(str(spec))
    if not p.is_file():
        raise UserError(f"unknown joint layout {str(spec)!r}: give a JSON file or 'zeggs9'")
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
        joints = [str(n) for n in d["joints"]]
        parents = [int(v) for v in d["parents"]]
        if len(parents) != len(joints):
            raise ValueError("'joints' and 'parents' differ in length")
        frames = {str(k): rot.quaternion_to_matrix(np.asarray(v, np.float64)) for k, v in d.get("frames", {}).items()}
        clav = {
            str(k): {
                "chest": str(v["chest"]),
                "arm": str(v["arm"]),
                "correction": rot.quaternion_to_matrix(np.asarray(v["correction"], np.float64)),
            }
            for k, v in d.get("clavicles", {}).items()
        }
        speaker = d.get("speaker")
        return Joints9Layout(
            name=str(d.get("name", p.stem)),
            joints=joints,
            parents=parents,
            fps=float(d["fps"]),
            frames=frames,
            skeleton_map=load_map(d["skeleton_map"]),
            clavicles=clav,
            dataset=str(d.get("dataset", "")),
            licence=str(d.get("licence", "")),
            speaker=None if speaker is None else int(speaker),
        )
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, ValueError) as exc:
        raise file_error(p, f"not a joint layout ({exc})") from None


def load_array(path: str | Path, layout: Joints9Layout) -> np.ndarray:
    """The (T, J, 7) float64 array of ``path``, checked against ``layout``; never unpickles."""
    path = require_file(path, "joint array")
    try:
        a = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise file_error(path, f"not a numpy array file ({exc})") from None
    J = len(layout.joints)
    if not isinstance(a, np.ndarray) or a.ndim != 3 or a.shape[1:] != (J, 7):
        raise file_error(
            path,
            f"expected a (T, {J}, 7) array ({layout.name}: position xyz + quaternion xyzw), "
            f"got {getattr(a, 'shape', '?')}",
        )
    if len(a) == 0:
        raise file_error(path, "the array has no frames")
    a = a.astype(np.float64)
    if not np.isfinite(a).all():
        raise file_error(path, "the array contains NaN or infinite values")
    if np.abs(np.linalg.norm(a[..., 3:], axis=-1) - 1.0).max() > 1e-3:
        raise file_error(path, "the quaternions are not unit length (expected x, y, z, w)")
    return a


def source_world(array: np.ndarray, layout: Joints9Layout) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Source-skeleton world rotations ``S`` (T, 3, 3) and positions (T, 3) by joint name."""
    quat_wxyz = array[..., [6, 3, 4, 5]]
    G = rot.quaternion_to_matrix(quat_wxyz)  # (T, J, 3, 3)
    rots, pos = {}, {}
    for j, name in enumerate(layout.joints):
        A = layout.frames.get(name, np.eye(3))
        rots[name] = G[:, j] @ A.T
        pos[name] = array[:, j, :3]
    return rots, pos


def joints9_to_pose(array: np.ndarray, layout: Joints9Layout, target: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """(T, J, 7) arrays → BEAT pose rot6d (T, 47, 6) float32 and mask (47,) (module docstring)."""
    jmap = layout.skeleton_map
    S, P = source_world(array, layout)
    world: dict[str, np.ndarray] = {}
    for t, s in jmap.joints.items():
        if s in S and (t in UPPER_BODY or t == ROOT):
            if t != ROOT and t not in jmap.corrections and jmap.joints.get(t) != t:
                raise UserError(f"joint map {jmap.name!r} states no rest correction for BEAT {t}")
            world[t] = S[s] @ jmap.corrections.get(t, np.eye(3))
    rest = rest_positions(target)
    for shoulder, c in layout.clavicles.items():
        chest_t = next((t for t, s in jmap.joints.items() if s == c["chest"] and t in world), None)
        if chest_t is None or c["arm"] not in P:
            continue
        chest_s = S[c["chest"]]
        d = np.einsum("tji,tj->ti", chest_s, P[c["arm"]] - P[c["chest"]])  # in the source chest frame
        q_chest = jmap.corrections.get(chest_t, np.eye(3))
        want = (c["correction"] @ q_chest.T @ d.T).T  # in BEAT's chest frame
        world[shoulder] = world[chest_t] @ clavicle_rotation(target, rest, shoulder, want)
    root = world.pop(ROOT, None)
    return pose_from_world(target, world, root)


def clavicle_rotation(target: Skeleton, rest: np.ndarray, shoulder: str, want: np.ndarray) -> np.ndarray:
    """BEAT clavicle rotations (T, 3, 3), in the chest's frame, that put the upper arm along ``want`` (T, 3).

    The clavicle turns about BEAT's shoulder joint (offset ``o`` from the chest) and
    carries the upper-arm joint (offset ``a`` from it): the arm lands on the point ``x``
    of the ray along ``want`` with ``|x − o| = |a|`` (the far one), and the clavicle takes
    the shortest arc from ``a`` to ``x − o``. A ray that misses the sphere takes its
    closest point.
    """
    chest = target.index("Spine3")
    sh, arm = target.index(shoulder), target.index(shoulder.replace("Shoulder", "Arm"))
    o, a = rest[sh] - rest[chest], rest[arm] - rest[sh]
    w = want / np.linalg.norm(want, axis=-1, keepdims=True)
    wo = w @ o
    disc = np.maximum(wo * wo - o @ o + a @ a, 0.0)
    x = (wo + np.sqrt(disc))[:, None] * w
    return rot.rotation_between(np.broadcast_to(a, x.shape), x - o)


def read_joints9(
    path: str | Path, target: Skeleton, layout: Joints9Layout | str | Path = "zeggs9", fps: float = timing.MODEL_FPS
) -> Retargeted:
    """Read a reduced-joint take as BEAT poses at ``fps`` with a per-joint mask."""
    if not isinstance(layout, Joints9Layout):
        layout = load_layout(layout)
    array = load_array(path, layout)
    array = timing.resample(array, layout.fps, fps)
    pose, mask = joints9_to_pose(array, layout, target)
    return Retargeted(
        pose=pose,
        mask=mask,
        fps=fps,
        map_name=layout.name,
        source_fps=layout.fps,
        dataset=layout.dataset or layout.name,
        licence=layout.licence,
        speaker=layout.speaker,
    )
