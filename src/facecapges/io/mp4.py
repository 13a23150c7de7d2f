"""The project's one MP4 writer: frames (and optionally a speech track) → H.264 + AAC.

Every video the project writes (avatar renders, side-by-side, skeleton animations,
capture overlays) goes through :class:`Mp4Writer`: the ``imageio-ffmpeg`` ffmpeg binary
(no system ffmpeg needed), H.264 ``yuv420p`` with ``+faststart`` (plays in browsers and
every player), CRF quality, and the audio muxed as AAC 128 kb/s with ``-shortest`` (the
video ends with the shorter of frames and audio).

Frames are either BGR ``uint8`` arrays (H, W, 3) — the size is fixed by the first frame,
odd sizes are padded with black to even ones (yuv420p needs them) — or, with
``jpeg=True``, encoded JPEG bytes as the browser renderer produces them. The file
appears whole or not at all: ffmpeg writes ``NAME.part.mp4`` and it is renamed on a
successful :meth:`close`.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np


class Mp4Writer:
    """``with Mp4Writer(path, fps, audio=wav) as w: w.write(frame)`` (module docstring)."""

    def __init__(
        self,
        path: str | Path,
        fps: float,
        audio: str | Path | None = None,
        crf: int = 20,
        jpeg: bool = False,
        preset: str = "veryfast",
    ):
        self.path = Path(path)
        self.fps, self.audio, self.crf, self.jpeg, self.preset = float(fps), audio, int(crf), jpeg, preset
        self.size: tuple[int, int] | None = None  # (width, height) as written
        self.frames = 0
        self._proc: subprocess.Popen[bytes] | None = None
        self._part = self.path.with_name(self.path.stem + ".part" + self.path.suffix)

    def _open(self, input_args: list[str]) -> None:
        import imageio_ffmpeg

        self.path.parent.mkdir(parents=True, exist_ok=True)
        cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-loglevel", "error", *input_args]
        if self.audio is not None:
            cmd += ["-i", str(self.audio), "-map", "0:v", "-map", "1:a", "-c:a", "aac", "-b:a", "128k", "-shortest"]
        if self.jpeg:
            cmd += ["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2"]
        cmd += [
            "-c:v",
            "libx264",
            "-preset",
            self.preset,
            "-crf",
            str(self.crf),
            "-pix_fmt",
            "yuv420p",
            "-movflags",
            "+faststart",
            "-f",
            "mp4",
            str(self._part),
        ]
        self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stderr=subprocess.PIPE)

    def write(self, frame: np.ndarray | bytes) -> None:
        """One frame: BGR uint8 (H, W, 3), or JPEG bytes when ``jpeg=True``."""
        if self.jpeg:
            if self._proc is None:
                self._open(["-f", "image2pipe", "-c:v", "mjpeg", "-framerate", f"{self.fps:g}", "-i", "-"])
            data = bytes(frame)
        else:
            img = np.asarray(frame)
            if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
                raise ValueError(f"a frame must be BGR uint8 (H, W, 3), got {img.dtype} {img.shape}")
            if self._proc is None:
                h, w = img.shape[:2]
                self.size = (w + w % 2, h + h % 2)
                self._open(
                    [
                        "-f",
                        "rawvideo",
                        "-pix_fmt",
                        "bgr24",
                        "-s",
                        f"{self.size[0]}x{self.size[1]}",
                        "-framerate",
                        f"{self.fps:g}",
                        "-i",
                        "-",
                    ]
                )
            assert self.size is not None  # set with the first frame
            w, h = self.size
            if img.shape[:2] != (h, w):
                pad = np.zeros((h, w, 3), np.uint8)
                pad[: min(h, img.shape[0]), : min(w, img.shape[1])] = img[:h, :w]
                img = pad
            data = np.ascontiguousarray(img).tobytes()
        assert self._proc is not None and self._proc.stdin is not None  # opened with the first frame, stdin=PIPE
        try:
            self._proc.stdin.write(data)
        except BrokenPipeError:
            self._fail()
        self.frames += 1

    def _fail(self) -> None:
        err = self._proc.stderr.read().decode(errors="replace").strip() if self._proc and self._proc.stderr else ""
        self.abort()
        raise RuntimeError(f"ffmpeg failed writing {self.path}: {err}")

    def close(self) -> Path:
        """Finish the file; a writer that got no frame is an error."""
        if self._proc is None:
            raise ValueError(f"{self.path}: no frames were written")
        assert self._proc.stdin is not None and self._proc.stderr is not None  # both PIPE
        try:
            self._proc.stdin.close()
        except BrokenPipeError:
            pass
        err = self._proc.stderr.read().decode(errors="replace").strip()
        if self._proc.wait() != 0:
            self._proc = None
            self._part.unlink(missing_ok=True)
            raise RuntimeError(f"ffmpeg failed writing {self.path}: {err}")
        self._proc = None
        self._part.replace(self.path)
        return self.path

    def abort(self) -> None:
        """Stop ffmpeg and leave no partial file."""
        if self._proc is not None:
            if self._proc.poll() is None:
                self._proc.kill()
            self._proc.wait()
            self._proc = None
        self._part.unlink(missing_ok=True)

    def __enter__(self) -> Mp4Writer:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
