"""Output at 30/60 Hz between 15 fps model frames: interpolation for VMC and the browser viewer.

The model makes one pose every ``P = 1/fps`` s (66.7 ms at 15 fps). Receivers that
draw only what arrives (most VMC apps, the viewer) show a 15 Hz staircase. An
:class:`Upsampler` sits between the scheduler and those sinks and sends at ``rate``
Hz (a multiple of ``fps``: 30 or 60 Hz at 15 fps, ``n = rate/fps`` frames per period)
**on its own clock**: tick ``k`` is due at ``t0 + k/rate``, an absolute schedule that
does not drift, whatever the model's frames do — late, early, bursty, or none at all
(an idle generator, a changed intensity: it sends from the latest pose it has, whatever
produced it).

At each tick it sends the blend (:func:`blend_frames`) of the frame shown when the
newest model frame ``k`` arrived (``S``) and frame ``k``, with weight
``min(1, (t − t_k)/P + 1/n)`` (``t`` the tick's due time, ``t_k`` the arrival):
local-joint rotations and the head by quaternion slerp, face weights linearly. Frame
``k`` is fully shown ``(n−1)/n · P`` after it arrives, and held after that until the
next one comes; the output never jumps (``S`` is what was on screen). The stream time
sent (``/VMC/Ext/T``) advances with the clock: every tick at least one tick (``1/rate``)
after the last one — the newest model frame's time plus the time since it arrived, minus
the added latency, when that is later (a model frame that came late or early moves it
less or more, never back, never repeated: receivers that order or interpolate by it need
it strictly increasing).

Added latency: **33.3 ms at 30 Hz, 50.0 ms at 60 Hz** (15 fps model), ``(n−1)/n · P``;
at ``rate = fps`` (``n = 1``) frames pass through untouched, no delay.

A tick that comes late (the machine busy) is sent at once and the schedule kept, so the
delivered rate stays the asked one; only a lag above :data:`MAX_LAG_S` (a stall) drops
the missed ticks and restarts the schedule (counted in ``resyncs``).
Between ticks the thread sleeps once, to the next tick's due time (no lock, no condition: the scheduler's
:meth:`Upsampler.write` hands a frame over under a lock the tick takes once).
:meth:`Upsampler.close` stops the thread (when its sleep ends: at most one tick), shows the last frame and closes
the sinks.

Between model frames, in each sink's own form
---------------------------------------------
A sink may interpolate in its own form of a frame (what it sends) instead of in the
:class:`OutputFrame`'s: it has ``model_frame(out)`` (a model frame in its form, computed once,
at the first tick after the frame came), ``between(a, b, w)`` (``w`` of the way from ``a``
to ``b``) and ``send(frame, time_s)``. The upsampler keeps, per sink, what it showed and the
start and end of its blend, and calls those from its thread; a model frame is sent as
``model_frame`` gives it (the same bytes as the sink's ``write`` of that frame). The VMC sender
(:class:`~facecapges.runtime.outputs.vmc.VmcSender`) is one: a tick slerps its bones' Unity
quaternions and lerps its clips' weights and packs them (compiled: :mod:`.vmc_kernels`), where
converting a blended :class:`OutputFrame` cost three times as much as the NumPy form of that (issue 36). Any other sink (``write(out)``) gets
:func:`blend_frames` of the frames (:class:`FrameBlend`). Slerp commutes with the fixed rest
frames on both sides (``Wp⁻¹ · Q · Wb``), so a bone that carries one BEAT joint moves the same
in either form; a bone that carries several (folded joints: Head ← Neck1, a proximal finger
bone ← its metacarpal) and the VRM preset clips (non-linear in the ARKit weights) take a slightly
different path between the same two model frames: 0.06° at most on the BEAT take (15 fps,
ticks at 30 Hz), clip weights up to 0.06 apart mid-way — never outside the two frames' values.
The browser viewer interpolates itself (:mod:`.viewer`): it is not behind the upsampler.
"""

from __future__ import annotations

import functools
import threading
import time
from array import array
from dataclasses import replace

import numpy as np

from facecapges import rotations as rot
from facecapges.runtime.frames import OutputFrame
from facecapges.runtime.os_threads import name_os_thread


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


def _key(head: np.ndarray) -> tuple[str, bytes]:
    h = np.asarray(head)
    return h.dtype.str, h.tobytes()


@functools.lru_cache(maxsize=8)
def _head_quaternion(dtype: str, head: bytes) -> np.ndarray:
    """A frame's head rot6d (its dtype and bytes) as a (1, 4) quaternion: a frame is the end of one blend and the
    start of the next, so each head is converted once (row by row the same numbers as both in one call)."""
    h = np.frombuffer(head, dtype).reshape(1, 6).astype(np.float64)
    q = rot.matrix_to_quaternion(rot.rot6d_to_matrix(h))
    q.flags.writeable = False
    return q


def blend_frames(a: OutputFrame, b: OutputFrame, t: float) -> OutputFrame:
    """Frame between ``a`` (t = 0) and ``b`` (t = 1): slerp rotations, lerp weights and time."""
    if t >= 1.0:
        return b
    # the joints and the head as one (J + 1)-row batch: the same row-wise arithmetic in half the calls (a tick
    # is mostly call overhead on 48 small rows: issue 36)
    J = len(a.quats)
    q0 = np.concatenate([np.asarray(a.quats, np.float64), _head_quaternion(*_key(a.head))])
    q1 = np.concatenate([np.asarray(b.quats, np.float64), _head_quaternion(*_key(b.head))])
    qs = rot.quaternion_slerp(q0, q1, t)
    rows = rot.quaternion_to_rot6d(qs)  # matrix_to_rot6d(quaternion_to_matrix(qs)) to the bit, in fewer calls
    q, pose, head = qs[:J], rows[:J], rows[J]
    face = (1.0 - t) * np.asarray(a.face, np.float64) + t * np.asarray(b.face, np.float64)
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


MAX_LAG_S = 0.25  # a tick this late (a stall) restarts the schedule instead of catching up


class FrameBlend:
    """A sink that takes :class:`OutputFrame` s (``write``), as the upsampler drives it: its own form of a
    model frame is the frame itself, the ticks between are :func:`blend_frames` (module docstring)."""

    def __init__(self, sink):
        self.sink = sink

    def model_frame(self, out: OutputFrame) -> OutputFrame:
        return out

    def between(self, a: OutputFrame, b: OutputFrame, w: float) -> OutputFrame:
        return blend_frames(a, b, w)

    def send(self, fr: OutputFrame, time_s: float) -> None:
        self.sink.write(fr if fr.time_s == time_s else replace(fr, time_s=time_s))


class _Feed:
    """One sink's side of the clock, in its own form (module docstring): what it showed last, where the
    blend to the newest model frame starts, that frame (converted at the first tick after it came)."""

    __slots__ = ("own", "shown", "start", "target")

    def __init__(self, sink):
        self.own = sink if hasattr(sink, "between") else FrameBlend(sink)
        self.shown = self.start = self.target = None


class Upsampler:
    """Sink wrapper: sends the latest model frame to ``sinks`` at ``rate_hz`` on its own clock (module docstring)."""

    def __init__(self, sinks, fps: float, rate_hz: float):
        self.sinks = list(sinks)
        self._feeds = [_Feed(s) for s in self.sinks]
        self.fps = float(fps)
        self.n = substeps(rate_hz, fps)
        self.rate_hz = float(rate_hz)
        self.period_s = 1.0 / self.fps
        self.emitted = 0
        self.late = 0  # ticks sent more than one output period after they were due
        self.resyncs = 0
        self.tick_ms = array("d")  # each tick's blend + send (ms, the emitting thread's work)
        self.tick_cpu_ms = array("d")  # the same in CPU time of that thread
        self._target: OutputFrame | None = None  # newest model frame
        self._t0 = 0.0  # its arrival time
        self._sent = False  # a tick was sent
        self._blends = False  # the newest model frame came after a tick: its blend starts from what was shown
        self._last_time = -np.inf  # the stream time sent last
        self._reached: OutputFrame | None = None  # the model frame shown in full last
        self._lock = threading.Lock()  # the hand-over: write (the scheduler) against a tick's blend
        self._started = threading.Event()  # the first model frame came (or close: nothing to tick)
        self._stop = False
        self._closed = False
        self._thread = None
        if self.n > 1:
            self._thread = threading.Thread(target=self._run, name="upsample", daemon=True)
            self._thread.start()

    def add_sink(self, sink) -> None:
        """One more sink fed from the same clock (it starts on the newest model frame)."""
        with self._lock:
            self.sinks.append(sink)
            self._feeds.append(_Feed(sink))

    @property
    def added_latency_ms(self) -> float:
        return added_latency_s(self.rate_hz, self.fps) * 1000.0

    def _emit(self, fr: OutputFrame) -> None:
        for s in list(self.sinks):
            s.write(fr)
        self.emitted += 1

    def write(self, out: OutputFrame) -> None:
        if self.n == 1:
            self._emit(out)
            return
        with self._lock:
            self._blends = self._sent
            for f in self._feeds:
                f.start, f.target = f.shown, None
            self._target = out
            self._t0 = time.monotonic()
        if not self._started.is_set():  # the clock starts; later frames wait for their tick (never a wake-up)
            self._started.set()

    def _tick(self, due: float) -> None:
        """Tick ``due``: each sink's blend towards the newest model frame and the stream time (module docstring),
        computed and recorded as shown in one hold of the lock (a frame written meanwhile would start from what
        was shown before this tick, and the output would step back), then sent."""
        with self._lock:
            target, t0 = self._target, self._t0
            assert target is not None  # ticks start with the first frame
            # a late tick (due before the frame came: the machine was busy) shows where it was, never behind it
            w = min(1.0, max(0.0, (due - t0) / self.period_s + 1.0 / self.n)) if self._blends else 1.0
            self._reached = target if w >= 1.0 else None
            t = target.time_s + (due - t0) - (self.n - 1) / self.n * self.period_s
            t = max(t, self._last_time + 1.0 / self.rate_hz, -np.inf if self._blends else target.time_s)
            self._last_time = t
            self._sent = True
            sends = []
            for f in self._feeds:
                if f.target is None:  # each sink's own form of a model frame, once
                    f.target = f.own.model_frame(target)
                f.shown = f.target if w >= 1.0 or f.start is None else f.own.between(f.start, f.target, w)
                sends.append((f.own, f.shown))
        for own, shown in sends:
            own.send(shown, t)
        self.emitted += 1

    def _run(self) -> None:
        """The clock: one sleep to each tick's due time (``time.sleep``: one absolute ``clock_nanosleep``, the GIL
        released), then the tick. No lock or condition between ticks (issue 36: a ``Condition.wait`` per tick, its
        lock made and its waiter list, cost more CPU than the sleep); ``close`` is seen when the sleep ends (at most
        one tick later)."""
        name_os_thread("upsample")
        self._started.wait()
        tick = 1.0 / self.rate_hz
        due = time.monotonic()
        monotonic, sleep, perf_counter, thread_time = time.monotonic, time.sleep, time.perf_counter, time.thread_time
        tick_ms, tick_cpu_ms = self.tick_ms.append, self.tick_cpu_ms.append
        while not self._stop:
            now = monotonic()
            if due - now > 0:
                sleep(due - now)
                continue
            if now - due > MAX_LAG_S:  # a stall: drop the missed ticks
                self.resyncs += 1
                due = now
            elif now - due > tick:
                self.late += 1
            t_work, c_work = perf_counter(), thread_time()
            self._tick(due)
            tick_ms((perf_counter() - t_work) * 1000.0)
            tick_cpu_ms((thread_time() - c_work) * 1000.0)
            due += tick

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._stop = True
        self._started.set()  # a clock that never started ends at once
        if self._thread is not None:
            self._thread.join(timeout=2)
            target = self._target
            if target is not None and self._reached is not target:  # end on the last model frame
                t = max(target.time_s, self._last_time + 1.0 / self.rate_hz)
                for f in self._feeds:
                    f.own.send(f.target if f.target is not None else f.own.model_frame(target), t)
                self.emitted += 1
        for s in self.sinks:
            s.close()
