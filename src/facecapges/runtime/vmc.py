"""VMC protocol sender (OSC over UDP): drive VSeeFace, Warudo, VNyan … with the avatar.

Each frame is one OSC bundle (python-osc) sent to ``host:port`` (default
127.0.0.1:39539, the VMC "Marionette" port) holding::

    /VMC/Ext/Root/Pos  "root"  px py pz  qx qy qz qw
    /VMC/Ext/Bone/Pos  <HumanBodyBones name>  px py pz  qx qy qz qw     (one per bone below)
    /VMC/Ext/Blend/Val <ARKit name> weight                              (52, ARKIT_NAMES)
    /VMC/Ext/Blend/Apply
    /VMC/Ext/OK 1
    /VMC/Ext/T  <stream time, s>

Conventions
-----------
* Rotations are **local** quaternions in Unity's left-handed, Y-up frame, sent as
  ``(x, y, z, w)``: the right-handed BVH rotation converted by
  :func:`facecapges.rotations.quaternion_to_unity` (X mirrored). Positions are metres
  with ``x → −x``; bones carry their rest-pose offsets (receivers keep their own
  model's proportions and use only the rotations), the root stays at the origin.
* BEAT's rest pose is a T-pose with every joint frame aligned to the world axes, so a
  local rotation is directly the rotation from the T-pose, which is what VMC
  receivers apply to a (VRM-normalised) humanoid.
* BEAT has more joints than Unity's humanoid (four spine joints, two neck joints, a
  metacarpal per finger). A bone's local rotation is therefore taken *relative to its
  Unity parent's BEAT joint*: ``q = G(parent)⁻¹ · G(joint)`` with ``G`` the BEAT global
  rotations, so every mapped bone ends up with exactly the BEAT orientation and the
  rotations of unmapped joints (marked "folded" below) are carried by the next mapped
  bone down the chain.

BEAT → HumanBodyBones (``Left``/``Right`` alike; BEAT's side prefix kept)

=====================  ==========================  ==================================
BEAT joint             HumanBodyBones              note
=====================  ==========================  ==================================
Hips                   Hips
Spine                  Spine
Spine1                 Chest
Spine2                 UpperChest
Spine3                 —                           folded into Neck
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

import numpy as np

from facecapges import rotations as rot
from facecapges.arkit import ARKIT_NAMES
from facecapges.runtime.frames import OutputFrame
from facecapges.skeleton import UPPER_BODY, Skeleton

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 39539


def _table() -> dict[str, str]:
    t = {"Hips": "Hips", "Spine": "Spine", "Spine1": "Chest", "Spine2": "UpperChest", "Neck": "Neck", "Head": "Head"}
    for side in ("Left", "Right"):
        t.update({f"{side}Shoulder": f"{side}Shoulder", f"{side}Arm": f"{side}UpperArm",
                  f"{side}ForeArm": f"{side}LowerArm", f"{side}Hand": f"{side}Hand"})
        for beat, unity in (("Thumb", "Thumb"), ("Index", "Index"), ("Middle", "Middle"), ("Ring", "Ring"),
                            ("Pinky", "Little")):
            for k, seg in enumerate(("Proximal", "Intermediate", "Distal"), start=1):
                t[f"{side}Hand{beat}{k}"] = f"{side}{unity}{seg}"
    return t


BEAT_TO_UNITY: dict[str, str] = _table()  # the table of the module docstring


class VmcMapping:
    """Precomputed paths: for each mapped bone, the BEAT joints whose rotations it carries."""

    def __init__(self, skeleton: Skeleton):
        self.skeleton = skeleton
        names = list(skeleton.names)
        missing = [n for n in BEAT_TO_UNITY if n not in names]
        if missing:  # the user's skeleton: the same error as the avatar's check_skeleton
            from facecapges.errors import UserError

            raise UserError(f"not a BEAT skeleton; VMC needs the joints {missing[:5]}"
                            f"{' …' if len(missing) > 5 else ''}")
        self.upper_idx = np.array([names.index(n) for n in UPPER_BODY])
        self.bones: list[tuple[str, list[int], np.ndarray]] = []
        for beat, unity in BEAT_TO_UNITY.items():
            j = names.index(beat)
            path = [j]
            a = int(skeleton.parents[j])
            while a >= 0 and names[a] not in BEAT_TO_UNITY:
                path.append(a)
                a = int(skeleton.parents[a])
            path.reverse()  # from just below the mapped ancestor down to the joint
            # rest position relative to the mapped ancestor (cm → m, Unity: x mirrored)
            offset = np.sum(skeleton.offsets[path], axis=0) / 100.0 if a >= 0 else skeleton.offsets[j] / 100.0
            self.bones.append((unity, path, offset * np.array([-1.0, 1.0, 1.0])))

    def local_rotations(self, quats47: np.ndarray) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """(Unity bone name, Unity position (3,), Unity quaternion (w, x, y, z)) per mapped bone."""
        n = self.skeleton.n_joints
        mats = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        mats[self.upper_idx] = rot.quaternion_to_matrix(np.asarray(quats47, np.float64))
        out = []
        for unity, path, pos in self.bones:
            R = mats[path[0]]
            for j in path[1:]:
                R = R @ mats[j]
            q = rot.quaternion_to_unity(rot.matrix_to_quaternion(R))
            out.append((unity, pos, q))
        return out


class VmcSender:
    """Sink: one OSC bundle per frame to a VMC receiver (module docstring)."""

    def __init__(self, skeleton: Skeleton, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT):
        from pythonosc.udp_client import SimpleUDPClient

        self.mapping = VmcMapping(skeleton)
        self.host, self.port = host, port
        self.client = SimpleUDPClient(host, port)
        self.sent = 0
        self.errors = 0

    @staticmethod
    def _msg(address: str, *args):
        from pythonosc.osc_message_builder import OscMessageBuilder

        b = OscMessageBuilder(address=address)
        for a in args:
            b.add_arg(a)
        return b.build()

    def bundle(self, out: OutputFrame):
        from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder

        bb = OscBundleBuilder(IMMEDIATELY)
        bb.add_content(self._msg("/VMC/Ext/Root/Pos", "root", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0))
        for name, p, q in self.mapping.local_rotations(out.quats):
            bb.add_content(self._msg("/VMC/Ext/Bone/Pos", name, float(p[0]), float(p[1]), float(p[2]),
                                     float(q[1]), float(q[2]), float(q[3]), float(q[0])))
        for name, w in zip(ARKIT_NAMES, np.asarray(out.face, np.float64)):
            bb.add_content(self._msg("/VMC/Ext/Blend/Val", name, float(w)))
        bb.add_content(self._msg("/VMC/Ext/Blend/Apply"))
        bb.add_content(self._msg("/VMC/Ext/OK", 1))
        bb.add_content(self._msg("/VMC/Ext/T", float(out.time_s)))
        return bb.build()

    def write(self, out: OutputFrame) -> None:
        try:
            self.client.send(self.bundle(out))
            self.sent += 1
        except OSError:  # receiver not there (ICMP port unreachable): UDP is fire-and-forget
            self.errors += 1

    def close(self) -> None:
        try:
            self.client._sock.close()
        except Exception:  # noqa: BLE001
            pass
