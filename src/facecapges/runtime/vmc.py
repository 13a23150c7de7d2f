"""VMC protocol sender (OSC over UDP): drive VSeeFace, Warudo, VNyan … with the avatar.

Each frame goes to ``host:port`` (default 127.0.0.1:39539, the VMC "Marionette" port)
as a few OSC 1.0 bundles, every datagram at most :data:`MAX_DATAGRAM_BYTES`
(1200 B: under any path MTU a LAN, Wi-Fi, VPN or IPv6 link has, so nothing is ever
fragmented — one bundle with everything was 6.3 KB, five IP fragments, lost whole
when one fragment is). In order::

    /VMC/Ext/Root/Pos  "root"  0 0 0  0 0 0 1                           (bundle 1 …)
    /VMC/Ext/Bone/Pos  <HumanBodyBones name>  px py pz  qx qy qz qw     (one per bone)
    /VMC/Ext/Blend/Val <clip name> weight                               (… the face clips)
    /VMC/Ext/Blend/Apply                                                (last bundle)
    /VMC/Ext/OK 1
    /VMC/Ext/T  <stream time, s>

``/VMC/Ext/Blend/Apply`` is in the last datagram, after every ``Blend/Val`` of the
frame; a receiver applies the frame's face at once. :func:`pack_bundles` packs the
messages greedily in this order.

Face clips (``blend``, ``live --vmc-blend``)
--------------------------------------------
VMC receivers look the name up in the avatar's ``BlendShapeProxy`` **case-sensitively**:

* ``vrm`` (default) — the VRM 0.x presets ``Blink``, ``Blink_L``, ``Blink_R``, ``A`` ``I``
  ``U`` ``E`` ``O``, ``Joy``, ``Angry``, ``Sorrow``, ``Fun``, ``Surprised``, ``LookUp`` …
  derived from the ARKit weights by :mod:`facecapges.arkit_vrm`. Every VRM has them.
* ``perfect-sync`` — the 52 ARKit clips in the spelling perfect-sync avatars use
  (``EyeBlinkLeft``, ``JawOpen``, …; :data:`facecapges.arkit_vrm.PERFECT_SYNC_NAMES`).
  Only avatars made with those 52 extra clips move; they move in full detail.
* ``both`` — presets and perfect-sync clips. For a receiver that picks what its avatar
  has; on an avatar with both sets the mouth would move twice (``A`` + ``JawOpen``).

Bone positions and the root
---------------------------
Established senders (Virtual Motion Capture, VSeeFace, waidayo) send *their loaded
avatar's own* local bone positions, and receivers such as EVMC4U apply them by default
(``BonePositionSynchronize``): the avatar keeps its proportions because both ends load
the same VRM. We do the same:

* ``/VMC/Ext/Root/Pos`` is the avatar's placement, the identity at the origin: the
  receiver's avatar stays where it stands (EVMC4U writes it into the model transform).
* with ``avatar`` (``live --vmc-avatar model.vrm``, the VRM the receiver shows) every
  bone carries that model's own rest local position (:func:`vrm_rest_positions`), so
  applying positions changes nothing; bones the model lacks (``UpperChest`` is
  optional in VRM) are not sent and their rotation folds into the next bone down.
* without it, bones carry BEAT's rest offsets in metres and Hips stands at BEAT's hip
  height (0.89 m above the feet, from the leg chain), never at the floor. A receiver
  that applies bone positions must then have that off (EVMC4U: "Bone Position
  Synchronize"), as iFacialMocap's VMC output also asks; receivers that retarget use
  only the rotations and the root.

Conventions
-----------
* Rotations are **local** quaternions in Unity's left-handed, Y-up frame, sent as
  ``(x, y, z, w)``: the right-handed BVH rotation converted by
  :func:`facecapges.rotations.quaternion_to_unity` (X mirrored). Positions are metres
  with ``x → −x`` (BEAT faces +Z with its right side at −x; Unity's humanoid faces +Z
  with its right at +x).
* BEAT's rest pose is a T-pose with every joint frame aligned to the world axes, so a
  local rotation is directly the rotation from the T-pose, which is what VMC
  receivers apply to a (VRM-normalised) humanoid.
* BEAT has more joints than Unity's humanoid (four spine joints, two neck joints, a
  metacarpal per finger). A bone's local rotation is therefore taken *relative to its
  Unity parent's BEAT joint*: ``q = G(parent)⁻¹ · G(joint)`` with ``G`` the BEAT global
  rotations, so every mapped bone ends up with exactly the BEAT orientation and the
  rotations of unmapped joints (marked "folded" below) are carried by the next mapped
  bone down the chain.

BEAT → HumanBodyBones (``Left``/``Right`` alike; BEAT's side prefix kept; derived from
:data:`facecapges.avatar.vrm.BEAT_BONES`, the project's one BEAT → humanoid table)

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
from pathlib import Path

import numpy as np

from facecapges import rotations as rot
from facecapges.arkit_vrm import PERFECT_SYNC_NAMES, VRM0_PRESETS, vrm0_weights
from facecapges.runtime.frames import OutputFrame
from facecapges.skeleton import UPPER_BODY, Skeleton

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
    from facecapges.avatar.vrm import BEAT_BONES  # the one BEAT → humanoid bone table

    legs = ("UpperLeg", "LowerLeg", "Foot", "Toes")  # not generated: the receiver keeps its own legs
    return {beat: vrm_to_unity(b) for b, beat in BEAT_BONES.items() if not b.endswith(legs)}


BEAT_TO_UNITY: dict[str, str] = _table()  # the table of the module docstring (from facecapges.avatar.vrm)
_UNITY_X = np.array([-1.0, 1.0, 1.0])  # right-handed (BEAT, VRM 1.0 glTF) → Unity positions


def hip_height_cm(skeleton: Skeleton) -> float:
    """Height of the hips joint above the lowest joint (the feet) in the rest pose, cm."""
    from facecapges.skeleton import rest_positions

    rest = rest_positions(skeleton)
    return float(rest[0, 1] - rest[:, 1].min())


def vrm_rest_positions(path: str | Path) -> dict[str, np.ndarray]:
    """A VRM avatar's humanoid bones → their rest local positions in Unity's frame (metres), Unity bone names.

    The file is read by :func:`facecapges.avatar.vrm.load_model` (VRM 0.x / 1.0 / humanoid
    GLB; UserError otherwise). The position is the bone node's ``translation`` (relative to
    its parent node), which is the ``Transform.localPosition`` a VMC receiver sets. VRM 0.x
    faces −Z in glTF and UniVRM imports it with z negated; VRM 1.0 (and GLB) faces +Z and
    is imported with x negated.
    """
    from facecapges.avatar.vrm import load_model, split_glb

    model = load_model(path)
    doc, _ = split_glb(model.data, str(path))
    nodes = doc.get("nodes") or []
    flip = np.array([1.0, 1.0, -1.0]) if model.kind == "vrm0" else _UNITY_X
    out = {}
    for bone, node in model.bones.items():
        t = np.asarray(nodes[node].get("translation", [0.0, 0.0, 0.0]), np.float64)
        if t.shape == (3,) and np.isfinite(t).all():
            out[vrm_to_unity(bone)] = t * flip
    return out


class VmcMapping:
    """Precomputed paths: for each mapped bone, the BEAT joints whose rotations it carries.

    ``positions`` (Unity bone name → local position, e.g. :func:`vrm_rest_positions`)
    limits the mapping to those bones and sends their positions; without it every bone
    of :data:`BEAT_TO_UNITY` is sent with BEAT's rest offsets (module docstring).
    """

    def __init__(self, skeleton: Skeleton, positions: dict[str, np.ndarray] | None = None):
        self.skeleton = skeleton
        names = list(skeleton.names)
        missing = [n for n in BEAT_TO_UNITY if n not in names]
        if missing:  # the user's skeleton: the same error as the avatar's check_skeleton
            from facecapges.errors import UserError

            raise UserError(
                f"not a BEAT skeleton; VMC needs the joints {missing[:5]}{' …' if len(missing) > 5 else ''}"
            )
        table = {b: u for b, u in BEAT_TO_UNITY.items() if positions is None or u in positions or u == "Hips"}
        self.upper_idx = np.array([names.index(n) for n in UPPER_BODY])
        self.bones: list[tuple[str, list[int], np.ndarray]] = []
        for beat, unity in table.items():
            j = names.index(beat)
            path = [j]
            a = int(skeleton.parents[j])
            while a >= 0 and names[a] not in table:
                path.append(a)
                a = int(skeleton.parents[a])
            path.reverse()  # from just below the mapped ancestor down to the joint
            if positions is not None and unity in positions:
                pos = np.asarray(positions[unity], np.float64)
            elif a < 0:  # Hips: standing at BEAT's hip height above the root, not on the floor
                pos = np.array([0.0, hip_height_cm(skeleton) / 100.0, 0.0])
            else:  # rest position relative to the mapped ancestor (cm → m, Unity: x mirrored)
                pos = np.sum(skeleton.offsets[path], axis=0) / 100.0 * _UNITY_X
            self.bones.append((unity, path, pos))

    def local_rotations(self, quats47: np.ndarray) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """(Unity bone name, Unity position (3,), Unity quaternion (w, x, y, z)) per mapped bone."""
        n = self.skeleton.n_joints
        mats = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        mats[self.upper_idx] = rot.quaternion_to_matrix(np.asarray(quats47, np.float64))
        R = np.empty((len(self.bones), 3, 3))
        for k, (_, path, _) in enumerate(self.bones):
            R[k] = mats[path[0]]
            for j in path[1:]:
                R[k] = R[k] @ mats[j]
        q = rot.quaternion_to_unity(rot.matrix_to_quaternion(R))  # one batched conversion
        return [(unity, pos, q[k]) for k, (unity, _, pos) in enumerate(self.bones)]


def blend_values(face52: np.ndarray, blend: str = "vrm") -> list[tuple[str, float]]:
    """(clip name, weight) pairs to send for one frame's ARKit weights (module docstring)."""
    if blend not in BLEND_MODES:
        raise ValueError(f"blend must be one of {BLEND_MODES}, got {blend!r}")
    w = np.clip(np.asarray(face52, np.float64).reshape(-1), 0.0, 1.0)
    out: list[tuple[str, float]] = []
    if blend in ("vrm", "both"):
        out += list(zip(VRM0_PRESETS, vrm0_weights(w).tolist()))
    if blend in ("perfect-sync", "both"):
        out += list(zip(PERFECT_SYNC_NAMES, w.tolist()))
    return out


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


_F7, _F1 = struct.Struct(">7f"), struct.Struct(">f")
_ROOT = _msg("/VMC/Ext/Root/Pos", "root", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
_APPLY, _OK = _msg("/VMC/Ext/Blend/Apply"), _msg("/VMC/Ext/OK", 1)
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
        avatar: the receiver's VRM file; its rest bone positions are sent (module docstring).
        max_datagram: the largest datagram, bytes.
    """

    def __init__(
        self,
        skeleton: Skeleton,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        blend: str = "vrm",
        avatar: str | Path | None = None,
        max_datagram: int = MAX_DATAGRAM_BYTES,
    ):
        if blend not in BLEND_MODES:
            raise ValueError(f"blend must be one of {BLEND_MODES}, got {blend!r}")
        self.mapping = VmcMapping(skeleton, vrm_rest_positions(avatar) if avatar is not None else None)
        self.blend = blend
        self.host, self.port = host, port
        self.max_datagram = int(max_datagram)
        self.address: tuple  # (host, port[, flow, scope]) as getaddrinfo gives it
        family, _, _, _, self.address = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0]
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        self.sent = 0  # frames
        self.datagrams = 0
        self.largest_datagram = 0
        self.errors = 0

    def messages(self, out: OutputFrame) -> list[bytes]:
        """The frame's OSC messages, in sending order (module docstring)."""
        msgs = [_ROOT]
        for name, p, q in self.mapping.local_rotations(out.quats):
            msgs.append(
                _prefix("/VMC/Ext/Bone/Pos", ",sfffffff", name) + _F7.pack(p[0], p[1], p[2], q[1], q[2], q[3], q[0])
            )
        for name, w in blend_values(out.face, self.blend):
            msgs.append(_prefix("/VMC/Ext/Blend/Val", ",sf", name) + _F1.pack(w))
        msgs += [_APPLY, _OK, _msg("/VMC/Ext/T", float(out.time_s))]
        return msgs

    def datagrams_for(self, out: OutputFrame) -> list[bytes]:
        return pack_bundles(self.messages(out), self.max_datagram)

    def write(self, out: OutputFrame) -> None:
        try:
            for d in self.datagrams_for(out):
                self.sock.sendto(d, self.address)
                self.datagrams += 1
                self.largest_datagram = max(self.largest_datagram, len(d))
            self.sent += 1
        except OSError:  # receiver not there (ICMP port unreachable): UDP is fire-and-forget
            self.errors += 1

    def stats(self) -> dict:
        return {
            "frames": self.sent,
            "datagrams": self.datagrams,
            "largest_datagram_bytes": self.largest_datagram,
            "errors": self.errors,
            "blend": self.blend,
        }

    def close(self) -> None:
        try:
            self.sock.close()
        except OSError:
            pass
