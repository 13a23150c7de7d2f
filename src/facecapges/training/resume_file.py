"""The training-state file ``RUN/last.pt``: data only, never code.

A run folder is something people copy and share, so reading one must not be able to
run anything. ``last.pt`` is written with :func:`torch.save` but holds only tensors and
plain values (dict, list, tuple, str, int, float, bool, None); numpy arrays are stored
as tensors under a one-key marker ``{"__ndarray__": tensor}`` and come back as numpy.
It is read with ``torch.load(weights_only=True)``, whose unpickler refuses every other
global: a file crafted to run code on load is refused with a :class:`UserError` and
its payload never runs.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from facecapges.errors import UserError

_ARRAY = "__ndarray__"
_PLAIN = (str, int, float, bool, type(None))


def _encode(obj, where: str):
    if isinstance(obj, torch.Tensor):
        return obj.detach().cpu()
    if isinstance(obj, np.ndarray):
        return {_ARRAY: torch.from_numpy(np.ascontiguousarray(obj))}
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, dict):
        return {k: _encode(v, f"{where}.{k}") for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(_encode(v, f"{where}[{i}]") for i, v in enumerate(obj))
    if isinstance(obj, _PLAIN):
        return obj
    raise TypeError(f"training state {where} is a {type(obj).__name__}; only tensors and plain values are stored")


def _decode(obj):
    if isinstance(obj, dict):
        if set(obj) == {_ARRAY} and isinstance(obj[_ARRAY], torch.Tensor):
            return obj[_ARRAY].numpy()
        return {k: _decode(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(_decode(v) for v in obj)
    return obj


def save_state(path: str | Path, state: dict) -> Path:
    """Write ``state`` to ``path`` atomically (``PATH.part``, fsync, rename); tensors go to the CPU."""
    path = Path(path)
    tmp = path.with_name(path.name + ".part")
    with open(tmp, "wb") as f:
        torch.save(_encode(state, "state"), f)
        f.flush()
        os.fsync(f.fileno())
    tmp.replace(path)
    return path


def load_state(path: str | Path, required: tuple[str, ...] = ()) -> dict:
    """Read a file written by :func:`save_state` (UserError when missing, corrupt, foreign or unsafe)."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: nothing to resume (no {p.name} in the run folder)")
    try:
        state = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001  pickle.UnpicklingError beyond data, or a corrupt file
        why = (
            "it holds more than tensors and plain values (refused: loading it could run code)"
            if "weights_only" in str(exc) or "global" in str(exc).lower()
            else f"{exc.__class__.__name__}"
        )
        raise UserError(f"{p}: cannot read the training state ({why})") from None
    if not isinstance(state, dict):
        raise UserError(f"{p}: not a training state (a {type(state).__name__}, expected a mapping)")
    missing = [k for k in required if k not in state]
    if missing:
        raise UserError(f"{p}: not a training state (missing {', '.join(missing)})")
    return _decode(state)


_HELD: dict[str, list[int]] = {}  # run folder -> [descriptor, holders in this process]


class RunFolderLock:
    """An exclusive lock on a run folder for as long as one training uses it.

    ``flock`` on the folder itself (no lock file is left behind; the kernel drops the
    lock when the process dies, ``kill -9`` included). A second ``train`` on the same
    folder gets a :class:`UserError` instead of writing the same epochs twice. Within
    one process the lock is re-entrant (the command takes it early, the trainer again).
    """

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self._key: str | None = None

    def acquire(self) -> RunFolderLock:
        import fcntl

        if self._key is not None:
            return self
        self.folder.mkdir(parents=True, exist_ok=True)
        key = str(self.folder.resolve())
        if key in _HELD:
            _HELD[key][1] += 1
        else:
            fd = os.open(self.folder, os.O_RDONLY)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                os.close(fd)
                raise UserError(
                    f"{self.folder}: another training is using this run folder; wait for it to end "
                    "(or stop it) before starting or resuming here"
                ) from None
            _HELD[key] = [fd, 1]
        self._key = key
        return self

    def release(self) -> None:
        if self._key is None:
            return
        held = _HELD[self._key]
        held[1] -= 1
        if held[1] == 0:
            os.close(held[0])  # closing the descriptor releases the flock
            del _HELD[self._key]
        self._key = None

    def __enter__(self) -> RunFolderLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def write_log(path: str | Path, rows: list[dict], fields: list[str]) -> None:
    """Write the whole ``log.csv`` from the run's history, atomically.

    The log is rebuilt from the history stored in ``last.pt`` at every save, so a run
    killed between saving its state and its log gets the missing row back on resume.
    """
    import csv

    path = Path(path)
    tmp = path.with_name(path.name + ".part")
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
        f.flush()
        os.fsync(f.fileno())
    tmp.replace(path)
