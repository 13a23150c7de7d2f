"""``facecapges run``: a video through the live code path, as fast as it goes, to files.

Writes into ``DIR``:

* ``motion.bvh`` — the generated upper body on the checkpoint's BEAT skeleton, model fps,
  with the avatar's head as shown (``--head``, :mod:`facecapges.runtime.head`);
* ``face.json`` — BEAT-format face JSON of the weights the avatar showed (+ head rot6d);
* ``avatar.mp4`` — the avatar (three.js in headless Chromium,
  :mod:`facecapges.avatar.render.video`, ``--video-size``, with a face close-up inset)
  with the input audio;
* ``side_by_side.mp4`` — the input video frame each model frame used (the newest one
  before the frame's deadline, the scheduler's rule) | the avatar, same audio;
* with ``--faces N`` (N > 1): ``motion_1.bvh``, ``face_1.json`` … one pair per face
  (face ``i`` = the ``i``-th face from the left as they first appear), and every
  avatar next to each other in ``avatar.mp4`` and ``side_by_side.mp4``;
* ``report.json`` — ``frames``, ``latency_ms`` (``p50``/``p99``/``mean``/``max`` per
  stage: ``capture``, ``features``, ``model``, ``output`` and ``total`` = input frame to
  pose + blendshapes; the first 5 frames are warm-up and excluded), ``events`` (the
  scheduler's fallback counters), ``head_follow`` (how closely the avatar's head
  follows the captured one: yaw/pitch correlation, ranges, mean error), wall-clock
  seconds per phase, inputs and checkpoint.

The frame count is ``ceil(audio duration · fps)`` (as ``generate``), or ``--max-frames``.
"""

from __future__ import annotations

import json
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from facecapges import timing
from facecapges.errors import UserError, check_output_dir, echo, echo_warning
from facecapges.runtime.options import DEFAULT_VIDEO_SIZE, RunOptions

OUR_AVATAR = "ours (BEAT skeleton, face: 52 ARKit morph targets)"
OUTPUTS = ("motion.bvh", "face.json", "avatar.mp4", "side_by_side.mp4", "report.json")


def _label(img: np.ndarray, text: str, x: int, dark: bool = False) -> None:
    import cv2

    if not dark:
        cv2.putText(img, text, (x, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 0), 4, cv2.LINE_AA)
    cv2.putText(
        img, text, (x, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (40, 40, 40) if dark else (255, 255, 255), 2, cv2.LINE_AA
    )


def _frames(mp4: Path):
    """BGR frames of an MP4 (imageio-ffmpeg's reader)."""
    import cv2
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(mp4))
    try:
        w, h = next(reader)["size"]
        for raw in reader:
            yield cv2.cvtColor(np.frombuffer(raw, np.uint8).reshape(h, w, 3), cv2.COLOR_RGB2BGR)
    finally:
        reader.close()


def _panels(frame, avs: list[np.ndarray], height: int, with_input: bool) -> np.ndarray:
    """One frame of :func:`side_by_side`: the input frame (black before the first) and the avatars,
    each scaled to ``height`` and labelled."""
    import cv2

    panels = []
    if with_input:
        src = frame if frame is not None else np.zeros((height, height, 3), np.uint8)
        panels.append(
            cv2.resize(
                src,
                (int(round(src.shape[1] * height / src.shape[0])) // 2 * 2, height),
                interpolation=cv2.INTER_AREA,
            )
        )
    for av in avs:
        if av.shape[0] != height:
            av = cv2.resize(av, (int(round(av.shape[1] * height / av.shape[0])), height), interpolation=cv2.INTER_AREA)
        panels.append(av)
    img = np.hstack(panels)
    x = 0
    if with_input:
        _label(img, "input", 10)
        x = panels[0].shape[1]
    for i, p in enumerate(panels[int(with_input) :]):
        _label(img, "avatar" if len(avs) == 1 else f"avatar {i + 1}", x + 10, dark=True)
        x += p.shape[1]
    return img


def side_by_side(
    video: Path,
    avatar_mp4s: list[Path],
    out: Path,
    fps: float,
    n_frames: int,
    audio_wav: Path | None,
    height: int = 480,
    with_input: bool = True,
) -> None:
    """Input frame used by model frame k (newest before (k+1)/fps) | avatar frame(s) k → ``out`` (H.264 + AAC).

    Several avatars (one per face, left to right as the faces' slots) stand next to each
    other; ``with_input=False`` writes the avatars alone (``avatar.mp4`` of several faces)."""
    import cv2

    from facecapges.io.mp4 import Mp4Writer

    cap = cv2.VideoCapture(str(video))
    vfps = float(cap.get(cv2.CAP_PROP_FPS) or 25.0)
    readers = [_frames(p) for p in avatar_mp4s]
    writer = Mp4Writer(out, fps, audio=audio_wav, crf=22)
    try:
        vi, frame = -1, None
        for k in range(n_frames):
            want = int(np.ceil((k + 1) / fps * vfps - 1e-9)) - 1  # newest source frame with time < deadline
            while vi < want:
                ok, img = cap.read()
                if not ok:
                    break
                vi, frame = vi + 1, img
            try:
                avs = [next(r) for r in readers]
            except StopIteration:
                break
            img = _panels(frame, avs, height, with_input)
            writer.write(img)
        if not writer.frames:
            raise UserError(f"{avatar_mp4s[0]}: no frames to put side by side")
        writer.close()
    except BaseException:
        writer.abort()
        raise
    finally:
        cap.release()
        for r in readers:
            r.close()


def shows_face_inset(driver) -> bool:
    """Whether avatar.mp4 gets the face close-up: ours and any avatar with face expressions do; one without
    (a bare humanoid GLB) would show an empty close-up, so it gets none (the report and the summary say so)."""
    return driver is None or bool(driver.faces.names)


def output_names(faces: int) -> tuple[str, ...]:
    """The files ``run`` writes: one motion and face file per face (``motion_1.bvh`` … for several)."""
    if faces == 1:
        return OUTPUTS
    per = tuple(f"{stem}_{i + 1}{ext}" for i in range(faces) for stem, ext in (("motion", ".bvh"), ("face", ".json")))
    return per + OUTPUTS[2:]


def parse_size(text: str | None, default: tuple[int, int] = DEFAULT_VIDEO_SIZE) -> tuple[int, int]:
    """``"WxH"`` (even, 160…3840 × 120…2160) → (width, height); None → ``default``."""
    if text is None:
        return default
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise UserError(f"--video-size must look like 640x480, got {text!r}") from None
    if not (160 <= w <= 3840 and 120 <= h <= 2160):
        raise UserError(f"--video-size {text}: width must be 160…3840 and height 120…2160")
    return w // 2 * 2, h // 2 * 2


def _recorders(out_dir: Path, checkpoint, faces: int, face_layout: str):
    """Each face's recorders: its motion BVH, its face JSON and a memory of its frames (for the videos).
    Returns (the memories, the sinks)."""
    from facecapges.runtime.outputs.recorders import MemoryRecorder, file_recorders, per_face

    mems = [MemoryRecorder() for _ in range(faces)]
    sinks = per_face(
        faces,
        lambda i: [*file_recorders(out_dir, checkpoint.skeleton, checkpoint.fps, face_layout, i, faces), mems[i]],
    )
    return mems, sinks


def _run_frames(sess, video: Path, out_dir: Path, max_frames: int | None, progress: bool):
    """Run the session over the whole audio (or ``max_frames``); closes it. Returns (why it stopped, frames
    with a face found, the loop's seconds, the input audio)."""
    from facecapges.progress import Progress
    from facecapges.runtime.inputs.sources import FileAudio

    sched = sess.scheduler
    audio_src = sess.audio
    assert isinstance(audio_src, FileAudio)  # run reads its speech from a file
    try:
        total = timing.n_frames_for(audio_src.duration_s, sess.checkpoint.fps)
        if max_frames is not None:
            total = min(total, max_frames)
        out_dir.mkdir(parents=True, exist_ok=True)
        t_loop = time.perf_counter()
        with Progress(disable=not progress, transient=True) as bar:
            task = bar.add_task(f"run {video.name}", total=total)
            found = [0]

            def on_frame(o) -> None:
                found[0] += bool(o.face_found)
                bar.advance(task)

            why = sched.run(max_frames=total, on_frame=on_frame)
        t_loop_end = time.perf_counter()
        input_audio = audio_src.samples
    finally:
        sess.close()
    return why, found[0], t_loop_end - t_loop, input_audio


def _render_videos(
    video: Path, out_dir: Path, checkpoint, mems, driver, input_audio, T: int, video_size, progress: bool, inset: bool
) -> dict[str, float]:
    """avatar.mp4 (each face's avatar, side by side for several) and side_by_side.mp4; returns their seconds."""
    from facecapges.avatar.gltf import avatar_glb, full_quaternions
    from facecapges.avatar.render.video import our_avatar, render_video
    from facecapges.io.audio import save_audio

    fps, faces = checkpoint.fps, len(mems)
    t0 = time.perf_counter()
    glb = avatar_glb(checkpoint.skeleton)
    width, height = video_size
    with tempfile.TemporaryDirectory(prefix="facecapges-run-") as tmp:
        wav = Path(tmp) / "audio.wav"
        n = int(timing.frame_sample_bounds(T, fps)[0])  # the samples frames 0 … T−1 own
        save_audio(wav, np.pad(input_audio[:n], (0, max(0, n - len(input_audio[:n])))))
        renders = []
        for i, m in enumerate(mems):
            weights = np.clip(np.stack(m.weights), 0.0, 1.0)
            dest = out_dir / "avatar.mp4" if faces == 1 else Path(tmp) / f"avatar_{i + 1}.mp4"
            if driver is not None:  # the VRM's frames: its normalised bones and expressions
                from facecapges.avatar.retarget import upper_body_locals

                page = driver.page()
                quats, weights = driver.frames(upper_body_locals(checkpoint.skeleton, np.stack(m.quats)), weights)
            else:
                page = our_avatar(glb)
                quats = full_quaternions(checkpoint.skeleton, np.stack(m.quats))
            render_video(
                page, quats, weights, fps, dest, audio=wav, progress=progress, width=width, height=height, inset=inset
            )
            renders.append(dest)
        if faces > 1:
            side_by_side(video, renders, out_dir / "avatar.mp4", fps, T, wav, height=height, with_input=False)
        t1 = time.perf_counter()
        side_by_side(video, renders, out_dir / "side_by_side.mp4", fps, T, wav, height=height)
        t2 = time.perf_counter()
    return {"avatar_video": round(t1 - t0, 3), "side_by_side_video": round(t2 - t1, 3)}


def _write_report(out_dir: Path, report: dict, faces: int) -> None:
    """The outputs written into the report, and report.json (written whole or not at all)."""
    for name in output_names(faces)[:-1]:
        p = out_dir / name
        if p.exists():
            report["outputs"][name] = str(p)
    report["outputs"]["report.json"] = str(out_dir / "report.json")
    tmp = out_dir / "report.json.part"
    tmp.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    tmp.replace(out_dir / "report.json")


def _run_report(video: Path, audio, checkpoint, sched, head: str, faces: int, found: int, mems, loop_s: float) -> dict:
    """The report of a ``run``: inputs, the scheduler's figures, how the head followed, the loop's time."""
    from facecapges.runtime.head import head_follow

    report = {
        "video": str(video),
        "audio": str(audio or video),
        "checkpoint": str(checkpoint.path),
        **sched.report(),
        "head": head,
        "faces": faces,
        "face_found_frames": found,
        "outputs": {},
    }
    T = sched.frames
    follow = [
        head_follow(np.stack(m.poses), np.stack(m.heads), np.array(m.found)) if m.poses else {"frames": 0} for m in mems
    ]
    report["head_follow"] = follow[0] if faces == 1 else follow
    report["seconds"] = {"pipeline": round(loop_s, 3)}
    report["ms_per_frame_wall"] = round(loop_s * 1000 / max(T, 1), 3)
    return report


def _vrm_driver(avatar, skeleton):
    """The VRM shown in avatar.mp4 (a file, or its model already read): a bad file fails before the run."""
    from facecapges.avatar.vrm.view import VrmDriver

    return VrmDriver.of(avatar, skeleton)


def run_video(
    video: str | Path,
    out_dir: str | Path,
    checkpoint,
    audio: str | Path | None = None,
    max_frames: int | None = None,
    force: bool = False,
    progress: bool = True,
    videos: bool = True,
    estimator: str = "hybrid",
    head: str = "capture",
    faces: int = 1,
    video_size: tuple[int, int] = DEFAULT_VIDEO_SIZE,
    avatar=None,
    face_layout: str = "beat",
    intensity: float = 1.0,
    face_track=None,
) -> dict:
    """The whole ``run`` command (module docstring); returns the report. ``avatar``: a VRM / humanoid GLB (a file,
    or its VrmModel read) in avatar.mp4 instead of ours; ``face_track``: a ``runtime.session.FaceTrack`` to fill or replay."""
    from facecapges.runtime.head import check_head_mode
    from facecapges.runtime.session import build_session

    t_start = time.perf_counter()
    video = Path(video)
    out_dir = Path(out_dir)
    check_head_mode(head)
    check_output_dir(out_dir, output_names(faces), force)
    if max_frames is not None and max_frames < 1:
        raise UserError("--max-frames must be at least 1")
    driver = _vrm_driver(avatar, checkpoint.skeleton) if avatar is not None and videos else None
    mems, sinks = _recorders(out_dir, checkpoint, faces, face_layout)
    sess = build_session(
        checkpoint,
        video=video,
        audio=audio,
        realtime=False,
        estimator=estimator,
        sinks=sinks,
        head=head,
        faces=faces,
        intensity=intensity,
        face_track=face_track,
    )
    sched = sess.scheduler
    why, found, loop_s, input_audio = _run_frames(sess, video, out_dir, max_frames, progress)
    if why == "interrupted":
        raise KeyboardInterrupt
    report = _run_report(video, audio, checkpoint, sched, head, faces, found, mems, loop_s)
    T = sched.frames
    inset = shows_face_inset(driver)
    if videos:
        report["avatar"] = driver.describe() if driver is not None else OUR_AVATAR
        report["face_inset"] = inset
    if videos and T > 0:
        report["seconds"].update(
            _render_videos(video, out_dir, checkpoint, mems, driver, input_audio, T, video_size, progress, inset)
        )
    report["seconds"]["total"] = round(time.perf_counter() - t_start, 3)
    _write_report(out_dir, report, faces)
    return report


def _say_summary(o: RunOptions, report: dict, say: Callable[..., None], warn: Callable[[str], None]) -> None:
    """The summary of a ``run``: frames and timing, the avatar, the files written, events and notes."""
    lat = report["latency_ms"]["total"]
    say(
        f"{report['frames']} frames → {o.out}  (compute per frame p50 {lat['p50']:.1f} ms, "
        f"p99 {lat['p99']:.1f} ms; {report['seconds']['total']:.1f} s in all)"
    )
    if "avatar" in report:
        say(
            f"avatar: {report['avatar']}"
            + ("" if report.get("face_inset", True) else "; no face close-up (it has no face expressions)")
        )
    say(f"face capture: {o.estimator} estimator; the avatar's head: {o.head}")
    for p in report["outputs"].values():
        say(f"wrote {p}")
    ev = {k: v for k, v in report["events"].items() if v and k != "video_frames_skipped"}
    if ev:
        say("events: " + ", ".join(f"{k} {v}" for k, v in ev.items()))
    if report["events"].get("video_frames_skipped"):  # decimation to the model rate, not a loss
        say(
            f"note: {report['events']['video_frames_skipped']} video frames were not needed at the "
            f"model's {report['fps']:g} fps (normal frame-rate conversion)"
        )
    if report.get("face_found_frames") == 0 and report["frames"]:
        warn(
            "warning: no face was found in any frame of the video; the avatar's face stayed neutral "
            "and its head at rest"
        )


def run_offline(o: RunOptions, say: Callable[..., None] = echo, warn: Callable[[str], None] = echo_warning) -> dict:
    """The whole ``run`` command: check ``o``, :func:`run_video`, tell the user; returns the report.

    ``say`` gets the summary (the report as JSON with ``o.json_out``), ``warn`` a
    warning when no face was found at all.
    """
    from facecapges.io.audio import check_audio
    from facecapges.io.face_json import check_face_layout
    from facecapges.runtime.session import check_inputs

    # every check before the model loads (a bad path or file type in a second, not after the load)
    size = parse_size(o.video_size)
    check_inputs(video=o.video, audio=o.audio, estimator=o.estimator, head=o.head, faces=o.faces, intensity=o.intensity)
    if o.audio is None:  # the speech is the video's own track
        try:
            check_audio(o.video)
        except UserError as exc:
            raise UserError(f"{exc} — the video needs an audio track, or pass --audio FILE") from None
    check_face_layout(o.face_json)
    check_output_dir(o.out, output_names(o.faces), o.force)
    if o.max_frames is not None and o.max_frames < 1:
        raise UserError("--max-frames must be at least 1")
    avatar = None
    if o.avatar is not None and not o.no_video:
        from facecapges.avatar.vrm.read import load_model

        avatar = load_model(o.avatar)  # a bad file fails here, before the model loads; parsed once
    from facecapges.styles import load_style

    ckpt = load_style(o.checkpoint, o.style)
    report = run_video(
        o.video,
        o.out,
        ckpt,
        audio=o.audio,
        max_frames=o.max_frames,
        force=o.force,
        progress=not o.json_out,
        videos=not o.no_video,
        estimator=o.estimator,
        head=o.head,
        faces=o.faces,
        video_size=size,
        avatar=avatar,
        face_layout=o.face_json,
        intensity=o.intensity,
    )
    if o.json_out:
        say(json.dumps(report, indent=2))
        return report
    _say_summary(o, report, say, warn)
    return report
