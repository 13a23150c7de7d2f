"""The one exception type a user sees.

Anything the user can fix (a missing file, a malformed BVH, a wrong skeleton, an
existing output) is raised as :class:`UserError`. The command line catches it,
prints its message on one line and exits with status 2 — never a traceback.
"""

from __future__ import annotations

from pathlib import Path


class UserError(Exception):
    """A problem with the user's input, described in words the user can act on."""


def file_error(path: str | Path, problem: str) -> UserError:
    """A :class:`UserError` that names the file first: ``"<path>: <problem>"``."""
    return UserError(f"{path}: {problem}")


def require_file(path: str | Path, what: str = "file") -> Path:
    """Return ``path`` as a Path, or raise a UserError if it is not an existing file."""
    p = Path(path)
    if not p.exists():
        raise file_error(p, f"{what} not found")
    if not p.is_file():
        raise file_error(p, f"{what} is not a regular file")
    return p


def refuse_overwrite(path: str | Path, force: bool, flag: str = "--force") -> Path:
    """Raise unless ``path`` is free or ``force`` is set (nothing is lost without asking)."""
    p = Path(path)
    if p.exists() and not force:
        raise file_error(p, f"already exists; pass {flag} to overwrite it")
    return p
