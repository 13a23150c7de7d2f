"""Issue 28, item 2: ``styles install RUN`` copies only the run's own files. Links (to a file outside,
inside ``model.fgd/``, loops) are refused, sizes are capped (a 2 GB sparse ``log.csv`` costs no disk),
and a refused install leaves the styles store as it was (everything is staged, then moved)."""

from __future__ import annotations

import os

import pytest

from facecapges.errors import UserError
from facecapges.styles import install_style, list_styles, styles_dir, user_styles_dir
from runtime_helpers import cli


@pytest.fixture()
def store(tmp_path, monkeypatch):
    monkeypatch.setenv("FACECAPGES_STYLES", str(tmp_path / "store"))
    return tmp_path / "store"


@pytest.fixture()
def run(tmp_path):
    """A run folder: a real checkpoint (a shipped style's file), its log, card and FGD folder."""
    r = tmp_path / "my-run"
    (r / "model.fgd").mkdir(parents=True)
    shipped = sorted(styles_dir().glob("*.safetensors"))[0]
    (r / "model.safetensors").write_bytes(shipped.read_bytes())
    (r / "log.csv").write_text("epoch,loss\n1,0.5\n")
    (r / "model_card.md").write_text("# my run\n")
    (r / "model.fgd" / "fgd.json").write_text("{}")
    return r


def _store_files(store):
    return sorted(p.name for p in store.iterdir()) if store.exists() else []


def test_a_clean_run_installs(store, run):
    dest = install_style(run)
    assert dest == user_styles_dir() / "my-run.safetensors" and list_styles()["my-run"] == dest
    assert _store_files(store) == ["my-run.fgd", "my-run.log.csv", "my-run.md", "my-run.safetensors"]
    assert (store / "my-run.md").read_text() == "# my run\n"


def _card_to_passwd(run, tmp_path):
    (run / "model_card.md").unlink()
    (run / "model_card.md").symlink_to("/etc/passwd")


def _link_in_fgd(run, tmp_path):
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "secret.txt").write_text("secret")
    (run / "model.fgd" / "more").symlink_to(outside)


def _file_link_in_fgd(run, tmp_path):
    (run / "model.fgd" / "passwd").symlink_to("/etc/passwd")


def _loop_in_fgd(run, tmp_path):
    (run / "model.fgd" / "a").symlink_to(run / "model.fgd" / "b")
    (run / "model.fgd" / "b").symlink_to(run / "model.fgd" / "a")


def _fgd_is_a_loop(run, tmp_path):
    import shutil

    shutil.rmtree(run / "model.fgd")
    (run / "model.fgd").symlink_to(run / "model.fgd")


def _sparse_log(run, tmp_path):
    with (run / "log.csv").open("wb") as f:
        f.truncate(2 << 30)


def _checkpoint_link(run, tmp_path):
    real = tmp_path / "elsewhere.safetensors"
    (run / "model.safetensors").rename(real)
    (run / "model.safetensors").symlink_to(real)


def _fifo_card(run, tmp_path):
    (run / "model_card.md").unlink()
    os.mkfifo(run / "model_card.md")


CASES = {"card links to /etc/passwd": (_card_to_passwd, "symbolic link"),
         "folder link inside model.fgd": (_link_in_fgd, "symbolic link"),
         "file link inside model.fgd": (_file_link_in_fgd, "symbolic link"),
         "link loop inside model.fgd": (_loop_in_fgd, "symbolic link"),
         "model.fgd links to itself": (_fgd_is_a_loop, "symbolic link"),
         "2 GB sparse log.csv": (_sparse_log, "more than a style's file may be"),
         "checkpoint is a link": (_checkpoint_link, "symbolic link"),
         "card is a FIFO": (_fifo_card, "not a regular file")}


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_crafted_run_is_refused_and_the_store_is_untouched(store, run, tmp_path, case):
    install_style(run, name="before")  # the store already holds a style: it must stay as it was
    before = {p.name: p.read_bytes() if p.is_file() else None for p in store.iterdir()}
    make, words = CASES[case]
    make(run, tmp_path)
    with pytest.raises(UserError, match=words):
        install_style(run, name="before", force=True)
    assert {p.name: p.read_bytes() if p.is_file() else None for p in store.iterdir()} == before
    assert not [p for p in store.iterdir() if p.name.startswith(".install-")]
    du = sum(p.stat().st_blocks * 512 for p in store.rglob("*") if p.is_file())
    assert du < 64 << 20  # no 2 GB copy, not even a partial one


def test_the_cli_refuses_without_traceback(store, run, tmp_path):
    _card_to_passwd(run, tmp_path)
    r = cli("styles", "install", str(run), timeout=120, env={"FACECAPGES_STYLES": str(store)})
    assert r.returncode == 2 and "Traceback" not in r.stderr and "symbolic link" in r.stderr, r.stderr[-2000:]
    assert _store_files(store) == []
