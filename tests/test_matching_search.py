"""The matcher's search as a pure function (matching.matcher.search): inputs → best row, its cost, switch.

Synthetic arrays only (no database file): every rule of the search checked against a brute-force reading."""

from __future__ import annotations

import numpy as np

from facecapges.matching.matcher import MatchingConfig, search

N, FEAT = 60, 5
CFG = MatchingConfig(onset_bonus=2.0, memory_penalty=100.0, near_frames=3, margin=1.0)


def arrays(seed: int = 0):
    rng = np.random.default_rng(seed)
    feats = rng.normal(size=(N, FEAT)).astype(np.float32)
    segment = np.repeat(np.arange(3), N // 3).astype(np.int32)
    lead = rng.uniform(0, 3, N).astype(np.float32)
    return feats, np.einsum("nf,nf->n", feats, feats), segment, lead


def run(queries, playing, *, onset=None, recent=None, blocked=None, forced=None, stale=None, cfg=CFG, seed=0):
    feats, sq, segment, lead = arrays(seed)
    B = len(playing)
    no = np.zeros(B, bool)
    return search(
        feats,
        sq,
        np.asarray(queries, np.float32),
        np.asarray(playing),
        segment,
        lead,
        onset_now=no if onset is None else onset,
        played_recently=np.zeros((B, N), bool) if recent is None else recent,
        blocked=np.zeros((B, N), bool) if blocked is None else blocked,
        forced=no if forced is None else forced,
        stale=no if stale is None else stale,
        config=cfg,
    )


def test_best_row_is_the_nearest_allowed_one_and_pure():
    feats, _, _, _ = arrays()
    q = feats[[40, 5]] + 0.01  # near rows 40 and 5
    playing = np.array([10, 50])  # far from both, other segments' rows
    r = run(q, playing)
    assert r.best.tolist() == [40, 5]
    d = ((feats[None] - q[:, None]) ** 2).sum(-1)
    np.testing.assert_allclose(r.cost, d[[0, 1], [40, 5]], rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(r.continue_cost, d[[0, 1], playing], rtol=1e-4, atol=1e-4)
    assert r.switch.all()
    again = run(q, playing)  # no state: the same inputs give the same answer
    assert all(np.array_equal(a, b) for a, b in zip(r, again))


def test_near_rows_in_the_segment_are_continuing_not_candidates():
    feats, _, _, _ = arrays()
    r = run(feats[[21]], [22])  # row 21 is the query itself, 1 frame from the playing row, same segment
    assert abs(int(r.best[0]) - 22) >= CFG.near_frames
    r = run(feats[[19]], [22])  # row 19 is in the previous segment: a candidate although 3 rows away
    assert r.best[0] == 19


def test_blocked_recent_onset_and_margin():
    feats, _, _, lead = arrays()
    q, playing = feats[[40]], np.array([5])
    blocked = np.zeros((1, N), bool)
    blocked[0, 40] = True
    assert run(q, playing, blocked=blocked).best[0] != 40
    recent = np.zeros((1, N), bool)
    recent[0, 40] = True
    r = run(q, playing, recent=recent)
    assert r.best[0] != 40 and r.cost[0] < 100.0
    none = np.ones((1, N), bool)  # every row blocked: no switch
    r = run(q, playing, blocked=none)
    assert not np.isfinite(r.cost[0]) and not r.switch[0]
    # onset: every cost falls by bonus · lead, continuing too
    plain, onset = run(q, playing), run(q, playing, onset=np.array([True]))
    assert onset.continue_cost[0] == np.float32(plain.continue_cost[0] - CFG.onset_bonus * lead[5])
    # margin: continuing wins unless the best beats it by the margin; forced and stale change continuing
    q_here = feats[[5]]  # the playing row itself is the best fit
    r = run(q_here, playing)
    assert not r.switch[0]
    assert run(q_here, playing, forced=np.array([True])).switch[0]
    assert run(q_here, playing, stale=np.array([True])).switch[0]
    big = MatchingConfig(onset_bonus=2.0, memory_penalty=100.0, near_frames=3, margin=1e6)
    assert not run(q, playing, cfg=big).switch[0]


def test_float32_costs_are_the_plain_formulas_bits():
    """The engine's float32 costs are computed in place (one buffer; the memory penalty added in float32 when
    it is a float32 number): the best rows and their costs are the bits of the plain formula, ``sq − 2·dots +
    |q|²`` with the penalty added in float64 — for a float32 penalty (100) and one that is not (100.1)."""
    feats, sq, _, _ = arrays(3)
    rng = np.random.default_rng(3)
    queries = rng.normal(size=(7, FEAT)).astype(np.float32)
    recent = rng.random((7, N)) < 0.4
    for penalty in (100.0, 100.1):
        cfg = MatchingConfig(memory_penalty=penalty, near_frames=1, onset_bonus=0.0)
        got = run(queries, np.zeros(7, np.int64), recent=recent, cfg=cfg, seed=3)
        dots = np.stack([feats @ q for q in queries])
        cost = sq[None] - 2.0 * dots + np.einsum("bf,bf->b", queries, queries)[:, None]
        np.add(cost, np.float64(penalty), out=cost, where=recent)
        cost[:, 0] = np.inf  # the playing row (near_frames 1: itself) is continuing, not a candidate
        best = np.argmin(cost, axis=1)
        assert np.array_equal(got.best, best)
        assert got.cost.tobytes() == cost[np.arange(7), best].tobytes()
