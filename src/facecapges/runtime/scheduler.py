"""The model-rate clock: one generator step per frame, inputs aligned, nothing from the future.

Frame ``k`` covers stream time ``[k/fps, (k+1)/fps)``; its **deadline** is ``(k+1)/fps``
(the moment its last audio sample exists). At frame ``k`` the scheduler

1. **capture** — takes the newest video frame stamped before the deadline
   (:meth:`FileVideo.next_frame`; older unread frames are skipped) and runs
   :class:`~facecapges.capture.FaceCapture` on it; or takes the newest Live Link
   sample that arrived before the deadline;
2. **features** — takes the audio samples frame ``k`` owns
   (``timing.frame_sample_bounds(k)``) and assembles ``(audio, face52, head rot6d)``,
   applying the fallbacks below;
3. **model** — calls :meth:`NetworkStream.step` once;
4. **output** — converts the pose to quaternions and hands the
   :class:`~facecapges.runtime.frames.OutputFrame` to every sink.

It never waits for future input: a source is only asked for data before the deadline,
and whatever has not arrived is replaced by a fallback. In ``realtime`` mode frame
``k`` starts at wall time ``t0 + deadline + input_slack_s`` (``input_slack_s`` covers a
microphone's block delivery; 0 for files); offline (``run``) it starts at once.
Every stage is timed with ``time.perf_counter``; ``total`` spans capture → output (the
sinks see a provisional ``total``: input frame → pose + blendshapes ready, before
output).

Fallbacks (each counted in :attr:`Scheduler.events`)
----------------------------------------------------
* **face lost** (``face_lost_frames``, ``face_lost_events``) — the project's one
  face-lost policy (:mod:`facecapges.capture.face_lost`): the last weights and head are
  held 500 ms, then eased to neutral over 1 s (smoothstep; the head along the
  geodesic), so the avatar never jumps.
* **no new input frame** (``input_frames_reused``: the camera dropped a frame, a
  frame came late, or the source is slower than the model rate) — the last face and
  head are reused; after the same 500 ms they ease to neutral exactly like a lost
  face (a stalled device looks like a face that left).
* **audio underrun** (``audio_underruns``) — samples that have not arrived are zeros
  (silence; the model's own padding convention). The end of a file is not an underrun.
* **late frame** (``late_frames``, realtime only) — a frame that starts more than one
  frame period after its scheduled time (the machine was busy, or the capture is slower
  than the frame rate). It is still computed (the model needs every frame's audio, in
  order), so output continues without a gap, but **its camera frames are dropped**
  (``camera_frames_dropped``: read past without conversion or capture, the held face
  reused): the expensive stage is skipped until the clock has caught up, so a machine
  that cannot capture every frame captures as many as it can and the output stays on
  time. Audio is never dropped. ``live`` says so in its status line.
* ``video_frames_skipped`` counts source frames never processed because a newer one was
  due (e.g. 25 fps video at the 15 fps model rate): decimation, not an error.
"""

from __future__ import annotations

import signal
import threading
import time
from array import array
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from facecapges import rotations as rot
from facecapges import timing
from facecapges.arkit import N_BLENDSHAPES
from facecapges.capture.face_lost import FaceLostPolicy
from facecapges.capture.speech_mouth import SpeechMouth
from facecapges.engine.contract import Stream
from facecapges.runtime.frames import InputFrame, OutputFrame
from facecapges.runtime.head import HeadDriver
from facecapges.runtime.inputs.sources import FaceSample
from facecapges.runtime.interfaces import AudioSource, FaceFeed, Sink, VideoSource

STAGES = (
    "capture",
    "features",
    "model",
    "output",
    "total",
    "input",
    "landmarks",
    "model_cpu",
    "output_cpu",
    "body",
    "body_mix",
    "input_cpu",
    "capture_cpu",
)
# ``input``: reading/decoding the video frame (not in ``total``); ``landmarks``: MediaPipe's part of ``capture``;
# ``model_cpu``, ``output_cpu``, ``input_cpu``, ``capture_cpu``: those stages' CPU time on the scheduler's thread
# (``time.thread_time``: what they cost, without the time the machine gave to others meanwhile; MediaPipe's graph
# runs in threads of its own, so ``capture_cpu`` is the frame's conversion, MediaPipe's Python side and ours);
# ``body`` (``live --body``): the body landmarkers and solve, part of ``capture``; ``body_mix``: the arms'
# hand-over, part of ``output``


class FaceHold:
    """Hold, then ease to neutral, when no fresh face arrives (module docstring)."""

    def __init__(self, hold_ms: float = 500.0, ease_ms: float = 1000.0):
        self.policy = FaceLostPolicy.from_ms(hold_ms, ease_ms)
        self.weights = np.zeros(N_BLENDSHAPES, np.float32)
        self.head = rot.identity_rot6d().astype(np.float32)
        self.found = False
        self.since: float | None = None  # stream time of the last fresh sample
        self.seen: float | None = None  # stream time of the last sample with a face
        self.remaining = 0.0  # how much of the last face is still shown (1 while tracked)

    def _remaining(self, now_s: float) -> float:
        return 0.0 if self.seen is None else self.policy.held(now_s - self.seen)

    def fresh(self, s: FaceSample) -> tuple[np.ndarray, np.ndarray, bool]:
        self.weights = np.asarray(s.weights52, np.float32)
        self.head = np.asarray(s.head_rot6d, np.float32)
        self.found = bool(s.face_found)
        self.since = s.ts_s
        if self.found:
            self.seen = s.ts_s
        # a lost face from the capture is already held/eased there, by the same policy
        self.remaining = 1.0 if self.found else self._remaining(s.ts_s)
        return self.weights, self.head, self.found

    def stale(self, now_s: float) -> tuple[np.ndarray, np.ndarray, bool]:
        if self.since is None:
            self.remaining = 0.0
            return self.weights, self.head, False
        k = self.policy.held(now_s - self.since)
        self.remaining = min(k, self._remaining(now_s)) if self.found else self._remaining(now_s)
        if k >= 1.0:
            return self.weights, self.head, self.found
        R = rot.rotation_power_about(rot.rot6d_to_matrix(self.head.astype(np.float64)), None, k)
        return (self.weights * k).astype(np.float32), rot.matrix_to_rot6d(R).astype(np.float32), False


def ms_stats(values, skip: int = 0) -> dict[str, float]:
    """p50 / p99 / mean / max of durations (ms), the first ``skip`` left out (warm-up)."""
    a = np.array(values, np.float64)  # a copy: the array keeps growing
    a = a[skip:] if len(a) > skip else (a if len(a) else np.zeros(1))
    return {
        "p50": round(float(np.percentile(a, 50)), 3),
        "p99": round(float(np.percentile(a, 99)), 3),
        "mean": round(float(a.mean()), 3),
        "max": round(float(a.max()), 3),
    }


@dataclass
class Timings:
    """Per-stage durations (ms) of every frame (8 bytes each: an hour is 2 MB), and their percentiles."""

    ms: dict[str, array] = field(default_factory=lambda: {s: array("d") for s in STAGES})
    sinks: dict[str, array] = field(default_factory=dict)  # each sink's ``write`` (ms), by :func:`sink_label`

    def add(self, stage_ms: dict[str, float]) -> None:
        for s in STAGES:
            self.ms[s].append(stage_ms.get(s, 0.0))

    def add_sink(self, label: str, ms: float) -> None:
        self.sinks.setdefault(label, array("d")).append(ms)

    def summary(self, skip: int = 0) -> dict[str, dict[str, float]]:
        """p50 / p99 / mean / max per stage (ms), ignoring the first ``skip`` frames (warm-up)."""
        return {s: ms_stats(self.ms[s], skip) for s in STAGES}

    def sink_summary(self, skip: int = 0) -> dict[str, dict[str, float]]:
        """The same per sink (its ``write`` in the scheduler's thread; a sink with several faces: per call)."""
        return {k: ms_stats(v, skip) for k, v in self.sinks.items()}


def sink_label(sink) -> str:
    """A sink's name in the timings: its class (``ForFace`` and ``Upsampler`` name what they wrap)."""
    inner = getattr(sink, "sink", None)
    if inner is not None:  # ForFace
        return sink_label(inner)
    name = type(sink).__name__
    wrapped = getattr(sink, "sinks", None)
    if wrapped is not None:  # Upsampler: its write hands the frame to its own thread
        return f"{name}[{'+'.join(sink_label(s) for s in wrapped)}]"
    return name


@dataclass
class FaceChain:
    """One face's chain: its generator, input hold, head driver, speech mouth and the last frame."""

    index: int
    gen: Stream
    hold: FaceHold
    head: HeadDriver
    mouth: SpeechMouth
    was_found: bool = True
    last: OutputFrame | None = None


class Scheduler:
    """Runs one session: sources → capture → generator(s) → sinks, once per model frame.

    Args:
        generator: a :class:`~facecapges.network.streaming.NetworkStream` (reset here),
            or one per face (a list) for several faces (``FaceCapture(num_faces=N)``).
        fps, sr: model rate and audio rate (the checkpoint's).
        video: a video source (:class:`FileVideo`, :class:`CameraVideo`) — needs ``capture``.
        face_feed: a face source without capture (:class:`LiveLinkFace`).
        audio: an audio source (:class:`FileAudio`, :class:`MicAudio`) or None (silence).
        capture: a :class:`~facecapges.capture.FaceCapture` for ``video``.
        sinks: objects satisfying :class:`~facecapges.runtime.interfaces.Sink` (closed by the owner); each
            gets every face's frames (``OutputFrame.face_index``); wrap one in
            :class:`~facecapges.runtime.outputs.recorders.ForFace` to give it one face only.
        realtime: pace frames by the wall clock (live) instead of as fast as possible.
        input_slack_s: extra wait after each deadline in realtime mode (device latency).
        head: what the avatar's head shows, ``capture``, ``model`` or ``blend``
            (:mod:`facecapges.runtime.head`).
        speech_mouth: drive the shown jaw and lips from the speech while there is no face
            (:mod:`facecapges.capture.speech_mouth`); the model's input is not changed.
        body: a :class:`~facecapges.runtime.body.LiveBody` (``live --body``, one face): it sees every
            captured video frame, and the person's arms replace the model's where they are seen.

    Several faces: the capture runs once per frame (:meth:`FaceCapture.process_slots`),
    then face ``i`` goes through generator ``i``; all of them share the audio.
    """

    def __init__(
        self,
        generator,
        fps: float = timing.MODEL_FPS,
        sr: int = timing.AUDIO_SR,
        video: VideoSource | None = None,
        face_feed: FaceFeed | None = None,
        audio: AudioSource | None = None,
        capture=None,
        sinks: Sequence[Sink] = (),
        realtime: bool = False,
        input_slack_s: float = 0.0,
        hold_ms: float = 500.0,
        ease_ms: float = 1000.0,
        head: str = "capture",
        speech_mouth: bool = True,
        body=None,
    ):
        if video is not None and capture is None:
            raise ValueError("a video source needs a FaceCapture")
        gens = list(generator) if isinstance(generator, (list, tuple)) else [generator]
        if len(gens) > 1 and (video is None or capture.num_faces != len(gens)):
            raise ValueError("several generators need a video source and a FaceCapture(num_faces=N) to match")
        self.fps, self.sr = float(fps), int(sr)
        self.video, self.face_feed, self.audio, self.capture = video, face_feed, audio, capture
        self.sinks = list(sinks)
        self.realtime, self.input_slack_s = realtime, input_slack_s
        self.speech_mouth = speech_mouth
        if body is not None and (video is None or len(gens) > 1):
            raise ValueError("the body capture needs a video source and one face")
        self.body = body
        policy, fps, sr = FaceLostPolicy.from_ms(hold_ms, ease_ms), self.fps, self.sr
        self.streams = [  # the head's chain and the mouth's sums compiled (Numba: the engines load it), keeping the bits
            FaceChain(i, g, FaceHold(hold_ms, ease_ms), HeadDriver(head, policy, True), SpeechMouth(fps, sr, True))
            for i, g in enumerate(gens)
        ]
        self.spf = timing.samples_per_frame(self.fps, self.sr)
        self.timings = Timings()
        self.events = {
            "face_lost_frames": 0,
            "face_lost_events": 0,
            "input_frames_reused": 0,
            "audio_underruns": 0,
            "late_frames": 0,
            "video_frames_skipped": 0,
            "camera_frames_dropped": 0,
        }
        self.frames = 0
        self.t0: float | None = None
        self.stopped_by = ""
        self._stop = False
        self.last_video_frame = None  # the frame capture saw last (for side-by-side video)
        self._stage: dict[str, float] = {}  # the current frame's stage times
        self._t_input = 0.0
        self._c_input = 0.0  # the scheduler thread's CPU clock then
        from facecapges.rotations_compiled import checked_rot6d_to_quaternions  # Numba: the engines load it anyway

        self._to_quaternions = checked_rot6d_to_quaternions()  # each frame's quaternions, one call, NumPy's bits
        for st in self.streams:
            st.gen.reset()

    @property
    def gen(self):
        """The (first face's) generator."""
        return self.streams[0].gen

    @property
    def hold(self) -> FaceHold:
        return self.streams[0].hold

    # ------------------------------------------------------------------ control
    def stop(self) -> None:
        """Ask :meth:`run` to finish after the current frame (thread-safe)."""
        self._stop = True

    def start(self) -> None:
        self.t0 = time.monotonic()
        for src in (self.video, self.face_feed, self.audio):
            if src is not None:
                src.start(self.t0)

    def _now_s(self) -> float:
        assert self.t0 is not None  # set by start()
        return time.monotonic() - self.t0

    def input_ended(self) -> bool:
        """A file source has nothing more for frame ``self.frames``."""
        if self.audio is not None:
            s, _ = timing.frame_sample_bounds(self.frames, self.fps, self.sr)
            return bool(self.audio.ended_at(int(s)))
        src = self.video or self.face_feed
        return bool(src is not None and src.ended)

    # ------------------------------------------------------------------ one frame
    def _capture(self, deadline: float, behind: bool = False) -> list[FaceSample | None]:
        """The fresh face sample of each stream (None: nothing new before the deadline, or ``behind``:
        the frames due are dropped unprocessed)."""
        n = len(self.streams)
        if self.video is not None:
            t, c = time.perf_counter(), time.thread_time()
            if behind:
                self.events["camera_frames_dropped"] += self.video.drop(deadline)
                vf = None
            else:
                vf = self.video.next_frame(deadline)
            self._t_input, self._c_input = time.perf_counter(), time.thread_time()
            self._stage["input"] = (self._t_input - t) * 1000.0
            self._stage["input_cpu"] = (self._c_input - c) * 1000.0
            if vf is None:
                return [None] * n
            self.last_video_frame = vf
            if n == 1:
                res = [self.capture.process(vf.image, vf.ts_s * 1000.0, vf.depth_mm)]
            else:
                res = self.capture.process_slots(vf.image, vf.ts_s * 1000.0, vf.depth_mm)
            detector = getattr(self.capture, "detector", None)
            self._stage["landmarks"] = float(getattr(detector, "last_ms", 0.0))
            if self.body is not None:
                self.body.observe(vf.image, vf.ts_s)
                self._stage["body"] = self.body.last_ms
            return [
                FaceSample(vf.ts_s, r.weights52, r.head_rot6d, bool(r.face_found))
                if r is not None
                else FaceSample(
                    vf.ts_s, np.zeros(N_BLENDSHAPES, np.float32), rot.identity_rot6d().astype(np.float32), False
                )
                for r in res
            ]
        assert self.face_feed is not None  # a scheduler has a video or a face feed
        sample = self.face_feed.next_face(deadline)
        self._t_input = time.perf_counter()
        return [sample]

    def _wait(self, deadline: float) -> tuple[float | None, bool]:
        """In real time, wait for ``deadline`` (+ the input slack): (the clock then, whether the frame is late
        by more than a frame); off line (None, False)."""
        if not self.realtime:
            return None, False
        behind = False
        due = deadline + self.input_slack_s
        wait = due - self._now_s()
        if wait > 0:
            time.sleep(wait)
        elif -wait > 1.0 / self.fps:
            self.events["late_frames"] += 1
            behind = True
        return self._now_s(), behind

    def _frame_audio(self, k: int, now: float | None) -> np.ndarray:
        """Frame ``k``'s audio samples (zeros where the input has none yet: an underrun, counted)."""
        s, e = timing.frame_sample_bounds(k, self.fps, self.sr)
        s, e = int(s), int(e)
        if self.audio is not None:
            a = self.audio.read(s, e, now)
            if len(a) < e - s and not self.audio.ended_at(s + len(a)):
                self.events["audio_underruns"] += 1
        else:
            a = np.zeros(0, np.float32)
        audio = np.zeros(e - s, np.float32)
        audio[: len(a)] = a[: e - s]
        return audio

    def _inputs(self, k: int, audio: np.ndarray, samples: list, deadline: float) -> list[InputFrame]:
        """Each face's input frame: its fresh capture, else its held face and head (fallbacks counted)."""
        inputs = []
        for st, sample in zip(self.streams, samples):
            if sample is not None:
                face, head, found = st.hold.fresh(sample)
            else:
                if self.video is not None or self.face_feed is not None:
                    self.events["input_frames_reused"] += 1
                face, head, found = st.hold.stale(deadline)
            if not found:
                self.events["face_lost_frames"] += 1
                if st.was_found:
                    self.events["face_lost_events"] += 1
            st.was_found = found
            inputs.append(InputFrame(k, audio, face, head, found))
        return inputs

    def _outputs(self, k: int, inputs: list[InputFrame], poses: list, stage: dict[str, float]) -> list[OutputFrame]:
        """Each face's output frame: the head and the face the avatar shows."""
        outs = []
        for st, inp, pose in zip(self.streams, inputs, poses):
            pose = st.head(pose, inp.head, inp.face_found, k / self.fps)
            shown = inp.face
            mouth = st.mouth.step(inp.audio) if self.speech_mouth else None
            if mouth is not None and not inp.face_found:
                # no face track: the speech moves the mouth, as much as the held face has gone
                shown = np.clip(inp.face + (1.0 - st.hold.remaining) * mouth, 0.0, 1.0).astype(np.float32)
            q64 = np.empty((len(pose), 4))
            self._to_quaternions(np.ascontiguousarray(pose, np.float64), q64)
            quats = q64.astype(np.float32)
            outs.append(OutputFrame(k, k / self.fps, pose, quats, shown, inp.head, inp.face_found, stage, st.index))
        return outs

    def step(self) -> OutputFrame:
        """Produce frame ``self.frames`` from what exists before its deadline (returns the first face's)."""
        k = self.frames
        deadline = (k + 1) / self.fps
        now, behind = self._wait(deadline)
        stage: dict[str, float] = {}
        self._stage = stage
        t_start, c_start = time.perf_counter(), time.thread_time()
        # 1. capture (behind the clock: the camera's frames are dropped, the model still gets this frame's audio)
        if self.video is not None or self.face_feed is not None:
            self._c_input = c_start
            samples = self._capture(deadline, behind)
            t_start, c_start = self._t_input, self._c_input  # reading/decoding the frame is input, not compute
        else:
            samples = [None] * len(self.streams)
        t1 = time.perf_counter()
        stage["capture"] = (t1 - t_start) * 1000.0
        stage["capture_cpu"] = (time.thread_time() - c_start) * 1000.0
        # 2. features: this frame's audio, face and head, with fallbacks
        inputs = self._inputs(k, self._frame_audio(k, now), samples, deadline)
        t2 = time.perf_counter()
        c2 = time.thread_time()
        stage["features"] = (t2 - t1) * 1000.0
        # 3. model
        poses = [st.gen.step(inp.audio, inp.face, inp.head) for st, inp in zip(self.streams, inputs)]
        t3 = time.perf_counter()
        c3 = time.thread_time()
        stage["model"] = (t3 - t2) * 1000.0
        stage["model_cpu"] = (c3 - c2) * 1000.0
        if self.body is not None:  # the person's arms where they are seen (one face)
            poses[0] = self.body.apply(poses[0], deadline)
            stage["body_mix"] = (time.perf_counter() - t3) * 1000.0
        # 4. output: the head and the face the avatar shows
        outs = self._outputs(k, inputs, poses, stage)
        stage["total"] = (time.perf_counter() - t_start) * 1000.0  # pose + blendshapes ready (sinks see this)
        for out in outs:
            for sink in self.sinks:
                t = time.perf_counter()
                sink.write(out)
                self.timings.add_sink(sink_label(sink), (time.perf_counter() - t) * 1000.0)
        for st, out in zip(self.streams, outs):
            st.last = out
        t4 = time.perf_counter()
        stage["output"] = (t4 - t3) * 1000.0
        stage["output_cpu"] = (time.thread_time() - c3) * 1000.0
        stage["total"] = (t4 - t_start) * 1000.0
        self.timings.add(stage)
        if self.video is not None:
            self.events["video_frames_skipped"] = int(self.video.skipped)
        self.frames += 1
        return outs[0]

    # ------------------------------------------------------------------ loop
    def run(self, max_frames: int | None = None, on_frame=None) -> str:
        """Step until the input ends, ``max_frames``, :meth:`stop` or Ctrl-C. Returns why it stopped."""
        if self.t0 is None:
            self.start()
        why = "end of input"
        interrupted = False

        def on_sigint(signum, frame) -> None:  # Ctrl-C ends the loop between frames: every sink has the same frames
            nonlocal interrupted
            if interrupted:
                raise KeyboardInterrupt  # a second Ctrl-C: at once
            interrupted = True

        # SIGTERM and SIGHUP too (the command line turns them into an interrupt): raised inside a library call
        # (MediaPipe building an image) the interrupt left a half-made object whose __del__ printed a traceback
        previous: dict = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None)):
                if sig is not None and signal.getsignal(sig) not in (signal.SIG_IGN, None):
                    previous[sig] = signal.signal(sig, on_sigint)
        try:
            while True:
                if interrupted:
                    why = "interrupted"
                    break
                if self._stop:
                    why = "stopped"
                    break
                if max_frames is not None and self.frames >= max_frames:
                    why = "end of input" if self.input_ended() else "frame limit"
                    break
                if self.input_ended():
                    break
                out = self.step()
                if on_frame is not None:
                    on_frame(out)
        except KeyboardInterrupt:
            why = "interrupted"
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        self.stopped_by = why
        return why

    def report(self, warmup: int = 5) -> dict:
        """Frames, latency percentiles per stage (warm-up frames excluded) and event counts."""
        return {
            "frames": self.frames,
            "fps": self.fps,
            "latency_ms": self.timings.summary(skip=warmup),
            "sink_ms": self.timings.sink_summary(skip=warmup),
            "latency_warmup_frames_excluded": min(warmup, max(self.frames - 1, 0)),
            "events": dict(self.events),
            "stopped_by": self.stopped_by,
        }
