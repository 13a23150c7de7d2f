"""The options of ``run`` and ``live``: the command line's defaults are these classes' defaults.

Kept apart from :mod:`.run` and :mod:`.live` (which do the work) so that the command line
imports nothing heavy to show ``--help``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass
class LiveOptions:
    """The options of ``live`` (``facecapges live --help`` says what each does)."""

    camera: int | None = None
    video: Path | None = None
    livelink: int | None = None
    realtime: bool = False
    loop: bool = False
    mic: str | None = None
    audio: Path | None = None
    vmc: str | None = None
    vmc_blend: str = "vrm"
    vmc_avatar: Path | None = None
    vmc_parts: str = "all"
    rate: float | None = None
    web: str | None = None
    host: str | None = None
    record: Path | None = None
    face_json: str = "beat"
    vrma: bool = False
    avatar: Path | None = None
    checkpoint: Path | None = None
    style: str | None = None
    intensity: float = 1.0
    estimator: str = "hybrid"
    depth: Path | None = None
    intrinsics: Path | None = None
    max_seconds: float | None = None
    head: str = "capture"
    faces: int = 1
    body: bool = False
    gestures: bool = False
    force: bool = False


DEFAULT_VIDEO_SIZE = (640, 480)


@dataclass
class RunOptions:
    """The options of ``run`` (``facecapges run --help`` says what each does)."""

    video: Path
    out: Path
    audio: Path | None = None
    checkpoint: Path | None = None
    style: str | None = None
    intensity: float = 1.0
    estimator: str = "hybrid"
    max_frames: int | None = None
    no_video: bool = False
    face_json: str = "beat"
    video_size: str | None = None
    head: str = "capture"
    faces: int = 1
    avatar: Path | None = None
    json_out: bool = False
    force: bool = False
