"""The answer store: one append-only JSON file per participant, written atomically.

``STUDY_DIR/responses/<participant>.json``::

    {"participant": "P01",
     "history": [
        {"type": "session", "time": "2026-11-22T01:30:00.123+00:00", "next": 0},
        {"type": "play", "time": ..., "trial": 0},
        {"type": "answer", "time": ..., "trial": 0, "clip": "scott_1",
         "positions": ["camn", "ours", "gt"],                 # system at each screen position, left → right
         "ranks_by_position": {"realism": [2, 1, 3], ...},   # what the participant entered
         "ranks": {"realism": {"camn": 2, "ours": 1, "gt": 3}, ...}},
        ...]}

Every event is appended to ``history`` and the whole file is rewritten under a
temporary name in the same folder, flushed to disk (fsync) and renamed over the old
file (``os.replace``, atomic on POSIX). The file on disk is therefore always a complete
earlier or later version — a browser closed mid-study, a killed server or a power cut
loses at most the event being written, never an answer already acknowledged. Nothing
is ever removed from ``history``.

Bounds: a participant file holds at most :data:`MAX_SESSIONS` session events and
:data:`MAX_PLAYS` play events per trial; more are refused (:class:`LimitError`, HTTP
429) and not written, so no client can grow a file — or the cost of rewriting it —
without limit. Every answer records ``auth``, the digest of the invitation token it
was given with (facecapges.study.design.token_digest); the analysis counts only answers
whose ``auth`` matches the participant's token.

The participant's progress is derived from the file: the next trial is the number of
answered trials. Answers must come in plan order — an answer for any trial other than
the next one is refused (no going back, no skipping), and a returning participant
resumes at the first unanswered trial.
"""

from __future__ import annotations

import json
import os
import tempfile
import threading
from datetime import UTC, datetime
from pathlib import Path

from facecapges.study.criteria import CRITERION_KEYS
from facecapges.study.design import StudyPlan, token_digest

MAX_SESSIONS = 200  # session (re)starts recorded per participant
MAX_PLAYS = 50  # play events recorded per trial


class AnswerError(ValueError):
    """An answer the store refuses (wrong trial, malformed ranks); the message says why."""


class LimitError(AnswerError):
    """An event beyond the bounds of a participant file (not recorded)."""


class DamagedFileError(Exception):
    """A participant file on disk that is not a valid answer file (the message names it)."""


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def write_json_atomic(path: Path, doc: dict) -> None:
    """Write ``doc`` to ``path`` via a temporary file in the same folder, fsync and rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(doc, f, indent=1)
            f.write("\n")
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    try:  # make the rename itself durable
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
    except OSError:
        pass


def answers_of(doc: dict) -> list[dict]:
    """The answer events of a participant file, first answer per trial, in trial order."""
    seen: dict[int, dict] = {}
    for ev in doc.get("history", []):
        if ev.get("type") == "answer" and int(ev["trial"]) not in seen:
            seen[int(ev["trial"])] = ev
    return [seen[i] for i in sorted(seen)]


class AnswerStore:
    """Thread-safe access to the participant files of one study."""

    def __init__(self, responses_dir: str | Path, plan: StudyPlan, criteria: tuple[str, ...] = CRITERION_KEYS):
        self.dir = Path(responses_dir)
        self.plan = plan
        self.criteria = tuple(criteria)
        self._locks: dict[str, threading.Lock] = {}
        self._guard = threading.Lock()

    def _lock(self, pid: str) -> threading.Lock:
        with self._guard:
            return self._locks.setdefault(pid, threading.Lock())

    def path(self, pid: str) -> Path:
        return self.dir / f"{pid}.json"

    def _participant(self, pid: str):
        p = self.plan.participant(pid)
        if p is None:
            raise KeyError(pid)
        return p

    def load(self, pid: str) -> dict:
        self._participant(pid)
        p = self.path(pid)
        if not p.exists():
            return {"participant": pid, "history": []}
        try:
            doc = json.loads(p.read_text(encoding="utf-8"))
            if (
                not isinstance(doc, dict)
                or not isinstance(doc.get("history"), list)
                or not all(isinstance(ev, dict) for ev in doc["history"])
            ):
                raise ValueError("no list of events")
            answers_of(doc)
        except (ValueError, KeyError, TypeError, RecursionError, OSError) as exc:
            raise DamagedFileError(
                f"{p}: damaged answer file ({exc.__class__.__name__}); nothing more is "
                "recorded for this participant until it is repaired or moved away"
            ) from None
        return doc

    def state(self, pid: str) -> dict:
        n = len(self._participant(pid).trials)
        done = len(answers_of(self.load(pid)))
        return {"participant": pid, "next": done, "total": n, "done": done >= n}

    def _append(self, pid: str, event: dict) -> dict:
        doc = self.load(pid)
        doc["history"].append({"time": _now(), **event})
        write_json_atomic(self.path(pid), doc)
        return doc

    def session(self, pid: str) -> dict:
        """Record that the participant (re)started; returns the state."""
        with self._lock(pid):
            st = self.state(pid)
            if sum(ev.get("type") == "session" for ev in self.load(pid)["history"]) < MAX_SESSIONS:
                self._append(pid, {"type": "session", "next": st["next"]})
            return st

    def event(self, pid: str, trial: int, kind: str) -> None:
        """Record a non-answer event of the current trial (e.g. ``play``)."""
        if kind not in ("play",):
            raise AnswerError(f"unknown event type {kind!r}")
        with self._lock(pid):
            st = self.state(pid)
            if trial != st["next"]:
                raise AnswerError(f"trial {trial} is not the current trial ({st['next']})")
            seen = sum(ev.get("type") == kind and ev.get("trial") == trial for ev in self.load(pid)["history"])
            if seen >= MAX_PLAYS:
                raise LimitError(f"at most {MAX_PLAYS} {kind} events are recorded per clip; not recorded")
            self._append(pid, {"type": kind, "trial": trial})

    def answer(self, pid: str, trial: int, ranks_by_position: object) -> dict:  # checked: from the client
        """Save the ranks of trial ``trial`` (must be the next one); returns the new state."""
        part = self._participant(pid)
        k = len(self.plan.systems)
        if not isinstance(ranks_by_position, dict) or set(ranks_by_position) != set(self.criteria):
            raise AnswerError(f"ranks must be given for exactly the criteria {list(self.criteria)}")
        clean = {}
        for c in self.criteria:
            r = ranks_by_position[c]
            if (
                not isinstance(r, list)
                or len(r) != k
                or any(isinstance(x, bool) or not isinstance(x, int) for x in r)
                or sorted(r) != list(range(1, k + 1))
            ):
                raise AnswerError(f"ranks for {c} must be 1..{k}, each once, one per position; got {r!r}")
            clean[c] = [int(x) for x in r]
        with self._lock(pid):
            st = self.state(pid)
            if st["done"]:
                raise AnswerError("every clip has already been ranked")
            if trial != st["next"]:
                raise AnswerError(
                    f"trial {trial} is not the current trial ({st['next']}); answers cannot be changed or skipped"
                )
            t = part.trials[trial]
            ranks = {c: {s: clean[c][j] for j, s in enumerate(t.systems)} for c in self.criteria}
            self._append(
                pid,
                {
                    "type": "answer",
                    "trial": trial,
                    "clip": t.clip,
                    "positions": list(t.systems),
                    "ranks_by_position": clean,
                    "ranks": ranks,
                    **({"auth": token_digest(part.token)} if part.token else {}),
                },
            )
            return self.state(pid)
