"""Input sources of the runtime: video frames, face feeds and audio, on one stream clock.

Each satisfies its protocol of :mod:`..interfaces` (``VideoSource``, ``FaceFeed``,
``AudioSource``).

Stream time ``t`` (seconds) starts at 0 when a session starts. The scheduler asks each
source only for what exists *before* a frame's deadline (:mod:`..scheduler`): sources
never hand out data from the future, and they never block waiting for it.

Visual sources (one per session)
--------------------------------
* :class:`FileVideo` — a video file read with OpenCV (frame ``i`` at ``i / video_fps``),
  optionally with RGB-D depth frames from a directory (frame ``i`` ↔ the ``i``-th depth
  file, millimetres, read by :mod:`facecapges.capture.depth`) and optionally looped;
  ``decode_threads`` sets FFmpeg's decoding threads (one for a file played in real time).
  :meth:`~FileVideo.next_frame` returns the newest unread frame before the deadline
  and *skips* older ones (``grab``: FFmpeg still decodes each, later frames are predicted
  from it, but not its conversion to BGR nor the copy out): a live system processes the
  freshest frame, and MediaPipe's tracker copes with the gap. Skips are counted.
* :class:`CameraVideo` — an OpenCV camera read by a thread that keeps the last three
  frames stamped with the stream clock; a camera that cannot open is a
  :class:`~facecapges.errors.UserError` naming it.
* :class:`LiveLinkFace` — the iPhone Live Link Face app (:mod:`.livelink`): no capture
  stage, the phone sends 52 blendshapes and head angles.

Audio sources
-------------
* :class:`FileAudio` — a file's audio track (or a WAV) via
  :func:`facecapges.io.audio.load_audio`, 16 kHz mono; in ``realtime`` mode only the
  samples up to the wall clock are available (a file paced like a microphone);
  optionally looped with the video (period = the audio's duration).
* :class:`MicAudio` — a sounddevice input stream (16 kHz mono, float32) into a ring
  buffer of 10 s; sample 0 = the first sample after the session starts. A microphone
  that cannot open (or a missing PortAudio library) is a :class:`UserError` naming
  the device.

:meth:`read` returns the samples ``[start, end)`` that exist by stream time ``now``;
fewer than asked for means an underrun (live) or the end of a file (``ended_at``).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from facecapges import timing
from facecapges.errors import UserError, file_error
from facecapges.runtime.os_threads import name_os_thread


@dataclass
class VideoFrame:
    ts_s: float
    image: np.ndarray  # BGR (H, W, 3) uint8
    depth_mm: np.ndarray | None = None


@dataclass
class FaceSample:
    ts_s: float
    weights52: np.ndarray
    head_rot6d: np.ndarray
    face_found: bool = True


# ------------------------------------------------------------------ video
class FileVideo:
    """Frames of a video file on the stream clock (see module docstring)."""

    is_live = False

    def __init__(
        self,
        path: str | Path,
        loop_period_s: float | None = None,
        depth_dir=None,
        intrinsics=None,
        decode_threads: int | None = None,
    ):
        from facecapges.capture.video import open_source

        p = Path(path)
        if not p.is_file():
            raise file_error(p, "video not found")
        self.path = p
        self.decode_threads = decode_threads  # FFmpeg's threads (capture.video.open_file); None: its own choice
        self._src = open_source(str(p), decode_threads)
        self.fps = self._src.fps
        self.width, self.height = self._src.width, self._src.height
        self.n_frames = self._src.n_frames
        self.loop_period_s = loop_period_s
        self.depth_files, self.intrinsics = None, None
        if depth_dir is not None or intrinsics is not None:
            from facecapges.capture.depth import check_depth_inputs

            self.depth_files, self.intrinsics = check_depth_inputs(depth_dir, intrinsics)
        self._i = 0  # index (within the current loop) of the next frame in the file
        self._offset = 0.0  # stream time of the current loop's start
        self.ended = False
        self.skipped = 0
        self.loops = 0

    @property
    def name(self) -> str:
        return str(self.path)

    def start(self, t0: float) -> None:
        """A file's frames are stamped by their index, not the wall clock: nothing to start."""

    def _ts(self, i: int) -> float:
        return self._offset + i / self.fps

    def _restart(self) -> bool:
        if self.loop_period_s is None:
            self.ended = True
            return False
        self._src.cap.release()
        from facecapges.capture.video import open_file

        self._src.cap = open_file(self.path, self.decode_threads)
        self._offset += self.loop_period_s
        self._i = 0
        self.loops += 1
        return True

    def _in_loop(self, i: int) -> bool:
        return self.loop_period_s is None or i / self.fps < self.loop_period_s - 1e-9

    def next_frame(self, deadline_s: float) -> VideoFrame | None:
        """The newest unread frame with time < ``deadline_s`` (older unread ones skipped), or None."""
        while not self.ended:
            if not self._in_loop(self._i):
                assert self.loop_period_s is not None  # out of the loop only when there is one
                if self._offset + self.loop_period_s >= deadline_s or not self._restart():
                    return None
                continue
            if self._ts(self._i) >= deadline_s:
                return None
            # is the frame after this one also due? then skip this one: decoded (grab), not converted
            if (
                self._in_loop(self._i + 1)
                and self._ts(self._i + 1) < deadline_s
                and (self.n_frames is None or self._i + 1 < self.n_frames)
            ):
                if not self._src.cap.grab():
                    if not self._restart():
                        return None
                    continue
                self._i += 1
                self.skipped += 1
                continue
            ok, img = self._src.cap.read()
            if not ok or img is None:
                if not self._restart():
                    return None
                continue
            i = self._i
            self._i += 1
            depth = None
            if self.depth_files is not None and i < len(self.depth_files):
                from facecapges.capture.depth import read_depth

                depth = read_depth(self.depth_files[i])
            return VideoFrame(self._ts(i), img, depth)
        return None

    def drop(self, deadline_s: float) -> int:
        """Read past every unread frame with time < ``deadline_s`` (``grab``: decoded, not converted); how many
        (the scheduler, behind the clock, drops them)."""
        n = 0
        while not self.ended:
            if not self._in_loop(self._i):
                assert self.loop_period_s is not None  # out of the loop only when there is one
                if self._offset + self.loop_period_s >= deadline_s or not self._restart():
                    break
                continue
            if self._ts(self._i) >= deadline_s:
                break
            if not self._src.cap.grab():
                if not self._restart():
                    break
                continue
            self._i += 1
            n += 1
        return n

    def close(self) -> None:
        self._src.close()


class CameraVideo:
    """An OpenCV camera read by a background thread (see module docstring)."""

    is_live = True

    def __init__(self, index: int):
        import cv2

        from facecapges.capture.video import open_source

        self.index = index
        level = cv2.utils.logging.getLogLevel()
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # our message says it in one line
        try:
            self._src = open_source(str(index))
        except UserError as exc:
            raise UserError(f"{exc}; check the device index (--camera) and that no other program uses it") from None
        finally:
            cv2.utils.logging.setLogLevel(level)
        self.fps = self._src.fps
        self.width, self.height = self._src.width, self._src.height
        self.ended = False
        self.skipped = 0
        self._frames: deque[tuple[int, float, np.ndarray]] = deque(maxlen=3)
        self._seq = 0
        self._last_seq = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._t0: float | None = None
        self._thread: threading.Thread | None = None

    @property
    def name(self) -> str:
        return f"camera {self.index}"

    def start(self, t0: float) -> None:
        self._t0 = t0
        self._thread = threading.Thread(target=self._run, name="camera", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        name_os_thread("camera")
        fails = 0
        while not self._stop.is_set():
            ok, img = self._src.cap.read()
            if not ok or img is None:
                fails += 1
                if fails > 50:
                    self.ended = True
                    return
                time.sleep(0.02)
                continue
            fails = 0
            assert self._t0 is not None  # set by start(), before this thread runs
            ts = time.monotonic() - self._t0
            with self._lock:
                self._seq += 1
                self._frames.append((self._seq, ts, img))

    def next_frame(self, deadline_s: float) -> VideoFrame | None:
        with self._lock:
            due = [f for f in self._frames if f[1] < deadline_s and f[0] > self._last_seq]
            if not due:
                return None
            seq, ts, img = due[-1]
            self.skipped += seq - self._last_seq - 1 if self._last_seq else 0
            self._last_seq = seq
        return VideoFrame(ts, img)

    def drop(self, deadline_s: float) -> int:
        """Mark every frame captured before ``deadline_s`` as read, unprocessed; how many."""
        with self._lock:
            due = [f[0] for f in self._frames if f[1] < deadline_s and f[0] > self._last_seq]
            if not due:
                return 0
            n = due[-1] - self._last_seq if self._last_seq else len(due)
            self._last_seq = due[-1]
        return n

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2)
        self._src.close()


class LiveLinkFace:
    """Face + head from the Live Link Face app (no capture stage)."""

    is_live = True

    def __init__(self, port: int, host: str = "127.0.0.1"):
        from facecapges.runtime.inputs.livelink import LiveLinkReceiver

        self.receiver = LiveLinkReceiver(port, host)
        self.name = f"Live Link UDP {self.receiver.address[0]}:{self.receiver.address[1]}"
        self.ended = False
        self._last_seq = 0
        self._t0 = time.monotonic()

    def start(self, t0: float) -> None:
        self._t0 = t0

    def next_face(self, deadline_s: float) -> FaceSample | None:
        seq, fr = self.receiver.latest()
        if fr is None or seq == self._last_seq:
            return None
        ts = fr.received_s - self._t0
        if ts >= deadline_s:  # arrived after this frame's deadline: it belongs to the next frame
            return None
        self._last_seq = seq
        return FaceSample(ts, fr.weights52, fr.head_rot6d, True)

    def close(self) -> None:
        self.receiver.close()


# ------------------------------------------------------------------ audio
class FileAudio:
    """A file's audio at 16 kHz mono (see module docstring)."""

    def __init__(self, path: str | Path, sr: int = timing.AUDIO_SR, realtime: bool = False, loop: bool = False):
        from facecapges.io.audio import load_audio

        p = Path(path)
        try:
            self.samples = load_audio(p, sr)
        except UserError as exc:
            if p.suffix.lower() in (".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v"):
                raise UserError(f"{exc} — the video needs an audio track, or pass --audio FILE") from None
            raise
        self.path, self.sr, self.realtime, self.loop = p, sr, realtime, loop
        self.name = str(p)
        self._t0: float | None = None

    @property
    def duration_s(self) -> float:
        return len(self.samples) / self.sr

    def start(self, t0: float) -> None:
        self._t0 = t0

    def ended_at(self, sample: int) -> bool:
        return not self.loop and sample >= len(self.samples)

    def read(self, start: int, end: int, now_s: float | None = None) -> np.ndarray:
        if now_s is not None and self.realtime:
            end = min(end, int(np.floor(now_s * self.sr + 1e-6)))
        end = max(end, start)
        if not self.loop:
            return self.samples[start : min(end, len(self.samples))]
        idx = np.arange(start, end) % len(self.samples)
        return self.samples[idx]

    def close(self) -> None:
        pass


def check_mic(device: str | int | None, sr: int = timing.AUDIO_SR) -> tuple[str, str | int | None]:
    """(label, sounddevice device) of a microphone that can record mono ``sr`` Hz; a UserError if there is none.

    Cheap (no stream is opened): ``live`` calls it before the model loads."""
    label = "the default microphone" if device in (None, "", "default") else f"microphone {device!r}"
    try:
        import sounddevice as sd
    except OSError as exc:  # PortAudio missing
        raise UserError(f"{label} cannot be opened: {exc} (run scripts/setup-runtime.sh)") from None
    dev = None if device in (None, "", "default") else (int(device) if str(device).isdigit() else str(device))
    try:
        sd.check_input_settings(device=dev, channels=1, samplerate=sr, dtype="float32")
    except Exception as exc:  # noqa: BLE001 - PortAudio raises many types; all mean "cannot open"
        raise UserError(
            f"{label} cannot be opened ({str(exc).strip() or type(exc).__name__}); list devices with "
            f"`python -m sounddevice`"
        ) from None
    return label, dev


class MicAudio:
    """A microphone through sounddevice (see module docstring)."""

    def __init__(self, device: str | int | None, sr: int = timing.AUDIO_SR, capacity_s: float = 10.0):
        self.sr = sr
        self.device = device
        label, dev = check_mic(device, sr)
        self.name = label
        import sounddevice as sd

        self._buf = np.zeros(int(capacity_s * sr), np.float32)
        self.written = 0
        self.overflows = 0
        self._lock = threading.Lock()
        self._t0: float | None = None
        try:
            self.stream = sd.InputStream(
                device=dev,
                channels=1,
                samplerate=sr,
                dtype="float32",
                blocksize=int(sr * 0.02),
                callback=self._callback,
            )
        except Exception as exc:  # noqa: BLE001 - PortAudio raises many types; all mean "cannot open"
            raise UserError(
                f"{label} cannot be opened ({str(exc).strip() or type(exc).__name__}); list devices with "
                f"`python -m sounddevice`"
            ) from None
        self.latency_s = float(getattr(self.stream, "latency", 0.0) or 0.0)

    def _callback(self, indata, frames, time_info, status) -> None:
        if status:
            self.overflows += 1
        x = indata[:, 0]
        with self._lock:
            n = len(self._buf)
            i = self.written % n
            k = min(len(x), n - i)
            self._buf[i : i + k] = x[:k]
            self._buf[: len(x) - k] = x[k:]
            self.written += len(x)

    def start(self, t0: float) -> None:
        self._t0 = t0
        self.stream.start()

    def ended_at(self, sample: int) -> bool:
        return False

    def read(self, start: int, end: int, now_s: float | None = None) -> np.ndarray:
        with self._lock:
            n = len(self._buf)
            lo = max(start, self.written - n)
            hi = min(end, self.written)
            if hi <= start:
                return np.zeros(0, np.float32)
            out = np.zeros(hi - start, np.float32)  # samples older than the ring are gone: zeros
            if hi > lo:
                idx = np.arange(lo, hi) % n
                out[lo - start :] = self._buf[idx]
            return out

    def close(self) -> None:
        try:
            self.stream.stop()
            self.stream.close()
        except Exception:  # noqa: BLE001 - closing a broken device must not mask the real error
            pass
