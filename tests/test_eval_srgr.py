"""SRGR (eq. 5.8) and BEAT semantic files."""

from __future__ import annotations

import numpy as np
import pytest

from facecapges.evaluation.srgr import srgr


def test_identical_sequences_give_one():
    x = np.random.default_rng(0).normal(size=(20, 47, 6))
    r = srgr(x, x)
    assert r.value == 1.0 and not r.weighted and r.label == "SRGR (unweighted)"


def test_hand_computed_hits_and_weights():
    real = np.zeros((2, 2, 6))
    gen = np.zeros((2, 2, 6))
    gen[0, 0, :2] = 0.2  # L1 0.4 < 0.5: hit
    gen[0, 1, 0] = 0.6  # L1 0.6: miss
    gen[1, 0, 5] = -0.1  # L1 0.1: hit
    gen[1, 1, 0] = 0.5  # L1 0.5, not < 0.5: miss
    assert srgr(real, gen).value == pytest.approx(0.5)
    r = srgr(real, gen, weights=np.array([1.0, 0.5]))
    assert r.weighted and r.label == "SRGR" and r.value == pytest.approx((1.0 + 0.5) / 4)
    assert srgr(real, gen, delta=0.7).value == pytest.approx(1.0)


def test_shape_errors():
    with pytest.raises(ValueError):
        srgr(np.zeros((3, 47, 6)), np.zeros((4, 47, 6)))
    with pytest.raises(ValueError):
        srgr(np.zeros((3, 47, 6)), np.zeros((3, 47, 6)), weights=np.ones(4))


def test_weights_from_a_beat_semantic_file(tmp_path):
    from facecapges.data.beat import read_semantic

    p = tmp_path / "2_scott_0_1_1.txt"
    p.write_text("deictic_l\t0.10\t0.40\t0.30\t0.8\tthere\n")
    lam = read_semantic(p, n_frames=10, fps=15.0)  # frames 2..6 (0.133–0.4 s) weigh 0.8
    real = np.zeros((10, 3, 6))
    gen = real.copy()
    gen[:5, 0, 0] = 1.0  # joint 0 misses in frames 0..4
    r = srgr(real, gen, lam)
    hits_weighted = 0.8 * (3 * 2 + 2 * 3)  # frames 2..4: 2 hits each; frames 5..6: 3 hits each
    assert r.weighted and r.value == pytest.approx(hits_weighted / 30)
