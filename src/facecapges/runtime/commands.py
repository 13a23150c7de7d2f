"""Commands of the runtime: ``run`` (a video to files) and ``live`` (devices to avatar)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import typer

STYLE_HELP = "Installed speaking style (see `facecapges styles`); default: the default style."
CKPT_HELP = "Checkpoint file of a speaking style (instead of --style)."
HEAD_HELP = (
    "What the avatar's head shows: capture (the person's head; the model's when the face is lost), "
    "model (the gesture model's neck) or blend (half-way)."
)
FACES_HELP = "Faces to follow, each with its own avatar (1-8; files, VMC ports and viewer avatars per face)."


def _check_face_json(layout: str) -> None:
    from facecapges.errors import UserError
    from facecapges.io.face_json import FACE_LAYOUTS

    if layout not in FACE_LAYOUTS:
        raise UserError(f"--face-json {layout}: choose {' or '.join(FACE_LAYOUTS)}")


def register(app: typer.Typer) -> None:
    @app.command("run")
    def run_cmd(
        video: Path = typer.Argument(..., help="Talking-head video (its audio track is the speech unless --audio)."),
        out: Path = typer.Option(
            ..., "--out", help="Output directory: motion.bvh, face.json, avatar.mp4, side_by_side.mp4, report.json."
        ),
        audio: Path | None = typer.Option(None, "--audio", help="Speech audio file instead of the video's track."),
        checkpoint: Path | None = typer.Option(None, "--checkpoint", help=CKPT_HELP),
        style: str | None = typer.Option(None, "--style", help=STYLE_HELP),
        estimator: str = typer.Option("hybrid", help="Face capture estimator: geometric, mediapipe or hybrid."),
        max_frames: int | None = typer.Option(None, "--max-frames", help="Stop after this many model frames."),
        no_video: bool = typer.Option(False, "--no-video", help="Skip avatar.mp4 and side_by_side.mp4."),
        face_json: str = typer.Option(
            "beat",
            "--face-json",
            help="face.json layout: beat (BEAT's: 51 weights at 60 fps) or full (52 weights at the model rate).",
        ),
        video_size: str | None = typer.Option(
            None, "--video-size", help="Avatar video size WxH (default 640x480; side_by_side.mp4 has its height)."
        ),
        head: str = typer.Option("capture", "--head", help=HEAD_HELP),
        faces: int = typer.Option(1, "--faces", help=FACES_HELP),
        avatar: Path | None = typer.Option(
            None, "--avatar", help="Avatar of avatar.mp4: a VRM 0.x/1.0 or a humanoid GLB (default: ours)."
        ),
        json_out: bool = typer.Option(False, "--json", help="Print the report as JSON."),
        force: bool = typer.Option(False, "--force", help="Overwrite outputs in --out."),
    ) -> None:
        """Video → face capture → gestures → avatar, frame by frame as live, as fast as it goes, to files."""
        from facecapges.errors import require_file
        from facecapges.model.checkpoint import load_checkpoint
        from facecapges.runtime.offline import parse_size, run_video

        size = parse_size(video_size)
        require_file(video, "video")
        if audio is not None:
            require_file(audio, "audio")
        _check_face_json(face_json)
        ckpt = load_checkpoint(checkpoint, style)
        report = run_video(
            video,
            out,
            ckpt,
            audio=audio,
            max_frames=max_frames,
            force=force,
            progress=not json_out,
            videos=not no_video,
            estimator=estimator,
            head=head,
            faces=faces,
            video_size=size,
            avatar=avatar,
            face_layout=face_json,
        )
        if json_out:
            typer.echo(json.dumps(report, indent=2))
            return
        lat = report["latency_ms"]["total"]
        typer.echo(
            f"{report['frames']} frames → {out}  (compute per frame p50 {lat['p50']:.1f} ms, "
            f"p99 {lat['p99']:.1f} ms; {report['seconds']['total']:.1f} s in all)"
        )
        ev = {k: v for k, v in report["events"].items() if v and k != "video_frames_skipped"}
        if ev:
            typer.echo("events: " + ", ".join(f"{k} {v}" for k, v in ev.items()))
        if report["events"].get("video_frames_skipped"):  # decimation to the model rate, not a loss
            typer.echo(
                f"note: {report['events']['video_frames_skipped']} video frames were not needed at the "
                f"model's {report['fps']:g} fps (normal frame-rate conversion)"
            )
        if report.get("face_found_frames") == 0 and report["frames"]:
            typer.secho(
                "warning: no face was found in any frame of the video; the avatar's face stayed neutral "
                "and its head at rest",
                err=True,
                fg=typer.colors.YELLOW,
            )

    @app.command("live")
    def live_cmd(
        camera: int | None = typer.Option(
            None, "--camera", help="Camera index (OpenCV); camera 0 when no other input is chosen."
        ),
        video: Path | None = typer.Option(None, "--video", help="A video file as the camera (+ its audio)."),
        livelink: int | None = typer.Option(
            None, "--livelink", help="Receive iPhone Live Link Face on this UDP port (the app's default is 11111)."
        ),
        realtime: bool = typer.Option(
            False, "--realtime", help="Pace --video like a device (else as fast as it goes)."
        ),
        loop: bool = typer.Option(False, "--loop", help="Loop --video (and its audio) until stopped."),
        mic: str | None = typer.Option(
            None, "--mic", help="Microphone: sounddevice index or name (default device for --camera / --livelink)."
        ),
        audio: Path | None = typer.Option(None, "--audio", help="Speech from a file instead of a microphone."),
        vmc: str | None = typer.Option(None, "--vmc", help="Send VMC (OSC/UDP) to HOST:PORT, e.g. 127.0.0.1:39539."),
        vmc_blend: str = typer.Option(
            "vrm",
            "--vmc-blend",
            help="Face clips sent over VMC: vrm (VRM presets Blink, "
            "A…O, Joy…; every VRM), perfect-sync (the 52 ARKit "
            "clips, EyeBlinkLeft…) or both.",
        ),
        vmc_avatar: Path | None = typer.Option(
            None,
            "--vmc-avatar",
            help="The receiver's VRM file: send its own "
            "rest bone positions (receivers that "
            "apply bone positions keep its "
            "proportions).",
        ),
        rate: float | None = typer.Option(
            None,
            "--rate",
            help="VMC and viewer output rate in Hz, a multiple of "
            "the model's 15 fps: 30 or 60 interpolate between "
            "model frames (+33 / +50 ms latency).",
        ),
        web: str | None = typer.Option(
            None, "--web", help="Serve the browser viewer on [HOST:]PORT, e.g. 127.0.0.1:8765 (port 0: any free port)."
        ),
        host: str | None = typer.Option(
            None,
            "--host",
            help="Bind servers (viewer, Live Link) to this address "
            "instead of 127.0.0.1, e.g. 0.0.0.0 for a phone on "
            "the LAN.",
        ),
        record: Path | None = typer.Option(
            None, "--record", help="Record motion.bvh, face.json and report.json into this directory."
        ),
        face_json: str = typer.Option(
            "beat",
            "--face-json",
            help="face.json layout: beat (BEAT's: 51 weights at 60 fps) or full (52 weights at the model rate).",
        ),
        vrma: bool = typer.Option(
            False,
            "--vrma",
            help="With --record: also record motion.vrma (VRM Animation, gestures + face as VRM presets).",
        ),
        avatar: Path | None = typer.Option(
            None, "--avatar", help="Show this avatar in --web: a VRM 0.x/1.0 or a humanoid GLB (default: ours)."
        ),
        checkpoint: Path | None = typer.Option(None, "--checkpoint", help=CKPT_HELP),
        style: str | None = typer.Option(None, "--style", help=STYLE_HELP),
        estimator: str = typer.Option("hybrid", help="Face capture estimator: geometric, mediapipe or hybrid."),
        depth: Path | None = typer.Option(
            None, "--depth", help="RGB-D: directory of depth frames for --video (16-bit PNG or .npy, mm)."
        ),
        intrinsics: Path | None = typer.Option(None, "--intrinsics", help="RGB-D: camera intrinsics K.json."),
        max_seconds: float | None = typer.Option(None, "--max-seconds", help="Stop after this much stream time."),
        head: str = typer.Option("capture", "--head", help=HEAD_HELP),
        faces: int = typer.Option(1, "--faces", help=FACES_HELP + " VMC: face i on PORT+i-1."),
        force: bool = typer.Option(False, "--force", help="Overwrite files in --record."),
    ) -> None:
        """Real-time avatar: camera/video/Live Link + microphone/audio → VMC, browser viewer, recording."""
        from facecapges.errors import UserError, check_output_dir
        from facecapges.model.checkpoint import load_checkpoint
        from facecapges.runtime.live import default_outputs, livelink_hint, per_face_sinks
        from facecapges.runtime.session import build_session
        from facecapges.runtime.sources import LiveLinkFace
        from facecapges.runtime.web_server import is_loopback, parse_address

        if livelink is not None:
            from facecapges.errors import check_port

            check_port(livelink, "--livelink")
        if camera is None and video is None and livelink is None:
            camera = 0
        web, default_note = default_outputs(web, vmc, record)
        if realtime and video is None:
            raise UserError("--realtime paces a --video file; devices are always real time")
        if loop and video is None:
            raise UserError("--loop needs --video")
        bind = host or "127.0.0.1"
        web_addr = None
        if web is not None:
            web_addr = parse_address(web, bind, "--web")
            if not is_loopback(web_addr[0]) and host is None:
                raise UserError(
                    f"--web {web}: refusing to serve on a non-loopback address without --host {web_addr[0]}"
                )
        vmc_addr = parse_address(vmc, "127.0.0.1", "--vmc") if vmc is not None else None
        if avatar is not None:
            from facecapges.avatar.vrm import load_model

            if web_addr is None:
                raise UserError(
                    "--avatar is the avatar of the browser viewer; pass --web too (VMC receivers show their own avatar)"
                )
            load_model(avatar)  # a bad file fails here, before any device opens
        if vrma and record is None:
            raise UserError("--vrma records into --record DIR; pass --record too")
        if record is not None:
            from facecapges.runtime.offline import output_names

            if vrma and faces > 1:
                raise UserError("--vrma records one performer; use it with --faces 1")
            check_output_dir(
                record,
                (*output_names(max(faces, 1))[: 2 * max(faces, 1)], "report.json", *(("motion.vrma",) if vrma else ())),
                force,
            )
        if max_seconds is not None and max_seconds <= 0:
            raise UserError("--max-seconds must be positive")
        if vmc_avatar is not None and vmc is None:
            raise UserError("--vmc-avatar needs --vmc HOST:PORT")
        _check_face_json(face_json)
        if vmc_blend not in ("vrm", "perfect-sync", "both"):
            raise UserError(f"--vmc-blend {vmc_blend}: choose vrm, perfect-sync or both")
        ckpt = load_checkpoint(checkpoint, style)
        if rate is not None:
            from facecapges.runtime.upsample import substeps

            try:
                substeps(rate, ckpt.fps)
            except ValueError as exc:
                raise UserError(f"--rate {rate:g}: {exc}") from None
        sinks, senders, ups = per_face_sinks(
            ckpt, faces, record, vmc_addr, vmc_blend=vmc_blend, vmc_avatar=vmc_avatar, rate=rate, face_layout=face_json
        )
        server = None
        if vrma and record is not None:  # --vrma without --record was refused above
            from facecapges.avatar.vrma import VrmaRecorder

            sinks.append(VrmaRecorder(record / "motion.vrma", ckpt.skeleton, ckpt.fps))
        sess = build_session(
            ckpt,
            video=video,
            camera=camera,
            livelink=livelink,
            audio=audio,
            mic=mic,
            realtime=realtime or video is None,
            loop=loop,
            depth_dir=depth,
            intrinsics=intrinsics,
            estimator=estimator,
            host=bind,
            sinks=sinks,
            silent_ok=True,
            head=head,
            faces=faces,
        )
        feed = sess.face_feed
        try:
            for note in sess.notes:
                typer.secho(f"warning: {note}", err=True, fg=typer.colors.YELLOW)
            if web_addr is not None:
                from facecapges.runtime.offline import avatar_glb
                from facecapges.runtime.web_server import ViewerServer, WebFeed

                if avatar is not None:  # a VRM: retargeted in Python, drawn by three-vrm (runtime/vrm_viewer.py)
                    from facecapges.runtime.vrm_viewer import open_vrm_viewer

                    server, feed_sink = open_vrm_viewer(avatar, ckpt, web_addr)
                    if faces > 1:  # the VRM viewer shows one avatar: the first face
                        from facecapges.runtime.sinks import ForFace

                        feed_sink = ForFace(0, feed_sink)
                else:
                    server = ViewerServer(avatar_glb(ckpt.skeleton), web_addr[0], web_addr[1], fps=ckpt.fps).start()
                    feed_sink = WebFeed(server)
                sess.closers.append(server)
                if rate is not None and rate != ckpt.fps and faces == 1:
                    from facecapges.runtime.upsample import Upsampler

                    ups.append(Upsampler([feed_sink], ckpt.fps, rate))  # the viewer at --rate too
                    feed_sink = ups[-1]
                sess.add_sink(feed_sink)
                typer.echo(f"viewer: {server.url}", nl=True)
            src = sess.video or sess.face_feed
            assert src is not None  # build_session opened one input
            vmc_text = (
                (
                    [f"VMC {vmc_addr[0]}:{vmc_addr[1]}"]
                    if faces == 1
                    else [f"VMC {vmc_addr[0]}:{vmc_addr[1]}…{vmc_addr[1] + faces - 1} (face i on port +i-1)"]
                )
                if vmc_addr
                else []
            )
            if default_note:
                typer.echo(default_note)
            hint = livelink_hint(feed, bind) if feed is not None else None
            if hint:
                typer.secho(f"note: {hint}", err=True, fg=typer.colors.YELLOW)
            typer.echo(
                f"live: {src.name} + {sess.audio.name if sess.audio else 'silence'} → "
                + ", ".join([*vmc_text, *(["viewer"] if server else []), *([f"record {record}"] if record else [])])
                + "  (Ctrl-C stops)"
            )
            max_frames = int(round(max_seconds * ckpt.fps)) if max_seconds else None
            last = [time.monotonic()]

            def status(out):
                now = time.monotonic()
                if now - last[0] >= 5.0:
                    last[0] = now
                    lat = sess.scheduler.timings.ms["total"][-75:]
                    lat = sorted(lat)[len(lat) // 2] if lat else 0.0
                    waiting = livelink_hint(feed, bind, waiting=True) if feed is not None else None
                    typer.echo(
                        f"frame {out.index}  compute p50 {lat:.1f} ms  face "
                        f"{'tracked' if out.face_found else 'lost'}"
                        + (f"  viewers {len(server.clients)}" if server else "")
                        + (f"  — {waiting}" if waiting else ""),
                        err=True,
                    )

            why = sess.scheduler.run(max_frames=max_frames, on_frame=status)
        except KeyboardInterrupt:
            why = "interrupted"
        finally:
            written = sess.close()
        report = sess.scheduler.report() if sess.scheduler is not None else {}
        report["stopped_by"] = why
        if isinstance(feed, LiveLinkFace):
            report["livelink"] = feed.receiver.stats()
        if server is not None:
            report["viewer"] = {
                "frames_sent": server.frames_sent,
                "rejected_requests": server.rejected_requests,
                "oversized_closes": server.oversized_closes,
            }
        if senders:
            report["vmc"] = senders[0].stats() if faces == 1 else [x.stats() for x in senders]
        if ups:
            report["output"] = {
                "rate_hz": ups[0].rate_hz,
                "interpolation_added_latency_ms": round(ups[0].added_latency_ms, 1),
                "frames_emitted": ups[0].emitted,
            }
        if record is not None:
            record.mkdir(parents=True, exist_ok=True)
            (record / "report.json").write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
            written.append(record / "report.json")
        lat = report.get("latency_ms", {}).get("total", {})
        typer.echo(
            f"stopped ({why}) after {report.get('frames', 0)} frames; compute p50 {lat.get('p50', 0):.1f} ms, "
            f"p99 {lat.get('p99', 0):.1f} ms; events {json.dumps(report.get('events', {}))}"
        )
        for p in written:
            typer.echo(f"wrote {p}")
