"""Training's trust boundaries: a crafted resume file runs no code, every config field is checked
with a message naming it, one training per run folder, no log row lost to a kill, no file
overwritten without --force."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from facecapges.errors import UserError
from facecapges.network.config import load_config_file
from facecapges.training.resume_file import RunFolderLock, load_state, save_state
from runtime_helpers import cli, refused

TINY_MODEL = dict(audio_frontend_channels=[8, 8, 8], audio_tcn_channels=8, audio_dim=16, face_tcn_channels=8,
                  face_dim=8, lstm_hidden=16, mlp_hidden=16, disc_channels=8)


class Payload:
    """Pickles to a call that creates ``marker`` when the file is unpickled."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.mkdir, (self.marker,))


def test_a_crafted_resume_file_runs_no_code(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    marker = tmp_path / "pwned"
    torch.save({"G": Payload(marker), "epoch": 1}, run / "last.pt")
    with pytest.raises(UserError, match="could run code"):
        load_state(run / "last.pt")
    p = cli("train", "--cache", str(tmp_path / "nocache"), "--speaker", "2", "--out", str(run), "--resume")
    refused(p, "last.pt", "could run code")
    assert not marker.exists()  # the payload never ran
    # a real state round-trips: tensors, numpy arrays and plain values
    state = {"G": {"w": torch.arange(4.0)}, "neutral": np.ones((2, 3), np.float32), "epoch": 3,
             "history": [{"epoch": 1, "total": 0.5}], "meta": {"clips": ("a", "b"), "x": None}}
    back = load_state(save_state(tmp_path / "s.pt", state))
    assert torch.equal(back["G"]["w"], state["G"]["w"]) and back["epoch"] == 3 and back["meta"]["clips"] == ("a", "b")
    assert isinstance(back["neutral"], np.ndarray) and back["neutral"].shape == (2, 3)
    (tmp_path / "junk.pt").write_bytes(b"\x80\x02not a pickle")
    with pytest.raises(UserError, match="cannot read"):
        load_state(tmp_path / "junk.pt")


@pytest.mark.parametrize("text, field", [
    ("train:\n  batch_size: abc\n", "train.batch_size"),
    ("train:\n  batch_size: 0\n", "train.batch_size"),
    ("train:\n  clip_len: 3\n", "train.clip_len"),
    ("train:\n  stride: 0\n", "train.stride"),
    ("model:\n  lstm_hidden: 0\n", "model.lstm_hidden"),
    ("model:\n  n_joints: 10\n", "model.n_joints"),
    ("train: 5\n", "'train:' must be a mapping"),
    ("train:\n  epochs: -3\n", "train.epochs"),
    ("train:\n  lr_base: .nan\n", "train.lr_base"),
    ("train:\n  optimizer: rmsprop\n", "train.optimizer"),
    ("model:\n  audio_tcn_dilations: [1, x]\n", "model.audio_tcn_dilations[1]"),
    ("train:\n  holdout_from: true\n", "train.holdout_from"),
    ("model:\n  dropout: 2\n", "model.dropout"),
])
def test_every_config_field_is_checked_by_name(tmp_path, text, field):
    f = tmp_path / "c.yaml"
    f.write_text(text)
    with pytest.raises(UserError, match=field.replace("[", r"\[").replace("]", r"\]")):
        load_config_file(f)


def test_binary_and_bad_config_files_are_one_line_errors(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(UserError, match="not valid YAML"):
        load_config_file(f)
    f.write_text("train:\n  epochs: -3\n")  # through the command: refused before any data is read
    p = cli("train", "--cache", str(tmp_path / "nocache"), "--speaker", "2", "--out", str(tmp_path / "r"),
            "--config", str(f), "--split", "all")
    refused(p, "train.epochs")
    assert not (tmp_path / "r" / "model.safetensors").exists()
    good = tmp_path / "good.yaml"
    good.write_text("model:\n  lstm_hidden: 16\ntrain:\n  batch_size: 16\n  holdout_from: 766\n")
    assert load_config_file(good) == ({"lstm_hidden": 16}, {"batch_size": 16, "holdout_from": 766})


def test_one_training_per_run_folder(tmp_path):
    run = tmp_path / "run"
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time; from facecapges.training.resume_file import RunFolderLock\n"
        f"RunFolderLock({str(run)!r}).acquire(); print('locked', flush=True); time.sleep(60)")],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        p = cli("train", "--cache", str(tmp_path / "nocache"), "--speaker", "2", "--out", str(run), "--resume")
        refused(p, "another training is using this run folder")
        with pytest.raises(UserError, match="another training"):
            RunFolderLock(run).acquire()
    finally:
        holder.kill()
        holder.wait()
    time.sleep(0.1)
    with RunFolderLock(run), RunFolderLock(run):  # free again (the kernel dropped it), re-entrant in-process
        pass
    assert sorted(os.listdir(run)) == []  # no lock file left behind


def _clips():
    from facecapges.training.segments import ClipArrays

    rng = np.random.default_rng(0)
    T = 140
    pose = np.zeros((T, 47, 6), np.float32)
    pose[..., 0] = pose[..., 4] = 1.0
    pose += rng.normal(scale=0.05, size=pose.shape).astype(np.float32)
    head = np.tile(np.array([1, 0, 0, 0, 1, 0], np.float32), (T, 1))
    return [ClipArrays("synthetic", pose, head, rng.uniform(size=(T, 52)).astype(np.float32),
                       rng.normal(scale=0.1, size=T * 1067).astype(np.float32))]


@pytest.mark.slow
def test_a_log_row_lost_to_a_kill_comes_back_on_resume(tmp_path):
    from facecapges.training.train import build_trainer

    n = torch.get_num_threads()
    try:
        clips = _clips()
        train = dict(batch_size=8, epochs=1, num_threads=1, adv_start_epoch=2, holdout_from=110)
        tr = build_trainer(clips, tmp_path / "run", dict(TINY_MODEL), train, {"split": "all"}, resume=False)
        tr.fit()
        log = tmp_path / "run" / "log.csv"
        assert len(log.read_text().splitlines()) == 2
        log.write_text(log.read_text().splitlines()[0] + "\n")  # killed after last.pt, before the log row
        tr = build_trainer(clips, tmp_path / "run", {}, {"epochs": 2}, {}, resume=True)
        tr.fit()
    finally:
        torch.set_num_threads(n)
    rows = log.read_text().splitlines()
    assert [r.split(",")[0] for r in rows] == ["epoch", "1", "2"]
    assert not list((tmp_path / "run").glob("*.part"))


def test_train_keeps_the_files_of_a_folder_without_a_run(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "model.safetensors").write_bytes(b"mine")
    (run / "log.csv").write_text("mine")
    p = cli("train", "--cache", str(tmp_path / "nocache"), "--speaker", "2", "--out", str(run))
    refused(p, "already exists", "--force")
    assert (run / "model.safetensors").read_bytes() == b"mine" and (run / "log.csv").read_text() == "mine"
