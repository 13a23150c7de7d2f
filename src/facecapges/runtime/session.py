"""Assemble a runtime session from user choices: sources, capture, generator, scheduler.

``run`` and ``live`` build their sessions here, so the offline command and the live
one share one code path (the scheduler); they differ only in pacing and sinks.
:class:`Session` owns everything that must be closed (devices, the capture's
MediaPipe graph, servers, file sinks) and closes it in reverse order, also after
Ctrl-C.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from facecapges.errors import UserError
from facecapges.runtime.interfaces import AudioSource, FaceFeed, Sink, VideoSource
from facecapges.timing import AUDIO_SR

if TYPE_CHECKING:
    from facecapges.capture.pipeline import FaceCapture
    from facecapges.engine.contract import GestureEngine
    from facecapges.runtime.body import LiveBody
    from facecapges.runtime.scheduler import Scheduler


@dataclass
class Session:
    scheduler: Scheduler = field(init=False)  # built last, by build_session
    checkpoint: GestureEngine  # either engine: only the interface is used
    video: VideoSource | None = None
    face_feed: FaceFeed | None = None
    audio: AudioSource | None = None
    capture: FaceCapture | None = None
    sinks: list[Sink] = field(default_factory=list)
    closers: list = field(default_factory=list)  # extra objects with close() (servers)
    notes: list[str] = field(default_factory=list)
    faces: int = 1  # faces (avatars) driven: generator i ↔ capture slot i
    thread_limit: Any = (
        None  # one BLAS (and torch, if loaded) thread for the session (engine/threads.py); close() restores
    )
    opencv_threads: int | None = None  # OpenCV's thread count before the session set it to one; close() restores
    generators: list = field(default_factory=list)  # one per face, in face order
    body: LiveBody | None = None  # live --body: the body capture and the arms' hand-over

    def set_intensity(self, value: float) -> float:
        """Every avatar's intensity dial (:mod:`facecapges.engine.intensity`), from the next frame on."""
        from facecapges.engine.intensity import check_intensity

        v = check_intensity(value, "intensity")
        for gen in self.generators:
            gen.intensity = v
        return v

    def add_sink(self, sink) -> None:
        """A sink that starts receiving frames now (and is closed with the session)."""
        self.sinks.append(sink)
        self.scheduler.sinks.append(sink)

    def close(self) -> list[Path]:
        """Close sinks first (files are written), then servers, capture and sources."""
        written = []
        errors = []
        objs = [*self.sinks, *reversed(self.closers), self.body, self.capture, self.video, self.face_feed, self.audio]
        for obj in objs:
            if obj is None:
                continue
            try:
                p = obj.close()
                if isinstance(p, Path):
                    written.append(p)
            except Exception as exc:  # noqa: BLE001 - close everything, then report the first failure
                errors.append(exc)
        self.sinks, self.closers = [], []
        self.capture = self.video = self.face_feed = self.audio = self.body = None
        if self.thread_limit is not None:  # the process's settings, as they were before the session
            self.thread_limit.restore_original_limits()
            self.thread_limit = None
        if self.opencv_threads is not None:
            import cv2

            cv2.setNumThreads(self.opencv_threads)
            self.opencv_threads = None
        if errors:
            raise errors[0]
        return written


def _open_inputs_once(video, camera, livelink, audio, mic, depth_dir, intrinsics, host: str) -> None:
    """Open each chosen input once (:func:`check_inputs` with ``devices``): the video decodes a frame, the
    audio's header reads, the camera opens, the microphone answers, the Live Link port binds."""
    from facecapges.capture.video import check_camera, check_video
    from facecapges.errors import check_port_free
    from facecapges.io.audio import check_audio

    if video is not None:
        check_video(video)
        if depth_dir is not None or intrinsics is not None:
            from facecapges.capture.depth import check_depth_inputs

            check_depth_inputs(depth_dir, intrinsics)
    elif camera is not None:
        check_camera(int(camera))
    elif livelink is not None:
        check_port_free(host, int(livelink), "--livelink", udp=True)
    if audio is not None:
        check_audio(audio)
    elif mic is not None or video is None:
        from facecapges.runtime.inputs.sources import check_mic

        check_mic(mic)


def check_inputs(
    *,
    video: str | Path | None = None,
    camera: int | None = None,
    livelink: int | None = None,
    audio: str | Path | None = None,
    mic: str | None = None,
    depth_dir=None,
    intrinsics=None,
    estimator: str = "hybrid",
    head: str = "capture",
    faces: int = 1,
    intensity: float = 1.0,
    host: str = "127.0.0.1",
    body: bool = False,
    devices: bool = True,
) -> None:
    """The checks of :func:`build_session`'s arguments, with no model loaded: a bad choice is a UserError now.

    With ``devices`` (what ``run`` and ``live`` do before they load the model) the files are opened too — the
    video decodes a frame, the audio's header (or first second) reads — the camera opens and closes, the
    microphone is asked for 16 kHz mono and the Live Link port is bound once: a wrong path, a file of another
    type, a missing device or a port in use is reported in a second instead of after the model's load.
    """
    from facecapges.capture.estimator import MODES
    from facecapges.engine.intensity import check_intensity
    from facecapges.runtime.head import check_head_mode

    chosen = [x for x in (video, camera, livelink) if x is not None]
    if len(chosen) != 1:
        raise UserError("choose one input: --camera INDEX, --video FILE or --livelink PORT")
    if audio is not None and mic is not None:
        raise UserError("choose one audio input: --mic DEVICE or --audio FILE")
    check_head_mode(head)
    check_intensity(intensity)
    if estimator not in MODES:
        raise UserError(f"--estimator must be {', '.join(MODES[:-1])} or {MODES[-1]}, got {estimator!r}")
    if not 1 <= int(faces) <= 8:
        raise UserError(f"--faces must be 1 to 8, got {faces}")
    if faces > 1 and livelink is not None:
        raise UserError("--faces N needs a camera or a video: Live Link sends one face")
    if body:
        _check_body(livelink, faces)
    if not devices:
        return
    _open_inputs_once(video, camera, livelink, audio, mic, depth_dir, intrinsics, host)


def _check_body(livelink, faces: int) -> None:
    """``--body``: a camera or a video (Live Link sends no image), one person, the models built."""
    if livelink is not None:
        raise UserError("--body needs a camera or a video: Live Link sends no image")
    if int(faces) > 1:
        raise UserError("--body follows one person's arms; use it with --faces 1")
    from facecapges.capture.body_models import HAND_TASK, POSE_TASK, model_path

    model_path(POSE_TASK), model_path(HAND_TASK)  # not built (make setup): one error line now


def _open_video(sess: Session, video, camera, livelink, depth_dir, intrinsics, host: str, realtime: bool) -> None:
    """The visual source, first: a camera that cannot open is reported before anything else. A file played in
    real time is decoded by one thread (FFmpeg's default, a thread per core and more, only adds hand-overs at a
    camera's rate: issue 36, docs/performance.md); offline (``run``) FFmpeg chooses."""
    from facecapges.runtime.inputs import sources as S

    if video is not None:
        threads = 1 if realtime else None
        sess.video = S.FileVideo(video, depth_dir=depth_dir, intrinsics=intrinsics, decode_threads=threads)
    elif camera is not None:
        sess.video = S.CameraVideo(camera)
    elif livelink is not None:  # one input was chosen by check_inputs
        sess.face_feed = S.LiveLinkFace(livelink, host)


def _open_audio(sess: Session, video, audio, mic, realtime: bool, loop: bool, silent_ok: bool) -> None:
    """The speech: a file, the microphone, or the video's own track (silence, with a note, when it has
    none and ``silent_ok``); with ``loop`` the video loops with the audio's period."""
    from facecapges.runtime.inputs import sources as S

    sr = AUDIO_SR
    if audio is not None:
        sess.audio = S.FileAudio(audio, sr, realtime=realtime, loop=loop)
    elif mic is not None or video is None:
        sess.audio = S.MicAudio(mic, sr)
    else:
        try:
            sess.audio = S.FileAudio(video, sr, realtime=realtime, loop=loop)
        except UserError:
            if not silent_ok:
                raise
            sess.notes.append(f"{video}: no readable audio track; the speech input is silence")
    if loop and isinstance(sess.video, S.FileVideo):  # video and audio loop with one period
        v = sess.video
        v.loop_period_s = sess.audio.duration_s if isinstance(sess.audio, S.FileAudio) else (v.n_frames or 1) / v.fps


def _open_capture(sess: Session, estimator: str, faces: int) -> None:
    """The face capture of the video (with its depth head tracker when the file video has depth)."""
    from facecapges.capture.models import resolve_model
    from facecapges.capture.pipeline import FaceCapture
    from facecapges.runtime.inputs import sources as S

    assert sess.video is not None
    resolve_model(None)
    import cv2

    # one OpenCV thread: a frame's colour conversion is a fraction of a millisecond, and handing it to a pool
    # thread and back cost more CPU than it saved (issue 36); restored by Session.close
    sess.opencv_threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    file_video = sess.video if isinstance(sess.video, S.FileVideo) else None
    K = file_video.intrinsics if file_video is not None else None
    sess.capture = FaceCapture(estimator=estimator, fps=sess.video.fps, intrinsics=K, num_faces=int(faces))
    if file_video is not None and file_video.depth_files is not None and K is not None:
        from facecapges.capture.depth import DepthHeadTracker

        sess.capture.depth_tracker = DepthHeadTracker(sess.capture.mesh.vertices / 100.0, K)


class FaceTrack:
    """The face capture's results of one offline run over a video, to replay in another run of the same video
    (:func:`facecapges.runtime.run.run_video`'s ``face_track``): the first run captures and fills it, a later one
    gets the same results frame by frame instead of capturing the same face again. Off line the scheduler asks
    the capture for the same frames in the same order each run (no clock decides), so a replay gives the generator
    exactly what a new capture would; a frame asked for that the capture did not see (another video, another
    ``--max-frames``) is an error, not a guess."""

    def __init__(self) -> None:
        self.frames: list[tuple[float, Any]] = []  # (timestamp in ms, the capture's result), in order
        self.faces: int | None = None  # the capture's face count, once filled
        self.filled = False

    def recorder(self, capture):
        """The capture that fills this track as it runs (once)."""
        if self.filled:
            raise ValueError("this face track is already filled")
        self.filled, self.faces = True, capture.num_faces
        return _RecordingCapture(capture, self.frames)

    def player(self, faces: int):
        """A stand-in for the capture, answering from this track."""
        if not self.filled or self.faces != faces:
            raise ValueError(f"no face track of {faces} face(s) was captured to replay")
        return _ReplayedCapture(self.frames, faces)


class _RecordingCapture:
    """A :class:`FaceCapture` whose results are kept (copies: the capture's own objects stay its own)."""

    def __init__(self, capture, frames: list) -> None:
        self._capture, self._frames = capture, frames
        self.num_faces, self.detector = capture.num_faces, capture.detector

    def process(self, image, ts_ms: float, depth_mm=None):
        r = self._capture.process(image, ts_ms, depth_mm)
        self._frames.append((ts_ms, copy.deepcopy(r)))
        return r

    def process_slots(self, image, ts_ms: float, depth_mm=None):
        r = self._capture.process_slots(image, ts_ms, depth_mm)
        self._frames.append((ts_ms, copy.deepcopy(r)))
        return r

    def close(self) -> None:
        self._capture.close()


class _ReplayedCapture:
    """The results of a :class:`FaceTrack`, frame by frame; a frame out of its order is an error."""

    def __init__(self, frames: list, faces: int) -> None:
        self._frames, self._k, self.num_faces = frames, 0, faces

    def process(self, image, ts_ms: float, depth_mm=None):
        if self._k >= len(self._frames) or self._frames[self._k][0] != ts_ms:
            raise ValueError(f"the face track has no frame {self._k} at {ts_ms} ms: it is another video's or run's")
        r = self._frames[self._k][1]
        self._k += 1
        return copy.deepcopy(r)

    process_slots = process

    def close(self) -> None:
        pass


def _open_face(sess: Session, estimator: str, faces: int, face_track: FaceTrack | None, realtime: bool) -> None:
    """The video's face capture (:func:`_open_capture`), kept in ``face_track``, or that track replayed."""
    if face_track is not None and (realtime or sess.video is None):
        raise ValueError("a face track is captured and replayed off line, from a video")
    if face_track is not None and face_track.filled:
        sess.capture = face_track.player(int(faces))
    elif sess.video is not None:
        _open_capture(sess, estimator, faces)
        if face_track is not None:
            sess.capture = face_track.recorder(sess.capture)


def _build_scheduler(sess: Session, sinks, faces: int, intensity: float, realtime: bool, head: str) -> None:
    """One stream per face and the scheduler over the session's sources and ``sinks``."""
    from facecapges.runtime.inputs import sources as S
    from facecapges.runtime.scheduler import Scheduler

    checkpoint = sess.checkpoint
    fps, sr = checkpoint.fps, AUDIO_SR
    slack = 0.0
    if isinstance(sess.audio, S.MicAudio):
        slack = sess.audio.latency_s + 0.02  # one 20 ms block
    sess.sinks = list(sinks)
    gens = sess.generators = [checkpoint.streaming() for _ in range(int(faces))]
    sess.set_intensity(intensity)
    sess.scheduler = Scheduler(
        gens if faces > 1 else gens[0],
        fps=fps,
        sr=sr,
        video=sess.video,
        face_feed=sess.face_feed,
        audio=sess.audio,
        capture=sess.capture,
        sinks=sess.sinks,
        realtime=realtime,
        input_slack_s=slack,
        head=head,
        body=sess.body,
    )


def _open_body(sess: Session, gestures: bool) -> None:
    """``live --body``: the body landmarkers on the video, the arms' hand-over (:mod:`facecapges.runtime.body`)."""
    from facecapges.runtime.body import LiveBody

    sess.body = LiveBody(sess.checkpoint.skeleton, sess.checkpoint.fps, gestures=gestures)


def build_session(
    checkpoint: GestureEngine,
    *,
    video: str | Path | None = None,
    camera: int | None = None,
    livelink: int | None = None,
    audio: str | Path | None = None,
    mic: str | None = None,
    realtime: bool = False,
    loop: bool = False,
    depth_dir=None,
    intrinsics=None,
    estimator: str = "hybrid",
    host: str = "127.0.0.1",
    sinks=(),
    silent_ok: bool = False,
    head: str = "capture",
    faces: int = 1,
    intensity: float = 1.0,
    body: bool = False,
    gestures: bool = False,
    face_track: FaceTrack | None = None,
) -> Session:
    """Open the sources and build the scheduler (sinks are added by the caller). ``head``: what the avatar's head
    shows (:mod:`facecapges.runtime.head`); ``faces``: how many faces of the video drive an avatar each (one generator
    per face); ``body``: the person's arms where the camera sees them (``gestures``: the engine's, the body still
    captured); ``face_track``: a :class:`FaceTrack` the capture fills, or replays when filled (off line only)."""
    check_inputs(
        video=video,
        camera=camera,
        livelink=livelink,
        audio=audio,
        mic=mic,
        estimator=estimator,
        head=head,
        faces=faces,
        intensity=intensity,
        body=body,
        devices=False,
    )
    # one thread: a frame's tensors are tiny, and a second torch thread only contends with
    # MediaPipe's (measured here: model step p50 28 ms with 2 threads, 1.7 ms with 1). Only when a
    # network style has loaded torch: a matching style's session runs without it (issue 36: memory)
    from facecapges.engine.threads import limit_threads

    sess = Session(checkpoint=checkpoint, faces=int(faces))
    sess.thread_limit = limit_threads(1)  # NumPy's products alike (engine/threads.py)
    try:
        _open_video(sess, video, camera, livelink, depth_dir, intrinsics, host, realtime)
        _open_audio(sess, video, audio, mic, realtime, loop, silent_ok)
        _open_face(sess, estimator, faces, face_track, realtime)
        if body:
            _open_body(sess, gestures)
        _build_scheduler(sess, sinks, faces, intensity, realtime, head)
    except BaseException:
        sess.close()
        raise
    return sess
