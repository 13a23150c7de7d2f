"""VMC protocol sender (OSC over UDP): drive VSeeFace, Warudo, VNyan … with the avatar.

Each frame goes to ``host:port`` (default 127.0.0.1:39539, the VMC "Marionette" port)
as a few OSC 1.0 bundles, every datagram at most :data:`MAX_DATAGRAM_BYTES`
(1200 B: under any path MTU a LAN, Wi-Fi, VPN or IPv6 link has, so nothing is ever
fragmented — one bundle with everything was 6.3 KB, five IP fragments, lost whole
when one fragment is). In order::

    /VMC/Ext/Root/Pos  "root"  0 0 0  0 0 0 1                   (bundle 1 …; parts "all" only)
    /VMC/Ext/Bone/Pos  <HumanBodyBones name>  px py pz  qx qy qz qw     (one per sent bone)
    /VMC/Ext/Blend/Val <clip name> weight                 (… the face clips; not with "arms")
    /VMC/Ext/Blend/Apply                                     (last bundle; not with "arms")
    /VMC/Ext/OK 1
    /VMC/Ext/T  <stream time, s>

``/VMC/Ext/Blend/Apply`` is in the last datagram, after every ``Blend/Val`` of the
frame; a receiver applies the frame's face at once. :func:`pack_bundles` packs the
messages greedily in this order.

Behind the upsampler (``live --rate``, :mod:`.upsample`) the sender interpolates in what it
sends: a model frame's bone quaternions and clip weights are computed once
(:meth:`VmcSender.model_frame`: the same datagrams as sending the frame alone), and a tick
between two model frames slerps those quaternions and lerps those weights
(:meth:`VmcSender.between`): for the bones carrying folded BEAT joints and the VRM preset clips
a slightly different path between the same two frames than converting a blended pose would
take (:mod:`.upsample`, "Between model frames"). The bones of a model frame, a tick's slerp and
lerp and the packing of a frame's numbers are compiled (:mod:`.vmc_kernels`, Numba, loaded when a
sender is built): the bits of :mod:`facecapges.rotations`' NumPy formulas, in a few calls; so are the
VRM presets (:mod:`facecapges.avatar.vrm.expressions_compiled`). The socket is connected to the
receiver (the route looked up once, not per datagram; a missing receiver's ICMP error then
comes back on a later send and is counted in ``errors``).

Face clips (``blend``, ``live --vmc-blend``)
--------------------------------------------
VMC receivers look the name up in the avatar's clips; some **case-sensitively** (EVMC4U
lower-cases both sides and maps VRM 1.0 names to 0.x ones), so the spelling matters:

* ``vrm`` (default) — the VRM 0.x presets ``Blink``, ``Blink_L``, ``Blink_R``, ``A`` ``I``
  ``U`` ``E`` ``O``, ``Joy``, ``Angry``, ``Sorrow``, ``Fun``, ``Surprised``, ``LookUp`` …
  derived from the ARKit weights by :mod:`facecapges.avatar.vrm.expressions`. Every VRM has them.
* ``perfect-sync`` — the 52 ARKit clips in the spelling perfect-sync avatars use
  (``EyeBlinkLeft``, ``JawOpen``, …; :data:`facecapges.avatar.vrm.expressions.PERFECT_SYNC_NAMES`).
  Only avatars made with those 52 extra clips move; they move in full detail.
* ``both`` — presets and perfect-sync clips. For a receiver that picks what its avatar
  has; on an avatar with both sets the mouth would move twice (``A`` + ``JawOpen``).

Which bones (``parts``, ``live --vmc-parts``)
---------------------------------------------
* ``all`` (default) — ``Root/Pos``, every bone below and the face clips.
* ``upper`` — the bones from Spine up (no ``Root/Pos``, no Hips) and the face: the
  receiver keeps its own placement and legs.
* ``arms`` — shoulders, arms, hands and fingers only: no root, hips, spine, neck or head,
  no ``Blend/Val`` / ``Blend/Apply``. For a receiver that takes head and face from the
  user's own face tracker (VSeeFace, VTube Studio, an iPhone) and the arms from us; a
  shoulder's rotation is relative to its parent bone, so the arms follow the torso the
  other tracker moves.

Bone positions and rest frames (the receiver's rules)
-----------------------------------------------------
What a receiver does with ``/VMC/Ext/Bone/Pos`` (EVMC4U's ``ExternalReceiver``, the
reference receiver): it finds the bone's ``Transform`` through Unity's humanoid
``Animator.GetBoneTransform`` and sets ``localRotation`` to the sent rotation and, with
*Bone Position Synchronize* (on by default), ``localPosition`` to the sent position;
``/VMC/Ext/Root/Pos`` becomes the model's own transform. Both are *local* to the bone's
parent ``Transform`` — the parent *node* in the file, humanoid or not. A VRM 0.x is
normalised (every node's rest rotation is the identity, the T-pose); UniVRM loads a
VRM 1.0 as it is (the spec dropped normalisation; EVMC4U loads it without a control
rig by default), so its bones keep the rest rotations their file gives them (Blender
exports have them). The sender must therefore know the avatar, as established senders
do (Virtual Motion Capture, VSeeFace send their own loaded avatar's transforms):

* :class:`VmcRig` is that knowledge: per humanoid bone its rest local position and
  the rest world rotations of its parent node ``Wp`` and of itself ``Wb`` (Unity frame).
  A bone's rotation is sent as ``Wp⁻¹ · Q · Wb``, ``Q`` being the pose's rotation
  relative to the nearest sent humanoid ancestor in the normalised (T-pose = identity)
  frame: the bone then ends up turned by exactly the pose from its rest, whatever its
  rest frame. With identity rest rotations (VRM 0.x, ours) that is ``Q`` itself.
* By default (no ``avatar``) the rig is **our own avatar** (``avatar build --format
  vrm``/``vrm0``, :func:`our_rig`): the positions are its node translations (Hips
  at its height above the avatar's origin, Head from BEAT's Neck1 node, fingers from the
  metacarpal nodes), so our avatar stays whole with or without position sync. For any
  other avatar that applies positions, ``live`` says at start to pass the avatar or
  turn position sync off.
* with ``avatar`` (``live --vmc-avatar model.vrm``, the VRM the receiver shows) the rig
  is read from that file (:func:`vrm_rig`): its own rest positions and frames, so
  applying positions changes nothing and a VRM 1.0 with rest rotations moves right;
  bones the model lacks (``UpperChest`` is optional in VRM) are not sent and their
  rotation folds into the next bone down.
* ``/VMC/Ext/Root/Pos`` is the avatar's placement, the identity at the origin: the
  receiver's avatar stays where it stands.

Conventions
-----------
* Rotations are **local** quaternions in Unity's left-handed, Y-up frame, sent as
  ``(x, y, z, w)``: the right-handed rotation with X mirrored
  (:func:`facecapges.rotations.quaternion_to_unity`). Positions are metres. UniVRM
  imports a VRM 1.0 (facing +Z) with ``x → −x`` and a VRM 0.x (facing −Z) with
  ``z → −z``; both then face +Z in Unity, as BEAT does with ``x → −x``.
* BEAT's rest pose is a T-pose with every joint frame aligned to the world axes, so a
  local rotation is directly the rotation from the T-pose (the normalised frame).
* BEAT has more joints than Unity's humanoid (four spine joints, two neck joints, a
  metacarpal per finger). A bone's ``Q`` is therefore taken *relative to its
  Unity parent's BEAT joint*: ``Q = G(parent)⁻¹ · G(joint)`` with ``G`` the BEAT global
  rotations, so every mapped bone ends up with exactly the BEAT orientation and the
  rotations of unmapped joints (marked "folded" below) are carried by the next mapped
  bone down the chain.

BEAT → HumanBodyBones (``Left``/``Right`` alike; BEAT's side prefix kept; derived from
:data:`facecapges.avatar.vrm.humanoid.BEAT_BONES`, the project's one BEAT → humanoid table)

=====================  ==========================  ==================================
BEAT joint             HumanBodyBones              note
=====================  ==========================  ==================================
Hips                   Hips
Spine                  Spine
Spine1                 Chest
Spine2                 —                           folded into UpperChest
Spine3                 UpperChest
Neck                   Neck
Neck1                  —                           folded into Head
Head                   Head
{S}Shoulder            {S}Shoulder
{S}Arm                 {S}UpperArm
{S}ForeArm             {S}LowerArm
{S}Hand                {S}Hand
{S}HandThumb1/2/3      {S}ThumbProximal/Intermediate/Distal
{S}HandIndex           —                           metacarpal, folded into IndexProximal
{S}HandIndex1/2/3      {S}IndexProximal/Intermediate/Distal
{S}HandMiddle1/2/3     {S}MiddleProximal/Intermediate/Distal
{S}HandRing            —                           metacarpal, folded into RingProximal
{S}HandRing1/2/3       {S}RingProximal/Intermediate/Distal
{S}HandPinky           —                           metacarpal, folded into LittleProximal
{S}HandPinky1/2/3      {S}LittleProximal/Intermediate/Distal
=====================  ==========================  ==================================
"""

from __future__ import annotations

import functools
import socket
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from facecapges import rotations as rot
from facecapges.avatar.vrm.expressions import PERFECT_SYNC_NAMES, VRM0_PRESETS, vrm0_weights
from facecapges.runtime.frames import OutputFrame
from facecapges.skeleton import UPPER_BODY, Skeleton

if TYPE_CHECKING:
    from facecapges.avatar.vrm.read import VrmModel

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 39539
MAX_DATAGRAM_BYTES = 1200  # module docstring
BLEND_MODES = ("vrm", "perfect-sync", "both")


def vrm_to_unity(bone: str) -> str:
    """A VRM 1.0 humanoid bone name → Unity's ``HumanBodyBones`` name (``leftUpperArm`` → ``LeftUpperArm``).

    VRM 1.0 counts the thumb from the metacarpal: ``thumbMetacarpal`` / ``thumbProximal`` /
    ``thumbDistal`` are Unity's ``ThumbProximal`` / ``ThumbIntermediate`` / ``ThumbDistal``.
    """
    name = bone[0].upper() + bone[1:]
    for old, new in (("ThumbProximal", "ThumbIntermediate"), ("ThumbMetacarpal", "ThumbProximal")):
        if name.endswith(old):
            return name[: -len(old)] + new
    return name


def _table() -> dict[str, str]:
    from facecapges.avatar.vrm.humanoid import BEAT_BONES  # the one BEAT → humanoid bone table

    legs = ("UpperLeg", "LowerLeg", "Foot", "Toes")  # not generated: the receiver keeps its own legs
    return {beat: vrm_to_unity(b) for b, beat in BEAT_BONES.items() if not b.endswith(legs)}


BEAT_TO_UNITY: dict[str, str] = _table()  # the table of the module docstring (from facecapges.avatar.vrm)
_UNITY_X = np.array([-1.0, 1.0, 1.0])  # right-handed (BEAT, VRM 1.0 glTF) → Unity positions
PARTS = ("all", "upper", "arms")
_ARM_WORDS = ("Shoulder", "UpperArm", "LowerArm", "Hand", "Thumb", "Index", "Middle", "Ring", "Little")


def bone_in_parts(unity: str, parts: str) -> bool:
    """Whether the Unity bone ``unity`` is sent with ``parts`` (module docstring)."""
    if parts == "arms":
        return any(w in unity for w in _ARM_WORDS)
    return parts == "all" or unity != "Hips"


def check_parts(parts: str) -> str:
    if parts not in PARTS:
        raise ValueError(f"parts must be one of {PARTS}, got {parts!r}")
    return parts


def hip_height_cm(skeleton: Skeleton) -> float:
    """Height of the hips joint above the lowest joint (the feet) in the rest pose, cm."""
    from facecapges.skeleton import rest_positions

    rest = rest_positions(skeleton)
    return float(rest[0, 1] - rest[:, 1].min())


@dataclass
class VmcRig:
    """The receiver's avatar as the sender must know it (module docstring), Unity frame, Unity bone names.

    ``positions``: rest local position of each humanoid bone (its node's translation, metres);
    ``parent_rest`` / ``bone_rest``: rest world rotations (3, 3) of the bone's parent node and of
    the bone itself; ``source``: what it was read from (for the messages).
    """

    source: str
    positions: dict[str, np.ndarray]
    parent_rest: dict[str, np.ndarray]
    bone_rest: dict[str, np.ndarray]


def our_rig(skeleton: Skeleton) -> VmcRig:
    """Our own avatar's rig (``avatar build --format vrm``): every BEAT joint a node, identity rest rotations.

    A bone's parent node is its BEAT parent joint (Neck1 for Head, the metacarpal for a finger's
    first bone …), so its position is its own BEAT offset; Hips carries the lift that stands the
    soles on the floor (:func:`facecapges.avatar.vrm.humanoid.sole_lift`), as the VRM writer does.
    """
    from facecapges.avatar.vrm.humanoid import sole_lift

    names = list(skeleton.names)
    pos = {}
    for beat, unity in BEAT_TO_UNITY.items():
        p = np.asarray(skeleton.offsets[names.index(beat)], np.float64) / 100.0
        if unity == "Hips":
            p = p + np.array([0.0, sole_lift(skeleton), 0.0])
        pos[unity] = p * _UNITY_X
    eye = {u: np.eye(3) for u in pos}
    return VmcRig("our avatar (avatar build --format vrm / vrm0)", pos, eye, dict(eye))


def vrm_rig(avatar: str | Path | VrmModel) -> VmcRig:
    """A VRM 0.x / 1.0 (or humanoid GLB) file's rig, as UniVRM loads it (module docstring).

    A file is read by :func:`facecapges.avatar.vrm.read.load_model` (UserError if it is no avatar);
    a model already read is used as it is.
    A bone's position is its node's rest translation relative to its parent node — the
    ``Transform.localPosition`` a VMC receiver sets. VRM 0.x faces −Z in glTF and UniVRM
    imports it with z negated; VRM 1.0 (and GLB) faces +Z and is imported with x negated.
    """
    from facecapges.avatar.vrm.glb import node_world_matrices, split_glb
    from facecapges.avatar.vrm.read import VrmModel, load_model

    model = avatar if isinstance(avatar, VrmModel) else load_model(avatar)
    doc, _ = split_glb(model.data, model.name)
    nodes = doc.get("nodes") or []
    world = node_world_matrices(doc)
    parent = np.full(len(nodes), -1)
    for i, n in enumerate(nodes):
        for c in n.get("children") or []:
            if isinstance(c, int) and 0 <= c < len(nodes):
                parent[c] = i
    M = np.diag([1.0, 1.0, -1.0]) if model.kind == "vrm0" else np.diag(_UNITY_X)
    rig = VmcRig(f"{Path(model.name).name} ({model.kind})", {}, {}, {})
    for bone, node in model.bones.items():
        p = int(parent[node])
        wp = world[p] if p >= 0 else np.eye(4)
        local = np.linalg.solve(wp, world[node])
        t = local[:3, 3]
        if not np.isfinite(t).all():
            continue
        u = vrm_to_unity(bone)
        rig.positions[u] = M @ t
        rig.parent_rest[u] = M @ rot.nearest_rotation(wp[:3, :3]) @ M  # a node's scale stripped
        rig.bone_rest[u] = M @ rot.nearest_rotation(world[node][:3, :3]) @ M
    return rig


def vrm_rest_positions(path: str | Path) -> dict[str, np.ndarray]:
    """A VRM avatar's humanoid bones → their rest local positions in Unity's frame (metres), Unity bone names."""
    return vrm_rig(path).positions


class VmcMapping:
    """Precomputed paths: for each sent bone, the BEAT joints whose rotations it carries, and its rig.

    ``rig`` (:class:`VmcRig`; default :func:`our_rig`) limits the mapping to the bones the
    avatar has, gives their positions and rest frames; ``parts`` (:data:`PARTS`) which of
    them are sent (module docstring).
    """

    def __init__(self, skeleton: Skeleton, rig: VmcRig | None = None, parts: str = "all"):
        self.skeleton = skeleton
        self.parts = check_parts(parts)
        names = list(skeleton.names)
        missing = [n for n in BEAT_TO_UNITY if n not in names]
        if missing:  # the user's skeleton: the same error as the avatar's check_skeleton
            from facecapges.errors import UserError

            raise UserError(
                f"not a BEAT skeleton; VMC needs the joints {missing[:5]}{' …' if len(missing) > 5 else ''}"
            )
        self.rig = rig if rig is not None else our_rig(skeleton)
        table = {b: u for b, u in BEAT_TO_UNITY.items() if u in self.rig.positions}
        self.upper_idx = np.array([names.index(n) for n in UPPER_BODY], np.int64)
        self.bones: list[tuple[str, list[int], np.ndarray]] = []
        rest_p, rest_b = [], []
        for beat, unity in table.items():
            j = names.index(beat)
            path = [j]
            a = int(skeleton.parents[j])
            while a >= 0 and names[a] not in table:
                path.append(a)
                a = int(skeleton.parents[a])
            if not bone_in_parts(unity, self.parts):
                continue  # (its rotation is still relative to its mapped ancestor, sent or not)
            path.reverse()  # from just below the mapped ancestor down to the joint
            self.bones.append((unity, path, np.asarray(self.rig.positions[unity], np.float64)))
            rest_p.append(self.rig.parent_rest[unity].T)
            rest_b.append(self.rig.bone_rest[unity])
        self._wp_inv = np.asarray(rest_p).reshape(-1, 3, 3)
        self._wb = np.asarray(rest_b).reshape(-1, 3, 3)
        # the paths as one index array: bone k's joints are _path[_starts[k] : _starts[k + 1]]
        self._path = np.array([j for _, path, _ in self.bones for j in path], np.int64)
        self._starts = np.cumsum([0] + [len(path) for _, path, _ in self.bones]).astype(np.int64)
        self._x = np.diag(_UNITY_X)  # Unity's X flip
        from facecapges.runtime.outputs import vmc_kernels  # Numba: loaded when a mapping is built (vmc_kernels)

        vmc_kernels.warm()  # (once a process) the machine code loaded now, not on the first frame
        self._kernels = vmc_kernels

    def local_rotations(self, quats47: np.ndarray) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """(Unity bone name, Unity position (3,), Unity quaternion (w, x, y, z)) per sent bone."""
        q = self.local_quaternions(quats47)[:, [3, 0, 1, 2]]
        return [(unity, pos, q[k]) for k, (unity, _, pos) in enumerate(self.bones)]

    def local_quaternions(self, quats47: np.ndarray) -> np.ndarray:
        """The Unity quaternions of the sent bones as sent, (x, y, z, w), (bones, 4) in :attr:`bones` order: each
        bone's path product ``Q`` (the pose's quaternions as matrices), ``Wp⁻¹ · (X · Q · X) · Wb`` in Unity's frame
        (module docstring), as a quaternion — one compiled call (:func:`.vmc_kernels.bone_quaternions`: the bits
        of :mod:`facecapges.rotations`' ``quaternion_to_matrix``, ``@`` and ``matrix_to_quaternion``)."""
        out = np.empty((len(self.bones), 4))
        self._kernels.bone_quaternions(
            np.ascontiguousarray(quats47, np.float64), self.upper_idx, self.skeleton.n_joints, self._path, self._starts,
            self._wp_inv, self._wb, self._x, out,
        )  # fmt: skip
        return out


def vmc_note(avatar: str | Path | None, parts: str = "all") -> str:
    """What ``live`` says at start about the VMC stream's bones (module docstring)."""
    if parts == "arms":
        what = "arms, hands and fingers only (no root, hips, spine, head or face: your face tracker keeps them)"
    else:
        what = "the upper body without root and hips" if parts == "upper" else "root, upper body and face"
    if avatar is not None:
        return f"VMC sends {what} in the bone positions and frames of {Path(avatar).name}"
    return (
        f"VMC sends {what} with our avatar's bone positions (avatar build --format vrm / vrm0): for another VRM "
        "pass --vmc-avatar YOUR.vrm (the one the app shows), or turn the app's bone-position sync off "
        "(EVMC4U: Bone Position Synchronize), else the app gives your avatar our proportions"
    )


def blend_values(face52: np.ndarray, blend: str = "vrm") -> list[tuple[str, float]]:
    """(clip name, weight) pairs to send for one frame's ARKit weights (module docstring)."""
    return list(zip(blend_names(blend), blend_weights(face52, blend).tolist()))


def blend_names(blend: str = "vrm") -> tuple[str, ...]:
    """The clip names :func:`blend_values` sends with ``blend``, in order."""
    if blend not in BLEND_MODES:
        raise ValueError(f"blend must be one of {BLEND_MODES}, got {blend!r}")
    return (VRM0_PRESETS if blend != "perfect-sync" else ()) + (PERFECT_SYNC_NAMES if blend != "vrm" else ())


def blend_weights(face52: np.ndarray, blend: str = "vrm") -> np.ndarray:
    """The weights (float64) :func:`blend_values` sends with ``blend``, in :func:`blend_names` order."""
    if blend not in BLEND_MODES:
        raise ValueError(f"blend must be one of {BLEND_MODES}, got {blend!r}")
    w = np.asarray(face52, np.float64).reshape(-1)
    if blend == "vrm":  # a VMC tick's case: the presets clip the weights themselves (one compiled call)
        return vrm0_weights(w)
    w = np.clip(w, 0.0, 1.0)
    return np.concatenate([vrm0_weights(w), w]) if blend == "both" else w


def _osc_string(x: str) -> bytes:
    b = x.encode("utf-8") + b"\0"
    return b + b"\0" * (-len(b) % 4)


def _msg(address: str, *args) -> bytes:
    """One OSC 1.0 message: address, type tags, big-endian int32 / float32 / padded strings.

    (Written here rather than with python-osc's builder, which re-parses every message it
    builds: 20× slower, too slow for 60 Hz; the tests parse our bytes with python-osc
    and with ``vmcp``.)
    """
    tags, data = ",", []
    for a in args:
        if isinstance(a, str):
            tags += "s"
            data.append(_osc_string(a))
        elif isinstance(a, (bool, int, np.integer)):
            tags += "i"
            data.append(struct.pack(">i", int(a)))
        else:
            tags += "f"
            data.append(struct.pack(">f", float(a)))
    return _osc_string(address) + _osc_string(tags) + b"".join(data)


@functools.lru_cache(maxsize=512)
def _prefix(address: str, tags: str, name: str) -> bytes:
    """Address, type tags and the leading string argument of a message (cached: the same every frame)."""
    return _osc_string(address) + _osc_string(tags) + _osc_string(name)


_ROOT = _msg("/VMC/Ext/Root/Pos", "root", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
_APPLY, _OK = _msg("/VMC/Ext/Blend/Apply"), _msg("/VMC/Ext/OK", 1)
_T_PREFIX = _osc_string("/VMC/Ext/T") + _osc_string(",f")  # the stream time's message before its float
_BUNDLE_HEAD = b"#bundle\0" + struct.pack(">Q", 1)  # OSC bundle, time tag "immediately"


def pack_bundles(messages: list[bytes], max_bytes: int = MAX_DATAGRAM_BYTES) -> list[bytes]:
    """OSC messages → as few OSC bundles as fit, in order, each datagram ≤ ``max_bytes``."""
    out: list[bytes] = []
    cur: list[bytes] = []
    size = len(_BUNDLE_HEAD)
    for m in messages:
        need = 4 + len(m)
        if len(_BUNDLE_HEAD) + need > max_bytes:
            raise ValueError(f"one OSC message of {len(m)} bytes cannot fit a {max_bytes}-byte datagram")
        if size + need > max_bytes:
            out.append(b"".join(cur))
            cur, size = [], len(_BUNDLE_HEAD)
        if not cur:
            cur.append(_BUNDLE_HEAD)
        cur.append(struct.pack(">i", len(m)) + m)
        size += need
    if cur:
        out.append(b"".join(cur))
    return out


class VmcSender:
    """Sink: each frame as a few OSC bundles to a VMC receiver (module docstring).

    Args:
        skeleton: the checkpoint's BEAT skeleton.
        host, port: the receiver.
        blend: which face clips to send, one of :data:`BLEND_MODES`.
        avatar: the receiver's VRM file (or that file read: its model or its :func:`vrm_rig`): its rest
            positions and bone frames are used (module docstring); default: our own avatar's.
        parts: which bones (and whether the root and the face) are sent, one of :data:`PARTS`.
        max_datagram: the largest datagram, bytes.
    """

    def __init__(
        self,
        skeleton: Skeleton,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        blend: str = "vrm",
        avatar: str | Path | VrmModel | VmcRig | None = None,
        parts: str = "all",
        max_datagram: int = MAX_DATAGRAM_BYTES,
    ):
        if blend not in BLEND_MODES:
            raise ValueError(f"blend must be one of {BLEND_MODES}, got {blend!r}")
        rig = avatar if isinstance(avatar, VmcRig) or avatar is None else vrm_rig(avatar)
        self.mapping = VmcMapping(skeleton, rig, parts)
        self.blend = blend
        self.parts = parts
        self.host, self.port = host, port
        self.max_datagram = int(max_datagram)
        self.address: tuple  # (host, port[, flow, scope]) as getaddrinfo gives it
        family, _, _, _, self.address = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0]
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        try:  # connected: the route is looked up once, not for every datagram (a tick's sends: −30 % CPU, issue 36)
            self.sock.connect(self.address)
            self._connected = True
        except OSError:  # no route now (a network not up yet): each datagram addressed, as UDP allows
            self._connected = False
        if blend != "perfect-sync":  # the presets' machine code (Numba) loaded now, never on a frame
            from facecapges.avatar.vrm import expressions_compiled

            expressions_compiled.warm()
        # what is the same every frame, built once: each bone's and each clip's message up to its numbers, and
        # the bones' positions (issue 36: a 30 Hz tick built ~70 messages one struct.pack at a time)
        bones = self.mapping.bones
        self._bone_prefix = [_prefix("/VMC/Ext/Bone/Pos", ",sfffffff", name) for name, _, _ in bones]
        self._bone_pos = np.array([pos for _, _, pos in bones], np.float64).reshape(-1, 3)
        self._blend_prefix = [_prefix("/VMC/Ext/Blend/Val", ",sf", n) for n in blend_names(blend)]
        self._template, self._at, self._spans = self._layout()
        self._buf = self._template.copy()  # what send packs into
        self._largest = [max([0] + [b - a for a, b in self._spans[:k]]) for k in range(len(self._spans) + 1)]
        self._kernels = self.mapping._kernels
        self._arc: tuple = (None, None, None)  # the last blend's pair and its arcs' angles (between)
        self.sent = 0  # frames
        self.datagrams = 0
        self.largest_datagram = 0
        self.errors = 0

    def _layout(self) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int]]]:
        """The frame's datagrams with their changing numbers blank, where each number's 4 bytes go and each
        datagram's span.

        Every message but its numbers is the same each frame and so is its length, hence the way
        :func:`pack_bundles` packs them: packed once here (the bones' positions, which never change, in place;
        zeros for the rest), a frame is then its rotations, weights and time packed at their offsets
        (:func:`.vmc_kernels.pack`, one compiled call; the same bytes as packing its messages)."""
        xyz = self._bone_pos.astype(">f4").tobytes()
        pieces = [(_ROOT, 0)] if self.parts == "all" else []
        pieces += [(pre + xyz[12 * k : 12 * k + 12], 16) for k, pre in enumerate(self._bone_prefix)]
        if self.parts != "arms":
            pieces += [(pre, 4) for pre in self._blend_prefix] + [(_APPLY, 0)]
        pieces += [(_OK, 0), (_T_PREFIX, 4)]
        msgs = [pre + bytes(n) for pre, n in pieces]
        grams = pack_bundles(msgs, self.max_datagram)
        slots: list[int] = []
        spans: list[tuple[int, int]] = []
        pos = k = 0
        for g in grams:  # walk the packed bytes: bundle head, then (length, message) until the datagram's end
            end = pos + len(g)
            spans.append((pos, end))
            pos += len(_BUNDLE_HEAD)
            while pos < end:
                pre, n = pieces[k]
                start = pos + 4 + len(pre)
                slots += range(start, start + n, 4)  # each number's first byte
                pos += 4 + len(msgs[k])
                k += 1
        assert k == len(pieces) and pos == sum(len(g) for g in grams)
        return np.frombuffer(b"".join(grams), np.uint8).copy(), np.array(slots, np.int64), spans

    # ------------------------------------------------------------------ the upsampler's interpolating sink
    def model_frame(self, out: OutputFrame) -> tuple[np.ndarray, np.ndarray]:
        """The sender's own form of a model frame (:mod:`.upsample`, module docstring "Between model frames"):
        its bones' Unity quaternions as sent, (bones, 4) (x, y, z, w), and its clips' weights, float64."""
        q = self.mapping.local_quaternions(out.quats)
        face = blend_weights(out.face, self.blend) if self.parts != "arms" else np.empty(0)
        return q, face

    def between(self, a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], w: float):
        """``w`` of the way from ``a`` to ``b`` (:meth:`model_frame` forms): the bones' slerp (the same arc in any
        order of the components; :func:`facecapges.rotations.quaternion_slerp`'s bits), the clips' weights linearly,
        in one compiled call (:func:`.vmc_kernels.between`). The arcs' angles are taken once per pair ``a``, ``b``
        (the ticks of one blend share them): with NumPy's own ``arccos``, as the slerp's formula has it."""
        arc = self._arc
        if arc[0] is not a or arc[1] is not b:
            cos = np.empty(len(a[0]))
            self._kernels.arcs(a[0], b[0], cos)
            self._arc = arc = (a, b, np.arccos(cos))
        q, face = np.empty_like(a[0]), np.empty_like(a[1])
        self._kernels.between(a[0], b[0], arc[2], a[1], b[1], float(w), q, face)
        return q, face

    def send(self, frame: tuple[np.ndarray, np.ndarray], time_s: float) -> None:
        """Send a frame in the sender's own form (:meth:`model_frame`, :meth:`between`) at stream time ``time_s``."""
        # packed into the sender's own buffer: the sink's send is called from one thread
        grams, sock, went = self._datagrams(frame, time_s, self._buf), self.sock, 0
        try:
            if self._connected:
                for d in grams:
                    sock.send(d)
                    went += 1
            else:
                for d in grams:
                    sock.sendto(d, self.address)
                    went += 1
            self.sent += 1
        except OSError:  # receiver not there (ICMP port unreachable, reported by the next send): fire-and-forget
            self.errors += 1
        if went:  # the counters once a frame, not once a datagram
            self.datagrams += went
            self.largest_datagram = max(self.largest_datagram, self._largest[went])

    def _datagrams(self, frame: tuple[np.ndarray, np.ndarray], time_s: float, buf=None) -> list[bytes]:
        """The frame's datagrams, its numbers packed into ``buf`` (default: a copy of the template)."""
        buf = self._template.copy() if buf is None else buf
        self._kernels.pack(frame[0], frame[1], float(time_s), buf, self._at)
        data = buf.tobytes()
        return [data[a:b] for a, b in self._spans]

    # ------------------------------------------------------------------ a frame as it is
    def messages(self, out: OutputFrame) -> list[bytes]:
        """The frame's OSC messages, in sending order (module docstring)."""
        q, face = self.model_frame(out)
        vals = np.empty((len(self._bone_prefix), 7), np.float64)
        vals[:, :3] = self._bone_pos
        vals[:, 3:] = q
        raw = vals.astype(">f4").tobytes()  # the rounding struct.pack(">f", x) does (nearest, ties even)
        msgs = [_ROOT] if self.parts == "all" else []
        msgs += [pre + raw[28 * k : 28 * k + 28] for k, pre in enumerate(self._bone_prefix)]
        if self.parts != "arms":
            raw = face.astype(">f4").tobytes()
            msgs += [pre + raw[4 * k : 4 * k + 4] for k, pre in enumerate(self._blend_prefix)]
            msgs.append(_APPLY)
        msgs += [_OK, _msg("/VMC/Ext/T", float(out.time_s))]
        return msgs

    def datagrams_for(self, out: OutputFrame) -> list[bytes]:
        """The frame's datagrams: :func:`pack_bundles` of :meth:`messages`, from the layout (:meth:`_layout`)."""
        return self._datagrams(self.model_frame(out), out.time_s)

    def write(self, out: OutputFrame) -> None:
        self.send(self.model_frame(out), out.time_s)

    def stats(self) -> dict:
        return {
            "frames": self.sent,
            "datagrams": self.datagrams,
            "largest_datagram_bytes": self.largest_datagram,
            "errors": self.errors,
            "blend": self.blend,
            "parts": self.parts,
            "bones": len(self.mapping.bones),
            "rig": self.mapping.rig.source,
        }

    def close(self) -> None:
        try:
            self.sock.close()
        except OSError:
            pass
