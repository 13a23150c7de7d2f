"""VRM: the avatar written as VRM 1.0, and any VRM 0.x / 1.0 (or humanoid GLB) read back.

VRM is glTF 2.0 binary + the ``VRMC_vrm`` extension (1.0) or the ``VRM`` extension
(0.x): a map from humanoid bone names (``hips``, ``leftUpperArm`` …) to glTF nodes,
named facial expressions bound to morph targets, eye control and licence metadata.
Specification: vrm-c/vrm-specification, ``specification/VRMC_vrm-1.0``.

Writing (:func:`avatar_to_vrm`)
-------------------------------
Our avatar's glTF (:mod:`facecapges.avatar.gltf`) plus ``VRMC_vrm``:

* **meta** — name, authors, version, the VRM Public Licence 1.0 URL with liberal
  settings (anyone may use, modify and redistribute it, commercially too), the
  MediaPipe face mesh's Apache-2.0 notice in ``thirdPartyLicenses``.
* **humanoid** — :data:`BEAT_BONES`: BEAT joint → VRM bone. BEAT's extra joints
  (Spine2, Neck1, the Index/Ring/Pinky metacarpals, fingertips, ForeFoot) stay as
  non-humanoid nodes between humanoid ones, which the spec allows. Hips is lifted so
  the soles (BEAT ForeFoot) stand on y = 0, as the VRM T-pose wants (under a ``Root``
  node at the origin); BEAT's rest pose already is a T-pose facing +Z, left hand at +X.
* **expressions** — the 52 ARKit blendshapes as *custom* expressions in perfect-sync
  spelling (``EyeBlinkLeft``, ``JawOpen`` …: :data:`facecapges.avatar.vrm.expressions.PERFECT_SYNC_NAMES`,
  the clip names VMC senders and perfect-sync avatars use), each bound to its morph
  target (named as in ARKit) at weight 1, and the VRM presets (``happy`` …) as fixed
  combinations of ARKit targets (:data:`PRESET_BINDS`); ``neutral`` binds nothing and
  is left out (the schema wants at least one bind per expression).
* **lookAt** — type ``expression`` (the face has no eye bones): ``lookUp/Down/Left/
  Right`` move the eyes with the ARKit eyeLook targets; the look-at origin is the
  centre of the eye openings.

Reading (:func:`load_model`)
----------------------------
A ``.vrm`` (0.x or 1.0) or a ``.glb`` whose node names follow the BEAT / Mixamo
convention (``Hips``, ``Spine``, ``LeftArm``, ``LeftForeArm`` … with an optional
``mixamorig:`` prefix) becomes a :class:`VrmModel`: its humanoid bones, their rest
positions in a +Z-facing frame, and the expressions it offers. A plain GLB gets a
``VRMC_vrm`` extension written into its JSON in memory, so the browser always loads
the avatar through ``@pixiv/three-vrm``. Problems are :class:`UserError`\\ s: not a
glTF binary, a required humanoid bone missing (named), an extension the loader cannot
decode (``extensionsRequired`` outside :data:`SUPPORTED_EXTENSIONS`), an unknown VRM
version.

Faces (:class:`ExpressionMap`): a model with perfect-sync expressions gets the ARKit
weights as they are; any other gets its VRM presets from the ARKit weights by
:mod:`facecapges.avatar.vrm.expressions` (the project's one ARKit → VRM preset mapping).
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facecapges.errors import UserError

LICENSE_URL = "https://vrm.dev/licenses/1.0/"
SPEC_VERSION = "1.0"

# (bone, parent bone, required) in the VRM 1.0 humanoid table's order
HUMAN_BONES: tuple[tuple[str, str | None, bool], ...] = (
    ("hips", None, True),
    ("spine", "hips", True),
    ("chest", "spine", False),
    ("upperChest", "chest", False),
    ("neck", "upperChest", False),
    ("head", "neck", True),
    ("leftEye", "head", False),
    ("rightEye", "head", False),
    ("jaw", "head", False),
    ("leftUpperLeg", "hips", True),
    ("leftLowerLeg", "leftUpperLeg", True),
    ("leftFoot", "leftLowerLeg", True),
    ("leftToes", "leftFoot", False),
    ("rightUpperLeg", "hips", True),
    ("rightLowerLeg", "rightUpperLeg", True),
    ("rightFoot", "rightLowerLeg", True),
    ("rightToes", "rightFoot", False),
    ("leftShoulder", "upperChest", False),
    ("leftUpperArm", "leftShoulder", True),
    ("leftLowerArm", "leftUpperArm", True),
    ("leftHand", "leftLowerArm", True),
    ("rightShoulder", "upperChest", False),
    ("rightUpperArm", "rightShoulder", True),
    ("rightLowerArm", "rightUpperArm", True),
    ("rightHand", "rightLowerArm", True),
) + tuple(
    (f"{side}{finger}{part}", f"{side}{finger}{prev}" if prev else f"{side}Hand", False)
    for side in ("left", "right")
    for finger, parts in (
        ("Thumb", ("Metacarpal", "Proximal", "Distal")),
        ("Index", ("Proximal", "Intermediate", "Distal")),
        ("Middle", ("Proximal", "Intermediate", "Distal")),
        ("Ring", ("Proximal", "Intermediate", "Distal")),
        ("Little", ("Proximal", "Intermediate", "Distal")),
    )
    for prev, part in zip((None,) + parts[:-1], parts)
)
BONE_NAMES: tuple[str, ...] = tuple(b for b, _, _ in HUMAN_BONES)
BONE_PARENT: dict[str, str | None] = {b: p for b, p, _ in HUMAN_BONES}
REQUIRED_BONES: tuple[str, ...] = tuple(b for b, _, r in HUMAN_BONES if r)
# VRM 0.x names its thumb bones one joint further out
VRM0_RENAME = {
    f"{s}Thumb{a}": f"{s}Thumb{b}"
    for s in ("left", "right")
    for a, b in (("Proximal", "Metacarpal"), ("Intermediate", "Proximal"))
}


def _beat_bones() -> dict[str, str]:
    m = {"hips": "Hips", "spine": "Spine", "chest": "Spine1", "upperChest": "Spine3", "neck": "Neck", "head": "Head"}
    for side, S in (("left", "Left"), ("right", "Right")):
        m.update(
            {
                f"{side}Shoulder": f"{S}Shoulder",
                f"{side}UpperArm": f"{S}Arm",
                f"{side}LowerArm": f"{S}ForeArm",
                f"{side}Hand": f"{S}Hand",
                f"{side}UpperLeg": f"{S}UpLeg",
                f"{side}LowerLeg": f"{S}Leg",
                f"{side}Foot": f"{S}Foot",
                f"{side}Toes": f"{S}ToeBase",
            }
        )
        for finger, beat in (
            ("Thumb", "Thumb"),
            ("Index", "Index"),
            ("Middle", "Middle"),
            ("Ring", "Ring"),
            ("Little", "Pinky"),
        ):
            parts = (
                ("Metacarpal", "Proximal", "Distal") if finger == "Thumb" else ("Proximal", "Intermediate", "Distal")
            )
            for k, part in enumerate(parts, start=1):
                m[f"{side}{finger}{part}"] = f"{S}Hand{beat}{k}"
    return m


BEAT_BONES: dict[str, str] = _beat_bones()  # VRM bone → BEAT joint (BEAT and Mixamo share these names)

# glTF extensions three.js's GLTFLoader decodes with no extra decoder, plus the VRM family
SUPPORTED_EXTENSIONS = frozenset(
    {
        "KHR_materials_unlit",
        "KHR_texture_transform",
        "KHR_materials_emissive_strength",
        "KHR_mesh_quantization",
        "KHR_materials_clearcoat",
        "KHR_materials_ior",
        "KHR_materials_specular",
        "KHR_materials_transmission",
        "KHR_materials_volume",
        "KHR_materials_sheen",
        "KHR_materials_iridescence",
        "KHR_materials_anisotropy",
        "KHR_materials_dispersion",
        "KHR_lights_punctual",
        "KHR_materials_pbrSpecularGlossiness",
        "EXT_texture_webp",
        "EXT_mesh_gpu_instancing",
        "VRM",
        "VRMC_vrm",
        "VRMC_materials_mtoon",
        "VRMC_springBone",
        "VRMC_springBone_extended_collider",
        "VRMC_node_constraint",
        "VRMC_materials_hdr_emissiveMultiplier",
    }
)


def _preset_binds() -> dict[str, dict[str, float]]:
    """The VRM presets of the avatar we write, as combinations of its ARKit targets.

    They are the inverse of :mod:`facecapges.avatar.vrm.expressions`'s ARKit → preset mapping (the
    one mapping of the project): the visemes are its mouth prototypes spelled as ARKit
    targets, the emotions sit at the top of its ramps, so that a face showing preset
    ``p`` maps back to ``p`` (tested).
    """
    from facecapges.avatar.vrm.expressions import VISEME_PROTOTYPES, VISEMES, VRM1_NAMES

    binds: dict[str, dict[str, float]] = {}
    for v, (opening, funnel, pucker, stretch, lower, upper) in zip(VISEMES, VISEME_PROTOTYPES):
        b = {"jawOpen": opening, "mouthFunnel": funnel, "mouthPucker": pucker}
        for side in ("Left", "Right"):
            b.update({f"mouthStretch{side}": stretch, f"mouthLowerDown{side}": lower, f"mouthUpperUp{side}": upper})
        binds[VRM1_NAMES[v]] = {a: float(w) for a, w in b.items() if w > 0}
    both = lambda stem, w: {f"{stem}Left": w, f"{stem}Right": w}  # noqa: E731
    binds.update(
        {
            "happy": {**both("mouthSmile", 0.8), **both("cheekSquint", 0.6), **both("eyeSquint", 0.3)},
            "relaxed": both("mouthSmile", 0.8),
            "angry": {**both("browDown", 0.8), **both("noseSneer", 0.4), **both("mouthPress", 0.3)},
            "sad": {"browInnerUp": 0.8, **both("mouthFrown", 0.7)},
            "surprised": {**both("eyeWide", 0.8), **both("browOuterUp", 0.8), "browInnerUp": 0.5},
            "blink": both("eyeBlink", 1.0),
            "blinkLeft": {"eyeBlinkLeft": 1.0},
            "blinkRight": {"eyeBlinkRight": 1.0},
            # the model's left is +X: looking left turns the left eye out and the right eye in
            "lookUp": both("eyeLookUp", 1.0),
            "lookDown": both("eyeLookDown", 1.0),
            "lookLeft": {"eyeLookOutLeft": 1.0, "eyeLookInRight": 1.0},
            "lookRight": {"eyeLookInLeft": 1.0, "eyeLookOutRight": 1.0},
            "neutral": {},
        }
    )
    return binds


PRESET_BINDS: dict[str, dict[str, float]] = _preset_binds()
# ARKit eye rotation range (degrees) behind eyeLook* = 1; the lookAt range maps use it
EYE_RANGE_DEG = 30.0


# VRM 0.x preset names → 1.0
def _vrm0_presets() -> dict[str, str]:
    from facecapges.avatar.vrm.expressions import VRM1_NAMES

    return {**{k.lower(): v for k, v in VRM1_NAMES.items()}, "neutral": "neutral"}


VRM0_PRESETS = _vrm0_presets()  # VRM 0.x ``presetName`` (lower case in the file) → 1.0 name
PERFECT_SYNC_MIN = 26  # a model with at least this many ARKit-named expressions is driven by them


# ===================================================================== writing
def vrm_meta(name: str = "FaceCapGes avatar", version: str = "0.1.0") -> dict:
    """``VRMC_vrm.meta`` of the avatar we build (its licence: VRM Public Licence 1.0, liberal)."""
    return {
        "name": name,
        "version": version,
        "authors": ["FaceCapGes"],
        "copyrightInformation": "FaceCapGes contributors (MIT licence)",
        "licenseUrl": LICENSE_URL,
        "avatarPermission": "everyone",
        "allowExcessivelyViolentUsage": False,
        "allowExcessivelySexualUsage": False,
        "commercialUsage": "corporation",
        "allowPoliticalOrReligiousUsage": False,
        "allowAntisocialOrHateUsage": False,
        "creditNotation": "unnecessary",
        "allowRedistribution": True,
        "modification": "allowModificationRedistribution",
        "thirdPartyLicenses": "Face mesh: MediaPipe canonical face model (Google), Apache License 2.0.",
    }


def sole_lift(skel) -> float:
    """How far (metres) the BEAT skeleton ``skel`` must be lifted for its soles (ForeFoot) to stand on y = 0."""
    from facecapges.avatar.gltf import CM_TO_M
    from facecapges.skeleton import rest_positions

    P = rest_positions(skel) * CM_TO_M
    sole = skel.names.index("LeftForeFoot") if "LeftForeFoot" in skel.names else skel.names.index("LeftFoot")
    return float(-P[sole, 1])


def avatar_to_vrm(avatar):
    """The glTF document of ``avatar`` (facecapges.avatar.body.Avatar) as a VRM 1.0 (module docstring)."""
    import pygltflib as g

    from facecapges.avatar.body import EYE
    from facecapges.avatar.gltf import CM_TO_M, avatar_to_gltf

    doc = avatar_to_gltf(avatar)
    skel = avatar.skeleton
    names = [n.name for n in doc.nodes]
    missing = [b for b in REQUIRED_BONES if BEAT_BONES[b] not in skel.names]
    if missing:
        raise UserError(f"the skeleton lacks the joints of VRM bones {missing}")
    lift = sole_lift(skel)
    hips = names.index("Hips")
    root = len(doc.nodes)
    # the lift is on Hips (Root stays at the origin), as VRoid / UniVRM exports have it: a VMC sender's
    # Hips local position is then its height above the avatar's origin, whatever the avatar
    doc.nodes[hips].translation = [
        float(x) for x in np.add(doc.nodes[hips].translation or [0.0, 0.0, 0.0], [0, lift, 0])
    ]
    doc.nodes.append(g.Node(name="Root", translation=[0.0, 0.0, 0.0], children=[hips]))
    scene = doc.scenes[0]
    scene.nodes = [root if n == hips else n for n in scene.nodes]
    face_node = names.index("Face")
    face = avatar.face
    morph = {n: k for k, n in enumerate(face.names)}

    def expr(binds: dict[str, float]) -> dict:
        return {
            "morphTargetBinds": [
                {"node": face_node, "index": morph[a], "weight": float(w)} for a, w in binds.items() if a in morph
            ],
            "isBinary": False,
            "overrideBlink": "none",
            "overrideLookAt": "none",
            "overrideMouth": "none",
        }

    # a preset with nothing to bind (neutral) is left out: the schema wants at least one bind
    preset = {p: expr(b) for p, b in PRESET_BINDS.items() if b}
    for p in ("happy", "angry", "sad", "relaxed", "surprised"):  # emotions damp the procedural ones
        preset[p]["overrideBlink"] = preset[p]["overrideMouth"] = "blend"
    from facecapges.arkit import arkit_index
    from facecapges.avatar.vrm.expressions import PERFECT_SYNC_NAMES

    custom = {PERFECT_SYNC_NAMES[arkit_index(a)]: expr({a: 1.0}) for a in face.names if arkit_index(a) is not None}
    eye_v = np.unique(face.faces[EYE].reshape(-1)) if EYE in face.faces else np.arange(len(face.vertices))
    eyes = (face.vertices[eye_v].mean(0) + face.offset) * CM_TO_M  # in the Head joint's frame
    rng = {"inputMaxValue": EYE_RANGE_DEG, "outputScale": 1.0}
    ext = {
        "specVersion": SPEC_VERSION,
        "meta": vrm_meta(),
        "humanoid": {"humanBones": {b: {"node": names.index(j)} for b, j in BEAT_BONES.items() if j in names}},
        "firstPerson": {
            "meshAnnotations": [
                {"node": face_node, "type": "thirdPersonOnly"},
                {"node": names.index("Body"), "type": "auto"},
            ]
        },
        "expressions": {"preset": preset, "custom": custom},
        "lookAt": {
            "type": "expression",
            "offsetFromHeadBone": [float(x) for x in eyes],
            "rangeMapHorizontalInner": dict(rng),
            "rangeMapHorizontalOuter": dict(rng),
            "rangeMapVerticalDown": dict(rng),
            "rangeMapVerticalUp": dict(rng),
        },
    }
    doc.extensionsUsed = ["VRMC_vrm"]
    doc.extensions = {"VRMC_vrm": ext}
    doc.asset.generator = "facecapges avatar (VRM 1.0)"
    doc.extras["facecapges"]["format"] = "vrm"
    return doc


def _turned(avatar):
    """``avatar`` turned 180° about Y (facing −Z, its left hand at −X), as VRM 0.x wants it."""
    from dataclasses import replace

    f = np.array([-1.0, 1.0, -1.0])
    skel = replace(
        avatar.skeleton,
        offsets=avatar.skeleton.offsets * f,
        end_sites={j: v * f for j, v in avatar.skeleton.end_sites.items()},
    )
    body = replace(avatar.body, vertices=avatar.body.vertices * f, normals=avatar.body.normals * f)
    face = replace(
        avatar.face,
        vertices=avatar.face.vertices * f,
        normals=avatar.face.normals * f,
        deltas=avatar.face.deltas * f,
        normal_deltas=avatar.face.normal_deltas * f,
        offset=avatar.face.offset * f,
    )
    return replace(avatar, skeleton=skel, rest=avatar.rest * f, body=body, face=face)


def avatar_to_vrm0(avatar):
    """``avatar`` as a VRM 0.x (``VRM`` extension) for apps that read only 0.x (VSeeFace).

    The same content as :func:`avatar_to_vrm` in VRM 0.x terms: the model turned to face
    −Z (VRM 0.x's rule; a rotation of the data, no node rotation), UniVRM's blend shape
    groups — the presets with UniVRM's lower-case ``presetName`` plus the 52 ARKit shapes
    named in perfect-sync spelling (``EyeBlinkLeft`` …, :data:`facecapges.avatar.vrm.expressions.PERFECT_SYNC_NAMES`)
    — weights in 0–100, glTF materials (``VRM_USE_GLTFSHADER``), licence ``CC_BY`` (editing allowed).
    """
    from facecapges.avatar.vrm.expressions import VRM1_NAMES

    doc = avatar_to_vrm(_turned(avatar))
    v1 = doc.extensions["VRMC_vrm"]
    to_v0 = {v: k for k, v in VRM0_RENAME.items()}
    face_node = doc.nodes.index(next(n for n in doc.nodes if n.name == "Face"))
    face_mesh = doc.nodes[face_node].mesh

    def group(name: str, preset: str, expr: dict) -> dict:
        return {
            "name": name,
            "presetName": preset,
            "isBinary": False,
            "materialValues": [],
            "binds": [
                {"mesh": face_mesh, "index": b["index"], "weight": 100.0 * b["weight"]}
                for b in expr["morphTargetBinds"]
            ],
        }

    v0_name = {v: k for k, v in VRM1_NAMES.items()}
    groups = [group("Neutral", "neutral", {"morphTargetBinds": []})]  # UniVRM's empty Neutral clip
    for p, expr in v1["expressions"]["preset"].items():
        clip = v0_name[p]
        groups.append(group(clip, clip.lower() if clip != "Surprised" else "unknown", expr))
    for ps, expr in v1["expressions"]["custom"].items():
        groups.append(group(ps, "unknown", expr))
    # BlendShape lookAt: xRange = the gaze angle (degrees) that gives yRange = weight 1; linear curve
    look = {"curve": [0, 0, 0, 1, 1, 1, 1, 0], "xRange": EYE_RANGE_DEG, "yRange": 1.0}
    head = v1["humanoid"]["humanBones"]["head"]["node"]
    off = v1["lookAt"]["offsetFromHeadBone"]
    meta = v1["meta"]
    doc.extensionsUsed = ["VRM"]
    doc.extensions = {
        "VRM": {
            "exporterVersion": "facecapges-0.1.0",
            "specVersion": "0.0",
            "meta": {
                "title": meta["name"],
                "version": meta["version"],
                "author": meta["authors"][0],
                "contactInformation": "",
                "reference": "",
                "allowedUserName": "Everyone",
                "violentUssageName": "Disallow",
                "sexualUssageName": "Disallow",
                "commercialUssageName": "Allow",
                "otherPermissionUrl": "",
                # a named licence that allows editing: "Other" (or an other-licence URL) makes importers
                # such as Blender's VRM add-on ask for a licence confirmation before they load the file
                "licenseName": "CC_BY",
                "otherLicenseUrl": "",
            },
            "humanoid": {
                "humanBones": [
                    {"bone": to_v0.get(b, b), "node": d["node"], "useDefaultValues": True}
                    for b, d in v1["humanoid"]["humanBones"].items()
                ],
                "armStretch": 0.05,
                "legStretch": 0.05,
                "upperArmTwist": 0.5,
                "lowerArmTwist": 0.5,
                "upperLegTwist": 0.5,
                "lowerLegTwist": 0.5,
                "feetSpacing": 0.0,
                "hasTranslationDoF": False,
            },
            "firstPerson": {
                "firstPersonBone": head,
                "firstPersonBoneOffset": dict(zip("xyz", off)),
                "meshAnnotations": [{"mesh": face_mesh, "firstPersonFlag": "ThirdPersonOnly"}],
                "lookAtTypeName": "BlendShape",
                "lookAtHorizontalInner": dict(look),
                "lookAtHorizontalOuter": dict(look),
                "lookAtVerticalDown": dict(look),
                "lookAtVerticalUp": dict(look),
            },
            "blendShapeMaster": {"blendShapeGroups": groups},
            "secondaryAnimation": {"boneGroups": [], "colliderGroups": []},
            "materialProperties": [
                {
                    "name": m.name,
                    "shader": "VRM_USE_GLTFSHADER",
                    "renderQueue": 2000,
                    "floatProperties": {},
                    "vectorProperties": {},
                    "textureProperties": {},
                    "keywordMap": {},
                    "tagMap": {},
                }
                for m in doc.materials
            ],
        }
    }
    doc.asset.generator = "facecapges avatar (VRM 0.x)"
    return doc


def write_vrm(avatar, path: str | Path, version: str = "1.0") -> Path:
    """Write ``avatar`` to ``path`` as a VRM 1.0 (or, ``version="0.x"``, a VRM 0.x) binary glTF."""
    p = Path(path)
    doc = avatar_to_vrm0(avatar) if version == "0.x" else avatar_to_vrm(avatar)
    p.write_bytes(b"".join(doc.save_to_bytes()))
    return p


# ===================================================================== reading
def split_glb(data: bytes, name: str = "file") -> tuple[dict, bytes]:
    """A binary glTF's JSON (parsed and checked, :mod:`facecapges.avatar.gltf_check`) and its BIN chunk.

    UserError if ``data`` is not one, or is not a self-contained, well-formed glTF."""
    from facecapges.avatar.gltf_check import BIN_CHUNK, check_document, check_header, decode_json

    jlen = check_header(data[:20], len(data), name)
    doc = decode_json(data[20 : 20 + jlen], name)
    off = 20 + ((jlen + 3) & ~3)
    binary = b""
    if off + 8 <= len(data):
        blen, btype = struct.unpack_from("<II", data, off)
        if btype == BIN_CHUNK:
            binary = data[off + 8 : off + 8 + blen]
    check_document(doc, len(binary), name)
    return doc, binary


def join_glb(doc: dict, binary: bytes) -> bytes:
    """A binary glTF from its JSON and BIN chunk."""
    j = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    j += b" " * (-len(j) % 4)
    b = binary + b"\0" * (-len(binary) % 4)
    chunks = struct.pack("<II", len(j), 0x4E4F534A) + j
    if b:
        chunks += struct.pack("<II", len(b), 0x004E4942) + b
    return b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks


def _quat_matrix(q) -> np.ndarray:
    x, y, z, w = (float(v) for v in q)
    n = np.sqrt(x * x + y * y + z * z + w * w) or 1.0
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def node_world_matrices(doc: dict) -> np.ndarray:
    """World matrices (N, 4, 4) of every node at rest (scene roots at the origin).

    Walked parents first without recursion (a long node chain is fine); the tree was checked
    by :func:`facecapges.avatar.gltf_check.check_document` (one parent per node, no cycle)."""
    nodes = doc.get("nodes") or []
    N = len(nodes)
    local = np.zeros((N, 4, 4))
    children: list[list[int]] = [[] for _ in range(N)]
    has_parent = np.zeros(N, bool)
    for i, n in enumerate(nodes):
        if "matrix" in n:
            local[i] = np.asarray(n["matrix"], float).reshape(4, 4).T
        else:
            m = np.eye(4)
            m[:3, :3] = _quat_matrix(n.get("rotation", [0, 0, 0, 1])) * np.asarray(n.get("scale", [1, 1, 1]), float)
            m[:3, 3] = n.get("translation", [0, 0, 0])
            local[i] = m
        for c in n.get("children", []):
            if 0 <= c < N and not has_parent[c]:
                children[i].append(c)
                has_parent[c] = True
    world = np.full((N, 4, 4), np.nan)
    stack = [int(i) for i in np.flatnonzero(~has_parent)]
    for i in stack:
        world[i] = local[i]
    while stack:
        i = stack.pop()
        for c in children[i]:
            world[c] = world[i] @ local[c]
            stack.append(c)
    if np.isnan(world[:, 0, 0]).any():
        raise UserError("the glTF node tree has a cycle")
    return world


def _normalize_name(name: str) -> str:
    n = name
    for pre in ("mixamorig:", "mixamorig_", "mixamorig"):
        if n.lower().startswith(pre):
            n = n[len(pre) :]
    return n


def humanoid_from_names(doc: dict) -> dict[str, int]:
    """VRM bone → node index for a GLB whose nodes carry BEAT / Mixamo joint names."""
    by_name: dict[str, int] = {}
    for i, n in enumerate(doc.get("nodes") or []):
        key = _normalize_name(str(n.get("name", "")))
        by_name.setdefault(key, i)
    bones = {b: by_name[j] for b, j in BEAT_BONES.items() if j in by_name}
    # Mixamo has Spine, Spine1, Spine2: the last spine joint before the neck is the upper chest
    if "Spine3" not in by_name and "Spine2" in by_name:
        bones["upperChest"] = by_name["Spine2"]
    return bones


@dataclass
class VrmModel:
    """A humanoid avatar read from a file (module docstring)."""

    name: str
    kind: str  # "vrm1", "vrm0" or "glb"
    data: bytes  # what the browser loads (a plain GLB gets a VRMC_vrm extension added)
    bones: dict[str, int]  # VRM 1.0 bone name → node index
    rest: dict[str, np.ndarray]  # bone → rest position (3,), metres, model facing +Z, left hand at +X
    expressions: list[str]  # expression names as @pixiv/three-vrm exposes them
    title: str = ""
    info: dict = field(default_factory=dict)

    @property
    def faces_minus_z(self) -> bool:
        return self.kind == "vrm0"


def _check_extensions(doc: dict, name: str) -> None:
    required = [e for e in doc.get("extensionsRequired") or [] if e not in SUPPORTED_EXTENSIONS]
    if required:
        raise UserError(
            f"{name}: uses the glTF extension(s) {required}, which the avatar viewer cannot decode "
            f"(supported: plain glTF 2.0, VRM 0.x/1.0, MToon, KHR_materials_unlit, "
            f"KHR_texture_transform …); export the model without them"
        )


def _morph_names(doc: dict) -> list[str]:
    out: list[str] = []
    for mesh in doc.get("meshes") or []:
        for n in (mesh.get("extras") or {}).get("targetNames") or []:
            if isinstance(n, str) and n not in out:
                out.append(n)
    return out


def _synthesize_vrm1(doc: dict, bones: dict[str, int], name: str) -> None:
    """Give a plain humanoid GLB a minimal VRMC_vrm extension (in memory): bones + ARKit customs."""
    from facecapges.arkit import arkit_index
    from facecapges.avatar.vrm.expressions import PERFECT_SYNC_NAMES

    custom: dict[str, dict] = {}
    for ni, node in enumerate(doc.get("nodes") or []):
        if "mesh" not in node:
            continue
        mesh = doc["meshes"][node["mesh"]]
        for k, t in enumerate((mesh.get("extras") or {}).get("targetNames") or []):
            a = arkit_index(str(t))
            if a is not None:
                custom.setdefault(PERFECT_SYNC_NAMES[a], {"morphTargetBinds": []})["morphTargetBinds"].append(
                    {"node": ni, "index": k, "weight": 1.0}
                )
    doc.setdefault("extensionsUsed", []).append("VRMC_vrm")
    doc.setdefault("extensions", {})["VRMC_vrm"] = {
        "specVersion": SPEC_VERSION,
        "meta": {"name": name, "authors": ["unknown (imported GLB)"], "licenseUrl": LICENSE_URL},
        "humanoid": {"humanBones": {b: {"node": n} for b, n in bones.items()}},
        "expressions": {"custom": custom},
    }


def load_model(path: str | Path) -> VrmModel:
    """Read a VRM 0.x / 1.0 or humanoid GLB file (module docstring); UserError if it is none."""
    from facecapges.avatar.gltf_check import read_avatar_file

    return parse_model(read_avatar_file(path), str(Path(path)))


def parse_model(data: bytes, name: str = "avatar") -> VrmModel:
    doc, binary = split_glb(data, name)
    _check_extensions(doc, name)
    nodes = doc.get("nodes") or []
    ext = doc.get("extensions") or {}
    title = Path(name).stem
    if "VRMC_vrm" in ext:
        v = ext["VRMC_vrm"]
        if str(v.get("specVersion")) not in ("1.0", "1.0-beta"):
            raise UserError(f"{name}: VRMC_vrm specVersion {v.get('specVersion')!r} is not supported (1.0 is)")
        raw = (v.get("humanoid") or {}).get("humanBones") or {}
        bones = {b: int(d["node"]) for b, d in raw.items() if isinstance(d, dict) and "node" in d}
        kind = "vrm1"
        ex = v.get("expressions") or {}
        expressions = [n for n in (ex.get("preset") or {}) if n in PRESET_BINDS] + list(ex.get("custom") or {})
        title = str((v.get("meta") or {}).get("name") or title)
    elif "VRM" in ext:
        v = ext["VRM"]
        bones = {}
        for hb in (v.get("humanoid") or {}).get("humanBones") or []:
            if isinstance(hb, dict) and "bone" in hb and "node" in hb:
                b = VRM0_RENAME.get(hb["bone"], hb["bone"])
                bones[b] = int(hb["node"])
        kind = "vrm0"
        expressions = []
        for grp in (v.get("blendShapeMaster") or {}).get("blendShapeGroups") or []:
            preset = str(grp.get("presetName", "unknown")).lower()
            n = VRM0_PRESETS.get(preset) or grp.get("name")
            if n and n not in expressions:
                expressions.append(n)
        title = str((v.get("meta") or {}).get("title") or title)
    else:
        bones = humanoid_from_names(doc)
        kind = "glb"
        expressions = []
    bad = [b for b, n in bones.items() if not 0 <= n < len(nodes)]
    if bad:
        raise UserError(f"{name}: humanoid bones {bad} point at nodes that do not exist")
    bones = {b: n for b, n in bones.items() if b in BONE_PARENT}
    missing = [b for b in REQUIRED_BONES if b not in bones]
    if missing:
        what = "VRM humanoid" if kind != "glb" else "humanoid skeleton (BEAT / Mixamo joint names)"
        raise UserError(f"{name}: its {what} lacks the required bones {missing}")
    if kind == "glb":
        _synthesize_vrm1(doc, bones, title)
        expressions = list(doc["extensions"]["VRMC_vrm"]["expressions"]["custom"])
        data = join_glb(doc, binary)
    world = node_world_matrices(doc)
    flip = np.array([-1.0, 1.0, -1.0]) if kind == "vrm0" else np.ones(3)
    rest = {b: world[n, :3, 3] * flip for b, n in bones.items()}
    info = {
        "nodes": len(nodes),
        "bones": len(bones),
        "expressions": len(expressions),
        "morph_targets": len(_morph_names(doc)),
        "bytes": len(data),
    }
    return VrmModel(
        name=name, kind=kind, data=data, bones=bones, rest=rest, expressions=expressions, title=title, info=info
    )


# ===================================================================== faces
class ExpressionMap:
    """ARKit weights (T, 52) → the model's expression weights (T, E), E = ``names``.

    Perfect-sync models (≥ :data:`PERFECT_SYNC_MIN` expressions named as ARKit shapes, any
    case) get the ARKit weights as they are; the others their VRM presets, derived by
    :func:`facecapges.avatar.vrm.expressions.vrm0_weights` (the project's one ARKit → preset mapping).
    """

    def __init__(self, model: VrmModel):
        from facecapges.arkit import arkit_index
        from facecapges.avatar.vrm.expressions import VRM1_EXPRESSIONS

        direct: dict[int, str] = {}
        for n in model.expressions:
            a = arkit_index(n)
            if a is not None:
                direct.setdefault(a, n)
        self.perfect_sync = len(direct) >= PERFECT_SYNC_MIN
        if self.perfect_sync:
            self._index = sorted(direct)
            self.names = [direct[a] for a in self._index]
        else:
            self._index = [k for k, n in enumerate(VRM1_EXPRESSIONS) if n in model.expressions]
            self.names = [VRM1_EXPRESSIONS[k] for k in self._index]

    def __call__(self, arkit: np.ndarray) -> np.ndarray:
        from facecapges.avatar.vrm.expressions import vrm0_weights

        arkit = np.clip(np.asarray(arkit, np.float64), 0.0, 1.0)
        w = arkit if self.perfect_sync else vrm0_weights(arkit)
        return np.ascontiguousarray(w[..., self._index], dtype=np.float32)
