"""JSON Schemas (draft 2020-12) of ``VRMC_vrm`` 1.0 and ``VRMC_vrm_animation`` 1.0, for the tests.

Written for this project from the VRM specification (vrm-c/vrm-specification,
``specification/VRMC_vrm-1.0/{README,meta,humanoid,expressions,lookAt,firstPerson}.md``
and ``specification/VRMC_vrm_animation-1.0``): the property tables — types, required
properties, allowed values, index minimums — restated as schemas. No npm package ships
the published ``*.schema.json`` files and nothing is downloaded at test time, so the
rules live here. Beyond the per-property rules, :func:`semantic_errors` checks what a
schema cannot: node indices in range, a bound node has a mesh whose morph target
exists, humanoid bones unique and each one's VRM parent an ancestor in the node tree.
"""

from __future__ import annotations

PRESETS = ["happy", "angry", "sad", "relaxed", "surprised", "aa", "ih", "ou", "ee", "oh", "blink", "blinkLeft",
           "blinkRight", "lookUp", "lookDown", "lookLeft", "lookRight", "neutral"]
_TORSO = ["hips", "spine", "chest", "upperChest", "neck", "head", "leftEye", "rightEye", "jaw"]
_LIMBS = [f"{s}{p}" for s in ("left", "right") for p in ("UpperLeg", "LowerLeg", "Foot", "Toes", "Shoulder",
                                                          "UpperArm", "LowerArm", "Hand")]
_FINGERS = [f"{s}{f}{p}" for s in ("left", "right") for f, parts in (
    ("Thumb", ("Metacarpal", "Proximal", "Distal")), ("Index", ("Proximal", "Intermediate", "Distal")),
    ("Middle", ("Proximal", "Intermediate", "Distal")), ("Ring", ("Proximal", "Intermediate", "Distal")),
    ("Little", ("Proximal", "Intermediate", "Distal"))) for p in parts]
HUMAN_BONES = _TORSO + _LIMBS + _FINGERS
REQUIRED_BONES = ["hips", "spine", "head"] + [f"{s}{p}" for s in ("left", "right") for p in (
    "UpperLeg", "LowerLeg", "Foot", "UpperArm", "LowerArm", "Hand")]

_index = {"type": "integer", "minimum": 0}
_ext = {"extensions": {"type": "object"}, "extras": {}}

_bone = {"type": "object", "properties": {"node": _index, **_ext}, "required": ["node"]}
_override = {"enum": ["none", "block", "blend"]}
_expression = {
    "type": "object",
    "properties": {
        "morphTargetBinds": {"type": "array", "minItems": 1, "items": {
            "type": "object", "required": ["node", "index", "weight"],
            "properties": {"node": _index, "index": _index, "weight": {"type": "number", "minimum": 0, "maximum": 1},
                           **_ext}}},
        "materialColorBinds": {"type": "array", "items": {
            "type": "object", "required": ["material", "type", "targetValue"],
            "properties": {"material": _index, "type": {"enum": ["color", "emissionColor", "shadeColor",
                                                                 "matcapColor", "rimColor", "outlineColor"]},
                           "targetValue": {"type": "array", "items": {"type": "number"}, "minItems": 4,
                                           "maxItems": 4}}}},
        "textureTransformBinds": {"type": "array", "items": {
            "type": "object", "required": ["material"],
            "properties": {"material": _index,
                           "scale": {"type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": 2},
                           "offset": {"type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": 2}}}},
        "isBinary": {"type": "boolean"},
        "overrideBlink": _override, "overrideLookAt": _override, "overrideMouth": _override, **_ext,
    },
}
_range_map = {"type": "object", "properties": {"inputMaxValue": {"type": "number", "minimum": 0},
                                               "outputScale": {"type": "number"}, **_ext}}
_string_list = {"type": "array", "items": {"type": "string"}}

VRMC_VRM = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "VRMC_vrm 1.0",
    "type": "object",
    "required": ["specVersion", "humanoid", "meta"],
    "properties": {
        "specVersion": {"const": "1.0"},
        "meta": {
            "type": "object",
            "required": ["name", "authors", "licenseUrl"],
            "properties": {
                "name": {"type": "string", "minLength": 1}, "version": {"type": "string"},
                "authors": {"type": "array", "minItems": 1, "items": {"type": "string"},
                            "contains": {"type": "string", "minLength": 1}},
                "copyrightInformation": {"type": "string"}, "contactInformation": {"type": "string"},
                "references": _string_list, "thirdPartyLicenses": {"type": "string"}, "thumbnailImage": _index,
                "licenseUrl": {"const": "https://vrm.dev/licenses/1.0/"},
                "avatarPermission": {"enum": ["onlyAuthor", "onlySeparatelyLicensedPerson", "everyone"]},
                "allowExcessivelyViolentUsage": {"type": "boolean"},
                "allowExcessivelySexualUsage": {"type": "boolean"},
                "commercialUsage": {"enum": ["personalNonProfit", "personalProfit", "corporation"]},
                "allowPoliticalOrReligiousUsage": {"type": "boolean"},
                "allowAntisocialOrHateUsage": {"type": "boolean"},
                "creditNotation": {"enum": ["required", "unnecessary"]},
                "allowRedistribution": {"type": "boolean"},
                "modification": {"enum": ["prohibited", "allowModification", "allowModificationRedistribution"]},
                "otherLicenseUrl": {"type": "string"}, **_ext,
            },
            "additionalProperties": False,
        },
        "humanoid": {
            "type": "object", "required": ["humanBones"],
            "properties": {"humanBones": {
                "type": "object", "required": REQUIRED_BONES,
                "properties": {b: _bone for b in HUMAN_BONES}, "additionalProperties": False}, **_ext},
        },
        "firstPerson": {"type": "object", "properties": {"meshAnnotations": {"type": "array", "items": {
            "type": "object", "required": ["node", "type"],
            "properties": {"node": _index, "type": {"enum": ["auto", "both", "thirdPersonOnly", "firstPersonOnly"]},
                           **_ext}}}, **_ext}},
        "lookAt": {
            "type": "object",
            "properties": {
                "offsetFromHeadBone": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3},
                "type": {"enum": ["bone", "expression"]},
                "rangeMapHorizontalInner": _range_map, "rangeMapHorizontalOuter": _range_map,
                "rangeMapVerticalDown": _range_map, "rangeMapVerticalUp": _range_map, **_ext,
            },
        },
        "expressions": {
            "type": "object",
            "properties": {
                "preset": {"type": "object", "properties": {p: _expression for p in PRESETS},
                           "additionalProperties": False},
                "custom": {"type": "object", "propertyNames": {"not": {"enum": PRESETS}},
                           "additionalProperties": _expression},
                **_ext,
            },
        },
        **_ext,
    },
}

_node_ref = {"type": "object", "required": ["node"], "properties": {"node": _index, **_ext}}
VRMC_VRM_ANIMATION = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "VRMC_vrm_animation 1.0",
    "type": "object",
    "required": ["specVersion", "humanoid"],
    "properties": {
        "specVersion": {"const": "1.0"},
        "humanoid": {"type": "object", "required": ["humanBones"], "properties": {"humanBones": {
            "type": "object", "required": REQUIRED_BONES,
            "properties": {b: _node_ref for b in HUMAN_BONES if b not in ("leftEye", "rightEye")},
            "additionalProperties": False}}},
        "expressions": {"type": "object", "properties": {
            "preset": {"type": "object", "properties": {p: _node_ref for p in PRESETS if not p.startswith("look")},
                       "additionalProperties": False},
            "custom": {"type": "object", "propertyNames": {"not": {"enum": PRESETS}},
                       "additionalProperties": _node_ref}}},
        "lookAt": _node_ref,
        **_ext,
    },
}

PARENT = {"spine": "hips", "chest": "spine", "upperChest": "chest", "neck": "upperChest", "head": "neck",
          "leftEye": "head", "rightEye": "head", "jaw": "head"}
for _s in ("left", "right"):
    PARENT.update({f"{_s}UpperLeg": "hips", f"{_s}LowerLeg": f"{_s}UpperLeg", f"{_s}Foot": f"{_s}LowerLeg",
                   f"{_s}Toes": f"{_s}Foot", f"{_s}Shoulder": "upperChest", f"{_s}UpperArm": f"{_s}Shoulder",
                   f"{_s}LowerArm": f"{_s}UpperArm", f"{_s}Hand": f"{_s}LowerArm"})
    for _f in ("Thumb", "Index", "Middle", "Ring", "Little"):
        _parts = ("Metacarpal", "Proximal", "Distal") if _f == "Thumb" else ("Proximal", "Intermediate", "Distal")
        PARENT[f"{_s}{_f}{_parts[0]}"] = f"{_s}Hand"
        PARENT[f"{_s}{_f}{_parts[1]}"] = f"{_s}{_f}{_parts[0]}"
        PARENT[f"{_s}{_f}{_parts[2]}"] = f"{_s}{_f}{_parts[1]}"


def semantic_errors(doc: dict, ext_name: str) -> list[str]:
    """Rules beyond the schema: indices in range, binds on real morph targets, the humanoid tree."""
    errs = []
    nodes = doc.get("nodes", [])
    ext = doc["extensions"][ext_name]
    parent = {c: i for i, n in enumerate(nodes) for c in n.get("children", [])}

    def ancestors(i):
        out = []
        while i in parent:
            i = parent[i]
            out.append(i)
        return out

    bones = {b: d["node"] for b, d in ext["humanoid"]["humanBones"].items()}
    if len(set(bones.values())) != len(bones):
        errs.append("a node is assigned to two humanoid bones")
    for b, n in bones.items():
        if n >= len(nodes):
            errs.append(f"{b}: node {n} out of range")
            continue
        p = PARENT.get(b)
        while p is not None and p not in bones:
            p = PARENT.get(p)
        if p is not None and bones[p] not in ancestors(n):
            errs.append(f"{b}: its humanoid parent {p} is not an ancestor node")
        s = nodes[n].get("scale")
        if s is not None and not (min(s) > 0 and max(s) - min(s) < 1e-6):
            errs.append(f"{b}: scale {s} is not a positive uniform scale")
    for group in ("preset", "custom"):
        for name, e in (ext.get("expressions", {}).get(group) or {}).items():
            if ext_name == "VRMC_vrm_animation":
                if e["node"] >= len(nodes):
                    errs.append(f"expression {name}: node out of range")
                continue
            for bind in e.get("morphTargetBinds", []):
                node = nodes[bind["node"]] if bind["node"] < len(nodes) else {}
                mesh = doc["meshes"][node["mesh"]] if "mesh" in node else None
                if mesh is None or any(bind["index"] >= len(p.get("targets", [])) for p in mesh["primitives"]):
                    errs.append(f"expression {name}: bind {bind} has no such morph target")
    return errs

# ----------------------------------------------------------------------------- VRM 0.x
V0_BONES = [b for b in HUMAN_BONES if "ThumbMetacarpal" not in b] + \
    [f"{s}ThumbIntermediate" for s in ("left", "right")]
V0_REQUIRED = ["hips", "spine", "chest", "neck", "head"] + [f"{s}{p}" for s in ("left", "right") for p in (
    "UpperArm", "LowerArm", "Hand", "UpperLeg", "LowerLeg", "Foot")]
# UniVRM writes (and three-vrm reads) presetName in lower case; the 0.0 README lists them capitalised
V0_PRESETS = ["unknown", "neutral", "a", "i", "u", "e", "o", "blink", "joy", "angry", "sorrow", "fun", "lookup",
              "lookdown", "lookleft", "lookright", "blink_l", "blink_r"]
_xyz = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_degree_map = {"type": "object", "properties": {"curve": {"type": "array", "items": {"type": "number"}},
                                                "xRange": {"type": "number"}, "yRange": {"type": "number"}}}
VRM0 = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "VRM 0.0",
    "type": "object",
    "required": ["meta", "humanoid"],
    "properties": {
        "exporterVersion": {"type": "string"}, "specVersion": {"const": "0.0"},
        "meta": {"type": "object", "properties": {
            **{k: {"type": "string"} for k in ("title", "version", "author", "contactInformation", "reference",
                                               "otherPermissionUrl", "otherLicenseUrl")},
            "texture": {"type": "integer"},
            "allowedUserName": {"enum": ["OnlyAuthor", "ExplicitlyLicensedPerson", "Everyone"]},
            "violentUssageName": {"enum": ["Disallow", "Allow"]}, "sexualUssageName": {"enum": ["Disallow", "Allow"]},
            "commercialUssageName": {"enum": ["Disallow", "Allow"]},
            "licenseName": {"enum": ["Redistribution_Prohibited", "CC0", "CC_BY", "CC_BY_NC", "CC_BY_SA",
                                     "CC_BY_NC_SA", "CC_BY_ND", "CC_BY_NC_ND", "Other"]}}},
        "humanoid": {"type": "object", "required": ["humanBones"], "properties": {"humanBones": {
            "type": "array", "items": {"type": "object", "required": ["bone", "node"], "properties": {
                "bone": {"enum": V0_BONES}, "node": _index, "useDefaultValues": {"type": "boolean"}}},
            "allOf": [{"contains": {"properties": {"bone": {"const": b}}}} for b in V0_REQUIRED]}}},
        "firstPerson": {"type": "object", "properties": {
            "firstPersonBone": {"type": "integer"}, "firstPersonBoneOffset": _xyz,
            "meshAnnotations": {"type": "array", "items": {"type": "object", "properties": {
                "mesh": {"type": "integer"},
                "firstPersonFlag": {"enum": ["Auto", "FirstPersonOnly", "ThirdPersonOnly", "Both"]}}}},
            "lookAtTypeName": {"enum": ["Bone", "BlendShape"]},
            **{k: _degree_map for k in ("lookAtHorizontalInner", "lookAtHorizontalOuter", "lookAtVerticalDown",
                                        "lookAtVerticalUp")}}},
        "blendShapeMaster": {"type": "object", "properties": {"blendShapeGroups": {"type": "array", "items": {
            "type": "object", "required": ["name"], "properties": {
                "name": {"type": "string"}, "presetName": {"enum": V0_PRESETS}, "isBinary": {"type": "boolean"},
                "binds": {"type": "array", "items": {"type": "object", "required": ["mesh", "index", "weight"],
                                                     "properties": {"mesh": _index, "index": _index,
                                                                    "weight": {"type": "number", "minimum": 0,
                                                                               "maximum": 100}}}},
                "materialValues": {"type": "array"}}}}}},
        "secondaryAnimation": {"type": "object"},
        "materialProperties": {"type": "array", "items": {"type": "object", "required": ["name", "shader"]}},
    },
}
