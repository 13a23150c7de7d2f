"""The FGD autoencoder that ships with the package: every engine gets an FGD in ``facecapges eval`` (issue #38)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from facecapges.evaluation.fgd import fgd_paths, find_fgd, load_fgd, packaged_fgd_dir
from runtime_helpers import cli

PACKAGED = packaged_fgd_dir()


def test_the_package_ships_a_beat_upper_body_autoencoder_with_its_card():
    w, j = fgd_paths(PACKAGED)
    assert w.is_file() and j.is_file()
    assert w.stat().st_size < 5e6  # a few MB at most in the wheel
    ev = load_fgd(PACKAGED)
    assert set(ev.regions) == {"with_head", "without_head"}
    meta = json.loads(j.read_text())
    assert meta["history"]["n_windows"] > 100  # both takes' training 80 %
    card = (PACKAGED / "README.md").read_text()
    for must in ("CC BY-NC 4.0", "BEAT", "BEAT2", "2_scott_0_1_1", "2_scott_0_2_2", "held-out", "ZEGGS"):
        assert must in card, must


def test_find_fgd_order(tmp_path):
    from facecapges.styles import resolve

    mm = resolve(style="beat2-scott-mm")  # a matching style: no .fgd folder of its own
    assert not fgd_paths(mm)[1].exists()
    assert find_fgd(mm)[0] == PACKAGED and "package" in find_fgd(mm)[1]
    demo = resolve(style="beat2-scott-demo")  # the network style carries its own
    assert find_fgd(demo)[0] == demo
    assert find_fgd(mm, tmp_path / "x") == (tmp_path / "x", "given with --fgd")


def test_the_packaged_autoencoder_never_saw_the_held_out_frames():
    """Its window count is what the first 80 % of the two takes give (957 → 765, 902 → 721 frames)."""
    meta = json.loads(fgd_paths(PACKAGED)[1].read_text())
    cfg = meta["config"]
    n = sum((f - cfg["window"]) // cfg["stride"] + 1 for f in (765, 721))
    assert meta["history"]["n_windows"] == n


@pytest.mark.slow
def test_eval_gives_fgd_for_the_matching_style(beat_take_cache, tmp_path):
    out = tmp_path / "eval"
    res = cli("eval", "--cache", str(beat_take_cache), "--style", "beat2-scott-mm", "--holdout-from", "860",
              "--out", str(out), "--no-video", "--samples", "1", "--offsets", "2,3.5", "--quiet")
    assert res.returncode == 0, res.stderr
    data = json.loads((out / "metrics.json").read_text())
    paired = data["paired"]
    assert paired["fgd_autoencoder"] == str(fgd_paths(PACKAGED)[0])
    assert "package" in paired["fgd_autoencoder_source"]
    for region in ("with_head", "without_head"):
        rows = paired["regions"][region]["methods"]
        assert all(m["FGD"] is not None and np.isfinite(m["FGD"]) for m in rows.values())
        assert rows["ground truth"]["FGD"] < 1e-3
    timing = paired["timing"]  # evaluation.timing for every method, the real held-out motion included
    assert {"ground truth", "random real segment"} <= set(timing)
    assert all(r["onsets"] > 0 for r in timing.values())
    md = (out / "metrics.md").read_text()
    assert "FGD autoencoder:" in md and "Timing against speech onsets" in md


def test_fgd_train_holdout_tail(beat_take_cache, tmp_path):
    out = tmp_path / "fgd"
    res = cli("fgd-train", "--cache", str(beat_take_cache), "--split", "all", "--holdout-tail", "--out", str(out),
              "--epochs", "1", "--regions", "with_head", "--quiet")
    assert res.returncode == 0, res.stderr
    assert json.loads((out / "fgd_autoencoder.json").read_text())["history"]["n_windows"] == (765 - 32) // 10 + 1
    bad = cli("fgd-train", "--cache", str(beat_take_cache), "--split", "all", "--holdout-tail", "--holdout-from",
              "700", "--out", str(tmp_path / "y"), "--quiet")
    assert bad.returncode == 2 and bad.stderr.startswith("error: ") and "Traceback" not in bad.stderr
