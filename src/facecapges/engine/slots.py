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
    """What a batched generator with :class:`Slots` in ``self.slots`` tells about its streams."""

    slots: Slots

    @property
    def n_open(self) -> int:
        return len(self.slots)

    @property
    def open_slots(self) -> frozenset[int]:
        return self.slots.open
