"""The runtime's interfaces, declared once: what a source and a sink must offer (a stream: the engines'
:class:`~facecapges.engine.contract.Stream`).

The scheduler (:mod:`.scheduler`) talks to its parts only through these protocols
(``typing.Protocol``; ``isinstance`` works on them, which the tests use to check that
every source and sink of the project satisfies its protocol):

* :class:`VideoSource` — frames to capture a face from (:class:`~.inputs.sources.FileVideo`,
  :class:`~.inputs.sources.CameraVideo`);
* :class:`FaceFeed` — faces that need no capture (:class:`~.inputs.sources.LiveLinkFace`);
* :class:`AudioSource` — the speech (:class:`~.inputs.sources.FileAudio`, :class:`~.inputs.sources.MicAudio`);
* a gesture stream — the engines' :class:`~facecapges.engine.contract.Stream`;
* :class:`Sink` — where output frames go (:mod:`.outputs.recorders`, :mod:`.outputs.vmc`, :mod:`.outputs.viewer`).

Stream time is seconds since the session started (:meth:`start` gets its monotonic
``t0``). A visual source's ``ended`` is a state (the file is over); an audio source ends
at a *sample*, so it answers :meth:`AudioSource.ended_at` for a position.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from facecapges.runtime.frames import OutputFrame


@runtime_checkable
class VideoSource(Protocol):
    @property
    def name(self) -> str: ...  # an attribute or a property

    fps: float
    ended: bool  # no frame will come any more (end of a file, a camera that died)
    skipped: int  # frames never handed out because a newer one was due

    def start(self, t0: float) -> None: ...

    def next_frame(self, deadline_s: float):  # -> sources.VideoFrame | None
        """The newest unread frame stamped before ``deadline_s``, or None; never blocks."""

    def drop(self, deadline_s: float) -> int:
        """Pass over every unread frame stamped before ``deadline_s`` unprocessed; how many (never blocks)."""

    def close(self) -> None: ...


@runtime_checkable
class FaceFeed(Protocol):
    @property
    def name(self) -> str: ...  # an attribute or a property

    ended: bool

    def start(self, t0: float) -> None: ...

    def next_face(self, deadline_s: float):  # -> sources.FaceSample | None
        """The newest unread face sample stamped before ``deadline_s``, or None; never blocks."""

    def close(self) -> None: ...


@runtime_checkable
class AudioSource(Protocol):
    @property
    def name(self) -> str: ...  # an attribute or a property

    def start(self, t0: float) -> None: ...

    def ended_at(self, sample: int) -> bool:
        """True when no sample at or after ``sample`` will ever come (a file's end)."""

    def read(self, start: int, end: int, now_s: float | None = None) -> np.ndarray:
        """Samples ``[start, end)`` that exist by stream time ``now_s`` (fewer when they do not yet)."""

    def close(self) -> None: ...


@runtime_checkable
class Sink(Protocol):
    def write(self, out: OutputFrame) -> None:
        """Called once per frame and face; must be cheap (it runs inside the frame)."""

    def close(self) -> Path | None:
        """Finish (write files atomically, close sockets); safe to call twice; a file written, or None."""
