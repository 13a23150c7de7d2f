"""``study analyze``: hand-computed mean ranks, Friedman statistic, Holm correction, plots."""

from __future__ import annotations

import json

import numpy as np
import pytest

from facecapges.study.analyze import analyze_criterion, analyze_study, bootstrap_ci, holm
from facecapges.study.build import Study
from facecapges.study.criteria import CRITERIA, CRITERION_KEYS
from facecapges.study.design import make_plan, new_token
from facecapges.study.store import AnswerStore


def test_holm_by_hand():
    # sorted p: 0.01·3 = 0.03, 0.03·2 = 0.06, 0.04·1 = 0.04 → monotone 0.06
    assert holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
    assert holm([0.5, 0.9]) == pytest.approx([1.0, 1.0])


def test_friedman_and_pairs_by_hand():
    systems = ["a", "b", "c"]
    rows = [[1, 2, 3]] * 5 + [[2, 1, 3]] * 3 + [[1, 3, 2]] * 2  # 10 answers, one participant each
    answers = [{"participant": f"p{i}", "ranks": {"realism": dict(zip(systems, r))}} for i, r in enumerate(rows)]
    res = analyze_criterion(answers, systems, "realism")
    R = np.array(rows, float)
    n, k = R.shape
    chi2 = 12 / (n * k * (k + 1)) * (R.sum(0) ** 2).sum() - 3 * n * (k + 1)  # Friedman without ties
    assert res["friedman"]["chi2"] == pytest.approx(chi2)
    assert res["friedman"]["kendall_w"] == pytest.approx(chi2 / (n * (k - 1)))
    assert [res["systems"][s]["mean_rank"] for s in systems] == pytest.approx(R.mean(0))
    assert res["systems"]["a"]["rank_counts"] == [7, 3, 0]
    ab = next(p for p in res["pairwise"] if (p["a"], p["b"]) == ("a", "b"))
    assert (ab["a_better"], ab["b_better"]) == (7, 3)
    assert all(p["p_holm"] >= p["p"] for p in res["pairwise"])
    ac = next(p for p in res["pairwise"] if (p["a"], p["b"]) == ("a", "c"))
    # a beats c in all 10 answers: exact two-sided Wilcoxon p = 2 / 2^10
    assert ac["p"] == pytest.approx(2 / 2**10) and ac["significant"]


def test_bootstrap_resamples_participants():
    ranks = np.array([[1, 2], [1, 2], [2, 1], [2, 1]], float)
    assert bootstrap_ci(ranks, np.array(["p", "p", "p", "p"])) is None
    ci = bootstrap_ci(ranks, np.array(["p", "p", "q", "q"]))
    assert ci[0] == pytest.approx([1.0, 2.0])  # either both answers of p or of q or a mix
    same = bootstrap_ci(np.array([[1, 2]] * 4, float), np.array(["p", "p", "q", "q"]))
    assert same == pytest.approx(np.array([[1.0, 1.0], [2.0, 2.0]]))


def test_analyze_study_outputs(tmp_path):
    systems = ["gt", "ours", "base"]
    plan = make_plan(["c1", "c2", "c3", "c4"], systems, 4, seed=0)
    d = tmp_path / "study"
    store = AnswerStore(d / "responses", plan)
    prefer = {"realism": ["gt", "ours", "base"], "synchrony": ["ours", "gt", "base"],
              "diversity": ["base", "ours", "gt"]}
    for p in plan.participants:
        p.token = new_token()  # answers count only when given with the participant's invitation
        for i, t in enumerate(p.trials):
            ranks = {c: [prefer[c].index(s) + 1 for s in t.systems] for c in CRITERION_KEYS}
            store.answer(p.id, i, ranks)
    study = Study(d, {"systems": systems, "criteria": [c.to_json() for c in CRITERIA]}, plan)
    out = tmp_path / "res"
    res = analyze_study(study, out)
    assert res["n_answers"] == 16 and res["n_participants"] == 4
    for c in CRITERION_KEYS:
        for s in systems:
            r = res["criteria"][c]["systems"][s]
            assert r["mean_rank"] == prefer[c].index(s) + 1
            assert r["ci95"] == pytest.approx([r["mean_rank"]] * 2)
        assert res["criteria"][c]["friedman"]["kendall_w"] == pytest.approx(1.0)
    saved = json.loads((out / "results.json").read_text())
    assert saved["criteria"]["synchrony"]["systems"]["ours"]["mean_rank"] == 1
    md = (out / "results.md").read_text()
    assert "| gt | 1.00 [1.00, 1.00] | 2.00 [2.00, 2.00] | 3.00 [3.00, 3.00] |" in md
    import cv2

    for name in ("mean_rank.png", "rank_shares.png"):
        img = cv2.imread(str(out / name))
        assert img.shape[0] > 300 and img.shape[1] > 600 and img.std() > 10


def test_mean_rank_plot_draws_the_chinese_criterion_names(tmp_path):
    """The criteria's Chinese names in mean_rank.png come from the installed CJK font (scripts/setup-avatar.sh
    installs fonts-wqy-microhei), not as empty boxes: matplotlib warns of no missing glyph."""
    import warnings

    from facecapges.io.plots import cjk_font

    assert cjk_font() is not None, "no CJK font: run scripts/setup-avatar.sh (fonts-wqy-microhei)"
    systems = ["gt", "ours"]
    plan = make_plan(["c1", "c2"], systems, 2, seed=0)
    d = tmp_path / "study"
    store = AnswerStore(d / "responses", plan)
    for p in plan.participants:
        p.token = new_token()
        for i, t in enumerate(p.trials):
            store.answer(p.id, i, {c: [t.systems.index(s) + 1 for s in t.systems] for c in CRITERION_KEYS})
    study = Study(d, {"systems": systems, "criteria": [c.to_json() for c in CRITERIA]}, plan)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        analyze_study(study, tmp_path / "res")
    missing = [str(w.message) for w in caught if "missing from font" in str(w.message)]
    assert not missing, missing
    assert (tmp_path / "res" / "mean_rank.png").stat().st_size > 10_000


def test_a_cjk_font_installed_after_matplotlibs_font_cache_is_found(monkeypatch):
    """matplotlib caches its font list on first use; setup-avatar.sh's font installed after that (a fresh clone's
    setup imported matplotlib first) must still be found, not reported missing."""
    from matplotlib import font_manager

    from facecapges.io import plots

    keep = [f for f in font_manager.fontManager.ttflist if not any(k in f.fname.lower() for k in plots.CJK_FILE_KEYS)]
    monkeypatch.setattr(font_manager.fontManager, "ttflist", keep)  # the list as cached before the font came
    plots.cjk_font.cache_clear()
    try:
        assert plots.cjk_font() == "WenQuanYi Micro Hei", "no CJK font: run scripts/setup-avatar.sh"
    finally:
        plots.cjk_font.cache_clear()
