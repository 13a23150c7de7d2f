"""``facecapges fgd-train`` and ``facecapges eval`` through the real command line on the shared clip."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from facecapges.data.cache import Cache
from facecapges.network.config import ModelConfig
from facecapges.network.network import FaceCapGes
from facecapges.network.style import save_checkpoint
from runtime_helpers import cli


def run(*args):
    return cli(*map(str, args))


def one_line_error(res: subprocess.CompletedProcess, *fragments: str) -> None:
    assert res.returncode == 2 and "Traceback" not in res.stderr + res.stdout
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    for f in fragments:
        assert f in lines[0], (f, lines[0])


@pytest.fixture(scope="module")
def cache(beat_take_cache):
    return beat_take_cache  # the session's prepare() of the sample take alone (tests/conftest.py)


@pytest.mark.slow
def test_fgd_train_from_cache_and_bvh(cache, tmp_path, beat_bvh):
    out = tmp_path / "fgd"
    res = run("fgd-train", "--cache", cache, "--speaker", 2, "--split", "all", "--holdout-from", 766,
              "--out", out, "--epochs", 2, "--regions", "with_head", "--quiet")
    assert res.returncode == 0, res.stderr
    meta = json.loads((out / "fgd_autoencoder.json").read_text())
    assert meta["config"]["epochs"] == 2 and meta["history"]["n_windows"] == (766 - 32) // 10 + 1
    assert list(meta["regions"]) == ["with_head"] and len(meta["history"]["loss"]["with_head"]) == 2
    again = run("fgd-train", "--cache", cache, "--split", "all", "--out", out, "--epochs", 1, "--quiet")
    one_line_error(again, "already exists", "--force")
    res = run("fgd-train", "--bvh", beat_bvh, "--out", tmp_path / "fgd_bvh", "--epochs", 1, "--quiet")
    assert res.returncode == 0 and (tmp_path / "fgd_bvh" / "fgd_autoencoder.safetensors").is_file()


def test_fgd_train_bad_input(cache, tmp_path):
    one_line_error(run("fgd-train", "--out", tmp_path / "x"), "--cache", "--bvh")
    one_line_error(run("fgd-train", "--cache", cache, "--out", tmp_path / "x"), "no 'train' clips", "--split all")
    one_line_error(run("fgd-train", "--cache", tmp_path / "nope", "--out", tmp_path / "x"), "nope")
    one_line_error(run("fgd-train", "--cache", cache, "--split", "all", "--checkpoint", tmp_path / "m.safetensors"),
                   "checkpoint not found")
    one_line_error(run("fgd-train", "--cache", cache, "--split", "all", "--out", tmp_path / "x",
                       "--regions", "head"), "--regions")


def test_eval_with_a_checkpoint_on_the_held_out_frames(cache, tmp_path, unseen_wav):
    import soundfile as sf

    audio, sr = sf.read(unseen_wav, dtype="float32")
    short_wav = tmp_path / "unseen_5s.wav"  # 5 s of the real unseen clip keeps the test short
    sf.write(short_wav, audio[10 * sr:15 * sr], sr)
    c = Cache(cache)
    torch_model = FaceCapGes(ModelConfig())  # an untrained but real model: the pipeline, not the quality, is tested
    name = c.clips()[0]["name"]
    meta = {"neutral_window": c.load(name)["pose"][:torch_model.cfg.n_history].tolist(), "speaker": 2,
            "skeleton": c.index["skeleton"]}
    ckpt = save_checkpoint(tmp_path / "run" / "model.safetensors", torch_model, meta)
    res = run("fgd-train", "--cache", cache, "--split", "all", "--holdout-from", 766, "--checkpoint", ckpt,
              "--epochs", 1, "--quiet")
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "run" / "model.fgd" / "fgd_autoencoder.safetensors").is_file()
    assert sorted(p.name for p in (tmp_path / "run").glob("*.safetensors")) == ["model.safetensors"]
    out = tmp_path / "eval"
    res = run("eval", "--cache", cache, "--checkpoint", ckpt, "--holdout-from", 860, "--out", out,
              "--offsets", "2,3.5", "--audio", short_wav, "--samples", 2, "--quiet")
    assert res.returncode == 0, res.stderr
    data = json.loads((out / "metrics.json").read_text())
    paired = data["paired"]
    assert paired["n_frames"] == 957 - 860 and paired["first_frame"] == 860
    for region in ("with_head", "without_head"):
        rows = paired["regions"][region]["methods"]
        assert set(rows) == {"ground truth", "mean pose", "random real segment", "FaceCapGes (model)"}
        assert rows["ground truth"]["FGD"] < 1e-3 and rows["ground truth"]["SRGR"] == 1.0
        for m in rows.values():
            assert all(m[k] is not None and np.isfinite(m[k]) for k in ("FGD", "SRGR", "BA", "BA_gap", "L1DIV"))
        model = rows["FaceCapGes (model)"]
        assert model["n_samples"] == 2 and model["L1DIV_samples"] >= 0 and rows["ground truth"]["L1DIV_samples"] is None
    unseen = data["unseen_audio"][str(short_wav)]["regions"]["with_head"]["methods"]["FaceCapGes (model)"]
    assert unseen["FGD"] is not None and unseen["SRGR"] is None and 0 <= unseen["BA"] <= 1
    realism = paired["realism"]  # issue #25 §3 figures, engine-agnostic (evaluation.realism)
    assert set(realism["methods"]) == set(rows) and realism["database"]["frames"] == 860
    model_real = realism["methods"]["FaceCapGes (model)"]
    assert model_real["transitions_per_min"] >= 0 and 0 <= model_real["database_share_used"] <= 1
    assert realism["methods"]["random real segment"]["longest_copy_s"] == pytest.approx(97 / 15)  # it is copied
    assert "classifier" not in realism["methods"]["ground truth"] and "classifier" in model_real
    unseen_real = data["unseen_audio"][str(short_wav)]["realism"]["methods"]["FaceCapGes (model)"]
    assert unseen_real["classifier_windows"] >= 0 and unseen_real["speech_s"] > 0
    md = (out / "metrics.md").read_text()
    assert "Upper body (without head)" in md and "Unseen audio" in md
    assert md.count("Against the targets of issue #25 §3") == 2 and "transitions a minute | ≤ 1 |" in md
    for f in ("beat_timeline.png", "joint_speed.png", "real_vs_generated.mp4"):
        assert (out / f).stat().st_size > 1000
    one_line_error(run("eval", "--cache", cache, "--checkpoint", ckpt, "--holdout-from", 860, "--out", out,
                       "--quiet"), "metrics.json", "--force")
    one_line_error(run("eval", "--cache", cache, "--checkpoint", ckpt, "--out", tmp_path / "e2", "--quiet",
                       "--split", "train"), "no 'train' clips")
    one_line_error(run("eval", "--cache", cache, "--checkpoint", ckpt, "--holdout-from", 400, "--samples", 1,
                       "--no-video", "--out", tmp_path / "e3", "--quiet"), "557 frames", "later --holdout-from")
