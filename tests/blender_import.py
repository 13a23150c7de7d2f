"""Runs INSIDE headless Blender (``blender -b --factory-startup --python tests/blender_import.py -- IN.json OUT.json``).

Imports a BVH and a GLB with Blender's own importers and writes what Blender made of them as JSON:

* ``bvh``: per requested frame, the world-space head of every bone of the imported armature (the joint
  positions Blender computed from the file), plus the scene's frame rate and frame range;
* ``glb``: the world-space head of every bone of the imported armature in its rest pose, the shape-key
  names of every mesh, and, for ``jawOpen``, how far each vertex moves (world space, evaluated through
  the depsgraph with the key at 1.0).

Used by tests/test_blender_import.py (one Blender process for every check). Only ``bpy`` and the
standard library here: Blender's Python is Debian's python3, not the project's venv.
"""

import builtins
import json
import sys

# --- Debian Blender 3.4 packaging fixes (in-process, this script only) -----------------------------
# 1. Blender 3.4's BVH importer opens the file with mode 'rU'; the 'U' flag is gone in Python 3.11
#    (Debian's Blender runs on the system python3.11), so the import fails with ValueError.
_open = builtins.open


def _open_without_u(file, mode="r", *args, **kwargs):
    if isinstance(mode, str) and "U" in mode:
        mode = mode.replace("U", "") or "r"
    return _open(file, mode, *args, **kwargs)


builtins.open = _open_without_u
# 2. Blender 3.4's glTF importer uses ``np.bool``, removed in numpy 1.24 (Debian's python3-numpy).
import numpy  # noqa: E402

if not hasattr(numpy, "bool"):
    numpy.bool = bool
# ----------------------------------------------------------------------------------------------------

import bpy  # noqa: E402


def clear():
    bpy.ops.wm.read_factory_settings(use_empty=True)


def armature():
    arms = [o for o in bpy.context.scene.objects if o.type == "ARMATURE"]
    assert len(arms) == 1, [o.name for o in bpy.context.scene.objects]
    return arms[0]


def bone_heads(arm, posed=True):
    bones = arm.pose.bones if posed else arm.data.bones
    return {b.name: list(arm.matrix_world @ (b.head if posed else b.head_local)) for b in bones}


def import_bvh(path, frames):
    clear()
    bpy.ops.import_anim.bvh(filepath=path, global_scale=1.0, frame_start=1, use_fps_scale=False,
                            update_scene_fps=True, update_scene_duration=True, rotate_mode="NATIVE",
                            axis_forward="-Z", axis_up="Y")
    arm = armature()
    scene = bpy.context.scene
    action = arm.animation_data.action
    out = {"fps": scene.render.fps / scene.render.fps_base, "frame_range": list(action.frame_range), "frames": {}}
    for f in frames:
        scene.frame_set(f + 1)  # BVH frame 0 is Blender frame 1 (frame_start)
        bpy.context.view_layer.update()
        out["frames"][str(f)] = bone_heads(arm, posed=True)
    return out


def import_glb(path):
    clear()
    bpy.ops.import_scene.gltf(filepath=path)
    arm = armature()
    out = {"rest": bone_heads(arm, posed=False), "shape_keys": {}, "jaw": None}
    deps = bpy.context.evaluated_depsgraph_get()
    for obj in bpy.context.scene.objects:
        if obj.type != "MESH" or obj.data.shape_keys is None:
            continue
        keys = obj.data.shape_keys.key_blocks
        out["shape_keys"][obj.name] = [k.name for k in keys]
        if "jawOpen" in keys:
            def world_vertices(obj=obj):  # called in this iteration only
                bpy.context.view_layer.update()
                ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
                mesh = ev.to_mesh()
                pts = [list(ev.matrix_world @ v.co) for v in mesh.vertices]
                ev.to_mesh_clear()
                return pts

            keys["jawOpen"].value = 0.0
            before = world_vertices()
            keys["jawOpen"].value = 1.0
            after = world_vertices()
            keys["jawOpen"].value = 0.0
            out["jaw"] = {"mesh": obj.name, "before": before, "after": after}
    del deps
    return out


def main():
    argv = sys.argv[sys.argv.index("--") + 1:]
    with _open(argv[0]) as f:
        job = json.load(f)
    result = {"blender": bpy.app.version_string}
    result["bvh"] = import_bvh(job["bvh"], job["frames"])
    result["glb"] = import_glb(job["glb"])
    with _open(argv[1], "w") as f:
        json.dump(result, f)


main()
