"""The VRM humanoid: bone names and hierarchy (VRM 1.0, with VRM 0.x's names beside them), and BEAT's bones.

* :data:`HUMAN_BONES` — the VRM 1.0 humanoid table (bone, parent, required);
  :data:`VRM0_RENAME` — the VRM 0.x names of the thumb bones that differ.
* :data:`BEAT_BONES` — BEAT joint of each VRM bone (BEAT and Mixamo share these names);
  :func:`humanoid_from_names` finds the bones of a plain GLB by those names.
* :func:`sole_lift` — how far a BEAT skeleton is lifted to stand on y = 0, as the VRM T-pose wants.
"""

from __future__ import annotations

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


def sole_lift(skel) -> float:
    """How far (metres) the BEAT skeleton ``skel`` must be lifted for its soles (ForeFoot) to stand on y = 0."""
    from facecapges.avatar.gltf import CM_TO_M
    from facecapges.skeleton import rest_positions

    P = rest_positions(skel) * CM_TO_M
    sole = skel.names.index("LeftForeFoot") if "LeftForeFoot" in skel.names else skel.names.index("LeftFoot")
    return float(-P[sole, 1])


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
