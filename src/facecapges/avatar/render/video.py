"""Avatar videos and blendshape contact sheets, rendered by three.js in headless Chromium.

One page (``web/render.html``) and one path here for both kinds of avatar: an
:class:`AvatarPage` says which (``"glb"``: our avatar, ``web/avatar_scene.js``, made by
:func:`our_avatar`; ``"vrm"``: a VRM / humanoid GLB through three-vrm, ``web/vrm_scene.js``,
made by :meth:`facecapges.avatar.vrm.view.VrmDriver.page`) and what the page fetches; the
kind chooses only the page's scene module and the per-frame data the caller passes (our
avatar: BEAT joint quaternions + 52 ARKit weights; a VRM: its normalised bone quaternions
+ expression weights, :meth:`~facecapges.avatar.vrm.view.VrmDriver.frames`).

* :func:`bvh_quaternions` turns BVH motion into the page's input: the local rotation
  of every joint as a (w, x, y, z) quaternion (T, J, 4), joint order = the avatar's
  (the BEAT BVH order). The BVH must have the avatar's skeleton (same joint names and
  tree), else a :class:`~facecapges.errors.UserError`. Root translation is not
  applied: the camera frames the upper body, which BEAT's upper-body motion keeps in
  place (its Hips channels are 0).
* :func:`render_video` renders frame ``t`` with pose ``t`` and face weights ``t``
  (front view, 640×480 by default, any ``width`` × ``height``) as JPEG in the page,
  with a **face close-up inset** in the top-right corner (a second camera on the head,
  a third of the frame's height: the whole video is watchable and the mouth and eyes
  are big enough to see them follow), and writes the MP4 with the audio through
  :class:`facecapges.io.mp4.Mp4Writer`; the video ends with the shorter of frames and audio.
* :func:`contact_sheet` renders the face close-up once per blendshape at weight 1
  (all others 0), labelled, in a grid PNG (the neutral face first).
"""

from __future__ import annotations

import base64
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facecapges import rotations as rot
from facecapges.avatar.render.browser import Browser, PageError, avatar_routes
from facecapges.errors import UserError
from facecapges.io.static_files import Routes
from facecapges.skeleton import Skeleton, local_matrices, motion_to_euler

PAGE = "/web/render.html"


@dataclass(frozen=True)
class AvatarPage:
    """The avatar the render page shows: its ``kind`` ("glb" or "vrm", the page's scene module) and
    ``routes``, what the page fetches (:class:`~facecapges.avatar.render.browser.Browser` routes)."""

    kind: str
    routes: Routes

    def url(self, width: int, height: int, inset: bool = False) -> str:
        return f"{PAGE}?avatar={self.kind}&w={width}&h={height}&inset={int(inset)}"


def our_avatar(glb: bytes) -> AvatarPage:
    """Our avatar .glb (``facecapges avatar build``) on the render page."""
    return AvatarPage("glb", avatar_routes(glb))


def bvh_quaternions(avatar_joint_names: list[str], skel: Skeleton, motion: np.ndarray, name: str = "BVH") -> np.ndarray:
    """Local joint rotations (T, J, 4) (w, x, y, z) of ``motion`` on ``skel``, in the avatar's joint order."""
    if list(skel.names) != list(avatar_joint_names):
        missing = [n for n in avatar_joint_names if n not in skel.names]
        what = f"missing joints {missing[:5]}" if missing else "joints in another order or tree"
        raise UserError(f"{name}: its skeleton is not the avatar's BEAT skeleton ({what})")
    _, euler = motion_to_euler(skel, motion)
    q = rot.matrix_to_quaternion(local_matrices(skel, euler))
    return np.ascontiguousarray(q, dtype=np.float32)


def _decode(url: str) -> bytes:
    return base64.b64decode(url.split(",", 1)[1])


def _first_line(error: object) -> str:
    """A page's error without its JavaScript stack: the first line of the first message, at most 300 characters."""
    if isinstance(error, list | tuple) and error:
        error = error[0]
    lines = str(error).strip().splitlines()
    return (lines[0] if lines else "")[:300]


def _open_page(avatar: AvatarPage, width: int, height: int, inset: bool = False) -> tuple[Browser, dict]:
    b = Browser(avatar.routes, avatar.url(width, height, inset), width, height)
    b.__enter__()
    try:
        info = b.wait_for("window.facecapges.ready")
        errors = b.evaluate("window.facecapges.errors")
        if errors:
            raise UserError(f"the browser could not show the avatar: {_first_line(errors)}")
    except PageError as exc:
        b.close()
        # the file passed avatar.gltf_check but three.js / three-vrm could not use it: still the user's file
        raise UserError(
            f"the browser could not load the avatar ({_first_line(exc)}); re-export it as VRM / glTF 2.0"
        ) from None
    except BaseException:
        b.close()
        raise
    return b, info


def render_video(
    avatar: AvatarPage,
    quats: np.ndarray,
    weights: np.ndarray,
    fps: float,
    out: str | Path,
    audio: str | Path | None = None,
    width: int = 640,
    height: int = 480,
    batch: int = 30,
    progress: bool = True,
    crf: int = 20,
    inset: bool = True,
) -> dict:
    """Render ``avatar`` with (T, J, 4) poses + (T, K) face weights (its kind's frame data, module
    docstring) to an MP4 at ``fps``; returns timing figures.

    ``inset``: draw the face close-up in the top-right corner (module docstring)."""
    import time

    from facecapges.io.mp4 import Mp4Writer
    from facecapges.progress import Progress

    T = quats.shape[0]
    if weights.shape[0] != T:
        raise ValueError(f"{T} poses but {weights.shape[0]} face frames")
    t0 = time.perf_counter()
    b, info = _open_page(avatar, width, height, inset)
    writer = Mp4Writer(out, fps, audio=audio, crf=crf, jpeg=True)
    try:
        _load_motion(b, info, quats, weights)
        t_ready = time.perf_counter()
        with Progress(disable=not progress, transient=True) as bar:
            task = bar.add_task("rendering avatar video", total=T)
            for start in range(0, T, batch):
                urls = b.evaluate(f"window.facecapges.renderFrames({start}, {batch}, 'image/jpeg', 0.92)")
                for u in urls:
                    writer.write(_decode(u))
                bar.advance(task, len(urls))
        writer.close()
    except BaseException:
        writer.abort()
        raise
    finally:
        b.close()
    t1 = time.perf_counter()
    return {
        "frames": T,
        "fps": fps,
        "size": [width, height],
        "startup_s": t_ready - t0,
        "render_s": t1 - t_ready,
        "total_s": t1 - t0,
        "frames_per_s": T / max(t1 - t_ready, 1e-9),
    }


def _load_motion(b: Browser, info: dict, quats: np.ndarray, weights: np.ndarray) -> None:
    """Serve the (T, J, 4) poses and (T, K) weights to the open page and load them (its sizes checked)."""
    T = quats.shape[0]
    if quats.shape[1] != info["joints"] or weights.shape[1] != info["blendshapes"]:
        raise ValueError(
            f"motion has {quats.shape[1]} joints / {weights.shape[1]} weights, avatar "
            f"{info['joints']} / {info['blendshapes']}"
        )
    b.routes["/motion/quats.bin"] = np.ascontiguousarray(quats, np.float32).tobytes()
    b.routes["/motion/weights.bin"] = np.ascontiguousarray(weights, np.float32).tobytes()
    b.evaluate(f"window.facecapges.loadMotion({T})")


def render_stills(
    avatar: AvatarPage,
    poses: list[np.ndarray | None],
    weights: list[np.ndarray | None],
    view: str = "body",
    width: int = 640,
    height: int = 480,
    inset: bool = False,
) -> list[np.ndarray]:
    """BGR images (H, W, 3) of ``avatar`` for each (pose (J, 4) or None, weights (K,) or None)."""
    import cv2

    b, _ = _open_page(avatar, width, height, inset)
    images: list[np.ndarray] = []
    try:
        b.evaluate(f"window.facecapges.setView({view!r})")
        for q, w in zip(poses, weights):
            qa = "null" if q is None else "[" + ",".join(f"{x:.7g}" for x in np.asarray(q).ravel()) + "]"
            wa = "null" if w is None else "[" + ",".join(f"{x:.7g}" for x in np.asarray(w).ravel()) + "]"
            png = _decode(b.evaluate(f"window.facecapges.renderStill({qa}, {wa})"))
            img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
            if img is None:
                raise RuntimeError("the avatar page returned an undecodable PNG")
            images.append(img)
    finally:
        b.close()
    return images


def contact_sheet(glb: bytes, names: list[str], out: str | Path, cols: int = 8, cell: int = 240) -> Path:
    """PNG grid: the neutral face, then each blendshape of ``names`` at weight 1."""
    import cv2

    K = len(names)
    weights = [None] + [np.eye(K)[k] for k in range(K)]
    images = render_stills(our_avatar(glb), [None] * (K + 1), weights, view="face", width=cell, height=cell)
    labels = ["neutral"] + list(names)
    rows = -(-len(images) // cols)
    sheet = np.full((rows * (cell + 22), cols * cell, 3), 255, np.uint8)
    for k, (img, label) in enumerate(zip(images, labels)):
        r, c = divmod(k, cols)
        y, x = r * (cell + 22), c * cell
        sheet[y : y + cell, x : x + cell] = img
        cv2.putText(sheet, label, (x + 4, y + cell + 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (20, 20, 20), 1, cv2.LINE_AA)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), sheet):
        raise UserError(f"{out}: cannot write the contact sheet")
    return out
