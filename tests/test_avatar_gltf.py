"""The avatar .glb: valid glTF 2.0 structure, BEAT skin, ARKit morph targets, loads in three.js."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pygltflib
import pytest

from facecapges.arkit import ARKIT_NAMES
from facecapges.avatar.body import default_avatar
from facecapges.avatar.gltf import avatar_to_gltf
from facecapges.io.bvh import read_bvh
from facecapges.skeleton import UPPER_BODY, rest_positions
from runtime_helpers import cli

_NP = {pygltflib.FLOAT: np.float32, pygltflib.UNSIGNED_SHORT: np.uint16, pygltflib.UNSIGNED_INT: np.uint32,
       pygltflib.UNSIGNED_BYTE: np.uint8}
_NC = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}


@pytest.fixture(scope="module")
def built(request):
    from conftest import shared_file

    bvh = read_bvh(shared_file("data/beat/2_scott_0_1_1.bvh"))
    av = default_avatar(bvh.skeleton)
    doc = avatar_to_gltf(av)
    glb = b"".join(doc.save_to_bytes())
    return bvh, av, pygltflib.GLTF2.load_from_bytes(glb), glb


def read_accessor(doc: pygltflib.GLTF2, i: int) -> np.ndarray:
    acc = doc.accessors[i]
    view = doc.bufferViews[acc.bufferView]
    blob = doc.binary_blob()
    n = _NC[acc.type]
    data = np.frombuffer(blob, _NP[acc.componentType], count=acc.count * n,
                         offset=view.byteOffset + (acc.byteOffset or 0))
    assert view.byteOffset + view.byteLength <= len(blob)
    return data.reshape(acc.count, n) if n > 1 else data


def test_structure_is_valid_gltf2(built):
    _, _av, doc, glb = built
    assert glb[:4] == b"glTF" and int.from_bytes(glb[4:8], "little") == 2
    assert doc.asset.version == "2.0"
    assert doc.buffers[0].byteLength == len(doc.binary_blob())
    for acc in doc.accessors:
        view = doc.bufferViews[acc.bufferView]
        size = acc.count * _NC[acc.type] * np.dtype(_NP[acc.componentType]).itemsize
        assert size <= view.byteLength and view.byteOffset % 4 == 0
    for mesh in doc.meshes:
        for prim in mesh.primitives:
            n = doc.accessors[prim.attributes.POSITION].count
            assert doc.accessors[prim.attributes.POSITION].min is not None
            idx = read_accessor(doc, prim.indices)
            assert idx.size % 3 == 0 and idx.max() < n
            for name in ("NORMAL", "JOINTS_0", "WEIGHTS_0"):
                a = getattr(prim.attributes, name)
                if a is not None:
                    assert doc.accessors[a].count == n
            for t in prim.targets or []:
                assert doc.accessors[t["POSITION"]].count == n and doc.accessors[t["POSITION"]].max is not None


def test_skin_uses_the_beat_joints_with_correct_inverse_bind_matrices(built):
    bvh, _av, doc, _ = built
    skin = doc.skins[0]
    names = [doc.nodes[j].name for j in skin.joints]
    assert names == list(bvh.skeleton.names) and len(names) == 75
    ibm = read_accessor(doc, skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)  # column-major
    # world rest transforms from the node tree must be the inverses of the IBMs
    rest = rest_positions(bvh.skeleton) * 0.01
    parent = {c: i for i, n in enumerate(doc.nodes) for c in (n.children or [])}
    for k, j in enumerate(skin.joints):
        pos, node = np.zeros(3), j
        while node is not None:
            pos += np.asarray(doc.nodes[node].translation or [0, 0, 0])
            assert doc.nodes[node].rotation in (None, [0, 0, 0, 1])
            node = parent.get(node)
        assert np.allclose(pos, rest[k], atol=1e-6)
        assert np.allclose(ibm[k] @ np.r_[pos, 1.0], [0, 0, 0, 1], atol=1e-6)


def test_skin_weights_cover_every_driven_joint(built):
    bvh, _av, doc, _ = built
    prim = doc.meshes[0].primitives[0]
    J = read_accessor(doc, prim.attributes.JOINTS_0)
    W = read_accessor(doc, prim.attributes.WEIGHTS_0)
    assert np.allclose(W.sum(1), 1.0, atol=1e-5) and W.min() >= 0 and J.max() < 75
    used = {bvh.skeleton.names[j] for j in np.unique(J[W > 0.2])}
    # every one of the 47 driven upper-body joints moves some skin (metacarpals: the palm)
    assert [n for n in UPPER_BODY if n not in used] == []
    # five fingers of three segments on each hand
    for side in ("Left", "Right"):
        for f in ("Thumb", "Index", "Middle", "Ring", "Pinky"):
            assert all(f"{side}Hand{f}{k}" in used for k in (1, 2, 3))


def test_face_morph_targets_are_the_52_arkit_shapes_on_the_head(built):
    _bvh, _av, doc, _ = built
    face_mesh = doc.meshes[1]
    assert face_mesh.extras["targetNames"] == list(ARKIT_NAMES)
    assert len(face_mesh.weights) == 52 and not any(face_mesh.weights)
    for prim in face_mesh.primitives:
        assert len(prim.targets) == 52
    head = next(n for n in doc.nodes if n.name == "Head")
    face_node = next(i for i, n in enumerate(doc.nodes) if n.name == "Face")
    assert face_node in head.children and doc.nodes[face_node].mesh == 1
    # jawOpen moves the chin down (metres)
    jaw = read_accessor(doc, face_mesh.primitives[0].targets[ARKIT_NAMES.index("jawOpen")]["POSITION"])
    assert jaw[152, 1] < -0.01
    assert {m.name for m in doc.materials} >= {"skin", "shirt", "hair", "eye", "mouth"}


def test_linear_blend_skinning_of_the_rest_pose_is_identity_and_bends_the_elbow(built):
    bvh, av, _doc, _ = built
    from facecapges import rotations as rot

    skel = bvh.skeleton
    J = skel.n_joints
    body = av.body

    def skin(local: np.ndarray) -> np.ndarray:
        G = np.zeros((J, 4, 4))
        P = rest_positions(skel)
        for j in range(J):
            L = np.eye(4)
            L[:3, :3] = local[j]
            L[:3, 3] = skel.offsets[j]
            G[j] = L if skel.parents[j] < 0 else G[skel.parents[j]] @ L
        inv = np.stack([np.linalg.inv(np.block([[np.eye(3), P[j][:, None]], [np.zeros((1, 3)), np.ones((1, 1))]]))
                        for j in range(J)])
        M = np.einsum("jab,jbc->jac", G, inv)
        vh = np.c_[body.vertices, np.ones(len(body.vertices))]
        return np.einsum("nk,nkab,nb->na", body.weights, M[body.joints], vh)[:, :3]

    eye = np.broadcast_to(np.eye(3), (J, 3, 3)).copy()
    assert np.allclose(skin(eye), body.vertices, atol=1e-9)
    bent = eye.copy()
    bent[skel.index("RightForeArm")] = rot.euler_to_matrix(np.array([0.0, 0.0, 90.0]), "XYZ", degrees=True)
    moved = np.linalg.norm(skin(bent) - body.vertices, axis=1)
    hand_vertices = body.joints[:, 0] == skel.index("RightHandMiddle2")
    torso_vertices = body.joints[:, 0] == skel.index("Spine2")
    assert moved[hand_vertices].min() > 10.0 and moved[torso_vertices].max() < 1e-9


@pytest.mark.skipif(shutil.which("chromium") is None, reason="chromium not installed (scripts/setup-avatar.sh)")
@pytest.mark.slow
def test_glb_loads_in_threejs_gltfloader_without_errors(built):
    from facecapges.avatar.render.browser import Browser, avatar_routes

    bvh, _, _, glb = built
    with Browser(avatar_routes(glb), "/web/render.html?w=160&h=120") as b:
        info = b.wait_for("window.facecapges.ready")
        assert b.evaluate("window.facecapges.errors") == []
        assert info["joints"] == 75 and info["blendshapes"] == 52 and info["morphMeshes"] >= 4
        assert info["jointNames"] == list(bvh.skeleton.names) and info["blendshapeNames"] == list(ARKIT_NAMES)
        # three.js reads the morph dictionary and the skeleton from the file itself
        dict_names = b.evaluate("Object.keys(window.facecapges.scene.morphMeshes[0].morphTargetDictionary)")
        bones = b.evaluate("(() => { let n = []; window.facecapges.scene.root.traverse(o => { "
                           "if (o.isSkinnedMesh) n = o.skeleton.bones.map(b => b.name); }); return n; })()")
        assert sorted(dict_names) == sorted(ARKIT_NAMES) and bones == list(bvh.skeleton.names)


def test_avatar_build_cli(tmp_path):
    from conftest import shared_file

    bvh = shared_file("data/beat/2_scott_0_1_1.bvh")
    out = tmp_path / "a.glb"
    r = cli("avatar", "build", "--skeleton", str(bvh), "--out", str(out))
    assert r.returncode == 0, r.stderr
    doc = pygltflib.GLTF2.load(str(out))
    assert doc.meshes[1].extras["targetNames"] == list(ARKIT_NAMES)
    # a BVH without the BEAT joints is refused
    other = tmp_path / "other.bvh"
    other.write_text("HIERARCHY\nROOT Root\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition "
                     "Zrotation Xrotation Yrotation\n End Site\n {\n  OFFSET 0 1 0\n }\n}\nMOTION\nFrames: 1\n"
                     "Frame Time: 0.0666667\n0 0 0 0 0 0\n")
    r = cli("avatar", "build", "--skeleton", str(other), "--out", str(tmp_path / "b.glb"))
    assert r.returncode == 2 and "not a BEAT skeleton" in r.stderr and "Traceback" not in r.stderr


def test_khronos_gltf_validator_reports_no_issues(built, tmp_path):
    from conftest import REPO

    script = REPO / "scripts" / "validate-gltf.mjs"
    if shutil.which("node") is None or not (REPO / "node_modules" / "gltf-validator").is_dir():
        pytest.skip("node or npm gltf-validator missing (scripts/setup-avatar.sh)")
    path = tmp_path / "a.glb"
    path.write_bytes(built[3])
    r = subprocess.run(["node", str(script), str(path)], capture_output=True, text=True, cwd=REPO)
    import json

    report = json.loads(r.stdout)
    assert r.returncode == 0 and report["numErrors"] == 0 and report["numWarnings"] == 0, report
