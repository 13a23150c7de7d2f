"""Which rows of a batched generator belong to an open stream: :class:`Slots`.

Every batched generator (the network's kernel :class:`~facecapges.network.batched.BatchedNetworkStreams`,
the motion-matching engine's :class:`~facecapges.matching.matcher.BatchedMatchingStreams` and its speech
predictor's streams) keeps its streams' state in stacked arrays, one row (*slot*) per stream. A stream
takes the lowest free slot when it opens and gives it back when it closes; when none is free, the owner
doubles its storage (keeping the rows it has) and tells :meth:`Slots.grown`. A step names its slots, each
at most once, all open (:meth:`Slots.check`). Not thread-safe by itself: the owner holds its own lock.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

import numpy as np


class Slots:
    """Free and open slot ids of one batched generator (module docs)."""

    def __init__(self) -> None:
        self.capacity = 0
        self._free: list[int] = []  # highest first: pop() gives the lowest
        self._open: set[int] = set()

    def grown(self, capacity: int) -> None:
        """The owner's storage now holds ``capacity`` rows: the new ones are free."""
        self._free = sorted(set(self._free) | set(range(self.capacity, capacity)), reverse=True)
        self.capacity = capacity

    def take(self, grow: Callable[[int], None]) -> int:
        """Open the lowest free slot; with none free, ``grow(2 · capacity)`` first (which calls :meth:`grown`)."""
        if not self._free:
            grow(max(1, 2 * self.capacity))
        slot = self._free.pop()
        self._open.add(slot)
        return slot

    def release(self, slot: int) -> bool:
        """Close ``slot`` (no-op when it is not open); True when it was open."""
        if slot not in self._open:
            return False
        self._open.discard(slot)
        self._free.append(slot)
        return True

    def require(self, slot: int) -> None:
        if slot not in self._open:
            raise KeyError(f"slot {slot} is not open")

    def check(self, slots: Iterable) -> list[int]:
        """The slot ids of one step as ints: each at most once, all open."""
        ids = [int(s) for s in slots]
        if len(set(ids)) != len(ids):
            raise ValueError("a stream can take only one frame per batched step")
        closed = [s for s in ids if s not in self._open]
        if closed:
            raise KeyError(f"slot(s) {closed} are not open")
        return ids

    def __contains__(self, slot: object) -> bool:
        return slot in self._open

    def __len__(self) -> int:
        return len(self._open)

    @property
    def open(self) -> frozenset[int]:
        return frozenset(self._open)


class SlotOwner:
    """A batched engine's streams' lifecycle, once for every engine: :meth:`open` takes the lowest free
    slot (growing the owner's storage through its ``_alloc(capacity)``), lets the owner set the slot's own
    state (:meth:`_opened`) and resets it to its cold start or ``initial_pose`` — a failed reset gives the
    slot back; the owner's ``close`` releases it. The owner holds ``self.slots`` and a re-entrant
    ``self._lock`` and defines ``_alloc``, ``reset`` and ``close``."""

    slots: Slots
    _lock: Any

    def _alloc(self, capacity: int) -> None:
        raise NotImplementedError

    def _opened(self, slot: int) -> None:
        """The owner's per-slot state of a new stream, before its reset (nothing by default)."""

    def reset(self, slot: int, initial_pose: np.ndarray | None = None) -> None:
        raise NotImplementedError

    def close(self, slot: int) -> None:
        raise NotImplementedError

    def open(self, initial_pose: np.ndarray | None = None) -> int:
        """A new stream from its cold start (or ``initial_pose``, (47, 6) rot6d); returns its slot id."""
        with self._lock:
            slot = self.slots.take(self._alloc)
            self._opened(slot)
            try:
                self.reset(slot, initial_pose)
            except Exception:
                self.close(slot)
                raise
            return slot

    @property
    def n_open(self) -> int:
        return len(self.slots)

    @property
    def open_slots(self) -> frozenset[int]:
        return self.slots.open
