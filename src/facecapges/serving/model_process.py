"""The server's model in a process of its own: :class:`ModelProcess`.

``serve`` runs its event loop (WebSocket I/O, JSON) in one thread. Stepped in a thread
of the same process, the eager batched kernel
(:class:`~facecapges.model.batched.BatchedStreamingGenerator`) gives up and takes back
the GIL at each of its few hundred tensor operations, and the busy event loop keeps
it waiting at each one: measured on this 2-core machine, 80 clients, one run (load
17–24): a worker thread managed 9 ticks in 6 s, the same kernel inline in the event
loop 44, and the kernel in this separate process never waits for the loop at all. So
the kernel runs here, in a child process (``spawn``), and the server talks to it over
a pipe; the inputs and poses of a tick travel through shared-memory tensors, so a
tick costs one small message each way.

It offers the part of the generator's interface the server uses: :meth:`open`,
:meth:`close`, :attr:`open_slots`, :meth:`step` (same arguments and result). Not
thread-safe: one caller at a time (the server's model thread).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from facecapges import timing
from facecapges.arkit import N_BLENDSHAPES
from facecapges.model.batched import pack_audio
from facecapges.skeleton import N_JOINTS


def _serve_model(conn, checkpoint, threads: int, audio, face, head, pose) -> None:
    """The child process: the style's batched generator, driven by messages on ``conn``."""
    torch.set_num_threads(max(1, threads))
    try:
        gen = checkpoint.batched(capacity=64)  # either engine
    except Exception as exc:  # noqa: BLE001  reported to the server, which says it
        conn.send(("error", f"{exc.__class__.__name__}: {exc}"))
        return
    a, f, h, p = audio.numpy(), face.numpy(), head.numpy(), pose.numpy()
    conn.send(("ok", None))
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
                res = None
            elif kind == "open":
                res = gen.open()
            elif kind == "close":
                gen.close(msg[1])
                res = None
            elif kind == "intensity":
                gen.set_intensity(msg[1], msg[2])
                res = None
            else:  # "quit"
                conn.send(("ok", None))
                return
            conn.send(("ok", res))
        except Exception as exc:  # noqa: BLE001  a bad call: report it, keep serving
            conn.send(("error", f"{exc.__class__.__name__}: {exc}"))


class ModelProcess:
    """The batched generator of a loaded style (``checkpoint.batched``: either engine) in a child
    process (module docs); the checkpoint object travels to the child when it starts.

    ``max_rows``: the most streams one :meth:`step` takes (the server's ``max_streams``).
    """

    def __init__(self, checkpoint, threads: int = 1, max_rows: int = 256):
        ctx = torch.multiprocessing.get_context("spawn")
        self.samples_per_frame = timing.samples_per_frame(timing.MODEL_FPS, timing.AUDIO_SR)
        self._audio = torch.zeros(max_rows, self.samples_per_frame).share_memory_()
        self._face = torch.zeros(max_rows, N_BLENDSHAPES).share_memory_()
        self._head = torch.zeros(max_rows, 6).share_memory_()
        self._pose = torch.zeros(max_rows, N_JOINTS, 6).share_memory_()
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(
            target=_serve_model,
            name="facecapges-serve-model",
            daemon=True,
            args=(
                child,
                checkpoint,
                threads,
                self._audio,
                self._face,
                self._head,
                self._pose,
            ),
        )
        self._proc.start()
        child.close()
        self._open: set[int] = set()
        self._call("ready")  # answered once the child has built its generator

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

    def open(self) -> int:
        slot = self._call("open")
        self._open.add(slot)
        return slot

    def close(self, slot: int) -> None:
        self._call("close", slot)
        self._open.discard(slot)

    def set_intensity(self, slot: int, value: float) -> None:
        """One stream's intensity dial (:mod:`facecapges.model.intensity`), from its next step on."""
        self._call("intensity", int(slot), float(value))

    def step(self, slots: Sequence[int], audio, face, head) -> np.ndarray:
        """Poses (B, 47, 6) of one frame per stream, as ``BatchedStreamingGenerator.step``."""
        B = len(slots)
        if len(self._audio) < B:
            raise ValueError(f"{B} streams in one step; this model process takes at most {len(self._audio)}")
        self._audio.numpy()[:B] = pack_audio(audio, self.samples_per_frame)
        self._face.numpy()[:B] = np.asarray(face, np.float32).reshape(B, -1)
        self._head.numpy()[:B] = np.asarray(head, np.float32).reshape(B, -1)
        self._call("step", [int(s) for s in slots])
        return self._pose.numpy()[:B].copy()

    def shutdown(self) -> None:
        if self._proc.is_alive():
            try:
                self._call("quit")
            except (EOFError, OSError, RuntimeError):
                pass
            self._proc.join(timeout=10)
            if self._proc.is_alive():
                self._proc.kill()
        self._conn.close()
