"""Gestures (+ face) as VRM Animation: a ``.vrma`` file (``VRMC_vrm_animation`` 1.0).

A ``.vrma`` is a binary glTF holding a humanoid skeleton in the VRM T-pose, one glTF
animation on it, and the extension mapping nodes to VRM humanoid bones and
expressions (spec: vrm-c/vrm-specification, ``specification/VRMC_vrm_animation-1.0``).
Players (``@pixiv/three-vrm-animation``, VRM apps) retarget it onto any VRM.

Layout written by :func:`motion_to_vrma`
----------------------------------------
* **Nodes**: the VRM humanoid bones BEAT has (:data:`facecapges.avatar.vrm.humanoid.BEAT_BONES`:
  52 of them, fingers included), in a tree of humanoid bones only, each at its BEAT
  rest offset (metres) with the identity as rest rotation — BEAT's rest pose is the VRM
  T-pose, facing +Z. A ``Root`` node lifts the hips so the soles stand on y = 0. BEAT
  joints that are not humanoid bones (Spine2, Neck1, metacarpals) are folded into the
  next humanoid bone (:class:`facecapges.avatar.retarget.Retargeter`), so nothing of
  the motion is lost.
* **Animation 0**: one rotation channel per bone (LINEAR, one key per frame at
  ``k / fps`` s), quaternions (x, y, z, w) as glTF stores them; no translations or
  scales (the spec allows a translation on hips only; BEAT's upper-body motion keeps
  them still).
* **Expressions**: one node per expression whose translation X is its weight (the
  spec's encoding), with ``face="presets"`` the VRM presets derived from the ARKit
  weights by :func:`facecapges.avatar.vrm.expressions.vrm0_weights` (any VRM can play them; the
  look presets are left out — the spec reserves them for lookAt), with
  ``face="perfect-sync"`` the 52 ARKit weights as custom expressions in perfect-sync
  spelling (``EyeBlinkLeft`` …, :data:`facecapges.avatar.vrm.expressions.PERFECT_SYNC_NAMES`), the names
  of the clips of perfect-sync avatars such as ours.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from facecapges.arkit import ARKIT_NAMES
from facecapges.avatar.vrm.humanoid import BEAT_BONES, sole_lift
from facecapges.avatar.vrm.read import VrmModel
from facecapges.errors import UserError

SPEC_VERSION = "1.0"
FACE_MODES = ("presets", "perfect-sync")


def check_face_mode(face: str) -> str:
    if face not in FACE_MODES:
        raise UserError(f"--vrma-face must be one of {', '.join(FACE_MODES)}, got {face!r}")
    return face


def beat_model(skel) -> VrmModel:
    """BEAT skeleton ``skel`` seen as a humanoid model (its rest pose, metres)."""
    from facecapges.skeleton import rest_positions

    P = rest_positions(skel) * 0.01
    bones = {b: skel.names.index(j) for b, j in BEAT_BONES.items() if j in skel.names}
    return VrmModel(
        name="BEAT", kind="vrm1", data=b"", bones=bones, rest={b: P[n] for b, n in bones.items()}, expressions=[]
    )


def motion_to_vrma(skel, local_mats: np.ndarray, fps: float, arkit: np.ndarray | None = None, face: str = "presets"):
    """The ``.vrma`` glTF document (pygltflib) of BEAT local rotations (T, J, 3, 3) (+ (T, 52) ARKit)."""
    import pygltflib as g

    from facecapges.avatar.retarget import Retargeter
    from facecapges.rotations import continuous_quaternions, matrix_to_quaternion

    check_face_mode(face)
    T = local_mats.shape[0]
    if T < 1:
        raise UserError("no frames to write as VRM Animation")
    model = beat_model(skel)
    rt = Retargeter(skel, model)
    L = rt.local_matrices(local_mats)  # (T, B, 3, 3); corrections are the identity on BEAT itself
    q = continuous_quaternions(matrix_to_quaternion(L))  # LINEAR (slerp) keys take the short way
    lift = sole_lift(skel)

    buf = _Blob()
    nodes, index = _bone_nodes(rt, model, lift)
    times = buf.add((np.arange(T) / fps)[:, None], g.SCALAR, minmax=True)
    samplers, channels = [], []
    for i, b in enumerate(rt.bones):
        out = buf.add(q[:, i][:, [1, 2, 3, 0]], g.VEC4)
        samplers.append(g.AnimationSampler(input=times, output=out, interpolation="LINEAR"))
        channels.append(
            g.AnimationChannel(
                sampler=len(samplers) - 1, target=g.AnimationChannelTarget(node=index[b], path="rotation")
            )
        )
    expressions: dict = {}
    scene_nodes = [0]
    if arkit is not None:
        group, tracks = _face_tracks(arkit, T, face)
        expressions[group] = _expression_channels(buf, nodes, samplers, channels, scene_nodes, times, tracks, T)
    ext = {"specVersion": SPEC_VERSION, "humanoid": {"humanBones": {b: {"node": index[b]} for b in rt.bones}}}
    if expressions:
        ext["expressions"] = expressions
    doc = g.GLTF2(
        asset=g.Asset(version="2.0", generator="facecapges (VRM Animation)"),
        scene=0,
        scenes=[g.Scene(nodes=scene_nodes)],
        nodes=nodes,
        animations=[g.Animation(name="gestures", samplers=samplers, channels=channels)],
        accessors=buf.accs,
        bufferViews=buf.views,
        buffers=[g.Buffer(byteLength=len(buf.blob))],
        extensionsUsed=["VRMC_vrm_animation"],
        extensions={"VRMC_vrm_animation": ext},
    )
    doc.set_binary_blob(bytes(buf.blob))
    return doc


class _Blob:
    """The binary chunk of a ``.vrma`` and its buffer views and float accessors (4-byte aligned)."""

    def __init__(self) -> None:
        self.blob = bytearray()
        self.views: list = []
        self.accs: list = []

    def add(self, arr: np.ndarray, typ: str, minmax: bool = False) -> int:
        """Append ``arr`` as float32; returns its accessor's index."""
        import pygltflib as g

        arr = np.ascontiguousarray(arr, np.float32)
        while len(self.blob) % 4:
            self.blob.append(0)
        self.views.append(g.BufferView(buffer=0, byteOffset=len(self.blob), byteLength=arr.nbytes))
        self.blob.extend(arr.tobytes())
        acc = g.Accessor(bufferView=len(self.views) - 1, componentType=g.FLOAT, count=int(arr.shape[0]), type=typ)
        if minmax:
            acc.min = [float(x) for x in arr.reshape(arr.shape[0], -1).min(0)]
            acc.max = [float(x) for x in arr.reshape(arr.shape[0], -1).max(0)]
        self.accs.append(acc)
        return len(self.accs) - 1


def _bone_nodes(rt, model: VrmModel, lift: float) -> tuple[list, dict]:
    """The ``Root`` node and the humanoid bones' tree at their rest offsets; each bone's node index."""
    import pygltflib as g

    nodes = [g.Node(name="Root", translation=[0.0, lift, 0.0], children=[])]
    index = {}
    for i, b in enumerate(rt.bones):
        p = rt.parent[i]
        offset = model.rest[b] - (model.rest[rt.bones[p]] if p >= 0 else 0.0)
        index[b] = len(nodes)
        nodes.append(g.Node(name=BEAT_BONES[b], translation=[float(x) for x in offset]))
        parent_node = index[rt.bones[p]] if p >= 0 else 0
        nodes[parent_node].children = list(nodes[parent_node].children or []) + [index[b]]
    return nodes, index


def _face_tracks(arkit: np.ndarray, T: int, face: str) -> tuple[str, dict[str, np.ndarray]]:
    """The expression group (``preset`` / ``custom``) and each expression's (T,) weights from (T, 52) ARKit."""
    from facecapges.avatar.vrm.expressions import PERFECT_SYNC_NAMES, VRM0_PRESETS, VRM1_NAMES, vrm0_weights

    arkit = np.clip(np.asarray(arkit, np.float64), 0.0, 1.0)
    if arkit.shape != (T, len(ARKIT_NAMES)):
        raise ValueError(f"face weights must be ({T}, {len(ARKIT_NAMES)}), got {arkit.shape}")
    if face == "presets":
        w = vrm0_weights(arkit)
        tracks = {VRM1_NAMES[n]: w[:, k] for k, n in enumerate(VRM0_PRESETS) if not n.startswith("Look")}
        group = "preset"
    else:
        tracks = {n: arkit[:, k] for k, n in enumerate(PERFECT_SYNC_NAMES)}
        group = "custom"
    return group, tracks


def _expression_channels(
    buf: _Blob, nodes: list, samplers: list, channels: list, scene_nodes: list, times: int, tracks: dict, T: int
) -> dict:
    """One node per expression, its weight animated as translation X (appended to the lists); name → node."""
    import pygltflib as g

    group: dict = {}
    for name, track in tracks.items():
        n = len(nodes)
        nodes.append(g.Node(name=f"Expression_{name}", translation=[0.0, 0.0, 0.0]))
        scene_nodes.append(n)
        xyz = np.zeros((T, 3), np.float32)
        xyz[:, 0] = track
        samplers.append(g.AnimationSampler(input=times, output=buf.add(xyz, g.VEC3), interpolation="LINEAR"))
        channels.append(
            g.AnimationChannel(sampler=len(samplers) - 1, target=g.AnimationChannelTarget(node=n, path="translation"))
        )
        group[name] = {"node": n}
    return group


def write_vrma(
    path: str | Path, skel, local_mats: np.ndarray, fps: float, arkit: np.ndarray | None = None, face: str = "presets"
) -> Path:
    """Write BEAT motion (+ face) to ``path`` as a ``.vrma``."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_bytes(b"".join(motion_to_vrma(skel, local_mats, fps, arkit, face).save_to_bytes()))
    return p


def write_bvh_as_vrma(
    bvh: str | Path, out: str | Path, face_json: str | Path | None = None, face: str = "presets"
) -> Path:
    """A BEAT BVH (+ face JSON, resampled to the BVH's rate) → ``.vrma``."""
    from facecapges.avatar.vrm.view import bvh_local_matrices
    from facecapges.io.bvh import read_bvh

    motion = read_bvh(bvh)
    L = bvh_local_matrices(motion.skeleton, motion.motion)
    arkit = None
    if face_json is not None:
        from facecapges.avatar.vrm.view import face_weights

        arkit = face_weights(Path(face_json), motion.fps, len(L))
    return write_vrma(out, motion.skeleton, L, motion.fps, arkit, face)


def write_pose_vrma(
    path: str | Path, skel, pose: np.ndarray, fps: float, arkit: np.ndarray | None = None, face: str = "presets"
) -> Path:
    """Upper-body poses (T, 47, 6) rot6d (other joints at rest) (+ (T, 52) ARKit) → ``.vrma``."""
    from facecapges.rotations import rot6d_to_matrix
    from facecapges.skeleton import upper_body_indices

    pose = np.asarray(pose, np.float64)
    mats = np.broadcast_to(np.eye(3), (len(pose), skel.n_joints, 3, 3)).copy()
    mats[:, upper_body_indices(skel)] = rot6d_to_matrix(pose)
    return write_vrma(path, skel, mats, fps, arkit, face)


class VrmaRecorder:
    """A runtime sink (``write(frame)`` / ``close()``, like the BVH recorder): every frame's
    pose (47, 6) and face (52,) in memory, the ``.vrma`` written on close (``live --record``)."""

    def __init__(self, path: str | Path, skeleton, fps: float, face: str = "presets"):
        self.path, self.skeleton, self.fps, self.face = Path(path), skeleton, fps, check_face_mode(face)
        self.poses: list[np.ndarray] = []
        self.weights: list[np.ndarray] = []
        self.closed = False

    def write(self, out) -> None:
        self.poses.append(np.asarray(out.pose, np.float32))
        self.weights.append(np.asarray(out.face, np.float32))

    def close(self) -> Path | None:
        if self.closed or not self.poses:
            self.closed = True
            return None
        self.closed = True
        from facecapges.rotations import normalize_rot6d

        poses = normalize_rot6d(np.stack(self.poses).astype(np.float64))
        return write_pose_vrma(self.path, self.skeleton, poses, self.fps, np.stack(self.weights), self.face)
