"""SRGR (eq. 5.8) and BEAT semantic files."""

from __future__ import annotations

import numpy as np
import pytest

from facecapges.errors import UserError
from facecapges.evaluation.srgr import read_semantic, semantic_weights, srgr


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


def test_semantic_file_parsing_and_frame_weights(tmp_path):
    p = tmp_path / "2_scott_0_1_1.txt"
    p.write_text("deictic_l\t0.10\t0.40\t0.30\t0.8\tthere\n"
                 "beat_align\t0.30\t1.00\t0.70\t0.5\n"
                 "\n"
                 "iconic\t2.00\t2.20\t0.20\t1.0\tbig\n")
    spans = read_semantic(p)
    assert [s.name for s in spans] == ["deictic_l", "beat_align", "iconic"]
    assert spans[0].word == "there" and spans[1].word == ""
    w = semantic_weights(spans, n_frames=40, fps=15.0)
    t = np.arange(40) / 15
    assert w[2] == 0.8 and w[6] == 0.8  # 0.133 s, 0.4 s: first span wins where two overlap
    assert w[7] == 0.5 and w[15] == 0.5 and w[16] == 0.0
    assert w[30] == 1.0 and w[33] == 1.0 and w[34] == 0.0
    assert np.all(w[(t < 0.1)] == 0)
    # a later window of the clip
    assert semantic_weights(spans, 5, 15.0, start_frame=30).tolist() == [1.0, 1.0, 1.0, 1.0, 0.0]


def test_bad_semantic_files_are_user_errors(tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("deictic\t0.1\t0.2\n")
    with pytest.raises(UserError, match="bad.txt: line 1"):
        read_semantic(bad)
    bad.write_text("deictic\tzero\t0.2\t0.1\t0.5\n")
    with pytest.raises(UserError, match="numbers"):
        read_semantic(bad)
    with pytest.raises(UserError, match="not found"):
        read_semantic(tmp_path / "missing.txt")
