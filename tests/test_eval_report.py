"""The evaluation suite on the real clip (held-out = last 20 %) and the written report."""

from __future__ import annotations

import json

import numpy as np
import pytest
import soundfile as sf

from facecapges.evaluation import baselines as bl
from facecapges.evaluation import fgd as F
from facecapges.evaluation.report import markdown_table, write_report
from facecapges.evaluation.suite import evaluate_paired, evaluate_unpaired
from facecapges.io.bvh import read_bvh
from facecapges.skeleton import motion_to_pose


@pytest.fixture(scope="module")
def clip():
    from conftest import shared_file

    bvh = read_bvh(shared_file("data/beat/2_scott_0_1_1.bvh"))
    audio, sr = sf.read(shared_file("data/beat/2_scott_0_1_1.wav"), dtype="float32")
    pose = motion_to_pose(bvh.skeleton, bvh.motion)[0]
    return pose, audio, sr, bvh.fps


def test_paired_evaluation_and_report(clip, tmp_path):
    pose, audio, sr, fps = clip
    h = int(round(len(pose) * 0.8))
    train, test = pose[:h], pose[h:]
    test_audio = audio[int(round(h / fps * sr)):]
    ev = F.train_fgd([train], F.FGDConfig(epochs=1), progress=False)
    methods = {"ground truth": bl.ground_truth(test), "mean pose": bl.mean_pose_sequence([train], len(test)),
               "random real segment": bl.random_segment([pose], len(test), 0, exclude=(0, h, len(pose)))}
    res = evaluate_paired(test, methods, test_audio, sr, fps, fgd=ev, offsets_s=[2, 5, 8], progress=False)
    for region in ("with_head", "without_head"):
        rows = res["regions"][region]["methods"]
        gt = rows["ground truth"]
        assert gt["FGD"] < 1e-3 and gt["SRGR"] == 1.0
        assert rows["mean pose"]["L1DIV"] == pytest.approx(0.0, abs=1e-9) and rows["mean pose"]["BA"] == 0.0
        assert rows["mean pose"]["FGD"] > gt["FGD"] and rows["random real segment"]["FGD"] > gt["FGD"]
        assert 0 < rows["random real segment"]["SRGR"] < 1
        assert all(np.isfinite(v) for m in rows.values() for k, v in m.items()
                   if k.startswith("BA") and k != "BA_gap_sd")
        # a motion without beats scores 0 against every shift: its gap has no sd units
        assert rows["mean pose"]["BA_gap_sd"] is None and np.isfinite(gt["BA_gap_sd"])
        assert gt["L1DIV_samples"] is None
    assert len(res["regions"]["without_head"]["joints"]) == 45
    paths = write_report(tmp_path, res, test, {k: v for k, v in methods.items() if k != "ground truth"},
                         test_audio, sr, fps)
    data = json.loads((tmp_path / "metrics.json").read_text())
    assert data["regions"]["with_head"]["methods"]["ground truth"]["SRGR"] == 1.0
    md = (tmp_path / "metrics.md").read_text()
    assert "| Upper body (with head) | ground truth |" in md and "| Upper body (without head) | ground truth |" in md
    assert "SRGR (unweighted)" in md and "BA shifted" in md
    for key in ("beat_timeline", "joint_speed"):
        png = tmp_path / f"{key}.png"
        assert paths[key] == str(png) and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_samples_and_unpaired_unseen_audio(clip, unseen_wav):
    pose, _, _sr, fps = clip
    audio, sr2 = sf.read(unseen_wav, dtype="float32")
    n = 300
    # two "samples" for the same audio: two different real stretches of the speaker
    methods = {"two real stretches": [pose[:n], pose[400:400 + n]]}
    res = evaluate_unpaired(methods, audio, sr2, fps, offsets_s=[3, 7], regions=("with_head",), progress=False)
    row = res["regions"]["with_head"]["methods"]["two real stretches"]
    assert row["FGD"] is None and row["SRGR"] is None and row["n_samples"] == 2
    assert row["L1DIV_samples"] > 0 and row["L1DIV"] > 0 and 0 < row["BA"] <= 1
    assert "L1DIV across generated samples" in markdown_table(res)


def test_suite_rejects_wrong_lengths(clip):
    pose, audio, sr, fps = clip
    with pytest.raises(ValueError, match="frames"):
        evaluate_paired(pose[:100], {"x": pose[:90]}, audio, sr, fps, progress=False)
