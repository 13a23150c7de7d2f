"""The avatar's geometry: a procedural upper body skinned to the BEAT skeleton, and a
blendshape face mounted on its Head joint.

Conventions
-----------
* Built in the skeleton's **rest pose** (every BVH rotation 0, joints at the summed
  ``OFFSET``\\s), in the BVH unit (BEAT: cm), right-handed, Y up, the character facing
  +Z. :mod:`facecapges.avatar.gltf` converts to metres.
* **Body** (:class:`SkinnedMesh`): torso, neck, arms, palms and five fingers per hand
  as swept tubes along the joints, with linear blend skinning (``v' = Σ_k w_k G_k
  B_k⁻¹ v``; up to 4 joints per vertex). Weights follow the bone a vertex sits on and
  blend linearly to 50/50 at each joint over ``blend`` cm, so elbows and knuckles bend
  smoothly. Legs are not modelled (the model drives the upper body only); the torso
  ends at the hips.
* **Face** (:class:`FaceMesh`): the neutral face mesh (MediaPipe's canonical face by
  default) plus a closed back of the head swept from the face's outline, in the
  Head joint's frame (``offset`` cm from it). It carries the blendshape targets as
  morph targets (thesis eq. 2.11: ``F = F0 + Σ w_i (B_i − F0)``); the back of the head
  never moves. Triangles are grouped by material: skin, hair, the eye openings and the
  mouth opening (the canonical mesh closes the mouth with triangles, drawn dark, so an
  open jaw reads at a glance).
* **Eyes**: the canonical mesh's eye-opening triangles are replaced by a dark socket
  (the opening's rim swept 2 cm into the head, following the lids) holding an
  eyeball (sclera, iris, pupil) just behind the lids; the ``eyeLook*`` targets rotate
  each eyeball about its centre (``GAZE_DEG`` at weight 1) as morph targets, so every
  glTF consumer shows the gaze, and a blink closes the lids over the eyeball.
* The back of the head is swept from the face's outline; under the jaw it tucks in
  towards the neck instead of bulging out, so no strip of it shows below the jaw line.
* The face is placed so that its 17.7 cm (chin to hairline) fits between the Head and
  HeadEnd joints; sizes of the body parts are fractions of the skeleton's own bone
  lengths where a bone fixes them, and plain centimetres otherwise (documented at each
  constant).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from facecapges import rotations as rot
from facecapges.avatar.mesh import TriMesh
from facecapges.errors import UserError
from facecapges.skeleton import UPPER_BODY, Skeleton, rest_positions

SKIN = "skin"
SHIRT = "shirt"
HAIR = "hair"
EYE = "eye"
MOUTH = "mouth"
SCLERA = "sclera"
IRIS = "iris"
PUPIL = "pupil"
COLORS = {  # linear-ish base colours (RGBA) of the glTF materials
    SKIN: (0.80, 0.55, 0.42, 1.0),
    SHIRT: (0.16, 0.27, 0.48, 1.0),
    HAIR: (0.10, 0.065, 0.04, 1.0),
    EYE: (0.03, 0.025, 0.025, 1.0),  # the eye sockets behind the eyeballs
    MOUTH: (0.30, 0.05, 0.06, 1.0),
    SCLERA: (0.86, 0.84, 0.80, 1.0),
    IRIS: (0.16, 0.09, 0.04, 1.0),
    PUPIL: (0.01, 0.01, 0.01, 1.0),
}
# eyeballs: radius as a fraction of the eye opening's width (an adult eye: 12 mm for a
# 30 mm wide opening), the largest gaze angles of the eyeLook* targets at weight 1
# (ARKit leaves them unstated; the human oculomotor range is about ±35°, gaze in
# conversation stays well inside it), and the iris/pupil as angles from the gaze axis
EYEBALL_RADIUS = 0.42
GAZE_DEG = {"Up": 25.0, "Down": 30.0, "In": 30.0, "Out": 30.0}
IRIS_RAD, PUPIL_RAD = 0.52, 0.22
REQUIRED_JOINTS = UPPER_BODY + ("Hips", "Spine1", "Spine2", "Spine3", "Head", "HeadEnd")
FINGERS = ("Thumb", "Index", "Middle", "Ring", "Pinky")


@dataclass
class SkinnedMesh:
    vertices: np.ndarray  # (N, 3) rest pose, skeleton unit
    normals: np.ndarray  # (N, 3)
    joints: np.ndarray  # (N, 4) skeleton joint indices
    weights: np.ndarray  # (N, 4) summing to 1
    faces: dict[str, np.ndarray]  # material -> (F, 3)


@dataclass
class FaceMesh:
    vertices: np.ndarray  # (N, 3) in the Head joint's frame
    normals: np.ndarray
    faces: dict[str, np.ndarray]
    names: list[str]  # blendshape names
    deltas: np.ndarray  # (T, N, 3) position offsets
    normal_deltas: np.ndarray  # (T, N, 3)
    offset: np.ndarray  # (3,) face origin relative to the Head joint


@dataclass
class Avatar:
    skeleton: Skeleton
    rest: np.ndarray  # (J, 3) rest joint positions
    body: SkinnedMesh
    face: FaceMesh
    info: dict = field(default_factory=dict)


def check_skeleton(skel: Skeleton, name: str = "skeleton") -> None:
    """UserError unless ``skel`` is a BEAT skeleton (the joints the avatar binds to)."""
    missing = skel.missing(REQUIRED_JOINTS)
    if missing:
        raise UserError(f"{name}: not a BEAT skeleton; missing joints {missing[:6]}{' …' if len(missing) > 6 else ''}")


# ------------------------------------------------------------------ mesh builder
class _Builder:
    """Accumulates vertices with skin weights and per-material triangles."""

    def __init__(self) -> None:
        self.v: list[np.ndarray] = []
        self.w: list[dict[int, float]] = []
        self.f: dict[str, list[np.ndarray]] = {}
        self.n = 0

    def add(self, verts: np.ndarray, weights: list[dict[int, float]], faces: np.ndarray, material: str) -> None:
        self.v.append(verts)
        self.w.extend(weights)
        self.f.setdefault(material, []).append(faces + self.n)
        self.n += len(verts)

    def build(self) -> SkinnedMesh:
        V = np.concatenate(self.v)
        J = np.zeros((len(V), 4), np.int64)
        W = np.zeros((len(V), 4))
        for i, wd in enumerate(self.w):
            top = sorted(((j, w) for j, w in wd.items() if w > 1e-6), key=lambda kv: -kv[1])[:4]
            s = sum(w for _, w in top)
            for k, (j, w) in enumerate(top):
                J[i, k], W[i, k] = j, w / s
        faces = {m: np.concatenate(fs) for m, fs in self.f.items()}
        allf = np.concatenate(list(faces.values()))
        return SkinnedMesh(V, TriMesh(V, allf).vertex_normals(), J, W, faces)


def _frame(t: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to tangent ``t``, the first close to ``ref``."""
    u = ref - np.dot(ref, t) * t
    if np.linalg.norm(u) < 1e-6:
        u = np.cross(t, [1.0, 0.0, 0.0]) if abs(t[0]) < 0.9 else np.cross(t, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    return u, np.cross(t, u)


def _tube(
    centers: np.ndarray,
    radii: np.ndarray,
    n_around: int = 14,
    ref=(0.0, 1.0, 0.0),
    cap_start: bool = True,
    cap_end: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A closed tube through ``centers`` (K, 3): vertices, triangles, and each vertex's ring
    index (caps get −1 at the start and K at the end). ``radii`` (K,) or (K, 2) for an
    elliptic section (along ``ref``-ish axis, along the other axis)."""
    K = len(centers)
    radii = np.asarray(radii, np.float64)
    if radii.ndim == 1:
        radii = np.stack([radii, radii], 1)
    ang = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    verts, ring_of = [], []
    u_prev = np.asarray(ref, np.float64)
    for k in range(K):
        t = centers[min(k + 1, K - 1)] - centers[max(k - 1, 0)]
        t /= np.linalg.norm(t)
        u, w = _frame(t, u_prev)
        u_prev = u
        ring = centers[k] + radii[k, 0] * np.cos(ang)[:, None] * u + radii[k, 1] * np.sin(ang)[:, None] * w
        verts.append(ring)
        ring_of += [k] * n_around
    faces = []
    for k in range(K - 1):
        a = k * n_around + np.arange(n_around)
        b = k * n_around + (np.arange(n_around) + 1) % n_around
        faces += [np.stack([a, b, b + n_around], 1), np.stack([a, b + n_around, a + n_around], 1)]
    V = np.concatenate(verts)
    n = len(V)
    extra = []
    if cap_start:
        t0 = centers[1] - centers[0]
        extra.append(centers[0] - 0.6 * radii[0].mean() * t0 / np.linalg.norm(t0))
        ring_of.append(-1)
        a = np.arange(n_around)
        faces.append(np.stack([np.full(n_around, n), (a + 1) % n_around, a], 1))
    if cap_end:
        t1 = centers[-1] - centers[-2]
        extra.append(centers[-1] + 0.6 * radii[-1].mean() * t1 / np.linalg.norm(t1))
        ring_of.append(K)
        a = (K - 1) * n_around + np.arange(n_around)
        faces.append(
            np.stack(
                [np.full(n_around, n + len(extra) - 1), a, (K - 1) * n_around + (np.arange(n_around) + 1) % n_around], 1
            )
        )
    if extra:
        V = np.concatenate([V, np.asarray(extra)])
    F = np.concatenate(faces).astype(np.int64)
    # orient outwards: compare the first side triangle's normal with the radial direction
    c = F[0]
    nrm = np.cross(V[c[1]] - V[c[0]], V[c[2]] - V[c[0]])
    if np.dot(nrm, V[c[0]] - centers[0]) < 0:
        F = F[:, ::-1]
    return V, F, np.asarray(ring_of)


def _chain_weights(s: np.ndarray, joint_s: list[float], joints: list[int], blend: float) -> list[dict[int, float]]:
    """Skin weights along a chain: arc length ``s`` of each vertex, joint ``k`` at ``joint_s[k]``
    owning the bone up to ``joint_s[k + 1]``; 50/50 at interior joints, pure ``blend`` away."""
    out = []
    for x in s:
        k = int(np.clip(np.searchsorted(joint_s, x, side="right") - 1, 0, len(joints) - 1))
        w = {joints[k]: 1.0}
        # blend with the previous bone near this bone's start
        if k > 0 and x - joint_s[k] < blend:
            a = 0.5 + 0.5 * max(x - joint_s[k], 0.0) / blend
            w = {joints[k]: a, joints[k - 1]: 1.0 - a}
        # blend with the next bone near this bone's end
        elif k + 1 < len(joints) and joint_s[k + 1] - x < blend:
            a = 0.5 + 0.5 * max(joint_s[k + 1] - x, 0.0) / blend
            w = {joints[k]: a, joints[k + 1]: 1.0 - a}
        out.append(w)
    return out


def _arc(points: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])


def _limb(
    b: _Builder,
    P: np.ndarray,
    path_joints: list[int],
    radii: list[float],
    material: str,
    blend: float,
    n_around: int = 14,
    start_back: float = 0.0,
    end_point: np.ndarray | None = None,
    subdiv: int = 3,
    squash: float = 1.0,
    ref=(0.0, 1.0, 0.0),
) -> None:
    """A tube along joints ``path_joints`` (each owning the bone to the next); ``radii`` per joint
    (+ one for ``end_point``), ``subdiv`` rings per bone."""
    pts = [P[j] for j in path_joints] + ([end_point] if end_point is not None else [])
    pts = np.asarray(pts)
    if start_back > 0:
        d = pts[1] - pts[0]
        pts = np.concatenate([[pts[0] - start_back * d / np.linalg.norm(d)], pts])
        radii = [radii[0]] + list(radii)
    js = _arc(pts)
    ss = np.concatenate(
        [np.linspace(js[k], js[k + 1], subdiv, endpoint=False) for k in range(len(pts) - 1)] + [[js[-1]]]
    )
    centers = np.stack([np.interp(ss, js, pts[:, a]) for a in range(3)], 1)
    r = np.interp(ss, js, radii)
    V, F, ring = _tube(centers, np.stack([r * squash, r], 1), n_around, ref=ref)
    joint_s = (
        list(_arc(np.asarray([P[j] for j in path_joints])))
        if start_back == 0
        else [0.0] + list(start_back + _arc(np.asarray([P[j] for j in path_joints]))[1:])
    )
    if start_back > 0:
        joint_s[0] = 0.0
    s_v = np.where(ring < 0, 0.0, np.where(ring >= len(ss), ss[-1], ss[np.clip(ring, 0, len(ss) - 1)]))
    b.add(V, _chain_weights(s_v, joint_s, path_joints, blend), F, material)


def _torso(b: _Builder, skel: Skeleton, P: np.ndarray) -> None:
    """Elliptic rings from the hips to the base of the neck, weighted along the spine."""
    spine = [skel.index(n) for n in ("Hips", "Spine", "Spine1", "Spine2", "Spine3", "Neck")]
    ys = P[spine, 1]
    zs = P[spine, 2]
    shoulder_y = P[skel.index("RightArm"), 1]
    arm_x = abs(P[skel.index("RightArm"), 0])
    neck_y = P[skel.index("Neck"), 1]
    # (height, half-width, half-depth): hips, waist, chest, shoulders, neck base (cm)
    prof = np.array(
        [
            [ys[0] - 6, 0.78 * arm_x, 11.0],
            [ys[0] + 4, 0.80 * arm_x, 11.5],
            [ys[2], 0.74 * arm_x, 10.5],
            [ys[3], 0.84 * arm_x, 11.5],
            [ys[4], 0.92 * arm_x, 11.5],
            [shoulder_y - 1, 0.98 * arm_x, 10.0],
            [shoulder_y + 2.5, 0.80 * arm_x, 8.0],
            [neck_y - 0.5, 0.42 * arm_x, 6.5],
            [neck_y + 1.5, 0.30 * arm_x, 5.5],
        ]
    )
    n_around = 28
    ang = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    rings = []
    for y, a, d in prof:
        zc = np.interp(y, ys, zs) + 1.0
        # a rounded-rectangle-ish section (superellipse, exponent 2.6)
        c, s = np.cos(ang), np.sin(ang)
        e = 2 / 2.6
        x = a * np.sign(c) * np.abs(c) ** e
        z = zc + d * np.sign(s) * np.abs(s) ** e
        rings.append(np.stack([x, np.full(n_around, y), z], 1))
    K = len(rings)
    V = np.concatenate(rings + [np.array([[0.0, prof[0, 0] - 2.0, np.interp(prof[0, 0], ys, zs) + 1.0]])])
    faces = []
    for k in range(K - 1):
        a = k * n_around + np.arange(n_around)
        bb = k * n_around + (np.arange(n_around) + 1) % n_around
        faces += [np.stack([a, bb + n_around, bb], 1), np.stack([a, a + n_around, bb + n_around], 1)]
    a = np.arange(n_around)
    faces.append(np.stack([np.full(n_around, K * n_around), a, (a + 1) % n_around], 1))
    F = np.concatenate(faces)
    nrm = np.cross(V[F[0, 1]] - V[F[0, 0]], V[F[0, 2]] - V[F[0, 0]])
    if np.dot(nrm, V[F[0, 0]] - np.array([0.0, V[F[0, 0], 1], np.interp(V[F[0, 0], 1], ys, zs)])) < 0:
        F = F[:, ::-1]
    sh = {"R": skel.index("RightShoulder"), "L": skel.index("LeftShoulder")}
    weights = []
    for x, y, _ in V:
        wd = {j: w for j, w in zip(spine, _spine_weights(y, ys))}
        # the top of the shoulders follows the clavicle joints
        ws = np.clip((abs(x) - 0.45 * arm_x) / (0.4 * arm_x), 0, 1) * np.clip((y - (shoulder_y - 12)) / 8, 0, 1)
        if ws > 0:
            wd = {j: w * (1 - ws) for j, w in wd.items()}
            wd[sh["L" if x > 0 else "R"]] = ws
        weights.append(wd)
    b.add(V, weights, F, SHIRT)


def _spine_weights(y: float, ys: np.ndarray) -> list[float]:
    """Linear interpolation weights of height ``y`` between consecutive spine joints."""
    w = np.zeros(len(ys))
    if y <= ys[0]:
        w[0] = 1.0
    elif y >= ys[-1]:
        w[-1] = 1.0
    else:
        k = int(np.searchsorted(ys, y) - 1)
        t = (y - ys[k]) / (ys[k + 1] - ys[k])
        # a joint rotates the segment above it: weight the lower joint of the segment
        w[k] = 1 - t * 0.5
        w[k + 1] = t * 0.5
    return list(w)


def _arm(b: _Builder, skel: Skeleton, P: np.ndarray, side: str) -> None:
    j = {n: skel.index(f"{side}{n}") for n in ("Shoulder", "Arm", "ForeArm", "Hand")}
    upper = np.linalg.norm(P[j["ForeArm"]] - P[j["Arm"]])  # upper-arm length sets the girth
    # shoulder → arm → forearm → hand: the tube starts inside the torso
    start = P[j["Arm"]] + 0.28 * (P[j["Shoulder"]] - P[j["Arm"]])
    pts = np.array([start, P[j["Arm"]], P[j["ForeArm"]], P[j["Hand"]]])
    r = np.array([0.14, 0.155, 0.125, 0.095]) * upper
    js = _arc(pts)
    ss = np.concatenate(
        [np.linspace(js[k], js[k + 1], n, endpoint=False) for k, n in enumerate((2, 6, 6))] + [[js[-1]]]
    )
    centers = np.stack([np.interp(ss, js, pts[:, a]) for a in range(3)], 1)
    V, F, ring = _tube(centers, np.interp(ss, js, r), 16)
    s_v = np.where(ring < 0, 0.0, np.where(ring >= len(ss), ss[-1], ss[np.clip(ring, 0, len(ss) - 1)]))
    w = _chain_weights(s_v, [0.0, js[1], js[2]], [j["Shoulder"], j["Arm"], j["ForeArm"]], blend=float(0.08 * upper))
    # the wrist end blends into the hand
    for i, s in enumerate(s_v):
        if s > js[3] - 0.06 * upper:
            a = 0.5 + 0.5 * (js[3] - s) / (0.06 * upper)
            w[i] = {j["ForeArm"]: a, j["Hand"]: 1 - a}
    b.add(V, w, F, SHIRT)


@dataclass(frozen=True)
class _PalmFrame:
    """A hand's palm in the rest pose: where it starts and ends, and its three directions (unit)."""

    wrist: np.ndarray  # (3,) the Hand joint
    knuckles: np.ndarray  # (4, 3) the Index, Middle, Ring and Pinky first joints
    fwd: np.ndarray  # wrist → the knuckles' mean
    length: float  # the wrist's distance to the knuckles' mean
    across: np.ndarray  # pinky knuckle → index knuckle
    width: float  # the distance between those two knuckles
    up: np.ndarray  # out of the back of the hand

    @classmethod
    def of(cls, skel: Skeleton, P: np.ndarray, side: str) -> _PalmFrame:
        J = lambda n: skel.index(f"{side}Hand{n}")  # noqa: E731
        knuckles = np.array([P[J(f"{f}1")] for f in ("Index", "Middle", "Ring", "Pinky")])
        wrist = P[skel.index(f"{side}Hand")]
        fwd = knuckles.mean(0) - wrist
        length = float(np.linalg.norm(fwd))
        fwd /= length
        across = knuckles[0] - knuckles[3]
        width = float(np.linalg.norm(across))
        across /= width
        up = np.cross(across, fwd) if side == "Left" else np.cross(fwd, across)
        up /= np.linalg.norm(up)
        return cls(wrist, knuckles, fwd, length, across, width, up)


def _hand(b: _Builder, skel: Skeleton, P: np.ndarray, side: str) -> None:
    palm = _PalmFrame.of(skel, P, side)
    V, F = _palm_mesh(palm)
    b.add(V, _palm_weights(skel, V, side, palm), F, SKIN)
    _fingers(b, skel, P, side, palm.up)


def _palm_mesh(palm: _PalmFrame) -> tuple[np.ndarray, np.ndarray]:
    """The palm: rounded-square rings along the hand, capped at both ends, faces outward."""
    wrist, knuckles, fwd, length = palm.wrist, palm.knuckles, palm.fwd, palm.length
    center_line = np.array(
        [wrist + t * length * fwd + (knuckles.mean(0) - wrist - length * fwd) * t for t in (-0.05, 0.3, 0.7, 1.02)]
    )
    half_w = np.array([0.36, 0.5, 0.56, 0.55]) * palm.width + 0.6
    half_t = np.array([0.9, 1.1, 1.05, 0.9])
    n = 16
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rings = []
    for c, hw, ht in zip(center_line, half_w, half_t):
        cc, ss = np.cos(ang), np.sin(ang)
        e = 2 / 3.0
        rings.append(
            c
            + hw * (np.sign(cc) * np.abs(cc) ** e)[:, None] * palm.across
            + ht * (np.sign(ss) * np.abs(ss) ** e)[:, None] * palm.up
        )
    V = np.concatenate(rings + [center_line[:1] - 0.5 * fwd, center_line[-1:] + 0.3 * fwd])
    faces = []
    K = len(rings)
    for k in range(K - 1):
        a = k * n + np.arange(n)
        bb = k * n + (np.arange(n) + 1) % n
        faces += [np.stack([a, bb, bb + n], 1), np.stack([a, bb + n, a + n], 1)]
    a = np.arange(n)
    faces += [
        np.stack([np.full(n, K * n), (a + 1) % n, a], 1),
        np.stack([np.full(n, K * n + 1), (K - 1) * n + a, (K - 1) * n + (a + 1) % n], 1),
    ]
    F = np.concatenate(faces)
    nrm = np.cross(V[F[0, 1]] - V[F[0, 0]], V[F[0, 2]] - V[F[0, 0]])
    if np.dot(nrm, V[F[0, 0]] - center_line[0]) < 0:
        F = F[:, ::-1]
    return V, F


def _palm_weights(skel: Skeleton, V: np.ndarray, side: str, palm: _PalmFrame) -> list[dict[int, float]]:
    """Skin weights of the palm's vertices: hand, a little forearm at the wrist, metacarpals at the far half."""
    J = lambda n: skel.index(f"{side}Hand{n}")  # noqa: E731
    hand = skel.index(f"{side}Hand")
    fore = skel.index(f"{side}ForeArm")
    # the far half of the palm follows the metacarpal joint of its finger (BEAT has
    # Index, Ring and Pinky metacarpals; the middle finger's column stays on the hand)
    mid = (palm.knuckles[0] + palm.knuckles[3]) / 2
    w = []
    for v in V:
        t = np.dot(v - palm.wrist, palm.fwd) / palm.length
        a = np.dot(v - mid, palm.across) / (palm.width / 2)  # +1 index side, −1 pinky side
        wd = {hand: 1.0} if t > 0.08 else {hand: 0.75, fore: 0.25}
        m = 0.6 * float(np.clip((t - 0.35) / 0.6, 0.0, 1.0))
        meta = "Index" if a > 0.35 else "Pinky" if a < -0.65 else "Ring" if a < -0.15 else None
        if m > 0 and meta is not None:
            wd = {hand: 1.0 - m, J(meta): m}
        w.append(wd)
    return w


def _fingers(b: _Builder, skel: Skeleton, P: np.ndarray, side: str, up: np.ndarray) -> None:
    """One tube along each finger's joints to its end site."""
    J = lambda n: skel.index(f"{side}Hand{n}")  # noqa: E731
    radius = {"Thumb": 1.05, "Index": 0.9, "Middle": 0.92, "Ring": 0.86, "Pinky": 0.76}
    for f in FINGERS:
        chain = [J(f"{f}{k}") for k in (1, 2, 3, 4)]
        end = P[chain[-1]] + skel.end_sites.get(chain[-1], P[chain[-1]] - P[chain[-2]])
        r0 = radius[f]
        radii = (
            [r0 * 1.15, r0, r0 * 0.92, r0 * 0.85, r0 * 0.8]
            if f == "Thumb"
            else [r0, r0 * 0.95, r0 * 0.9, r0 * 0.82, r0 * 0.78]
        )
        _limb(
            b,
            P,
            chain,
            radii,
            SKIN,
            blend=0.5,
            n_around=10,
            end_point=end,
            subdiv=2,
            start_back=0.0 if f == "Thumb" else 1.2,
            squash=0.9,
            ref=up,
        )


def _neck(b: _Builder, skel: Skeleton, P: np.ndarray) -> None:
    neck, neck1, head = (skel.index(n) for n in ("Neck", "Neck1", "Head"))
    top = P[head] + np.array([0.0, 4.0, 0.5])
    _limb(
        b,
        P,
        [neck, neck1, head],
        [5.6, 5.3, 5.1, 5.0],
        SKIN,
        blend=1.2,
        n_around=18,
        start_back=3.0,
        end_point=top,
        subdiv=2,
        ref=(0.0, 0.0, 1.0),
    )


def build_body(skel: Skeleton) -> SkinnedMesh:
    """The skinned upper body of ``skel`` (a BEAT skeleton) in its rest pose."""
    check_skeleton(skel)
    P = rest_positions(skel)
    b = _Builder()
    _torso(b, skel, P)
    _neck(b, skel, P)
    for side in ("Right", "Left"):
        _arm(b, skel, P, side)
        _hand(b, skel, P, side)
    return b.build()


# ------------------------------------------------------------------------- face
def boundary_loop(faces: np.ndarray) -> np.ndarray:
    """The vertices of a mesh's (single) boundary, in order along it."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    edge_set = {(int(a), int(b)) for a, b in directed}
    nxt = {a: b for a, b in edge_set if (b, a) not in edge_set}
    start = min(nxt)
    loop = [start]
    while nxt[loop[-1]] != start:
        loop.append(nxt[loop[-1]])
        if len(loop) > len(nxt):
            raise ValueError("mesh boundary is not one simple loop")
    return np.asarray(loop)


def back_of_head(
    face: TriMesh, n_rings: int = 9, depth: float = 0.62
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (M, 3) and triangles (using face indices for the rim) closing the face into a head.

    The face outline is swept backwards around a centre behind the eyes: each outline
    point turns towards −Z (spherical interpolation of its direction), its distance
    growing to ``depth`` × face height, with a bulge for the skull. Returns the new
    vertices (to append after the face's), the triangles of the cap, and for each new
    vertex the outline vertex it was swept from and its ring number (1 … n_rings; the
    pole has ring n_rings + 1 and source −1).
    """
    V = face.vertices
    loop = boundary_loop(face.faces)
    height = V[:, 1].max() - V[:, 1].min()
    c = np.array([0.0, V[:, 1].min() + 0.6 * height, V[loop, 2].mean()])
    back = np.array([0.0, 0.1, -1.0])
    back /= np.linalg.norm(back)
    rings = []
    for k in range(1, n_rings + 1):
        t = k / (n_rings + 1)
        ring = []
        for i in loop:
            u = V[i] - c
            r0 = np.linalg.norm(u)
            d0 = u / r0
            om = np.arccos(np.clip(np.dot(d0, back), -1, 1))
            d = (np.sin((1 - t) * om) * d0 + np.sin(t * om) * back) / max(np.sin(om), 1e-6)
            # below the cheekbones the skull bulge fades out and the surface tucks in under
            # the jaw (else its first rings stick out below the jaw line, a pale strip)
            low = float(np.clip(-u[1] / (0.3 * height), 0.0, 1.0))
            r_end = (1 - low) * depth * height + low * min(0.85 * r0, depth * height)
            r = (1 - t) * r0 + t * r_end + (1 - low) * 0.09 * height * np.sin(np.pi * t)
            ring.append(c + r * d)
        rings.append(ring)
    pole = c + (depth * height) * back
    new = np.concatenate([np.asarray(rings).reshape(-1, 3), pole[None]])
    N0 = len(V)
    m = len(loop)
    idx = [loop] + [N0 + k * m + np.arange(m) for k in range(n_rings)]
    faces = []
    for k in range(n_rings):
        a, b = idx[k], idx[k + 1]
        a2, b2 = np.roll(a, -1), np.roll(b, -1)
        faces += [np.stack([a, b, b2], 1), np.stack([a, b2, a2], 1)]
    last = idx[-1]
    faces.append(np.stack([last, np.full(m, N0 + len(new) - 1), np.roll(last, -1)], 1))
    F = np.concatenate(faces)
    # consistent orientation with the face: a rim edge of the cap must run opposite to the
    # same edge in the face (the second triangle of the first strip holds the rim edge a2 → a)
    face_edges = {
        (int(x), int(y))
        for x, y in np.concatenate([face.faces[:, [0, 1]], face.faces[:, [1, 2]], face.faces[:, [2, 0]]])
    }
    t = F[m]  # [a, b2, a2]
    if (int(t[0]), int(t[2])) not in face_edges:
        F = F[:, ::-1]
    src = np.concatenate([np.tile(loop, n_rings), [-1]])
    ring_no = np.concatenate([np.repeat(np.arange(1, n_rings + 1), m), [n_rings + 1]])
    return new, F, src, ring_no


def _eye(
    V: np.ndarray, deltas: np.ndarray, tris: np.ndarray, names: list[str], side: str, base: int
) -> tuple[np.ndarray, np.ndarray, dict[str, list]]:
    """Socket + eyeball of one eye opening (triangles ``tris`` of the neutral face ``V``).

    Returns the new vertices, their deltas (T, M, 3) and triangles per material (indices
    from ``base``; the socket's rim is the opening's own vertices, so it follows the lids)."""
    loop = boundary_loop(tris)
    rim = V[loop]
    ctr = rim.mean(0)
    width = float(np.ptp(rim[:, 0]))
    fwd = np.array([0.0, 0.0, 1.0])
    sock_v, sock_d, sock_f = _eye_socket(loop, rim, ctr, fwd, deltas, base)
    # eyeball: its front just behind the lids at the opening's middle
    r = EYEBALL_RADIUS * width
    mid = np.argsort(np.abs(rim[:, 0] - ctr[0]))[:4]
    center = np.array([ctr[0], ctr[1], rim[mid, 2].mean() - 0.12 - r])
    ball, ball_f = _eyeball_mesh(center, r, fwd, base + len(sock_v))
    ball_d = _gaze_deltas(ball, center, names, side, len(deltas))
    return (np.concatenate([sock_v, ball]), np.concatenate([sock_d, ball_d], axis=1), {EYE: sock_f, **ball_f})


def _eye_socket(
    loop: np.ndarray, rim: np.ndarray, ctr: np.ndarray, fwd: np.ndarray, deltas: np.ndarray, base: int
) -> tuple[np.ndarray, np.ndarray, list]:
    """The socket: two rings swept into the head and a back pole, each following its rim vertex."""
    m = len(loop)
    sock_v, sock_src, sock_k = [], [], []
    for shrink, depth in ((0.9, 0.6), (0.55, 1.6)):
        sock_v.append(ctr + shrink * (rim - ctr) - depth * fwd)
        sock_src.append(loop)
        sock_k.append(np.full(m, shrink))
    sock_v = np.concatenate(sock_v + [(ctr - 2.0 * fwd)[None]])
    src = np.concatenate(sock_src)
    scale = np.concatenate(sock_k)
    sock_d = np.zeros((len(deltas), len(sock_v), 3))
    sock_d[:, :-1] = deltas[:, src] * scale[None, :, None]
    idx = [loop, base + np.arange(m), base + m + np.arange(m)]
    sock_f = []
    for a, b in itertools.pairwise(idx):
        a2, b2 = np.roll(a, -1), np.roll(b, -1)
        sock_f += list(np.stack([a, b2, b], 1)) + list(np.stack([a, a2, b2], 1))
    pole = base + 2 * m
    sock_f += list(np.stack([idx[-1], np.roll(idx[-1], -1), np.full(m, pole)], 1))
    return sock_v, sock_d, sock_f


def _eyeball_mesh(center: np.ndarray, r: float, fwd: np.ndarray, b0: int) -> tuple[np.ndarray, dict[str, list]]:
    """The eyeball's vertices (poles and rings of latitude) and its triangles per material, indices from ``b0``."""
    thetas = np.array([0.1, PUPIL_RAD, 0.36, IRIS_RAD, 0.72, 0.95, 1.25, 1.6, 2.0, 2.5, 2.95])
    n = 24
    phi = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ball = [center + r * fwd]
    for th in thetas:
        ball += list(
            center + r * np.stack([np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi), np.full(n, np.cos(th))], 1)
        )
    ball.append(center - r * fwd)
    ball = np.asarray(ball)
    ball_f: dict[str, list] = {PUPIL: [], IRIS: [], SCLERA: []}

    def mat(th: float) -> str:
        return PUPIL if th <= PUPIL_RAD + 1e-9 else IRIS if th <= IRIS_RAD + 1e-9 else SCLERA

    ring = lambda k: b0 + 1 + k * n + np.arange(n)  # noqa: E731
    ball_f[mat(thetas[0])] += list(np.stack([np.full(n, b0), ring(0), np.roll(ring(0), -1)], 1))
    for k in range(len(thetas) - 1):
        a, b = ring(k), ring(k + 1)
        for t in list(np.stack([a, b, np.roll(b, -1)], 1)) + list(np.stack([a, np.roll(b, -1), np.roll(a, -1)], 1)):
            ball_f[mat(thetas[k + 1])].append(t)
    last = ring(len(thetas) - 1)
    ball_f[SCLERA] += list(np.stack([last, np.full(n, b0 + len(ball) - 1), np.roll(last, -1)], 1))
    return ball, ball_f


def _gaze_deltas(ball: np.ndarray, center: np.ndarray, names: list[str], side: str, T: int) -> np.ndarray:
    """eyeLook{Up,Down,In,Out}{side} turn this eyeball about its centre: (T, len(ball), 3) deltas."""
    ball_d = np.zeros((T, len(ball), 3))
    inward = -1.0 if side == "Left" else 1.0  # towards the nose, in X
    for direction, deg in GAZE_DEG.items():
        name = f"eyeLook{direction}{side}"
        if name not in names:
            continue
        if direction in ("Up", "Down"):
            R = rot.axis_angle_matrix("X", np.radians(-deg if direction == "Up" else deg))  # +X turns +Z down
        else:
            R = rot.axis_angle_matrix("Y", np.radians(deg * (inward if direction == "In" else -inward)))  # +Z to +X
        ball_d[names.index(name)] = (ball - center) @ R.T + center - ball
    return ball_d


def build_face(
    neutral: TriMesh,
    names: list[str],
    targets: np.ndarray,
    eye_rings: list[list[int]],
    mouth_ring: list[int],
    brow_rings: Sequence[list[int]] = (),
    head_to_hairline: float = 16.8,
) -> FaceMesh:
    """The morph-target head: ``neutral`` + its ``targets`` (T, N, 3) + a closed back of head.

    ``eye_rings`` / ``mouth_ring``: vertex indices outlining the eye and mouth openings
    (triangles with all corners on one outline get the eye / mouth material);
    ``brow_rings``: the eyebrow strips (drawn in the hair colour). The face
    is offset so its top sits ``head_to_hairline`` cm above the Head joint.
    """
    cap_v, cap_f, cap_src, cap_ring = back_of_head(neutral)
    V = np.concatenate([neutral.vertices, cap_v])
    n_face = neutral.n_vertices
    faces, ymax = _face_materials(neutral, V, cap_f, eye_rings, mouth_ring, brow_rings)
    T = len(names)
    n_head = len(V)
    deltas_face = targets - neutral.vertices[None]
    extra_v, extra_d = _face_eyes(neutral, deltas_face, faces, eye_rings, names, n_head)
    if extra_v:
        V = np.concatenate([V] + extra_v)
    by_material = {m: np.asarray(f, np.int64).reshape(-1, 3) for m, f in faces.items() if len(f)}  # per material
    allf = np.concatenate(list(by_material.values()))
    normals = TriMesh(V, allf).vertex_normals()
    deltas = np.zeros((T, len(V), 3))
    deltas[:, :n_face] = deltas_face
    # the first rings of the back of the head follow their outline vertex (a jaw moving
    # sideways drags the skin below the ear), fading out by the third ring
    fade = np.clip(1.0 - cap_ring / 4.0, 0.0, 1.0) ** 2
    moving = cap_src >= 0
    deltas[:, n_face:n_head][:, moving] = deltas[:, cap_src[moving]] * fade[moving][None, :, None]
    if extra_d:
        deltas[:, n_head:] = np.concatenate(extra_d, axis=1)
    ndel = np.zeros_like(deltas)
    for t in range(T):
        Vt = V + deltas[t]
        ndel[t] = TriMesh(Vt, allf).vertex_normals() - normals
    offset = np.array([0.0, head_to_hairline - ymax, 3.0])
    return FaceMesh(V, normals, by_material, list(names), deltas, ndel, offset)


def _face_materials(
    neutral: TriMesh,
    V: np.ndarray,
    cap_f: np.ndarray,
    eye_rings: list[list[int]],
    mouth_ring: list[int],
    brow_rings: Sequence[list[int]],
) -> tuple[dict[str, list], float]:
    """The face's and back of head's triangles per material, and the face's top (max Y)."""
    faces: dict[str, list] = {SKIN: [], EYE: [], MOUTH: [], HAIR: []}
    ring_sets = [(set(r), EYE) for r in eye_rings] + [(set(mouth_ring), MOUTH)] + [(set(r), HAIR) for r in brow_rings]
    for tri in neutral.faces:
        mat = SKIN
        for rs, m in ring_sets:
            if all(int(v) in rs for v in tri):
                mat = m
        faces[mat].append(tri)
    ymin, ymax = neutral.vertices[:, 1].min(), neutral.vertices[:, 1].max()
    zmax = neutral.vertices[:, 2].max()
    for tri in cap_f:
        c = V[tri].mean(0)
        # hair over the top and back of the skull; skin at the temples, jaw and under the chin
        hair = c[1] > ymin + 0.62 * (ymax - ymin) - 0.35 * max(0.0, (zmax - 8.0) - c[2]) and c[1] > ymin + 0.25 * (
            ymax - ymin
        )
        faces[HAIR if hair else SKIN].append(tri)
    return faces, ymax


def _face_eyes(
    neutral: TriMesh,
    deltas_face: np.ndarray,
    faces: dict[str, list],
    eye_rings: list[list[int]],
    names: list[str],
    n_head: int,
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The eyes: the opening triangles (taken out of ``faces``) give way to a socket and an eyeball each.

    Returns the eyes' vertices and deltas; their triangles go into ``faces``."""
    eye_tris = faces.pop(EYE, [])
    extra_v: list[np.ndarray] = []
    extra_d: list[np.ndarray] = []
    for ring in eye_rings:
        rs = set(ring)
        tris = np.asarray([t for t in eye_tris if all(int(v) in rs for v in t)], np.int64).reshape(-1, 3)
        if not len(tris):
            continue
        side = "Left" if neutral.vertices[ring, 0].mean() > 0 else "Right"  # head frame: +X = subject's left
        base = n_head + sum(len(v) for v in extra_v)
        ev, ed, ef = _eye(neutral.vertices, deltas_face, tris, names, side, base)
        extra_v.append(ev)
        extra_d.append(ed)
        for m, f in ef.items():
            faces.setdefault(m, []).extend(f)
    return extra_v, extra_d


def build_avatar(
    skel: Skeleton,
    neutral: TriMesh,
    names: list[str],
    targets: np.ndarray,
    eye_rings: list[list[int]],
    mouth_ring: list[int],
    brow_rings: Sequence[list[int]] = (),
) -> Avatar:
    """Body skinned to ``skel`` + the morph-target face mounted on its Head joint."""
    check_skeleton(skel)
    body = build_body(skel)
    face = build_face(neutral, names, targets, eye_rings, mouth_ring, brow_rings)
    return Avatar(
        skel,
        rest_positions(skel),
        body,
        face,
        info={
            "body_vertices": len(body.vertices),
            "face_vertices": len(face.vertices),
            "joints": skel.n_joints,
            "morph_targets": len(names),
        },
    )


def default_avatar(skel: Skeleton, progress=None) -> Avatar:
    """The FaceCapGes avatar: ``skel``'s body + MediaPipe's canonical face with the 52 ARKit
    targets of the shipped control table (AOI Laplacian deformation)."""
    from facecapges.avatar import blendshape_table as bt
    from facecapges.avatar.blendshapes import arkit_blendshapes

    check_skeleton(skel)
    shapes = arkit_blendshapes(progress=progress)
    eyes = [bt.EYE_UPPER[side] + bt.EYE_LOWER[side] + bt.EYE_CORNERS[side] for side in ("R", "L")]
    mouth = bt.LIP_INNER_UPPER + bt.LIP_INNER_LOWER
    brows = [bt.BROW[side] for side in ("R", "L")]
    return build_avatar(skel, shapes.neutral, shapes.names, shapes.targets, eyes, mouth, brows)
