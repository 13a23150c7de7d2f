"""The gesture engines behind one interface: what a loaded style offers, whatever makes its motion.

:func:`facecapges.styles.load_style` returns a :class:`GestureEngine`: the thesis
network's :class:`~facecapges.network.style.NetworkStyle` or a motion-matching style's
:class:`~facecapges.matching.style.MatchingStyle`. The runtime, ``serve``, ``generate`` and
evaluation use only what is defined here, so another engine slots in beside ``model/`` and
``matching/`` without touching them:

* ``meta`` (the file's metadata, what its model card is made from), ``path``, ``engine`` (the kind:
  ``"network"``, ``"matching"``) and :attr:`~GestureEngine.display_name` (its name in tables);
* ``fps`` (the model rate: a recording's inputs are planned at it, :meth:`~GestureEngine.plan_inputs`),
  ``skeleton`` (the BEAT skeleton its poses belong to) and ``neutral_window`` (the cold-start
  history, (N, 47, 6) rot6d) — read from ``meta`` here, once for every engine;
* ``streaming()`` — one stream (:class:`Stream`: ``reset(initial_pose)``, ``step(audio, face, head)``,
  ``intensity``, ``frames``), ``batched(capacity)`` — many streams stepped as
  one batch (what ``serve`` runs);
* ``database_poses()`` — the real frames an engine replays (repetition is measured against them), or
  None for an engine that generates its poses.

What only a network can do (resume training from it, the ablation's variants) asks for a
network by :func:`facecapges.styles.network_only`.
"""

from __future__ import annotations

import abc
import functools
from collections.abc import Sequence
from pathlib import Path
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np

from facecapges.engine.inputs import FrameInputs, StreamedInputs, plan_inputs, prepare_inputs
from facecapges.errors import file_error
from facecapges.skeleton import Skeleton, skeleton_from_dict


@runtime_checkable
class Stream(Protocol):
    """One stream of an engine: a pose (47, 6) per frame of inputs, from a history it is reset to."""

    intensity: float  # the dial, 0 (rest) … 1 … 1.3 (facecapges.engine.intensity)

    @property
    def frames(self) -> int:
        """Frames stepped since the last reset."""
        ...

    def reset(self, initial_pose: np.ndarray | None = None) -> None: ...

    def step(self, audio: np.ndarray, face: np.ndarray, head: np.ndarray) -> np.ndarray: ...


@runtime_checkable
class BatchedStreams(Protocol):
    """Many streams of one style stepped as one batch (what ``serve`` runs): each open stream owns a
    *slot* (:mod:`facecapges.engine.slots`) from :meth:`open` until :meth:`close`; one :meth:`step` takes
    one frame of inputs for each slot it names (each at most once) and returns their poses in that order."""

    @property
    def n_open(self) -> int: ...

    @property
    def open_slots(self) -> frozenset[int]: ...

    def open(self, initial_pose: np.ndarray | None = None) -> int:
        """A new stream from its cold start (or from ``initial_pose``, (47, 6) rot6d); its slot."""
        ...

    def close(self, slot: int) -> None: ...

    def reset(self, slot: int, initial_pose: np.ndarray | None = None) -> None: ...

    def set_intensity(self, slot: int, value: float) -> None:
        """The dial of one stream (:mod:`facecapges.engine.intensity`), from its next step on."""
        ...

    def step(self, slots: Sequence[int], audio, face, head) -> np.ndarray:
        """One frame for each of ``slots``: audio chunks (B, samples), faces (B, 52), heads (B, 6) → (B, 47, 6)."""
        ...

    def warmup(self, slots: Sequence[int], audio, face, head, pose) -> None:
        """Feed known frames (inputs and the poses that went with them) as history, without generating."""
        ...


class GestureEngine(abc.ABC):
    """A loaded style of any engine (module docs); subclasses are dataclasses with ``meta`` and ``path``."""

    meta: dict
    path: Path
    engine: ClassVar[str]  # the kind of engine, as ``styles list`` shows it
    label: ClassVar[str]  # the method's name in evaluation tables

    @property
    @abc.abstractmethod
    def fps(self) -> int:
        """The model rate (frames per second) the engine runs at."""

    @abc.abstractmethod
    def streaming(self) -> Stream:
        """A new stream from the cold start (:attr:`neutral_window`)."""

    @abc.abstractmethod
    def batched(self, capacity: int = 8) -> BatchedStreams:
        """Many streams of this style stepped as one batch (what ``serve`` runs)."""

    @functools.cached_property
    def skeleton(self) -> Skeleton:
        """The style's skeleton, built once (its per-joint caches then serve every frame)."""
        if "skeleton" not in self.meta:
            raise file_error(self.path, "checkpoint has no skeleton in its metadata: it cannot write motion")
        return skeleton_from_dict(self.meta["skeleton"])

    @property
    def neutral_window(self) -> np.ndarray:
        """The cold-start history (N, 47, 6): the frames a stream starts from."""
        return np.array(self.meta["neutral_window"], dtype=np.float32)

    @property
    def display_name(self) -> str:
        """The method's name in tables: ``FaceCapGes (stem)``, ``motion matching (stem)``."""
        return f"{self.label} ({self.path.stem})"

    def database_poses(self) -> np.ndarray | None:
        """The real poses (N, 47, 6) the engine replays; None: it generates them."""
        return None

    def plan_inputs(
        self, audio: str | Path, face: str | Path | None = None, head: str | Path | None = None
    ) -> StreamedInputs:
        """A recording's inputs at this engine's rate, read block by block
        (:func:`facecapges.engine.inputs.plan_inputs`)."""
        return plan_inputs(audio, face, head, fps=self.fps)

    def prepare_inputs(
        self, audio: str | Path, face: str | Path | None = None, head: str | Path | None = None
    ) -> FrameInputs:
        """A recording's inputs at this engine's rate, all in memory
        (:func:`facecapges.engine.inputs.prepare_inputs`)."""
        return prepare_inputs(audio, face, head, fps=self.fps)
