"""Write the avatar as a glTF 2.0 binary (``.glb``) with pygltflib.

Layout of the file
------------------
* **Nodes 0 … J−1** are the skeleton's joints in BVH order, named exactly as in the
  BEAT BVH (``Hips``, ``Spine`` … ``LeftToeBaseEnd``), each with its rest
  ``translation`` = BVH ``OFFSET`` in metres and no rotation (a BVH rest pose has
  none), so a joint's local glTF rotation **is** its BVH local rotation — a player sets
  ``node.rotation`` from the BVH Euler angles and nothing else.
* Node J: the body mesh (``skin`` 0). The skin lists all J joints (``skeleton`` =
  Hips) with inverse bind matrices = inverse rest world transforms (pure
  translations).
* Node J+1 ("Face"): the face mesh, a **child of the Head joint** with the face's
  offset as translation. Its mesh has 52 morph targets (POSITION and NORMAL offsets)
  named in ``mesh.extras.targetNames`` (ARKit names), default weights 0.
* Units: metres (BVH centimetres × 0.01); right-handed, Y up, facing +Z.
* Every primitive of one mesh shares the mesh's vertex accessors; only the indices
  and the material differ (skin, shirt, hair, eye and mouth openings).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pygltflib as g

from facecapges.avatar.body import COLORS, Avatar, FaceMesh

CM_TO_M = 0.01


class _Buffer:
    def __init__(self) -> None:
        self.data = bytearray()
        self.views: list[g.BufferView] = []
        self.accessors: list[g.Accessor] = []

    def add(self, arr: np.ndarray, acc_type: str, target: int | None, minmax: bool = False) -> int:
        arr = np.ascontiguousarray(arr)
        while len(self.data) % 4:
            self.data.append(0)
        self.views.append(g.BufferView(buffer=0, byteOffset=len(self.data), byteLength=arr.nbytes, target=target))
        self.data.extend(arr.tobytes())
        ctype = {
            np.dtype(np.float32): g.FLOAT,
            np.dtype(np.uint16): g.UNSIGNED_SHORT,
            np.dtype(np.uint32): g.UNSIGNED_INT,
            np.dtype(np.uint8): g.UNSIGNED_BYTE,
        }[arr.dtype]
        count = arr.shape[0] if arr.ndim > 1 or acc_type != g.SCALAR else arr.size
        if acc_type == g.MAT4:
            count = arr.shape[0]
        acc = g.Accessor(bufferView=len(self.views) - 1, componentType=ctype, count=int(count), type=acc_type)
        if minmax:
            flat = arr.reshape(int(count), -1)
            acc.min = [float(x) for x in flat.min(0)]
            acc.max = [float(x) for x in flat.max(0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def avatar_to_gltf(avatar: Avatar) -> g.GLTF2:
    """Build the glTF document of ``avatar`` (see the module docstring for its layout)."""
    skel = avatar.skeleton
    buf = _Buffer()
    kids = skel.children()
    nodes = [
        g.Node(name=n, translation=[float(x) * CM_TO_M for x in skel.offsets[j]], children=list(kids[j]))
        for j, n in enumerate(skel.names)
    ]

    materials, mat_index = _materials()
    meshes, skin = _body_mesh(buf, avatar, mat_index)
    meshes.append(_face_mesh(buf, avatar.face, mat_index))

    body_node = len(nodes)
    nodes.append(g.Node(name="Body", mesh=0, skin=0))
    face = avatar.face
    face_node = len(nodes)
    nodes.append(g.Node(name="Face", mesh=1, translation=[float(x) * CM_TO_M for x in face.offset]))
    head = skel.index("Head")
    nodes[head].children = list(nodes[head].children) + [face_node]
    root = int(np.flatnonzero(skel.parents < 0)[0])

    doc = g.GLTF2(
        asset=g.Asset(version="2.0", generator="facecapges avatar"),
        scene=0,
        scenes=[g.Scene(name="Avatar", nodes=[root, body_node])],
        nodes=nodes,
        meshes=meshes,
        skins=[skin],
        materials=materials,
        accessors=buf.accessors,
        bufferViews=buf.views,
        buffers=[g.Buffer(byteLength=len(buf.data))],
        extras={
            "facecapges": {
                "joint_names": list(skel.names),
                "blendshape_names": list(face.names),
                "units": "metres",
                **avatar.info,
            }
        },
    )
    doc.set_binary_blob(bytes(buf.data))
    return doc


def _materials() -> tuple[list[g.Material], dict[str, int]]:
    """One material per :data:`COLORS` entry, and each one's index by name."""
    materials: list[g.Material] = []
    mat_index: dict[str, int] = {}
    for name, rgba in COLORS.items():
        mat_index[name] = len(materials)
        materials.append(
            g.Material(
                name=name,
                pbrMetallicRoughness=g.PbrMetallicRoughness(
                    baseColorFactor=list(rgba), metallicFactor=0.0, roughnessFactor=0.8 if name != "eye" else 0.3
                ),
                doubleSided=name in ("eye", "mouth"),
            )
        )
    return materials, mat_index


def _index_accessor(buf: _Buffer, faces: np.ndarray, n_vertices: int) -> int:
    """The accessor of a triangle list: 16-bit indices when they fit."""
    dt = np.uint16 if n_vertices < 65535 else np.uint32
    return buf.add(faces.astype(dt).reshape(-1), g.SCALAR, g.ELEMENT_ARRAY_BUFFER)


def _body_mesh(buf: _Buffer, avatar: Avatar, mat_index: dict[str, int]) -> tuple[list[g.Mesh], g.Skin]:
    """The skinned body mesh (in a list, the document's meshes) and its skin of the BEAT joints."""
    skel = avatar.skeleton
    J = skel.n_joints
    body = avatar.body
    pos = buf.add((body.vertices * CM_TO_M).astype(np.float32), g.VEC3, g.ARRAY_BUFFER, minmax=True)
    nrm = buf.add(body.normals.astype(np.float32), g.VEC3, g.ARRAY_BUFFER)
    jnt = buf.add(body.joints.astype(np.uint8 if J < 256 else np.uint16), g.VEC4, g.ARRAY_BUFFER)
    wgt = buf.add(body.weights.astype(np.float32), g.VEC4, g.ARRAY_BUFFER)
    prims = [
        g.Primitive(
            attributes=g.Attributes(POSITION=pos, NORMAL=nrm, JOINTS_0=jnt, WEIGHTS_0=wgt),
            indices=_index_accessor(buf, f, len(body.vertices)),
            material=mat_index[m],
            mode=g.TRIANGLES,
        )
        for m, f in body.faces.items()
    ]
    meshes = [g.Mesh(name="Body", primitives=prims)]
    ibm = np.zeros((J, 4, 4), np.float32)
    for j in range(J):
        m = np.eye(4)
        m[:3, 3] = -avatar.rest[j] * CM_TO_M
        ibm[j] = m.T  # glTF matrices are column-major
    ibm_acc = buf.add(ibm.reshape(J, 16), g.MAT4, None)
    skin = g.Skin(name="BEAT", joints=list(range(J)), inverseBindMatrices=ibm_acc, skeleton=0)
    return meshes, skin


def _face_mesh(buf: _Buffer, face: FaceMesh, mat_index: dict[str, int]) -> g.Mesh:
    """The face mesh with its morph targets (its node is parented to the Head joint)."""
    fpos = buf.add((face.vertices * CM_TO_M).astype(np.float32), g.VEC3, g.ARRAY_BUFFER, minmax=True)
    fnrm = buf.add(face.normals.astype(np.float32), g.VEC3, g.ARRAY_BUFFER)
    targets = []
    for t in range(len(face.names)):
        dp = buf.add((face.deltas[t] * CM_TO_M).astype(np.float32), g.VEC3, g.ARRAY_BUFFER, minmax=True)
        dn = buf.add(face.normal_deltas[t].astype(np.float32), g.VEC3, g.ARRAY_BUFFER)
        targets.append({"POSITION": dp, "NORMAL": dn})
    fprims = [
        g.Primitive(
            attributes=g.Attributes(POSITION=fpos, NORMAL=fnrm),
            targets=targets,
            indices=_index_accessor(buf, f, len(face.vertices)),
            material=mat_index[m],
            mode=g.TRIANGLES,
        )
        for m, f in face.faces.items()
    ]
    return g.Mesh(
        name="Face", primitives=fprims, weights=[0.0] * len(face.names), extras={"targetNames": list(face.names)}
    )


def write_glb(avatar: Avatar, path: str | Path) -> Path:
    """Write ``avatar`` to ``path`` as a binary glTF."""
    doc = avatar_to_gltf(avatar)
    p = Path(path)
    doc.save_binary(str(p))
    return p


def avatar_glb(skeleton) -> bytes:
    """Our default avatar for ``skeleton`` (:func:`facecapges.avatar.body.default_avatar`) as GLB bytes."""
    from facecapges.avatar.body import default_avatar

    return b"".join(avatar_to_gltf(default_avatar(skeleton)).save_to_bytes())


def full_quaternions(skeleton, quats47: np.ndarray) -> np.ndarray:
    """(T, 47, 4) upper-body quaternions → (T, J, 4) for every joint of ``skeleton`` (others at rest):
    what our avatar's page takes."""
    from facecapges.skeleton import upper_body_indices

    q = np.asarray(quats47, np.float32)
    out = np.zeros((q.shape[0], skeleton.n_joints, 4), np.float32)
    out[..., 0] = 1.0
    out[:, upper_body_indices(skeleton)] = q
    return out
