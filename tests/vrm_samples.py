"""Humanoid test avatars built here, independently of facecapges' VRM writer.

:func:`build_sample` writes, with pygltflib only, a small humanoid whose proportions
differ from BEAT's (long arms, short torso, wide shoulders), made of one box per bone,
rigidly skinned; the left hand is pure red and the right hand pure blue so a
screenshot shows where the hands are. Variants:

* ``"vrm1"`` — VRM 1.0 (``VRMC_vrm``), facing +Z; every node has a *non-identity* rest
  rotation (translations compensate, the appearance is the T-pose), so three-vrm's
  bone normalisation and our rest-pose handling are both exercised; 52 perfect-sync
  custom expressions.
* ``"vrm1_blender"`` — the same VRM 1.0 with rest rotations as Blender's VRM add-on exports
  them: each bone's local +Y points along the bone to its first child (Blender's bone
  axis), +Z as near the model's forward axis as that allows (e.g. the left shoulder's
  rest rotation turns +Y to +X).
* ``"vrm0"`` — VRM 0.x (``VRM`` extension), facing −Z as VRM 0.x does, identity rest
  rotations, presets only (blink, a, joy …) on a few morph targets.
* ``"glb"`` — a plain GLB with Mixamo joint names (``mixamorig:LeftArm`` …), arms in an
  A-pose (40° down), no fingers: the rest-pose correction must raise the arms.
"""

from __future__ import annotations

import numpy as np
import pygltflib as g

from facecapges.avatar.vrm.expressions import PERFECT_SYNC_NAMES

# bone, parent, canonical rest position relative to the parent (metres, +Z forward, left = +X)
_TORSO = [("hips", None, (0, 0.95, 0)), ("spine", "hips", (0, 0.08, -0.01)), ("chest", "spine", (0, 0.10, 0)),
          ("upperChest", "chest", (0, 0.09, 0.01)), ("neck", "upperChest", (0, 0.14, 0)),
          ("head", "neck", (0, 0.09, 0.01))]


def _side(s: str, sx: float, fingers: bool) -> list:
    S = s
    bones = [(f"{S}Shoulder", "upperChest", (sx * 0.03, 0.11, 0)), (f"{S}UpperArm", f"{S}Shoulder", (sx * 0.13, 0, 0)),
             (f"{S}LowerArm", f"{S}UpperArm", (sx * 0.34, 0, 0)), (f"{S}Hand", f"{S}LowerArm", (sx * 0.31, 0, 0)),
             (f"{S}UpperLeg", "hips", (sx * 0.10, -0.05, 0)), (f"{S}LowerLeg", f"{S}UpperLeg", (0, -0.43, 0)),
             (f"{S}Foot", f"{S}LowerLeg", (0, -0.42, 0)), (f"{S}Toes", f"{S}Foot", (0, -0.04, 0.12))]
    if fingers:
        for f, z, n in (("Index", 0.025, "Proximal Intermediate Distal"), ("Middle", 0.0, "Proximal Intermediate Distal"),
                        ("Thumb", 0.04, "Metacarpal Proximal Distal")):
            parent = f"{S}Hand"
            for k, part in enumerate(n.split()):
                off = (sx * (0.09 if k == 0 and f != "Thumb" else 0.035), 0, z if k == 0 else (0.02 if f == "Thumb" else 0))
                if f == "Thumb" and k == 0:
                    off = (sx * 0.02, -0.01, 0.03)
                bones.append((f"{S}{f}{part}", parent, off))
                parent = f"{S}{f}{part}"
    return bones


MIXAMO = {"hips": "Hips", "spine": "Spine", "chest": "Spine1", "upperChest": "Spine2", "neck": "Neck", "head": "Head"}
for _s, _S in (("left", "Left"), ("right", "Right")):
    MIXAMO.update({f"{_s}Shoulder": f"{_S}Shoulder", f"{_s}UpperArm": f"{_S}Arm", f"{_s}LowerArm": f"{_S}ForeArm",
                   f"{_s}Hand": f"{_S}Hand", f"{_s}UpperLeg": f"{_S}UpLeg", f"{_s}LowerLeg": f"{_S}Leg",
                   f"{_s}Foot": f"{_S}Foot", f"{_s}Toes": f"{_S}ToeBase"})


def _rot(axis, angle) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _quat_xyzw(R: np.ndarray) -> list[float]:
    from facecapges.rotations import matrix_to_quaternion

    w, x, y, z = matrix_to_quaternion(R)
    return [float(x), float(y), float(z), float(w)]


def skeleton(variant: str) -> tuple[list[str], list[int], np.ndarray]:
    """Bone names (VRM), parent indices and canonical rest world positions (+Z facing)."""
    fingers = variant.startswith("vrm1")
    bones = _TORSO + _side("left", 1, fingers) + _side("right", -1, fingers)
    names = [b for b, _, _ in bones]
    parents = [names.index(p) if p else -1 for _, p, _ in bones]
    P = np.zeros((len(bones), 3))
    for i, (_, _, off) in enumerate(bones):
        P[i] = np.asarray(off, float) + (P[parents[i]] if parents[i] >= 0 else 0)
    if variant == "glb":  # A-pose: each arm chain turned 40° down about the forward axis at the upper arm
        for side, sx in (("left", 1), ("right", -1)):
            root = names.index(f"{side}UpperArm")
            R = _rot([0, 0, 1], -sx * np.radians(40))
            for i, n in enumerate(names):
                if n.startswith(side) and any(k in n for k in ("LowerArm", "Hand")):
                    P[i] = P[root] + R @ (P[i] - P[root])
    return names, parents, P


def _bone_axes(P: np.ndarray, parents: list[int]) -> list[np.ndarray]:
    """Blender-style rest frames: +Y along the bone (to the first child, else the parent's way), +Z forward-most."""
    out = []
    for i in range(len(P)):
        kids = [c for c in range(len(P)) if parents[c] == i]
        d = P[kids[0]] - P[i] if kids else P[i] - P[parents[i]]
        y = d / np.linalg.norm(d)
        ref = np.array([0.0, 0.0, 1.0]) if abs(y[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
        z = ref - y * (ref @ y)
        z /= np.linalg.norm(z)
        out.append(np.stack([np.cross(y, z), y, z], axis=1))
    return out


def build_sample(variant: str, head_scale: float = 1.0) -> bytes:
    """The sample avatar ``variant`` ("vrm1", "vrm1_blender", "vrm0" or "glb") as binary glTF bytes.

    ``head_scale`` scales the head box (a big-headed avatar: 2–3 × ours)."""
    names, parents, P = skeleton(variant)
    J = len(names)
    flip = np.array([-1.0, 1.0, -1.0]) if variant == "vrm0" else np.ones(3)
    Pw = P * flip
    rng = np.random.default_rng(7)
    Rw = [(_rot(rng.normal(size=3), rng.uniform(0.3, 1.2)) if variant == "vrm1" else np.eye(3)) for _ in range(J)]
    if variant == "vrm1_blender":
        Rw = _bone_axes(Pw, parents)
    nodes = []
    for i in range(J):
        p = parents[i]
        Rp = Rw[p] if p >= 0 else np.eye(3)
        tp = Pw[p] if p >= 0 else np.zeros(3)
        t = Rp.T @ (Pw[i] - tp)
        r = Rp.T @ Rw[i]
        node_name = ("mixamorig:" + MIXAMO[names[i]]) if variant == "glb" else f"J_{names[i]}"
        nodes.append(g.Node(name=node_name, translation=[float(x) for x in t], rotation=_quat_xyzw(r),
                            children=[c for c in range(J) if parents[c] == i]))
    # one box per bone (from the joint to its first child, or a short stub), skinned to that bone
    V, N, JI, F = [], [], [], {"body": [], "left": [], "right": []}
    kids = {i: [c for c in range(J) if parents[c] == i] for i in range(J)}
    for i, n in enumerate(names):
        if n in ("hips",) or "Toes" in n:
            continue
        a = Pw[i]
        along = (a - Pw[parents[i]]) / np.linalg.norm(a - Pw[parents[i]]) if parents[i] >= 0 else np.zeros(3)
        if n.endswith("Hand"):
            b = a + along * 0.09
        elif n == "head":
            b = a + np.array([0, 0.2 * head_scale, 0])
        elif kids[i]:
            b = Pw[kids[i][0]]
        else:
            b = a + along * 0.025
        mat = "body"
        if n.endswith("Hand") or any(f in n for f in ("Thumb", "Index", "Middle")):
            mat = "left" if n.startswith("left") else "right"
        d = b - a
        L = np.linalg.norm(d)
        u = d / L
        v = np.cross(u, [0, 0, 1.0]) if abs(u[2]) < 0.9 else np.cross(u, [1.0, 0, 0])
        v /= np.linalg.norm(v)
        w = np.cross(u, v)
        r = 0.03 if mat == "body" else 0.025
        if "Proximal" in n or "Intermediate" in n or "Distal" in n or "Metacarpal" in n:
            r = 0.008
        if n == "head":
            r = 0.09 * head_scale
        base = len(V)
        for s in (0, 1):
            for cv, cw in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                V.append(a + s * d + r * (cv * v + cw * w))
                N.append(cv * v + cw * w)
                JI.append(i)
        quads = [(0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7), (3, 2, 1, 0), (4, 5, 6, 7)]
        for q in quads:
            F[mat] += [(base + q[0], base + q[1], base + q[2]), (base + q[0], base + q[2], base + q[3])]
    V = np.asarray(V, np.float32)
    N = np.asarray(N, np.float32)
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    blob = bytearray()
    views, accs = [], []

    def add(arr, typ, target=None, minmax=False):
        arr = np.ascontiguousarray(arr)
        while len(blob) % 4:
            blob.append(0)
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=arr.nbytes, target=target))
        blob.extend(arr.tobytes())
        ct = {np.dtype(np.float32): g.FLOAT, np.dtype(np.uint16): g.UNSIGNED_SHORT}[arr.dtype]
        acc = g.Accessor(bufferView=len(views) - 1, componentType=ct, count=len(arr), type=typ)
        if minmax:
            acc.min = [float(x) for x in arr.reshape(len(arr), -1).min(0)]
            acc.max = [float(x) for x in arr.reshape(len(arr), -1).max(0)]
        accs.append(acc)
        return len(accs) - 1

    pos = add(V, g.VEC3, g.ARRAY_BUFFER, True)
    nrm = add(N, g.VEC3, g.ARRAY_BUFFER)
    jnt = add(np.stack([np.asarray(JI), np.zeros(len(JI)), np.zeros(len(JI)), np.zeros(len(JI))], 1).astype(np.uint16),
              g.VEC4, g.ARRAY_BUFFER)
    wgt = add(np.tile(np.array([1, 0, 0, 0], np.float32), (len(V), 1)), g.VEC4, g.ARRAY_BUFFER)
    colors = {"body": [0.55, 0.55, 0.6, 1], "left": [1, 0, 0, 1], "right": [0, 0, 1, 1]}
    materials = [g.Material(name=m, pbrMetallicRoughness=g.PbrMetallicRoughness(baseColorFactor=c, metallicFactor=0,
                                                                                 roughnessFactor=1),
                            emissiveFactor=c[:3] if m != "body" else [0, 0, 0],
                            extensions={"KHR_materials_unlit": {}} if m != "body" else {})
                 for m, c in colors.items()]
    prims = [g.Primitive(attributes=g.Attributes(POSITION=pos, NORMAL=nrm, JOINTS_0=jnt, WEIGHTS_0=wgt),
                         indices=add(np.asarray(F[m], np.uint16).reshape(-1), g.SCALAR, g.ELEMENT_ARRAY_BUFFER),
                         material=k) for k, m in enumerate(colors)]
    ibm = np.zeros((J, 4, 4), np.float32)
    for i in range(J):
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = Rw[i], Pw[i]
        ibm[i] = np.linalg.inv(M).T
    ibm_acc = add(ibm.reshape(J, 16), g.MAT4)
    meshes = [g.Mesh(name="Body", primitives=prims)]
    nodes.append(g.Node(name="Body", mesh=0, skin=0))
    # a face patch under the head with morph targets (perfect sync on vrm1, a few presets on vrm0)
    head = names.index("head")
    fv = np.array([[-0.04, 0.06, 0.1], [0.04, 0.06, 0.1], [0.04, 0.12, 0.1], [-0.04, 0.12, 0.1]], np.float32)
    fv = (fv * flip).astype(np.float32)
    targets_names = list(PERFECT_SYNC_NAMES) if variant.startswith("vrm1") else ["Blink", "Mouth_A", "Smile"]
    fpos = add(fv, g.VEC3, g.ARRAY_BUFFER, True)
    targets = []
    for k in range(len(targets_names)):
        dv = np.zeros_like(fv)
        dv[k % 4, 1] = 0.01
        targets.append({"POSITION": add(dv, g.VEC3, g.ARRAY_BUFFER, True)})
    fidx = add(np.array([0, 1, 2, 0, 2, 3], np.uint16), g.SCALAR, g.ELEMENT_ARRAY_BUFFER)
    meshes.append(g.Mesh(name="Face", primitives=[g.Primitive(attributes=g.Attributes(POSITION=fpos), targets=targets,
                                                               indices=fidx, material=0)],
                         weights=[0.0] * len(targets_names), extras={"targetNames": targets_names}))
    face_node = len(nodes)
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = Rw[head], Pw[head]
    Minv = np.linalg.inv(M)
    nodes.append(g.Node(name="FacePatch", mesh=1, translation=[float(x) for x in Minv[:3, 3]],
                        rotation=_quat_xyzw(Minv[:3, :3])))
    nodes[head].children = list(nodes[head].children) + [face_node]
    skin = g.Skin(joints=list(range(J)), inverseBindMatrices=ibm_acc, skeleton=0)
    doc = g.GLTF2(asset=g.Asset(version="2.0", generator="facecapges tests/vrm_samples.py"), scene=0,
                  scenes=[g.Scene(nodes=[0, J])], nodes=nodes, meshes=meshes, skins=[skin], materials=materials,
                  accessors=accs, bufferViews=views, buffers=[g.Buffer(byteLength=len(blob))],
                  extensionsUsed=["KHR_materials_unlit"])
    if variant.startswith("vrm1"):
        doc.extensionsUsed.append("VRMC_vrm")
        bind = lambda k: {"morphTargetBinds": [{"node": face_node, "index": k, "weight": 1.0}]}  # noqa: E731
        doc.extensions = {"VRMC_vrm": {
            "specVersion": "1.0",
            "meta": {"name": "sample long-armed VRM 1.0", "authors": ["facecapges tests"],
                     "licenseUrl": "https://vrm.dev/licenses/1.0/"},
            "humanoid": {"humanBones": {n: {"node": i} for i, n in enumerate(names)}},
            "expressions": {"preset": {"blink": bind(list(PERFECT_SYNC_NAMES).index("EyeBlinkLeft"))},
                            "custom": {n: bind(k) for k, n in enumerate(PERFECT_SYNC_NAMES)}}}}
    elif variant == "vrm0":
        doc.extensionsUsed.append("VRM")
        v0name = {"leftThumbMetacarpal": "leftThumbProximal"}  # (no fingers in this variant)
        groups = [{"name": "Blink", "presetName": "blink", "binds": [{"mesh": 1, "index": 0, "weight": 100}],
                   "materialValues": [], "isBinary": False},
                  {"name": "A", "presetName": "a", "binds": [{"mesh": 1, "index": 1, "weight": 100}],
                   "materialValues": [], "isBinary": False},
                  {"name": "Joy", "presetName": "joy", "binds": [{"mesh": 1, "index": 2, "weight": 100}],
                   "materialValues": [], "isBinary": False}]
        doc.extensions = {"VRM": {
            "exporterVersion": "facecapges-tests", "specVersion": "0.0",
            "meta": {"title": "sample long-armed VRM 0.x", "version": "1", "author": "facecapges tests",
                     "allowedUserName": "Everyone", "licenseName": "CC0"},
            "humanoid": {"humanBones": [{"bone": v0name.get(n, n), "node": i, "useDefaultValues": True}
                                        for i, n in enumerate(names)]},
            "blendShapeMaster": {"blendShapeGroups": groups},
            "firstPerson": {"firstPersonBone": head, "firstPersonBoneOffset": {"x": 0, "y": 0.06, "z": 0},
                            "meshAnnotations": [], "lookAtTypeName": "BlendShape"},
            "secondaryAnimation": {"boneGroups": [], "colliderGroups": []},
            "materialProperties": []}}
    doc.set_binary_blob(bytes(blob))
    return b"".join(doc.save_to_bytes())
