"""Writing a VRM: our avatar as VRM 1.0 (:func:`avatar_to_vrm`) or VRM 0.x (:func:`avatar_to_vrm0`).

VRM 1.0 (:func:`avatar_to_vrm`)
-------------------------------
Our avatar's glTF (:mod:`facecapges.avatar.gltf`) plus ``VRMC_vrm``:

* **meta** — name, authors, version, the VRM Public Licence 1.0 URL with liberal
  settings (anyone may use, modify and redistribute it, commercially too), the
  MediaPipe face mesh's Apache-2.0 notice in ``thirdPartyLicenses``.
* **humanoid** — :data:`~facecapges.avatar.vrm.humanoid.BEAT_BONES`: BEAT joint → VRM bone. BEAT's extra joints
  (Spine2, Neck1, the Index/Ring/Pinky metacarpals, fingertips, ForeFoot) stay as
  non-humanoid nodes between humanoid ones, which the spec allows. Hips is lifted so
  the soles (BEAT ForeFoot) stand on y = 0, as the VRM T-pose wants (under a ``Root``
  node at the origin); BEAT's rest pose already is a T-pose facing +Z, left hand at +X.
* **expressions** — the 52 ARKit blendshapes as *custom* expressions in perfect-sync
  spelling (``EyeBlinkLeft``, ``JawOpen`` …: :data:`facecapges.avatar.vrm.expressions.PERFECT_SYNC_NAMES`,
  the clip names VMC senders and perfect-sync avatars use), each bound to its morph
  target (named as in ARKit) at weight 1, and the VRM presets (``happy`` …) as fixed
  combinations of ARKit targets (:data:`~facecapges.avatar.vrm.expressions.PRESET_BINDS`); ``neutral`` binds nothing and
  is left out (the schema wants at least one bind per expression).
* **lookAt** — type ``expression`` (the face has no eye bones): ``lookUp/Down/Left/
  Right`` move the eyes with the ARKit eyeLook targets; the look-at origin is the
  centre of the eye openings.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from facecapges.avatar.vrm.expressions import PRESET_BINDS
from facecapges.avatar.vrm.humanoid import BEAT_BONES, REQUIRED_BONES, VRM0_RENAME, sole_lift
from facecapges.avatar.vrm.meta import SPEC_VERSION, vrm0_meta, vrm_meta
from facecapges.errors import UserError

# ARKit eye rotation range (degrees) behind eyeLook* = 1; the lookAt range maps use it
EYE_RANGE_DEG = 30.0


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
    preset, custom = _vrm_expressions(face, face_node)
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


def _vrm_expressions(face, face_node: int) -> tuple[dict, dict]:
    """VRM 1.0's preset expressions (bound to ARKit shapes) and the 52 perfect-sync custom ones."""
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

    custom = {PERFECT_SYNC_NAMES[k]: expr({a: 1.0}) for a in face.names if (k := arkit_index(a)) is not None}
    return preset, custom


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
    doc = avatar_to_vrm(_turned(avatar))
    v1 = doc.extensions["VRMC_vrm"]
    face_node = doc.nodes.index(next(n for n in doc.nodes if n.name == "Face"))
    face_mesh = doc.nodes[face_node].mesh
    groups = _vrm0_groups(v1, face_mesh)
    doc.extensionsUsed = ["VRM"]
    doc.extensions = {
        "VRM": {
            "exporterVersion": "facecapges-0.1.0",
            "specVersion": "0.0",
            "meta": vrm0_meta(v1["meta"]),
            "humanoid": _vrm0_humanoid(v1),
            "firstPerson": _vrm0_first_person(v1, face_mesh),
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


def _vrm0_groups(v1: dict, face_mesh: int) -> list[dict]:
    """UniVRM's blend shape groups from the VRM 1.0 expressions: Neutral, the presets, the perfect-sync shapes."""
    from facecapges.avatar.vrm.expressions import VRM1_NAMES

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
    return groups


def _vrm0_humanoid(v1: dict) -> dict:
    """VRM 0.x's humanoid: the VRM 1.0 bones renamed, UniVRM's default muscle settings."""
    to_v0 = {v: k for k, v in VRM0_RENAME.items()}
    return {
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
    }


def _vrm0_first_person(v1: dict, face_mesh: int) -> dict:
    """VRM 0.x's firstPerson: the head bone and offset, BlendShape lookAt."""
    # BlendShape lookAt: xRange = the gaze angle (degrees) that gives yRange = weight 1; linear curve
    look = {"curve": [0, 0, 0, 1, 1, 1, 1, 0], "xRange": EYE_RANGE_DEG, "yRange": 1.0}
    head = v1["humanoid"]["humanBones"]["head"]["node"]
    off = v1["lookAt"]["offsetFromHeadBone"]
    return {
        "firstPersonBone": head,
        "firstPersonBoneOffset": dict(zip("xyz", off)),
        "meshAnnotations": [{"mesh": face_mesh, "firstPersonFlag": "ThirdPersonOnly"}],
        "lookAtTypeName": "BlendShape",
        "lookAtHorizontalInner": dict(look),
        "lookAtHorizontalOuter": dict(look),
        "lookAtVerticalDown": dict(look),
        "lookAtVerticalUp": dict(look),
    }


def write_vrm(avatar, path: str | Path, version: str = "1.0") -> Path:
    """Write ``avatar`` to ``path`` as a VRM 1.0 (or, ``version="0.x"``, a VRM 0.x) binary glTF."""
    p = Path(path)
    doc = avatar_to_vrm0(avatar) if version == "0.x" else avatar_to_vrm(avatar)
    p.write_bytes(b"".join(doc.save_to_bytes()))
    return p
