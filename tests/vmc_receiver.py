"""A VMC receiver that applies a stream to a VRM file by the receivers' own rules — independent of our sender.

Written from the public sources, not from facecapges.runtime.outputs.vmc (it reads the file with
pygltflib and does its rotations with scipy):

* EVMC4U ``ExternalReceiver.cs`` (gpsnmeajp/EasyVirtualMotionCaptureForUnity), the reference
  VMC receiver: ``/VMC/Ext/Root/Pos`` sets the model transform's ``localPosition`` /
  ``localRotation`` (RootPositionSynchronize / RootRotationSynchronize, on by default);
  ``/VMC/Ext/Bone/Pos name p q`` looks ``name`` up as a ``HumanBodyBones`` value, takes that
  bone's ``Transform`` (``Animator.GetBoneTransform``) and sets ``localRotation = q`` always and
  ``localPosition = p`` when BonePositionSynchronize is on (its default); ``/VMC/Ext/Blend/Val``
  stores a weight by lower-cased key, ``/VMC/Ext/Blend/Apply`` applies what is stored. A VRM 1.0
  is loaded with ``controlRigGenerationOption = None`` by default: the bones are the file's own
  nodes.
* The VMC protocol (protocol.vmc.info, Marionette spec): positions and rotations are the
  bone's local transform, quaternions sent (x, y, z, w), Unity's left-handed frame.
* UniVRM (vrm.dev): a glTF node becomes a ``Transform`` with the node's local translation and
  rotation; a VRM 0.x is converted with its z axis negated (it faces −Z in glTF) and is
  normalised (identity rest rotations, the T-pose); a VRM 1.0 (facing +Z) with its x axis
  negated and keeps its nodes' rest rotations (VRM 1.0 dropped normalisation).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def unity_bone_name(vrm_bone: str, version: str) -> str:
    """A VRM humanoid bone name → Unity's ``HumanBodyBones`` name (VRM 1.0 counts the thumb from the metacarpal)."""
    name = vrm_bone[0].upper() + vrm_bone[1:]
    if version == "1":
        for old, new in (("ThumbProximal", "ThumbIntermediate"), ("ThumbMetacarpal", "ThumbProximal")):
            if name.endswith(old):
                return name[: -len(old)] + new
    return name


def osc_messages(datagrams: list[bytes]) -> list[tuple[str, tuple]]:
    """(address, arguments) of every message in OSC bundles, parsed with python-osc."""
    from pythonosc.osc_bundle import OscBundle
    from pythonosc.osc_message import OscMessage

    out = []
    for d in datagrams:
        items = OscBundle(d) if OscBundle.dgram_is_bundle(d) else [OscMessage(d)]
        for m in items:
            out.append((m.address, tuple(m.params)))
    return out


class Receiver:
    """One VRM avatar in a receiver: the node tree as Unity holds it, and the EVMC4U rules to apply messages."""

    def __init__(self, path, bone_positions: bool = True):
        import pygltflib

        doc = pygltflib.GLTF2.load_binary(str(path))
        ext = doc.extensions or {}
        if "VRMC_vrm" in ext:
            self.version = "1"
            pairs = [(b, d["node"]) for b, d in ext["VRMC_vrm"]["humanoid"]["humanBones"].items()]
            flip = np.diag([-1.0, 1.0, 1.0])
        else:
            self.version = "0"
            pairs = [(d["bone"], d["node"]) for d in ext["VRM"]["humanoid"]["humanBones"]]
            flip = np.diag([1.0, 1.0, -1.0])
        self.bone_positions = bone_positions
        n = len(doc.nodes)
        self.parent = np.full(n, -1)
        for i, node in enumerate(doc.nodes):
            for c in node.children or []:
                self.parent[c] = i
        self.t = np.zeros((n, 3))
        self.r = np.tile(np.eye(3), (n, 1, 1))
        for i, node in enumerate(doc.nodes):
            t = np.asarray(node.translation or [0, 0, 0], float)
            r = Rotation.from_quat(node.rotation or [0, 0, 0, 1]).as_matrix()  # glTF: (x, y, z, w)
            self.t[i], self.r[i] = flip @ t, flip @ r @ flip
        self.bones = {unity_bone_name(b, self.version): int(i) for b, i in pairs}
        self.model_t, self.model_r = np.zeros(3), np.eye(3)
        self.blend: dict[str, float] = {}
        self.applied_blend: dict[str, float] = {}
        self.rest_world = self.world()

    def apply(self, messages: list[tuple[str, tuple]]) -> None:
        for address, args in messages:
            if address == "/VMC/Ext/Root/Pos":
                self.model_t = np.asarray(args[1:4], float)
                self.model_r = Rotation.from_quat(args[4:8]).as_matrix()
            elif address == "/VMC/Ext/Bone/Pos" and args[0] in self.bones:
                i = self.bones[args[0]]
                if self.bone_positions:
                    self.t[i] = np.asarray(args[1:4], float)
                self.r[i] = Rotation.from_quat(args[4:8]).as_matrix()  # Unity/VMC: (x, y, z, w)
            elif address == "/VMC/Ext/Blend/Val":
                self.blend[str(args[0]).lower()] = float(args[1])
            elif address == "/VMC/Ext/Blend/Apply":
                self.applied_blend = dict(self.blend)

    def world(self) -> tuple[np.ndarray, np.ndarray]:
        """World positions (N, 3) and rotations (N, 3, 3) of every node (Unity frame)."""
        n = len(self.t)
        P, R = np.zeros((n, 3)), np.zeros((n, 3, 3))
        done = np.zeros(n, bool)

        def get(i: int) -> None:
            if done[i]:
                return
            p = self.parent[i]
            if p < 0:
                pt, pr = self.model_t, self.model_r
            else:
                get(p)
                pt, pr = P[p], R[p]
            P[i], R[i] = pt + pr @ self.t[i], pr @ self.r[i]
            done[i] = True

        for i in range(n):
            get(i)
        return P, R

    def position(self, bone: str, rest: bool = False) -> np.ndarray:
        P = self.rest_world[0] if rest else self.world()[0]
        return P[self.bones[bone]]

    def rotation(self, bone: str) -> np.ndarray:
        return self.world()[1][self.bones[bone]]
