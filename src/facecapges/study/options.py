"""The options of the ``study`` commands: the command line's defaults are these classes' defaults.

Kept apart from :mod:`.build`, :mod:`.server` and :mod:`.analyze` (which import numpy) so that
the command line imports nothing heavy to show ``--help``; the library functions take their
defaults from the same fields.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass
class StudyCreateOptions:
    """The options of ``study create`` that have defaults."""

    participants: int | None = None
    seed: int = 0
    force: bool = False
    avatar: Path | None = None


@dataclass
class StudyServeOptions:
    """The options of ``study serve`` that have defaults."""

    host: str = "127.0.0.1"
    port: int = 8770
    language: str = "en"


@dataclass
class StudyAnalyzeOptions:
    """The options of ``study analyze`` that have defaults."""

    only: str = ""
    force: bool = False
