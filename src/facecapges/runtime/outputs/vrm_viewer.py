"""``live --web --avatar FILE.vrm``: the browser viewer showing a VRM (0.x / 1.0 / humanoid GLB).

:class:`VrmViewerServer` is the viewer server (:mod:`.viewer`: same security rules,
same ``/ws`` feed socket) serving the one viewer page ``web/viewer.html`` at ``/``, the avatar at
``/avatar.vrm``, three-vrm at ``/pixiv/*`` and the frame layout at ``/vrm/layout.json``
(``{"bones": [VRM bone names], "expressions": [names]}``). :class:`VrmWebFeed` is its
sink: each frame's BEAT pose is retargeted onto the avatar's normalised humanoid bones
and its ARKit weights mapped to the avatar's expressions in Python
(:class:`facecapges.avatar.vrm.view.VrmDriver`, the one retargeting implementation),
then broadcast as a ``vrm_pose`` message::

    {"type": "vrm_pose", "frame": k, "time": k / fps, "pose": [B × (w, x, y, z)],
     "weights": [E floats], "face_found": true, "latency_ms": {...}, "sent_ms": ...}

(the viewer ignores the BEAT ``hello``/``pose`` layout of :mod:`.protocol`).
"""

from __future__ import annotations

import json
import time

import numpy as np

from facecapges.runtime.frames import OutputFrame
from facecapges.runtime.outputs.viewer import ViewerServer
from facecapges.timing import MODEL_FPS


class VrmViewerServer(ViewerServer):
    def __init__(
        self,
        driver,
        host: str = "127.0.0.1",
        port: int = 8765,
        fps: float = float(MODEL_FPS),
        rate: float | None = None,
    ):
        super().__init__(b"", host, port, fps, rate=rate)
        self.driver = driver
        self.routes = driver.routes()  # the one viewer page asks for /vrm/layout.json: the VRM scene


def encode_vrm_pose(out: OutputFrame, quats: np.ndarray, weights: np.ndarray) -> str:
    return json.dumps(
        {
            "type": "vrm_pose",
            "frame": int(out.index),
            "time": round(float(out.time_s), 6),
            "pose": [round(float(v), 6) for v in np.asarray(quats).reshape(-1)],
            "weights": [round(float(v), 5) for v in np.asarray(weights).reshape(-1)],
            "face_found": bool(out.face_found),
            "latency_ms": {k: round(float(v), 3) for k, v in out.latency_ms.items()},
            "sent_ms": round(time.time() * 1000.0, 1),
        },
        separators=(",", ":"),
    )


class VrmWebFeed:
    """Sink: every frame retargeted onto the VRM and sent to every viewer of a :class:`VrmViewerServer`."""

    def __init__(self, server: VrmViewerServer, skeleton):
        self.server = server
        self.skeleton = skeleton

    def write(self, out: OutputFrame) -> None:
        if not self.server.clients:
            return
        from facecapges.avatar.retarget import upper_body_locals

        d = self.server.driver
        q, w = d.frames(upper_body_locals(self.skeleton, np.asarray(out.quats)[None]), np.asarray(out.face)[None])
        self.server.broadcast(encode_vrm_pose(out, q[0], w[0]))

    def close(self) -> None:
        pass


def open_vrm_viewer(avatar, ckpt, address: tuple[str, int], rate: float | None = None):
    """Start the VRM viewer for ``avatar`` (a file, or its :class:`~facecapges.avatar.vrm.read.VrmModel`
    already read) on ``address`` (the page blending between frames at ``rate``: :mod:`.viewer`); returns
    (server, sink)."""
    from facecapges.avatar.vrm.read import VrmModel
    from facecapges.avatar.vrm.view import VrmDriver

    driver = (
        VrmDriver(avatar, ckpt.skeleton) if isinstance(avatar, VrmModel) else VrmDriver.from_file(avatar, ckpt.skeleton)
    )
    server = VrmViewerServer(driver, address[0], address[1], fps=ckpt.fps, rate=rate).start()
    return server, VrmWebFeed(server, ckpt.skeleton)
