"""facecapges.progress: a bar on a terminal, plain rate-limited lines on stderr in a log or a pipe."""

from __future__ import annotations

import io

from rich.console import Console

from facecapges.progress import Progress


def _work(monkeypatch, capsys, seconds: str, terminal: bool = False) -> list[str]:
    monkeypatch.setenv("FACECAPGES_PROGRESS_SECONDS", seconds)
    console = Console(file=io.StringIO(), force_terminal=terminal)
    with Progress(console=console, prefix="prepare") as bar:
        task = bar.add_task("2_scott_0_1_1", total=50, info="")
        for _ in range(50):
            bar.update(task, advance=1, info="loss 0.5")
    return capsys.readouterr().err.splitlines()


def test_plain_lines_when_not_a_terminal(monkeypatch, capsys):
    lines = _work(monkeypatch, capsys, "0")  # every update, for the test
    assert len(lines) == 50 and lines[0].startswith("prepare 2_scott_0_1_1: 1/50 (2 %), ")
    assert lines[-1].startswith("prepare 2_scott_0_1_1: 50/50 (100 %), ") and ", done  loss 0.5" in lines[-1]


def test_short_work_prints_nothing_and_a_terminal_gets_the_bar(monkeypatch, capsys):
    assert _work(monkeypatch, capsys, "10") == []  # shorter than the interval: silent
    assert _work(monkeypatch, capsys, "0", terminal=True) == []  # rich draws its bar instead
