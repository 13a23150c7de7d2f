"""Slot bookkeeping shared by the batched generators (model.slots): lowest free first, growth, step checks."""

from __future__ import annotations

import pytest

from facecapges.engine.slots import Slots


def test_lowest_free_slot_growth_and_reuse():
    s, grown = Slots(), []

    def grow(n):
        grown.append(n)
        s.grown(n)

    s.grown(2)
    assert [s.take(grow), s.take(grow)] == [0, 1] and grown == []
    assert s.take(grow) == 2 and grown == [4]  # full: storage doubled, the next row opened
    assert s.release(1) and not s.release(1)
    assert s.take(grow) == 1 and len(s) == 3 and s.open == {0, 1, 2}


def test_a_step_names_open_slots_once():
    s = Slots()
    s.grown(4)
    a, b = s.take(s.grown), s.take(s.grown)
    assert s.check([b, a]) == [b, a]
    with pytest.raises(ValueError, match="only one frame"):
        s.check([a, a])
    with pytest.raises(KeyError, match=r"\[3\]"):
        s.check([a, 3])
    s.release(a)
    with pytest.raises(KeyError):
        s.require(a)
