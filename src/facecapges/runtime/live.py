"""What ``live`` decides for the user, and says: default outputs, Live Link reachability, per-face sinks.

* **Nothing to show?** ``live`` with none of ``--web``, ``--vmc``, ``--record`` would run
  without a visible result, so it opens the browser viewer (127.0.0.1:8765, or any
  free port when that one is taken) and says what else can be added.
* **Live Link on 127.0.0.1.** The receiver binds the loopback address unless ``--host``
  says otherwise (nothing is exposed to the network by default), but a phone can only
  send to the machine's LAN address: ``live`` says so at start, and the status line
  says "no packets yet" with the fix until the first packet arrives.
* **Several faces** (``--faces N``): face ``i`` (1-based, left to right as the faces
  appear) gets its own recorder files (``motion_i.bvh``, ``face_i.json``) and VMC port
  ``PORT + i − 1`` (a receiver per avatar; VMC has no notion of several performers on
  one port); the viewer gets every face on one feed (the ``face`` field of ``pose``).
"""

from __future__ import annotations

import socket
from pathlib import Path

DEFAULT_VIEWER_PORT = 8765


def _port_free(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def default_outputs(web: str | None, vmc: str | None, record: Path | None) -> tuple[str | None, str | None]:
    """(the ``--web`` to use, a note for the user) — the viewer when no output was chosen."""
    if web is not None or vmc is not None or record is not None:
        return web, None
    port = DEFAULT_VIEWER_PORT if _port_free("127.0.0.1", DEFAULT_VIEWER_PORT) else 0
    return (
        f"127.0.0.1:{port}",
        "no --web, --vmc or --record given: opening the browser viewer (add --vmc 127.0.0.1:39539 to drive "
        "VSeeFace / Warudo / VNyan, --record DIR to save motion.bvh + face.json)",
    )


def livelink_hint(feed, bind: str, waiting: bool = False) -> str | None:
    """What to tell a Live Link user: at start (``waiting=False``) and while no packet has come."""
    from facecapges.runtime.web_server import is_loopback

    port = feed.receiver.address[1]
    loop = is_loopback(bind)
    if waiting:
        if feed.receiver.stats()["packets"]:
            return None
        if loop:
            return "no packets yet — is the phone set to this machine's LAN address? use --host 0.0.0.0"
        return f"no packets yet — is the phone's Live Link target this machine's LAN address, port {port}?"
    if loop:
        return (
            f"Live Link listens on {bind}:{port}, which a phone cannot reach: add --host 0.0.0.0 and set the "
            f"app's target to this machine's LAN address, port {port}"
        )
    return None


def per_face_sinks(
    ckpt,
    faces: int,
    record: Path | None,
    vmc_addr: tuple[str, int] | None,
    *,
    vmc_blend: str = "both",
    vmc_avatar=None,
    rate: float | None = None,
    face_layout: str = "beat",
):
    """Recorders and VMC senders, one set per face (module docstring).

    Returns ``(sinks, senders, upsamplers)``: what the session writes to, the VMC senders
    (for their stats) and, with ``rate`` above the model rate, the per-face interpolators
    the senders sit behind (recorders always get the model's own frames).
    """
    from facecapges.runtime.interfaces import Sink
    from facecapges.runtime.sinks import BvhRecorder, FaceJsonRecorder, ForFace
    from facecapges.runtime.upsample import Upsampler

    sinks: list[Sink] = []
    senders: list[VmcSender] = []
    ups: list[Upsampler] = []
    for i in range(faces):
        sfx = "" if faces == 1 else f"_{i + 1}"
        per: list[Sink] = []
        if record is not None:
            per += [
                BvhRecorder(record / f"motion{sfx}.bvh", ckpt.skeleton, ckpt.fps),
                FaceJsonRecorder(record / f"face{sfx}.json", ckpt.fps, face_layout),
            ]
        if vmc_addr is not None:
            from facecapges.runtime.vmc import VmcSender

            sender = VmcSender(ckpt.skeleton, vmc_addr[0], vmc_addr[1] + i, blend=vmc_blend, avatar=vmc_avatar)
            senders.append(sender)
            if rate is not None and rate != ckpt.fps:
                ups.append(Upsampler([sender], ckpt.fps, rate))
                per.append(ups[-1])
            else:
                per.append(sender)
        sinks += per if faces == 1 else [ForFace(i, x) for x in per]
    return sinks, senders, ups
