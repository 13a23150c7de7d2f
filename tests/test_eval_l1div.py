"""L1DIV: eq. 5.11 across samples and the per-sequence deviation from the temporal mean."""

from __future__ import annotations

import numpy as np
import pytest

from facecapges.evaluation.l1div import l1div_samples, l1div_temporal, l1div_temporal_many


def test_constant_sequence_has_zero_temporal_l1div():
    x = np.tile(np.random.default_rng(0).normal(size=(1, 47, 6)), (30, 1, 1))
    assert l1div_temporal(x) == pytest.approx(0.0, abs=1e-12)


def test_temporal_hand_computed():
    x = np.zeros((4, 2, 6))
    x[::2] = 1.0  # alternates 1, 0: mean 0.5, every component deviates by 0.5
    assert l1div_temporal(x) == pytest.approx(2 * 6 * 0.5)
    y = np.zeros((2, 2, 6))  # constant: 0
    assert l1div_temporal_many([x, y]) == pytest.approx(6.0 * 4 / 6)


def test_samples_eq_5_11_hand_computed():
    a = np.zeros((3, 2, 6))
    b = a + 0.1  # L1 per joint-frame 0.6
    assert l1div_samples([a, b]) == pytest.approx(0.6 / 2)  # Σ_{i<k} / N(N-1) with N = 2
    c = a + 0.3  # pairs: ab 0.6, ac 1.8, bc 1.2 → 3.6 / 6
    assert l1div_samples(np.stack([a, b, c])) == pytest.approx(3.6 / 6)
    assert l1div_samples([a, a, a]) == 0.0


def test_samples_needs_two_of_one_shape():
    with pytest.raises(ValueError):
        l1div_samples([np.zeros((3, 2, 6))])
    with pytest.raises(ValueError):
        l1div_samples([np.zeros((3, 2, 6)), np.zeros((4, 2, 6))])
