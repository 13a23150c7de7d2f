"""Balanced Latin squares and the study plan: counterbalancing proven by counting."""

from __future__ import annotations

from collections import Counter
from itertools import pairwise

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from facecapges.study.design import (
    StudyPlan,
    balance_report,
    default_participants,
    make_plan,
    participant_ids,
    williams_square,
)


@pytest.mark.parametrize("n", range(1, 10))
def test_williams_square_is_a_balanced_latin_square(n):
    rows = williams_square(n)
    assert len(rows) == (n if n % 2 == 0 or n == 1 else 2 * n)
    for row in rows:  # every row shows every treatment once
        assert sorted(row) == list(range(n))
    for pos in range(n):  # every treatment equally often in every serial position
        counts = Counter(row[pos] for row in rows)
        assert set(counts) == set(range(n)) and len(set(counts.values())) == 1
    pairs = Counter((a, b) for row in rows for a, b in pairwise(row))
    want = 1 if n % 2 == 0 else 2  # first-order carry-over: every ordered pair equally often
    assert all(pairs[(a, b)] == want for a in range(n) for b in range(n) if a != b) or n == 1
    assert not any(a == b for a, b in pairs)


def test_williams_square_even_known_rows():
    # the classic 4-treatment Williams design: 0 1 3 2 / 1 2 0 3 / 2 3 1 0 / 3 0 2 1
    assert williams_square(4) == [[0, 1, 3, 2], [1, 2, 0, 3], [2, 3, 1, 0], [3, 0, 2, 1]]


def _clip_counts(plan: StudyPlan):
    serial = Counter((t.clip, i) for p in plan.participants for i, t in enumerate(p.trials))
    carry = Counter((a.clip, b.clip) for p in plan.participants for a, b in zip(p.trials, p.trials[1:]))
    return serial, carry


def _position_counts(plan: StudyPlan):
    return Counter((s, j) for p in plan.participants for t in p.trials for j, s in enumerate(t.systems))


@pytest.mark.parametrize("n_clips,k", [(2, 2), (3, 3), (4, 3), (4, 4), (5, 2), (6, 3), (8, 3), (7, 5)])
def test_plan_is_counterbalanced(n_clips, k):
    clips = [f"c{i}" for i in range(n_clips)]
    systems = [f"s{i}" for i in range(k)]
    r = default_participants(n_clips)
    # smallest multiple of R whose trial count is a multiple of K: everything exactly balanced
    p = next(m * r for m in range(1, 100) if (m * r * n_clips) % k == 0)
    plan = make_plan(clips, systems, p, seed=7)
    assert [q.id for q in plan.participants] == participant_ids(p)
    for q in plan.participants:
        assert sorted(t.clip for t in q.trials) == sorted(clips)  # every clip once
        for t in q.trials:
            assert sorted(t.systems) == sorted(systems)  # every system once per trial
    serial, carry = _clip_counts(plan)
    assert len({serial[(c, i)] for c in clips for i in range(n_clips)}) == 1
    if n_clips > 1:
        # first-order carry-over balanced: each clip follows each other clip equally often
        assert len({carry[(a, b)] for a in clips for b in clips if a != b}) == 1
    pos = _position_counts(plan)
    assert len({pos[(s, j)] for s in systems for j in range(k)}) == 1
    assert pos[(systems[0], 0)] == p * n_clips // k
    assert balance_report(plan) == {"participants": p, "clips": n_clips, "systems": k, "sequences": r,
                                   "position_spread": 0, "serial_position_spread": 0, "carry_over_spread": 0}


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 8), st.integers(2, 5), st.integers(1, 30), st.integers(0, 2**31))
def test_positions_within_one_of_balanced(n_clips, k, p, seed):
    plan = make_plan([f"c{i}" for i in range(n_clips)], [f"s{i}" for i in range(k)], p, seed)
    pos = _position_counts(plan)
    counts = [pos[(f"s{i}", j)] for i in range(k) for j in range(k)]
    assert max(counts) - min(counts) <= 1
    assert balance_report(plan)["position_spread"] == max(counts) - min(counts)


def test_plan_is_seeded_and_random():
    clips, systems = [f"c{i}" for i in range(8)], ["a", "b", "c"]
    one = make_plan(clips, systems, 16, seed=3)
    assert make_plan(clips, systems, 16, seed=3).to_json() == one.to_json()
    other = make_plan(clips, systems, 16, seed=4)
    assert other.to_json() != one.to_json()
    # positions are randomised per participant and clip, not a fixed rotation
    layouts = Counter(t.systems for q in one.participants for t in q.trials)
    assert len(layouts) == 6  # all 3! orders occur
    firsts = {q.trials[0].clip for q in one.participants}
    assert len(firsts) == len(clips)  # every clip opens the study for someone
    assert StudyPlan.from_json(one.to_json()).to_json() == one.to_json()


def test_plan_rejects_bad_input():
    with pytest.raises(ValueError, match="two distinct systems"):
        make_plan(["a"], ["x"], 2)
    with pytest.raises(ValueError, match="unique"):
        make_plan(["a", "a"], ["x", "y"], 2)
    with pytest.raises(ValueError, match="participant"):
        make_plan(["a"], ["x", "y"], 0)
    with pytest.raises(ValueError):
        williams_square(0)
