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

:func:`run_live` is the whole command: :class:`~facecapges.runtime.options.LiveOptions`
holds its options, ``say``/``warn`` say where its messages go.
"""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from facecapges.errors import echo, echo_warning
from facecapges.runtime.options import LiveOptions

if TYPE_CHECKING:
    from facecapges.runtime.outputs.vmc import VmcSender

DEFAULT_VIEWER_PORT = 8765
LOOPBACK = "127.0.0.1"
STATUS_EVERY_S = 5.0  # the status line's period


@dataclass
class _Outputs:
    """What :func:`run_live` opened for the user's outputs (for the start line and the report)."""

    web_addr: tuple[str, int] | None
    vmc_addr: tuple[str, int] | None
    bind: str
    default_note: str | None
    avatar: Any = None  # --avatar, parsed once (a VrmModel)
    vmc_avatar: Any = None  # --vmc-avatar, parsed once (a VrmModel)
    senders: list = field(default_factory=list)
    ups: list = field(default_factory=list)
    server: Any = None


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
    from facecapges.runtime.outputs.viewer import is_loopback

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
    vmc_parts: str = "all",
    rate: float | None = None,
    face_layout: str = "beat",
):
    """Recorders and VMC senders, one set per face (module docstring).

    Returns ``(sinks, senders, upsamplers)``: what the session writes to, the VMC senders
    (for their stats) and, with ``rate`` above the model rate, the per-face interpolators
    the senders sit behind (recorders always get the model's own frames).
    """
    from facecapges.runtime.interfaces import Sink
    from facecapges.runtime.outputs.recorders import file_recorders, per_face
    from facecapges.runtime.outputs.upsample import Upsampler

    senders: list[VmcSender] = []
    ups: list[Upsampler] = []
    if vmc_addr is not None and vmc_avatar is not None:
        from facecapges.runtime.outputs.vmc import vrm_rig

        vmc_avatar = vrm_rig(vmc_avatar)  # the receiver's rig, read once for every sender

    def sinks_of(i: int) -> list[Sink]:
        per: list[Sink] = []
        if record is not None:
            per += file_recorders(record, ckpt.skeleton, ckpt.fps, face_layout, i, faces)
        if vmc_addr is not None:
            from facecapges.runtime.outputs.vmc import VmcSender

            sender = VmcSender(
                ckpt.skeleton, vmc_addr[0], vmc_addr[1] + i, blend=vmc_blend, avatar=vmc_avatar, parts=vmc_parts
            )
            senders.append(sender)
            if rate is not None and rate != ckpt.fps:
                ups.append(Upsampler([sender], ckpt.fps, rate))
                per.append(ups[-1])
            else:
                per.append(sender)
        return per

    sinks = per_face(faces, sinks_of)
    return sinks, senders, ups


def _check_vmc(o: LiveOptions):
    """The VMC options (and the face JSON layout, in the order the user meets them); returns
    ``--vmc-avatar`` parsed (a VrmModel), or None."""
    from facecapges.errors import UserError
    from facecapges.io.face_json import check_face_layout

    if o.vmc_avatar is not None and o.vmc is None:
        raise UserError("--vmc-avatar needs --vmc HOST:PORT")
    check_face_layout(o.face_json)
    from facecapges.runtime.outputs.vmc import BLEND_MODES, PARTS

    if o.vmc_blend not in BLEND_MODES:
        raise UserError(f"--vmc-blend {o.vmc_blend}: choose {', '.join(BLEND_MODES[:-1])} or {BLEND_MODES[-1]}")
    if o.vmc_parts not in PARTS:
        raise UserError(f"--vmc-parts {o.vmc_parts}: choose {', '.join(PARTS[:-1])} or {PARTS[-1]}")
    if o.vmc_parts != "all" and o.vmc is None:
        raise UserError("--vmc-parts needs --vmc HOST:PORT")
    if o.vmc_avatar is not None:
        from facecapges.avatar.vrm.read import load_model

        return load_model(o.vmc_avatar)  # a bad file fails here, before any device opens
    return None


def _check_record(o: LiveOptions) -> None:
    """``--record``'s files (and ``--vrma``'s one performer) before anything opens."""
    from facecapges.errors import UserError, check_output_dir
    from facecapges.runtime.run import output_names

    assert o.record is not None
    if o.vrma and o.faces > 1:
        raise UserError("--vrma records one performer; use it with --faces 1")
    n = max(o.faces, 1)
    check_output_dir(
        o.record, (*output_names(n)[: 2 * n], "report.json", *(("motion.vrma",) if o.vrma else ())), o.force
    )


def _check(o: LiveOptions) -> _Outputs:
    """Every check that needs no device and no model, in the order the user meets them."""
    from facecapges.errors import UserError, check_port
    from facecapges.runtime.outputs.viewer import is_loopback, parse_address

    if o.livelink is not None:
        check_port(o.livelink, "--livelink")
    if o.camera is None and o.video is None and o.livelink is None:
        o.camera = 0
    o.web, default_note = default_outputs(o.web, o.vmc, o.record)
    if o.realtime and o.video is None:
        raise UserError("--realtime paces a --video file; devices are always real time")
    if o.loop and o.video is None:
        raise UserError("--loop needs --video")
    bind = o.host or LOOPBACK
    web_addr = None
    if o.web is not None:
        web_addr = parse_address(o.web, bind, "--web")
        if not is_loopback(web_addr[0]) and o.host is None:
            raise UserError(f"--web {o.web}: refusing to serve on a non-loopback address without --host {web_addr[0]}")
    vmc_addr = parse_address(o.vmc, LOOPBACK, "--vmc") if o.vmc is not None else None
    avatar = None
    if o.avatar is not None:
        from facecapges.avatar.vrm.read import load_model

        if web_addr is None:
            raise UserError(
                "--avatar is the avatar of the browser viewer; pass --web too (VMC receivers show their own avatar)"
            )
        avatar = load_model(o.avatar)  # a bad file fails here, before any device opens
    if o.vrma and o.record is None:
        raise UserError("--vrma records into --record DIR; pass --record too")
    if o.record is not None:
        _check_record(o)
    if o.max_seconds is not None and o.max_seconds <= 0:
        raise UserError("--max-seconds must be positive")
    if o.gestures and not o.body:
        raise UserError("--gestures gives the arms back to the engine under --body; without --body they are already")
    vmc_avatar = _check_vmc(o)
    from facecapges.errors import check_port_free
    from facecapges.runtime.session import check_inputs

    if web_addr is not None:
        check_port_free(web_addr[0], web_addr[1], "--web")
    check_inputs(  # files decode, the camera and microphone open, the Live Link port is free: before the model
        video=o.video,
        camera=o.camera,
        livelink=o.livelink,
        audio=o.audio,
        mic=o.mic,
        depth_dir=o.depth,
        intrinsics=o.intrinsics,
        estimator=o.estimator,
        head=o.head,
        faces=o.faces,
        intensity=o.intensity,
        host=bind,
        body=o.body,
    )
    return _Outputs(web_addr, vmc_addr, bind, default_note, avatar, vmc_avatar)


def _check_rate(rate: float | None, fps: float) -> None:
    from facecapges.errors import UserError
    from facecapges.runtime.outputs.upsample import substeps

    if rate is not None:
        try:
            substeps(rate, fps)
        except ValueError as exc:
            raise UserError(f"--rate {rate:g}: {exc}") from None


def _open_viewer(o: LiveOptions, outs: _Outputs, sess) -> None:
    """The browser viewer on ``outs.web_addr`` (ours, or the --avatar VRM), added to the session's sinks."""
    from facecapges.avatar.gltf import avatar_glb
    from facecapges.runtime.outputs.viewer import ViewerServer, WebFeed

    ckpt = sess.checkpoint
    assert outs.web_addr is not None
    # --rate: the page blends between the model's frames itself (runtime/outputs/viewer.py), as one avatar's
    # upsampler would; the feed carries the model's frames (issue 36: no blend, encode and send per tick)
    rate = o.rate if o.rate is not None and o.faces == 1 else None
    if o.avatar is not None:  # a VRM: retargeted in Python, drawn by three-vrm (runtime/outputs/vrm_viewer.py)
        from facecapges.runtime.outputs.vrm_viewer import open_vrm_viewer

        server, feed_sink = open_vrm_viewer(outs.avatar, ckpt, outs.web_addr, rate)
        if o.faces > 1:  # the VRM viewer shows one avatar: the first face
            from facecapges.runtime.outputs.recorders import ForFace

            feed_sink = ForFace(0, feed_sink)
    else:
        server = ViewerServer(
            avatar_glb(ckpt.skeleton), outs.web_addr[0], outs.web_addr[1], fps=ckpt.fps, rate=rate
        ).start()
        feed_sink = WebFeed(server)
    server.on_intensity = sess.set_intensity  # the viewer's slider
    server.intensity = o.intensity
    sess.closers.append(server)
    outs.server = server
    sess.add_sink(feed_sink)


def _start_line(o: LiveOptions, outs: _Outputs, sess) -> str:
    src = sess.video or sess.face_feed
    assert src is not None  # build_session opened one input
    vmc_text = []
    if outs.vmc_addr:
        host, port = outs.vmc_addr
        vmc_text = [
            f"VMC {host}:{port}" if o.faces == 1 else f"VMC {host}:{port}…{port + o.faces - 1} (face i on port +i-1)"
        ]
    shown = [*vmc_text, *(["viewer"] if outs.server else []), *([f"record {o.record}"] if o.record else [])]
    return (
        f"live: {src.name} + {sess.audio.name if sess.audio else 'silence'} → " + ", ".join(shown) + "  (Ctrl-C stops)"
    )


def body_status(body) -> str:
    """``--body``'s part of the status line: where each arm comes from, or that no one is seen."""
    if body.frames_seen and not body.person_frames:
        return "body: no person seen yet (the engine's gestures drive the arms; film the upper body)"
    src = ["yours" if on else "gestures" for on in body.arms_on_body]
    return f"arms R {src[0]} L {src[1]}"


def body_warning(body) -> str | None:
    """The closing warning of ``--body`` when the body was never or hardly seen."""
    if body.frames_seen == 0:
        return None
    if body.person_frames == 0:
        return (
            f"--body: no person's body was seen in any of the {body.frames_seen} camera frames; the engine's "
            "gestures drove the arms throughout (film the upper body and hands facing the camera)"
        )
    on = body.handover.body_frames
    if not any(on) and not body.gestures:
        return "--body: a person was seen but never their arms (shoulder, elbow and wrist in view); the engine's gestures drove the arms"
    return None


BEHIND_NOTE = "behind real time: dropping camera frames to keep up (audio is kept)"


def _status(sess, outs: _Outputs, say: Callable[..., None]) -> Callable[[Any], None]:
    """The scheduler's ``on_frame``: a status line on stderr every :data:`STATUS_EVERY_S` seconds.

    When camera frames have been dropped for a second's worth of frames (the machine cannot
    keep up: :mod:`.scheduler`; a frame or two at start-up, while the engine warms up, is
    not worth a word) a status line comes at once and says so (:data:`BEHIND_NOTE`),
    once; later lines count the frames dropped."""
    feed, last, told = sess.face_feed, [time.monotonic()], [False]
    events, fps = sess.scheduler.events, sess.scheduler.fps

    def status(out) -> None:
        now = time.monotonic()
        dropped = events["camera_frames_dropped"]
        first_drop = dropped >= fps and not told[0]
        if now - last[0] >= STATUS_EVERY_S or first_drop:
            last[0] = now
            lat = sess.scheduler.timings.ms["total"][-75:]
            lat = sorted(lat)[len(lat) // 2] if lat else 0.0
            waiting = livelink_hint(feed, outs.bind, waiting=True) if feed is not None else None
            say(
                f"frame {out.index}  compute p50 {lat:.1f} ms  face {'tracked' if out.face_found else 'lost'}"
                + (f"  {body_status(sess.body)}" if sess.body is not None else "")
                + (f"  viewers {len(outs.server.clients)}" if outs.server else "")
                + (f"  camera frames dropped {dropped}" if dropped else "")
                + (f"  — {BEHIND_NOTE}" if first_drop else "")
                + (f"  — {waiting}" if waiting else ""),
                err=True,
            )
            told[0] = told[0] or first_drop

    return status


def _report(o: LiveOptions, outs: _Outputs, scheduler, feed, why: str, body=None) -> dict:
    """The scheduler's report + what stopped the run and each output's counters."""
    from facecapges.runtime.inputs.sources import LiveLinkFace
    from facecapges.runtime.scheduler import ms_stats

    report = scheduler.report() if scheduler is not None else {}
    report["stopped_by"] = why
    if isinstance(feed, LiveLinkFace):
        report["livelink"] = feed.receiver.stats()
    if outs.server is not None:
        report["viewer"] = {
            "frames_sent": outs.server.frames_sent,
            "rejected_requests": outs.server.rejected_requests,
            "oversized_closes": outs.server.oversized_closes,
            "page_blends_at_rate_hz": outs.server.rate if outs.server.rate > outs.server.fps else None,
        }
    if outs.senders:
        report["vmc"] = outs.senders[0].stats() if o.faces == 1 else [x.stats() for x in outs.senders]
    if body is not None:
        report["body"] = body.report()
    if outs.ups:
        report["output"] = {
            "rate_hz": outs.ups[0].rate_hz,
            "interpolation_added_latency_ms": round(outs.ups[0].added_latency_ms, 1),
            "frames_emitted": outs.ups[0].emitted,
            "late_ticks": outs.ups[0].late,
            "resyncs": outs.ups[0].resyncs,
            "tick_ms": ms_stats(outs.ups[0].tick_ms),
            "tick_cpu_ms": ms_stats(outs.ups[0].tick_cpu_ms),
        }
    return report


def _open_session(o: LiveOptions, outs: _Outputs, ckpt):
    """The session with its recorders and VMC senders (one set per face) and the ``--vrma`` recorder."""
    from facecapges.runtime.session import build_session

    sinks, outs.senders, outs.ups = per_face_sinks(
        ckpt,
        o.faces,
        o.record,
        outs.vmc_addr,
        vmc_blend=o.vmc_blend,
        vmc_avatar=outs.vmc_avatar,
        vmc_parts=o.vmc_parts,
        rate=o.rate,
        face_layout=o.face_json,
    )
    if o.vrma and o.record is not None:  # --vrma without --record was refused by _check
        from facecapges.avatar.vrm.animation import VrmaRecorder

        sinks.append(VrmaRecorder(o.record / "motion.vrma", ckpt.skeleton, ckpt.fps))
    sess = build_session(
        ckpt,
        video=o.video,
        camera=o.camera,
        livelink=o.livelink,
        audio=o.audio,
        mic=o.mic,
        realtime=o.realtime or o.video is None,
        loop=o.loop,
        depth_dir=o.depth,
        intrinsics=o.intrinsics,
        estimator=o.estimator,
        host=outs.bind,
        sinks=sinks,
        silent_ok=True,
        head=o.head,
        faces=o.faces,
        intensity=o.intensity,
        body=o.body,
        gestures=o.gestures,
    )
    return sess


def _announce(o: LiveOptions, outs: _Outputs, sess, say: Callable[..., None], warn: Callable[[str], None]) -> None:
    """The session's notes, the viewer (opened here), the VMC and Live Link notes and the start line."""
    for note in sess.notes:
        warn(f"warning: {note}")
    if outs.web_addr is not None:
        _open_viewer(o, outs, sess)
        say(f"viewer: {outs.server.url}")
    if outs.default_note:
        say(outs.default_note)
    if outs.senders:
        from facecapges.runtime.outputs.vmc import vmc_note

        warn(f"note: {vmc_note(o.vmc_avatar, o.vmc_parts)}")
    hint = livelink_hint(sess.face_feed, outs.bind) if sess.face_feed is not None else None
    if hint:
        warn(f"note: {hint}")
    say(_start_line(o, outs, sess))


def _finish(o: LiveOptions, report: dict, written: list, why: str, say: Callable[..., None]) -> None:
    """report.json into ``--record``, the closing line and the files written."""
    if o.record is not None:
        o.record.mkdir(parents=True, exist_ok=True)
        (o.record / "report.json").write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
        written.append(o.record / "report.json")
    lat = report.get("latency_ms", {}).get("total", {})
    say(
        f"stopped ({why}) after {report.get('frames', 0)} frames; compute p50 {lat.get('p50', 0):.1f} ms, "
        f"p99 {lat.get('p99', 0):.1f} ms; events {json.dumps(report.get('events', {}))}"
    )
    for p in written:
        say(f"wrote {p}")


def run_live(o: LiveOptions, say: Callable[..., None] = echo, warn: Callable[[str], None] = echo_warning) -> dict:
    """The whole ``live`` command: check ``o``, open inputs and outputs, run until stopped; returns the report.

    ``say(text, err=False)`` gets the start line, the status lines (``err=True``) and the
    summary; ``warn(text)`` the warnings and notes. The report is also written to
    ``--record``'s ``report.json``.
    """
    from facecapges.runtime.os_memory import limit_malloc_arenas, release_free_memory
    from facecapges.styles import load_style

    o = replace(o)  # _check fills in the defaults it decides (camera 0, the viewer)
    outs = _check(o)
    limit_malloc_arenas()  # before MediaPipe's and our threads start (runtime/os_memory.py)
    ckpt = load_style(o.checkpoint, o.style)
    _check_rate(o.rate, ckpt.fps)
    sess = _open_session(o, outs, ckpt)
    feed, body = sess.face_feed, sess.body  # close() forgets them; the report asks them for their stats
    try:
        _announce(o, outs, sess, say, warn)
        release_free_memory()  # what the start-up freed
        max_frames = int(round(o.max_seconds * ckpt.fps)) if o.max_seconds else None
        why = sess.scheduler.run(max_frames=max_frames, on_frame=_status(sess, outs, say))
    except KeyboardInterrupt:
        why = "interrupted"
    finally:
        written = sess.close()
    report = _report(o, outs, sess.scheduler, feed, why, body)
    if body is not None and (w := body_warning(body)):
        warn(f"warning: {w}")
    _finish(o, report, written, why, say)
    return report
