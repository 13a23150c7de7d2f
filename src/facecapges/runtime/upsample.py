"""Output at 30/60 Hz between 15 fps model frames: interpolation for VMC and the browser viewer.

The model makes one pose every ``P = 1/fps`` s (66.7 ms at 15 fps). Receivers that
draw only what arrives (most VMC apps, the viewer) show a 15 Hz staircase. An
:class:`Upsampler` sits between the scheduler and those sinks and emits ``n = rate/fps``
frames per model period (``rate`` a multiple of ``fps``: 30 or 60 Hz at 15 fps):

When model frame ``k`` arrives at wall time ``t_k`` it emits, at ``t_k + j·P/n`` for
``j = 0 … n−1``, the blend of the frame shown last (``S``) and frame ``k`` with weight
``(j + 1)/n`` (:func:`blend_frames`): local-joint rotations and the head by quaternion
slerp, face weights linearly, stream time linearly. The last of them *is* frame ``k``.
``S`` is what was shown last (frame ``k−1``, or an intermediate blend if frame ``k``
came early), so the output never jumps.

Added latency: frame ``k`` is fully shown ``(n−1)/n · P`` after it exists instead of at
once — **33.3 ms at 30 Hz, 50.0 ms at 60 Hz** (15 fps model); for any intermediate
motion the delay is the same constant ``(n−1)/n · P`` (a linear ramp is reproduced
exactly, shifted). At ``rate = fps`` (``n = 1``) frames pass through untouched, no delay.

The emitting thread calls the wrapped sinks' ``write`` (VMC sender, viewer feed: both
thread-safe); :meth:`Upsampler.close` shows the last frame, stops the thread and closes
them.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from facecapges import rotations as rot
from facecapges.runtime.frames import OutputFrame


def substeps(rate_hz: float, fps: float) -> int:
    """``rate_hz / fps`` as an integer ≥ 1; ValueError if ``rate_hz`` is not a multiple of ``fps``."""
    n = rate_hz / fps
    if rate_hz <= 0 or n < 1 - 1e-9 or abs(n - round(n)) > 1e-6:
        raise ValueError(f"output rate {rate_hz:g} Hz must be a multiple of the model rate {fps:g} fps")
    return int(round(n))


def added_latency_s(rate_hz: float, fps: float) -> float:
    """The constant delay interpolation adds, ``(n − 1)/n · 1/fps`` (module docstring)."""
    n = substeps(rate_hz, fps)
    return (n - 1) / n / fps


def blend_frames(a: OutputFrame, b: OutputFrame, t: float) -> OutputFrame:
    """Frame between ``a`` (t = 0) and ``b`` (t = 1): slerp rotations, lerp weights and time."""
    if t >= 1.0:
        return b
    q = rot.quaternion_slerp(np.asarray(a.quats, np.float64), np.asarray(b.quats, np.float64), t)
    ha = rot.matrix_to_quaternion(rot.rot6d_to_matrix(np.asarray(a.head, np.float64)))
    hb = rot.matrix_to_quaternion(rot.rot6d_to_matrix(np.asarray(b.head, np.float64)))
    head = rot.matrix_to_rot6d(rot.quaternion_to_matrix(rot.quaternion_slerp(ha, hb, t)))
    face = (1.0 - t) * np.asarray(a.face, np.float64) + t * np.asarray(b.face, np.float64)
    pose = rot.matrix_to_rot6d(rot.quaternion_to_matrix(q))
    return OutputFrame(
        b.index,
        (1.0 - t) * a.time_s + t * b.time_s,
        pose.astype(np.float32),
        q.astype(np.float32),
        face.astype(np.float32),
        head.astype(np.float32),
        b.face_found,
        dict(b.latency_ms),
    )


class Upsampler:
    """Sink wrapper: re-emits model frames to ``sinks`` at ``rate_hz``, interpolated (module docstring)."""

    def __init__(self, sinks, fps: float, rate_hz: float):
        self.sinks = list(sinks)
        self.fps = float(fps)
        self.n = substeps(rate_hz, fps)
        self.rate_hz = float(rate_hz)
        self.period_s = 1.0 / self.fps
        self.emitted = 0
        self._shown: OutputFrame | None = None  # what the sinks got last
        self._target: OutputFrame | None = None  # newest model frame
        self._start: OutputFrame | None = None  # the segment's start (what was shown when it began)
        self._t0 = 0.0
        self._j = 0  # next substep of the segment
        self._cond = threading.Condition()
        self._stop = False
        self._closed = False
        self._thread = None
        if self.n > 1:
            self._thread = threading.Thread(target=self._run, name="upsample", daemon=True)
            self._thread.start()

    @property
    def added_latency_ms(self) -> float:
        return added_latency_s(self.rate_hz, self.fps) * 1000.0

    def _emit(self, fr: OutputFrame) -> None:
        for s in self.sinks:
            s.write(fr)
        self.emitted += 1

    def write(self, out: OutputFrame) -> None:
        if self.n == 1:
            self._emit(out)
            return
        with self._cond:
            self._start = self._shown
            self._target = out
            self._t0 = time.monotonic()
            self._j = 0
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._stop and (self._target is None or self._j >= self.n):
                    self._cond.wait()
                if self._stop:
                    return
                due = self._t0 + self._j * self.period_s / self.n
                wait = due - time.monotonic()
                if wait > 0:
                    self._cond.wait(wait)  # a new frame (or close) may cut the wait short
                    continue
                j, start, target = self._j, self._start, self._target
                assert target is not None  # the wait above ends only with a frame
                self._j = self.n if start is None else self._j + 1  # the very first frame: shown once
            fr = target if start is None else blend_frames(start, target, (j + 1) / self.n)
            with self._cond:
                if target is self._target:  # not superseded while blending
                    self._shown = fr
            self._emit(fr)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        with self._cond:
            self._stop = True
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(timeout=2)
            if self._target is not None and self._shown is not self._target:
                self._emit(self._target)  # end on the last model frame
        for s in self.sinks:
            s.close()
