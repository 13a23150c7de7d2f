"""The one progress display of long work: a bar on a terminal, plain lines in a log or a pipe.

:class:`Progress` is ``rich.progress.Progress`` (same ``add_task`` / ``update`` / ``advance`` /
``start`` / ``stop``, usable as a context manager) drawn on stderr. When stderr is not a terminal
(``cmd 2> log``, ``cmd |& tee``, a CI job) rich would draw nothing until the end, so instead each
task prints a plain line to stderr, at most one line per :func:`interval` seconds per display,
and a last line when a task that printed one finishes::

    speech predictor: 240/800 (30 %), 1 min 12 s, about 2 min 48 s left  validation 0.512 (best 0.498 at 200)

Work shorter than the interval prints nothing. ``FACECAPGES_PROGRESS_SECONDS`` sets the interval
(default 10 s; 0 prints every update, for tests). ``disable=True`` (a command's ``--quiet``) shows
nothing either way.
"""

from __future__ import annotations

import os
import sys
import time
from typing import Any

from rich.console import Console
from rich.progress import Progress as _RichProgress
from rich.progress import TaskID
from rich.text import Text

DEFAULT_INTERVAL_S = 10.0


def interval() -> float:
    """Seconds between two plain progress lines (``FACECAPGES_PROGRESS_SECONDS``, default 10)."""
    try:
        return max(0.0, float(os.environ.get("FACECAPGES_PROGRESS_SECONDS", DEFAULT_INTERVAL_S)))
    except ValueError:
        return DEFAULT_INTERVAL_S


def _plain(text: str) -> str:
    """``text`` without rich markup (as written when it is none: "FGD autoencoder [upper]")."""
    try:
        return Text.from_markup(text).plain
    except Exception:  # noqa: BLE001 — rich's MarkupError: a bracket that is no tag
        return text


def _duration(s: float) -> str:
    s = int(round(s))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60} s"
    return f"{s // 3600} h {s % 3600 // 60} min"


class Progress(_RichProgress):
    """``rich.progress.Progress`` on stderr that prints rate-limited plain lines when stderr is no terminal."""

    def __init__(
        self, *columns: Any, disable: bool = False, console: Console | None = None, prefix: str = "", **kw: Any
    ):
        """``prefix`` goes before each task's description in the plain lines (e.g. ``prepare``)."""
        console = console or Console(stderr=True)
        self._plain = not disable and not console.is_terminal
        super().__init__(*columns, console=console, disable=disable or self._plain, **kw)
        self._every = interval()
        self._last_line = time.monotonic()  # the first line after one interval: short work stays silent
        self._announced: set[TaskID] = set()  # tasks that printed a line
        self._done: set[TaskID] = set()  # tasks that printed their last line
        self._prefix = prefix

    def update(self, task_id: TaskID, *args: Any, **kw: Any) -> None:
        super().update(task_id, *args, **kw)
        if self._plain:
            self._line(task_id)

    def advance(self, task_id: TaskID, advance: float = 1) -> None:
        super().advance(task_id, advance)
        if self._plain:
            self._line(task_id)

    def _line(self, task_id: TaskID) -> None:
        with self._lock:
            task = self._tasks.get(task_id)
            if task is None:
                return
            finished = task.total is not None and task.completed >= task.total
            now = time.monotonic()
            if finished:
                if task_id not in self._announced or task_id in self._done:
                    return
            elif now - self._last_line < self._every:
                return
            self._last_line = now
            self._announced.add(task_id)
            what = " ".join(x for x in (self._prefix, _plain(task.description)) if x) or "working"
            done = f"{task.completed:.0f}"
            if task.total:
                done += f"/{task.total:.0f} ({100 * task.completed / task.total:.0f} %)"
            line = f"{what}: {done}, {_duration(task.elapsed or 0.0)}"
            left = task.time_remaining
            if finished:
                line += ", done"
                self._done.add(task_id)
            elif left is not None:
                line += f", about {_duration(left)} left"
            info = task.fields.get("info")
            if info:
                line += f"  {_plain(str(info))}"
        print(line, file=sys.stderr, flush=True)
