"""``facecapges run``: a video through the live code path, as fast as it goes, to files.

Writes into ``DIR``:

* ``motion.bvh`` — the generated upper body on the checkpoint's BEAT skeleton, model fps;
* ``face.json`` — BEAT-format face JSON of the weights the avatar showed (+ head rot6d);
* ``avatar.mp4`` — the avatar (three.js in headless Chromium,
  :mod:`facecapges.avatar.render.video`) with the input audio;
* ``side_by_side.mp4`` — the input video frame each model frame used (the newest one
  before the frame's deadline, the scheduler's rule) | the avatar, same audio;
* ``report.json`` — ``frames``, ``latency_ms`` (``p50``/``p99``/``mean``/``max`` per
  stage: ``capture``, ``features``, ``model``, ``output`` and ``total`` = input frame to
  pose + blendshapes; the first 5 frames are warm-up and excluded), ``events`` (the
  scheduler's fallback counters), wall-clock seconds per phase, inputs and checkpoint.

The frame count is ``ceil(audio duration · fps)`` (as ``generate``), or ``--max-frames``.
"""

from __future__ import annotations

import json
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from facecapges.errors import UserError, refuse_overwrite

OUTPUTS = ("motion.bvh", "face.json", "avatar.mp4", "side_by_side.mp4", "report.json")


def _avatar_glb(skeleton) -> bytes:
    from facecapges.avatar.body import default_avatar
    from facecapges.avatar.gltf import avatar_to_gltf

    return b"".join(avatar_to_gltf(default_avatar(skeleton)).save_to_bytes())


def side_by_side(video: Path, avatar_mp4: Path, out: Path, fps: float, n_frames: int, audio_wav: Path | None,
                 height: int = 480) -> None:
    """Input frame used by model frame k (newest before (k+1)/fps) | avatar frame k → ``out`` (H.264 + AAC)."""
    import cv2
    import imageio_ffmpeg

    cap = cv2.VideoCapture(str(video))
    vfps = float(cap.get(cv2.CAP_PROP_FPS) or 25.0)
    reader = imageio_ffmpeg.read_frames(str(avatar_mp4))
    meta = next(reader)
    aw, ah = meta["size"]
    proc = None
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
                av = np.frombuffer(next(reader), np.uint8).reshape(ah, aw, 3)
            except StopIteration:
                break
            av = cv2.cvtColor(av, cv2.COLOR_RGB2BGR)
            if av.shape[0] != height:
                av = cv2.resize(av, (int(round(aw * height / ah)), height), interpolation=cv2.INTER_AREA)
            src = frame if frame is not None else np.zeros((height, height, 3), np.uint8)
            src = cv2.resize(src, (int(round(src.shape[1] * height / src.shape[0])) // 2 * 2, height),
                             interpolation=cv2.INTER_AREA)
            img = np.hstack([src, av])
            cv2.putText(img, "input", (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 0), 4, cv2.LINE_AA)
            cv2.putText(img, "input", (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2, cv2.LINE_AA)
            cv2.putText(img, "avatar", (src.shape[1] + 10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (40, 40, 40), 2,
                        cv2.LINE_AA)
            if proc is None:
                h, w = img.shape[:2]
                cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt",
                       "bgr24", "-s", f"{w}x{h}", "-framerate", f"{fps:g}", "-i", "-"]
                if audio_wav is not None:
                    cmd += ["-i", str(audio_wav), "-map", "0:v", "-map", "1:a", "-c:a", "aac", "-b:a", "128k",
                            "-shortest"]
                cmd += ["-c:v", "libx264", "-preset", "veryfast", "-crf", "22", "-pix_fmt", "yuv420p",
                        "-movflags", "+faststart", str(out)]
                proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stderr=subprocess.PIPE)
            proc.stdin.write(np.ascontiguousarray(img).tobytes())
        if proc is None:
            raise UserError(f"{avatar_mp4}: no frames to put side by side")
        proc.stdin.close()
        err = proc.stderr.read().decode(errors="replace")
        if proc.wait() != 0:
            raise RuntimeError(f"ffmpeg failed writing {out}: {err.strip()}")
    finally:
        cap.release()
        reader.close()
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()


def run_video(video: str | Path, out_dir: str | Path, checkpoint, audio: str | Path | None = None,
              max_frames: int | None = None, force: bool = False, progress: bool = True, videos: bool = True,
              estimator: str = "hybrid", face_layout: str = "beat") -> dict:
    """The whole ``run`` command (module docstring); returns the report."""
    from rich.progress import Progress

    from facecapges.io.audio import save_audio
    from facecapges.runtime.session import build_session, full_quaternions
    from facecapges.runtime.sinks import BvhRecorder, FaceJsonRecorder, MemoryRecorder

    t_start = time.perf_counter()
    video = Path(video)
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise UserError(f"{out_dir}: exists and is not a directory")
    for name in OUTPUTS:
        refuse_overwrite(out_dir / name, force)
    if max_frames is not None and max_frames < 1:
        raise UserError("--max-frames must be at least 1")
    fps = checkpoint.fps
    mem = MemoryRecorder()
    bvh = BvhRecorder(out_dir / "motion.bvh", checkpoint.skeleton, fps)
    face = FaceJsonRecorder(out_dir / "face.json", fps, face_layout)
    sess = build_session(checkpoint, video=video, audio=audio, realtime=False, estimator=estimator,
                         sinks=[bvh, face, mem])
    sched = sess.scheduler
    try:
        total = int(np.ceil(sess.audio.duration_s * fps - 1e-6))
        if max_frames is not None:
            total = min(total, max_frames)
        out_dir.mkdir(parents=True, exist_ok=True)
        t_loop = time.perf_counter()
        with Progress(disable=not progress, transient=True) as bar:
            task = bar.add_task(f"run {video.name}", total=total)
            why = sched.run(max_frames=total, on_frame=lambda o: bar.advance(task))
        t_loop_end = time.perf_counter()
        input_audio = sess.audio.samples
    finally:
        sess.close()
    if why == "interrupted":
        raise KeyboardInterrupt
    report = {"video": str(video), "audio": str(audio or video), "checkpoint": str(checkpoint.path),
              **sched.report(), "outputs": {}}
    report["seconds"] = {"pipeline": round(t_loop_end - t_loop, 3)}
    report["ms_per_frame_wall"] = round((t_loop_end - t_loop) * 1000 / max(sched.frames, 1), 3)
    T = sched.frames
    if videos and T > 0:
        from facecapges.avatar.render.video import render_video

        t0 = time.perf_counter()
        glb = _avatar_glb(checkpoint.skeleton)
        quats = full_quaternions(checkpoint.skeleton, np.stack(mem.quats))
        weights = np.clip(np.stack(mem.weights), 0.0, 1.0)
        with tempfile.TemporaryDirectory(prefix="facecapges-run-") as tmp:
            wav = Path(tmp) / "audio.wav"
            n = int(round(T / fps * 16000))
            save_audio(wav, np.pad(input_audio[:n], (0, max(0, n - len(input_audio[:n])))))
            render_video(glb, quats, weights, fps, out_dir / "avatar.mp4", audio=wav, progress=progress)
            t1 = time.perf_counter()
            side_by_side(video, out_dir / "avatar.mp4", out_dir / "side_by_side.mp4", fps, T, wav)
            t2 = time.perf_counter()
        report["seconds"].update({"avatar_video": round(t1 - t0, 3), "side_by_side_video": round(t2 - t1, 3)})
    report["seconds"]["total"] = round(time.perf_counter() - t_start, 3)
    for name in OUTPUTS[:-1]:
        p = out_dir / name
        if p.exists():
            report["outputs"][name] = str(p)
    report["outputs"]["report.json"] = str(out_dir / "report.json")
    tmp = out_dir / "report.json.part"
    tmp.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    tmp.replace(out_dir / "report.json")
    return report
