"""The server's model in a process of its own: :class:`ModelProcess`.

``serve`` runs its event loop (WebSocket I/O, JSON) in one thread. Stepped in a thread
of the same process, the eager batched kernel
(:class:`~facecapges.network.batched.BatchedNetworkStreams`) gives up and takes back
the GIL at each of its few hundred tensor operations, and the busy event loop keeps
it waiting at each one: measured on this 2-core machine, 80 clients, one run (load
17–24): a worker thread managed 9 ticks in 6 s, the same kernel inline in the event
loop 44, and the kernel in this separate process never waits for the loop at all. So
the kernel runs here, in a child process (``spawn``), and the server talks to it over
a pipe; the inputs and outputs of a tick (poses as rot6d and as the quaternions the
``pose`` messages carry, converted here, beside the kernel, by a compiled loop that gives NumPy's
``rot6d_to_quaternion`` to the bit: :func:`facecapges.rotations_compiled.checked_rot6d_to_quaternions`) travel through blocks of
shared memory (the standard library's ``multiprocessing.shared_memory``, seen as NumPy
arrays on both sides), so a tick costs one small message each way. The server makes the
blocks and unlinks them when it stops, also after the child crashed; should the server
itself be killed, multiprocessing's resource tracker unlinks them.

Neither side imports torch for a matching style: the child sets torch's threads only
when the style's own loading imported it (a network style;
:func:`facecapges.engine.threads.limit_threads`: the rule ``live`` follows). Measured
(2026-12-03, load 8–10, ``facecapges serve`` start to ``ready:``, three runs each,
alternating): 9.7 s median with torch's shared tensors, 2.1 s without (at load 1: 5.6 and 1.1 s); the model
process's memory (RSS) 320 → 73 MB, the server's 303 → 59 MB (docs/performance.md).

The server's event loop neither blocks on nor hands off to a thread for a tick: it
submits the inputs (:meth:`~ModelProcess.submit`), waits for the pipe to become readable
(``loop.add_reader`` on :meth:`~ModelProcess.fileno`) while it keeps receiving, then
collects the outputs (:meth:`~ModelProcess.collect`). Measured (2026-12-02, matching style,
load 7–9, 30 and 40 clients): with a worker thread waiting for the pipe instead, as before,
a tick's model time at p99 was 115 ms of which 24 ms inside the child — the rest was that
thread waiting for the GIL held by the busy event loop. Opening, closing and intensity
changes of one tick travel as one :meth:`~ModelProcess.sync` message, not one round trip
per stream (40 streams connecting at once held the event loop 190 ms). Both designs served
alternately, 30 clients, four 5-s trials each (load 14–16): median p99 round trip 413 ms
against 1,513 ms, frames lost 1,032 against 3,092, CPU per returned frame (server and
model process) 0.40–0.48 ms against 0.52–0.83 ms.

A network style's child is forked from a *forkserver* that has imported torch and the network's modules once
(:func:`_context`): the spawned interpreter's torch import was 4–7 s of every such start (each test server of a
network style, each ``serve`` reload), and a fork of that clean process takes a fraction of a second. The
forkserver is started by multiprocessing as a new interpreter (not a fork of the server, whose event loop and
pool threads must not be forked) with ``OPENBLAS_NUM_THREADS=1`` in its environment only, so it runs one thread
when it forks (NumPy's OpenBLAS would otherwise start a pool thread on import; torch starts none until it
computes); the child then sets its threads as before (:func:`~facecapges.engine.threads.limit_threads`). A
matching style's child is still spawned: it must not get torch (the memory figures above).

Before it answers ``ready`` the child runs a tick of 1 and one of 32 streams on slots it closes again
(:func:`warm_engine`): the engines import some modules at their first tick of a size (scipy's FFT from 16 streams
on, ~190 modules with it), which took seconds on a busy machine while the first streams' frames were dropped.

It offers what the server uses: :attr:`open_slots`, :meth:`sync` (opening, closing and
dialling streams), the split :meth:`submit` / :meth:`collect`, and :meth:`step` (the two
together, the generator's own signature and result). Not thread-safe: one caller
at a time (the server's event loop).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
from collections.abc import Sequence
from multiprocessing import shared_memory

import numpy as np

from facecapges import rotations as rot
from facecapges import timing
from facecapges.arkit import N_BLENDSHAPES
from facecapges.engine.inputs import pack_audio
from facecapges.skeleton import N_JOINTS

_BLOCKS = ("audio", "face", "head", "pose", "quat")  # the order of the shared blocks, both sides

# what a network style's forkserver imports once (module docs): torch and what unpickling and stepping the style
# import, so that a forked child imports nothing heavy
FORKSERVER_PRELOAD = [
    "torch",
    "facecapges.network.network",
    "facecapges.network.batched",
    "facecapges.network.style",
    "facecapges.serving.model_process",
]


def _context(checkpoint):
    """The start method of the style's model process: a forkserver with torch imported for a network style,
    ``spawn`` for any other (module docs)."""
    if getattr(checkpoint, "engine", None) != "network":
        return multiprocessing.get_context("spawn")
    from multiprocessing import forkserver

    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(FORKSERVER_PRELOAD)  # no effect once it runs: it has these already
    before = os.environ.get("OPENBLAS_NUM_THREADS")
    os.environ["OPENBLAS_NUM_THREADS"] = "1"  # the forkserver's environment only: one thread when it forks
    # started with SIGINT ignored, as the spawned child is (ModelProcess): its children ignore it from their start
    main = threading.current_thread() is threading.main_thread()
    before_int = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
    try:
        forkserver.ensure_running()
    finally:
        if main and before_int is not None:
            signal.signal(signal.SIGINT, before_int)
        if before is None:
            del os.environ["OPENBLAS_NUM_THREADS"]
        else:
            os.environ["OPENBLAS_NUM_THREADS"] = before
    return ctx


def _layouts(max_rows: int, samples_per_frame: int) -> list[tuple[tuple[int, ...], type]]:
    """Shape and dtype of each shared block (:data:`_BLOCKS`): a tick's inputs and outputs."""
    return [
        ((max_rows, samples_per_frame), np.float32),
        ((max_rows, N_BLENDSHAPES), np.float32),
        ((max_rows, 6), np.float32),
        ((max_rows, N_JOINTS, 6), np.float32),
        ((max_rows, N_JOINTS, 4), np.float64),
    ]


def _view(block: shared_memory.SharedMemory, shape: tuple[int, ...], dtype: type) -> np.ndarray:
    return np.ndarray(shape, dtype, buffer=block.buf)


def _serve_model(conn, checkpoint, threads: int, names: list[str], layouts) -> None:
    """The child process: the style's batched generator, driven by messages on ``conn``; the tick's
    arrays are the server's shared blocks ``names`` (shapes and dtypes ``layouts``)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the server's to handle (it says "quit")
    from facecapges.engine.threads import limit_threads

    # torch's threads (a network style: the checkpoint's tensors imported torch) and NumPy's BLAS
    # (the matching engine, the speech predictor) alike; a matching style never imports torch
    limit_threads(threads)
    blocks = [shared_memory.SharedMemory(name=n) for n in names]
    try:
        _run(conn, checkpoint, [_view(b, *lay) for b, lay in zip(blocks, layouts)])
    finally:
        for b in blocks:  # the views are gone with _run; the server unlinks the blocks
            b.close()


def _run(conn, checkpoint, arrays: list[np.ndarray]) -> None:
    try:
        gen = checkpoint.batched(capacity=64)  # either engine
    except Exception as exc:  # noqa: BLE001  reported to the server, which says it
        conn.send(("error", f"{exc.__class__.__name__}: {exc}"))
        return
    a, f, h, p, q = arrays
    try:
        warm_engine(gen, a.shape[1])
        from facecapges.rotations_compiled import checked_rot6d_to_quaternions

        to_quaternions = checked_rot6d_to_quaternions()  # NumPy's rot6d_to_quaternion to the bit, compiled
    except Exception as exc:  # noqa: BLE001  as a failed load
        conn.send(("error", f"{exc.__class__.__name__}: {exc}"))
        return
    try:
        conn.send(("ok", None))
    except OSError:  # the server is gone
        return
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):  # the server is gone
            return
        kind = msg[0]
        try:
            if kind == "step":
                B = len(msg[1])
                p[:B] = gen.step(msg[1], a[:B], f[:B], h[:B])
                to_quaternions(p[:B].reshape(-1, 6), q[:B].reshape(-1, 4))
                res = None
            elif kind == "sync":
                res = _sync(gen, *msg[1:])
            else:  # "quit"
                conn.send(("ok", None))
                return
            conn.send(("ok", res))
        except Exception as exc:  # noqa: BLE001  a bad call: report it, keep serving
            conn.send(("error", f"{exc.__class__.__name__}: {exc}"))


def warm_engine(gen, samples_per_frame: int, sizes: tuple[int, ...] = (1, 32)) -> None:
    """A tick of 1 and one of 32 streams (a quiet tone, a neutral face, the head straight) on slots closed
    again, before the server says ``ready:``, so that the first real ticks run warm: the engine's lazy imports
    happen here (scipy's FFT, taken from 16 streams a tick on, and the ~190 modules it pulls in: seconds on a
    busy machine, during which the first streams' frames piled up and were dropped as "busy"). Streams share
    no state (each slot is reset when it opens), so no output changes."""
    for n in sizes:
        slots = [gen.open() for _ in range(n)]
        t = np.arange(samples_per_frame, dtype=np.float32) / timing.AUDIO_SR
        audio = np.tile(0.1 * np.sin(2 * np.pi * 220.0 * t), (n, 1)).astype(np.float32)
        head = np.tile(np.array([1.0, 0.0, 0.0, 0.0, 1.0, 0.0], np.float32), (n, 1))
        pose = gen.step(slots, audio, np.zeros((n, N_BLENDSHAPES), np.float32), head)
        rot.rot6d_to_quaternion(np.asarray(pose, np.float64))
        for slot in slots:
            gen.close(slot)


def _sync(
    gen, close: list[int], n_open: int, intensity: list[tuple[int, float]], initial: list | None = None
) -> list[int]:
    """Close slots, open ``n_open`` new ones (their ids are returned; the k-th starting at
    ``initial[k]``, a rot6d pose, when that is not None), then set intensities; ``intensity`` may
    name a slot opened here by ``-1 - k`` (the k-th new one)."""
    for slot in close:
        gen.close(slot)
    starts = initial or [None] * n_open
    new = [gen.open(starts[k]) if starts[k] is not None else gen.open() for k in range(n_open)]
    for slot, value in intensity:
        gen.set_intensity(new[-1 - slot] if slot < 0 else slot, value)
    return new


class ModelProcess:
    """The batched generator of a loaded style (``checkpoint.batched``: either engine) in a child
    process (module docs); the checkpoint object travels to the child when it starts.

    ``max_rows``: the most streams one :meth:`step` takes (the server's ``max_streams``).
    """

    def __init__(self, checkpoint, threads: int = 1, max_rows: int = 256):
        ctx = _context(checkpoint)
        self.samples_per_frame = timing.samples_per_frame(timing.MODEL_FPS, timing.AUDIO_SR)
        layouts = _layouts(max_rows, self.samples_per_frame)
        # the tick's arrays: blocks of shared memory (zero-filled when made), unlinked by shutdown();
        # should the server die without it, multiprocessing's resource tracker unlinks them
        self._blocks: list[shared_memory.SharedMemory] = []
        try:
            for shape, dtype in layouts:
                self._blocks.append(
                    shared_memory.SharedMemory(create=True, size=int(np.prod(shape)) * np.dtype(dtype).itemsize)
                )
        except BaseException:
            self._release()
            raise
        self._audio, self._face, self._head, self._pose, self._quat = (
            _view(b, *lay) for b, lay in zip(self._blocks, layouts)
        )
        self._rows = 0  # streams of the step submitted and not yet collected
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(
            target=_serve_model,
            name="facecapges-serve-model",
            daemon=True,
            args=(child, checkpoint, threads, [b.name for b in self._blocks], layouts),
        )
        # The child ignores SIGINT from its first instruction on (the disposition survives the exec of
        # ``spawn``): a Ctrl-C in a terminal reaches the whole process group, and the server, not the
        # child, stops on it — telling the child to quit — with no traceback from the child.
        main = threading.current_thread() is threading.main_thread()
        before = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
        try:
            self._proc.start()
        except BaseException:
            self._conn.close()
            child.close()
            self._release()
            raise
        finally:
            if main and before is not None:
                signal.signal(signal.SIGINT, before)
        child.close()
        self._open: set[int] = set()
        try:
            self._call("ready")  # answered once the child has built its generator
        except BaseException:  # failed or interrupted while starting: no child (nor shared block) left behind
            self._proc.kill()
            self._proc.join(timeout=10)
            self._conn.close()
            self._release()
            raise

    def _release(self) -> None:
        """Close and unlink the shared blocks (the views first: a block with views cannot close)."""
        for name in ("_audio", "_face", "_head", "_pose", "_quat"):
            self.__dict__.pop(name, None)
        for b in self._blocks:
            try:
                b.close()
            finally:
                try:
                    b.unlink()
                except FileNotFoundError:  # already gone
                    pass
        self._blocks = []

    def _call(self, *msg):
        if msg != ("ready",):
            self._conn.send(msg)
        kind, value = self._conn.recv()
        if kind == "error":
            raise RuntimeError(f"model process: {value}")
        return value

    @property
    def open_slots(self) -> frozenset[int]:
        return frozenset(self._open)

    def sync(
        self,
        close: Sequence[int],
        n_open: int,
        intensity: Sequence[tuple[int, float]] = (),
        initial: Sequence[np.ndarray | None] | None = None,
    ) -> list[int]:
        """One round trip for the slot changes between two ticks: close ``close``, open ``n_open``
        streams (their slots are returned, in order; the k-th starting at ``initial[k]``, a rot6d
        pose (47, 6), when given: a resumed stream), then set each ``(slot, value)`` intensity —
        a slot ``-1 - k`` is the k-th stream opened by this call."""
        starts = list(initial) if initial is not None and any(p is not None for p in initial) else None
        new = self._call(
            "sync", [int(s) for s in close], int(n_open), [(int(s), float(v)) for s, v in intensity], starts
        )
        self._open.difference_update(close)
        self._open.update(new)
        return new

    def submit(self, slots: Sequence[int], audio, face, head) -> None:
        """Start one frame per stream (:meth:`step`'s arguments); :meth:`collect` gets the result.
        :meth:`fileno` becomes readable when it is ready."""
        B = len(slots)
        if len(self._audio) < B:
            raise ValueError(f"{B} streams in one step; this model process takes at most {len(self._audio)}")
        self._audio[:B] = pack_audio(audio, self.samples_per_frame)
        self._face[:B] = np.asarray(face, np.float32).reshape(B, -1)
        self._head[:B] = np.asarray(head, np.float32).reshape(B, -1)
        self._conn.send(("step", [int(s) for s in slots]))
        self._rows = B

    def collect(self) -> tuple[np.ndarray, np.ndarray]:
        """The submitted step's poses: rot6d (B, 47, 6) float32 and quaternions (B, 47, 4) float64."""
        B, self._rows = self._rows, 0
        kind, value = self._conn.recv()
        if kind == "error":
            raise RuntimeError(f"model process: {value}")
        return self._pose[:B].copy(), self._quat[:B].copy()

    def fileno(self) -> int:
        """The pipe's descriptor: readable once a submitted step is done."""
        return self._conn.fileno()

    def step(self, slots: Sequence[int], audio, face, head) -> np.ndarray:
        """Poses (B, 47, 6) of one frame per stream, as ``BatchedNetworkStreams.step``."""
        self.submit(slots, audio, face, head)
        return self.collect()[0]

    def shutdown(self) -> None:
        if self._proc.is_alive():
            try:
                if self._rows:  # a step submitted and never collected (the server stopped during a tick)
                    self.collect()
                self._call("quit")
            except (EOFError, OSError, RuntimeError):
                pass
            self._proc.join(timeout=10)
            if self._proc.is_alive():
                self._proc.kill()
                self._proc.join(timeout=10)
        self._conn.close()
        self._release()
