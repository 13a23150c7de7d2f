"""A VRM avatar driven by BEAT motion + ARKit face weights, rendered by @pixiv/three-vrm.

:class:`VrmDriver` holds a model (:func:`facecapges.avatar.vrm.read.load_model`), its
:class:`~facecapges.avatar.retarget.Retargeter` and its
:class:`~facecapges.avatar.vrm.expressions.ExpressionMap`, and turns BEAT local rotations + 52
ARKit weights into what ``web/vrm_scene.js`` sets: normalised bone quaternions
(T, B, 4) and expression weights (T, E), in the order of :attr:`VrmDriver.layout`.
:meth:`VrmDriver.page` is the VRM on the one render page (``web/render.html?avatar=vrm``):
:func:`facecapges.avatar.render.video.render_video` renders it as it renders our avatar.

three-vrm comes from ``node_modules/@pixiv`` beside three.js (npm, pinned in
package.json, installed by ``scripts/setup-avatar.sh``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from facecapges.errors import UserError

if TYPE_CHECKING:
    from facecapges.avatar.render.video import AvatarPage


def pixiv_dir() -> Path:
    """``node_modules/@pixiv`` (three-vrm 3.5.5 and three-vrm-animation 3.5.5)."""
    from facecapges.avatar.render.browser import SETUP_HINT, three_dir

    d = three_dir().parent / "@pixiv"
    if not (d / "three-vrm" / "lib" / "three-vrm.module.js").is_file():
        raise UserError(f"@pixiv/three-vrm (npm) not found in node_modules; {SETUP_HINT}")
    return d


def is_vrm_file(path: str | Path) -> bool:
    """True unless ``path`` is an avatar .glb written by ``facecapges avatar build`` (BEAT joints, no VRM)."""
    from facecapges.avatar.gltf_check import read_avatar_file
    from facecapges.avatar.vrm.glb import split_glb

    data = read_avatar_file(path)  # too large, not a glTF: refused here, before anything else reads it
    doc, _ = split_glb(data, str(path))  # and not self-contained or not well-formed
    ext = doc.get("extensions") or {}
    ours = "joint_names" in ((doc.get("extras") or {}).get("facecapges") or {})
    return "VRMC_vrm" in ext or "VRM" in ext or not ours


class VrmDriver:
    """BEAT motion + ARKit weights → a VRM's normalised bones and expressions."""

    def __init__(self, model, skeleton):
        from facecapges.avatar.retarget import Retargeter
        from facecapges.avatar.vrm.expressions import ExpressionMap

        self.model = model
        self.retarget = Retargeter(skeleton, model)
        self.faces = ExpressionMap(model.expressions)

    @classmethod
    def from_file(cls, path: str | Path, skeleton) -> VrmDriver:
        from facecapges.avatar.vrm.read import load_model

        return cls(load_model(path), skeleton)

    @classmethod
    def of(cls, avatar, skeleton) -> VrmDriver:
        """The driver of ``avatar``: a file, or its :class:`~facecapges.avatar.vrm.read.VrmModel` already read."""
        from facecapges.avatar.vrm.read import VrmModel

        return cls(avatar, skeleton) if isinstance(avatar, VrmModel) else cls.from_file(avatar, skeleton)

    @property
    def layout(self) -> dict:
        return {
            "bones": list(self.retarget.bones),
            "expressions": list(self.faces.names),
            "perfect_sync": self.faces.perfect_sync,
            "kind": self.model.kind,
        }

    def frames(self, local_mats: np.ndarray, arkit: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(T, J, 3, 3) BEAT local rotations, (T, 52) weights → (T, B, 4) quats, (T, E) weights."""
        return self.retarget(local_mats), self.faces(arkit)

    def routes(self) -> dict[str, bytes | Path]:
        from facecapges.avatar.render.browser import three_dir, web_dir

        return {
            "/web/": web_dir(),
            "/three/": three_dir(),
            "/pixiv/": pixiv_dir(),
            "/avatar.vrm": self.model.data,
            "/vrm/layout.json": json.dumps(self.layout).encode("utf-8"),
        }

    def page(self) -> AvatarPage:
        """This VRM on the render page (its frames: :meth:`frames`)."""
        from facecapges.avatar.render.video import AvatarPage

        return AvatarPage("vrm", self.routes())

    def describe(self) -> str:
        m = self.model
        face = (
            f"perfect sync ({len(self.faces.names)} ARKit expressions)"
            if self.faces.perfect_sync
            else f"{len(self.faces.names)} VRM presets from ARKit"
            if self.faces.names
            else "none (no expressions: the face stays still)"
        )
        return (
            f"{m.title!r} ({'VRM 0.x' if m.kind == 'vrm0' else 'VRM 1.0' if m.kind == 'vrm1' else 'humanoid GLB'}"
            f"): {len(self.retarget.bones)} humanoid bones driven, face: {face}"
        )


def bvh_local_matrices(skel, motion: np.ndarray) -> np.ndarray:
    """BVH motion (T, C) → local rotation matrices (T, J, 3, 3)."""
    from facecapges.skeleton import local_matrices, motion_to_euler

    _, euler = motion_to_euler(skel, motion)
    return local_matrices(skel, euler)


def face_weights(face: Path | None, fps: float, T: int):
    """(T, 52) ARKit weights of a face JSON resampled to ``fps`` (held at its last frame), zeros without one."""
    import numpy as np

    from facecapges.arkit import ARKIT_NAMES

    weights = np.zeros((T, len(ARKIT_NAMES)), np.float32)
    if face is not None:
        from facecapges.io.face_json import read_face_json
        from facecapges.timing import resample

        track = read_face_json(face)
        w = resample(track.weights, track.fps, fps)
        n = min(T, len(w))
        weights[:n] = w[:n]
        if 0 < n < T:
            weights[n:] = w[n - 1]
    return weights
