"""Multi-process training on CPU (gloo): 2 ranks == 1 process with the same global batch.

73 training segments (frames >= 756 held out): the global batch of 14 leaves a last
batch of 3 that the two ranks split 2/1, so the parity test checks the loss weighting
of uneven shares; the torchrun test's global batch of 24 leaves a last batch of one
segment, which one rank joins with weight 0 (it must not hang).
"""

from __future__ import annotations

import os
import socket
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.multiprocessing as mp

from runtime_helpers import cli as run_cli
from runtime_helpers import cli_process

TINY_MODEL = dict(audio_frontend_channels=[8, 8, 8], audio_tcn_channels=8, audio_dim=16, face_tcn_channels=8,
                  face_dim=8, lstm_hidden=16, mlp_hidden=16, disc_channels=8, dropout=0.0)
TRAIN = dict(adv_start_epoch=2, num_threads=1, epochs=2, holdout_from=756, seed=3, lr_base=1.0, grad_clip=1.0)
GLOBAL_BATCH = 14


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cli(*args: str, torchrun: int = 0, port: int = 0) -> subprocess.CompletedProcess:
    """``facecapges ARGS`` under ``torchrun`` (``torchrun`` ranks, a real process group), else in-process."""
    if torchrun:
        p = cli_process(*args, launcher=("-m", "torch.distributed.run", f"--nproc_per_node={torchrun}",
                                         "--master_addr=127.0.0.1", f"--master_port={port}", "-m", "facecapges"))
    else:
        p = run_cli(*args)
    assert p.returncode == 0, p.stderr[-3000:] + p.stdout[-2000:]
    return p


@pytest.fixture(scope="module")
def cache(beat_cache) -> Path:
    return beat_cache  # the session's `prepare` of the BEAT sample (tests/conftest.py)


def _rank_worker(rank: int, world: int, port: int, cache: Path, out: Path) -> None:
    from facecapges.training.distributed import init_distributed, shutdown
    from facecapges.training.segments import load_clips
    from facecapges.training.train import build_trainer

    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port), RANK=str(rank), WORLD_SIZE=str(world),
                      LOCAL_RANK=str(rank))
    ctx = init_distributed("cpu")
    try:
        _, clips = load_clips(cache, 2, "all")
        tr = build_trainer(clips, out / "run", dict(TINY_MODEL), dict(TRAIN, batch_size=GLOBAL_BATCH // world),
                           {"split": "all"}, resume=False, dist=ctx)
        tr.fit()
        torch.save({"G": tr.G.state_dict(), "D": tr.D.state_dict(), "history": tr.history,
                    "opt_lr": tr.opt_g.param_groups[0]["lr"]}, out / f"rank{rank}.pt")
    finally:
        shutdown(ctx)


@pytest.mark.slow
def test_two_gloo_ranks_equal_each_other_and_one_process(tmp_path, cache):
    from facecapges.training.segments import load_clips
    from facecapges.training.train import build_trainer

    mp.spawn(_rank_worker, args=(2, free_port(), cache, tmp_path), nprocs=2, join=True)
    r0 = torch.load(tmp_path / "rank0.pt", weights_only=False)
    r1 = torch.load(tmp_path / "rank1.pt", weights_only=False)
    for net in ("G", "D"):  # DDP keeps the replicas identical, bit for bit (the same all-reduced gradients)
        for k in r0[net]:
            assert torch.equal(r0[net][k], r1[net][k]), (net, k)
    # rank 0 alone wrote the run folder
    assert {p.name for p in (tmp_path / "run").iterdir()} == {"last.pt", "model.safetensors", "log.csv",
                                                                "summary.json"}

    _, clips = load_clips(cache, 2, "all")
    threads = torch.get_num_threads()
    try:
        one = build_trainer(clips, tmp_path / "one", dict(TINY_MODEL), dict(TRAIN, batch_size=GLOBAL_BATCH),
                            {"split": "all"}, resume=False)
        one.fit()
    finally:
        torch.set_num_threads(threads)
    assert len(one.train_set) % GLOBAL_BATCH == 3  # the last global batch splits 2/1
    assert r0["opt_lr"] == pytest.approx(one.opt_g.param_groups[0]["lr"])  # lr from the global batch
    # Two ranks against one process are two paths to one training run: each rank's forward pass runs another batch
    # (7 segments, not 14: other GEMM blockings) and the gradients are summed in another order (each share, then
    # gloo's all-reduce), so they agree to float32 rounding, ≲ 100 ulps of each gradient. Plain SGD at lr = 0.109 on
    # gradients clipped to norm 1 moves a weight by ≤ 0.109·|g| a step: 12 steps part the weights by
    # ≤ 12 · 0.109 · 100 · 1.2e-7 ≈ 1.6e-5 (weight units), whence 2e-5; a loss (a mean of ~1e5 terms) moves by its
    # sums' ~20 ulps plus |∇L|·|Δw|, whence 1e-4 relative. Weighting the uneven 2/1 share wrongly would move the last
    # step's update by ~lr·|g|/6 ≈ 1e-3, far above both.
    for h2, h1 in zip(r0["history"], one.history):  # the same loss curve (D joins at epoch 2)
        for k in ("total", "rec", "vel", "acc", "adv", "d", "held_rec", "held_vel", "held_acc"):
            if k in h1:
                assert h2[k] == pytest.approx(h1[k], rel=1e-4), (h1["epoch"], k)
    assert "adv" in one.history[-1]
    for net, ref in (("G", one.G.state_dict()), ("D", one.D.state_dict())):
        for k, v in ref.items():
            assert torch.allclose(r0[net][k], v, atol=2e-5, rtol=0), (net, k, float((r0[net][k] - v).abs().max()))


@pytest.mark.slow
def test_torchrun_cli_then_resume_with_one_process(tmp_path, cache):
    import yaml

    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump({"model": TINY_MODEL, "train": dict(TRAIN, batch_size=12, epochs=1)}))
    run = tmp_path / "run"
    p = cli("train", "--cache", str(cache), "--speaker", "2", "--out", str(run), "--config", str(cfg),
            "--split", "all", "--amp", torchrun=2, port=free_port())
    assert "2 processes, global batch 24" in p.stdout
    assert p.stdout.count("checkpoint:") == 1  # one rank speaks
    assert "--amp is GPU-only" in p.stderr
    state = torch.load(run / "last.pt", weights_only=True)
    assert state["epoch"] == 1 and state["world_size"] == 2
    # resume the 2-process run with 1 process: the global batch and the lr follow the new count
    p = cli("train", "--cache", str(cache), "--speaker", "2", "--out", str(run), "--epochs", "2", "--resume")
    rows = [line.split(",") for line in (run / "log.csv").read_text().splitlines()]
    head = rows[0]
    assert [r[0] for r in rows[1:]] == ["1", "2"]
    assert [(r[head.index("processes")], r[head.index("global_batch")]) for r in rows[1:]] == [("2", "24"),
                                                                                              ("1", "12")]
    assert all(np.isfinite(float(r[head.index("total")])) for r in rows[1:])
    state = torch.load(run / "last.pt", weights_only=True)
    assert state["epoch"] == 2 and state["world_size"] == 1
    lr = state["opt_g"]["param_groups"][0]["lr"]
    assert lr == pytest.approx(1.0 * 12 / 128)
    from facecapges.styles import load_style

    ck = load_style(run / "model.safetensors")
    assert ck.meta["epochs_trained"] == 2 and ck.meta["global_batch"] == 12
