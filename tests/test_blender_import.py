"""Blender as the consumer: our BVH and GLB imported by Debian's headless Blender 3.4 (one process).

``scripts/setup-test.sh`` (run by ``make test``) installs ``blender``; tests/blender_import.py runs inside
Blender and reports what its importers built; here that is compared with our own forward kinematics.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from facecapges.arkit import ARKIT_NAMES
from facecapges.io.bvh import read_bvh, write_bvh
from facecapges.skeleton import joint_positions

HELPER = Path(__file__).with_name("blender_import.py")
FRAMES = [0, 5, 11, 17, 23]
# Blender's importers turn Y-up files into its Z-up world: (x, y, z) → (x, −z, y)
TO_BLENDER = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])


@pytest.fixture(scope="module")
def blender(tmp_path_factory):
    if shutil.which("blender") is None:
        pytest.skip("Debian's blender is not installed (scripts/setup-test.sh installs it)")
    from conftest import shared_file
    from facecapges.avatar.body import default_avatar
    from facecapges.avatar.gltf import avatar_to_gltf

    tmp = tmp_path_factory.mktemp("blender")
    src = read_bvh(shared_file("data/beat/2_scott_0_1_1.bvh"))
    motion = src.motion[100:100 + 24 * 10:10]  # 24 frames of real BEAT motion, written by our writer
    write_bvh(tmp / "motion.bvh", src.skeleton, motion, 15.0)
    ours = read_bvh(tmp / "motion.bvh")
    doc = avatar_to_gltf(default_avatar(ours.skeleton))
    (tmp / "avatar.glb").write_bytes(b"".join(doc.save_to_bytes()))
    (tmp / "job.json").write_text(json.dumps({"bvh": str(tmp / "motion.bvh"), "glb": str(tmp / "avatar.glb"),
                                              "frames": FRAMES}))
    r = subprocess.run(["blender", "-b", "--factory-startup", "--python-exit-code", "1", "--python", str(HELPER),
                        "--", str(tmp / "job.json"), str(tmp / "out.json")], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0 and (tmp / "out.json").exists(), (r.stdout[-3000:], r.stderr[-3000:])
    return ours, json.loads((tmp / "out.json").read_text())


@pytest.mark.slow
def test_bvh_joint_positions_match_our_fk(blender):
    ours, out = blender
    bvh = out["bvh"]
    assert bvh["fps"] == pytest.approx(15.0, abs=1e-3) and bvh["frame_range"] == [1, 24]
    fk = joint_positions(ours.skeleton, ours.motion) @ TO_BLENDER.T  # (T, J, 3), cm = Blender units here
    names = list(ours.skeleton.names)
    errors = []
    for f in FRAMES:
        heads = bvh["frames"][str(f)]
        assert set(heads) == set(names)  # one bone per joint (end sites are tails)
        got = np.array([heads[n] for n in names])
        errors.append(np.linalg.norm(got - fk[f], axis=1))
    err = np.concatenate(errors)
    print(f"Blender BVH vs our FK: max {err.max():.2e} cm, median {np.median(err):.2e} cm")
    assert err.max() < 1e-3  # cm
    spread = np.ptp(fk[FRAMES][:, names.index("RightHand")], axis=0).max()
    assert spread > 5.0  # the frames really differ: the hand moves by centimetres


@pytest.mark.slow
def test_glb_skeleton_shape_keys_and_jaw(blender):
    from facecapges.skeleton import rest_positions

    ours, out = blender
    glb = out["glb"]
    rest = rest_positions(ours.skeleton) * 0.01 @ TO_BLENDER.T  # metres
    names = list(ours.skeleton.names)
    got = np.array([glb["rest"][n] for n in names])
    err = np.linalg.norm(got - rest, axis=1)
    print(f"Blender GLB rest joints vs our FK: max {err.max() * 1000:.3f} mm")
    assert err.max() < 1e-5  # metres
    face_keys = [keys for keys in glb["shape_keys"].values() if "jawOpen" in keys]
    assert len(face_keys) == 1 and set(ARKIT_NAMES) <= set(face_keys[0]) and len(face_keys[0]) == 53  # + Basis
    before, after = np.array(glb["jaw"]["before"]), np.array(glb["jaw"]["after"])
    move = after - before
    dist = np.linalg.norm(move, axis=1)
    moving = dist > 1e-3
    assert dist.max() > 0.005 and moving.sum() > 20  # jawOpen at 1 moves vertices by millimetres
    assert move[moving, 2].mean() < 0  # … downwards (Blender's −Z): the jaw opens
    chin_side = before[moving, 2].mean() < before[:, 2].mean()
    assert chin_side  # the moving part is the lower face
