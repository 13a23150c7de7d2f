"""The options of ``eval``, ``ablate`` and ``fgd-train``: the command line's defaults are these classes' defaults.

Kept apart from :mod:`.run`, :mod:`.ablate` and :mod:`.fgd` (which import numpy and torch) so
that the command line imports nothing heavy to show ``--help``. The library functions take
their defaults from the same fields (``facecapges eval --help`` says what each option does).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

OFFSETS = "2:60:2"  # the BeatAlign control's audio shifts in s (START:STOP:STEP, stop included)


@dataclass
class EvalOptions:
    """The options of ``eval`` that have defaults."""

    checkpoint: Path | None = None
    style: str | None = None
    speaker: int | None = None
    split: str = "test"
    holdout_from: int | None = None
    fgd: Path | None = None
    offsets: str = OFFSETS
    video: bool = True
    seed: int = 0
    samples: int = 3
    force: bool = False
    quiet: bool = False


@dataclass
class AblateOptions:
    """The options of ``ablate`` that have defaults."""

    speaker: int = 2
    config: Path | None = None
    epochs: int | None = None
    split: str | None = None
    holdout_from: int | None = None
    variants: str = "full,no_head,offline,camn"
    reuse_default: bool = True
    given: str | None = None
    retrain: bool = False
    fgd: Path | None = None
    fgd_epochs: int = 400  # = FGDConfig.epochs (a test checks)
    samples: int = 3
    offsets: str = OFFSETS
    seed: int = 0
    force: bool = False
    quiet: bool = False


@dataclass
class FgdTrainOptions:
    """The options of ``fgd-train`` that have defaults (epochs, batch size, momentum, seed: FGDConfig's)."""

    cache: Path | None = None
    speaker: int = 2
    split: str = "train"
    holdout_from: int | None = None
    out: Path | None = None
    checkpoint: Path | None = None
    epochs: int = 400
    batch_size: int = 256
    momentum: float = 0.9
    regions: str = "with_head,without_head"
    seed: int = 0
    force: bool = False
    quiet: bool = False
