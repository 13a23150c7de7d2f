"""The options of ``eval``, ``ablate`` and ``fgd-train``: the command line's defaults are these classes' defaults.

Kept apart from :mod:`.run`, :mod:`.ablate` and :mod:`.fgd` (which import numpy and torch) so
that the command line imports nothing heavy to show ``--help``. The library functions take
their defaults from the same fields (``facecapges eval --help`` says what each option does).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from facecapges.errors import UserError

OFFSETS = "2:60:2"  # the BeatAlign control's audio shifts in s (START:STOP:STEP, stop included)


@dataclass
class EvalOptions:
    """The options of ``eval``: what :func:`facecapges.evaluation.run.run_eval` takes."""

    cache: Path
    out: Path
    checkpoint: Path | None = None
    style: str | None = None
    speaker: int | None = None
    split: str = "test"
    holdout_from: int | None = None
    audio: list[Path] = field(default_factory=list)
    fgd: Path | None = None
    offsets: str = OFFSETS
    video: bool = True
    seed: int = 0
    samples: int = 3
    force: bool = False
    quiet: bool = False


@dataclass
class AblateOptions:
    """The options of ``ablate``: what :func:`facecapges.evaluation.ablate.run_ablation` takes."""

    cache: Path
    out: Path
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
    holdout_tail: bool = False
    out: Path | None = None
    checkpoint: Path | None = None
    epochs: int = 400
    batch_size: int = 256
    momentum: float = 0.9
    regions: str = "with_head,without_head"
    seed: int = 0
    force: bool = False
    quiet: bool = False


def parse_offsets(text: str) -> list[float]:
    """``"2:60:2"`` (start:stop:step, stop included) or ``"2,5,9"`` → offsets in seconds."""
    try:
        if ":" in text:
            a, b, c = (float(x) for x in text.split(":"))
            if c <= 0 or b < a:
                raise ValueError
            n = int((b - a) // c) + 1
            return [a + i * c for i in range(n)]
        out = [float(x) for x in text.split(",") if x.strip()]
        if not out:
            raise ValueError
        return out
    except ValueError:
        raise UserError(f"--offsets must be START:STOP:STEP or a comma list of seconds, got {text!r}") from None


def parse_given(text: str | None) -> dict[str, str]:
    """``"full=beat2-scott-demo,camn=run/model.safetensors"`` → {variant: checkpoint}."""
    if not text:
        return {}
    out = {}
    for item in text.split(","):
        name, sep, ref = item.partition("=")
        if not sep or not name.strip() or not ref.strip():
            raise UserError(f"--given must be VARIANT=CHECKPOINT[,VARIANT=CHECKPOINT…], got {text!r}")
        out[name.strip()] = ref.strip()
    return out
