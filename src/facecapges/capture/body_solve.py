"""BEAT upper-body joint rotations from MediaPipe pose and hand world landmarks.

Input (per 15 fps frame, see :mod:`facecapges.capture.body`): the 33 pose world
landmarks and their visibility, and for each of the subject's hands the 21 hand
world landmarks (or nothing). MediaPipe's world axes are the camera's (x right in
the image, y down, z away from the camera, metres); :data:`MP_TO_BVH` turns them
into the BEAT skeleton's (X the character's left, Y up, Z forward) for a person
facing the camera.

The solve, per frame, walking the BEAT tree from the root (every rest rotation of
the BEAT skeleton is the identity, so a joint's rest bone direction is the offset
of its child):

* **Spine** takes the whole torso frame (shoulder line, hips→shoulders up): its roll in
  the image plane per frame, its lean and turn (seen only in depth, noisy) smoothed over
  ~2 s (:data:`TORSO_SIGMA`), the lean then blended with BEAT's population mean
  (:data:`LEAN_PRIOR_DEG`; the landmarker's share :data:`LEAN_WEIGHT`); Hips, Spine1–3 and the
  clavicles stay at rest (the product drives Spine only).
* **Arm**: the swing that points the bone at the elbow, turned about the bone so
  the elbow bends in the arm's rest hinge plane (weighted by how bent the elbow is).
* **ForeArm**: the swing to the wrist — where the hand landmarker found the hand,
  towards the pose's elbow→wrist with its image-plane part blended with the hand's
  wrist→middle knuckle (:data:`HAND_WEIGHT`; the hand model's image-plane direction is
  sharper than the pose's, its depth is not, so depth stays the pose's) — plus the
  twist about the bone the hand's orientation asks for. **Hand**: the rest of the hand frame (wrist→middle knuckle,
  index→pinky knuckles) from the hand landmarks, or from the pose's coarse hand
  points (wrist, index, pinky) when the hand landmarker found no hand.
* **Fingers**: each phalanx swings to its landmark direction; metacarpals at rest.
* **Neck, Neck1**: half each of the head's turn relative to the torso (ears → nose).

Landmarks are smoothed with a zero-phase Gaussian (offline capture may look ahead, so
no filter lag) within each run of frames where they were seen. Every joint gets a
confidence (pose visibility for the arm, hand presence for the fingers); its
rotation is blended towards a relaxed rest pose (arms down, hands open) by that
confidence eased over :data:`EASE_S`, so a hand that leaves the frame eases to
rest and back.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from facecapges import rotations as rot
from facecapges.skeleton import UPPER_BODY, Skeleton, rest_positions

MP_TO_BVH = np.diag([1.0, -1.0, -1.0])  # camera axes (x right, y down, z away) → X left, Y up, Z forward
EASE_S = 0.4  # seconds a joint takes to ease to rest (or back) when its confidence changes
MIN_VISIBILITY = 0.5
DEPTH_GAIN = 1.0
HAND_WEIGHT = 0.6  # share of the hand's wrist → middle knuckle in the forearm's image-plane direction (hand seen)
SMOOTH_SIGMA = 1.0  # frames (15 fps) of the zero-phase Gaussian over the pose landmarks
HAND_SIGMA = 1.0  # the same over each hand's landmarks
TORSO_SIGMA = 30.0  # frames: the torso's lean and turn (seen only in depth, noisy) over ~2 s
# The torso's lean towards the camera (the BEAT Spine's X rotation): a frontal camera barely sees it, so the
# landmarker's (smoothed) lean is blended with a population prior by their reliabilities.
# Prior: the mean (and std over frames) of the Spine's X rotation over the BEAT 4-speaker training set
# (speakers 2, 4, 6, 8; CaMN's ``bvh_mean.npy`` / ``bvh_std.npy`` in ../shared/data/beat/stats; speaker 2 is
# one of the four). The landmarker's lean: its rms error against the truth on the development stretch
# (first 80 % of 2_scott_0_1_1 rendered; it reads 4.1° ± 1.4° where he leans 13.1°, r = -0.3 frame by frame).
LEAN_PRIOR_DEG = 15.9
LEAN_PRIOR_SD_DEG = 4.98
LEAN_LANDMARK_RMS_DEG = 9.5
LEAN_WEIGHT = LEAN_PRIOR_SD_DEG**2 / (LEAN_PRIOR_SD_DEG**2 + LEAN_LANDMARK_RMS_DEG**2)  # the landmarker's share: 0.22

# pose landmark indices (BlazePose 33)
NOSE, L_EAR, R_EAR = 0, 7, 8
SHOULDER = {"Left": 11, "Right": 12}
ELBOW = {"Left": 13, "Right": 14}
WRIST = {"Left": 15, "Right": 16}
PINKY = {"Left": 17, "Right": 18}
INDEX = {"Left": 19, "Right": 20}
HIP = {"Left": 23, "Right": 24}

# BEAT finger joint → (hand landmark at the joint, hand landmark at its child)
FINGERS = {
    "Thumb1": (1, 2),
    "Thumb2": (2, 3),
    "Thumb3": (3, 4),
    "Index1": (5, 6),
    "Index2": (6, 7),
    "Index3": (7, 8),
    "Middle1": (9, 10),
    "Middle2": (10, 11),
    "Middle3": (11, 12),
    "Ring1": (13, 14),
    "Ring2": (14, 15),
    "Ring3": (15, 16),
    "Pinky1": (17, 18),
    "Pinky2": (18, 19),
    "Pinky3": (19, 20),
}
SIDES = ("Right", "Left")


@dataclass
class BodyLandmarks:
    """Landmarks of T frames (camera axes, metres; NaN where not seen).

    pose (T, 33, 3) world landmarks; visibility (T, 33); hands (T, 2, 21, 3) world
    landmarks of the subject's right [0] and left [1] hand; hand_score (T, 2) (0: not seen);
    optionally pose_image (T, 33, 3), the pose's image landmarks (x, y normalised by the picture's
    ``image_size`` (width, height)), which give the arm bones' image-plane directions
    (:func:`image_directions`).
    """

    pose: np.ndarray
    visibility: np.ndarray
    hands: np.ndarray
    hand_score: np.ndarray
    fps: float
    pose_image: np.ndarray | None = None
    image_size: tuple[int, int] | None = None

    @property
    def n_frames(self) -> int:
        return int(self.pose.shape[0])


@dataclass
class BodySolve:
    """The solve's result: upper-body pose rot6d (T, 47, 6) and confidence (T, 47) in [0, 1]."""

    pose: np.ndarray
    confidence: np.ndarray


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, 1e-9)


def _frame(a: np.ndarray, lateral: np.ndarray) -> np.ndarray:
    """Orthonormal frame (3, 3), columns (a, lateral ⟂ a, a × lateral)."""
    a = _unit(a)
    lat = _unit(lateral - a * np.dot(lateral, a))
    return np.stack([a, lat, np.cross(a, lat)], axis=-1)


def _rodrigues(axis: np.ndarray, angle: float) -> np.ndarray:
    return rot.exp_so3(_unit(axis) * angle)


class _Rig:
    """The BEAT skeleton's rest directions the solve needs."""

    def __init__(self, skel: Skeleton):
        self.skel = skel
        self.P = rest_positions(skel)
        self.idx = {n: skel.index(n) for n in UPPER_BODY}
        self.slot = {n: k for k, n in enumerate(UPPER_BODY)}

    def bone(self, joint: str, child: str) -> np.ndarray:
        return _unit(self.P[self.skel.index(child)] - self.P[self.skel.index(joint)])

    def hand_frame(self, side: str) -> np.ndarray:
        h = f"{side}Hand"
        a = self.P[self.skel.index(f"{h}Middle1")] - self.P[self.skel.index(h)]
        lat = self.P[self.skel.index(f"{h}Index1")] - self.P[self.skel.index(f"{h}Pinky1")]
        return _frame(a, lat)


def _swing_local(parent_g: np.ndarray, rest_dir: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Local rotation (and new global) that points ``rest_dir`` (rest global) at ``target``."""
    cur = parent_g @ rest_dir
    s = rot.rotation_between(cur, _unit(target))
    g = s @ parent_g
    return parent_g.T @ g, g


def torso_frame(pose: np.ndarray) -> np.ndarray:
    """The torso's rotation (3, 3; columns X left, Y up, Z forward) from one frame's BVH-axes landmarks."""
    up = (pose[SHOULDER["Left"]] + pose[SHOULDER["Right"]]) / 2 - (pose[HIP["Left"]] + pose[HIP["Right"]]) / 2
    left = pose[SHOULDER["Left"]] - pose[SHOULDER["Right"]]
    f = _frame(up, left)  # columns up, left, forward
    torso = np.stack([f[:, 1], f[:, 0], -f[:, 2]], axis=-1)  # columns X (left), Y (up), Z (forward)
    if np.linalg.det(torso) < 0:
        torso[:, 2] *= -1
    return torso


def _twist(R: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The part of rotation ``R`` about unit ``axis`` (swing-twist decomposition)."""
    q = rot.matrix_to_quaternion(R)
    ang = 2.0 * np.arctan2(float(np.dot(q[1:], axis)), float(q[0]))
    return _rodrigues(axis, ang)


def _torso(slow: np.ndarray, fast: np.ndarray, lean_weight: float = LEAN_WEIGHT) -> np.ndarray:
    """The torso frame: its lean and turn (depth-borne, noisy) from the slowly smoothed landmarks
    ``slow``, its roll in the image plane (well seen) from ``fast``; the lean (the pitch of the
    intrinsic X·Y·Z angles, the BEAT Spine's channel order) then blended with :data:`LEAN_PRIOR_DEG`,
    the landmarker's share ``lean_weight`` (1: the landmarker's lean as it is)."""
    g_slow, g_fast = torso_frame(slow), torso_frame(fast)
    fwd = g_slow[:, 2]
    g = _twist(g_fast @ g_slow.T, fwd) @ g_slow
    if lean_weight >= 1.0:
        return g
    e = rot.matrix_to_euler(g, "XYZ")
    e[0] = lean_weight * e[0] + (1.0 - lean_weight) * np.radians(LEAN_PRIOR_DEG)
    return rot.euler_to_matrix(e, "XYZ")


def _solve_frame(
    rig: _Rig,
    pose: np.ndarray,
    hands: list[np.ndarray | None],
    rest: dict[str, np.ndarray],
    torso: np.ndarray | None = None,
    hand_weight: float = 0.0,
) -> dict[str, np.ndarray]:
    """Local rotations of the driven joints for one frame of converted (BVH-axes) landmarks."""
    out: dict[str, np.ndarray] = {}
    if torso is None:
        torso = torso_frame(pose)
    out["Spine"] = torso
    # head: ears line and ear-middle → nose, relative to the torso, split over Neck and Neck1
    ears = (pose[L_EAR] + pose[R_EAR]) / 2
    hf = _frame(pose[NOSE] - ears, pose[L_EAR] - pose[R_EAR])  # columns fwd, left, fwd × left (= up)
    head = np.stack([hf[:, 1], hf[:, 2], hf[:, 0]], axis=-1)  # columns X (left), Y (up), Z (forward)
    rel = torso.T @ head
    half = rot.exp_so3(rot.log_so3(rel) * 0.5)
    out["Neck"] = out["Neck1"] = half
    for s, side in enumerate(SIDES):
        g_parent = torso  # Spine1-3 and the clavicle at rest
        out[f"{side}Shoulder"] = np.eye(3)
        d_up = pose[ELBOW[side]] - pose[SHOULDER[side]]
        d_fo = pose[WRIST[side]] - pose[ELBOW[side]]
        hand = hands[s]
        if hand is not None and hand_weight > 0:
            # the hand landmarker's wrist → middle knuckle as a second view of the forearm's direction in
            # the image plane, where it is sharp; its depth is poorer than the pose's, so depth stays the pose's
            u, h = _unit(d_fo), _unit(hand[9] - hand[0])
            xy = (1.0 - hand_weight) * u[:2] + hand_weight * h[:2]
            d_fo = np.array([xy[0], xy[1], u[2]])
        r_up = rig.bone(f"{side}Arm", f"{side}ForeArm")
        local, g_arm = _swing_local(g_parent, r_up, d_up)
        # turn the upper arm about its bone so the elbow bends in its rest hinge plane
        n0 = _unit(np.cross(r_up, [0.0, 0.0, 1.0]))
        n = np.cross(_unit(d_up), _unit(d_fo))
        bend = float(np.linalg.norm(n))
        if bend > 1e-3:
            have = g_arm @ n0
            axis = _unit(d_up)
            n = n / bend
            ang = float(np.arctan2(np.dot(np.cross(have, n), axis), np.dot(have, n)))
            w = min(1.0, bend / 0.5)
            g_arm = _rodrigues(axis, w * ang) @ g_arm
            local = g_parent.T @ g_arm
        out[f"{side}Arm"] = local
        r_fo = rig.bone(f"{side}ForeArm", f"{side}Hand")
        local_fo, g_fo = _swing_local(g_arm, r_fo, d_fo)
        # the hand's frame: from the hand landmarks, else the pose's coarse hand points
        if hand is not None:
            hand_f = _frame(hand[9] - hand[0], hand[5] - hand[17])
        else:
            mid = (pose[INDEX[side]] + pose[PINKY[side]]) / 2
            hand_f = _frame(mid - pose[WRIST[side]], pose[INDEX[side]] - pose[PINKY[side]])
        g_hand = hand_f @ rig.hand_frame(side).T
        # forearm twist: the part of the hand's turn about the forearm bone
        rel_h = g_fo.T @ g_hand
        ax = r_fo
        q = rot.matrix_to_quaternion(rel_h)
        proj = np.dot(q[1:], ax)
        twist = 2.0 * np.arctan2(proj, q[0])
        twist = (twist + np.pi) % (2 * np.pi) - np.pi
        tw = _rodrigues(ax, float(twist))
        local_fo = local_fo @ tw
        g_fo = g_fo @ tw
        out[f"{side}ForeArm"] = local_fo
        out[f"{side}Hand"] = g_fo.T @ g_hand
        g_h = g_hand
        for name in ("Index", "Ring", "Pinky"):
            out[f"{side}Hand{name}"] = np.eye(3)
        if hand is None:
            for name in FINGERS:
                out[f"{side}Hand{name}"] = rest[f"{side}Hand{name}"]
            continue
        # fingers: each phalanx swings to its landmark direction
        globals_: dict[str, np.ndarray] = {}
        for name, (a, b) in FINGERS.items():
            finger, k = name[:-1], int(name[-1])
            # first phalanges hang off the hand or a metacarpal at rest (the thumb off HandIndex): the hand's frame
            parent = g_h if k == 1 else globals_[f"{finger}{k - 1}"]
            child = f"{side}Hand{finger}{k + 1}" if k < 3 else f"{side}Hand{finger}4"
            if child not in rig.skel.names:
                break
            rdir = rig.bone(f"{side}Hand{name}", child)
            loc, g = _swing_local(parent, rdir, hand[b] - hand[a])
            out[f"{side}Hand{name}"] = loc
            globals_[name] = g
    return out


def _confidence(rig: _Rig, vis: np.ndarray, hand_score: np.ndarray) -> np.ndarray:
    """Per-joint confidence (47,) of one frame: the pose's visibility for the torso and arms, the hand's
    presence for the fingers (the hand itself: at least half the forearm's)."""
    c = np.ones(len(UPPER_BODY))
    for s, side in enumerate(SIDES):
        arm = float(min(vis[SHOULDER[side]], vis[ELBOW[side]]))
        fore = float(min(vis[ELBOW[side]], vis[WRIST[side]]))
        for n in UPPER_BODY:
            if not n.startswith(side):
                continue
            if n in (f"{side}Shoulder", f"{side}Arm"):
                c[rig.slot[n]] = arm
            elif n == f"{side}ForeArm":
                c[rig.slot[n]] = fore
            elif n == f"{side}Hand":
                c[rig.slot[n]] = max(float(hand_score[s]), 0.5 * fore)
            else:
                c[rig.slot[n]] = float(hand_score[s])
    c[:3] = float(min(vis[SHOULDER["Left"]], vis[SHOULDER["Right"]]))
    return c


def _rest_pose(rig: _Rig) -> dict[str, np.ndarray]:
    """Relaxed rest: torso upright, arms hanging slightly forward, hands and fingers at rest."""
    out = {n: np.eye(3) for n in UPPER_BODY}
    for side in SIDES:
        sgn = 1.0 if side == "Left" else -1.0
        r_up = rig.bone(f"{side}Arm", f"{side}ForeArm")
        loc, g = _swing_local(np.eye(3), r_up, np.array([0.12 * sgn, -1.0, 0.05]))
        out[f"{side}Arm"] = loc
        r_fo = rig.bone(f"{side}ForeArm", f"{side}Hand")
        out[f"{side}ForeArm"], _ = _swing_local(g, r_fo, np.array([0.05 * sgn, -0.8, 0.45]))
    return out


ARM_CHAINS = [(SHOULDER[s], ELBOW[s], WRIST[s]) for s in SIDES]


def _arm_lengths(pose: np.ndarray) -> dict[tuple[int, int], float]:
    """Each arm bone's length: the median over the clip of its 3D length in the world landmarks."""
    out = {}
    for a, b, c in ARM_CHAINS:
        for i, j in ((a, b), (b, c)):
            d = np.linalg.norm(pose[:, j] - pose[:, i], axis=-1)
            d = d[np.isfinite(d)]
            out[(i, j)] = float(np.median(d)) if len(d) else 0.0
    return out


def _complete_depth(p: np.ndarray, lengths: dict[tuple[int, int], float]) -> np.ndarray:
    """Forearm depths from bone lengths (camera axes, one frame's (33, 3)).

    The landmarker's image-plane offsets (x, y) are good, its depth offsets (z) are
    compressed. A forearm of known length L whose image-plane offset is shorter than L
    must make up the rest in depth: |dz| = sqrt(L² − dx² − dy²), with the sign the
    landmarker gives (kept when it already says more). The upper arm keeps the landmarker's
    depth: it hangs nearly in the image plane (his median 10° out of it), where a 2D length a few
    per cent short of L already asks for 15–20° of depth, often with the wrong sign (on the
    development stretch its completion made the elevation error 8–10° → 10–11° and flipped the
    elbow behind the shoulder in most of the worst frames)."""
    p = p.copy()
    for _, i, j in ARM_CHAINS:
        d = p[j] - p[i]
        L = lengths[(i, j)]
        dz = np.sqrt(max(L * L - d[0] ** 2 - d[1] ** 2, 0.0))
        if dz > abs(d[2]):
            p[j, 2] += np.sign(d[2]) * dz - d[2] if d[2] != 0 else 0.0
    return p


def image_directions(pose: np.ndarray, pose_image: np.ndarray | None, size: tuple[int, int] | None) -> np.ndarray:
    """World landmarks (..., 33, 3; camera axes) with each arm bone's image-plane direction taken from the
    image landmarks (..., 33, 3; x, y normalised by ``size`` = (width, height)) — its image-plane length and
    its depth stay the world landmarks'; the elbow, the wrist and the hand points move with their bone.

    On the development stretch the image landmarks' bone directions were 2.2–2.8° (median) from the truth
    seen through the render's camera, the world landmarks' x, y 3.3–7.6°: the world landmarks flatten the
    picture's perspective unevenly. Nothing is assumed about the camera (no field of view): the direction
    is the picture's as it is."""
    if pose_image is None or size is None:
        return pose
    img = pose_image[..., :2] * np.asarray(size, np.float64)  # pixels (x right, y down, as the camera axes)
    p = pose.copy()
    for side in SIDES:
        s, e, w = SHOULDER[side], ELBOW[side], WRIST[side]
        start = p[..., s, :]
        moved = []
        for i, j in ((s, e), (e, w)):
            d = pose[..., j, :] - pose[..., i, :]
            u = img[..., j, :] - img[..., i, :]
            n = np.linalg.norm(u, axis=-1, keepdims=True)
            ok = np.isfinite(n) & (n > 1e-6)
            xy = np.where(ok, u / np.where(ok, n, 1.0) * np.linalg.norm(d[..., :2], axis=-1, keepdims=True), d[..., :2])
            start = start + np.concatenate([xy, d[..., 2:]], axis=-1)
            moved.append(start)
        shift = moved[1] - p[..., w, :]
        for k in (INDEX[side], PINKY[side]):
            p[..., k, :] = p[..., k, :] + shift
        p[..., e, :], p[..., w, :] = moved
    return p


def _ease_step(cur: np.ndarray, target: np.ndarray, fps: float) -> np.ndarray:
    """One frame of the easing: ``cur`` moves towards ``target`` by at most 1/(EASE_S·fps)."""
    step = 1.0 / max(EASE_S * fps, 1.0)
    return cur + np.clip(target - cur, -step, step)


def _ease(target: np.ndarray, fps: float) -> np.ndarray:
    """Confidence eased in time: moves towards ``target`` (T, K) by at most 1/(EASE_S·fps) per frame."""
    out = np.empty_like(target)
    cur = target[0].copy()
    for t in range(len(target)):
        cur = _ease_step(cur, target[t], fps)
        out[t] = cur
    return out


def smooth_segments(x: np.ndarray, seen: np.ndarray, sigma: float) -> np.ndarray:
    """Zero-phase Gaussian smoothing (``sigma`` frames) of ``x`` (T, ...) along time, within each run of seen frames.

    Offline capture may look ahead, so a symmetric filter smooths without the lag a causal
    filter (One-Euro) adds; runs are smoothed apart so a lost stretch does not bleed in."""
    from scipy.ndimage import gaussian_filter1d

    out = x.copy()
    if sigma <= 0:
        return out
    t = 0
    T = len(x)
    while t < T:
        if not seen[t]:
            t += 1
            continue
        e = t
        while e < T and seen[e]:
            e += 1
        if e - t > 1:
            out[t:e] = gaussian_filter1d(x[t:e], sigma, axis=0, mode="nearest")
        t = e
    return out


# A style's database replays the captured motion as it is, so the motion ``styles build --video`` puts
# there is smoothed further (chosen on the development stretch, docs/capture-body.md "A smoother capture
# for a style"): every joint's rotation over time with a Gaussian of STYLE_SIGMA frames (the fingers
# FINGER_SIGMA), then the frames where a joint still accelerates faster than ACCEL_LIMIT are smoothed
# again, locally, until none does.
STYLE_SIGMA = 1.0  # frames (15 fps): the rotations of every joint but the fingers
FINGER_SIGMA = 2.0  # frames: the finger joints' (the hand landmarker's fingers jitter most)
ACCEL_LIMIT = 124.0  # rad/s² per joint: half his whole-body 99.9th percentile (the pop rule's threshold)
LIMIT_SIGMA = 2.0  # frames: the Gaussian each pass of the limiter blends in around a frame over the limit
LIMIT_PASSES = 30


def _finger_joints() -> list[int]:
    return [j for j, n in enumerate(UPPER_BODY) if any(k in n for k in ("Thumb", "Index", "Middle", "Ring", "Pinky"))]


def smooth_for_style(
    pose: np.ndarray,
    fps: float,
    sigma: float = STYLE_SIGMA,
    finger_sigma: float = FINGER_SIGMA,
    limit: float = ACCEL_LIMIT,
) -> np.ndarray:
    """Captured rot6d poses (T, 47, 6) smoothed for a style's database: a zero-phase Gaussian over time
    (:func:`smooth_segments`, ``sigma`` frames, ``finger_sigma`` for the fingers), then an offline
    acceleration limiter: wherever a joint's angular acceleration (:func:`rotations.angular_acceleration`)
    exceeds ``limit`` rad/s², that joint's frames within ±2 of it take a Gaussian of :data:`LIMIT_SIGMA`,
    pass after pass (at most :data:`LIMIT_PASSES`). Rotations are re-orthonormalised after each step."""
    from scipy.ndimage import binary_dilation

    x = np.asarray(pose, dtype=np.float64)
    every = np.ones(len(x), dtype=bool)
    fingers = _finger_joints()
    rest = [j for j in range(x.shape[1]) if j not in fingers]
    out = x.copy()
    out[:, rest] = smooth_segments(x[:, rest], every, sigma)
    out[:, fingers] = smooth_segments(x[:, fingers], every, finger_sigma)
    out = rot.normalize_rot6d(out)
    for _ in range(LIMIT_PASSES):
        over = rot.angular_acceleration(out, fps) > limit  # (T, 47)
        if not over.any():
            break
        near = binary_dilation(over, structure=np.ones((3, 1), dtype=bool), iterations=2)
        out = rot.normalize_rot6d(np.where(near[..., None], smooth_segments(out, every, LIMIT_SIGMA), out))
    return out.astype(np.float32)


def solve(
    skel: Skeleton,
    lm: BodyLandmarks,
    smooth: bool = True,
    depth_completion: bool = True,
    depth_gain: float = DEPTH_GAIN,
    sigma: float = SMOOTH_SIGMA,
    hand_sigma: float = HAND_SIGMA,
    torso_sigma: float = TORSO_SIGMA,
    hand_weight: float = HAND_WEIGHT,
    lean_weight: float = LEAN_WEIGHT,
    image_dirs: bool = True,
) -> BodySolve:
    """BEAT upper-body pose rot6d (T, 47, 6) and per-joint confidence (T, 47) from landmarks."""
    rig = _Rig(skel)
    T = lm.n_frames
    rest = _rest_pose(rig)
    lengths = _arm_lengths(lm.pose * [1.0, 1.0, depth_gain]) if depth_completion else None
    rest_arr = np.stack([rest[n] for n in UPPER_BODY])
    seen = np.isfinite(lm.pose).all(axis=(1, 2))
    pose = image_directions(lm.pose, lm.pose_image, lm.image_size) if image_dirs else lm.pose
    seen &= np.isfinite(pose).all(axis=(1, 2))
    P = np.where(seen[:, None, None], pose, 0.0) * [1.0, 1.0, depth_gain]
    if lengths is not None:
        P = np.stack([_complete_depth(p, lengths) if ok else p for p, ok in zip(P, seen, strict=True)])
    P = P @ MP_TO_BVH.T
    torso_P = P
    hand_seen = (lm.hand_score > 0) & np.isfinite(lm.hands).all(axis=(2, 3))
    H = np.where(hand_seen[:, :, None, None], lm.hands, 0.0) @ MP_TO_BVH.T
    if smooth:
        torso_P = smooth_segments(P, seen, torso_sigma)
        P = smooth_segments(P, seen, sigma)
        H = np.stack([smooth_segments(H[:, s], hand_seen[:, s], hand_sigma) for s in range(2)], axis=1)
    mats = np.broadcast_to(rest_arr, (T, len(UPPER_BODY), 3, 3)).copy()
    conf = np.zeros((T, len(UPPER_BODY)))
    last = rest_arr.copy()
    for t in range(T):
        if not seen[t]:
            mats[t] = last
            continue
        p = P[t]
        hands: list[np.ndarray | None] = [H[t, s] if hand_seen[t, s] else None for s in range(2)]
        torso = _torso(torso_P[t], p, lean_weight)
        local = _solve_frame(rig, p, hands, rest, torso, hand_weight)
        mats[t] = np.stack([local[n] for n in UPPER_BODY])
        last = mats[t]
        conf[t] = _confidence(rig, lm.visibility[t], lm.hand_score[t])
    # a joint below MIN_VISIBILITY eases to rest, and back when it is seen again
    weight = _ease((conf >= MIN_VISIBILITY).astype(np.float64), lm.fps)
    q = rot.matrix_to_quaternion(mats)
    q_rest = np.broadcast_to(rot.matrix_to_quaternion(rest_arr), q.shape)
    q = rot.quaternion_slerp(q_rest, q, weight[..., None])
    out = rot.matrix_to_rot6d(rot.quaternion_to_matrix(q)).astype(np.float32)
    return BodySolve(pose=out, confidence=conf.astype(np.float32))


# ------------------------------------------------------------------ causal, frame by frame (live --body)
LIVE_POSE_FILTER = (1.0, 2.0)  # One-Euro (min cut-off Hz, beta per m/s) of the pose landmarks, live
LIVE_HAND_FILTER = (1.5, 2.0)  # the same for each hand's landmarks
LIVE_ROT_FILTER = (3.0, 0.5)  # One-Euro (min cut-off Hz, beta per rad/s) of the solved rotations
LIVE_FINGER_FILTER = (0.2, 0.0)  # the same for the finger joints (the hand model's fingers jitter most)
LIVE_TWIST_FILTER = (0.5, 0.0)  # One-Euro of each forearm's twist about its bone (cos, sin of the angle)
HAND_FADE_S = 0.5  # seconds over which a hand the hand landmarker finds or loses fades in or out of the solve
LENGTH_WINDOW = 150  # frames (10 s) of seen arm-bone lengths whose median the live depth completion uses


class OneEuro:
    """The One-Euro filter (Casiez et al. 2012), causal, over arrays of points (..., 3); each point's
    cut-off rises with its own speed (the norm of its filtered velocity). PyPI's ``OneEuroFilter``
    filters one float at a time (225 filter objects a frame here, each coordinate's speed apart)."""

    def __init__(self, fps: float, min_cutoff: float, beta: float, d_cutoff: float = 1.0):
        self.dt = 1.0 / fps
        self.min_cutoff, self.beta, self.d_cutoff = min_cutoff, beta, d_cutoff
        self.x: np.ndarray | None = None
        self.dx: np.ndarray | None = None

    def _alpha(self, cutoff: np.ndarray | float) -> np.ndarray:
        tau = 1.0 / (2.0 * np.pi * np.asarray(cutoff))
        return 1.0 / (1.0 + tau / self.dt)

    def _share(self, d: np.ndarray) -> np.ndarray:
        """The share (..., 1) of this frame's displacement ``d`` (..., 3) from the filtered value to keep."""
        assert self.dx is not None
        self.dx = self.dx + self._alpha(self.d_cutoff) * (d / self.dt - self.dx)
        speed = np.linalg.norm(self.dx, axis=-1, keepdims=True)
        return self._alpha(self.min_cutoff + self.beta * speed)

    def reset(self) -> None:
        self.x = self.dx = None

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if self.x is None or self.dx is None:
            self.x, self.dx = x.copy(), np.zeros_like(x)
            return x.copy()
        d = x - self.x
        self.x = self.x + self._share(d) * d
        return self.x.copy()


class RotationOneEuro(OneEuro):
    """The same over unit quaternions (..., 4): the displacement is the rotation vector from the filtered
    rotation to the new one, the speed an angular speed (rad/s)."""

    def __call__(self, q: np.ndarray) -> np.ndarray:
        if self.x is None or self.dx is None:
            self.x, self.dx = q.copy(), np.zeros(q.shape[:-1] + (3,))
            return q.copy()
        d = rot.quaternion_log(rot.standardize_quaternion(rot.quaternion_multiply(q, rot.quaternion_invert(self.x))))
        self.x = rot.standardize_quaternion(rot.quaternion_multiply(rot.quaternion_exp(self._share(d) * d), self.x))
        return self.x.copy()


class StreamSolver:
    """:func:`solve` one frame at a time, causally (``live --body``): nothing from later frames is used.

    The same per-frame solve (:func:`_solve_frame`), confidence and easing to rest; what :func:`solve`
    takes from the whole clip is taken from the past here: the landmarks are filtered by a One-Euro
    filter (:data:`LIVE_POSE_FILTER`, :data:`LIVE_HAND_FILTER`; reset where they are lost) instead of
    the zero-phase Gaussian, the torso's slow lean and turn by an exponential average over
    :data:`TORSO_SIGMA` frames instead of the Gaussian of that σ, and the depth completion's bone
    lengths are the median of the last :data:`LENGTH_WINDOW` frames' instead of the clip's.

    Three more steps keep a live arm as smooth as real motion. On the development stretch (20 s of
    1_1's first 80 %, rendered) the plain causal solve's whole-body acceleration exceeded his real
    motion's 99.9th percentile (the conversation metric's pop rule) on 73 % of the frames (capture-body's
    offline solve: 71 %): the hand landmarker finds and loses a hand every few frames (139 changes in
    300 frames), and the forearm's twist, taken from the hand's orientation, jumps with it. So:

    * a hand that the hand landmarker finds or loses **fades** in or out over :data:`HAND_FADE_S`
      (the solve with its last landmarks and the solve without it, slerped): 73 → 62 %;
    * each forearm's **twist** about its bone has its own filter (:data:`LIVE_TWIST_FILTER`), its
      swing (the arm's direction) keeps the solve's;
    * all rotations go through a rotation One-Euro filter (:data:`LIVE_ROT_FILTER`), the fingers a
      heavier one (:data:`LIVE_FINGER_FILTER`): 0 % of the frames above the threshold, the median
      acceleration 61 rad/s² (his 49), arm directions 15.8° / 30.5° (median / p90) against 15.2° / 30.0°
      unfiltered and 15.3° / 28.6° offline.
    """

    def __init__(
        self,
        skel: Skeleton,
        fps: float,
        hand_weight: float = HAND_WEIGHT,
        lean_weight: float = LEAN_WEIGHT,
        image_dirs: bool = False,
    ):
        self.rig = _Rig(skel)
        self.fps = float(fps)
        self.hand_weight = hand_weight
        self.lean_weight = lean_weight
        self.image_dirs = image_dirs
        self.rest = _rest_pose(self.rig)
        self.q_rest = rot.matrix_to_quaternion(np.stack([self.rest[n] for n in UPPER_BODY]))
        self.pose_f = OneEuro(fps, *LIVE_POSE_FILTER)
        self.hand_f = [OneEuro(fps, *LIVE_HAND_FILTER) for _ in SIDES]
        self.rot_f = RotationOneEuro(fps, *LIVE_ROT_FILTER)
        self.finger_f = RotationOneEuro(fps, *LIVE_FINGER_FILTER)
        self.fingers = np.array(
            [
                k
                for k, n in enumerate(UPPER_BODY)
                for side in SIDES
                if n.startswith(f"{side}Hand") and n != f"{side}Hand"
            ]
        )
        self.sides = [np.array([k for k, n in enumerate(UPPER_BODY) if n.startswith(side)]) for side in SIDES]
        self.twist_f = OneEuro(fps, *LIVE_TWIST_FILTER)
        self.forearms = np.array([UPPER_BODY.index(f"{side}ForeArm") for side in SIDES])
        self.twist_axes = np.stack([self.rig.bone(f"{side}ForeArm", f"{side}Hand") for side in SIDES])
        self.torso_slow: np.ndarray | None = None
        self.lengths: deque[np.ndarray] = deque(maxlen=LENGTH_WINDOW)
        self.q_last = self.q_rest.copy()
        self.weight: np.ndarray | None = None
        self.hand_w = np.zeros(len(SIDES))  # how much of each hand's landmarks the solve takes (fading)
        self.hand_held: list[np.ndarray | None] = [None] * len(SIDES)  # each hand's last filtered landmarks

    def _depth(self, pose: np.ndarray) -> np.ndarray:
        """Depth completion with the recent frames' median bone lengths (this frame's included)."""
        bones = [(i, j) for a, b, c in ARM_CHAINS for i, j in ((a, b), (b, c))]
        self.lengths.append(np.array([np.linalg.norm(pose[j] - pose[i]) for i, j in bones]))
        med = np.median(np.stack(self.lengths), axis=0)
        return _complete_depth(pose, {bone: float(m) for bone, m in zip(bones, med, strict=True)})

    def _hands(self, hands: list[np.ndarray | None], hand_score: np.ndarray) -> None:
        """Filter each found hand, hold its last landmarks, fade its weight in or out."""
        step = 1.0 / max(HAND_FADE_S * self.fps, 1.0)
        for s in range(len(SIDES)):
            h = hands[s]
            if h is not None and hand_score[s] > 0 and np.isfinite(h).all():
                self.hand_held[s] = self.hand_f[s](np.asarray(h, np.float64) @ MP_TO_BVH.T)
                self.hand_w[s] = min(self.hand_w[s] + step, 1.0)
            else:
                self.hand_f[s].reset()
                self.hand_w[s] = max(self.hand_w[s] - step, 0.0)

    def _solve(self, P: np.ndarray, torso: np.ndarray) -> np.ndarray:
        """Local quaternions (47, 4) of one frame, each hand faded in by its weight."""

        def one(use: list[bool]) -> np.ndarray:
            hs = [self.hand_held[s] if use[s] else None for s in range(len(SIDES))]
            local = _solve_frame(self.rig, P, hs, self.rest, torso, self.hand_weight)
            return rot.matrix_to_quaternion(np.stack([local[n] for n in UPPER_BODY]))

        full = [bool(w > 0 and self.hand_held[s] is not None) for s, w in enumerate(self.hand_w)]
        q = one(full)
        partial = [s for s in range(len(SIDES)) if full[s] and self.hand_w[s] < 1.0]
        if partial:  # a hand fading in or out: slerp its arm between the solves without and with it
            q0 = one([False] * len(SIDES))
            for s in partial:
                J = self.sides[s]
                q[J] = rot.quaternion_slerp(q0[J], q[J], self.hand_w[s])
        return q

    def _filter_twist(self, q: np.ndarray) -> np.ndarray:
        """Each forearm's twist about its bone (from the hand's orientation: the noisiest part of the solve)
        through its own filter, its swing as solved."""
        qf = q[self.forearms]
        ax = self.twist_axes
        proj = (qf[:, 1:] * ax).sum(-1)
        ang = 2.0 * np.arctan2(proj, qf[:, 0])
        twist = np.concatenate([np.cos(ang / 2)[:, None], np.sin(ang / 2)[:, None] * ax], axis=-1)
        swing = rot.quaternion_multiply(qf, rot.quaternion_invert(twist))
        cs = self.twist_f(np.stack([np.cos(ang), np.sin(ang)], axis=-1))
        a = np.arctan2(cs[:, 1], cs[:, 0])
        twist_f = np.concatenate([np.cos(a / 2)[:, None], np.sin(a / 2)[:, None] * ax], axis=-1)
        out = q.copy()
        out[self.forearms] = rot.quaternion_multiply(swing, twist_f)
        return out

    def step(
        self,
        pose: np.ndarray | None,
        visibility: np.ndarray,
        hands: list[np.ndarray | None],
        hand_score: np.ndarray,
        pose_image: np.ndarray | None = None,
        image_size: tuple[int, int] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """One frame: pose world landmarks (33, 3) or None (no person), their visibility (33,), each hand's
        world landmarks (21, 3) or None, the hands' scores (2,), optionally the pose's image landmarks (33, 3)
        in a picture of ``image_size`` (:func:`image_directions`) → local quaternions (47, 4) and the
        per-joint confidence (47,). With no person the last pose is held (confidence 0, easing to rest)."""
        if pose is not None and self.image_dirs:
            pose = image_directions(np.asarray(pose, np.float64), pose_image, image_size)
        if pose is None or not np.isfinite(pose).all():
            self.pose_f.reset()
            self._hands([None] * len(SIDES), np.zeros(len(SIDES)))
            conf = np.zeros(len(UPPER_BODY))
            q = self.q_last
        else:
            P = self.pose_f(self._depth(np.asarray(pose, np.float64)) @ MP_TO_BVH.T)
            a = 1.0 / TORSO_SIGMA
            self.torso_slow = P.copy() if self.torso_slow is None else self.torso_slow + a * (P - self.torso_slow)
            self._hands(hands, hand_score)
            q = self.rot_f(self._filter_twist(self._solve(P, _torso(self.torso_slow, P, self.lean_weight))))
            q[self.fingers] = self.finger_f(q[self.fingers])
            self.q_last = q
            conf = _confidence(self.rig, visibility, hand_score)
        target = (conf >= MIN_VISIBILITY).astype(np.float64)
        self.weight = target if self.weight is None else _ease_step(self.weight, target, self.fps)
        return rot.quaternion_slerp(self.q_rest, q, self.weight[:, None]), conf
