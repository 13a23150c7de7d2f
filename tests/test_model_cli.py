"""train / generate / styles through the real command line, on the real shared clip."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch

from facecapges.arkit import BEAT_NAMES
from runtime_helpers import cli

TINY = """
model:
  audio_frontend_channels: [8, 8, 8]
  audio_tcn_channels: 8
  audio_dim: 16
  face_tcn_channels: 8
  face_dim: 8
  lstm_hidden: 16
  mlp_hidden: 16
  disc_channels: 8
train:
  batch_size: 32
  adv_start_epoch: 2
  num_threads: 1
"""


def run(*args: str, ok: bool = True):
    p = cli(*args)
    if ok:
        assert p.returncode == 0, p.stderr + p.stdout
    else:
        assert p.returncode != 0, p.stdout
        assert "Traceback" not in p.stderr, p.stderr
        assert p.stderr.strip().startswith("error:"), p.stderr
    return p


@pytest.fixture(scope="module")
def cache(beat_cache) -> Path:
    return beat_cache  # the session's `prepare` of the BEAT sample (tests/conftest.py)


@pytest.fixture(scope="module")
def trained(tmp_path_factory, cache) -> Path:
    d = tmp_path_factory.mktemp("run")
    cfg = d / "tiny.yaml"
    cfg.write_text(TINY)
    run("train", "--cache", str(cache), "--speaker", "2", "--out", str(d / "run"), "--config", str(cfg),
        "--epochs", "2", "--split", "all", "--holdout-from", "766")
    return d / "run"


@pytest.mark.slow
def test_train_writes_checkpoint_log_and_resumes_exactly(tmp_path, cache, trained):
    log = (trained / "log.csv").read_text().splitlines()
    assert log[0].startswith("epoch,total,rec") and len(log) == 3
    row = dict(zip(log[0].split(","), log[2].split(",")))
    assert math.isfinite(float(row["total"])) and float(row["held_rec"]) > 0
    assert row["adv"] != ""  # the discriminator joined at epoch 2 (adv_start_epoch)
    # 1 epoch, then --resume to 2, must equal the 2-epoch run bit for bit: the same code path on this CPU (the same
    # batches in the same order, one thread, the state restored bit for bit), so exact on any CPU (docs/testing.md)
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(TINY)
    run("train", "--cache", str(cache), "--speaker", "2", "--out", str(tmp_path / "r"), "--config", str(cfg),
        "--epochs", "1", "--split", "all", "--holdout-from", "766")
    run("train", "--cache", str(cache), "--speaker", "2", "--out", str(tmp_path / "r"), "--epochs", "2", "--resume")
    a = torch.load(trained / "last.pt", weights_only=True)["G"]
    b = torch.load(tmp_path / "r" / "last.pt", weights_only=True)["G"]
    for k in a:
        assert torch.equal(a[k], b[k]), k
    # an existing run is never overwritten without asking
    p = run("train", "--cache", str(cache), "--speaker", "2", "--out", str(tmp_path / "r"), "--split", "all", ok=False)
    assert "--resume" in p.stderr


def test_train_bad_inputs(tmp_path, cache):
    p = run("train", "--cache", str(tmp_path / "none"), "--speaker", "2", "--out", str(tmp_path / "x"), ok=False)
    assert "none" in p.stderr
    p = run("train", "--cache", str(cache), "--speaker", "2", "--out", str(tmp_path / "x"), ok=False)
    assert "--split all" in p.stderr  # the shared clip is a BEAT test clip
    bad = tmp_path / "bad.yaml"
    bad.write_text("model:\n  lstm_hiden: 3\n")
    p = run("train", "--cache", str(cache), "--speaker", "2", "--out", str(tmp_path / "x"), "--config", str(bad),
            "--split", "all", ok=False)
    assert "lstm_hiden" in p.stderr


@pytest.mark.slow
def test_generate_audio_only_frame_count_and_bvh(tmp_path, trained, unseen_wav):
    out = tmp_path / "g.bvh"
    p = run("generate", "--audio", str(unseen_wav), "--checkpoint", str(trained / "model.safetensors"),
            "--out", str(out), "--json")
    summary = json.loads(p.stdout.strip().splitlines()[-1])
    info = sf.info(str(unseen_wav))
    assert summary["frames"] == math.ceil(info.frames / info.samplerate * 15 - 1e-6)
    from facecapges.io.bvh import read_bvh

    b = read_bvh(out)
    assert b.n_frames == summary["frames"] and b.fps == 15 and b.skeleton.n_joints == 75
    assert np.isfinite(b.motion).all()
    run("generate", "--audio", str(unseen_wav), "--checkpoint", str(trained), "--out", str(out), ok=False)  # exists


@pytest.mark.slow
def test_generate_with_face_json_any_fps_and_unknown_names(tmp_path, trained, beat_wav):
    T = 60 * 5  # 5 s at 60 fps, BEAT's face rate
    rng = np.random.default_rng(0)
    names = list(BEAT_NAMES) + ["notABlendshape"]
    frames = [{"time": i / 60, "weights": rng.uniform(0, 1, len(names)).tolist()} for i in range(T)]
    face = tmp_path / "f.json"
    face.write_text(json.dumps({"names": names, "frames": frames}))
    p = run("generate", "--audio", str(beat_wav), "--face", str(face), "--checkpoint", str(trained),
            "--out", str(tmp_path / "o.bvh"))
    assert "notABlendshape" in p.stderr  # reported, ignored
    frames[3]["weights"][0] = float("nan")
    face.write_text(json.dumps({"names": names, "frames": frames}).replace("NaN", "NaN"))
    p = run("generate", "--audio", str(beat_wav), "--face", str(face), "--checkpoint", str(trained),
            "--out", str(tmp_path / "o2.bvh"), ok=False)
    assert "f.json" in p.stderr


@pytest.mark.slow
def test_generate_bad_audio_and_checkpoint(tmp_path, trained):
    silent = tmp_path / "silent.wav"
    sf.write(silent, np.zeros(16000, np.float32), 16000)
    p = run("generate", "--audio", str(silent), "--checkpoint", str(trained), "--out", str(tmp_path / "a.bvh"), ok=False)
    assert "silent" in p.stderr
    short = tmp_path / "short.wav"
    sf.write(short, (np.random.default_rng(0).normal(size=300) * 0.3).astype(np.float32), 16000)
    p = run("generate", "--audio", str(short), "--checkpoint", str(trained), "--out", str(tmp_path / "b.bvh"), ok=False)
    assert "shorter than one frame" in p.stderr
    empty = tmp_path / "empty.wav"
    empty.write_bytes(b"")
    run("generate", "--audio", str(empty), "--checkpoint", str(trained), "--out", str(tmp_path / "c.bvh"), ok=False)
    corrupt = tmp_path / "corrupt.safetensors"
    corrupt.write_bytes((trained / "model.safetensors").read_bytes()[:5000])
    p = run("generate", "--audio", str(short), "--checkpoint", str(corrupt), "--out", str(tmp_path / "d.bvh"), ok=False)
    assert "corrupt.safetensors" in p.stderr


@pytest.mark.slow
def test_train_records_its_data_and_holdout_from_replaces_the_configs_fraction(tmp_path, cache):
    """The style records each clip's dataset and licence (what tests/test_shipped_licences.py checks), and
    ``--holdout-from`` wins over a config's ``holdout_fraction`` (the shipped recipe's), not the other way."""
    from facecapges.styles import load_style

    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(TINY + "  holdout_fraction: 0.2\n")
    run("train", "--cache", str(cache), "--speaker", "2", "--out", str(tmp_path / "r"), "--config", str(cfg),
        "--epochs", "1", "--split", "all", "--holdout-from", "700")
    meta = load_style(tmp_path / "r" / "model.safetensors").meta
    assert meta["train_config"]["holdout_from"] == 700 and meta["train_config"]["holdout_fraction"] is None
    assert meta["neutral_window"] is not None and not meta["train_config"]["init_from"]
    assert meta["data"] == {"clips": [{"name": "2_scott_0_1_1", "dataset": "BEAT"}], "licence": "CC BY-NC 4.0",
                            "performer": "scott"}
