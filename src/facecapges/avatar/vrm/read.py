"""Reading a VRM: any VRM 0.x / 1.0 file or humanoid GLB as a :class:`VrmModel`.

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
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facecapges.arkit import arkit_index
from facecapges.avatar.vrm.expressions import PERFECT_SYNC_NAMES, PRESET_BINDS, VRM1_NAMES
from facecapges.avatar.vrm.glb import join_glb, node_world_matrices, split_glb
from facecapges.avatar.vrm.humanoid import BONE_PARENT, REQUIRED_BONES, VRM0_RENAME, humanoid_from_names
from facecapges.avatar.vrm.meta import LICENSE_URL, SPEC_VERSION
from facecapges.errors import UserError

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


# VRM 0.x preset names → 1.0
def _vrm0_presets() -> dict[str, str]:
    return {**{k.lower(): v for k, v in VRM1_NAMES.items()}, "neutral": "neutral"}


VRM0_PRESETS = _vrm0_presets()  # VRM 0.x ``presetName`` (lower case in the file) → 1.0 name


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
    bones = {b: n for b, n in bones.items() if b in BONE_PARENT}  # nodes in range: split_glb checked them
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
