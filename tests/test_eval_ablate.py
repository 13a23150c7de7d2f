"""Ablation study (thesis 5.7): the offline-decoding variant, its trainer and ``facecapges ablate``."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import yaml

from facecapges.network.bidirectional import BidirectionalDecoder, load_bidirectional, save_bidirectional
from facecapges.network.config import ModelConfig
from facecapges.network.network import FaceCapGes
from runtime_helpers import cli

TINY = dict(audio_frontend_channels=(8, 8, 8), audio_tcn_channels=8, audio_dim=16, face_tcn_channels=8, face_dim=8,
            lstm_hidden=16, mlp_hidden=16, disc_channels=8, dropout=0.0)


def run(*args):
    return cli(*map(str, args))


def _inputs(T: int, cfg: ModelConfig, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(1, T, cfg.samples_per_frame, generator=g) * 0.1, torch.rand(1, T, 52, generator=g),
            torch.randn(1, T, 6, generator=g))


def test_offline_is_bidirectional_unlike_facecapges():
    """Early outputs of the offline model depend on later inputs; FaceCapGes's never do."""
    torch.manual_seed(0)
    cfg = ModelConfig(**TINY)
    N, L = cfg.n_history, 34
    off, fcg = BidirectionalDecoder(cfg).eval(), FaceCapGes(cfg).eval()
    audio, face, head = _inputs(N + L, cfg)
    seed = torch.randn(1, N, cfg.pose_dim) * 0.1

    def outputs(a, f, h):
        with torch.no_grad():
            return off(a, f, h, seed)[:, N:], fcg.rollout(fcg.encode(a, f, h), seed)  # both (1, L, D)

    # 1. exact dependency structure by autograd: d(first generated frame) / d(inputs of the last frames)
    a = audio.clone().requires_grad_(True)
    f = face.clone().requires_grad_(True)
    h = head.clone().requires_grad_(True)
    off(a, f, h, seed)[:, N].sum().backward()
    assert all(x.grad[:, -4:].abs().sum() > 0 for x in (a, f, h))  # the backward LSTMs carry the future back
    a.grad = f.grad = h.grad = None
    fcg.rollout(fcg.encode(a, f, h), seed)[:, 0].sum().backward()
    assert all(x.grad[:, N + 1:].abs().sum() == 0 for x in (a, f, h))  # closed loop: strictly causal
    # 2. the same seen on outputs: change only frames from N+4 on
    a2, f2, h2 = audio.clone(), face.clone(), head.clone()
    a2[:, N + 4:] += 0.5
    f2[:, N + 4:] = 1.0 - f2[:, N + 4:]
    h2[:, N + 4:] *= -1
    (o1, r1), (o2, r2) = outputs(audio, face, head), outputs(a2, f2, h2)
    assert (o1[:, :4] - o2[:, :4]).abs().max() > 1e-4  # offline: frames before the change move
    assert torch.equal(r1[:, :4], r2[:, :4])  # FaceCapGes: bit-identical before the change
    assert (r1[:, 4:] - r2[:, 4:]).abs().max() > 1e-4  # ... and it does react where the change happens


def test_offline_generate_and_checkpoint_round_trip(tmp_path):
    torch.manual_seed(1)
    cfg = ModelConfig(**TINY)
    m = BidirectionalDecoder(cfg).eval()
    T = 40
    rng = np.random.default_rng(0)
    audio = rng.normal(0, 0.1, (T, cfg.samples_per_frame)).astype(np.float32)
    face, head = rng.uniform(0, 1, (T, 52)).astype(np.float32), rng.normal(0, 1, (T, 6)).astype(np.float32)
    seed = rng.normal(0, 0.1, (cfg.n_history, 47, 6)).astype(np.float32)
    out = m.generate(audio, face, head, seed)
    assert out.shape == (T, 47, 6) and np.isfinite(out).all()
    # one pass == decoding the seed + sequence as one segment
    with torch.no_grad():
        z = torch.cat([m.no_input_embedding().expand(1, cfg.n_history, -1),
                       m.encode(*(torch.from_numpy(x)[None] for x in (audio, face, head)))], 1)
        ref = m.decode(z, torch.from_numpy(seed.reshape(1, cfg.n_history, -1)))[0, cfg.n_history:]
    np.testing.assert_allclose(out.reshape(T, -1), ref.numpy(), atol=1e-6)
    p = save_bidirectional(tmp_path / "off.safetensors", m, {"neutral_window": seed.tolist()})
    m2, meta = load_bidirectional(p)
    np.testing.assert_array_equal(m2.generate(audio, face, head, seed), out)
    assert meta["format"] == "facecapges-offline-1" and meta["model_config"]["lstm_hidden"] == 16
    from facecapges.errors import UserError
    from facecapges.styles import load_style

    with pytest.raises(UserError):  # not a streaming checkpoint
        load_style(p)


@pytest.mark.slow
def test_offline_trainer_learns_the_segments(tmp_path):
    """A few epochs of the offline trainer lower its loss on the M frames after the seed."""
    from facecapges.training.bidirectional import build_bidirectional_trainer
    from facecapges.training.segments import ClipArrays

    rng = np.random.default_rng(0)
    T = 200
    t = np.arange(T)[:, None, None]
    pose = (np.sin(t / 5.0 + np.arange(47)[None, :, None] / 7.0) * 0.3
            + np.array([1, 0, 0, 0, 1, 0], np.float32)).astype(np.float32)
    clip = ClipArrays("synthetic", pose, rng.normal(0, 1, (T, 6)).astype(np.float32),
                      np.zeros((T, 52), np.float32), rng.normal(0, 0.05, T * 1067).astype(np.float32))
    tr = build_bidirectional_trainer([clip], tmp_path / "run", dict(TINY),
                               dict(epochs=8, batch_size=8, optimizer="adam", lr_base=0.016, adv_start_epoch=4,
                                    holdout_from=150, num_threads=1), {"speaker": 2, "clips": ["synthetic"]})
    hist = tr.fit(progress=False)
    assert hist[-1]["rec"] < hist[0]["rec"] and "adv" in hist[-1] and "held_rec" in hist[-1]
    _m, meta = load_bidirectional(tmp_path / "run" / "model.safetensors")
    assert meta["epochs_trained"] == 8 and meta["train_config"]["holdout_from"] == 150
    assert np.asarray(meta["neutral_window"]).shape == (16, 47, 6)
    lines = (tmp_path / "run" / "log.csv").read_text().splitlines()
    assert len(lines) == 9 and lines[0].startswith("epoch,total,rec")


def test_a_checkpoint_is_reused_as_the_full_variant_only_when_trained_by_the_same_recipe():
    """The reuse rule accepts a checkpoint of the ablation's own recipe and rejects any other.

    The ablation trains every variant from random weights (a config's ``init_from`` is
    dropped) on the frames before one hold-out frame (``--holdout-from`` replaces the config's
    ``holdout_fraction``), so the shipped network style, which holds out each of its two takes'
    last 20 %, is not reused for a one-take ablation.
    """
    from facecapges.evaluation.ablate import _same_recipe, default_config_path, make_recipe
    from facecapges.styles import DEFAULT_NETWORK_STYLE, load_style

    assert default_config_path().is_file()
    shipped = load_style(style=DEFAULT_NETWORK_STYLE).meta
    assert make_recipe(None, 2, None, None, None, 15.0).train_over["holdout_fraction"] == 0.2
    recipe = make_recipe(None, 2, None, None, 765, 15.0)
    assert recipe.split == "all" and recipe.holdout_from == 765
    assert "init_from" not in recipe.train_over and "holdout_fraction" not in recipe.train_over
    assert not shipped["train_config"]["init_from"] and shipped["train_config"]["holdout_fraction"] == 0.2
    assert _same_recipe(shipped, recipe, None, ["2_scott_0_1_1"]) == "training config differs"  # so not reused
    mcfg, tcfg = recipe.resolved()
    meta = dict(shipped, clips=["2_scott_0_1_1"], model_config=mcfg, train_config=tcfg, epochs_trained=tcfg["epochs"])
    assert _same_recipe(meta, recipe, None, ["2_scott_0_1_1"]) is None
    assert _same_recipe(meta, make_recipe(None, 2, None, 3, None, 15.0), None, ["2_scott_0_1_1"])
    assert _same_recipe(meta, recipe, {"head_dim": 0}, ["2_scott_0_1_1"]) == "model config differs"
    assert _same_recipe(meta, recipe, None, ["other"]) == "other clips"


@pytest.fixture(scope="module")
def cache(beat_take_cache):
    return beat_take_cache  # the session's prepare() of the sample take alone (tests/conftest.py)


@pytest.mark.slow
def test_ablate_trains_and_evaluates_every_variant(cache, tmp_path):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump({"model": {k: list(v) if isinstance(v, tuple) else v for k, v in TINY.items()},
                                   "train": dict(batch_size=16, optimizer="adam", lr_base=0.008, epochs=3,
                                                 adv_start_epoch=2, holdout_from=860, num_threads=1)}))
    out = tmp_path / "abl"
    args = ("ablate", "--cache", cache, "--speaker", 2, "--out", out, "--config", cfg, "--epochs", 1,
            "--fgd-epochs", 1, "--samples", 2, "--offsets", "2,3.5", "--quiet")
    res = run(*args)
    assert res.returncode == 0, res.stderr
    doc = json.loads((out / "ablation.json").read_text())
    labels = ["FaceCapGes (full)", "without head pose", "offline decoding", "CaMN (baseline)"]
    for region in ("with_head", "without_head"):
        rows = doc["result"]["regions"][region]["methods"]
        assert list(rows) == ["ground truth", "mean pose", "random real segment"] + labels
        assert rows["ground truth"]["FGD"] < 1e-3 and rows["ground truth"]["SRGR"] == 1.0
        for name, m in rows.items():
            assert all(m[k] is not None and np.isfinite(m[k]) for k in ("FGD", "SRGR", "BA", "BA_gap", "L1DIV")), name
        for name in labels:
            assert rows[name]["n_samples"] == 2 and rows[name]["L1DIV_samples"] is not None
    assert doc["result"]["n_frames"] == 957 - 860 and doc["result"]["first_frame"] == 860
    for v in ("full", "no_head", "offline", "camn"):
        info = doc["variants"][v]
        assert info["source"] == "trained" and info["epochs"] == 1 and (out / "runs" / v / "model.safetensors").is_file()
    from facecapges.styles import load_style

    assert load_style(out / "runs" / "no_head" / "model.safetensors").model.cfg.head_dim == 0
    assert load_style(out / "runs" / "full" / "model.safetensors").model.cfg.head_dim == 12
    md = (out / "ablation.md").read_text()
    assert "Upper body (without head)" in md and all(lb in md for lb in labels) and "Table 5.3" in md
    # a second run refuses to overwrite; with --force it reuses the finished runs instead of training
    again = run(*args)
    assert again.returncode == 2 and "--force" in again.stderr and "Traceback" not in again.stderr
    res = run(*args, "--force", "--variants", "no_head,offline")
    assert res.returncode == 0, res.stderr
    assert res.stdout.count("already holds this recipe's model: reused") == 2
    assert list(json.loads((out / "ablation.json").read_text())["variants"]) == ["no_head", "offline"]
    # any checkpoint can stand as the 'full' row; the table says when its recipe is another one
    res = run(*args, "--force", "--variants", "full,camn", "--samples", 1,
              "--given", f"full={out / 'runs' / 'no_head' / 'model.safetensors'},camn={out / 'runs' / 'camn'}/model.safetensors")
    assert res.returncode == 0, res.stderr
    info = json.loads((out / "ablation.json").read_text())["variants"]["full"]
    assert info["source"] == "given checkpoint (not this recipe: model config differs)"
    assert "given checkpoint (not this recipe" in (out / "ablation.md").read_text()
    assert json.loads((out / "ablation.json").read_text())["variants"]["camn"]["source"] == "given checkpoint"
    bad = run(*args, "--force", "--variants", "full", "--given", "camn")
    assert bad.returncode == 2 and "--given" in bad.stderr
    bad = run("ablate", "--cache", cache, "--out", tmp_path / "x", "--config", cfg, "--variants", "diffsheg", "--quiet")
    assert bad.returncode == 2 and bad.stderr.startswith("error: ") and "--variants" in bad.stderr


@pytest.mark.slow
def test_bench_counts_macs_of_the_streaming_step():
    """The 5.8 speed report counts every matrix product of a step, per kernel stage too (no timing asserted)."""
    from facecapges.benchmarks.model import speed_report
    from facecapges.styles import DEFAULT_NETWORK_STYLE, load_style

    ckpt = load_style(style=DEFAULT_NETWORK_STYLE)
    cfg = ckpt.model.cfg
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        rep = speed_report(ckpt, quick=True)
    finally:
        torch.set_num_threads(threads)
    comp = rep["compute"]
    assert set(rep["stages_ms"]) >= {"audio_frontend", "decoder", "to_bvh_euler"}  # from the step's profiler scopes
    assert comp["lstm_window_check"]["counted_equals_analytic"]
    assert sum(comp["macs_per_frame_by_stage"].values()) == comp["macs_per_frame"]
    fe = ckpt.model.audio_enc.frontend
    if cfg.audio_repr == "raw":  # hand count: Σ out_len · C_out · C_in · k over its convolutions
        length, macs = cfg.samples_per_frame, 0
        for conv in list(fe.convs) + [fe.collapse]:
            length = (length - conv.kernel_size[0]) // conv.stride[0] + 1
            macs += length * conv.out_channels * conv.in_channels * conv.kernel_size[0]
        assert comp["macs_per_frame_by_stage"]["audio_frontend"] == macs
    else:  # Mel features: at least the Mel filter bank and the two linear layers
        macs = fe.features.mel_basis.numel() + fe.proj.weight.numel() + fe.out.weight.numel()  # power averaged first
        assert comp["macs_per_frame_by_stage"]["audio_frontend"] >= macs
    H, W = cfg.lstm_hidden, cfg.window
    assert comp["macs_per_frame_by_stage"]["decoder"] > 2 * W * H * 4 * H  # both 17-step recurrences at least
    # 1.6x for the shipped small Mel model: its encoders, which the naive loop re-runs over the window,
    # are small beside the decoder, which both loops run in full
    assert comp["naive_macs_per_frame"] > 1.3 * comp["macs_per_frame"]
    assert rep["per_frame"]["frames"] == 60 and rep["cpu_peak_gflops_1thread"] > 0
    assert 0 < rep["fraction_of_peak"] < 1
